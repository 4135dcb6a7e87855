"""Flocking metrics of the paper (avd(t), amd(t), POD-KLD) and order parameters for any swarm.

* avd(t), average velocity difference: the mean over ordered pairs i != j of |v_i - v_j|
  (0 when every robot moves with the same velocity);
* amd(t), average minimum distance: the mean over robots of min_{j != i} |p_i - p_j|;
* POD-KLD: the energy distribution of the first ``modes`` singular values of the
  trajectory's snapshot matrix (one column per time step), and KL(true || predicted).

Order parameters that mean something for every swarm (docs/scenarios.md), on positions and
velocities ``[..., n, dim]`` (dim 2 or 3): nearest-neighbour distance, polarisation, rotation
order (milling), speed quantiles, number of groups, escapes from the arena, closest approach.
A robot with zero speed (or at the centroid) has no direction: it adds a zero vector to the means
of unit vectors, so a resting swarm has polarisation and rotation order 0.
"""

from __future__ import annotations

import numpy as np

from .geometry import pair_distances

__all__ = [
    'avd',
    'amd',
    'pod_energy',
    'pod_kld',
    'kl_divergence',
    'velocities',
    'nearest_neighbour_distance',
    'polarisation',
    'rotation_order',
    'speeds',
    'speed_quantiles',
    'group_labels',
    'group_count',
    'outside_arena',
    'escaped',
    'closest_approach',
]


def avd(velocities: np.ndarray) -> np.ndarray:
    """Average velocity difference of ``velocities [..., n, m]`` -> ``[...]`` (n >= 2)."""
    n = velocities.shape[-2]
    if n < 2:
        raise ValueError('avd needs at least 2 robots')
    return pair_distances(velocities, exclude_self=False).sum(axis=(-1, -2)) / (n * (n - 1))


def amd(positions: np.ndarray) -> np.ndarray:
    """Average minimum distance of ``positions [..., n, p]`` -> ``[...]`` (n >= 2)."""
    n = positions.shape[-2]
    if n < 2:
        raise ValueError('amd needs at least 2 robots')
    return pair_distances(positions).min(axis=-1).mean(axis=-1)


def pod_energy(
    states: np.ndarray, modes: int = 10, center: bool = False, squared: bool = False
) -> np.ndarray:
    """Energy distribution of the first ``modes`` POD modes of one trajectory.

    Args:
        states: ``[T, n, d]``; the snapshot matrix is ``[n * d, T]`` (one column per step).
        center: subtract the temporal mean of each row first.
        squared: use S^2 (variance) instead of S (the paper's choice, the default).

    Returns:
        ``[modes]`` non-negative, summing to 1 (missing modes count as zero energy).
    """
    X = np.asarray(states, dtype=np.float64).reshape(states.shape[0], -1).T
    if center:
        X = X - X.mean(axis=1, keepdims=True)
    s = np.linalg.svd(X, compute_uv=False)
    e = s * s if squared else s
    e = np.concatenate([e, np.zeros(max(0, modes - e.size))])[:modes]
    total = e.sum()
    if total <= 0:
        raise ValueError('POD energy is zero: the snapshot matrix is all zeros')
    return e / total


def pod_kld(
    true_states: np.ndarray,
    predicted_states: np.ndarray,
    modes: int = 10,
    center: bool = False,
    squared: bool = False,
    eps: float = 1e-12,
) -> float:
    """KL(true || predicted) between the POD energy distributions of two trajectories ``[T, n, d]``.

    ``eps`` keeps the divergence finite where the prediction has no energy in a mode.
    """
    return kl_divergence(
        pod_energy(true_states, modes, center, squared),
        pod_energy(predicted_states, modes, center, squared),
        eps,
    )


def kl_divergence(p: np.ndarray, q: np.ndarray, eps: float = 1e-12) -> float:
    """KL(p || q) of two distributions ``[m]`` over the support of p; ``q`` is floored at ``eps``."""
    support = p > 0
    return float(np.sum(p[support] * np.log(p[support] / np.maximum(q[support], eps))))


def _unit(x: np.ndarray) -> np.ndarray:
    """``x / |x|`` over the last axis; zero where ``|x| = 0``."""
    norm = np.linalg.norm(x, axis=-1, keepdims=True)
    return np.divide(x, norm, out=np.zeros_like(x, dtype=np.float64), where=norm > 0)


def velocities(states: np.ndarray, spec, dt: float) -> np.ndarray:
    """Velocities ``[..., T, n, dim]`` of trajectories ``states [..., T, n, d]`` of scenario ``spec``:
    the state's velocity where it has one, else backward differences of the positions (frame 0
    takes frame 1's; T >= 2). A heading is no velocity: its speed is not in the state."""
    states = np.asarray(states, dtype=np.float64)
    if spec.velocity is not None:
        return states[..., spec.velocity]
    if states.shape[-3] < 2:
        raise ValueError('velocities from positions need at least 2 frames')
    p = states[..., spec.position]
    v = np.empty_like(p)
    v[..., 1:, :, :] = np.diff(p, axis=-3) / dt
    v[..., 0, :, :] = v[..., 1, :, :]
    return v


