"""The ``simulator`` executable: integrates the swarm and publishes every robot's state.

Publishes ``robot_<i>/odom`` for robots 0 .. n-1 (with a ``fleet`` file: each fleet robot's
state topic and type, PoseStamped with optional seeded position noise when the fleet gives
poses), ``/clock`` (the simulated time; every other
node runs with ``use_sim_time``), ``markers`` (RViz) and ``simulator/status`` (JSON: phase,
step, readiness); subscribes to each robot's command and to the agents' and the recorder's
status. The physics and the lockstep bookkeeping live in :class:`SwarmSim`.

The phases (waiting, running, done), the timeouts and what the run waits for live in
:class:`~.simulator_lifecycle.SimLifecycle` (ROS-free); this node declares the parameters,
converts messages, keeps the timers and carries out what the lifecycle asks (its ``Outputs``).
"""

from __future__ import annotations

import sys
import time
from functools import partial

import numpy as np
from geometry_msgs.msg import AccelStamped, TwistStamped
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.task import Future
from rosgraph_msgs.msg import Clock as ClockMsg
from std_msgs.msg import Int64, String
from visualization_msgs.msg import MarkerArray

from knode_swarm_ros.core.scenarios import get_scenario
from knode_swarm_ros.logic.common import (
    CLOCK_TOPIC,
    EXIT_OK,
    MARKERS_TOPIC,
    MODES,
    RECORDER_PROGRESS_TOPIC,
    RECORDER_STATUS_TOPIC,
    SIMULATOR_STATUS_TOPIC,
    ConfigError,
    parse_status,
    status_json,
)
from knode_swarm_ros.logic.contract.fleet import default_fleet, load_fleet
from knode_swarm_ros.logic.reporting import write_json_report
from knode_swarm_ros.logic.simulator.run_phases import LifecycleConfig, SimLifecycle
from knode_swarm_ros.logic.simulator.swarm_sim import (
    SwarmSim,
    has_ground_truth,
    initial_state,
    initial_state_from_file,
    make_ground_truth,
    setpoint_acceleration,
)
from knode_swarm_ros.nodes.common import qos
from knode_swarm_ros.nodes.common.conversions import (
    COMMAND_MESSAGES,
    STATE_MESSAGES,
    CdrError,
    command_fields_from_cdr,
    fields_to_cdr,
    pose_to_cdr,
    time_msg,
    twist_fields_from_cdr,
)
from knode_swarm_ros.nodes.common.executor import run_node
from knode_swarm_ros.nodes.common.markers import swarm_markers
from knode_swarm_ros.nodes.common.params import check_overrides, declare, declare_scenario

from .robot_model import declare_robot_model

__all__ = ['SimulatorNode', 'main', 'substeps_of']

_WATCHDOG_PERIOD = 0.01  # wall seconds
_COMMAND_MESSAGES = {'acceleration': AccelStamped, 'velocity': TwistStamped}  # CommandWire.kind -> type


def substeps_of(state_rate: float, dt: float, mode: str) -> int:
    """Sub-steps per step for parameter ``state_rate`` (0: 1).

    Raises:
        ConfigError: a rate that is not a whole multiple of 1 / dt, or any outside realtime.
    """
    if not state_rate:
        return 1
    k = int(round(state_rate * dt))
    if mode != 'realtime' or k < 1 or abs(k - state_rate * dt) > 1e-6:
        raise ConfigError(
            f"parameter 'state_rate' = {state_rate:g}: realtime only, and a whole multiple of 1 / dt = "
            f'{1.0 / dt:g} Hz (the simulator takes whole sub-steps of each step)'
        )
    return k


