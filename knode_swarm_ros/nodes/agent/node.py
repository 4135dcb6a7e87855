"""The ``agent`` executable: one robot's learnt controller as a ROS 2 node.

``ros2 run knode_swarm_ros agent --ros-args -p id:=3 --params-file config/agent_flock2d.yaml``
``ros2 run knode_swarm_ros agent --ros-args -p fleet:=fleet.yaml -p name:=cf231``

With a fleet file the topics, names and message types are the fleet's (docs/ros.md, "Your own
fleet"): ``Fleet.state_topic`` / ``command_topic`` / ``status_topic`` below stand for the
``robot_<id>/...`` names of the default fleet.

Subscribes to every robot's ``robot_<j>/odom`` (its own included), publishes
``robot_<id>/cmd_accel`` (flock2d, AccelStamped) or ``robot_<id>/cmd_vel`` (boids3d,
TwistStamped) stamped with the own state's stamp, and ``robot_<id>/agent_status`` (JSON:
readiness and counters). All buffering and maths live in :class:`AgentLogic`; this node only
declares parameters, converts messages and keeps time. The node is called ``agent_<id>`` when
``-p id:=N`` is on the command line.
"""

from __future__ import annotations

import sys
import time

import numpy as np
from rclpy.clock import Clock, ClockType
from rclpy.lifecycle import LifecycleNode
from std_msgs.msg import String

from knode_swarm_ros.logic.agent.agent_logic import DROP_REASONS, AgentLogic
from knode_swarm_ros.logic.agent.realtime_tick import GraceArm
from knode_swarm_ros.logic.agent.setpoint import SetpointOutput
from knode_swarm_ros.logic.common import ConfigError, status_json
from knode_swarm_ros.logic.reporting import LOG_EVERY_S as _LOG_EVERY_S
from knode_swarm_ros.logic.reporting import Throttle, throttled_log, write_json_report
from knode_swarm_ros.nodes.common import qos
from knode_swarm_ros.nodes.common.conversions import (
    COMMAND_MESSAGES,
    CdrError,
    command_to_cdr,
    odom_fields_from_cdr,
    time_msg,
    twist_to_cdr,
)
from knode_swarm_ros.nodes.common.executor import run_node
from knode_swarm_ros.nodes.common.params import check_overrides, declare, node_name_from_args
from knode_swarm_ros.nodes.common.state_inbox import StateInbox

from .health import AgentHealth
from .link import AgentLink
from .managed import ManagedAgentMixin
from .params import declare_agent_parameters
from .plumbing import StateDecoder, control_timers, load_agent_policy, missing_names, warm_up_inputs
from .unicycle import AgentUnicycle

__all__ = ['AgentNode', 'main']

_EXPLAIN = {
    'malformed': 'that could not be decoded as nav_msgs/Odometry',
    'unknown_id': 'from a robot that is not part of the swarm',
    'bad_size': 'of the wrong size',
    'non_finite': 'with non-finite values',
    'too_old': 'older than state_timeout',
    'too_future': 'stamped further ahead of the clock than future_tolerance',
}

#: While a tick waits for its neighbours' states in the inbox: how often it is taken (wall s).
INBOX_POLL_S = 0.005

#: How long after the first robot is heard a robot never heard is named (s).
MISSING_AFTER_S = 5.0


