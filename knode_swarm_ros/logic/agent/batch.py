"""From what a robot heard to its command, for one robot or a batch of them (``agents``).

:class:`Request`: a command waiting for its policy output; :func:`build_matrices` fills the
neighbour matrices of many requests with one core call per snapshot of rows;
:func:`evaluate_batch` calls the policy once for all of them and :func:`clean_commands` turns
its outputs into the commands an agent publishes. A lone agent
calls them with one request (:class:`.agent_logic.AgentLogic`), a hosting process with all its
robots' (:class:`.hosted.HostedAgents`): the same code.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from knode_swarm_ros.core.network import neighbour_matrix_rows
from knode_swarm_ros.core.saturation import saturate

from .hearing import Rows
from .policy_call import evaluate_rows

__all__ = ['Request', 'build_matrices', 'clean_commands', 'evaluate_batch']


@dataclass
class Request:
    """A command waiting for its policy output: robot ``robot``'s own state ``own [d]`` of own
    step ``step`` and the delayed states ``rows`` it hears, to be stamped ``stamp_ns``;
    ``Y [k, d]`` and ``mask [k]`` once built (:func:`build_matrices`; see :meth:`AgentLogic.finish`)."""

    step: int
    stamp_ns: int
    robot: int
    own: np.ndarray
    rows: Rows
    Y: Optional[np.ndarray] = None
    mask: Optional[np.ndarray] = None


def build_matrices(requests: Sequence[Request], position_dim: int, d_cr: float, k: int) -> None:
    """Fill ``Y``, ``mask`` of every request with :func:`knode_swarm_ros.core.neighbour_matrix_rows`,
    one call per snapshot of rows (the robots of a process that hear the same rows share it)."""
    groups: Dict[int, List[Request]] = {}
    for r in requests:
        groups.setdefault(id(r.rows), []).append(r)
    for group in groups.values():
        rows = group[0].rows
        Y, mask = neighbour_matrix_rows(
            [rows.index[r.robot] for r in group],
            np.stack([r.own for r in group]),
            rows.Z,
            position_dim,
            d_cr,
            k,
        )
        for r, y, m in zip(group, Y, mask):
            r.Y, r.mask = y, m


def evaluate_batch(
    policy,
    Y: np.ndarray,
    mask: np.ndarray,
    robots: Sequence[int],
    parity_index: Optional[Dict[int, int]] = None,
) -> np.ndarray:
    """The policy's outputs ``[B, m]`` for the matrices ``Y [B, k, d]``, ``mask [B, k]`` of
    ``robots [B]``, in one call.

    ``parity_index`` ``{robot: swarm index}`` of every robot of the swarm: the batch is shaped
    like the offline rollout's, each robot's matrix at its index (parity rows,
    :mod:`.policy_call`); None: a batch of exactly B."""
    if parity_index is None:
        return evaluate_rows(policy, Y, mask)
    return evaluate_rows(policy, Y, mask, [parity_index[rid] for rid in robots], len(parity_index))


def clean_commands(U: np.ndarray, limit: Optional[float]) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The commands ``[B, m]`` an agent publishes for the policy's outputs ``U [B, m]``: a row
    with a non-finite entry becomes zero, then every entry is clipped to ``[-limit, limit]``;
    also which rows were non-finite ``[B]`` and which the clip changed ``[B]``."""
    U = np.asarray(U, dtype=np.float64)
    non_finite = ~np.isfinite(U).all(axis=-1)
    value = np.where(non_finite[:, None], 0.0, U) if non_finite.any() else U
    clipped = saturate(value, limit)
    return clipped, non_finite, (clipped != value).any(axis=-1)
