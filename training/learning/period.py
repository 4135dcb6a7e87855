"""Training for a control period longer than the data's frame period.

A swarm recorded at 100 Hz (dt 0.01 s) can train a policy for 20 Hz control (dt 0.05 s):
the policy dt is ``ratio`` data frames, the one-step-ahead pairs go from frame t to frame
t + ratio (the zero-order hold of one command over the longer period), neighbour delays in
policy steps become ``tau * ratio`` frames (:func:`training.learning.samples.make_samples` with
``ratio``), and the selection rollouts compare with the data subsampled to every ratio-th
frame (:func:`subsample`).
"""

from __future__ import annotations

from typing import Optional

import numpy as np

__all__ = ['period_ratio', 'policy_dt', 'subsample', 'phases', 'RATIO_TOLERANCE']

#: Relative tolerance for "policy dt is a whole multiple of the data dt" (float seconds).
RATIO_TOLERANCE = 1e-6


def period_ratio(data_dt: float, target_dt: Optional[float], field: str = 'data.policy_dt') -> int:
    """Whole number of data frames per policy step (1 when ``target_dt`` is None).

    Raises:
        ValueError: ``target_dt`` is not a positive whole multiple of ``data_dt``; the message
            names ``field`` and both periods.
    """
    if target_dt is None:
        return 1
    if not (np.isfinite(target_dt) and target_dt > 0 and np.isfinite(data_dt) and data_dt > 0):
        raise ValueError(
            f"{field} = {target_dt!r}: must be a positive multiple of the data's dt ({data_dt:g} s)"
        )
    exact = float(target_dt) / float(data_dt)
    ratio = int(round(exact))
    if ratio < 1 or abs(exact - ratio) > RATIO_TOLERANCE * ratio:
        raise ValueError(
            f"{field} = {target_dt:g} s is not a whole multiple of the data's dt {data_dt:g} s "
            f'(ratio {exact:.6g}); use a multiple such as {max(ratio, 1) * data_dt:g} s'
        )
    return ratio


def policy_dt(data_dt: float, ratio: int) -> float:
    """The policy's dt in seconds, ``data_dt * ratio``; its 12-significant-digit form where that
    is the same number to a few ulps (0.01 x 5 is written 0.05, not 0.05000000000000001), never
    where it is not (1/60 stays 1/60: 3e-14 of dt measurably changed chaotic boids rollouts)."""
    exact = float(data_dt) * int(ratio)
    short = float(f'{exact:.12g}')
    return short if abs(short - exact) <= 4 * np.finfo(float).eps * abs(exact) else exact


def subsample(states: np.ndarray, ratio: int) -> np.ndarray:
    """Every ratio-th frame of trajectories ``[N, T, n, d]`` -> ``[N, ceil(T / ratio), n, d]``
    (frame 0 kept): the data as a robot controlled at the policy's period observes it."""
    return np.asarray(states)[:, :: int(ratio)]


def phases(states: np.ndarray, ratio: int) -> np.ndarray:
    """Every phase of the subsampling as its own trajectory: ``[N, T, n, d]`` ->
    ``[N * ratio, T // ratio, n, d]`` (phase p holds frames p, p + ratio, ...; cut to the
    shortest phase), the trajectories a robot controlled at the policy's period could observe.
    Used by the multi-step objective, whose windows step at the policy's dt."""
    states = np.asarray(states)
    r = int(ratio)
    if r == 1:
        return states
    T = states.shape[1] // r
    return np.concatenate([states[:, p::r][:, :T] for p in range(r)], axis=0)
