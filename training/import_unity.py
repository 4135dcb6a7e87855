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
import sys
from pathlib import Path
from typing import List, Optional, Sequence

import numpy as np

from knode_swarm_ros.core import save_trajectories
from knode_swarm_ros.core.cli import cli
from training.data.unity.recordings import UNITY_DIR, UnityFormatError, read_recording, shipped_recordings

__all__ = [
    'read_recording',
    'import_recordings',
    'shipped_recordings',
    'UNITY_DIR',
    'UnityFormatError',
    'main',
]


def import_recordings(
    paths: Sequence, out, dt: float = 1.0 / 60.0, discard: int = 10, separate: bool = False
) -> List[Path]:
    """Import recordings into trajectory file(s); returns the written paths."""
    recordings = [read_recording(p, discard=discard) for p in paths]
    counts = {r.shape[1] for r in recordings}
    if len(counts) > 1:
        raise UnityFormatError(
            f'recordings hold different boid counts {sorted(counts)}; import them separately'
        )
    lengths = [int(r.shape[0]) for r in recordings]
    base = {
        'generator': 'training.import_unity',
        'source': 'Unity boids (LishuoPan/Boids)',
        'discarded_frames': discard,
        'dt_assumed': dt,
    }
    out = Path(out)
    written = []
    if separate:
        for i, (path, rec) in enumerate(zip(paths, recordings)):
            target = out.with_name(f'{out.stem}_{i}{out.suffix or ".npz"}')
            save_trajectories(
                target, rec[None], dt, 'boids3d', dict(base, files=[str(path)], frames=[lengths[i]])
            )
            written.append(target)
    else:
        T = min(lengths)
        states = np.stack([r[:T] for r in recordings])
        save_trajectories(
            out,
            states,
            dt,
            'boids3d',
            dict(base, files=[str(p) for p in paths], frames=lengths, trimmed_to=T),
        )
        written.append(out)
    return written


@cli('python -m training.import_unity')
def main(argv: Optional[Sequence[str]] = None) -> int:
    ap = argparse.ArgumentParser(
        prog='python -m training.import_unity',
        description=__doc__.split('\n\n')[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument('files', nargs='+', help='Unity recordings (simulation_data*.txt or .txt.xz)')
    ap.add_argument('--out', required=True, help='output trajectory file (.npz)')
    ap.add_argument('--dt', type=float, default=1.0 / 60.0, help='frame time in seconds (default 1/60)')
    ap.add_argument('--discard', type=int, default=10, help='leading frames dropped (default 10)')
    ap.add_argument('--separate', action='store_true', help='one output file per recording, untrimmed')
    args = ap.parse_args(argv)
    if not args.dt > 0:
        ap.error(f'--dt must be > 0, got {args.dt}')
    if args.discard < 0:
        ap.error(f'--discard must be >= 0, got {args.discard}')
    written = import_recordings(args.files, args.out, args.dt, args.discard, args.separate)
    for path in written:
        print(f'wrote {path}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
