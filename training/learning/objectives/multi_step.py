"""The multi-step objective (``training.objective: multi_step``): fit the hybrid model to whole
windows of observed swarm motion.

The one-step-ahead loss (``training.objective: one_step``) compares one zero-order-hold step
from every observed state with the next observation. It barely weighs a small persistent
jitter of the commands in the flocked state, which is what keeps the learnt swarm's final avd
an order of magnitude above the ground truth's (docs/training.md). ``multi_step`` instead rolls
the model out over H steps from an observed swarm state with the deployment semantics
(:func:`knode_swarm_ros.core.rollout_torch`: zero-order hold, neighbour matrices rebuilt from
the model's own predicted states, delayed by tau) and penalises the whole predicted window,
with gradients through the rollout (direct backprop; ``multistep.checkpoint`` recomputes
segments in the backward pass to save memory on long horizons). ``multistep.consensus_weight``
adds the error of the velocities relative to the swarm's mean, what avd measures. A curriculum
raises H stage by stage (``multistep.horizons`` with ``multistep.epochs`` epochs each),
starting from a one-step model (``multistep.init``).

Shapes: N trajectories, T frames, n robots, d state entries, W windows of H + 1 frames.
"""

from __future__ import annotations

import math
from typing import Any, Dict, List, Optional, Tuple

import numpy as np
import torch
from torch import Tensor

from knode_swarm_ros.core.errors import ConfigError
from knode_swarm_ros.core.rollout import rollout_torch
from knode_swarm_ros.core.scenarios import Scenario

from ..period import phases
from .base import Objective, TrainingData

__all__ = [
    'MultiStepObjective',
    'load_init_state',
    'Windows',
    'horizon_at',
    'window_scales',
    'window_loss',
    'consensus_loss',
    'augment_windows',
    'rollout_windows',
]


class Windows:
    """Observed trajectories ``[N, T, n, d]`` (float32) from which training windows are drawn.

    A window is (trajectory, start frame t0): the model starts from frame t0 (with frames
    t0 - tau .. t0 - 1 as what the robots heard before, clamped at frame 0) and is compared with
    frames t0 + 1 .. t0 + H.
    """

    def __init__(self, states: np.ndarray, tau: int, bad_steps: Optional[np.ndarray] = None):
        """``bad_steps [N, T - 1]`` bool marks steps t -> t + 1 that no window may contain (e.g. an
        implied command beyond the policy's saturation: no saturated policy can follow it)."""
        self.states = torch.from_numpy(np.ascontiguousarray(states, dtype=np.float32))
        self.tau = int(tau)
        N, T = self.states.shape[:2]
        bad = np.zeros((N, T - 1), bool) if bad_steps is None else np.asarray(bad_steps, bool)
        if bad.shape != (N, T - 1):
            raise ValueError(f'bad_steps must be [{N}, {T - 1}], got {bad.shape}')
        # bad_before[s, t] = number of bad steps before step t: a window [t0, t0 + H) is clean
        # when bad_before[t0 + H] == bad_before[t0]
        self._bad_before = np.concatenate([np.zeros((N, 1), np.int64), np.cumsum(bad, axis=1)], axis=1)
        self._clean: Dict[int, Tensor] = {}

    def clean_starts(self, H: int) -> Tensor:
        """``[K, 2]`` every (trajectory, t0) whose window of H steps holds no bad step."""
        N, T = self.states.shape[:2]
        H = min(H, T - 1)
        if H not in self._clean:
            ok = self._bad_before[:, H:] == self._bad_before[:, : T - H]  # [N, T - H]
            self._clean[H] = torch.from_numpy(np.argwhere(ok))
        return self._clean[H]

    def __len__(self) -> int:
        """Number of (trajectory, frame) start states, the unit of ``windows_per_epoch``."""
        N, T = self.states.shape[:2]
        return N * (T - 1)

    def starts(self, count: int, H: int, g: Optional[torch.Generator]) -> Tensor:
        """``[count, 2]`` (trajectory, t0) pairs, uniform over every clean window that fits."""
        clean = self.clean_starts(H)
        if len(clean) == 0:
            raise ValueError(f'no window of {H} steps without a bad step in the training data')
        return clean[torch.randint(0, len(clean), (count,), generator=g)]

    def fixed_starts(self, count: int, H: int) -> Tensor:
        """Deterministic, evenly spread starts (validation)."""
        N, T = self.states.shape[:2]
        H = min(H, T - 1)
        per = max(1, math.ceil(count / N))
        t0 = torch.linspace(0, T - 1 - H, per).round().long()
        pairs = torch.cartesian_prod(torch.arange(N), t0)
        return pairs[:count]

    def gather(self, starts: Tensor, H: int) -> Tuple[Tensor, Optional[Tensor]]:
        """Observed windows ``[W, H + 1, n, d]`` and histories ``[W, tau, n, d]`` (None if tau = 0)."""
        T = self.states.shape[1]
        H = min(H, T - 1)
        frames = starts[:, 1:2] + torch.arange(H + 1)  # [W, H + 1]
        obs = self.states[starts[:, 0:1], frames]
        history = None
        if self.tau > 0:
            past = (starts[:, 1:2] + torch.arange(-self.tau, 0)).clamp(min=0)  # [W, tau]
            history = self.states[starts[:, 0:1], past]
        return obs, history