class SimulatorNode(Node):
    """Thin ROS server around :class:`SwarmSim` (see the module doc and docs/ros.md)."""

    def __init__(self, node_name: str = 'simulator', **kwargs):
        super().__init__(node_name, **kwargs)
        scenario = declare_scenario(self, 'flock2d')
        robots = declare(
            self,
            'robots',
            10,
            'number of robots, ids 0 .. robots-1 (0: as many as the init trajectory has)',
            int_range=(0, 10_000),
        )
        self.steps = declare(
            self, 'steps', 2000, 'steps to simulate, then finish (0: until stopped)', int_range=(0, 2**31 - 1)
        )
        mode = declare(
            self,
            'mode',
            'lockstep',
            'lockstep: a step advances when every live agent has answered; '
            'realtime: fixed rate, newest commands',
            choices=MODES,
        )
        spec = get_scenario(scenario)
        dt = (
            declare(
                self,
                'dt',
                0.0,
                f"seconds per step (0: the scenario's, {spec.dt:g}); must equal the policy's dt",
                float_range=(0.0, 3600.0),
            )
            or spec.dt
        )
        seed = declare(
            self,
            'seed',
            0,
            'seed of the initial state (ignored with init; a scenario of your own: swarm_sim.random_start)',
            int_range=(0, 2**31 - 1),
        )
        init = declare(self, 'init', '', 'initial state: frame 0 of FILE.npz[:TRAJ] (empty: drawn from seed)')
        variant = declare(
            self,
            'variant',
            '',
            'ground-truth variant (flock2d: paper, gym_flock; boids3d: paper, '
            'published; none for a scenario of your own); also shapes the seeded initial state '
            '(empty: paper)',
        )
        ground_truth = declare(
            self,
            'ground_truth',
            False,
            'drive the robots with the ground-truth controller '
            '(Tanner / boids) instead of commands; agents are not waited for',
        )
        self.rtf = declare(
            self,
            'real_time_factor',
            1.0,
            'realtime: simulated seconds per wall second',
            float_range=(1e-3, 1000.0),
        )
        publish_rate = declare(
            self,
            'publish_rate',
            20.0,
            'realtime: odom and /clock rate in simulated Hz (lockstep publishes every step)',
            float_range=(1e-3, 10_000.0),
        )
        state_rate = declare(
            self,
            'state_rate',
            0.0,
            'realtime: states per simulated second above 1 / dt (a motion capture faster than the policy): '
            'each step is taken as state_rate * dt sub-steps, a whole number, each published '
            '(0: publish_rate)',
            float_range=(0.0, 10_000.0),
        )
        command_timeout = declare(
            self,
            'command_timeout',
            0.5,
            'realtime: a command older than this many simulated seconds stops the robot',
            float_range=(1e-6, 3600.0),
        )
        stop_limit = declare(
            self,
            'stop_limit',
            0.0,
            'per-axis deceleration of a braking stop (lost or silent '
            "acceleration-commanded robot); the policy's command_limit (0: rest in one step)",
            float_range=(0.0, 1e9),
        )
        self.lockstep_timeout = declare(
            self,
            'lockstep_timeout',
            5.0,
            'lockstep: wall seconds to wait for an agent before stopping it (brake or zero velocity)',
            float_range=(1e-3, 3600.0),
        )
        self.startup_timeout = declare(
            self,
            'startup_timeout',
            120.0,
            'wall seconds to wait for every agent (and the recorder) to be ready',
            float_range=(1e-3, 86_400.0),
        )
        self.republish_period = declare(
            self,
            'republish_period',
            0.5,
            'wall seconds between re-publications of a state nobody has answered yet',
            float_range=(1e-3, 3600.0),
        )
        self.wait_for_agents = (
            declare(
                self,
                'wait_for_agents',
                True,
                'wait for every agent to be ready before starting (off in ground-truth mode)',
            )
            and not ground_truth
        )
        self.wait_for_recorder = declare(
            self,
            'wait_for_recorder',
            False,
            'wait for the recorder before starting, '
            'keep within recorder_max_lag steps of it, and until it saved at the end',
        )
        self.recorder_max_lag = declare(
            self, 'recorder_max_lag', 50, 'steps the recorder may lag behind', int_range=(1, 150)
        )
        self.done_timeout = declare(
            self,
            'done_timeout',
            30.0,
            'wall seconds to wait for the recorder after the last step',
            float_range=(0.0, 3600.0),
        )
        d_cr = declare(
            self,
            'd_cr',
            0.0,
            'radius of the neighbour links drawn in the markers (0: no links)',
            float_range=(0.0, 1e9),
        )
        self.frame_id = declare(
            self,
            'frame_id',
            'world',
            'world frame of the odometry poses (header.frame_id; '
            'REP 105: the twist is in child_frame_id robot_<id>/base_link)',
        )
        marker_rate = declare(
            self, 'marker_rate', 10.0, 'markers per wall second (0: none)', float_range=(0.0, 1000.0)
        )
        self.report_path = declare(
            self, 'report', '', 'write a JSON report (timings, latency, counters) here at exit (empty: no)'
        )
        self.progress_period = declare(
            self,
            'progress_period',
            5.0,
            'wall seconds between progress lines in the log (0: none)',
            float_range=(0.0, 86_400.0),
        )
        self.exit_when_done = declare(
            self,
            'exit_when_done',
            True,
            'exit after the last step (otherwise keep publishing the final state until stopped)',
        )
        fleet_file = declare(
            self,
            'fleet',
            '',
            "fleet file: publish each fleet robot's state topic and type, take its command topic and "
            "type (overrides 'robots'; empty: robot_<i>, Odometry)",
        )
        self.pose_noise = declare(
            self,
            'pose_noise',
            0.0,
            'fleet with poses: standard deviation of the position noise per axis in metres (seeded by seed)',
            float_range=(0.0, 100.0),
        )
        robot_model, robot_params = declare_robot_model(self)
        check_overrides(self, sys.argv)
        fleet = load_fleet(fleet_file) if fleet_file else None
        if fleet is not None:
            robots = len(fleet.robots)

        if init:
            z0, path, traj = initial_state_from_file(init, scenario, robots)
            gt = make_ground_truth(scenario, z0, variant, dt) if ground_truth else None
            origin = {'init': f'{path}:{traj}'}
        else:
            if robots < 1:
                raise ConfigError("parameter 'robots' must be >= 1 without 'init'")
            z0, gt = initial_state(scenario, robots, seed, variant)
            if ground_truth:
                make_ground_truth(scenario, z0, variant, dt)  # checks dt
            else:
                gt = None
            origin = {'seed': seed}
        self.sim = SwarmSim(
            scenario,
            z0,
            dt,
            mode,
            command_timeout,
            gt,
            stop_limit,
            robot_model=robot_model,
            robot_params=robot_params,
            substeps=substeps_of(state_rate, dt, mode),
        )
        self.spec = spec
        self.mode = mode
        self.n = self.sim.n
        self.fleet = fleet or default_fleet(range(self.n))
        if len(self.fleet.robots) != self.n:
            raise ConfigError(
                f'the fleet {self.fleet.path} has {len(self.fleet.robots)} robots, the initial state {self.n}'
            )
        self.rids = self.fleet.ids  # robot index r is the fleet's r-th robot (ascending ids)
        self.poses = self.fleet.state.type == 'pose'
        self._noise = np.random.default_rng([int(seed), 1]) if self.poses and self.pose_noise > 0 else None
        self.d_cr = d_cr
        self.publish_every = (
            1
            if mode == 'lockstep' or self.sim.substeps > 1
            else max(1, int(round(1.0 / (publish_rate * dt))))
        )
        self.meta = {
            'scenario': scenario,
            'robots': self.n,
            'mode': mode,
            'dt': dt,
            'steps': self.steps,
            'publish_every': self.publish_every,
            'substeps': self.sim.substeps,
            'ground_truth': ground_truth,
            'variant': variant or ('paper' if has_ground_truth(spec) else ''),
            'robot_model': robot_model,
            **origin,
        }
        if fleet is not None:
            self.meta.update(fleet=fleet.path, pose_noise=self.pose_noise, **fleet.meta())

        self.finished = Future()
        self.exit_code = EXIT_OK
        self.life = SimLifecycle(
            self.sim,
            LifecycleConfig(
                steps=self.steps,
                mode=mode,
                publish_every=self.publish_every,
                real_time_factor=self.rtf,
                lockstep_timeout=self.lockstep_timeout,
                startup_timeout=self.startup_timeout,
                republish_period=self.republish_period,
                wait_for_agents=self.wait_for_agents,
                wait_for_recorder=self.wait_for_recorder,
                recorder_max_lag=self.recorder_max_lag,
                done_timeout=self.done_timeout,
                progress_period=self.progress_period,
                exit_when_done=self.exit_when_done,
            ),
            self,
            self.meta,
        )

        wall = Clock(clock_type=ClockType.STEADY_TIME)
        state_type = STATE_MESSAGES[self.fleet.state.type]
        self.odom_pubs = [
            self.create_publisher(state_type, self.fleet.state_topic(rid), qos.ODOM) for rid in self.rids
        ]
        self.clock_pub = self.create_publisher(ClockMsg, CLOCK_TOPIC, qos.CLOCK)
        self.status_pub = self.create_publisher(String, SIMULATOR_STATUS_TOPIC, qos.STATUS)
        self.markers_pub = self.create_publisher(MarkerArray, MARKERS_TOPIC, qos.MARKERS)
        wire = self.sim.robots.wire
        self.command_fields = wire.fields
        command = self.fleet.command
        self.command_type = (
            'policy' if command.interface == 'unicycle' else self.fleet.command_type(wire.kind)
        )
        self.setpoints = command.interface == 'velocity_setpoint'
        if self.setpoints and (spec.command != 'acceleration' or robot_model != 'double_integrator'):
            raise ConfigError(
                f'the fleet {self.fleet.path} sends velocity setpoints: the simulator models them on '
                'double-integrator robots of an acceleration scenario only'
            )
        if gt is None:
            # raw=True: serialized bytes read by conversions.command_fields_from_cdr (no message objects)
            msg_type = (
                _COMMAND_MESSAGES[wire.kind]
                if self.command_type == 'policy'
                else COMMAND_MESSAGES[self.command_type]
            )
            self.cmd_subs = [
                self.create_subscription(
                    msg_type,
                    wire.topic(r) if fleet is None else self.fleet.command_topic(rid, wire.kind),
                    partial(self._on_command, r),
                    qos.COMMAND,
                    raw=True,
                )
                for r, rid in enumerate(self.rids)
            ]
        if self.wait_for_agents:
            self.agent_subs = [
                self.create_subscription(
                    String, self.fleet.status_topic(rid), partial(self._on_agent_status, r), qos.STATUS
                )
                for r, rid in enumerate(self.rids)
            ]
        if self.wait_for_recorder:
            self.create_subscription(String, RECORDER_STATUS_TOPIC, self._on_recorder_status, qos.STATUS)
            self.create_subscription(Int64, RECORDER_PROGRESS_TOPIC, self._on_recorder_progress, qos.PROGRESS)
        self.watchdog = self.create_timer(_WATCHDOG_PERIOD, self._on_watchdog, clock=wall)
        self.status_timer = self.create_timer(0.5, self.publish_status, clock=wall)
        if marker_rate > 0:
            self.marker_timer = self.create_timer(1.0 / marker_rate, self._publish_markers, clock=wall)
        self.physics_timer = None
        self._wall_clock = wall
        source = f'init {origin["init"]}' if init else f'seed {seed}'
        waiting = (
            ' and '.join(
                w
                for w, on in (('agents', self.wait_for_agents), ('the recorder', self.wait_for_recorder))
                if on
            )
            or 'nobody'
        )
        kind = f'{mode} (ground truth {self.meta["variant"]})' if gt else mode
        self.get_logger().info(
            f'{self.n} robots, {spec.name}, {kind}, dt {dt:g} s, {self.steps or "unlimited"} steps, '
            f'initial state from {source}; waiting for {waiting}'
        )
        self.life.publish()
        self.publish_status()

    @property
    def phase(self) -> str:
        return self.life.phase

    # --- the lifecycle's outputs ------------------------------------------------------
    def log(self, level: str, text: str) -> None:
        if level == 'error':  # one call site per severity (rclpy)
            self.get_logger().error(text)
        elif level == 'warn':
            self.get_logger().warning(text)
        else:
            self.get_logger().info(text)

    def start_physics(self, period: float) -> None:
        self.physics_timer = self.create_timer(period, self._on_physics, clock=self._wall_clock)

    def stop_physics(self) -> None:
        if self.physics_timer is not None:
            self.physics_timer.cancel()

    def finish(self, code: int) -> None:
        if not self.finished.done():
            self.exit_code = code
            self.finished.set_result(code)

    # --- publishing ----------------------------------------------------------------
    def publish_frame(self) -> None:
        ns = self.sim.stamp_ns
        robots = self.sim.robots
        if self.poses:
            self._publish_poses(ns)
        else:
            for r, pub in enumerate(self.odom_pubs):
                # serialized directly: the bytes rclpy would make of the Odometry, without its conversion
                rid = self.rids[r]
                pub.publish(
                    fields_to_cdr(rid, ns, *robots.odom_fields(r), self.frame_id, self.fleet.frame(rid))
                )
        self.clock_pub.publish(ClockMsg(clock=time_msg(ns)))

    def _publish_poses(self, ns: int) -> None:
        """Motion capture: every robot's PoseStamped, its position noisy when ``pose_noise`` > 0."""
        fields = [self.sim.robots.odom_fields(r) for r in range(self.n)]
        noise = (
            self._noise.normal(0.0, self.pose_noise, (self.n, 3))
            if self._noise is not None
            else np.zeros((self.n, 3))
        )
        dims = self.spec.dimensions
        for r, pub in enumerate(self.odom_pubs):
            position = np.array(fields[r][0], dtype=np.float64)
            position[:dims] += noise[r, :dims]  # a 2D robot's z stays 0
            pub.publish(pose_to_cdr(ns, position, fields[r][1], self.frame_id))

    def publish_status(self) -> None:
        self.status_pub.publish(String(data=status_json(**self.life.status_fields())))

    def _publish_markers(self) -> None:
        if self.markers_pub.get_subscription_count() > 0:
            self.markers_pub.publish(swarm_markers(self.sim.states, self.spec, self.d_cr, self.sim.stamp_ns))

    # --- callbacks -----------------------------------------------------------------
    def _on_command(self, robot: int, data: bytes) -> None:
        try:
            if self.command_type == 'twist':  # no header: taken as the command of the current step
                ns, u = self.sim.stamp_ns, twist_fields_from_cdr(data, self.command_fields)
            else:
                ns, u = command_fields_from_cdr(data, self.command_fields)
        except CdrError as exc:
            self.life.on_malformed_command(robot, str(exc))
            return
        if self.setpoints:  # a velocity loop reaching v_sp within one step: u = (v_sp - v) / dt
            u = setpoint_acceleration(u, self.sim.states[robot, self.spec.velocity], self.sim.dt)
        self.life.on_command(robot, ns, u, time.monotonic())

    def _on_agent_status(self, robot: int, msg: String) -> None:
        self.life.on_agent_status(robot, parse_status(msg.data))

    def _on_recorder_status(self, msg: String) -> None:
        self.life.on_recorder_status(parse_status(msg.data))

    def _on_recorder_progress(self, msg: Int64) -> None:
        self.life.on_recorder_progress(msg.data)

    def _on_watchdog(self) -> None:
        self.life.on_watchdog(time.monotonic())

    def _on_physics(self) -> None:
        self.life.on_physics(time.monotonic())

    # --- report --------------------------------------------------------------------
    def report(self) -> dict:
        """Timings, counters and latency of the run so far."""
        return self.life.report()

    def write_report(self) -> None:
        """Write :meth:`report` to the ``report`` file (if set), atomically."""
        if getattr(self, 'report_path', '') and hasattr(self, 'life'):
            write_json_report(self.report_path, self.report(), indent=1, default=str)


def main(args=None):
    """Entry point of the ``simulator`` executable."""
    run_node('simulator', SimulatorNode, SimulatorNode.write_report, args)
