"""Reading the Unity boids recordings (the paper's own 3D data) and finding the shipped ones.

Each line of a recording is one rendered frame holding every boid as
``(x, y, z)(hx, hy, hz)``: position and unit heading, 7 decimals. :func:`read_recording`
checks every line (boid count, finite values, unit headings), names file and line of anything
malformed, and reads ``.txt`` and ``.txt.xz`` alike. The recordings ship xz-compressed in
``training/unity_boids/`` (:data:`UNITY_DIR`, MIT, see the README there).
"""

from __future__ import annotations

import lzma
import re
from pathlib import Path
from typing import List, Optional

import numpy as np

from knode_swarm_ros.core.errors import KnodeError

__all__ = ['read_recording', 'shipped_recordings', 'UNITY_DIR', 'UnityFormatError']

#: The Unity recordings shipped with the repository (MIT, see the README there).
UNITY_DIR = Path(__file__).resolve().parent.parent.parent / 'unity_boids'

_TUPLE = re.compile(r'\(([^()]*)\)')
# Headings are stored with 7 decimals, so their norm is 1 only up to rounding.
UNIT_TOLERANCE = 1e-4


class UnityFormatError(KnodeError, ValueError):
    """A recording line is malformed; the message names file and line."""


def _parse_line(text: str, where: str, boids: Optional[int]) -> np.ndarray:
    tuples = _TUPLE.findall(text)
    rest = _TUPLE.sub('', text).strip()
    if rest:
        raise UnityFormatError(f'{where}: unexpected text {rest[:40]!r} outside the (x, y, z) groups')
    if not tuples or len(tuples) % 2:
        raise UnityFormatError(
            f'{where}: expected pairs of (x, y, z)(hx, hy, hz) groups, found {len(tuples)} groups'
        )
    if boids is not None and len(tuples) != 2 * boids:
        raise UnityFormatError(f'{where}: {len(tuples) // 2} boids, expected {boids}')
    values = np.empty((len(tuples), 3))
    for g, group in enumerate(tuples):
        parts = group.split(',')
        if len(parts) != 3:
            raise UnityFormatError(f'{where}: group {g + 1} holds {len(parts)} numbers, expected 3')
        try:
            values[g] = [float(v) for v in parts]
        except ValueError as exc:
            raise UnityFormatError(f'{where}: group {g + 1}: a number could not be read ({exc})') from None
    if not np.all(np.isfinite(values)):
        raise UnityFormatError(
            f'{where}: non-finite value in group {np.argwhere(~np.isfinite(values))[0][0] + 1}'
        )
    frame = values.reshape(-1, 6)
    norms = np.linalg.norm(frame[:, 3:], axis=1)
    bad = np.flatnonzero(np.abs(norms - 1.0) > UNIT_TOLERANCE)
    if bad.size:
        raise UnityFormatError(f'{where}: heading of boid {bad[0]} has norm {norms[bad[0]]:.6f}, not 1')
    return frame


def read_recording(path, boids: Optional[int] = None, discard: int = 10) -> np.ndarray:
    """One recording as ``[T, n, 6]`` (position, unit heading), first ``discard`` frames dropped.

    Args:
        boids: expected boid count; by default the first line sets it for the file.
    """
    path = Path(path)
    if not path.is_file():
        raise UnityFormatError(f'{path}: no such file')
    frames: List[np.ndarray] = []
    opener = lzma.open if path.suffix == '.xz' else open
    with opener(path, 'rt', encoding='utf-8') as fh:
        for number, line in enumerate(fh, start=1):
            if not line.strip():
                continue
            frame = _parse_line(line, f'{path}:{number}', boids)
            boids = frame.shape[0]
            frames.append(frame)
    if len(frames) <= discard:
        raise UnityFormatError(f'{path}: {len(frames)} frames, need more than the {discard} discarded')
    states = np.stack(frames[discard:])
    # Renormalise away the 7-decimal rounding so headings are unit to float precision.
    states[..., 3:] /= np.linalg.norm(states[..., 3:], axis=-1, keepdims=True)
    return states


def shipped_recordings() -> List[Path]:
    """The shipped recordings ``simulation_data{0..5}_*.txt.xz``, in recording order."""
    paths = sorted(UNITY_DIR.glob('simulation_data*.txt.xz'))
    if not paths:
        raise UnityFormatError(f'{UNITY_DIR}: no simulation_data*.txt.xz recordings')
    return paths