def horizon_at(epoch: int, horizons: List[int], epochs: List[int]) -> int:
    """Horizon H of 1-based ``epoch`` under the curriculum (stage i lasts ``epochs[i]`` epochs)."""
    done = 0
    for H, count in zip(horizons, epochs):
        done += count
        if epoch <= done:
            return H
    return horizons[-1]


def window_scales(
    spec: Scenario, dt: float, H: int, units: str, heading_weight: float = 1.0, velocity_weight: float = 1.0
) -> Tensor:
    """Per-frame, per-entry divisors ``[H, d]`` of the window error.

    ``command``: the error at frame h expressed as the constant command error that would cause
    it under the zero-order hold (acceleration: position / ((h dt)^2 / 2), velocity / (h dt);
    velocity command: position / (h dt), heading by 1 / sqrt(heading_weight)), so every frame
    of the window weighs in the same units as the one-step loss (H = 1 is that loss exactly).
    ``state``: plain state errors. ``velocity_weight`` (acceleration scenarios) multiplies the
    squared velocity errors: avd, the flocking measure, is a velocity spread, and a jitter of
    the commands shows in the velocities before it moves the positions.
    """
    p, d = spec.position_dim, spec.state_dim
    vw = 1.0 / math.sqrt(velocity_weight) if spec.command == 'acceleration' else 1.0
    if units == 'state':
        return torch.cat([torch.ones(H, p), torch.full((H, d - p), vw)], dim=1)
    h = torch.arange(1, H + 1, dtype=torch.float32)[:, None] * dt  # [H, 1]
    if spec.command == 'acceleration':
        return torch.cat([(0.5 * h * h).expand(H, p), (h * vw).expand(H, d - p)], dim=1)
    hw = 1.0 / math.sqrt(heading_weight) if heading_weight > 0 else float('inf')
    return torch.cat([h.expand(H, p), torch.full((H, d - p), hw)], dim=1)


def window_loss(pred: Tensor, obs: Tensor, scales: Tensor) -> Tensor:
    """Mean of ((pred - obs) / scales)^2 over windows, frames 1..H, robots and entries."""
    return (((pred[:, 1:] - obs[:, 1:]) / scales[None, :, None, :]) ** 2).mean()


def consensus_loss(pred: Tensor, obs: Tensor, scales: Tensor, velocity: slice) -> Tensor:
    """Mean squared error of every robot's velocity relative to its swarm's mean velocity.

    ``pred``, ``obs`` ``[W, H + 1, n, d]``, ``scales [H, d]`` (the window's units), frames 1..H.
    avd, the flocking measure, is the spread of exactly these relative velocities; a common drift
    of the whole swarm (equal for every robot) costs nothing here, while in the plain window loss
    it can outweigh the small disagreements that keep a swarm from flocking.
    """

    def rel(z):
        v = z[:, 1:, :, velocity]  # [W, H, n, m]
        return v - v.mean(dim=2, keepdim=True)

    return (((rel(pred) - rel(obs)) / scales[None, :, None, velocity]) ** 2).mean()