class AgentNode(ManagedAgentMixin, LifecycleNode):
    """Thin ROS wrapper around :class:`AgentLogic` (see the module doc and docs/ros.md); a
    lifecycle node (:mod:`.agent_lifecycle`) that configures and activates itself unless managed."""

    def __init__(self, node_name: str = 'agent', **kwargs):
        super().__init__(node_name, **kwargs)
        self.managed = declare(
            self,
            'managed',
            False,
            'true: wait for the lifecycle services (configure, then '
            'activate); false: configure and activate at start',
        )
        if not self.managed:
            self._setup()  # errors propagate: exit status 2 with the message
            self.configured = True
            self.trigger_configure()
            self.trigger_activate()

    def _setup(self) -> None:
        """Parameters, policy (loaded, checked, warmed up), subscriptions, timers: configure."""
        robot_id = declare(self, 'id', -1, "this robot's id (robot_<id>/...)", int_range=(-1, 1_000_000))
        name = declare(self, 'name', '', "this robot's name in the fleet file (instead of 'id')")
        p = declare_agent_parameters(self)  # the same for the hosting ``agents`` node
        fleet = p.swarm_fleet()
        robot_id = own_id(fleet, robot_id, name, bool(p.fleet_file))
        mode, control_rate, state_timeout = p.mode, p.control_rate, p.state_timeout
        self.twist_frame = p.twist_frame
        self.link = AgentLink(self, robot_id, mode)  # link model (loss, delay, range): off by default
        self.report_path = declare(
            self, 'report', '', 'write counters as JSON to this file at exit (empty: no)'
        )
        check_overrides(self, sys.argv)

        ids = p.ids
        config = p.config(robot_id)
        config.validate()

        policy = load_agent_policy(p.policy, *p.policy_args())
        self.logic = AgentLogic(config, policy)
        self.spec = self.logic.spec
        fleet.check_scenario(self.spec.command, self.spec.velocity is not None)
        self.fleet = fleet
        self.states = StateDecoder(fleet, self.spec, self.twist_frame, policy.dt, own=[robot_id])
        self._own_z = None  # the newest own state heard (a velocity setpoint starts from its velocity)
        self.setpoint = (
            SetpointOutput(
                1.0 / control_rate if mode == 'realtime' and control_rate > 0 else policy.dt,
                fleet.command.speed_limit,
            )
            if fleet.command.interface == 'velocity_setpoint'
            else None
        )
        self._warm_up()
        self.unicycle = AgentUnicycle(
            self,
            robot_id,
            self.spec,
            mode,  # off by default; lockstep: period dt
            control_rate if mode == 'realtime' else 1.0 / policy.dt,
            qos.COMMAND,
            self.twist_frame,
            fleet=fleet,
        )
        self.health = AgentHealth(
            self, robot_id, state_timeout, qos.DIAGNOSTICS, fleet.name_of
        )  # /diagnostics

        self.mode = mode
        self._wall = Clock(clock_type=ClockType.STEADY_TIME)
        self._drops = {reason: [0, 0.0, ''] for reason in DROP_REASONS}  # count since log, last log, detail
        self._log_throttle = Throttle()
        self._announced_ready = False

        if self.unicycle.enabled and fleet.state.type != 'odometry':
            raise ConfigError(
                f"parameter 'command_interface' = 'unicycle' reads the Odometry twist, but the fleet "
                f'{fleet.path} gives poses (state type {fleet.state.type})'
            )
        self.command_type = fleet.command_type(self.spec.command)
        self.cmd_pub = self.create_publisher(
            COMMAND_MESSAGES[self.command_type], fleet.command_topic(robot_id, self.spec.command), qos.COMMAND
        )
        self.status_pub = self.create_publisher(String, fleet.status_topic(robot_id), qos.STATUS)
        # A realtime pose stream (motion capture, faster than the policy): the neighbours' poses
        # are taken when the agent wakes anyway (its own pose, its timers), not one by one.
        poses_in_realtime = fleet.state.type == 'pose' and mode == 'realtime'
        inboxed = [i for i in ids if i != robot_id] if poses_in_realtime else []
        stream = qos.POSE_STREAM if poses_in_realtime else qos.ODOM
        self.odom_subs = self.states.subscribe(
            self, [i for i in ids if i not in inboxed], self._on_odom, stream
        )
        self.inbox = (
            StateInbox(
                self.context,
                fleet,
                stream.depth,
                name=f'{self.get_name()}_inbox',
                ids=inboxed,
                qos_profile=stream,
                namespace=self.get_namespace(),
            )
            if inboxed
            else None
        )
        self._missing_since = None  # when the swarm was first heard (monotonic s)
        self.on_state = (
            self.logic.ticks is not None
        )  # realtime: ticks come with the own state (realtime_tick.py)
        self.control_timer, self._grace = control_timers(
            self,
            mode,
            control_rate,
            self.logic.ticks.grace_s if self.on_state else None,
            self._on_tick,
            self._on_grace,
            self._on_lockstep_timer,
            self._wall,
        )
        self.grace_timer = None if self._grace is None else self._grace.timer
        self._inbox_poll = (  # while a tick waits: take the inbox every INBOX_POLL_S
            GraceArm(self.create_timer(INBOX_POLL_S, self._on_inbox_poll, clock=self._wall))
            if self.inbox is not None and self._grace is not None
            else None
        )
        self.status_timer = self.create_timer(p.status_period, self._publish_status, clock=self._wall)
        self.get_logger().info(
            f'robot {robot_id} of {len(ids)} ({self.spec.name}, {mode}): policy {policy.path} on {policy.backend} '
            f'(k={policy.k}, d_cr={policy.d_cr:g}, tau={policy.tau}, dt={policy.dt:g}, '
            f'limit={self.logic.limit}); publishing {self.cmd_pub.topic_name}'
        )
        self._log_events()  # the control-period warning, once, at start
        self._publish_status()

    def _warm_up(self) -> None:
        Y, mask = warm_up_inputs(1, self.logic.k, self.spec.state_dim)
        self.logic.evaluate(Y[0], mask[0])

    # --- callbacks -----------------------------------------------------------------
    def _on_odom(self, topic_robot: int, data: bytes) -> None:
        now = self.get_clock().now().nanoseconds
        self._take_inbox(now)
        self._hear(topic_robot, data, now)
        self._after_hearing(now)

    def _take_inbox(self, now: int) -> None:
        """File what the neighbours' inbox holds (realtime pose fleets: :class:`StateInbox`)."""
        if self.inbox is not None:
            for topic_robot, data in self.inbox.take_raw():
                self._hear(topic_robot, data, now)

    def _on_inbox_poll(self) -> None:
        now = self.get_clock().now().nanoseconds
        self._take_inbox(now)
        self._realtime_poll(now)

    def _hear(self, topic_robot: int, data: bytes, now: int) -> None:
        """Decode and file one message of robot ``topic_robot``'s state topic (no tick polled)."""
        try:
            filed = self.states.filed(topic_robot, data)
        except CdrError as exc:
            self.logic.malformed()
            self._note_drop('malformed', str(exc))
            return
        for robot, stamp, frame, z, step, own in filed:
            if (
                self.unicycle.enabled and robot is not None
            ):  # the policy sees the point ahead (unicycle_state)
                z = self.unicycle.observe(robot == self.logic.me, *odom_fields_from_cdr(data)[2:], z)
            if robot == self.logic.me and np.all(np.isfinite(z)):
                self._own_z = z if own is None else own
                if own is not None and step is not None:
                    self.logic.own_row(step, own)
            if not self._through_link(robot, stamp, z, now):
                continue  # states the link released may complete a waiting tick: polled after
            outcome = self.logic.receive(robot, stamp, z, now, time.monotonic(), step=step)
            if outcome in self._drops:
                detail = (
                    f'child_frame_id {frame!r} on {self.fleet.state_topic(topic_robot)}'
                    if outcome == 'unknown_id'
                    else f'robot {topic_robot} at {stamp * 1e-9:.3f} s (clock {now * 1e-9:.3f} s)'
                )
                self._note_drop(outcome, detail)

    def _after_hearing(self, now: int) -> None:
        if self.mode == 'lockstep':
            self._lockstep_poll()
        elif self.on_state:
            self._realtime_poll(now)
        if not self._announced_ready and self.logic.ready:
            self._announced_ready = True
            self.get_logger().info(f'heard all {len(self.logic.ids)} robots: ready')
            self._publish_status()

    def _lockstep_poll(self) -> None:
        cmd = self.logic.lockstep_poll(time.monotonic())
        if cmd is not None:
            self._publish_command(cmd)
        self._log_events()

    def _on_lockstep_timer(self) -> None:
        self._lockstep_poll()
        self._flush_drops()

    def _through_link(self, robot, stamp: int, z, now: int) -> bool:
        """True: file the state now; False: the link model took it (lost, out of range, or
        filed when its delay has passed, by :meth:`_release_link`)."""
        if not self.link.enabled or robot is None or robot == self.logic.me:
            return True
        latest = self.logic.buffer.latest(self.logic.me)
        self.link.offer(
            now * 1e-9, robot, stamp, z, None if latest is None else latest[1], self.spec.position_dim
        )
        self._release_link(now)
        return False

    def _release_link(self, now: int) -> None:
        # Before the clock runs (0: the simulator waits for every agent to hear every robot) a delay
        # cannot pass: deliver what the link let through, or the swarm would never start.
        for robot, stamp, z in self.link.due(now * 1e-9 if now > 0 else float('inf')):
            self.logic.receive(robot, stamp, z, now, time.monotonic())

    def _realtime_poll(self, now: int) -> None:
        cmd = self.logic.realtime_poll(now, time.monotonic())
        if cmd is not None:
            self._publish_command(cmd)
        waiting = self.logic.ticks.pending is not None
        self._grace.set(waiting)
        if self._inbox_poll is not None:  # the neighbours' states of the tick are not taken on arrival
            self._inbox_poll.set(waiting)

    def _on_grace(self) -> None:
        now = self.get_clock().now().nanoseconds
        self._take_inbox(now)
        self._release_link(now)
        self._realtime_poll(now)

    def _on_tick(self) -> None:
        now = self.get_clock().now().nanoseconds
        self._take_inbox(now)
        self._release_link(now)
        cmd = self.logic.watchdog(now) if self.on_state else self.logic.tick(now)
        if cmd is None:
            # (ticking on the own state, a fresh own state also gives None: its arrival ticks)
            if not (self.on_state and self.logic.me in self.logic.newest_ns):
                self._throttled(
                    'no_state',
                    f'no state of my own yet on {self.fleet.state_topic(self.logic.me)}: no command',
                )
        else:
            if cmd.stop:
                own = self.logic.newest_ns.get(self.logic.me, 0)
                self._throttled(
                    'stale',
                    f'own state is stale ({(now - own) * 1e-9:.3f} s old, timeout '
                    f'{self.logic.config.state_timeout:g} s): publishing a stop command '
                    '(zero velocity, or a brake to rest)',
                    warn=True,
                )
            self._publish_command(cmd)
        self._log_events()
        self._flush_drops()

    def _publish_command(self, cmd) -> None:
        if not self.active:  # managed and not active: only the stop after deactivate, then nothing
            self._brake(cmd.stamp_ns)
            return
        if self.unicycle.enabled:  # differential drive: cmd_vel (linear.x, angular.z)
            self.unicycle.publish(time_msg(cmd.stamp_ns), cmd)
            return
        value = cmd.value
        self.states.command(self.logic.me, cmd.stamp_ns, value)  # the own velocity knows it
        if self.setpoint is not None:  # a velocity loop: v_sp = v_est + u T
            value = self.setpoint.value(cmd, self._own_z[self.spec.velocity])
        # serialized directly (AccelStamped and TwistStamped share one layout)
        if self.command_type == 'twist':
            self.cmd_pub.publish(twist_to_cdr(value))
        else:
            self.cmd_pub.publish(command_to_cdr(cmd.stamp_ns, value, self.spec))

    # --- logging -------------------------------------------------------------------
    def _throttled(self, key: str, text: str, warn: bool = False) -> None:
        throttled_log(self.get_logger(), self._log_throttle, key, text, warn)

    def _note_drop(self, reason: str, detail: str) -> None:
        entry = self._drops[reason]
        entry[0] += 1
        entry[2] = detail
        if time.monotonic() - entry[1] >= _LOG_EVERY_S:
            self._flush_drop(reason)

    def _flush_drops(self) -> None:
        for reason, entry in self._drops.items():
            if entry[0] and time.monotonic() - entry[1] >= _LOG_EVERY_S:
                self._flush_drop(reason)

    def _flush_drop(self, reason: str) -> None:
        entry = self._drops[reason]
        self.get_logger().warning(
            f'dropped {entry[0]} state(s) {_EXPLAIN[reason]} ({reason}; latest: {entry[2]}; '
            f'{self.logic.counters[reason]} in all)'
        )
        entry[0], entry[1] = 0, time.monotonic()

    def _log_events(self) -> None:
        for text in self.logic.drain_events():
            self.get_logger().warning(text)

    def _publish_status(self) -> None:
        self._report_missing()
        status = self._status()
        self.status_pub.publish(String(data=status_json(**status)))
        last = self.logic.last_command
        self.health.publish(
            status,
            self.get_clock().now().nanoseconds,
            self.logic.newest_ns.get(self.logic.me),
            0 if last is None else last.neighbours,
            time.monotonic(),
        )

    def _report_missing(self) -> None:
        """Name, now and then, the fleet's robots never heard (left out of every Y until they are)."""
        missing = self.logic.missing()
        if not missing or len(missing) == len(self.logic.ids):
            return  # nothing heard yet: the swarm is still being discovered, no robot is missing
        if self._missing_since is None:
            self._missing_since = time.monotonic()
        # a robot may start a little later than the others: name it once that is past
        if time.monotonic() - self._missing_since >= max(MISSING_AFTER_S, self.logic.config.state_timeout):
            self._throttled(
                'missing', f'never heard: {missing_names(self.fleet, missing)} (left out of Y)', True
            )

    def _status(self) -> dict:
        status = self.logic.status()
        status['missing_names'] = [self.fleet.name_of(i) for i in status['missing']]
        status['ready'] = bool(status['ready'] and self.active)  # a simulator waits for activation
        status['lifecycle'] = 'active' if self.active else 'inactive'
        if self.link.enabled:
            status['link'] = self.link.status()
        if getattr(self, 'unicycle', None) is not None and self.unicycle.enabled:
            status['unicycle'] = self.unicycle.status()
        return status

    def write_report(self) -> None:
        """Write the counters to the ``report`` file (if set)."""
        if getattr(self, 'report_path', ''):
            write_json_report(self.report_path, self._status())


def own_id(fleet, robot_id: int, name: str, from_file: bool) -> int:
    """This robot's id from the ``id`` / ``name`` parameters (one of them; both must agree).

    Raises:
        ConfigError: neither given, a name not in the fleet, or the two disagree.
    """
    if name:
        named = fleet.robot(name).id
        if robot_id >= 0 and robot_id != named:
            raise ConfigError(
                f"parameter 'id' = {robot_id} but 'name' = {name!r} is robot {named} of the fleet"
            )
        return named
    if robot_id < 0:
        hint = ' or -p name:=NAME' if from_file else ''
        raise ConfigError(f"parameter 'id' is required: pass -p id:=N{hint}")
    return robot_id


def main(args=None):
    """Entry point of the ``agent`` executable."""
    argv = args if args is not None else sys.argv
    run_node('agent', lambda: AgentNode(node_name_from_args(argv, 'agent')), AgentNode.write_report, args)
