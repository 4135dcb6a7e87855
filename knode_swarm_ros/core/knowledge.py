"""Known physics of the hybrid model: potential-function avoidance (paper, "KNODE").

Both terms derive from U(d) = (lambda / 2) / d^2 for d <= d0 (zero beyond), so the
force on the robot is -grad U = lambda * r / d^4, with r pointing away from the obstacle.
That force jumps from lambda / d0^3 to 0 at d0, and the collision term jumps again whenever the
closest neighbour changes; inside the range of a flock's spacing a network cannot cancel such
jumps, so every command carries them (docs/training.md, "A continuous avoidance potential").
The ``continuous`` variants keep the paper's idea and its 1 / d^3 growth at contact but vanish
continuously at d0: U(d) = (lambda / 2) (1/d - 1/d0)^2, force lambda (1/d - 1/d0) / d^2 along
r / d, summed over every heard neighbour within d0 (a sum of pair potentials, so nothing jumps
when neighbours change rank).
With an acceleration command the wall terms take the distance left after braking at the command
limit (:func:`stopping_reach`): a double integrator cannot stop at once, and a push that only
grows with the distance lets a fast robot through the wall before it outweighs the learnt part.
Gains are lambda = a + phi^2 with a >= 0 fixed and phi trainable (the paper uses a > 0
in 2D and a = 0 in 3D), which keeps every gain non-negative whatever phi learns.

All functions are TorchScript-compatible and work on a batch of neighbour matrices.
"""

from __future__ import annotations

from typing import Optional

import torch
from torch import Tensor, nn

__all__ = [
    'AvoidanceGain',
    'collision_avoidance',
    'wall_avoidance',
    'stopping_reach',
    'collision_potential',
    'wall_potential',
    'continuous_collision_avoidance',
    'continuous_wall_avoidance',
    'continuous_collision_potential',
    'continuous_wall_potential',
    'MIN_DISTANCE',
]

# Distances are floored at ``min_distance`` (default MIN_DISTANCE) so that two robots on top
# of each other get a huge but finite push (the policy's saturation bounds it), not inf/NaN:
# closer than min_distance the collision push is lambda / min_distance^3 along r / |r|, and for
# robots exactly on top of each other (r = 0) along +x, the first position axis. The neighbour
# matrix carries no ids, so nothing tells two coincident robots with equal states apart: both
# get the same deterministic push (it is bounded and never silently zero; the commands of
# different neighbourhoods or velocities then separate them).
# TorchScript cannot read module globals, hence the literal defaults below.
MIN_DISTANCE = 1e-3


class AvoidanceGain(nn.Module):
    """lambda = a + phi^2 with ``a`` a fixed buffer and ``phi`` a trainable parameter."""

    def __init__(self, a: float = 0.0, phi: float = 1.0, trainable: bool = True):
        super().__init__()
        if a < 0:
            raise ValueError(f'gain offset a must be >= 0, got {a}')
        self.register_buffer('a', torch.tensor(float(a)))
        self.phi = nn.Parameter(torch.tensor(float(phi)), requires_grad=trainable)

    def forward(self) -> Tensor:
        return self.a + self.phi * self.phi


def _closest_active(Y: Tensor, mask: Tensor, position_dim: int):
    """Offset r = p_0 - p_j ``[B, p]`` and distance ``[B]`` to the closest active neighbour row."""
    own = Y[:, 0, :position_dim]
    offsets = own.unsqueeze(1) - Y[:, 1:, :position_dim]  # [B, k-1, p]
    dist = torch.linalg.vector_norm(offsets, dim=-1)  # [B, k-1]
    inactive = mask[:, 1:] <= 0
    dist = dist.masked_fill(inactive, float('inf'))
    best, j = torch.min(dist, dim=-1)  # first row wins ties
    r = torch.gather(offsets, 1, j.view(-1, 1, 1).expand(-1, 1, offsets.shape[-1])).squeeze(1)
    return r, best