def augment_windows(
    obs: Tensor,
    history: Optional[Tensor],
    dt: float,
    rotate: bool,
    boost_std: float,
    g: Optional[torch.Generator],
) -> Tuple[Tensor, Optional[Tensor]]:
    """flock2d symmetries on whole windows ``[W, F, n, 4]``: one planar rotation per window, and
    one Galilean boost b per window (every velocity + b, positions + b * (time since t0))."""
    W = obs.shape[0]
    if rotate:
        theta = torch.rand(W, generator=g) * (2 * math.pi)
        c, s = torch.cos(theta), torch.sin(theta)
        R = torch.stack([torch.stack([c, -s], -1), torch.stack([s, c], -1)], -2).to(obs.dtype)  # [W, 2, 2]

        def rot(z):
            blocks = z.reshape(z.shape[:-1] + (2, 2))  # [..., block, xy]
            return torch.einsum('wij,wfnkj->wfnki', R, blocks).reshape(z.shape)

        obs = rot(obs)
        history = None if history is None else rot(history)
    if boost_std > 0:
        b = (torch.randn(W, 2, generator=g) * boost_std).to(obs.dtype)

        def boost(z, t):  # t [F] times relative to t0
            shift = torch.cat([b[:, None, :] * t[None, :, None], b[:, None, :].expand(W, len(t), 2)], -1)
            return z + shift[:, :, None, :]

        obs = boost(obs, torch.arange(obs.shape[1], dtype=obs.dtype) * dt)
        if history is not None:
            history = boost(history, torch.arange(-history.shape[1], 0, dtype=obs.dtype) * dt)
    return obs, history


def rollout_windows(
    policy,
    spec: Scenario,
    cfg_policy: Dict[str, Any],
    dt: float,
    obs: Tensor,
    history: Optional[Tensor],
    checkpoint_every: int = 0,
) -> Tensor:
    """Roll ``policy`` out from ``obs[:, 0]`` for ``F - 1`` steps: ``[W, F, n, d]``.

    ``checkpoint_every`` > 0 cuts the rollout into segments of that many steps whose
    activations are recomputed in the backward pass (memory O(segment) instead of O(H)).
    """
    H = obs.shape[1] - 1
    d_cr, k, tau = cfg_policy['d_cr'], cfg_policy['k'], cfg_policy['tau']
    if checkpoint_every <= 0 or checkpoint_every >= H:
        return rollout_torch(policy, obs[:, 0], H, spec, d_cr, k, tau, dt, history)
    from torch.utils.checkpoint import checkpoint

    frames = [obs[:, 0]]
    past = history  # [W, tau, n, d] or None
    t = 0
    while t < H:
        steps = min(checkpoint_every, H - t)

        def segment(z0, hist, steps=steps):
            return rollout_torch(policy, z0, steps, spec, d_cr, k, tau, dt, hist)[:, 1:]

        if tau > 0:
            known = torch.stack(frames, dim=1)
            if past is not None:
                known = torch.cat([past, known], dim=1)
            L = known.shape[1]
            hist = known[:, max(0, L - 1 - tau) : L - 1]  # the tau frames before frames[t]
            if hist.shape[1] < tau:  # clamp at the earliest frame
                hist = torch.cat([known[:, :1].expand(-1, tau - hist.shape[1], -1, -1), hist], dim=1)
            seg = checkpoint(segment, frames[-1], hist, use_reentrant=False)
        else:
            seg = checkpoint(segment, frames[-1], None, use_reentrant=False)
        frames.extend(seg.unbind(1))
        t += steps
    return torch.stack(frames, dim=1)


# What a policy file's state dict does not carry but its module computes with: the knowledge
# form and ranges, and the information network. The starting model must agree on them.
_INIT_MUST_MATCH = ('potential', 'collision', 'collision_d0', 'wall', 'wall_d0', 'k', 'd_cr', 'tau', 'frame')


def _policy_defaults() -> Dict[str, Any]:
    import dataclasses

    from knode_swarm_ros.core.policy import PolicyConfig

    return {
        f.name: f.default for f in dataclasses.fields(PolicyConfig) if f.default is not dataclasses.MISSING
    }


