"""The ``agents`` executable: several robots' learnt controllers in one ROS 2 process.

``python -m knode_swarm_ros.nodes.agents --ros-args -p ids:=0..49 -p robots:=100 ...``
(``ids`` a list ``[0, 1, 5]`` or a range ``'0..49'``; the other parameters are the ``agent``'s).

For simulating large swarms on one machine; a real robot runs the lone ``agent``. Each hosted
robot runs the same :class:`AgentLogic` as a lone agent (:class:`HostedAgents`): its own
lockstep bookkeeping, neighbour matrix, counters, ``robot_<id>/cmd_*`` and
``robot_<id>/agent_status`` topics, and only what its robot hears. Shared plumbing: one raw
subscription per robot's ``robot_<j>/odom``, each state decoded, checked and filed once in the
process's :class:`knode_swarm_ros.logic.agent.hearing.Hearing` (what each hosted robot would
have filed alike), one executor, one policy module, one batched policy call per tick. The node
is called ``agents_<first>_<last>``.

Parameters: the lone agent's, declared by the same code (:mod:`knode_swarm_ros.nodes.agent.params`),
with ``ids`` instead of ``id``. Not offered, refused at start with exit status 2
(:func:`refuse_per_robot_options`): the link model (``link_*``), ``managed: true`` and
``command_interface: unicycle``.
"""

from __future__ import annotations

import sys
import time

from rcl_interfaces.msg import ParameterDescriptor
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from std_msgs.msg import String

from knode_swarm_ros.core.yaml_file import load_yaml
from knode_swarm_ros.logic.agent.agent_logic import DROP_REASONS
from knode_swarm_ros.logic.agent.hosted import HostedAgents, format_ids, parse_ids
from knode_swarm_ros.logic.common import ConfigError, status_json
from knode_swarm_ros.logic.reporting import Throttle, write_json_report
from knode_swarm_ros.nodes.agent.health import HostedHealth
from knode_swarm_ros.nodes.agent.params import declare_agent_parameters
from knode_swarm_ros.nodes.agent.plumbing import (
    StateDecoder,
    control_timers,
    load_agent_policy,
    missing_names,
    warm_up_inputs,
)
from knode_swarm_ros.nodes.common import qos
from knode_swarm_ros.nodes.common.conversions import COMMAND_MESSAGES, CdrError, command_to_cdr, string_to_cdr
from knode_swarm_ros.nodes.common.executor import run_node
from knode_swarm_ros.nodes.common.params import check_overrides, declare

__all__ = ['AgentsNode', 'main', 'node_name_for', 'refuse_per_robot_options']


def node_name_for(argv) -> str:
    """``agents_<first>_<last>`` from ``-p ids:=...`` on the command line, else ``agents``."""
    items = list(argv or [])
    for flag, value in zip(items, items[1:]):
        if flag in ('-p', '--param') and value.startswith('ids:='):
            try:
                import yaml

                ids = parse_ids(load_yaml(value[len('ids:=') :]))
            except (ConfigError, ValueError, ImportError, yaml.YAMLError):
                return 'agents'
            return f'agents_{ids[0]}_{ids[-1]}'
    return 'agents'


def refuse_per_robot_options(node, robot_id: int, p, spec) -> None:
    """Declare the lone agent's options that a hosting process does not offer (the same
    parameters, by the same modules) and refuse any that is switched on with a
    :class:`ConfigError` naming it (exit status 2):

    * ``link_*`` (the link model): each robot would hear through its own lossy link, while the
      robots of a process share what they hear (:mod:`knode_swarm_ros.logic.agent.hearing`);
    * ``managed: true``: a lifecycle is one robot's (configure, activate, brake to rest);
    * ``command_interface: unicycle``: a differential-drive robot is a real robot: run its ``agent``.
    """
    from knode_swarm_ros.nodes.agent.link import AgentLink
    from knode_swarm_ros.nodes.agent.unicycle import AgentUnicycle

    lone = 'run one agent process per robot (agent, or swarm --agents-per-process 1)'
    if AgentLink(node, robot_id, p.mode).enabled:
        raise ConfigError(
            f"parameters 'link_*' (the link model) are not offered by the agents node: its robots "
            f'share what they hear; {lone}'
        )
    if declare(
        node, 'managed', False, "not offered by the agents node (a lifecycle is one robot's): must be false"
    ):
        raise ConfigError(f"parameter 'managed' = true: the agents node is not a lifecycle node; {lone}")
    if AgentUnicycle(node, robot_id, spec, p.mode, p.control_rate, qos.COMMAND).enabled:
        raise ConfigError(
            f"parameter 'command_interface' = 'unicycle' is not offered by the agents node; {lone}"
        )


