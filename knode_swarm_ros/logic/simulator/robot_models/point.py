"""``double_integrator``: the scenario's own point robots (the default robot model).

flock2d robots are double integrators commanded in acceleration (``robot_<i>/cmd_accel``),
boids3d robots move first order at the commanded velocity, heading along it (``robot_<i>/cmd_vel``):
:func:`knode_swarm_ros.core.rollout.zoh_step`, so lockstep equals :func:`core.rollout` bit for bit.
A stop brakes an acceleration-commanded robot to rest at the saturated deceleration and gives a
velocity-commanded one zero velocity (:func:`knode_swarm_ros.core.saturation.stop_command`).
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from knode_swarm_ros.core.rollout import zoh_step
from knode_swarm_ros.core.saturation import stop_command
from knode_swarm_ros.core.scenarios import Scenario
from knode_swarm_ros.logic.contract.rep105 import state_to_fields

from .base import CommandWire, OdomFields, RobotModel

__all__ = ['PointRobots']

_NO_TURN = (0.0, 0.0, 0.0)


class PointRobots(RobotModel):
    """Point robots from ``z0 [n, d]`` stepped by the scenario's own dynamics."""

    summary = "the scenario's point robots on its own command (cmd_accel or cmd_vel)"
    ground_truth = True

    def __init__(self, spec: Scenario, z0: np.ndarray):
        self.spec = spec
        self.z = np.array(z0, dtype=np.float64)
        m = spec.command_dim
        self.wire = CommandWire(spec.command, tuple(range(m)))
        self.applied = np.zeros((self.z.shape[0], m))  # the last command held (boids3d's twist)

    def states(self) -> np.ndarray:
        return self.z

    def step(self, command: np.ndarray, dt: float) -> None:
        self.z = zoh_step(self.z, command, self.spec, dt)
        self.applied = command

    def place(self, states: np.ndarray) -> None:
        self.z = states

    def stop_commands(self, stop_limit: Optional[float], dt: float) -> np.ndarray:
        spec = self.spec
        v = self.z[:, spec.velocity] if spec.command == 'acceleration' else np.zeros_like(self.applied)
        return stop_command(spec.command, v, stop_limit, dt)

    def odom_fields(self, robot: int) -> OdomFields:
        velocity = self.applied[robot] if self.spec.command == 'velocity' else None
        return (*state_to_fields(self.z[robot], self.spec, velocity), _NO_TURN)