def load_init_state(path: str, policy_cfg: Optional[Dict[str, Any]] = None) -> Dict[str, Tensor]:
    """Parameters of the starting model: a policy file (TorchScript) or a run directory
    (its ``policy.pt``). The module must have the configured architecture, and (given
    ``policy_cfg``) the configured knowledge form and network (``ValueError`` naming the field:
    a paper-potential model fine-tuned as a continuous one would silently change its law)."""
    import os

    from knode_swarm_ros.core import load_policy

    if os.path.isdir(path):
        path = os.path.join(path, 'policy.pt')
    if not os.path.isfile(path):
        raise FileNotFoundError(f'multistep.init {path}: no such policy file')
    loaded = load_policy(path)
    if policy_cfg is not None:
        # a field newer than the file has its default in the file's module (e.g. potential: paper)
        have = {**_policy_defaults(), **loaded.meta.get('config', {})}
        for name in _INIT_MUST_MATCH:
            if name in policy_cfg and have[name] != policy_cfg[name]:
                raise ValueError(f"its policy.{name} is {have[name]!r}, the config's {policy_cfg[name]!r}")
    return {k: v.detach().clone() for k, v in loaded.module.state_dict().items()}


class MultiStepObjective(Objective):
    """Batches and loss of the ``multi_step`` objective over trajectories ``train_states [N, T, n, d]``
    at the policy's ``dt``.

    ``batches(epoch, g)`` returns the window starts of one epoch (batches of
    ``multistep.batch_windows``) at the curriculum's horizon; ``loss(policy, starts, g)`` rolls
    the policy out over each window and returns :func:`window_loss` (plus the weighted
    :func:`consensus_loss`). Training starts from ``multistep.init`` when it is set.
    """

    def __init__(self, cfg: Dict[str, Any], spec: Scenario, dt: float, train_states: np.ndarray):
        self.cfg, self.spec, self.dt = cfg, spec, dt
        self.mc = cfg['multistep']
        self.init = self.mc['init']
        bad = None
        if cfg['data']['drop_saturated']:
            # as the one-step samples: steps whose implied command exceeds the saturation (close
            # pairs at t = 0) cannot be followed by any saturated policy; no window holds one
            v = spec.velocity if spec.command == 'acceleration' else spec.position
            implied = np.abs(np.diff(train_states[..., v], axis=1)) / dt  # [N, T-1, n, m]
            bad = implied.max(axis=(2, 3)) > cfg['policy']['command_limit']
        self.windows = Windows(train_states, cfg['policy']['tau'], bad)
        self.H = self.mc['horizons'][0]

    @classmethod
    def from_data(
        cls, cfg: Dict[str, Any], spec: Scenario, dt: float, data: TrainingData
    ) -> MultiStepObjective:
        if len(data.trajectories) > 1:
            raise ConfigError(
                "training.objective = 'multi_step' takes one --data file (windows roll out "
                "one swarm); mixed sizes train with 'one_step'"
            )
        # windows step at the policy's dt: every phase of the subsampled data is a trajectory
        return cls(cfg, spec, dt, phases(data.trajectories[0], data.ratio))

    def load_init(self, policy: torch.nn.Module) -> None:
        if self.init is None:
            return
        try:
            policy.load_state_dict(load_init_state(self.init, self.cfg['policy']))
        except (OSError, RuntimeError, ValueError) as exc:
            raise ConfigError(f"config field 'multistep.init' = {self.init!r}: {exc}") from None

    def batches(self, epoch: int, g: torch.Generator) -> List[Tensor]:
        self.H = horizon_at(epoch, self.mc['horizons'], self.mc['epochs'])
        starts = self.windows.starts(self.mc['windows_per_epoch'], self.H, g)
        return list(torch.split(starts, self.mc['batch_windows']))

    def loss(self, policy, starts: Tensor, g: Optional[torch.Generator]) -> Tensor:
        obs, history = self.windows.gather(starts, self.H)
        ac = self.cfg['augment']
        if g is not None and (ac['rotate'] or ac['velocity_boost'] > 0):
            obs, history = augment_windows(obs, history, self.dt, ac['rotate'], ac['velocity_boost'], g)
        pred = rollout_windows(
            policy, self.spec, self.cfg['policy'], self.dt, obs, history, self.mc['checkpoint']
        )
        tc = self.cfg['training']
        scales = window_scales(
            self.spec,
            self.dt,
            obs.shape[1] - 1,
            self.mc['units'],
            tc['heading_weight'],
            self.mc['velocity_weight'],
        )
        loss = window_loss(pred, obs, scales)
        cw = self.mc['consensus_weight']
        if cw > 0:  # config: acceleration scenarios only
            loss = loss + cw * consensus_loss(pred, obs, scales, self.spec.velocity)
        return loss
