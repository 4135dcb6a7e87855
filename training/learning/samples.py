"""One-step-ahead training samples from trajectories, and the symmetry augmentation of a batch.

Shapes: N trajectories, T frames, n robots, d state entries, k neighbour rows, m command
entries, M = samples (one per trajectory, frame t < T - 1 and robot). Neighbour matrices come
from the core's batched builder :func:`knode_swarm_ros.core.neighbour_matrices`, so training
sees exactly what a robot sees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np
import torch
from torch import Tensor

from knode_swarm_ros.core import neighbour_matrices
from knode_swarm_ros.core.scenarios import Scenario


@dataclass
class Samples:
    """One-step-ahead training pairs: the robot's neighbour matrix at t and its own state at t + 1.

    ``Y [M, k, d]`` float32 (row 0 = own state at t), ``mask [M, k]`` float32,
    ``target [M, d]`` float32 (own state at t + 1), ``clean_own [M, d]`` own state at t
    without observation noise (equal to ``Y[:, 0]`` unless noise mode is ``observations``).
    """

    Y: Tensor
    mask: Tensor
    target: Tensor
    clean_own: Tensor

    def __len__(self) -> int:
        return self.Y.shape[0]

    def subset(self, keep: Tensor) -> 'Samples':
        return Samples(self.Y[keep], self.mask[keep], self.target[keep], self.clean_own[keep])


def concat_samples(parts: 'list[Samples]') -> Samples:
    """One sample set from several (e.g. files with swarms of different sizes: every sample is one
    robot's k-row neighbour matrix, whatever n its swarm had)."""
    if len(parts) == 1:
        return parts[0]
    return Samples(*(torch.cat([getattr(p, f) for p in parts]) for f in ('Y', 'mask', 'target', 'clean_own')))


def implied_command(own: Tensor, target: Tensor, spec: Scenario, dt: float) -> Tensor:
    """The command ``[M, m]`` that a zero-order hold needs to go from ``own`` to ``target``
    (acceleration: velocity change / dt; velocity: displacement / dt)."""
    p = spec.position_dim
    if spec.command == 'acceleration':
        return (target[:, p:] - own[:, p:]) / dt
    return (target[:, :p] - own[:, :p]) / dt


def make_samples(
    states: np.ndarray,
    spec: Scenario,
    d_cr: float,
    k: int,
    tau: int,
    stride: int = 1,
    obs_noise_std: float = 0.0,
    rng: Optional[np.random.Generator] = None,
    ratio: int = 1,
) -> Samples:
    """Build samples from trajectories ``[N, T, n, d]`` (T >= ratio + 1) with the core's batched builder.

    ``obs_noise_std`` > 0 adds Gaussian noise to the observed trajectories once (the paper's
    noisy observations): inputs and targets both see it. ``stride`` keeps every stride-th
    frame as a start state. ``ratio`` (policy dt / data dt, see :mod:`training.learning.period`): the
    target of start frame t is frame t + ratio and the delay ``tau`` (policy steps) is
    ``tau * ratio`` frames, so the pairs are observations at the policy's period taken at
    every phase of the data (``stride = ratio`` keeps one phase).
    """
    states = np.asarray(states, dtype=np.float64)
    if states.ndim != 4 or states.shape[1] < ratio + 1:
        raise ValueError(f'need trajectories [N, T >= {ratio + 1}, n, d], got {states.shape}')
    clean = states
    if obs_noise_std > 0:
        rng = rng or np.random.default_rng(0)
        states = states + rng.normal(0.0, obs_noise_std, size=states.shape)
    Y, mask = neighbour_matrices(states, spec.position_dim, d_cr, k, tau * ratio)  # [N, T, n, k, d]
    starts = np.arange(0, states.shape[1] - ratio, stride)
    d = states.shape[-1]
    Ys = Y[:, starts].reshape(-1, k, d)
    ms = mask[:, starts].reshape(-1, k)
    target = states[:, starts + ratio].reshape(-1, d)
    own = clean[:, starts].reshape(-1, d)
    f32 = lambda a: torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32))  # noqa: E731
    return Samples(f32(Ys), f32(ms), f32(target), f32(own))


def random_rotations(B: int, dims: int, g: Optional[torch.Generator]) -> Tensor:
    """``B`` random rotation matrices ``[B, dims, dims]``: a uniform angle in 2D, a uniform
    rotation (a normalised Gaussian quaternion) in 3D."""
    if dims == 2:
        theta = torch.rand(B, generator=g) * (2 * math.pi)
        c, s = torch.cos(theta), torch.sin(theta)
        return torch.stack([torch.stack([c, -s], -1), torch.stack([s, c], -1)], -2)
    q = torch.randn(B, 4, generator=g)
    w, x, y, z = (q / q.norm(dim=1, keepdim=True)).unbind(1)
    return torch.stack(
        [
            torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            torch.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            torch.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def augment_batch(
    Y: Tensor,
    mask: Tensor,
    own: Tensor,
    target: Tensor,
    spec: Scenario,
    dt: float,
    rotate: bool,
    boost_std: float,
    g: Optional[torch.Generator],
):
    """Apply symmetries of the scenario to a batch of samples (the config allows them only
    where they hold: rotations without an arena, boosts for acceleration scenarios).

    ``rotate``: one random rotation per sample (planar in 2D, uniform on SO(3) in 3D) of every
    position, velocity and heading (an isotropic law is rotation invariant); ``boost_std``: one
    Gaussian velocity offset per sample added to every velocity (Galilean invariance: only
    velocity differences enter), with the target position shifted by offset * dt. The implied
    command rotates with the sample and is unchanged by the boost, so the augmented pairs are exact observations of the same law.
    """
    B, p = Y.shape[0], spec.position_dim
    if rotate:
        R = random_rotations(B, p, g)  # [B, p, p]

        def rot(z):  # z [B, ..., d]: blocks of p entries (position, then velocity or heading)
            shape = z.shape
            blocks = z.reshape(B, -1, shape[-1] // p, p)  # [B, rows, block, axis]
            return torch.einsum('bij,brkj->brki', R, blocks).reshape(shape)

        Y, own, target = rot(Y), rot(own), rot(target)
    if boost_std > 0:
        b = torch.randn(B, p, generator=g) * boost_std
        Y = torch.cat([Y[..., :p], Y[..., p:] + b[:, None, :] * mask.unsqueeze(-1)], dim=-1)
        own = torch.cat([own[:, :p], own[:, p:] + b], dim=1)
        target = torch.cat([target[:, :p] + b * dt, target[:, p:] + b], dim=1)
    return Y, own, target
