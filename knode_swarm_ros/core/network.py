"""The decentralised information network (paper, Method A and B; docs/DESIGN.md).

For robot i at step t, with radius ``d_cr``, ``k`` rows (the robot itself included) and a
delay of ``tau`` steps, the neighbour matrix Y_i is ``[k, d]``:

* row 0 is robot i's own state z_i(t), without delay;
* rows 1..k-1 are the delayed states z_j(t - tau) of the robots j != i whose delayed
  position lies within ``d_cr`` (inclusive) of robot i's delayed position, closest first,
  ties broken by the lower id;
* rows without a neighbour are zeros and ``mask`` (1 = real row) says which rows are real;
* before t - tau exists (t < tau) the earliest state is used.

There is one implementation: :func:`neighbour_matrix` works on any leading batch shape
(time steps, trajectories) and :func:`neighbour_matrix_single` feeds one robot through the
same ranking code, so training, rollouts and the agent node agree bit for bit.
"""

from __future__ import annotations

from typing import Tuple

import numpy as np

from .geometry import distances, pair_distances

__all__ = [
    'neighbour_matrix',
    'rank_neighbours',
    'neighbour_matrix_single',
    'neighbour_matrices',
    'neighbour_index',
    'neighbour_matrix_torch',
    'neighbour_matrix_rows',
    'delayed_index',
]


def rank_neighbours(dist: np.ndarray, d_cr: float, k: int) -> Tuple[np.ndarray, np.ndarray]:
    """Pick up to k-1 neighbours per query row from ``dist [..., q, n]``.

    Entries that are not candidates (the robot itself) must already be ``inf``.
    Returns (index ``[..., q, k-1]`` int64, valid ``[..., q, k-1]`` bool); invalid indices are 0.
    """
    dist = np.where(dist <= d_cr, dist, np.inf)
    # A stable sort keeps the lower id first among equal distances.
    order = np.argsort(dist, axis=-1, kind='stable')[..., : k - 1]
    ranked = np.take_along_axis(dist, order, axis=-1)
    valid = np.isfinite(ranked)
    if order.shape[-1] < k - 1:  # fewer robots than rows: pad
        pad = [(0, 0)] * (order.ndim - 1) + [(0, k - 1 - order.shape[-1])]
        order = np.pad(order, pad)
        valid = np.pad(valid, pad)
    return np.where(valid, order, 0), valid


def _assemble(
    z_now: np.ndarray, z_delayed: np.ndarray, index: np.ndarray, valid: np.ndarray
) -> Tuple[np.ndarray, np.ndarray]:
    """Stack own rows ``z_now [..., q, d]`` over gathered delayed rows ``z_delayed[..., index, :]``."""
    d = z_delayed.shape[-1]
    src = np.broadcast_to(z_delayed[..., None, :, :], index.shape[:-1] + z_delayed.shape[-2:])
    rows = np.take_along_axis(src, index[..., None], axis=-2) * valid[..., None]
    Y = np.concatenate([z_now[..., None, :], rows], axis=-2)
    mask = np.concatenate([np.ones(valid.shape[:-1] + (1,), dtype=bool), valid], axis=-1)
    assert Y.shape[-1] == d
    return Y, mask


def neighbour_matrix(
    z_now: np.ndarray, z_delayed: np.ndarray, position_dim: int, d_cr: float, k: int
) -> Tuple[np.ndarray, np.ndarray]:
    """Neighbour matrices of every robot of one or many swarm snapshots.

    Args:
        z_now: ``[..., n, d]`` states at step t (own rows).
        z_delayed: ``[..., n, d]`` states at step t - tau (neighbour rows and distances).
        position_dim: p; ``z[..., :p]`` is the position.
        d_cr: communication radius (inclusive).
        k: rows per matrix, the robot itself included (k >= 1).

    Returns:
        ``Y [..., n, k, d]`` (dtype of the inputs) and ``mask [..., n, k]`` bool.
    """
    z_now = np.asarray(z_now)
    z_delayed = np.asarray(z_delayed)
    if z_now.shape != z_delayed.shape:
        raise ValueError(f'z_now {z_now.shape} and z_delayed {z_delayed.shape} differ in shape')
    index, valid = neighbour_index(z_delayed, position_dim, d_cr, k)
    return _assemble(z_now, z_delayed, index, valid)


def neighbour_index(
    z_delayed: np.ndarray, position_dim: int, d_cr: float, k: int
) -> Tuple[np.ndarray, np.ndarray]:
    """Who is in whose neighbour matrix: the ranking step of :func:`neighbour_matrix` alone.

    Args:
        z_delayed: ``[..., n, d]`` states at step t - tau.

    Returns:
        ``index [..., n, k-1]`` int64 (the robots in rows 1..k-1, closest first; 0 where
        invalid) and ``valid [..., n, k-1]`` bool.
    """
    if k < 1:
        raise ValueError(f'k must be >= 1, got {k}')
    pos = np.asarray(z_delayed)[..., :position_dim]
    dist = pair_distances(pos)  # inf diagonal: a robot is not its own neighbour
    return rank_neighbours(dist, d_cr, k)


