"""Import the Unity boids recordings (the paper's own 3D data) into trajectory files.

Each line of a recording is one rendered frame holding every boid as
``(x, y, z)(hx, hy, hz)``: position and unit heading, 7 decimals. The importer checks
every line (boid count, finite values, unit headings) and names file and line of
anything malformed; it drops the first ``--discard`` frames (10, as the paper does,
because the first frames contain spawn jumps).

Recordings differ in length. By default all recordings are trimmed to the shortest
one and written as one file (``[recordings, T, n, 6]``); ``--separate`` writes one file
per recording instead (``OUT`` gets a ``_<index>`` suffix), keeping every frame.

    python -m training.import_unity training/unity_boids/*.txt.xz --out data/unity.npz

The six recordings the project uses ship xz-compressed in ``training/unity_boids/``
(:data:`UNITY_DIR`, :func:`shipped_recordings`); ``read_recording`` reads ``.txt`` and
``.txt.xz`` alike.
"""
from __future__ import annotations

import argparse
import lzma
import re
import sys
from pathlib import Path
from typing import List, Optional, Sequence

import numpy as np

from knode_swarm_ros.core import save_trajectories
from knode_swarm_ros.core.cli import cli
from knode_swarm_ros.core.errors import KnodeError

__all__ = ["read_recording", "import_recordings", "shipped_recordings", "UNITY_DIR", "UnityFormatError", "main"]

#: The Unity recordings shipped with the repository (MIT, see the README there).
UNITY_DIR = Path(__file__).resolve().parent / "unity_boids"

_TUPLE = re.compile(r"\(([^()]*)\)")
# Headings are stored with 7 decimals, so their norm is 1 only up to rounding.
UNIT_TOLERANCE = 1e-4


class UnityFormatError(KnodeError, ValueError):
    """A recording line is malformed; the message names file and line."""


def _parse_line(text: str, where: str, boids: Optional[int]) -> np.ndarray:
    tuples = _TUPLE.findall(text)
    rest = _TUPLE.sub("", text).strip()
    if rest:
        raise UnityFormatError(f"{where}: unexpected text {rest[:40]!r} outside the (x, y, z) groups")
    if not tuples or len(tuples) % 2:
        raise UnityFormatError(f"{where}: expected pairs of (x, y, z)(hx, hy, hz) groups, found {len(tuples)} groups")
    if boids is not None and len(tuples) != 2 * boids:
        raise UnityFormatError(f"{where}: {len(tuples) // 2} boids, expected {boids}")
    values = np.empty((len(tuples), 3))
    for g, group in enumerate(tuples):
        parts = group.split(",")
        if len(parts) != 3:
            raise UnityFormatError(f"{where}: group {g + 1} holds {len(parts)} numbers, expected 3")
        try:
            values[g] = [float(v) for v in parts]
        except ValueError as exc:
            raise UnityFormatError(f"{where}: group {g + 1}: a number could not be read ({exc})") from None
    if not np.all(np.isfinite(values)):
        raise UnityFormatError(f"{where}: non-finite value in group {np.argwhere(~np.isfinite(values))[0][0] + 1}")
    frame = values.reshape(-1, 6)
    norms = np.linalg.norm(frame[:, 3:], axis=1)
    bad = np.flatnonzero(np.abs(norms - 1.0) > UNIT_TOLERANCE)
    if bad.size:
        raise UnityFormatError(f"{where}: heading of boid {bad[0]} has norm {norms[bad[0]]:.6f}, not 1")
    return frame


def read_recording(path, boids: Optional[int] = None, discard: int = 10) -> np.ndarray:
    """One recording as ``[T, n, 6]`` (position, unit heading), first ``discard`` frames dropped.

    Args:
        boids: expected boid count; by default the first line sets it for the file.
    """
    path = Path(path)
    if not path.is_file():
        raise UnityFormatError(f"{path}: no such file")
    frames: List[np.ndarray] = []
    opener = lzma.open if path.suffix == ".xz" else open
    with opener(path, "rt", encoding="utf-8") as fh:
        for number, line in enumerate(fh, start=1):
            if not line.strip():
                continue
            frame = _parse_line(line, f"{path}:{number}", boids)
            boids = frame.shape[0]
            frames.append(frame)
    if len(frames) <= discard:
        raise UnityFormatError(f"{path}: {len(frames)} frames, need more than the {discard} discarded")
    states = np.stack(frames[discard:])
    # Renormalise away the 7-decimal rounding so headings are unit to float precision.
    states[..., 3:] /= np.linalg.norm(states[..., 3:], axis=-1, keepdims=True)
    return states


def shipped_recordings() -> List[Path]:
    """The shipped recordings ``simulation_data{0..5}_*.txt.xz``, in recording order."""
    paths = sorted(UNITY_DIR.glob("simulation_data*.txt.xz"))
    if not paths:
        raise UnityFormatError(f"{UNITY_DIR}: no simulation_data*.txt.xz recordings")
    return paths


def import_recordings(paths: Sequence, out, dt: float = 1.0 / 60.0, discard: int = 10,
                      separate: bool = False) -> List[Path]:
    """Import recordings into trajectory file(s); returns the written paths."""
    recordings = [read_recording(p, discard=discard) for p in paths]
    counts = {r.shape[1] for r in recordings}
    if len(counts) > 1:
        raise UnityFormatError(f"recordings hold different boid counts {sorted(counts)}; import them separately")
    lengths = [int(r.shape[0]) for r in recordings]
    base = {"generator": "training.import_unity", "source": "Unity boids (LishuoPan/Boids)",
            "discarded_frames": discard, "dt_assumed": dt}
    out = Path(out)
    written = []
    if separate:
        for i, (path, rec) in enumerate(zip(paths, recordings)):
            target = out.with_name(f"{out.stem}_{i}{out.suffix or '.npz'}")
            save_trajectories(target, rec[None], dt, "boids3d", dict(base, files=[str(path)], frames=[lengths[i]]))
            written.append(target)
    else:
        T = min(lengths)
        states = np.stack([r[:T] for r in recordings])
        save_trajectories(out, states, dt, "boids3d",
                          dict(base, files=[str(p) for p in paths], frames=lengths, trimmed_to=T))
        written.append(out)
    return written


@cli("python -m training.import_unity")
def main(argv: Optional[Sequence[str]] = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m training.import_unity", description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("files", nargs="+", help="Unity recordings (simulation_data*.txt or .txt.xz)")
    ap.add_argument("--out", required=True, help="output trajectory file (.npz)")
    ap.add_argument("--dt", type=float, default=1.0 / 60.0, help="frame time in seconds (default 1/60)")
    ap.add_argument("--discard", type=int, default=10, help="leading frames dropped (default 10)")
    ap.add_argument("--separate", action="store_true", help="one output file per recording, untrimmed")
    args = ap.parse_args(argv)
    if not args.dt > 0:
        ap.error(f"--dt must be > 0, got {args.dt}")
    if args.discard < 0:
        ap.error(f"--discard must be >= 0, got {args.discard}")
    written = import_recordings(args.files, args.out, args.dt, args.discard, args.separate)
    for path in written:
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
