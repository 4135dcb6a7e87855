"""``unicycle`` (flock2d, not with the ground truth): differential-drive bases taking (v, omega).

Every robot is a base of :class:`knode_swarm_ros.core.unicycle.UnicycleRobots`: pose, forward
speed, turn rate, its limits (:data:`LIMIT_PARAMETERS`) enforced by the base as a real one does.
It takes geometry_msgs/TwistStamped on ``robot_<i>/cmd_vel`` (linear.x, angular.z;
``header.stamp`` = the state it answers, so lockstep works); a stop commands (0, 0), which the
base reaches within its acceleration limits. Its Odometry is a differential-drive driver's
(REP 105): the yaw quaternion, twist (v, 0, 0) / (0, 0, omega) in ``robot_<i>/base_link``; the
recorder reads that back as the world velocity v (cos theta, sin theta), so the recording keeps
its flock2d layout. Driven by agents with ``command_interface: unicycle``.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from knode_swarm_ros.core.scenarios import Scenario
from knode_swarm_ros.core.unicycle import UnicycleLimits, UnicycleRobots
from knode_swarm_ros.logic.common import ConfigError
from knode_swarm_ros.logic.contract.rep105 import unicycle_fields

from .base import CommandWire, OdomFields, RobotModel

__all__ = ['UnicycleBases', 'LIMIT_PARAMETERS']

#: The base's limits: parameter -> description (the agent's unicycle limits have the same names).
LIMIT_PARAMETERS = {
    'max_linear_speed': '|forward speed| limit, m/s',
    'max_angular_speed': '|turn rate| limit, rad/s',
    'max_linear_accel': 'forward acceleration limit, m/s^2',
    'max_angular_accel': 'turn acceleration limit, rad/s^2',
}


class UnicycleBases(RobotModel):
    """Differential-drive bases from flock2d states ``z0 [n, 4]`` (heading along the velocity)."""

    summary = 'flock2d: differential-drive bases taking TwistStamped cmd_vel (linear.x, angular.z)'
    scenarios = ('flock2d',)
    ground_truth_refusal = '(the Tanner law commands point masses)'
    parameters = LIMIT_PARAMETERS
    command_interface = 'unicycle'
    wire = CommandWire('velocity', (0, 5))  # linear.x, angular.z

    def __init__(self, spec: Scenario, z0: np.ndarray, **limits: float):
        try:
            self.bases = UnicycleRobots(z0, UnicycleLimits(**limits))
        except ValueError as exc:
            raise ConfigError(f'parameter {exc}') from None

    def states(self) -> np.ndarray:
        return self.bases.states()

    def step(self, command: np.ndarray, dt: float) -> None:
        self.bases.step(command, dt)

    def stop_commands(self, stop_limit: Optional[float], dt: float) -> np.ndarray:
        return np.zeros((self.bases.pose.shape[0], 2))  # the base brakes within its own limits

    def odom_fields(self, robot: int) -> OdomFields:
        b = self.bases
        return unicycle_fields(b.pose[robot], b.speed[robot], b.turn[robot])
