"""The ``monitor`` node: a live view of a simulated or real swarm.

Reads what the agents read: ``robot_<i>/odom`` of robots 0 .. n-1, or the state topics and
types of a fleet's robots (parameter ``fleet``), through a
:class:`~knode_swarm_ros.nodes.common.state_inbox.StateInbox`: no callback per message, the
messages queued since the last tick are taken and decoded at the tick (an Odometry: only each
robot's newest is kept; poses: a tick's worth, so that the velocity estimate, the fleet's window
as the agents', sees the whole stream). And the agents' health on ``/diagnostics``
(``hardware_id``: the robot's name in the fleet, ``robot_<id>`` without a fleet file). Every tick (``rate`` per wall second) it
builds a :class:`~knode_swarm_ros.logic.monitor.Snapshot` and sends it to the web page
(``http://host:port/``, unless ``web`` is false); the links and the metrics, O(n^2) in the
robots, are computed ``figures_rate`` times per second and published as ``monitor/metrics``
(std_msgs/String, JSON: step, avd, amd, nnd, polarisation, robots by health), and as RViz markers on
``monitor/markers`` (``marker_rate`` per second, only while someone listens: robots coloured by
health, headings, the Y_i links, trails). It publishes nothing the swarm reads: it can stop at
any time.
"""

from __future__ import annotations

import sys
import time

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from std_msgs.msg import String
from visualization_msgs.msg import MarkerArray

from knode_swarm_ros.core.scenarios import get_scenario
from knode_swarm_ros.logic.common import ConfigError, parse_robot_frame, status_json
from knode_swarm_ros.logic.contract.fleet import default_fleet, load_fleet
from knode_swarm_ros.logic.contract.pose import PoseStates
from knode_swarm_ros.logic.contract.rep105 import fields_to_states
from knode_swarm_ros.logic.monitor import (
    METRICS_TOPIC,
    MONITOR_MARKERS_TOPIC,
    SwarmWatch,
    Throttle,
    hello_message,
    network_defaults,
    tick_message,
    view_scale,
)
from knode_swarm_ros.nodes.common import qos
from knode_swarm_ros.nodes.common.conversions import TWIST_FRAMES
from knode_swarm_ros.nodes.common.executor import run_node
from knode_swarm_ros.nodes.common.markers import swarm_markers
from knode_swarm_ros.nodes.common.params import check_overrides, declare, declare_scenario
from knode_swarm_ros.nodes.common.state_inbox import StateInbox

__all__ = ['MonitorNode', 'main']

CANVAS = (960, 720)  # the page's canvas in pixels (sent in the hello message)