def _unit(r: Tensor, dist: Tensor) -> Tensor:
    """``r / dist`` (``dist`` broadcast over the last axis), or +x, the first position axis, where
    dist = 0 (module comment). The safe divisor keeps autograd free of 0/0 in the branch not taken."""
    axis = (torch.arange(r.shape[-1], device=r.device) == 0).to(r.dtype)  # [p], broadcast (ONNX-exportable)
    apart = dist > 0
    return torch.where(apart, r / torch.where(apart, dist, torch.ones_like(dist)), axis)


def stopping_reach(velocity: Tensor, limit: float):
    """How far a robot moving at ``velocity [B, p]`` still travels towards the +box and the -box
    faces while braking at ``limit`` per axis: v^2 / (2 limit) for the axes it moves along, 0 else."""
    up = velocity.clamp(min=0.0)
    down = (-velocity).clamp(min=0.0)
    return up * up / (2.0 * limit), down * down / (2.0 * limit)


def _wall_pushes(
    position: Tensor,
    box: float,
    gain: Tensor,
    d0: float,
    min_distance: float,
    continuous: bool,
    velocity: Optional[Tensor] = None,
    limit: float = 0.0,
) -> Tensor:
    """Both wall terms ``[B, p]``: per face within d0, lambda / d^3 (paper) or
    lambda (1/d - 1/d0) / d^2 (continuous) along the inward normal, distances floored.

    With ``velocity`` (an acceleration command saturated at ``limit``) d is the distance left
    after braking at the limit: the push grows without bound before a robot can no longer stop
    at the wall, so it outweighs any learnt push while braking can still keep the robot in."""
    up = box - position  # distance to the +box faces
    down = position + box  # distance to the -box faces
    if velocity is not None:
        reach_up, reach_down = stopping_reach(velocity, limit)
        up = up - reach_up
        down = down - reach_down
    up = up.clamp(min=min_distance)
    down = down.clamp(min=min_distance)
    zero = torch.zeros_like(position)
    if continuous:
        return torch.where(up < d0, -gain * (1.0 / up - 1.0 / d0) / up**2, zero) + torch.where(
            down < d0, gain * (1.0 / down - 1.0 / d0) / down**2, zero
        )
    return torch.where(up <= d0, -gain / up**3, zero) + torch.where(down <= d0, gain / down**3, zero)


def collision_avoidance(
    Y: Tensor, mask: Tensor, position_dim: int, gain: Tensor, d0: float, min_distance: float = 1e-3
) -> Tensor:
    """Repulsion from the closest active neighbour only.

    Args:
        Y: ``[B, k, d]`` neighbour matrices (row 0 = own state, positions first).
        mask: ``[B, k]`` 1 for real rows.
        gain: scalar lambda.
        d0: range of the potential; no force beyond it.

    Returns:
        ``[B, p]`` force lambda * r / d^4 (zero without an active neighbour within d0;
        closer than ``min_distance``: lambda / min_distance^3 along r / |r|, or along +x for r = 0).
    """
    if Y.shape[1] < 2:
        return torch.zeros(Y.shape[0], position_dim, dtype=Y.dtype, device=Y.device)
    r, dist = _closest_active(Y, mask, position_dim)
    near = (dist <= d0).unsqueeze(-1)
    d = dist.clamp(min=min_distance).masked_fill(~near.squeeze(-1), 1.0).unsqueeze(-1)
    force = gain * r / d**4
    # inside the floor: the floored magnitude along r / |r| (or +x)
    unit = _unit(r, dist.unsqueeze(-1))
    inside = (dist < min_distance).unsqueeze(-1)
    force = torch.where(inside, gain * unit / (min_distance**3), force)
    return torch.where(near, force, torch.zeros_like(r))


def wall_avoidance(
    position: Tensor,
    box: float,
    gain: Tensor,
    d0: float,
    min_distance: float = 1e-3,
    velocity: Optional[Tensor] = None,
    limit: float = 0.0,
) -> Tensor:
    """Repulsion from the closest point of each face of the cube [-box, box]^p.

    Args:
        position: ``[B, p]``.

    Returns:
        ``[B, p]``: for each face within d0, lambda / d^3 along the inward normal. A robot
        already outside the box is pushed back in with the floored distance. With ``velocity``
        and ``limit`` (acceleration commands) d is the distance left after braking at the limit.
    """
    return _wall_pushes(position, box, gain, d0, min_distance, False, velocity, limit)


