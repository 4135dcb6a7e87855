"""The rotation-equivariant network part of a policy (``policy.encoder: equivariant``).

Swarm laws are mostly sums of pairwise terms along the directions that two robots define:
a central force ``f(d) r_hat``, an alignment ``g(d) dv``, a turn to the left. A network on raw
offsets must build a product such as ``f(d) r_hat`` out of tanh units of linear features,
which it does poorly where ``f`` changes fast or is not zero at contact (a repulsion that
grows as robots close in). Here the network computes only rotation-invariant coefficients,
and the command is built from vectors the robots define, as in E(n)-equivariant graph
networks:

``u_i = sum_j sum_c a_c(s_ij) e_c,ij + mean_j sum_c a'_c(s_ij) e_c,ij + sum_c b_c(s_i) e_c,i``

* pair vectors ``e_c,ij``: the direction to the neighbour ``r_hat``, the velocity difference
  ``dv``, the own velocity ``v`` (or heading), and in 2D each turned by +90 degrees, in 3D
  their cross products: chiral laws (a swarm that mills one way) keep their sense; ``dv`` and
  ``v`` enter as ``x / sqrt(1 + |x|^2)`` (in units of the velocity scale), so every term is
  bounded whatever the inputs;
* pair scalars ``s_ij``: ``log(1 + d)`` (d in units of the policy's position scale, so a
  short-range repulsion and a weak far attraction both reach the tanh units at O(1)) and its
  radial basis (:data:`DISTANCE_BASIS` Gaussians evenly spaced on ``log(1 + d)`` from contact to
  the communication radius, as SchNet-like networks encode distances: one tanh layer on
  ``log(1 + d)`` alone fits a force that changes fast at short range poorly), the norms and dot
  products of those vectors and their signed areas (2D) or triple product (3D);
* one tanh layer gives the coefficients of the sum channel (grows with the neighbour count,
  as a force does) and of the mean channel (does not: alignment, the centroid); a neighbour in
  the robot's own state adds nothing (its direction and velocity difference are zero, and the
  own velocity's coefficients are taken relative to its), yet the push along ``r_hat`` may stay
  finite as two robots touch, as a repulsion that is finite at contact does;
* the own term ``b_c`` (one tanh layer on ``|v|`` and the neighbours' mean hidden units)
  scales ``v`` (2D: and ``v`` turned), the self-propulsion of most laws.

Every part is exactly equivariant under rotations (proper ones: reflections flip the turned
vectors), so no rotation augmentation or half-turn average is needed for it. With an arena
the own position matters: ``place`` (one tanh layer on the own position and velocity) adds an
absolute command, which the policy's half-turn average (``symmetric``) keeps equivariant
under the arena's own symmetries. Inputs arrive already divided by the policy's input scales.
A position-only state has no velocity: the vectors are ``r_hat`` (and, in 2D, it turned).

``axes``: where rotations are no symmetry of the law (a room whose vertical is special: drones
that swirl about it, a school that keeps its depth), the pair terms also see the coordinate
axes: the components of ``r_hat`` (and of ``dv``, ``v``) are pair scalars and the axes' unit
vectors pair vectors, so a pair term may be any function of the offset (a swirl about the
vertical is ``e_z x r_hat``, two axes' coefficients); the half-turn average keeps what symmetry
the arena has. A neighbour in the own state still adds nothing (the axes' coefficients are
taken relative to it, as the own velocity's).

``rank``: a topological law (each robot heeds its few nearest, however far) weighs a neighbour
by its place among the others, not by its distance alone. The rows of ``Y`` arrive sorted by
distance, so with ``rank = R > 0`` the pair scalars gain ``log(1 + min(rank, R))`` (rank 1 for
the nearest row): a pair term may then fall off with rank. Rows past the R-th count as the R-th:
a swarm denser than the data gives ranks the data never showed, and a tanh layer extrapolates
them freely. The own-state subtraction is taken at each row's rank, so that a neighbour in the
own state still adds nothing.
"""

