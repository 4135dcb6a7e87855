"""Unity's frame times, recovered from a recording, and our boids stepped with them.

The recordings hold no frame time and no speed. :func:`estimate_frame_times` recovers both:
Unity moves a boid by p(t+1) = p(t) + v(t+1) dt(t), so p(t+1) - p(t) is parallel to the
recorded heading h(t+1) and its length is |v(t+1)| dt(t); the one unknown per frame, dt(t),
is fitted so that our boids update maps frame t to frame t + 1 for all boids at once
(:func:`model_check` reports the residual). :func:`simulate_with_frame_times` replays them.
Shapes: T frames, n boids, rows (x, y, z, hx, hy, hz).
"""

from __future__ import annotations

import dataclasses
from typing import Any, Dict, Optional, Sequence, Tuple

import numpy as np

from knode_swarm_ros.core.geometry import pair_distances
from knode_swarm_ros.core.groundtruth import boids as gt_boids

__all__ = [
    'estimate_frame_times',
    'decision_margins',
    'model_check',
    'simulate_with_frame_times',
    'NOMINAL_DT',
    'MISMATCH',
    'TIE_MARGIN',
    'PRESET',
]

NOMINAL_DT = 1.0 / 60.0
#: A one-step residual above this (relative to the frame's displacement) counts as a mismatch.
MISMATCH = 1e-3
#: A decision (sweep or radius test) this close to its threshold is a tie that float32 may flip.
TIE_MARGIN = 1e-4
PRESET = 'published'


# --------------------------------------------------------------------------- frame times


def _predicted_displacement(v: np.ndarray, a: np.ndarray, dt: np.ndarray, params) -> np.ndarray:
    """(v + a dt) speed-clamped, times dt; ``dt`` broadcasts against ``v [..., n, 3]``."""
    vn = v + a * dt
    s = np.linalg.norm(vn, axis=-1, keepdims=True)
    ok = s > 0
    vn = np.where(ok, vn / np.where(ok, s, 1.0), 0.0) * np.clip(s, params.min_speed, params.max_speed)
    return vn * dt


def estimate_frame_times(
    states: np.ndarray, params=None, initial_speed: Optional[float] = None, grid: int = 41, levels: int = 6
) -> Tuple[np.ndarray, np.ndarray]:
    """Unity's frame times of one recording ``[T, n, 6]`` and the one-step model residuals.

    Frame t is stepped with our boids update for a candidate dt(t) from velocities
    v(t) = h(t) |p(t) - p(t-1)| / dt(t-1); dt(t) is the candidate (nested grids between the
    bounds that keep every speed within [min_speed, max_speed]) that best reproduces the
    displacements to frame t + 1. Frame 0 has no predecessor: with ``initial_speed`` (a
    recording that starts at the spawn, where Unity sets every speed to (min + max) / 2),
    v(0) = h(0) initial_speed and dt(0) is fitted like the others; otherwise dt(0) takes its
    upper bound (exact when a boid sits at the minimum speed) and later frames correct it.

    Returns:
        ``dt [T - 1]`` (seconds, dt[t] moves frame t to t + 1) and ``residual [T - 1, n]``:
        |predicted - recorded displacement| / |recorded displacement| of frame t + 1 predicted
        from frame t (row 0 is NaN without ``initial_speed``).
    """
    params = gt_boids.get_preset(PRESET) if params is None else params
    p, h = states[..., :3], states[..., 3:]
    d = np.diff(p, axis=0)
    dist = np.linalg.norm(d, axis=-1)
    if np.any(dist <= 0):
        raise ValueError('a boid did not move between two frames; frame times cannot be estimated')
    lo_all = dist.max(axis=1) / params.max_speed
    hi_all = np.maximum(dist.min(axis=1) / params.min_speed, lo_all)
    T1 = d.shape[0]
    dt = np.empty(T1)
    residual = np.full((T1, p.shape[1]), np.nan)
    u = np.linspace(0.0, 1.0, grid)
    for t in range(T1):
        if t == 0:
            if initial_speed is None:
                dt[0] = hi_all[0]
                continue
            v = h[0] * float(initial_speed)
        else:
            v = h[t] * (dist[t - 1] / dt[t - 1])[:, None]
        a = gt_boids.boids_acceleration(p[t], v, params)
        lo, hi = lo_all[t], hi_all[t]
        L, H = lo, hi
        best = hi
        for _ in range(levels):
            cand = L + (H - L) * u
            err = np.linalg.norm(
                _predicted_displacement(v, a, cand[:, None, None], params) - d[t], axis=-1
            ).sum(1)
            k = int(np.argmin(err))
            best, step = cand[k], (H - L) / (grid - 1)
            L, H = max(best - step, lo), min(best + step, hi)
        dt[t] = best
        residual[t] = np.linalg.norm(_predicted_displacement(v, a, best, params) - d[t], axis=-1) / dist[t]
    return dt, residual