class AgentsNode(Node):
    """Thin ROS wrapper around :class:`HostedAgents` (see the module doc and docs/ros.md)."""

    def __init__(self, node_name: str = 'agents', **kwargs):
        super().__init__(node_name, **kwargs)
        descriptor = ParameterDescriptor(
            description="the hosted robots' ids: a list [0, 1, 5] or a range '0..49'",
            dynamic_typing=True,
            read_only=True,
        )
        raw_ids = self.declare_parameter('ids', '', descriptor).value
        if raw_ids in ('', None):
            raise ConfigError("parameter 'ids' is required: pass -p ids:=[0,1,2] or -p ids:=0..49")
        hosted = parse_ids(raw_ids)
        p = declare_agent_parameters(self)  # the lone agent's parameters: one declaration for both
        self.report_path = declare(
            self, 'report', '', "write every hosted robot's counters as JSON to this file at exit (empty: no)"
        )
        config = p.config(hosted[0])
        config.validate()
        policy = load_agent_policy(p.policy, *p.policy_args())
        self.hosted = HostedAgents(hosted, config, policy)
        self.spec = self.hosted.spec
        refuse_per_robot_options(self, hosted[0], p, self.spec)
        check_overrides(self, sys.argv)
        self.mode = mode = p.mode
        self.twist_frame = p.twist_frame
        ids = self.hosted.ids
        self._wall = Clock(clock_type=ClockType.STEADY_TIME)
        self._drops = {reason: 0 for reason in DROP_REASONS}
        self._log_throttle = Throttle()
        self._announced_ready = False
        self._warm_up(policy)
        fleet = self.fleet = p.swarm_fleet()
        self.health = HostedHealth(self, hosted, p.state_timeout, qos.DIAGNOSTICS, fleet.name_of)  # one array

        fleet.check_scenario(self.spec.command, self.spec.velocity is not None)
        if fleet.command.interface != 'policy' or fleet.command_type(self.spec.command) == 'twist':
            raise ConfigError(
                f'the fleet {fleet.path} commands {fleet.command.interface} ({fleet.command.type}): a real '
                "robot's output, not offered by the agents node; run one agent per robot"
            )
        self.states = StateDecoder(fleet, self.spec, self.twist_frame, policy.dt, own=hosted)
        msg_type = COMMAND_MESSAGES[fleet.command_type(self.spec.command)]
        self.cmd_pubs = {
            rid: self.create_publisher(msg_type, fleet.command_topic(rid, self.spec.command), qos.COMMAND)
            for rid in hosted
        }
        self.status_pubs = {
            rid: self.create_publisher(String, fleet.status_topic(rid), qos.STATUS) for rid in hosted
        }
        self.odom_subs = self.states.subscribe(self, ids, self._on_odom)  # decoded and filed once for all
        self._started = time.monotonic()
        ticks = self.hosted.logics[hosted[0]].ticks
        self.on_state = ticks is not None  # realtime: ticks come with the own states
        self.control_timer, self._grace = control_timers(
            self,
            mode,
            p.control_rate,
            ticks.grace_s if self.on_state else None,
            self._on_tick,
            self._on_grace,
            self._on_lockstep_timer,
            self._wall,
        )
        self.status_timer = self.create_timer(p.status_period, self._publish_status, clock=self._wall)
        self._log_events()  # the control-period warning, once, at start
        self._publish_status()
        # last: this line says the node is up (tests wait for it)
        self.get_logger().info(
            f'robots {format_ids(hosted)} ({len(hosted)} hosted) of {len(ids)} ({self.spec.name}, {mode}): '
            f'policy {policy.path} on {policy.backend} (k={policy.k}, d_cr={policy.d_cr:g}, tau={policy.tau}, '
            f'dt={policy.dt:g})'
        )

    def _warm_up(self, policy) -> None:
        policy(*warm_up_inputs(len(self.hosted.hosted), policy.k, self.spec.state_dim))

    # --- callbacks -----------------------------------------------------------------------
    def _on_odom(self, topic_robot: int, data: bytes) -> None:
        try:
            filed = self.states.filed(topic_robot, data)
        except CdrError as exc:
            self.hosted.malformed()
            self._note_drop('malformed', str(exc))
            return
        now = self.get_clock().now().nanoseconds
        for robot, stamp, _frame, z, step, own in filed:
            if own is not None and step is not None and robot in self.hosted.logics:
                self.hosted.logics[robot].own_row(step, own)
            outcome = self.hosted.receive(robot, stamp, z, now, time.monotonic(), step=step)
            if outcome in self._drops:
                self._note_drop(outcome, f'robot {topic_robot} at {stamp * 1e-9:.3f} s')
        if self.mode == 'lockstep':
            self._publish(self.hosted.lockstep_poll(time.monotonic()))
        elif self.on_state:
            self._realtime_poll(now)
        if not self._announced_ready and self.hosted.ready:
            self._announced_ready = True
            self.get_logger().info(f'every hosted robot has heard all {len(self.hosted.ids)} robots: ready')
            self._publish_status()

    def _publish(self, commands) -> None:
        for rid, cmd in commands:
            self.states.command(rid, cmd.stamp_ns, cmd.value)  # the own velocity knows it
            self.cmd_pubs[rid].publish(
                command_to_cdr(cmd.stamp_ns, cmd.value, self.spec)
            )  # bytes: no msg objects
        if commands:  # notes come with commands (or a timer): not worth a look at every message
            self._log_events()

    def _log_events(self) -> None:
        for text in self.hosted.drain_events():
            self.get_logger().warning(text)

    def _on_lockstep_timer(self) -> None:
        self._publish(self.hosted.lockstep_poll(time.monotonic()))
        self._log_events()

    def _realtime_poll(self, now: int) -> None:
        self._publish(self.hosted.realtime_poll(now, time.monotonic()))
        self._grace.set(bool(self.hosted.waiting_ticks))

    def _on_grace(self) -> None:
        self._realtime_poll(self.get_clock().now().nanoseconds)

    def _on_tick(self) -> None:
        now = self.get_clock().now().nanoseconds
        self._publish(self.hosted.watchdog(now) if self.on_state else self.hosted.tick(now))
        self._log_events()

    def _note_drop(self, reason: str, detail: str) -> None:
        self._drops[reason] += 1
        if self._log_throttle.ready(reason):
            self.get_logger().warning(
                f'dropped {self._drops[reason]} state(s) in all ({reason}; latest: {detail})'
            )

    def _publish_status(self) -> None:
        reports = {}
        missing = set()
        for rid, logic in self.hosted.logics.items():
            status = logic.status()
            status['missing_names'] = [self.fleet.name_of(i) for i in status['missing']]
            missing.update(status['missing'])
            self.status_pubs[rid].publish(string_to_cdr(status_json(**status)))  # bytes: no msg objects
            last = logic.last_command
            reports[rid] = (status, logic.newest_ns.get(rid), 0 if last is None else last.neighbours)
        self.health.publish(reports, self.get_clock().now().nanoseconds, time.monotonic())
        late = (
            time.monotonic() - self._started >= self.hosted.logics[self.hosted.hosted[0]].config.state_timeout
        )
        if missing and late and self._log_throttle.ready('missing'):
            self.get_logger().warning(
                f'never heard: {missing_names(self.fleet, sorted(missing))} (left out of Y)'
            )

    def write_report(self) -> None:
        """Write every hosted robot's counters to the ``report`` file (if set)."""
        if not getattr(self, 'report_path', '') or not hasattr(self, 'hosted'):
            return
        write_json_report(self.report_path, self.hosted.status())


def main(args=None):
    """Entry point of the ``agents`` executable."""
    argv = args if args is not None else sys.argv
    run_node('agents', lambda: AgentsNode(node_name_for(argv)), AgentsNode.write_report, args)
