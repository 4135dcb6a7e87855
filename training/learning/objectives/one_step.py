"""The one-step-ahead objective (``training.objective: one_step``): predict every sampled robot's
next state with the policy from its neighbour matrix, and penalise the error.

The model is always :class:`knode_swarm_ros.core.KNODEPolicy`: the trained module is the
exported one. Shapes: M samples, B samples of a batch, k neighbour rows, d state entries.
"""

from __future__ import annotations

import math
from typing import Any, Dict, List, Optional

import torch
from torch import Tensor, nn

from knode_swarm_ros.core import KNODEPolicy
from knode_swarm_ros.core.rollout import heading_torch, zoh_step_torch
from knode_swarm_ros.core.scenarios import Scenario

from ..samples import Samples, augment_batch
from .base import Objective, TrainingData


class HeldNeighbourField(nn.Module):
    """Hybrid vector field of one robot over one step, neighbours held at their observed rows.

    ``forward(t, z [B, d]) -> dz/dt``: the own row of Y follows z (plus its input noise),
    the neighbour rows stay fixed. Double integrator: (v, u); first order: (u, 0) (the
    heading is set from the displacement after the step).
    """

    def __init__(
        self, policy: KNODEPolicy, spec: Scenario, Y: Tensor, mask: Tensor, own_noise: Optional[Tensor]
    ):
        super().__init__()
        self.policy = policy
        self.spec = spec
        self.Y_rest = Y[:, 1:]
        self.mask = mask
        self.own_noise = own_noise
        self.nfe = 0

    def forward(self, t: Tensor, z: Tensor) -> Tensor:
        self.nfe += 1
        own = z if self.own_noise is None else z + self.own_noise
        u = self.policy(torch.cat([own.unsqueeze(1), self.Y_rest], dim=1), self.mask)
        p = self.spec.position_dim
        if self.spec.command == 'acceleration':
            return torch.cat([z[:, p:], u], dim=1)
        return torch.cat([u, torch.zeros_like(z[:, p:])], dim=1)


def predict_next(
    policy: KNODEPolicy,
    spec: Scenario,
    dt: float,
    Y: Tensor,
    mask: Tensor,
    own: Tensor,
    solver: str = 'zoh',
    ode_method: str = 'rk4',
    input_noise: Optional[Tensor] = None,
) -> Tensor:
    """Predicted own state at t + dt ``[B, d]`` from neighbour matrices ``Y [B, k, d]``.

    Args:
        own: ``[B, d]`` the state the prediction starts from (the observed own state).
        solver: ``zoh`` (exact zero-order hold of the command at t: what deployment does),
            ``rk4`` (direct backprop through ``torchdiffeq.odeint`` of the held-neighbour field),
            ``adjoint`` (``torchdiffeq.odeint_adjoint`` of the same field, the paper's gradient).
        input_noise: optional ``[B, k, d]`` noise added to the policy's input only.
    """
    Yin = Y if input_noise is None else Y + input_noise * mask.unsqueeze(-1)
    if solver == 'zoh':
        return zoh_step_torch(own, policy(Yin, mask), spec, dt)
    import torchdiffeq

    own_noise = None if input_noise is None else input_noise[:, 0]
    field = HeldNeighbourField(policy, spec, Yin, mask, own_noise)
    t = torch.tensor([0.0, dt], dtype=Y.dtype)
    options = {'step_size': dt} if ode_method != 'dopri5' else {}
    kwargs = dict(method=ode_method, options=options)
    if ode_method == 'dopri5':
        kwargs.update(rtol=1e-6, atol=1e-8)
    if solver == 'adjoint':
        z1 = torchdiffeq.odeint_adjoint(field, own, t, adjoint_params=tuple(policy.parameters()), **kwargs)[
            -1
        ]
    else:
        z1 = torchdiffeq.odeint(field, own, t, **kwargs)[-1]
    if spec.command == 'velocity':
        p = spec.position_dim
        z1 = torch.cat([z1[:, :p], heading_torch(z1[:, :p] - own[:, :p], own[:, p:])], dim=1)
    return z1


def loss_scales(spec: Scenario, dt: float, units: str, heading_weight: float = 1.0) -> Tensor:
    """Per-entry divisors ``[d]`` of the one-step error.

    ``state``: the paper's plain state MSE (all ones). ``command``: the error expressed in
    command units (acceleration: position / (dt^2 / 2), velocity / dt; velocity command:
    position / dt, heading scaled by 1 / sqrt(heading_weight)), which makes the loss read
    as the squared error of the implied command and keeps numbers O(1) in float32.
    """
    p, d = spec.position_dim, spec.state_dim
    if units == 'state':
        return torch.ones(d)
    if spec.command == 'acceleration':
        return torch.tensor([0.5 * dt * dt] * p + [dt] * (d - p))
    hw = 1.0 / math.sqrt(heading_weight) if heading_weight > 0 else float('inf')
    return torch.tensor([dt] * p + [hw] * (d - p))


def one_step_loss(pred: Tensor, target: Tensor, scales: Tensor) -> Tensor:
    """Mean over samples and entries of ((pred - target) / scales)^2."""
    return (((pred - target) / scales) ** 2).mean()


class OneStepObjective(Objective):
    """Batches and loss of the ``one_step`` objective over one-step ``samples``.

    ``batches(epoch, g)`` is a shuffle of the sample indices cut into ``training.batch_size``;
    ``loss(policy, idx [B], g)`` is :func:`one_step_loss` of :func:`predict_next` on those samples,
    with the ``augment`` symmetries and the input noise (``noise.mode: inputs``) drawn from ``g``.
    """

    def __init__(self, cfg: Dict[str, Any], spec: Scenario, dt: float, samples: Samples):
        self.cfg, self.spec, self.dt, self.samples = cfg, spec, dt, samples
        tc, nc = cfg['training'], cfg['noise']
        self.input_std = math.sqrt(nc['variance']) if nc['mode'] == 'inputs' else 0.0
        self.scales = loss_scales(spec, dt, tc['loss_units'], tc['heading_weight'])

    @classmethod
    def from_data(
        cls, cfg: Dict[str, Any], spec: Scenario, dt: float, data: TrainingData
    ) -> OneStepObjective:
        return cls(cfg, spec, dt, data.samples)

    def batches(self, epoch: int, g: torch.Generator) -> List[Tensor]:
        M = len(self.samples)
        bs = self.cfg['training']['batch_size']
        bs = M if bs == 'full' else min(bs, M)
        perm = torch.randperm(M, generator=g)
        return list(torch.split(perm, bs))

    def loss(self, policy: KNODEPolicy, idx: Tensor, g: Optional[torch.Generator]) -> Tensor:
        s = self.samples
        Y, mask, target, own = s.Y[idx], s.mask[idx], s.target[idx], s.clean_own[idx]
        ac = self.cfg['augment']
        if g is not None and (ac['rotate'] or ac['velocity_boost'] > 0):
            Y, own, target = augment_batch(
                Y, mask, own, target, self.spec, self.dt, ac['rotate'], ac['velocity_boost'], g
            )
        noise = None
        if g is not None and self.input_std > 0:
            noise = torch.randn(Y.shape, generator=g) * self.input_std
        tc = self.cfg['training']
        pred = predict_next(policy, self.spec, self.dt, Y, mask, own, tc['solver'], tc['ode_method'], noise)
        return one_step_loss(pred, target, self.scales)
