"""What the tracks lack, derived on the grid: velocities (``position_velocity``, as flock2d) and unit
headings (``position_heading``, as boids3d), from the smoother (:mod:`training.data.smoother`, the
default: positions and velocities estimated together at the samples' stamps), finite differences of
the positions, the given velocities (a bag's Odometry twist, a file's ``vx, vy``) or the given
headings (a bag's pose orientation, a file's ``hx, hy``) (docs/import_bag.md)."""

from __future__ import annotations

from typing import List, Optional, Tuple

import numpy as np

from knode_swarm_ros.core import get_scenario
from knode_swarm_ros.core.estimator import VelocityEstimator

from .smoother import estimate_noise, smooth_tracks
from .tracks import ResampleOptions, Track, TrackError

__all__ = [
    'finite_difference',
    'moving_average',
    'causal_velocities',
    'derive_states',
    'uses_smoother',
    'smooth_episode',
    'noise_lines',
    'SMOOTHER',
    'smoother_derivation',
]

#: How the smoother derives, in the trajectory file's ``meta.derivation``.
SMOOTHER = (
    "Rauch-Tung-Striebel smoother, constant-acceleration model, at the samples' stamps; noise level "
    'estimated from the data (meta.noise), process noise by maximum likelihood'
)


def smoother_derivation(opts: ResampleOptions) -> str:
    """How the smoother derives the state's velocity or heading, for ``meta.derivation``."""
    if get_scenario(opts.scenario).velocity is not None:
        return SMOOTHER
    return f'direction of {opts.heading_diff} differences of the smoothed positions on the grid ({SMOOTHER})'


def finite_difference(p: np.ndarray, dt: float, scheme: str) -> np.ndarray:
    """Velocities ``[L, ...]`` from positions ``p[L, ...]`` sampled every ``dt`` (L >= 3).

    ``central``: (p[k+1] - p[k-1]) / (2 dt) inside, second-order one-sided at both ends
    (``numpy.gradient(edge_order=2)``). ``backward``: (p[k] - p[k-1]) / dt, frame 0 takes frame 1's.
    """
    if scheme == 'central':
        return np.gradient(p, dt, axis=0, edge_order=2)
    if scheme == 'backward':
        v = np.empty_like(p)
        v[1:] = (p[1:] - p[:-1]) / dt
        v[0] = v[1]
        return v
    raise ValueError(f'unknown difference scheme {scheme!r}')


def causal_velocities(p: np.ndarray, dt: float, window: int) -> np.ndarray:
    """Velocities ``[L, ...]`` of positions ``p [L, ...]`` on a grid of ``dt`` by the agents' causal
    estimator (:class:`knode_swarm_ros.core.estimator.VelocityEstimator`, stamps as the nodes stamp
    step k): what a robot hearing these poses estimates, lag and noise included (frame 0: at rest)."""
    est = VelocityEstimator(window)
    return np.stack([est.update(int(round(k * float(dt) * 1e9)), p[k]) for k in range(p.shape[0])])


def moving_average(x: np.ndarray, window: int) -> np.ndarray:
    """Centred moving average over axis 0 with an odd ``window``; near the ends the window
    shrinks symmetrically (so the average stays centred: no lag, ends less smoothed)."""
    L = x.shape[0]
    half = window // 2
    c = np.concatenate([np.zeros((1,) + x.shape[1:]), np.cumsum(x, axis=0)], axis=0)
    k = np.arange(L)
    h = np.minimum(np.minimum(k, L - 1 - k), half)
    lo, hi = k - h, k + h + 1
    shape = (L,) + (1,) * (x.ndim - 1)
    return (c[hi] - c[lo]) / (hi - lo).reshape(shape)


def _smooth(v: np.ndarray, opts: ResampleOptions, notes: List[str], label: str) -> np.ndarray:
    if opts.smooth == 'none':
        return v
    L = v.shape[0]
    window = min(opts.smooth_window, L if L % 2 else L - 1)
    if window != opts.smooth_window:
        notes.append(f'{label}: {L} frames, smoothing window shrunk to {window}')
    if opts.smooth == 'moving-average':
        return moving_average(v, window)
    try:
        from scipy.signal import savgol_filter
    except ImportError:
        raise TrackError(
            '--smooth savgol needs scipy (pip install scipy), or use --smooth moving-average'
        ) from None
    if window <= opts.smooth_order:
        notes.append(f'{label}: too short for a Savitzky-Golay window; not smoothed')
        return v
    return savgol_filter(v, window, opts.smooth_order, axis=0, mode='interp')


def uses_smoother(opts: ResampleOptions) -> bool:
    """Whether the states come from the smoother: ``--smooth rts`` when something is derived from
    the positions (not with given velocities or headings, not for a position-only state, not when
    the agents' causal estimator is asked for)."""
    spec = get_scenario(opts.scenario)
    given = opts.use_twist or opts.use_orientation or opts.velocity_estimator
    return opts.smooth == 'rts' and spec.state != 'position' and not given


def smooth_episode(robots: List[Track], opts: ResampleOptions, medians: dict) -> Optional[dict]:
    """Smooth every robot of one episode (``robot.smoothed``, after
    :func:`training.data.timeline.timeline` has set ``robot.t`` and ``medians``, the median sample
    interval of each robot id); the noise record for the meta
    (:func:`training.data.smoother.smooth_tracks`, ``noise_std`` in m), or None without the smoother."""
    if not uses_smoother(opts):
        return None
    # the noise estimate's windows of four samples: one dropped sample is fine, a gap is not
    max_span = 4.5 * max(medians.values())
    p = get_scenario(opts.scenario).position_dim
    fits, record = smooth_tracks([(r.t, r.pos[:, :p]) for r in robots], max_span)
    for r, fit in zip(robots, fits):
        r.smoothed = fit
    record['per_robot_noise_std'] = {
        str(r.id): estimate_noise([(r.t, r.pos[:, :p])], max_span)[0] for r in robots
    }
    return record