class MonitorNode(Node):
    """Thin ROS wrapper around :class:`SwarmWatch` and the web server (see the module doc)."""

    def __init__(self, node_name: str = 'monitor', **kwargs):
        super().__init__(node_name, **kwargs)
        self.scenario = declare_scenario(self, 'flock2d')
        robots = declare(self, 'robots', 10, 'number of robots, ids 0 .. robots-1', int_range=(1, 10_000))
        default_d_cr, default_k = network_defaults(self.scenario)
        d_cr = declare(
            self,
            'd_cr',
            0.0,
            f'communication radius of the links (0: the policy default, {default_d_cr:g})',
            float_range=(0.0, 1e6),
        )
        k = declare(
            self,
            'k',
            0,
            f'rows of Y_i, the robot included (0: the policy default, {default_k})',
            int_range=(0, 10_000),
        )
        rate = declare(self, 'rate', 12.0, 'ticks (page updates) per wall second', float_range=(0.1, 100.0))
        figures_rate = declare(
            self,
            'figures_rate',
            2.0,
            'links and metrics (page, monitor/metrics) per wall second, at most one a tick',
            float_range=(0.1, 100.0),
        )
        marker_rate = declare(
            self, 'marker_rate', 5.0, 'RViz markers per wall second (0: none)', float_range=(0.0, 100.0)
        )
        stale_after = declare(
            self, 'stale_after', 1.0, 'wall seconds without a state: stale', float_range=(1e-3, 3600.0)
        )
        lost_after = declare(
            self, 'lost_after', 5.0, 'wall seconds without a state: lost', float_range=(1e-3, 3600.0)
        )
        trail = declare(self, 'trail', 50, 'points of each robot trail (RViz)', int_range=(1, 10_000))
        self.web_on = declare(self, 'web', True, 'serve the live web page')
        self.host = declare(self, 'host', '127.0.0.1', 'address the web page binds')
        port = declare(self, 'port', 8765, 'port of the web page (0: any free one)', int_range=(0, 65535))
        self.twist_frame = declare(
            self,
            'twist_frame',
            'body',
            'frame of the Odometry twist: body (REP 105) or world',
            choices=TWIST_FRAMES,
        )
        fleet_file = declare(
            self, 'fleet', '', "fleet file: its robots' state topics and types (overrides 'robots')"
        )
        check_overrides(self, sys.argv)
        self.fleet = load_fleet(fleet_file) if fleet_file else default_fleet(range(robots))
        robots = len(self.fleet.robots)
        self._by_name = {r.name: r.id for r in self.fleet.robots}  # the agents' diagnostics hardware_id
        self.poses = (
            PoseStates(self.scenario, self.fleet.state.velocity_window)
            if self.fleet.state.type == 'pose'
            else None
        )
        if lost_after < stale_after:
            raise ConfigError(f"parameter 'lost_after' = {lost_after} is below 'stale_after' = {stale_after}")
        self.spec = get_scenario(self.scenario)
        self.watch = SwarmWatch(
            self.scenario,
            self.fleet.ids,
            d_cr or default_d_cr,
            k or default_k,
            stale_after=stale_after,
            lost_after=lost_after,
            trail=trail,
        )
        self.hello = None
        self.web = None
        if self.web_on:
            try:
                from .web import WebServer, is_loopback
            except ImportError as exc:
                raise ConfigError(
                    f"parameter 'web': the page needs aiohttp ({exc}): pip install aiohttp==3.14.5 "
                    "(the 'monitor' extra), or run with web:=false"
                ) from None

            if not is_loopback(self.host):
                self.get_logger().warning(
                    f'the page binds {self.host}: other machines can reach it (no authentication)'
                )
            self.web = WebServer(self.host, port)
            try:
                self.web.start()
            except OSError as exc:
                raise ConfigError(
                    f"parameters 'host' / 'port': cannot serve on {self.host}:{port}: {exc}"
                ) from None
        self.marker_throttle = Throttle(marker_rate)
        self.figures_throttle = Throttle(figures_rate)
        self.metrics_pub = self.create_publisher(String, METRICS_TOPIC, qos.STATUS)
        self.markers_pub = self.create_publisher(MarkerArray, MONITOR_MARKERS_TOPIC, qos.MARKERS)
        # Odometry: only the newest matters; poses: all of them, the ODOM depth (2 s at 100 Hz)
        self.inbox = StateInbox(
            self.context, self.fleet, 1 if self.poses is None else qos.ODOM.depth, f'{self.get_name()}_inbox'
        )
        self.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics, qos.DIAGNOSTICS)
        self.create_timer(1.0 / rate, self._on_tick, clock=Clock(clock_type=ClockType.STEADY_TIME))
        where = f'; page at http://{self.host}:{self.web.port}/' if self.web else ''
        self.get_logger().info(f'watching {robots} robots ({self.spec.name}){where}')

    def _take_states(self) -> None:
        """File every state the inbox holds, arrived (for health) at this tick's wall time."""
        taken = self.inbox.take()
        if not len(taken.robots):
            return
        if self.poses is None:
            states = fields_to_states(
                taken.positions, taken.quaternions, taken.linears, self.spec, self.twist_frame
            )
        else:
            states = [
                self.poses.state(int(rid), int(ns), pos, q)
                for rid, ns, pos, q in zip(taken.robots, taken.stamps, taken.positions, taken.quaternions)
            ]
        self.watch.receive_many(taken.robots, taken.stamps, states, time.monotonic())

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            robot = self._by_name.get(status.hardware_id, parse_robot_frame(status.hardware_id))
            if robot is not None:
                level = status.level
                self.watch.diagnostics(robot, level[0] if isinstance(level, bytes) else int(level))

    def _on_tick(self) -> None:
        self._take_states()
        now = time.monotonic()
        markers = self.marker_throttle.due(now) and self.markers_pub.get_subscription_count() > 0
        snap = self.watch.snapshot(now, figures=self.figures_throttle.due(now) or markers)
        if snap.step is None:
            return
        if snap.metrics is not None:
            counts = {h: snap.health.count(h) for h in set(snap.health)}
            self.metrics_pub.publish(String(data=status_json(step=snap.step, robots=counts, **snap.metrics)))
        if markers:
            self.markers_pub.publish(
                swarm_markers(
                    self.watch.states,
                    self.spec,
                    self.watch.d_cr,
                    snap.stamp_ns,
                    links=snap.links,
                    health=snap.health,
                    trails=self.watch.trails(),
                )
            )
        if self.web is not None:
            if self.hello is None:  # the scale is fixed on the first states heard
                heard = [i for i, h in enumerate(snap.health) if h != 'unheard']
                scale = view_scale(snap.positions[heard], *CANVAS, self.watch.d_cr)
                self.hello = hello_message(
                    self.scenario, snap.ids, self.watch.d_cr, self.watch.k, scale, CANVAS
                )
            self.web.publish(self.hello, tick_message(snap))

    def close(self) -> None:
        if self.web is not None:
            self.web.stop()

    def destroy_node(self):
        inbox = getattr(self, 'inbox', None)  # a constructor cut short may not have made it yet
        if inbox is not None:
            inbox.destroy()
        return super().destroy_node()


def main(args=None):
    """Entry point of the ``monitor`` executable."""
    run_node('monitor', MonitorNode, MonitorNode.close, args)
