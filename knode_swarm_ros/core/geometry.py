"""Small geometry used everywhere: distances between robots (numpy only, no ROS).

Shapes: n robots, p position entries, q query points; leading ``...`` dimensions broadcast.
"""

from __future__ import annotations

import numpy as np

__all__ = ['distances', 'pair_distances', 'min_pair_distance']


def distances(query: np.ndarray, others: np.ndarray) -> np.ndarray:
    """Euclidean distances ``[..., q, n]`` between ``query [..., q, p]`` and ``others [..., n, p]``."""
    p = query.shape[-1]
    if not 0 < p < 8:
        diff = query[..., :, None, :] - others[..., None, :, :]
        return np.sqrt(np.sum(diff * diff, axis=-1))
    # Axis by axis, without the [..., q, n, p] temporaries (7x faster at 200 robots in 2D): the
    # same squares added in the same order as numpy's sum over fewer than 8 entries, so the
    # same bits.
    d = query[..., :, None, 0] - others[..., None, :, 0]
    total = d * d
    for axis in range(1, p):
        d = query[..., :, None, axis] - others[..., None, :, axis]
        total += d * d
    return np.sqrt(total)


def pair_distances(x: np.ndarray, exclude_self: bool = True) -> np.ndarray:
    """Distances ``[..., n, n]`` between the rows of ``x [..., n, p]``.

    ``exclude_self``: the diagonal is ``inf`` (a robot is not its own neighbour, so minima over
    a row skip it); otherwise it is 0 (sums over pairs).
    """
    x = np.asarray(x)
    dist = distances(x, x)
    if exclude_self:
        n = x.shape[-2]
        dist[..., np.arange(n), np.arange(n)] = np.inf
    return dist


def min_pair_distance(positions: np.ndarray) -> np.ndarray:
    """Smallest distance between two robots ``[...]`` of ``positions [..., n, p]`` (n >= 2)."""
    return pair_distances(positions).min(axis=(-1, -2))