def decision_margins(frame: np.ndarray, params=None) -> np.ndarray:
    """Per boid of one frame ``[n, 6]``: the smallest distance of any discrete decision of
    the boids update to its threshold (|distance - perception radius|, |distance - avoidance
    radius|, the heading's sweep test, and the sweep tests of the golden-spiral candidates up to
    the first clear one). Below :data:`TIE_MARGIN`, float32 (Unity) and float64 (ours) may
    decide differently."""
    params = gt_boids.get_preset(PRESET) if params is None else params
    p, h = frame[:, :3], frame[:, 3:]
    dist = pair_distances(p)
    margin = np.minimum(
        np.abs(dist - params.perception_radius).min(1), np.abs(dist - params.avoidance_radius).min(1)
    )
    lo, hi = gt_boids._sweep_limits(p, params)
    heading = np.minimum(hi - h, h - lo).min(-1)
    margin = np.minimum(margin, np.abs(heading))
    spiral = gt_boids.golden_spiral_directions(params.num_directions)
    for i in np.flatnonzero(heading <= 0):
        world = spiral @ gt_boids.look_rotation(h[i])
        m = np.minimum(hi[i] - world, world - lo[i]).min(-1)
        first = int(np.argmax(m > 0)) if np.any(m > 0) else len(m) - 1
        margin[i] = min(margin[i], np.abs(m[: first + 1]).min())
    return margin


def model_check(full: np.ndarray, discard: int = 10, params=None) -> Dict[str, Any]:
    """Frame times and one-step residuals of one whole recording ``[T, n, 6]`` (nothing discarded,
    frame 0 = the spawn), reported from frame ``discard`` on, with the mismatches explained by
    decision ties."""
    params = gt_boids.get_preset(PRESET) if params is None else params
    dt, res = estimate_frame_times(full, params, initial_speed=0.5 * (params.min_speed + params.max_speed))
    kept = res[discard:]  # residual row t predicts frame t + 1 from frame t
    bad = np.argwhere(kept > MISMATCH)
    ties = sum(1 for t, i in bad if decision_margins(full[t + discard], params)[i] < TIE_MARGIN)
    dk = dt[discard:]
    return {
        'frame_time_x60_percentiles': dict(
            zip(
                ['min', 'p05', 'p25', 'p50', 'p75', 'p95', 'max'],
                np.percentile(dk * 60, [0, 5, 25, 50, 75, 95, 100]).round(4).tolist(),
            )
        ),
        'frames_longer_than_1.01/60': float(np.mean(dk * 60 > 1.01)),
        'duration_s': float(dk.sum()),
        'preroll_s': float(dt[:discard].sum()),
        'preroll_frame_times_x60': (dt[:discard] * 60).round(3).tolist(),
        'residual_percentiles': dict(
            zip(['p50', 'p99', 'p99.9', 'max'], np.percentile(kept, [50, 99, 99.9, 100]).tolist())
        ),
        'boid_frames': int(kept.size),
        'mismatches': int(len(bad)),
        'mismatches_at_ties': int(ties),
        '_dt': dk,
        '_preroll': dt[:discard],
        '_residual': kept,
    }


# --------------------------------------------------------------------------- simulation


def simulate_with_frame_times(
    runs: int,
    n: int,
    frames: int,
    seed: int,
    frame_times: Sequence[np.ndarray],
    params=None,
    preroll: Optional[Sequence[np.ndarray]] = None,
) -> np.ndarray:
    """Our boids with the same spawns as :func:`simulate` (same seed) but stepped with given frame
    times: run j replays ``frame_times[j % R]`` (dt of recorded frame 0, 1, ...; at least
    ``frames - 1`` values) after the 10 discarded frames, which are stepped with ``preroll[j % R]``
    (10 values; default 1/60 each).

    Returns ``[runs, frames, n, 6]``.
    """
    params = gt_boids.get_preset(PRESET) if params is None else params
    R = len(frame_times)
    for k, seq in enumerate(frame_times):
        if len(seq) < frames - 1:
            raise ValueError(f'frame_times[{k}] holds {len(seq)} values, need {frames - 1}')
    if preroll is None:
        preroll = [np.full(gt_boids.DISCARD_FRAMES, NOMINAL_DT)] * R
    if len(preroll) != R or any(len(x) != gt_boids.DISCARD_FRAMES for x in preroll):
        raise ValueError(f'preroll needs {R} sequences of {gt_boids.DISCARD_FRAMES} frame times')
    rng = np.random.default_rng(seed)
    pos, vel = gt_boids.initial_boids(rng, runs, n, params)
    out = np.empty((runs, frames, n, 6))
    for g in range(R):
        idx = np.arange(g, runs, R)
        if idx.size == 0:
            continue
        p, v = pos[idx], vel[idx]
        for dt in preroll[g]:
            p, v = gt_boids.boids_step(p, v, dataclasses.replace(params, dt=float(dt)))
        out[idx, 0] = gt_boids.observe(p, v)
        for t in range(1, frames):
            p, v = gt_boids.boids_step(p, v, dataclasses.replace(params, dt=float(frame_times[g][t - 1])))
            out[idx, t] = gt_boids.observe(p, v)
    return out