def neighbour_matrix_torch(z_now, z_delayed, position_dim: int, d_cr: float, k: int):
    """:func:`neighbour_matrix` for torch tensors ``[..., n, d]``, differentiable in the states.

    The ranking (who is a neighbour, in which row) is piecewise constant in the states, so it
    is computed once by :func:`neighbour_index` on detached values; the rows are gathered from
    the tensors, so gradients flow through every row's content (training through rollouts).

    Returns:
        ``Y [..., n, k, d]`` (dtype of the inputs) and ``mask [..., n, k]`` of the same dtype.
    """
    import torch

    if z_now.shape != z_delayed.shape:
        raise ValueError(f'z_now {tuple(z_now.shape)} and z_delayed {tuple(z_delayed.shape)} differ in shape')
    index, valid = neighbour_index(z_delayed.detach().cpu().numpy(), position_dim, d_cr, k)
    index_t = torch.from_numpy(index).to(z_now.device)
    valid_t = torch.from_numpy(valid).to(device=z_now.device, dtype=z_now.dtype)
    lead, (n, d) = z_delayed.shape[:-2], z_delayed.shape[-2:]
    src = z_delayed.unsqueeze(-3).expand(lead + (n, n, d))  # [..., n, n, d]
    rows = torch.gather(src, -2, index_t.unsqueeze(-1).expand(index.shape + (d,))) * valid_t.unsqueeze(-1)
    Y = torch.cat([z_now.unsqueeze(-2), rows], dim=-2)
    mask = torch.cat(
        [torch.ones(valid_t.shape[:-1] + (1,), dtype=z_now.dtype, device=z_now.device), valid_t], -1
    )
    return Y, mask


def neighbour_matrix_single(
    i: int, z_now_i: np.ndarray, z_delayed: np.ndarray, position_dim: int, d_cr: float, k: int
) -> Tuple[np.ndarray, np.ndarray]:
    """Neighbour matrix of robot ``i`` alone (what an agent node computes).

    Args:
        i: index of the robot within ``z_delayed``.
        z_now_i: ``[d]`` its own state at step t.
        z_delayed: ``[n, d]`` every robot's state at t - tau (row i included: it fixes the
            centre of the radius). Robots not heard from can be left out of the array
            entirely by the caller; indices then refer to the rows passed.

    Returns:
        ``Y [k, d]`` and ``mask [k]`` bool, identical to row i of :func:`neighbour_matrix`.
    """
    Y, mask = neighbour_matrix_rows([i], np.asarray(z_now_i)[None, :], z_delayed, position_dim, d_cr, k)
    return Y[0], mask[0]


def neighbour_matrix_rows(
    rows, z_now: np.ndarray, z_delayed: np.ndarray, position_dim: int, d_cr: float, k: int
) -> Tuple[np.ndarray, np.ndarray]:
    """Neighbour matrices of the robots at ``rows`` of one snapshot (the robots a process hosts).

    Each robot's matrix is computed from its own row of distances alone, so the result is
    identical to those rows of :func:`neighbour_matrix` and to :func:`neighbour_matrix_single`
    one robot at a time, whatever the other rows are.

    Args:
        rows: ``[q]`` indices of the robots within ``z_delayed`` (distinct or not).
        z_now: ``[q, d]`` their own states at step t.
        z_delayed: ``[n, d]`` the states at t - tau of the robots heard (rows ``rows`` included).

    Returns:
        ``Y [q, k, d]`` and ``mask [q, k]`` bool.
    """
    if k < 1:
        raise ValueError(f'k must be >= 1, got {k}')
    rows = np.asarray(rows, dtype=np.int64).reshape(-1)
    z_delayed = np.asarray(z_delayed)
    pos = z_delayed[:, :position_dim]
    dist = distances(pos[rows], pos)
    dist[np.arange(len(rows)), rows] = np.inf  # a robot is not its own neighbour
    index, valid = rank_neighbours(dist, d_cr, k)
    return _assemble(np.asarray(z_now), z_delayed, index, valid)


def delayed_index(T: int, tau: int) -> np.ndarray:
    """Frame index of t - tau for t = 0..T-1, clamped at the earliest frame."""
    if tau < 0:
        raise ValueError(f'tau must be >= 0, got {tau}')
    return np.maximum(np.arange(T) - tau, 0)


def neighbour_matrices(
    states: np.ndarray, position_dim: int, d_cr: float, k: int, tau: int
) -> Tuple[np.ndarray, np.ndarray]:
    """Neighbour matrices for whole trajectories (the paper's S(t - tau) Z(t - tau)).

    Args:
        states: ``[..., T, n, d]`` trajectories.

    Returns:
        ``Y [..., T, n, k, d]`` and ``mask [..., T, n, k]``.
    """
    states = np.asarray(states)
    T = states.shape[-3]
    delayed = np.take(states, delayed_index(T, tau), axis=-3)
    return neighbour_matrix(states, delayed, position_dim, d_cr, k)
