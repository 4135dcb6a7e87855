"""The canonical rollout (docs/DESIGN.md, "Rollout semantics").

At each step every robot builds its neighbour matrix, the policy is evaluated once per
robot, and the command is held over the step (zero-order hold), integrated exactly:

* double integrator (``acceleration``): p += v dt + c dt^2 / 2, v += c dt;
* first order (``velocity``): p += c dt; with a heading in the state (``position_heading``)
  h = c / |c| (h unchanged when c = 0).

Which applies, and in how many dimensions, follows the scenario object (its ``command``, ``state``
and ``dimensions``), never its name.

The simulator node and the parity tests use :func:`zoh_step`; offline evaluation uses
:func:`rollout`, batched over several swarms at once.

Observation: with ``observe='state'`` the robots hear the exact states; with ``observe='pose'``
(a fleet that publishes poses only, motion capture) they hear positions, and a state's velocity
is estimated from each robot's position stream by :class:`core.estimator.VelocityEstimator`,
the estimator the agents run (stamps of step t: ``round(t dt 1e9)`` ns, as the nodes stamp).
"""

from __future__ import annotations

from typing import Any, Callable, Mapping, Optional, Union

import numpy as np

from .estimator import DEFAULT_WINDOW, OWN_WINDOW_FACTOR, CommandAidedEstimator, VelocityEstimator
from .network import neighbour_matrix, neighbour_matrix_torch
from .saturation import saturate
from .scenarios import Scenario, get_scenario

__all__ = [
    'zoh_step',
    'zoh_step_torch',
    'rollout',
    'rollout_torch',
    'policy_commands',
    'PolicyFn',
    'OBSERVATIONS',
    'PoseObserver',
]

#: What the robots hear of each other: exact states, or poses with estimated velocities.
OBSERVATIONS = ('state', 'pose')

# A policy maps Y [B, k, d] and mask [B, k] to commands [B, m] (numpy float64 in and out).
PolicyFn = Callable[[np.ndarray, np.ndarray], np.ndarray]

# A Scenario, a shipped name, a scenario file's path or the scenario's mapping (get_scenario).
ScenarioRef = Union[str, Mapping[str, Any], Scenario]

_POLICY_LIMIT = object()  # rollout's default: the policy's own ``command_limit`` attribute, if any


def zoh_step(states: np.ndarray, command: np.ndarray, scenario: Scenario, dt: float) -> np.ndarray:
    """Advance ``states [..., n, d]`` by one step of ``dt`` under ``command [..., n, m]`` held constant."""
    p = scenario.position
    new = np.array(states, dtype=np.float64, copy=True)
    c = np.asarray(command, dtype=np.float64)
    if scenario.command == 'acceleration':
        v = new[..., scenario.velocity]
        new[..., p] = new[..., p] + v * dt + 0.5 * c * dt * dt
        new[..., scenario.velocity] = v + c * dt
    else:
        new[..., p] = new[..., p] + c * dt
        if scenario.heading is None:
            return new
        speed = np.linalg.norm(c, axis=-1, keepdims=True)
        moving = speed > 0
        heading = np.divide(c, speed, out=np.zeros_like(c), where=moving)
        new[..., scenario.heading] = np.where(moving, heading, new[..., scenario.heading])
    return new


def zoh_step_torch(z, command, scenario: Scenario, dt: float):
    """:func:`zoh_step` for torch tensors ``z [..., d]``, ``command [..., m]``, differentiable
    (training's one-step-ahead prediction integrates exactly what deployment does)."""
    import torch

    p = scenario.position_dim
    if scenario.command == 'acceleration':
        v = z[..., p:]
        return torch.cat([z[..., :p] + v * dt + 0.5 * command * dt * dt, v + command * dt], dim=-1)
    if scenario.heading is None:
        return z[..., :p] + command * dt
    return torch.cat([z[..., :p] + command * dt, heading_torch(command, z[..., p:])], dim=-1)


