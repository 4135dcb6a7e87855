"""Command saturation and the braking stop: one rule for the offline rollout, the agent and the simulator.

docs/DESIGN.md, "ROS 2 interfaces": the applied command is the policy's output clipped per axis at
the policy's ``command_limit`` (when its knode.json has one); an agent parameter may lower the
limit, never raise it. A robot that must stop (stale own state, lost agent) gets zero velocity
(velocity-commanded) or brakes to rest at the saturated deceleration (acceleration-commanded):
zero acceleration would let it coast.

numpy only (no torch, no ROS), so that any runtime (TorchScript, ONNX, a test) can call it.
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np

__all__ = ['effective_limit', 'saturate', 'stop_command', 'velocity_setpoint']


def effective_limit(policy_limit: Optional[float], requested: Optional[float] = None) -> Optional[float]:
    """The per-axis limit that applies: the policy's, lowered by ``requested`` when that is
    tighter; ``requested`` 0 or None means "the policy's". None when neither sets a limit.

    Raises:
        ValueError: a limit that is negative or not finite.
    """
    limits = []
    for name, value in (('policy command_limit', policy_limit), ('requested command_limit', requested)):
        if value is None or value == 0:
            continue
        value = float(value)
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f'{name} must be a finite number > 0, got {value}')
        limits.append(value)
    return min(limits) if limits else None


def saturate(command, limit: Optional[float]) -> np.ndarray:
    """``command [..., m]`` clipped per axis to ``[-limit, limit]`` (a float64 copy; unchanged
    when ``limit`` is None). Non-finite entries are the caller's to handle: NaN stays NaN."""
    u = np.array(command, dtype=np.float64, copy=True)
    if limit is None:
        return u
    return np.clip(u, -float(limit), float(limit), out=u)


def stop_command(command_kind: str, velocity, limit: Optional[float], dt: float) -> np.ndarray:
    """The command ``[..., m]`` of a robot that must stop.

    Args:
        command_kind: ``velocity`` (zero command) or ``acceleration`` (brake).
        velocity: ``[..., m]`` the robot's current velocity (ignored for ``velocity``).
        limit: the per-axis command limit (None: brake in one step).
        dt: the step over which the command is held (zero-order hold).

    For ``acceleration`` the command is ``-v / dt`` saturated per axis: one held step brings
    each axis to rest if the limit allows, otherwise it decelerates at the limit; it never
    reverses the velocity (``|c dt| <= |v|`` on every axis).
    """
    v = np.asarray(velocity, dtype=np.float64)
    if command_kind == 'velocity':
        return np.zeros_like(v)
    if command_kind != 'acceleration':
        raise ValueError(f'unknown command kind {command_kind!r}')
    if not (math.isfinite(dt) and dt > 0):
        raise ValueError(f'dt must be > 0, got {dt}')
    return saturate(-v / float(dt), limit)


def velocity_setpoint(
    velocity, acceleration, period: float, speed_limit: Optional[float] = None
) -> np.ndarray:
    """The velocity setpoint ``[..., m]`` that stands for an acceleration command on a robot whose
    controller takes velocities: ``v_sp = v + u T``, clipped per axis at ``speed_limit`` (None:
    no limit).

    Args:
        velocity: ``[..., m]`` the robot's (estimated) velocity now.
        acceleration: ``[..., m]`` the policy's (saturated) acceleration command.
        period: T, the control period in seconds: the setpoint is where the velocity would be
            after one period of the commanded acceleration, so a velocity loop that tracks it
            within the period reproduces the double integrator.
    """
    v_sp = np.asarray(velocity, dtype=np.float64) + np.asarray(acceleration, dtype=np.float64) * float(period)
    return saturate(v_sp, speed_limit)