from __future__ import annotations

import math
from typing import List

import torch
from torch import Tensor, nn
from torch.nn import functional as F

__all__ = ['EquivariantEncoder', 'DISTANCE_BASIS']

#: Gaussians of the pair distance the pair layer sees beside ``log(1 + d)``.
DISTANCE_BASIS = 32

#: A basis Gaussian is zero where its exponent exceeds this (exp(-80) is 1.8e-35, nothing beside
#: the O(1) inputs of the pair layer).
BASIS_CUTOFF = 80.0


def _left(x: Tensor) -> Tensor:
    """``x [..., 2]`` turned by +90 degrees."""
    return torch.stack([-x[..., 1], x[..., 0]], dim=-1)


def _cross(a: Tensor, b: Tensor) -> Tensor:
    """``a x b`` for ``[..., 3]`` vectors (written out: ONNX has no cross product)."""
    return torch.stack(
        [
            a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
            a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
            a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0],
        ],
        dim=-1,
    )


def _dot(a: Tensor, b: Tensor) -> Tensor:
    return (a * b).sum(-1, keepdim=True)


def _soft(a: Tensor) -> Tensor:
    """``a / sqrt(1 + |a|^2)``: ``a`` where small, a unit vector where large. Every vector the
    command is built from is then bounded, and so is the command, whatever the inputs: float32
    sums stay small enough for the ONNX twin to agree with TorchScript within 1e-5."""
    return a / torch.sqrt(1.0 + (a * a).sum(-1, keepdim=True))


def _norm(a: Tensor) -> Tensor:
    # smooth at 0: coincident robots and robots at rest have no direction, not a NaN slope
    return torch.sqrt((a * a).sum(-1, keepdim=True) + 1e-12)