def heading_torch(c, fallback):
    """Unit vector ``c / |c|`` ``[..., m]``, ``fallback`` where ``c`` is zero."""
    import torch

    speed = torch.linalg.vector_norm(c, dim=-1, keepdim=True)
    return torch.where(speed > 0, c / speed.clamp(min=1e-12), fallback)


def policy_commands(
    policy: PolicyFn,
    z_now: np.ndarray,
    z_delayed: np.ndarray,
    scenario: Scenario,
    d_cr: float,
    k: int,
    command_limit: Optional[float] = None,
) -> np.ndarray:
    """Commands ``[..., n, m]`` of every robot: neighbour matrices, then one batched policy call,
    saturated per axis at ``command_limit`` (:func:`core.saturation.saturate`, the agent's rule)."""
    Y, mask = neighbour_matrix(z_now, z_delayed, scenario.position_dim, d_cr, k)
    lead = Y.shape[:-2]
    out = policy(Y.reshape((-1,) + Y.shape[-2:]), mask.reshape((-1, mask.shape[-1])))
    out = saturate(np.asarray(out, dtype=np.float64), command_limit)
    return out.reshape(lead + (scenario.command_dim,))


class PoseObserver:
    """States as heard from poses: the position exact, the velocity (when the state has one)
    estimated from the positions heard so far; without a velocity the state is the pose itself.

    ``observe(stamp_ns, z [..., n, d])`` -> the heard states ``[..., n, d]`` (float64 copy).
    ``own(heard)``: each robot's own row, its velocity from its poses and its own commands
    (``command(stamp_ns, u [..., n, m])``, :class:`.estimator.CommandAidedEstimator`) when the
    scenario commands accelerations, as an agent's own row; else ``heard`` itself.
    """

    def __init__(self, scenario: Scenario, window: int = DEFAULT_WINDOW):
        self.spec = scenario
        self.estimator = VelocityEstimator(window) if scenario.velocity is not None else None
        aided = self.estimator is not None and scenario.command == 'acceleration'
        self.aided = CommandAidedEstimator(OWN_WINDOW_FACTOR * int(window)) if aided else None

    def observe(self, stamp_ns: int, z: np.ndarray) -> np.ndarray:
        heard = np.array(z, dtype=np.float64, copy=True)
        if self.estimator is not None:
            p = heard[..., self.spec.position]
            heard[..., self.spec.velocity] = self.estimator.update(stamp_ns, p)
            if self.aided is not None:
                self.aided.push(stamp_ns, p)
        return heard

    def own(self, heard: np.ndarray) -> np.ndarray:
        if self.aided is None:
            return heard
        own = np.array(heard, dtype=np.float64, copy=True)
        own[..., self.spec.velocity] = self.aided.velocity
        return own

    def command(self, stamp_ns: int, u: np.ndarray) -> None:
        if self.aided is not None:
            self.aided.command(stamp_ns, u)