def continuous_collision_avoidance(
    Y: Tensor, mask: Tensor, position_dim: int, gain: Tensor, d0: float, min_distance: float = 1e-3
) -> Tensor:
    """Sum over every active neighbour within d0 of lambda (1/d - 1/d0) / d^2 along r / d.

    Args and floor as :func:`collision_avoidance` (closer than ``min_distance`` the magnitude
    at ``min_distance``, along +x for r = 0). Returns ``[B, p]``, zero at and beyond d0.
    """
    if Y.shape[1] < 2:
        return torch.zeros(Y.shape[0], position_dim, dtype=Y.dtype, device=Y.device)
    offsets = Y[:, :1, :position_dim] - Y[:, 1:, :position_dim]  # r = p_0 - p_j [B, k-1, p]
    dist = torch.linalg.vector_norm(offsets, dim=-1, keepdim=True)  # [B, k-1, 1]
    near = (dist < d0) & (mask[:, 1:] > 0).unsqueeze(-1)
    d = dist.clamp(min=min_distance)
    unit = _unit(offsets, dist)
    magnitude = gain * (1.0 / d - 1.0 / d0) / d**2
    return torch.where(near, magnitude * unit, torch.zeros_like(offsets)).sum(dim=1)


def continuous_wall_avoidance(
    position: Tensor,
    box: float,
    gain: Tensor,
    d0: float,
    min_distance: float = 1e-3,
    velocity: Optional[Tensor] = None,
    limit: float = 0.0,
) -> Tensor:
    """Per face within d0, lambda (1/d - 1/d0) / d^2 along the inward normal ``[B, p]``
    (floored distance outside the box, and the distance left after braking with ``velocity``,
    as :func:`wall_avoidance`)."""
    return _wall_pushes(position, box, gain, d0, min_distance, True, velocity, limit)


def _pair_potential(
    dist: Tensor, gain: Tensor, d0: float, continuous: bool, near: Optional[Tensor] = None
) -> Tensor:
    """U per distance (same shape): (lambda / 2) / d^2 for d <= d0 (paper) or
    (lambda / 2) (1/d - 1/d0)^2 for d < d0 (continuous), 0 beyond and where ``near`` is False."""
    within = dist < d0 if continuous else dist <= d0
    near = within if near is None else within & near
    d = dist.masked_fill(~near, 1.0)
    u = 0.5 * gain * (1.0 / d - 1.0 / d0) ** 2 if continuous else 0.5 * gain / d**2
    return torch.where(near, u, torch.zeros_like(d))


def _wall_potential(position: Tensor, box: float, gain: Tensor, d0: float, continuous: bool) -> Tensor:
    """U ``[B]`` of both wall terms, summed over the faces."""
    return _pair_potential(box - position, gain, d0, continuous).sum(-1) + _pair_potential(
        position + box, gain, d0, continuous
    ).sum(-1)


def continuous_collision_potential(
    Y: Tensor, mask: Tensor, position_dim: int, gain: Tensor, d0: float
) -> Tensor:
    """U ``[B]`` of :func:`continuous_collision_avoidance`."""
    dist = torch.linalg.vector_norm(Y[:, :1, :position_dim] - Y[:, 1:, :position_dim], dim=-1)  # [B, k-1]
    return _pair_potential(dist, gain, d0, True, near=mask[:, 1:] > 0).sum(-1)


def continuous_wall_potential(position: Tensor, box: float, gain: Tensor, d0: float) -> Tensor:
    """U ``[B]`` of :func:`continuous_wall_avoidance` for robots inside the box."""
    return _wall_potential(position, box, gain, d0, True)


def collision_potential(Y: Tensor, mask: Tensor, position_dim: int, gain: Tensor, d0: float) -> Tensor:
    """U ``[B]`` of :func:`collision_avoidance` (for checks against autograd)."""
    _, dist = _closest_active(Y, mask, position_dim)
    return _pair_potential(dist, gain, d0, False)


def wall_potential(position: Tensor, box: float, gain: Tensor, d0: float) -> Tensor:
    """U ``[B]`` of :func:`wall_avoidance` for robots inside the box."""
    return _wall_potential(position, box, gain, d0, False)