def noise_lines(record: Optional[dict]) -> List[str]:
    """The importer's log lines about the noise the smoother estimated (none without it)."""
    if record is None:
        return []
    per = ', '.join(f'{k}: {v * 1e3:.3g}' for k, v in record['per_robot_noise_std'].items())
    return [
        f'noise: position noise estimated at {record["noise_std"] * 1e3:.3g} mm (std, from '
        f'{record["residuals"]} residuals; per robot id, mm: {per}); process ratio '
        f'{record["process_ratio"]:.3g}'
    ]


def derive_states(
    seg_t: np.ndarray, robots: List[Track], opts: ResampleOptions, dt: float, notes: List[str], label: str
) -> Tuple[Optional[np.ndarray], Optional[str]]:
    """States ``[L, n, d]`` on the grid times ``seg_t``, or (None, reason) when undefined."""
    spec = get_scenario(opts.scenario)
    p = spec.position_dim
    L, n = seg_t.size, len(robots)

    def interp(values) -> np.ndarray:
        """``[L, n, p]``: each robot's ``values(robot)[m, >= p]`` linearly interpolated at ``seg_t``."""
        out = np.empty((L, n, p))
        for i, r in enumerate(robots):
            v = values(r)
            for c in range(p):
                out[:, i, c] = np.interp(seg_t, r.t, v[:, c])
        return out

    if robots and robots[0].smoothed is not None:
        pos, vel = np.empty((L, n, p)), np.empty((L, n, p))
        for i, r in enumerate(robots):
            pos[:, i], vel[:, i] = r.smoothed.at(seg_t)
        if spec.velocity is not None:
            return np.concatenate([pos, vel], axis=2), None
        # a heading is the direction of the last command (p += u dt), so the positions' own step:
        # the smoothed velocity at a turn already leans towards the next command
        vel = finite_difference(pos, dt, opts.heading_diff)
    else:
        pos, vel = interp(lambda r: r.pos), None
    if spec.state == 'position':  # nothing to derive
        return pos, None
    if spec.velocity is not None:
        if opts.use_twist:
            vel = interp(lambda r: r.given_velocity(opts.twist_frame))
        elif opts.velocity_estimator:
            vel = causal_velocities(pos, dt, opts.velocity_estimator)
        else:
            vel = _smooth(finite_difference(pos, dt, 'central'), opts, notes, label)
        return np.concatenate([pos, vel], axis=2), None

    if opts.use_orientation:  # given headings, renormalised
        head = np.empty((L, n, p))
        for i, r in enumerate(robots):
            h_raw = r.given_heading()[:, :p]
            for c in range(p):
                head[:, i, c] = np.interp(seg_t, r.t, h_raw[:, c])
            norm = np.linalg.norm(head[:, i], axis=1)
            bad = norm < 1e-6  # antipodal headings on both sides: take the nearer sample
            if np.any(bad):
                idx = np.clip(np.searchsorted(r.t, seg_t[bad]), 1, r.t.size - 1)
                nearer = np.where(
                    np.abs(r.t[idx - 1] - seg_t[bad]) <= np.abs(r.t[idx] - seg_t[bad]), idx - 1, idx
                )
                head[bad, i] = h_raw[nearer]
                norm[bad] = np.linalg.norm(h_raw[nearer], axis=1)
            if np.any(norm < 1e-12):
                k = int(np.argmax(norm < 1e-12))
                return None, f'{r.label} has a zero heading at t = {seg_t[k]:.3f} s'
            head[:, i] /= norm[:, None]
        return np.concatenate([pos, head], axis=2), None
    if vel is None:
        vel = (
            interp(lambda r: r.given_velocity(opts.twist_frame))
            if opts.use_twist
            else _smooth(finite_difference(pos, dt, opts.heading_diff), opts, notes, label)
        )
    speed = np.linalg.norm(vel, axis=2)
    head = np.empty_like(vel)
    for i, r in enumerate(robots):
        valid = speed[:, i] > opts.min_speed
        if not np.any(valid):
            return None, (
                f'{r.label} never moves faster than --min-speed {opts.min_speed} m/s, so its heading '
                f'is undefined (give headings: --use-orientation for a bag, hx, hy columns in a track file)'
            )
        idx = np.nonzero(valid)[0]
        nearest = idx[np.clip(np.searchsorted(idx, np.arange(L)), 0, idx.size - 1)]
        prev = idx[np.clip(np.searchsorted(idx, np.arange(L)) - 1, 0, idx.size - 1)]
        nearest = np.where(np.abs(prev - np.arange(L)) <= np.abs(nearest - np.arange(L)), prev, nearest)
        nearest = np.where(valid, np.arange(L), nearest)
        head[:, i] = vel[nearest, i] / speed[nearest, i][:, None]
        if not np.all(valid):
            notes.append(
                f'{label}: {r.label}: {int((~valid).sum())} frame(s) slower than --min-speed take the '
                f'nearest valid heading'
            )
    return np.concatenate([pos, head], axis=2), None