def rollout(
    policy: PolicyFn,
    z0: np.ndarray,
    steps: int,
    scenario: ScenarioRef,
    d_cr: float,
    k: int,
    tau: int,
    dt: float,
    progress: Optional[Callable[[int], None]] = None,
    command_limit=_POLICY_LIMIT,
    observe: str = 'state',
    velocity_window: int = DEFAULT_WINDOW,
) -> np.ndarray:
    """Roll a policy out from initial states.

    Args:
        policy: ``(Y [B, k, d], mask [B, k]) -> [B, m]``, e.g. a :class:`LoadedPolicy`.
        z0: ``[n, d]`` or ``[S, n, d]`` initial states of one or S swarms (any n).
        steps: number of steps; the result holds ``steps + 1`` frames, frame 0 = z0.
        scenario: a :class:`Scenario` or any reference :func:`get_scenario` resolves.
        tau: delay in steps; before t - tau exists the earliest frame is used.
        progress: optional callback called with the step index after each step.
        command_limit: per-axis saturation of every command (None: none); by default the
            policy's ``command_limit`` attribute (a :class:`LoadedPolicy` has its knode.json
            value), so the offline rollout applies exactly what an agent applies.
        observe: ``state`` (exact states heard) or ``pose`` (velocities estimated from the
            positions, window ``velocity_window`` samples: :class:`PoseObserver`).

    Returns:
        float64 ``[S, steps + 1, n, d]`` (``[steps + 1, n, d]`` for a single ``[n, d]`` input).
    """
    spec = get_scenario(scenario)
    z0 = np.asarray(z0, dtype=np.float64)
    single = z0.ndim == 2
    if single:
        z0 = z0[None]
    if z0.ndim != 3 or z0.shape[-1] != spec.state_dim:
        raise ValueError(f'z0 must be [n, {spec.state_dim}] or [S, n, {spec.state_dim}], got {z0.shape}')
    if steps < 0:
        raise ValueError(f'steps must be >= 0, got {steps}')
    if observe not in OBSERVATIONS:
        raise ValueError(f'observe must be one of {", ".join(OBSERVATIONS)}, got {observe!r}')
    if command_limit is _POLICY_LIMIT:
        command_limit = getattr(policy, 'command_limit', None)
    out = np.empty((z0.shape[0], steps + 1) + z0.shape[1:], dtype=np.float64)
    out[:, 0] = z0
    heard = out  # exact states; with poses, the estimates (frame t is filled at step t)
    if observe == 'pose':
        observer = PoseObserver(spec, velocity_window)
        heard = np.empty_like(out)
    for t in range(steps):
        stamp = int(round(t * float(dt) * 1e9))
        own = heard[:, t]
        if observe == 'pose':
            heard[:, t] = observer.observe(stamp, out[:, t])
            own = observer.own(heard[:, t])  # each robot's own row: its command-aided velocity
        z_delayed = heard[:, max(t - tau, 0)]
        command = policy_commands(policy, own, z_delayed, spec, d_cr, k, command_limit)
        if observe == 'pose':
            observer.command(stamp, command)
        out[:, t + 1] = zoh_step(out[:, t], command, spec, dt)
        if progress is not None:
            progress(t)
    return out[0] if single else out


def rollout_torch(
    policy, z0, steps: int, scenario: ScenarioRef, d_cr: float, k: int, tau: int, dt: float, history=None
):
    """:func:`rollout` for torch, differentiable: training through the deployment semantics.

    Every step rebuilds each robot's neighbour matrix from the rolled-out states themselves
    (delayed by ``tau``, as a robot would hear them), evaluates ``policy`` once on all rows and
    integrates the zero-order hold with :func:`zoh_step_torch`.

    Args:
        policy: ``(Y [B, k, d], mask [B, k]) -> [B, m]`` torch callable (a KNODEPolicy).
        z0: ``[S, n, d]`` initial states (one window per swarm).
        history: optional ``[S, tau, n, d]`` states of the ``tau`` frames before ``z0`` (oldest
            first): what the robots heard before the window. Without it, the earliest frame
            (``z0``) stands in, as in :func:`rollout` from frame 0.

    Returns:
        ``[S, steps + 1, n, d]``; frame 0 is ``z0``.
    """
    import torch

    spec = get_scenario(scenario)
    if z0.dim() != 3 or z0.shape[-1] != spec.state_dim:
        raise ValueError(f'z0 must be [S, n, {spec.state_dim}], got {tuple(z0.shape)}')
    if history is not None and (history.dim() != 4 or history.shape[1] != tau):
        raise ValueError(f'history must be [S, tau={tau}, n, d], got {tuple(history.shape)}')
    frames = [z0]
    for t in range(steps):
        j = t - tau
        z_delayed = frames[j] if j >= 0 else (history[:, j] if history is not None else frames[0])
        Y, mask = neighbour_matrix_torch(frames[t], z_delayed, spec.position_dim, d_cr, k)
        S, n = Y.shape[:2]
        command = policy(Y.reshape(S * n, k, -1), mask.reshape(S * n, k)).reshape(S, n, -1)
        frames.append(zoh_step_torch(frames[t], command, spec, dt))
    return torch.stack(frames, dim=1)
