"""The ``agents`` executable: several robots' learnt controllers in one ROS 2 process.

``python -m knode_swarm_ros.nodes.agents --ros-args -p ids:=0..49 -p robots:=100 ...``
(``ids`` a list ``[0, 1, 5]`` or a range ``'0..49'``; the other parameters are the ``agent``'s).

For simulating large swarms on one machine; a real robot runs the lone ``agent``. Each hosted
robot runs the same :class:`AgentLogic` as a lone agent (:class:`HostedAgents`): its own delay
buffer, neighbour matrix, counters, ``robot_<id>/cmd_*`` and ``robot_<id>/agent_status``
topics, and only what its robot hears. Shared plumbing: one raw subscription per robot's
``robot_<j>/odom`` (decoded once, handed to every hosted robot), one executor, one policy
module, one batched policy call per tick. The node is called ``agents_<first>_<last>``.
"""
from __future__ import annotations

import sys
import time
from functools import partial

from nav_msgs.msg import Odometry
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from std_msgs.msg import String

from . import qos
from .agent import load_agent_policy
from .agent_logic import DROP_REASONS, AgentConfig
from .common import (MODES, ConfigError, agent_status_topic, command_topic, odom_topic, robot_frame,
                     robot_id_list, status_json)
from .conversions import CdrError, command_msg_type, command_to_msg, odom_from_cdr
from .executor import run_node
from .hosted_logic import HostedAgents, format_ids, parse_ids
from .params import declare, declare_int_array
from .reporting import Throttle, write_json_report

__all__ = ['AgentsNode', 'main', 'node_name_for']



def node_name_for(argv) -> str:
    """``agents_<first>_<last>`` from ``-p ids:=...`` on the command line, else ``agents``."""
    items = list(argv or [])
    for flag, value in zip(items, items[1:]):
        if flag in ('-p', '--param') and value.startswith('ids:='):
            try:
                import yaml
                ids = parse_ids(yaml.safe_load(value[len('ids:='):]))
            except (ConfigError, ValueError, ImportError):
                return 'agents'
            return f'agents_{ids[0]}_{ids[-1]}'
    return 'agents'


