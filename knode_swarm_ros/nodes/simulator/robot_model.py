"""The simulator's robot model (parameter ``robot_model``): point masses or differential-drive bases.

* ``double_integrator`` (default): the scenario's own robots, commanded on ``robot_<i>/cmd_accel``
  (flock2d) or ``robot_<i>/cmd_vel`` (boids3d) as docs/DESIGN.md says.
* ``unicycle`` (flock2d only, no ground truth): every robot is a differential-drive base
  (:class:`knode_swarm_ros.core.unicycle.UnicycleRobots`: pose, forward speed, turn rate; its
  limits ``max_linear_speed``, ``max_angular_speed``, ``max_linear_accel``, ``max_angular_accel``
  enforced by the base, as a real one does). It takes geometry_msgs/TwistStamped on
  ``robot_<i>/cmd_vel`` (linear.x, angular.z; ``header.stamp`` = the state it answers, as every
  command here, so lockstep works) and publishes REP 105 Odometry: the yaw quaternion, twist
  (v, 0, 0) / (0, 0, omega) in ``robot_<i>/base_link``. The recorder reads that back as the world
  velocity v (cos theta, sin theta), so the recording keeps its flock2d layout.

ROS-free but for :func:`declare_robot_model` (parameters) and :func:`command_subscription`.
"""

from __future__ import annotations

from typing import Dict, Optional, Tuple

import numpy as np

from knode_swarm_ros.core.unicycle import UnicycleLimits, UnicycleRobots
from knode_swarm_ros.logic.common import ConfigError
from knode_swarm_ros.logic.contract.rep105 import unicycle_fields

__all__ = [
    'ROBOT_MODELS',
    'LIMIT_PARAMETERS',
    'make_robot_model',
    'declare_robot_model',
    'unicycle_odom_fields',
    'command_subscription',
]

ROBOT_MODELS = ('double_integrator', 'unicycle')

#: The base's limits: parameter -> description (the agent's unicycle limits have the same names).
LIMIT_PARAMETERS = {
    'max_linear_speed': '|forward speed| limit, m/s',
    'max_angular_speed': '|turn rate| limit, rad/s',
    'max_linear_accel': 'forward acceleration limit, m/s^2',
    'max_angular_accel': 'turn acceleration limit, rad/s^2',
}


def make_robot_model(
    model: str, scenario: str, z0: np.ndarray, ground_truth: bool, limits: Optional[dict] = None
) -> Optional[UnicycleRobots]:
    """None for ``double_integrator``; the unicycle bases from ``z0 [n, 4]`` for ``unicycle``.

    Raises:
        ConfigError: unknown model, a unicycle with boids3d or ground truth, a bad limit.
    """
    if model not in ROBOT_MODELS:
        raise ConfigError(f"parameter 'robot_model' = {model!r} is not one of {', '.join(ROBOT_MODELS)}")
    if model == 'double_integrator':
        return None
    if scenario != 'flock2d':
        raise ConfigError(f"parameter 'robot_model' = 'unicycle' needs scenario flock2d, not {scenario}")
    if ground_truth:
        raise ConfigError(
            "parameter 'robot_model' = 'unicycle' cannot be driven by the ground truth "
            '(the Tanner law commands point masses)'
        )
    lim = UnicycleLimits(**(limits or {}))
    try:
        return UnicycleRobots(z0, lim)
    except ValueError as exc:
        raise ConfigError(f'parameter {exc}') from None


def declare_robot_model(node) -> Tuple[str, Dict[str, float]]:
    """Declare ``robot_model`` and the base's limits on ``node``; returns (model, limits) for
    :func:`make_robot_model`."""
    from knode_swarm_ros.nodes.common.params import declare

    model = declare(
        node,
        'robot_model',
        'double_integrator',
        "double_integrator (the scenario's point "
        'masses) or unicycle (flock2d: differential-drive bases taking TwistStamped cmd_vel)',
        choices=ROBOT_MODELS,
    )
    limits = {
        name: declare(node, name, 0.0, f'unicycle base: {text} (0: none)', float_range=(0.0, 1e6))
        for name, text in LIMIT_PARAMETERS.items()
    }
    return model, limits


def unicycle_odom_fields(robots: UnicycleRobots, r: int):
    """Odometry fields of base ``r`` (see :func:`.odom_mapping.unicycle_fields`)."""
    return unicycle_fields(robots.pose[r], robots.speed[r], robots.turn[r])


def command_subscription(node, robots: int, callback, qos_profile):
    """Subscribe to every base's ``robot_<i>/cmd_vel`` (TwistStamped); ``callback(robot, stamp_ns,
    u [2] = (linear.x, angular.z))``."""
    from functools import partial

    from geometry_msgs.msg import TwistStamped

    from knode_swarm_ros.nodes.common.conversions import time_ns

    def on_twist(robot: int, msg) -> None:
        callback(robot, time_ns(msg.header.stamp), np.array([msg.twist.linear.x, msg.twist.angular.z]))

    return [
        node.create_subscription(TwistStamped, f'robot_{r}/cmd_vel', partial(on_twist, r), qos_profile)
        for r in range(robots)
    ]
