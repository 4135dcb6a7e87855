"""Resample Unity recordings onto a uniform 1/60 s time grid, using their estimated frame times.

    python -m training.studies.unity_retime training/unity_boids/simulation_data{0,1,2}_*.txt.xz --out data/unity_s2_retimed.npz

Unity steps its boids with the variable ``Time.deltaTime`` (median exactly 1/60 s, about a
quarter of the frames 1-5 % longer, a few hitches of 2.6/60 s); the recordings hold no time.
:func:`training.data.unity.frames.estimate_frame_times` recovers every frame time from the
spawn on (relative error about 1e-5). Between two frames a Unity boid moves in a straight
line with its new velocity, so positions are linear in time between frames and the heading
of the segment is the later frame's: this module samples that path every 1/60 s from
frame ``--discard`` (default 10) on, so that displacement x 60 is the boid's true velocity
(up to the chord of a step that straddles a frame). The result is a trajectory file
(boids3d, dt 1/60) trimmed to the shortest recording; training reads it like
``training.import_unity``'s output.
"""

from __future__ import annotations

import argparse
import sys
from typing import List, Optional, Sequence

import numpy as np

from knode_swarm_ros.core import save_trajectories
from knode_swarm_ros.core.cli import cli
from knode_swarm_ros.core.groundtruth import boids as gt_boids
from training.data.unity.frames import NOMINAL_DT, PRESET, estimate_frame_times
from training.data.unity.recordings import UnityFormatError, read_recording

__all__ = ['resample_uniform', 'retime_recordings', 'main']


def resample_uniform(
    states: np.ndarray, frame_times: np.ndarray, start: int = 0, step: float = NOMINAL_DT
) -> np.ndarray:
    """Sample a recording ``[T, n, 6]`` with frame times ``[T - 1]`` every ``step`` seconds from frame ``start``.

    Positions are interpolated linearly between frames; the heading at a time strictly inside
    (t_k, t_k+1] is h_k+1 (the heading the boid moves with), at a frame time exactly, that frame's.
    """
    states = np.asarray(states, dtype=np.float64)
    frame_times = np.asarray(frame_times, dtype=np.float64)
    if frame_times.shape != (states.shape[0] - 1,) or np.any(frame_times <= 0):
        raise ValueError(f'need {states.shape[0] - 1} positive frame times, got shape {frame_times.shape}')
    t = np.concatenate([[0.0], np.cumsum(frame_times)])
    span = t[-1] - t[start]
    count = int(np.floor(span / step + 1e-9)) + 1
    tau = t[start] + step * np.arange(count)
    k = np.clip(np.searchsorted(t, tau, side='right') - 1, 0, len(t) - 2)  # t[k] <= tau < t[k + 1]
    w = (tau - t[k]) / frame_times[k]
    exact = np.isclose(w, 0.0, atol=1e-12)
    p = states[k, :, :3] + w[:, None, None] * (states[k + 1, :, :3] - states[k, :, :3])
    h = np.where(exact[:, None, None], states[k, :, 3:], states[k + 1, :, 3:])
    return np.concatenate([p, h], axis=-1)


def retime_recordings(paths: Sequence[str], out: str, discard: int = gt_boids.DISCARD_FRAMES) -> np.ndarray:
    """Estimate frame times (from the spawn) and write uniform-time trajectories; returns them."""
    params = gt_boids.get_preset(PRESET)
    spawn_speed = 0.5 * (params.min_speed + params.max_speed)
    runs: List[np.ndarray] = []
    info = []
    for path in paths:
        full = read_recording(path, discard=0)
        if full.shape[0] < discard + 3:
            raise UnityFormatError(f'{path}: {full.shape[0]} frames, need at least {discard + 3}')
        dt, res = estimate_frame_times(full, params, initial_speed=spawn_speed)
        runs.append(resample_uniform(full, dt, start=discard))
        info.append(
            {
                'file': str(path),
                'frames': int(full.shape[0] - discard),
                'samples': int(runs[-1].shape[0]),
                'duration_s': float(dt[discard:].sum()),
                'max_residual': float(np.nanmax(res[discard:])),
            }
        )
    T = min(r.shape[0] for r in runs)
    states = np.stack([r[:T] for r in runs])
    save_trajectories(
        out,
        states,
        NOMINAL_DT,
        'boids3d',
        {
            'generator': 'training.studies.unity_retime',
            'source': 'Unity boids (LishuoPan/Boids)',
            'discarded_frames': discard,
            'retimed': 'positions linear between frames at the estimated Unity frame times, sampled every 1/60 s',
            'recordings': info,
            'trimmed_to': T,
        },
    )
    return states


@cli('python -m training.studies.unity_retime')
def main(argv: Optional[Sequence[str]] = None) -> int:
    ap = argparse.ArgumentParser(
        prog='python -m training.studies.unity_retime',
        description=__doc__.split('\n\n')[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument(
        'files', nargs='+', help='Unity recordings (simulation_data*.txt), whole (from the spawn)'
    )
    ap.add_argument('--out', required=True, help='output trajectory file (.npz)')
    ap.add_argument(
        '--discard', type=int, default=gt_boids.DISCARD_FRAMES, help='leading frames dropped (default 10)'
    )
    args = ap.parse_args(argv)
    if args.discard < 0:
        ap.error(f'--discard must be >= 0, got {args.discard}')
    states = retime_recordings(args.files, args.out, args.discard)
    print(f'wrote {args.out}: {states.shape[0]} recordings x {states.shape[1]} samples of 1/60 s')
    return 0


if __name__ == '__main__':
    sys.exit(main())
