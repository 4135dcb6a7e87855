"""The agent's unicycle output mode for differential-drive robots (``command_interface: unicycle``).

The policy's planar command (flock2d acceleration) becomes ``cmd_vel`` = (linear.x, angular.z)
through :class:`knode_swarm_ros.core.unicycle.UnicycleMapper` (feedback linearisation about a
point ``unicycle_lookahead`` ahead of the axle; see that module for the method and why), on
``robot_<id>/cmd_vel`` as geometry_msgs/TwistStamped (``unicycle_stamped: true``, default) or
Twist (``false``): Jazzy drivers use both. With a fleet the topic and the frame are the fleet's
(``command.topic``, ``<name>/base_link``); a fleet whose ``command.interface`` is ``unicycle``
turns this output on and its ``command.type`` chooses TwistStamped or Twist. The heading comes from the own Odometry's
orientation; the velocity of the point ahead from its twist (linear.x in the body frame, as
REP 105 and every differential-drive driver publish it, and angular.z). A stop (stale own
state) brakes to rest within the acceleration limits.

What the policy sees (``unicycle_state``): ``point`` (default) the position and velocity of
every robot's point ahead (own and neighbours, from their Odometry: all robots are taken to be
unicycles with the same lookahead), so that the closed loop is the policy's double-integrator
swarm while no limit binds; ``axle`` the Odometry as it is (the axle centres), which measured
far worse (docs/ros.md, "Differential-drive robots").

Lockstep works with TwistStamped (the stamp says which state a command answers; the simulator's
``robot_model: unicycle``); then the control period is the policy's dt.
"""

from __future__ import annotations

from typing import Any, Dict, Optional

import numpy as np

from knode_swarm_ros.core.unicycle import UnicycleLimits, UnicycleMapper
from knode_swarm_ros.logic.common import ConfigError, robot_frame
from knode_swarm_ros.logic.contract.rep105 import fields_to_point_state, rotate_inverse, yaw_of

__all__ = ['AgentUnicycle', 'COMMAND_INTERFACES', 'UNICYCLE_STATES']

#: ``command_interface`` values: '' (the policy's own: accel or twist), accel, twist, unicycle.
COMMAND_INTERFACES = ('', 'accel', 'twist', 'unicycle')
#: ``unicycle_state`` values: what the policy sees of each robot.
UNICYCLE_STATES = ('point', 'axle')