class AgentsNode(Node):
    """Thin ROS wrapper around :class:`HostedAgents` (see the module doc and docs/ros.md)."""

    def __init__(self, node_name: str = 'agents', **kwargs):
        super().__init__(node_name, **kwargs)
        descriptor = ParameterDescriptor(description="the hosted robots' ids: a list [0, 1, 5] or a range '0..49'",
                                         dynamic_typing=True, read_only=True)
        raw_ids = self.declare_parameter('ids', '', descriptor).value
        if raw_ids in ('', None):
            raise ConfigError("parameter 'ids' is required: pass -p ids:=[0,1,2] or -p ids:=0..49")
        hosted = parse_ids(raw_ids)
        # The lone agent's parameters, same names and meaning (docs/ros.md, "agent").
        robots = declare(self, 'robots', 10, 'swarm size: robot ids are 0 .. robots-1 (unless robot_ids is set)',
                         int_range=(1, 10_000))
        robot_ids = declare_int_array(self, 'robot_ids', "the swarm's robot ids (overrides 'robots')")
        scenario = declare(self, 'scenario', '', "flock2d or boids3d (empty: the policy's)",
                           choices=('', 'flock2d', 'boids3d'))
        policy_path = declare(self, 'policy', '', 'TorchScript policy file (empty: the shipped policy of scenario)')
        mode = declare(self, 'mode', 'realtime', 'lockstep or realtime (as the agent)', choices=MODES)
        control_rate = declare(self, 'control_rate', 20.0, 'realtime control rate in Hz (ROS clock)',
                               float_range=(0.01, 1000.0))
        state_timeout = declare(self, 'state_timeout', 0.5, 'seconds after which a silent neighbour leaves the '
                                'neighbour set and a stale own state gives a zero command', float_range=(1e-3, 3600.0))
        future_tolerance = declare(self, 'future_tolerance', 0.5, 'states stamped more than this many seconds '
                                   'ahead of the clock are dropped', float_range=(0.0, 3600.0))
        command_limit = declare(self, 'command_limit', 0.0, "per-axis command saturation (0: the policy's limit)",
                                float_range=(0.0, 1e9))
        k = declare(self, 'k', 0, "rows of Y (0: the policy's)", int_range=(0, 1000))
        d_cr = declare(self, 'd_cr', 0.0, "communication radius (0: the policy's)", float_range=(0.0, 1e9))
        tau = declare(self, 'tau', -1, "delay in steps (-1: the policy's)", int_range=(-1, 100_000))
        dt = declare(self, 'dt', 0.0, "seconds per step (0: the policy's)", float_range=(0.0, 3600.0))
        parity_batch = declare(self, 'parity_batch', True, 'lockstep: a rollout-shaped batch (bit-for-bit parity)')
        threads = declare(self, 'torch_threads', 1, 'torch intra-op threads', int_range=(1, 256))
        status_period = declare(self, 'status_period', 0.5, 'seconds between status messages (wall clock)',
                                float_range=(0.01, 3600.0))
        self.report_path = declare(self, 'report', '', 'write every hosted robot\'s counters as JSON to this file '
                                   'at exit (empty: no)')

        ids = robot_id_list(robots, robot_ids)
        config = AgentConfig(hosted[0], ids, mode, state_timeout, future_tolerance, command_limit, parity_batch)
        config.validate()
        import torch  # here: parameter errors come without the torch import
        torch.set_num_threads(threads)
        policy = load_agent_policy(policy_path, scenario, k, d_cr, tau, dt)
        self.hosted = HostedAgents(hosted, config, policy)
        self.spec = self.hosted.spec
        self.mode = mode
        self._wall = Clock(clock_type=ClockType.STEADY_TIME)
        self._drops = {reason: 0 for reason in DROP_REASONS}
        self._log_throttle = Throttle()
        self._announced_ready = False
        self._warm_up(policy)

        msg_type = command_msg_type(self.spec)
        self.cmd_pubs = {rid: self.create_publisher(msg_type, command_topic(rid, self.spec.command), qos.COMMAND)
                         for rid in hosted}
        self.status_pubs = {rid: self.create_publisher(String, agent_status_topic(rid), qos.STATUS)
                            for rid in hosted}
        # One raw subscription per robot topic for every hosted robot (decoded once).
        self.odom_subs = [self.create_subscription(Odometry, odom_topic(rid), partial(self._on_odom, rid), qos.ODOM,
                                                   raw=True) for rid in ids]
        if mode == 'realtime':
            self.control_timer = self.create_timer(1.0 / control_rate, self._on_tick)
        else:
            self.control_timer = self.create_timer(0.05, self._on_lockstep_timer, clock=self._wall)
        self.status_timer = self.create_timer(status_period, self._publish_status, clock=self._wall)
        self._publish_status()
        # last: this line says the node is up (tests wait for it)
        self.get_logger().info(
            f'robots {format_ids(hosted)} ({len(hosted)} hosted) of {len(ids)} ({policy.scenario}, {mode}): '
            f'policy {policy.path} (k={policy.k}, d_cr={policy.d_cr:g}, tau={policy.tau}, dt={policy.dt:g})')

    def _warm_up(self, policy) -> None:
        import numpy as np
        Y = np.zeros((len(self.hosted.hosted), policy.k, self.spec.state_dim))
        mask = np.zeros(Y.shape[:2], dtype=bool)
        mask[:, 0] = True
        policy(Y, mask)

    # --- callbacks -----------------------------------------------------------------------
    def _on_odom(self, topic_robot: int, data: bytes) -> None:
        try:
            stamp, frame, z = odom_from_cdr(data, self.spec)
        except CdrError as exc:
            self.hosted.malformed()
            self._note_drop('malformed', f'{odom_topic(topic_robot)}: {exc}')
            return
        robot = topic_robot if frame in ('', robot_frame(topic_robot)) else None
        now = self.get_clock().now().nanoseconds
        outcome = self.hosted.receive(robot, stamp, z, now, time.monotonic())
        if outcome in self._drops:
            self._note_drop(outcome, f'robot {topic_robot} at {stamp * 1e-9:.3f} s')
        if self.mode == 'lockstep':
            self._publish(self.hosted.lockstep_poll(time.monotonic()))
        if not self._announced_ready and self.hosted.ready:
            self._announced_ready = True
            self.get_logger().info(f'every hosted robot has heard all {len(self.hosted.ids)} robots: ready')
            self._publish_status()

    def _publish(self, commands) -> None:
        for rid, cmd in commands:
            self.cmd_pubs[rid].publish(command_to_msg(cmd.stamp_ns, cmd.value, self.spec))
        for text in self.hosted.drain_events():
            self.get_logger().warning(text)

    def _on_lockstep_timer(self) -> None:
        self._publish(self.hosted.lockstep_poll(time.monotonic()))

    def _on_tick(self) -> None:
        self._publish(self.hosted.tick(self.get_clock().now().nanoseconds))

    def _note_drop(self, reason: str, detail: str) -> None:
        self._drops[reason] += 1
        if self._log_throttle.ready(reason):
            self.get_logger().warning(f'dropped {self._drops[reason]} state(s) in all ({reason}; latest: {detail})')

    def _publish_status(self) -> None:
        for rid, logic in self.hosted.logics.items():
            self.status_pubs[rid].publish(String(data=status_json(**logic.status())))

    def write_report(self) -> None:
        """Write every hosted robot's counters to the ``report`` file (if set)."""
        if not getattr(self, 'report_path', '') or not hasattr(self, 'hosted'):
            return
        write_json_report(self.report_path, self.hosted.status())


def main(args=None):
    """Entry point of the ``agents`` executable."""
    argv = args if args is not None else sys.argv
    run_node('agents', lambda: AgentsNode(node_name_for(argv)), AgentsNode.write_report, args)


if __name__ == '__main__':
    main()