class EquivariantEncoder(nn.Module):
    """``forward(Y [B, k, d], mask [B, k]) -> [B, m]`` (the network part, before knowledge)."""

    def __init__(
        self,
        state_dim: int,
        position_dim: int,
        command_dim: int,
        hidden: int,
        keep_own_position: bool,
        reach: float = 8.0,
        axes: bool = False,
        rank: int = 0,
    ):
        """``reach``: the communication radius in units of the position scale (the farthest
        neighbour distance the basis resolves); ``axes``: the pair terms see the coordinate axes;
        ``rank``: they see the row's rank among the neighbours, up to that rank (0: not at all;
        module docstring)."""
        super().__init__()
        self.position_dim = position_dim
        self.moving = state_dim > position_dim
        if self.moving:
            self.vectors = 6  # r_hat, dv, v and their turns (2D) or cross products (3D)
            scalars = 6 + (3 if position_dim == 2 else 1)
        else:
            self.vectors = 2 if position_dim == 2 else 1
            scalars = 1
        scalars += DISTANCE_BASIS
        self.axes = bool(axes)
        if self.axes:
            scalars += position_dim * (3 if self.moving else 1)  # the components of r_hat (dv, v)
        self.rank = int(rank)
        if self.rank > 0:
            scalars += 1
        relative_vectors = self.vectors  # those a neighbour in the own state gives as zero
        if self.axes:
            self.vectors += position_dim
        top = math.log1p(float(reach))
        # plain floats, as the other constants here: ONNX export takes flat lists
        self.basis_centres: List[float] = [top * i / (DISTANCE_BASIS - 1) for i in range(DISTANCE_BASIS)]
        self.basis_width = top / (DISTANCE_BASIS - 1)
        self.basis_cutoff = BASIS_CUTOFF
        self.own_vectors = (2 if position_dim == 2 else 1) if self.moving else 0
        # 1 for the pair vectors that do not vanish for a neighbour in the own state (v, v turned),
        # per channel (sum, then mean): plain floats, as the half-turn signs, for ONNX export
        own_velocity = [0.0] * relative_vectors + [1.0] * (self.vectors - relative_vectors)
        if self.moving:
            own_velocity[2] = 1.0
            if position_dim == 2:
                own_velocity[5] = 1.0
        self.own_velocity_mask: List[float] = own_velocity * 2
        # with the rank, those columns alone are taken relative to the own state, row by row, and
        # put back in place by a 0 / 1 matrix [2C, n] (ONNX export takes no scatter)
        columns = [i for i, x in enumerate(self.own_velocity_mask) if x == 1.0]
        self.has_same_columns = len(columns) > 0
        # never empty: TorchScript infers a list's type from its elements (unused without any)
        self.same_columns: List[int] = columns or [0]
        self.same_embed: List[float] = [
            float(c == col and self.has_same_columns)
            for c in range(len(self.own_velocity_mask))
            for col in self.same_columns
        ]
        self.axis_vectors: List[float] = [
            float(i == j) for i in range(position_dim) for j in range(position_dim)
        ]
        self.pair = nn.Linear(scalars, hidden)
        self.pair_out = nn.Linear(hidden, 2 * self.vectors, bias=False)  # sum, then mean channel
        # built only where used (hasattr is resolved when scripted: one branch per policy)
        if self.own_vectors > 0:
            self.own = nn.Sequential(
                nn.Linear(1 + hidden, hidden), nn.Tanh(), nn.Linear(hidden, self.own_vectors)
            )
        if keep_own_position:
            self.place = nn.Sequential(
                nn.Linear(state_dim, hidden), nn.Tanh(), nn.Linear(hidden, command_dim)
            )

    def pair_terms(self, r: Tensor, dv: Tensor, v: Tensor):
        """Scalars ``[B, J, S]`` and vectors ``[B, J, C, p]`` of pairs with offsets ``r``,
        velocity differences ``dv`` and own velocities ``v`` (all ``[B, J, p]``)."""
        d = _norm(r)
        rh = r / d
        logd = torch.log(1.0 + d)
        centres = torch.tensor(self.basis_centres, dtype=r.dtype, device=r.device)
        q = ((logd - centres) / self.basis_width) ** 2
        # A Gaussian's far tail is exactly zero, not subnormal: float32 subnormals (below 1e-38)
        # slow x86 arithmetic many times over, and one in fifty of the basis values were. The
        # clamp keeps exp itself from computing them (where evaluates both branches).
        cut = torch.clamp(q, max=self.basis_cutoff)
        gauss = torch.where(q < self.basis_cutoff, torch.exp(-cut), torch.zeros_like(q))
        radial = torch.cat([logd, gauss], dim=-1)
        dv, v = _soft(dv), _soft(v)
        if not self.moving:
            scalars = radial
            vectors = torch.stack([rh, _left(rh)], dim=2) if self.position_dim == 2 else rh.unsqueeze(2)
            return self._with_axes(scalars, vectors, [rh])
        base = [
            radial,
            _norm(dv),
            _norm(v),
            _dot(rh, dv),
            _dot(rh, v),
            _dot(dv, v),
        ]
        if self.position_dim == 2:
            left_rh, left_dv, left_v = _left(rh), _left(dv), _left(v)
            scalars = torch.cat(base + [_dot(left_rh, dv), _dot(left_rh, v), _dot(left_dv, v)], dim=-1)
            vectors = torch.stack([rh, dv, v, left_rh, left_dv, left_v], dim=2)
        else:
            scalars = torch.cat(base + [_dot(rh, _cross(dv, v))], dim=-1)
            vectors = torch.stack([rh, dv, v, _cross(rh, dv), _cross(rh, v), _cross(dv, v)], dim=2)
        return self._with_axes(scalars, vectors, [rh, dv, v])

    def _with_axes(self, scalars: Tensor, vectors: Tensor, components: List[Tensor]):
        """With ``axes``, the pair scalars gain the ``components`` vectors' coordinates and the
        pair vectors the axes' unit vectors; else both as they are."""
        if not self.axes:
            return scalars, vectors
        p = self.position_dim
        eye = torch.tensor(self.axis_vectors, dtype=vectors.dtype, device=vectors.device).reshape(1, 1, p, p)
        eye = eye.expand(vectors.shape[0], vectors.shape[1], p, p)
        return torch.cat([scalars] + components, dim=-1), torch.cat([vectors, eye], dim=2)

    def forward(self, Y: Tensor, mask: Tensor) -> Tensor:
        p = self.position_dim
        own = Y[:, 0, :]
        rel = Y[:, 1:, :] - Y[:, :1, :]  # [B, J, d]
        J = rel.shape[1]
        if self.moving:
            v = own[:, p : 2 * p]
            vj = v.unsqueeze(1).expand(-1, J, -1)
            dv = rel[:, :, p : 2 * p]
        else:
            v = torch.zeros_like(own[:, :p])
            vj = torch.zeros_like(rel[:, :, :p])
            dv = vj
        scalars, vectors = self.pair_terms(rel[:, :, :p], dv, vj)
        # A neighbour in the robot's own state adds nothing: its direction and velocity difference
        # are zero vectors, and the coefficients of the own velocity (which is not) are taken
        # relative to it. Those of the direction are not: a repulsion may be finite at contact.
        same, _ = self.pair_terms(
            torch.zeros_like(v).unsqueeze(1), torch.zeros_like(v).unsqueeze(1), v.unsqueeze(1)
        )
        m = mask[:, 1:].to(Y.dtype).unsqueeze(-1)
        if self.rank > 0:
            # valid rows come first, nearest first (core.network.rank_neighbours). The rank is the
            # pair layer's last input: its part is added to the others' (the same for every row of
            # the own state), not concatenated, which would double the layer's work.
            ranks = torch.arange(1, J + 1, dtype=Y.dtype, device=Y.device)
            ranks = torch.log1p(torch.clamp(ranks, max=float(self.rank)))
            weight = self.pair.weight
            by_rank = ranks.view(1, J, 1) * weight[:, -1].view(1, 1, -1)  # [1, J, H]
            h_raw = torch.tanh(F.linear(scalars, weight[:, :-1], self.pair.bias) + by_rank) * m
            a = self.pair_out(h_raw)  # [B, J, 2C]
            h = h_raw
            # the own state's hidden units differ row by row now: computed only where used
            if self.has_same_columns or self.own_vectors > 0:
                h_same = torch.tanh(F.linear(same, weight[:, :-1], self.pair.bias) + by_rank) * m
                h = h_raw - h_same
                if self.has_same_columns:
                    columns = torch.tensor(self.same_columns, dtype=torch.long, device=Y.device)
                    a_same = F.linear(h_same, self.pair_out.weight.index_select(0, columns))
                    embed = torch.tensor(self.same_embed, dtype=Y.dtype, device=Y.device)
                    a = a - F.linear(a_same, embed.view(a.shape[-1], len(self.same_columns)))
        else:
            h_same = torch.tanh(self.pair(same))  # [B, 1, H]
            h_raw = torch.tanh(self.pair(scalars)) * m  # [B, J, H]
            h = h_raw - h_same * m
            own_velocity = torch.tensor(self.own_velocity_mask, dtype=Y.dtype, device=Y.device)
            a = self.pair_out(h_raw) - self.pair_out(h_same) * own_velocity * m  # [B, J, 2C]
        C = self.vectors
        count = torch.clamp(m.sum(1), min=1.0)  # [B, 1]
        u = (a[:, :, :C].unsqueeze(-1) * vectors).sum(dim=(1, 2))
        u = u + (a[:, :, C:].unsqueeze(-1) * vectors).sum(dim=(1, 2)) / count
        if hasattr(self, 'own'):
            b = self.own(torch.cat([_norm(v), h.sum(1) / count], dim=1))
            vs = _soft(v)
            if p == 2:
                u = u + b[:, :1] * vs + b[:, 1:2] * _left(vs)
            else:
                u = u + b[:, :1] * vs
        if hasattr(self, 'place'):
            u = u + self.place(own)
        return u
