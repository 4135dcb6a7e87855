"""The agent's unicycle output mode for differential-drive robots (``command_interface: unicycle``).

The policy's planar command (flock2d acceleration) becomes ``cmd_vel`` = (linear.x, angular.z)
through :class:`knode_swarm_ros.core.unicycle.UnicycleMapper` (feedback linearisation about a
point ``unicycle_lookahead`` ahead of the axle; see that module for the method and why), on
``robot_<id>/cmd_vel`` as geometry_msgs/TwistStamped (``unicycle_stamped: true``, default) or
Twist (``false``): Jazzy drivers use both. The heading comes from the own Odometry's
orientation; the velocity of the point ahead from its twist (linear.x in the body frame, as
REP 105 and every differential-drive driver publish it, and angular.z). A stop (stale own
state) brakes to rest within the acceleration limits.

Real time only: a unicycle command pairs with no lockstep step of this project's simulator
(whose robots are double integrators or first-order).
"""
from __future__ import annotations

import math
from typing import Any, Dict, Optional

import numpy as np

from ..core.unicycle import UnicycleLimits, UnicycleMapper, point_ahead
from .common import ConfigError, robot_frame

__all__ = ['AgentUnicycle', 'COMMAND_INTERFACES']

#: ``command_interface`` values: '' (the policy's own: accel or twist), accel, twist, unicycle.
COMMAND_INTERFACES = ('', 'accel', 'twist', 'unicycle')


class AgentUnicycle:
    """Declares the unicycle parameters on ``node``; maps and publishes commands when enabled."""

    def __init__(self, node, robot_id: int, spec, mode: str, control_rate: float, qos_profile):
        from .params import declare  # rclpy: imported with the node only
        interface = declare(node, 'command_interface', '', "command output: empty (the policy's: accel for "
                            'acceleration, twist for velocity policies), accel, twist, or unicycle (differential '
                            'drive: cmd_vel linear.x and angular.z)', choices=COMMAND_INTERFACES)
        stamped = declare(node, 'unicycle_stamped', True, 'unicycle: TwistStamped (true) or Twist (false)')
        lookahead = declare(node, 'unicycle_lookahead', 0.2, 'unicycle: distance of the controlled point ahead '
                            'of the axle (m)', float_range=(1e-6, 1e3))
        limits = {name: declare(node, name, 0.0, f'unicycle: {text} (0: none)', float_range=(0.0, 1e6))
                  for name, text in (('max_linear_speed', '|linear.x| limit, m/s'),
                                     ('max_angular_speed', '|angular.z| limit, rad/s'),
                                     ('max_linear_accel', 'linear acceleration limit, m/s^2'),
                                     ('max_angular_accel', 'angular acceleration limit, rad/s^2'))}
        natural = 'accel' if spec.command == 'acceleration' else 'twist'
        if interface not in ('', natural, 'unicycle'):
            raise ConfigError(f"parameter 'command_interface' = {interface!r} does not fit a {spec.command} "
                              f"policy: use {natural!r} (or empty) or 'unicycle'")
        self.enabled = interface == 'unicycle'
        self.yaw: Optional[float] = None
        self.point_velocity = np.zeros(2)
        if not self.enabled:
            return
        if spec.position_dim != 2:
            raise ConfigError(f"parameter 'command_interface' = 'unicycle' needs a planar scenario, "
                              f'not {spec.name}')
        if mode != 'realtime':
            raise ConfigError("parameter 'command_interface' = 'unicycle' needs mode 'realtime' "
                              f'(got {mode!r}): unicycle commands pair with no lockstep step')
        from geometry_msgs.msg import Twist, TwistStamped
        self.limits = UnicycleLimits(lookahead, **limits)
        try:
            self.mapper = UnicycleMapper(self.limits, spec.command, 1.0 / control_rate)
        except ValueError as exc:
            raise ConfigError(f'parameter {exc}') from None
        self.stamped = bool(stamped)
        self.frame = robot_frame(robot_id)
        self.msg_type = TwistStamped if self.stamped else Twist
        self.publisher = node.create_publisher(self.msg_type, f'robot_{int(robot_id)}/cmd_vel', qos_profile)

    def observe_own(self, pose, linear, angular) -> None:
        """Heading and point-ahead velocity from the own Odometry fields (body-frame twist)."""
        qx, qy, qz, qw = pose[3:7]
        self.yaw = math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
        _, self.point_velocity = point_ahead(0.0, 0.0, self.yaw, float(linear[0]), float(angular[2]),
                                             self.limits.lookahead)

    def publish(self, stamp_msg, command) -> None:
        """Map and publish the agent's command (``command.stop``: brake to rest)."""
        if self.yaw is None:
            return
        if command.stop:
            v, w = self.mapper.stop()
        else:
            v, w = self.mapper(command.value, self.yaw, self.point_velocity)
        self.publish_raw(stamp_msg, v, w)

    def publish_raw(self, stamp_msg, v: float, w: float) -> None:
        """Publish (linear.x, angular.z) = (v, w) as it is."""
        msg = self.msg_type()
        twist = msg.twist if self.stamped else msg
        twist.linear.x, twist.angular.z = float(v), float(w)
        if self.stamped:
            msg.header.stamp = stamp_msg
            msg.header.frame_id = self.frame  # body frame: linear.x and angular.z of the robot itself
        self.publisher.publish(msg)

    def status(self) -> Dict[str, Any]:
        """Counters for the agent status (empty when off)."""
        if not self.enabled:
            return {}
        return {'periods': self.mapper.periods, 'limited': self.mapper.bound, 'last': list(self.mapper.last)}