class AgentUnicycle:
    """Declares the unicycle parameters on ``node``; maps and publishes commands when enabled."""

    def __init__(
        self,
        node,
        robot_id: int,
        spec,
        mode: str,
        control_rate: float,
        qos_profile,
        twist_frame: str = 'body',
        fleet=None,
    ):
        from knode_swarm_ros.nodes.common.params import declare  # rclpy: imported with the node only

        interface = declare(
            node,
            'command_interface',
            '',
            "command output: empty (the policy's: accel for "
            'acceleration, twist for velocity policies), accel, twist, or unicycle (differential '
            'drive: cmd_vel linear.x and angular.z)',
            choices=COMMAND_INTERFACES,
        )
        stamped = declare(node, 'unicycle_stamped', True, 'unicycle: TwistStamped (true) or Twist (false)')
        lookahead = declare(
            node,
            'unicycle_lookahead',
            0.2,
            'unicycle: distance of the controlled point ahead of the axle (m)',
            float_range=(1e-6, 1e3),
        )
        state = declare(
            node,
            'unicycle_state',
            'point',
            'unicycle: what the policy sees of every robot: point '
            '(its point ahead; all robots unicycles with this lookahead) or axle (the Odometry as is)',
            choices=UNICYCLE_STATES,
        )
        limits = {
            name: declare(node, name, 0.0, f'unicycle: {text} (0: none)', float_range=(0.0, 1e6))
            for name, text in (
                ('max_linear_speed', '|linear.x| limit, m/s'),
                ('max_angular_speed', '|angular.z| limit, rad/s'),
                ('max_linear_accel', 'linear acceleration limit, m/s^2'),
                ('max_angular_accel', 'angular acceleration limit, rad/s^2'),
            )
        }
        natural = 'accel' if spec.command == 'acceleration' else 'twist'
        by_fleet = fleet is not None and fleet.command.interface == 'unicycle'
        if by_fleet and interface not in ('', 'unicycle'):
            raise ConfigError(
                f"parameter 'command_interface' = {interface!r}, but the fleet {fleet.path} says "
                'interface unicycle: drop the parameter or change the fleet'
            )
        interface = 'unicycle' if by_fleet else interface
        if interface not in ('', natural, 'unicycle'):
            raise ConfigError(
                f"parameter 'command_interface' = {interface!r} does not fit a {spec.command} "
                f"policy: use {natural!r} (or empty) or 'unicycle'"
            )
        self.enabled = interface == 'unicycle'
        self.yaw: Optional[float] = None
        self.turn = 0.0
        self.point_velocity = np.zeros(2)
        self.point = state == 'point'
        self._answered = (-1, (0.0, 0.0))  # (state stamp, twist) of the last mapped command
        self.lockstep = mode != 'realtime'
        self.twist_frame = twist_frame
        if not self.enabled:
            return
        if spec.position_dim != 2:
            raise ConfigError(
                f"parameter 'command_interface' = 'unicycle' needs a planar scenario, not {spec.name}"
            )
        if mode != 'realtime' and not stamped:
            raise ConfigError(
                "parameter 'command_interface' = 'unicycle' with unicycle_stamped false needs mode "
                f"'realtime' (got {mode!r}): a Twist has no stamp to pair with a lockstep step"
            )
        from geometry_msgs.msg import Twist, TwistStamped

        self.limits = UnicycleLimits(lookahead, **limits)
        try:
            self.mapper = UnicycleMapper(self.limits, spec.command, 1.0 / control_rate)
        except ValueError as exc:
            raise ConfigError(f'parameter {exc}') from None
        self.stamped = bool(stamped)
        topic = f'robot_{int(robot_id)}/cmd_vel'
        self.frame = robot_frame(robot_id)
        if fleet is not None:  # the fleet's names and topic; its message type when it states one
            topic = fleet.command_topic(robot_id, 'velocity')
            self.frame = fleet.frame(robot_id)
            if by_fleet and fleet.command.type is not None:
                self.stamped = fleet.command.type == 'twist_stamped'
        self.msg_type = TwistStamped if self.stamped else Twist
        self.publisher = node.create_publisher(self.msg_type, topic, qos_profile)

    def observe(self, own: bool, pose, linear, angular, z: np.ndarray) -> np.ndarray:
        """The state ``[4]`` the policy sees of a robot, from its Odometry fields (pose [7], twist
        linear [3], angular [3]) and their decoding ``z``; notes heading, turn rate and the point
        ahead's velocity of the own robot (``own``)."""
        if self.twist_frame == 'world':  # a driver that deviates from REP 105: into the body frame first
            linear = rotate_inverse(pose[3:7], linear)
        point = fields_to_point_state(pose[:3], pose[3:7], linear, angular, self.limits.lookahead)
        if own:
            self.yaw, self.turn, self.point_velocity = yaw_of(pose[3:7]), float(angular[2]), point[2:]
            if (
                self.mapper.periods == 0
            ):  # a robot already moving: its acceleration limits start from its motion
                self.mapper.last = (float(linear[0]), float(angular[2]))
        return point if self.point else z

    def publish(self, stamp_msg, command) -> None:
        """Map and publish the agent's command (``command.stop``: brake to rest)."""
        if self.yaw is None:
            return
        if command.stop:
            v, w = self.mapper.stop()
        elif (
            self.lockstep and command.stamp_ns == self._answered[0]
        ):  # a resend: the same twist, ramp not advanced
            v, w = self._answered[1]
        else:
            v, w = self.mapper(command.value, self.yaw, self.point_velocity, self.turn)
            self._answered = (command.stamp_ns, (v, w))
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