def nearest_neighbour_distance(positions: np.ndarray) -> np.ndarray:
    """Distance of every robot to its nearest neighbour: ``positions [..., n, dim]`` -> ``[..., n]``
    (n >= 2; :func:`amd` is its mean over robots)."""
    if positions.shape[-2] < 2:
        raise ValueError('nearest-neighbour distances need at least 2 robots')
    return pair_distances(positions).min(axis=-1)


def polarisation(velocities: np.ndarray) -> np.ndarray:
    """|mean of the unit velocities| ``[...]`` of ``velocities [..., n, dim]``: 1 when all robots
    move the same way, near 0 for a mill or a gas (about 1 / sqrt(n) for random directions)."""
    return np.linalg.norm(_unit(np.asarray(velocities, dtype=np.float64)).mean(axis=-2), axis=-1)


def rotation_order(positions: np.ndarray, velocities: np.ndarray) -> np.ndarray:
    """Milling order ``[...]``: |mean over robots of (r_i x v_i) / (|r_i| |v_i|)| with r_i the offset
    from the centroid; in 3D the norm of the mean of these unit-scaled angular momenta.

    ``positions`` and ``velocities`` are ``[..., n, dim]``; 1 for a perfect mill around the
    centroid, near 0 for a flock or a gas.
    """
    positions = np.asarray(positions, dtype=np.float64)
    r = _unit(positions - positions.mean(axis=-2, keepdims=True))
    v = _unit(np.asarray(velocities, dtype=np.float64))
    if positions.shape[-1] == 2:
        return np.abs((r[..., 0] * v[..., 1] - r[..., 1] * v[..., 0]).mean(axis=-1))
    return np.linalg.norm(np.cross(r, v).mean(axis=-2), axis=-1)


def speeds(velocities: np.ndarray) -> np.ndarray:
    """|v_i| ``[..., n]`` of ``velocities [..., n, dim]``."""
    return np.linalg.norm(velocities, axis=-1)


def speed_quantiles(velocities: np.ndarray, quantiles=(0.05, 0.25, 0.5, 0.75, 0.95)) -> np.ndarray:
    """Quantiles of the robots' speeds ``[..., Q]`` of ``velocities [..., n, dim]`` (per snapshot;
    reshape ``[..., T * n, dim]`` for a whole trajectory's distribution)."""
    return np.moveaxis(np.quantile(speeds(velocities), quantiles, axis=-1), 0, -1)


def group_labels(positions: np.ndarray, distance: float) -> np.ndarray:
    """Connected components of the graph linking robots within ``distance`` (inclusive):
    ``positions [..., n, dim]`` -> ``[..., n]`` int64, each robot labelled with the lowest index
    in its group."""
    positions = np.asarray(positions, dtype=np.float64)
    n = positions.shape[-2]
    linked = pair_distances(positions, exclude_self=False) <= distance  # [..., n, n], self included
    labels = np.broadcast_to(np.arange(n), positions.shape[:-1]).copy()
    for _ in range(n):  # the minimum spreads one link per pass; a path has at most n - 1 links
        new = np.where(linked, labels[..., None, :], n).min(axis=-1)
        if np.array_equal(new, labels):
            break
        labels = new
    return labels


def group_count(positions: np.ndarray, distance: float) -> np.ndarray:
    """Number of groups ``[...]`` (:func:`group_labels`) of ``positions [..., n, dim]``."""
    labels = group_labels(positions, distance)
    return (labels == np.arange(labels.shape[-1])).sum(axis=-1)


def outside_arena(positions: np.ndarray, half_width: float, tol: float = 1e-9) -> np.ndarray:
    """Whether each robot is outside ``[-w, w]^dim``: ``positions [..., n, dim]`` -> ``[..., n]``."""
    return np.any(np.abs(positions) > half_width + tol, axis=-1)


def escaped(positions: np.ndarray, half_width: float, tol: float = 1e-9) -> np.ndarray:
    """Whether each robot escapes the arena: ``positions [..., T, n, dim]`` -> ``[..., n]``, True when
    it is outside at some frame after having been inside (a robot that starts outside and never
    gets in has not escaped)."""
    out = outside_arena(positions, half_width, tol)  # [..., T, n]
    was_inside = np.logical_or.accumulate(~out, axis=-2)
    return np.any(out[..., 1:, :] & was_inside[..., :-1, :], axis=-2)


def closest_approach(positions: np.ndarray) -> np.ndarray:
    """Smallest distance between two robots over a trajectory: ``positions [..., T, n, dim]`` ->
    ``[...]`` (n >= 2)."""
    return nearest_neighbour_distance(positions).min(axis=(-1, -2))
