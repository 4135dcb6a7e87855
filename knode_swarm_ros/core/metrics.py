"""Flocking metrics of the paper: avd(t), amd(t) and POD-KLD.

* avd(t), average velocity difference: the mean over ordered pairs i != j of |v_i - v_j|
  (0 when every robot moves with the same velocity);
* amd(t), average minimum distance: the mean over robots of min_{j != i} |p_i - p_j|;
* POD-KLD: the energy distribution of the first ``modes`` singular values of the
  trajectory's snapshot matrix (one column per time step), and KL(true || predicted).
"""

from __future__ import annotations

import numpy as np

from .geometry import pair_distances

__all__ = ['avd', 'amd', 'pod_energy', 'pod_kld', 'kl_divergence']


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
