"""The one place where an agent process calls its policy: one batched call for its robots.

A lone ``agent`` calls it for its one robot, a hosting ``agents`` process once per tick for all
the robots it hosts. The policy is anything with the docs/DESIGN.md signature
``(Y [B, k, d], mask [B, k]) -> [B, m]`` (today the TorchScript :class:`LoadedPolicy`); a
runtime swap (ONNX) changes what is passed in, not this function.

Parity rows: float32 matrix products round differently for different batch shapes, so a batch
shaped like the offline rollout's (one row per robot of the swarm, each robot's matrix at its
index) makes the result equal :func:`knode_swarm_ros.core.rollout` bit for bit. The rows of
robots not evaluated here are filled with the first matrix: a row's result does not depend on
the other rows' values, only on the batch's shape (the lone agent's parity rests on the same).
"""

from __future__ import annotations

from typing import Optional, Sequence

import numpy as np

__all__ = ['evaluate_rows']


def evaluate_rows(
    policy, Y: np.ndarray, mask: np.ndarray, rows: Optional[Sequence[int]] = None, batch: Optional[int] = None
) -> np.ndarray:
    """Commands ``[B, m]`` float64 for ``Y [B, k, d]``, ``mask [B, k]`` in one policy call.

    Args:
        rows: with ``batch``: the row of each of the B matrices in a batch of ``batch`` rows
            (distinct, < batch); None: a batch of exactly B.
    """
    Y = np.asarray(Y)
    mask = np.asarray(mask)
    if rows is None or batch is None or batch == len(Y):
        if rows is not None and list(rows) != list(range(len(Y))):
            full_Y, full_mask = np.empty((len(Y),) + Y.shape[1:], Y.dtype), np.empty(mask.shape, mask.dtype)
            full_Y[list(rows)], full_mask[list(rows)] = Y, mask
            return np.asarray(policy(full_Y, full_mask), dtype=np.float64)[list(rows)]
        return np.asarray(policy(Y, mask), dtype=np.float64)
    rows = list(rows)
    full_Y = np.repeat(Y[:1], batch, axis=0)
    full_mask = np.repeat(mask[:1], batch, axis=0)
    full_Y[rows] = Y
    full_mask[rows] = mask
    return np.asarray(policy(full_Y, full_mask), dtype=np.float64)[rows]
