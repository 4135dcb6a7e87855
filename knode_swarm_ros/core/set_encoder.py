"""The permutation-invariant network part of a policy (``policy.encoder: set``).

``u_theta(Y, mask) = W_sum sum_j h_j + rho(own, mean_j h_j)``, with one shared per-neighbour
network ``h_j = g(y_j - y_0) - g(0)``, ``g(r) = tanh(W [own velocity or heading, r, |r_p|] + b)``,
over the neighbours the mask keeps (a neighbour in the robot's own state adds nothing).
The own position (kept only where walls make it matter) enters
``rho`` alone: what depends on where the robot is must not grow with its neighbour count.

* The sum channel is a sum of learnt pairwise interactions: it grows with the number of
  neighbours as a physical force does, so a policy learnt on a small swarm sees a denser one
  push and pull harder (the flat MLP sees at most its k rows and knows no count it never saw).
* The mean channel (through ``rho``, one tanh layer) is what does not grow with the count:
  alignment, the neighbours' centroid.

No weight depends on k: the rows are summed, so shuffling neighbour rows or adding masked rows
leaves the command unchanged, and a policy learnt with a small k runs with a larger one.
Inputs arrive already divided by the policy's input scales.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

__all__ = ['NeighbourSetEncoder']


class NeighbourSetEncoder(nn.Module):
    """``forward(Y [B, k, d], mask [B, k]) -> [B, m]`` (the network part, before knowledge)."""

    def __init__(
        self,
        state_dim: int,
        position_dim: int,
        command_dim: int,
        hidden: int,
        keep_own_position: bool,
        reach: float = 0.0,
    ):
        """``reach`` (the communication radius in position scales) is not used: the set encoder
        sees the offsets themselves."""
        super().__init__()
        self.position_dim = position_dim
        self.keep_own_position = keep_own_position
        self.moving = state_dim > position_dim
        self.phi = nn.Linear(2 * state_dim - position_dim + 1, hidden)
        self.rho = nn.Sequential(
            nn.Linear(state_dim + hidden, hidden), nn.Tanh(), nn.Linear(hidden, command_dim)
        )
        self.sum_out = nn.Linear(hidden, command_dim, bias=False)

    def forward(self, Y: Tensor, mask: Tensor) -> Tensor:
        own = Y[:, 0, :]
        if not self.keep_own_position:
            own = torch.cat(
                [torch.zeros_like(own[:, : self.position_dim]), own[:, self.position_dim :]], dim=1
            )
        rel = Y[:, 1:, :] - Y[:, :1, :]  # [B, k - 1, d]
        # a smooth distance: sqrt has an infinite slope at 0 (coincident robots)
        dist = torch.sqrt((rel[:, :, : self.position_dim] ** 2).sum(-1, keepdim=True) + 1e-12)
        x = torch.cat([rel, dist], dim=-1)
        if self.moving:  # the own velocity or heading (a position-only state has none)
            x = torch.cat([own[:, self.position_dim :].unsqueeze(1).expand(-1, rel.shape[1], -1), x], dim=-1)
        m = mask[:, 1:].to(Y.dtype).unsqueeze(-1)
        # a neighbour with the robot's own state contributes nothing: otherwise a constant per
        # neighbour, balanced by rho's bias at the training swarm's count, drifts a denser swarm
        same = torch.zeros_like(x[:, :1, :])
        if self.moving:
            same = torch.cat(
                [x[:, :1, : x.shape[2] - rel.shape[2] - 1], same[:, :, : rel.shape[2] + 1]], dim=-1
            )
        h = (torch.tanh(self.phi(x)) - torch.tanh(self.phi(same))) * m  # masked rows: exact zeros
        total = h.sum(1)
        mean = total / torch.clamp(m.sum(1), min=1.0)
        return self.sum_out(total) + self.rho(torch.cat([own, mean], dim=1))
