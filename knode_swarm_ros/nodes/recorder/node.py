"""The ``recorder`` executable: every robot's odometry into a trajectory file.

Subscribes to ``robot_<i>/odom`` for robots 0 .. n-1 (with a ``fleet`` file: each fleet robot's
state topic; from poses the velocities are the agents' estimates,
:class:`knode_swarm_ros.logic.contract.pose.PoseStates`) and to ``simulator/status``; publishes
``recorder/status`` (JSON: ready once every robot was heard, ``saved`` at the end),
``recorder/progress`` (std_msgs/Int64, the newest step up to which every frame is complete:
the simulator's lockstep flow control) and live ``recorder/avd`` / ``recorder/amd``
(std_msgs/Float64). It writes ``output`` (the docs/DESIGN.md trajectory format, one trajectory,
atomically) when the simulator reports ``done`` and every frame up to the final one is here
(or ``grace_period`` later, filling gaps), and also when stopped with Ctrl-C or SIGTERM. Robots
the simulator stops for silence (their agent died or stalled) are in the file's meta ``silent``:
robot -> the step since which, as the simulator last reported it.
"""

from __future__ import annotations

import importlib.util
import sys
import time
from functools import partial

from rclpy.clock import Clock, ClockType
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.task import Future
from std_msgs.msg import Float64, Int64, String

from knode_swarm_ros.core.scenarios import get_scenario
from knode_swarm_ros.logic.common import (
    AMD_TOPIC,
    AVD_TOPIC,
    EXIT_FAILURE,
    EXIT_OK,
    RECORDER_PROGRESS_TOPIC,
    RECORDER_STATUS_TOPIC,
    SIMULATOR_STATUS_TOPIC,
    ConfigError,
    parse_status,
    status_json,
)
from knode_swarm_ros.logic.contract.fleet import default_fleet, load_fleet
from knode_swarm_ros.logic.contract.pose import PoseStates
from knode_swarm_ros.logic.recorder import FrameCollector, swarm_metrics
from knode_swarm_ros.logic.reporting import Throttle
from knode_swarm_ros.nodes.common import qos
from knode_swarm_ros.nodes.common.conversions import (
    STATE_MESSAGES,
    TWIST_FRAMES,
    CdrError,
    odom_from_cdr,
    pose_from_cdr,
)
from knode_swarm_ros.nodes.common.executor import run_node
from knode_swarm_ros.nodes.common.params import check_overrides, declare, declare_scenario

__all__ = ['RecorderNode', 'main']


class RecorderNode(Node):
    """Thin ROS wrapper around :class:`FrameCollector` (see the module doc and docs/ros.md)."""

    def __init__(self, node_name: str = 'recorder', **kwargs):
        super().__init__(node_name, **kwargs)
        self.scenario = declare_scenario(self, 'flock2d')
        robots = declare(self, 'robots', 10, 'number of robots, ids 0 .. robots-1', int_range=(1, 10_000))
        self.output = declare(self, 'output', '', 'trajectory file to write (.npz), required')
        spec = get_scenario(self.scenario)
        self.dt = (
            declare(
                self,
                'dt',
                0.0,
                f"seconds per simulation step (0: the scenario's, {spec.dt:g})",
                float_range=(0.0, 3600.0),
            )
            or spec.dt
        )
        self.frame_every = declare(
            self,
            'frame_every',
            0,
            'steps between recorded frames (0: as the simulator publishes, else inferred)',
            int_range=(0, 1_000_000),
        )
        self.stop_on_done = declare(self, 'stop_on_done', True, 'save and exit when the simulator is done')
        self.grace_period = declare(
            self,
            'grace_period',
            3.0,
            'wall seconds to wait for missing frames after the simulator is done',
            float_range=(0.0, 3600.0),
        )
        self.bag = declare(
            self,
            'bag',
            '',
            'also write the recorded odometry as a bag: an .mcap file, else a '
            'rosbag2 directory (needs the rosbags package: pip install knode_swarm_ros[bag])',
        )
        if self.bag and importlib.util.find_spec('rosbags') is None:
            raise ConfigError(
                f"parameter 'bag' = {self.bag!r}: writing bags needs the rosbags package "
                "(pip install 'knode_swarm_ros[bag]')"
            )
        self.twist_frame = declare(
            self,
            'twist_frame',
            'body',
            'frame of the Odometry twist: body (REP 105) or world (a driver that deviates from REP 105)',
            choices=TWIST_FRAMES,
        )
        metrics_rate = declare(
            self, 'metrics_rate', 5.0, 'avd/amd messages per wall second (0: none)', float_range=(0.0, 1000.0)
        )
        max_age = declare(
            self,
            'max_age',
            5.0,
            'states stamped more than this many seconds before the clock (or before 0) are dropped',
            float_range=(1e-3, 86_400.0),
        )
        future_tolerance = declare(
            self,
            'future_tolerance',
            0.5,
            'states stamped more than this many seconds ahead of the clock are dropped',
            float_range=(0.0, 86_400.0),
        )
        fleet_file = declare(
            self,
            'fleet',
            '',
            "fleet file: record each fleet robot's state topic (overrides 'robots'; empty: robot_<i>/odom)",
        )
        check_overrides(self, sys.argv)
        self.fleet = load_fleet(fleet_file) if fleet_file else default_fleet(range(robots))
        robots = len(self.fleet.robots)
        self.rids = self.fleet.ids  # index r records the fleet's r-th robot (ascending ids)
        self.poses = (
            PoseStates(spec, self.fleet.state.velocity_window) if self.fleet.state.type == 'pose' else None
        )
        if not self.output:
            raise ConfigError("parameter 'output' is required: pass -p output:=/path/to/run.npz")
        if not self.output.endswith('.npz'):
            raise ConfigError(f"parameter 'output' = {self.output!r} must end with .npz")

        self.frames = FrameCollector(self.scenario, robots, self.dt, max_age, future_tolerance)
        if self.frame_every:
            self.frames.set_every(self.frame_every)
        self.source = {}
        self.silent = {}  # robot -> step since which the simulator stops it (its last status)
        self.phase = 'recording'
        self.final_step = None
        self._done_wall = None
        self.saved_path = None
        self.finished = Future()
        self.exit_code = EXIT_OK
        self._metrics_period = 1.0 / metrics_rate if metrics_rate > 0 else None
        self._last_metrics = -1e9
        self._announced = False
        self._dt_warned = False
        self._substeps = 1  # the simulator's sub-steps per step (states between the steps' are expected)
        self._published_progress = -1
        self._drop_throttle = Throttle()
        self._sim_time = bool(self.get_parameter('use_sim_time').value)

        wall = Clock(clock_type=ClockType.STEADY_TIME)
        self.status_pub = self.create_publisher(String, RECORDER_STATUS_TOPIC, qos.STATUS)
        self.progress_pub = self.create_publisher(Int64, RECORDER_PROGRESS_TOPIC, qos.PROGRESS)
        self.avd_pub = self.create_publisher(Float64, AVD_TOPIC, qos.METRICS)
        self.amd_pub = self.create_publisher(Float64, AMD_TOPIC, qos.METRICS)
        state_type = STATE_MESSAGES[self.fleet.state.type]
        self.subs = [
            self.create_subscription(
                state_type, self.fleet.state_topic(rid), partial(self._on_odom, r), qos.ODOM, raw=True
            )
            for r, rid in enumerate(self.rids)
        ]  # serialized bytes: see conversions.odom_from_cdr
        self.create_subscription(String, SIMULATOR_STATUS_TOPIC, self._on_sim_status, qos.STATUS)
        self.create_timer(0.5, self._on_timer, clock=wall)
        self.get_logger().info(f'recording {robots} robots ({spec.name}) to {self.output}')
        self._publish_status()

    # --- callbacks -----------------------------------------------------------------
    def _on_odom(self, robot: int, data: bytes) -> None:
        try:
            if self.poses is not None:
                stamp, _, pose = pose_from_cdr(data)
                z = self.poses.state(robot, stamp, pose[:3], pose[3:])
            else:
                stamp, frame, z = odom_from_cdr(data, self.scenario, self.twist_frame)
        except CdrError:
            self.frames.counters['malformed'] += 1
            return
        if self.poses is None and not self.fleet.owns_frame(frame, self.rids[robot]):
            self.frames.counters['unknown_id'] += 1
            return
        # The clock is a reference only when it is the simulation's (use_sim_time, as the swarm runs it).
        now = self.get_clock().now().nanoseconds if self._sim_time else None
        dt_ns = self.dt * 1e9
        if self._substeps > 1 and abs(stamp - round(stamp / dt_ns) * dt_ns) > 0.01 * dt_ns:
            # a motion capture faster than the policy: the pose fed the estimate above; the
            # recording keeps the step grid
            self.frames.counters['between_steps'] = self.frames.counters.get('between_steps', 0) + 1
            return
        outcome = self.frames.receive(robot, stamp, z, now)
        if outcome != 'accepted':
            if outcome in ('too_old', 'too_future', 'off_grid', 'non_finite'):
                self._throttled_drop(outcome, robot, stamp)
            return
        if self.frames.progress > self._published_progress:
            self._published_progress = self.frames.progress
            self.progress_pub.publish(Int64(data=self.frames.progress))
            self._metrics(self.frames.progress)
        if not self._announced and self.frames.ready:
            self._announced = True
            self.get_logger().info(f'heard all {self.frames.n} robots: ready')
            self._publish_status()
        if self.phase == 'finishing':
            self._maybe_save()

    def _throttled_drop(self, reason: str, robot: int, stamp: int) -> None:
        if self._drop_throttle.ready(reason):
            self.get_logger().warning(
                f'dropped a state of robot {robot} stamped {stamp * 1e-9:.3f} s ({reason}; '
                f'{self.frames.counters[reason]} in all)'
            )

    def _metrics(self, step: int) -> None:
        if self._metrics_period is None or time.monotonic() - self._last_metrics < self._metrics_period:
            return
        self._last_metrics = time.monotonic()
        a, m = swarm_metrics(self.frames.frames[step], self.scenario)
        self.avd_pub.publish(Float64(data=a))
        self.amd_pub.publish(Float64(data=m))

    def _on_sim_status(self, msg: String) -> None:
        status = parse_status(msg.data)
        if status is None:
            return
        self.source = {
            k: v
            for k, v in status.items()
            if k not in ('phase', 'step', 'lost', 'silent_since', 'agents_ready', 'final_step')
        }
        self._substeps = int(status.get('substeps') or 1)
        silent = status.get('silent_since')
        if isinstance(silent, dict):  # a status from elsewhere may hold anything: ids and steps only
            self.silent = {str(r): s for r, s in silent.items() if str(r).isdigit() and type(s) is int}
        every = int(status.get('publish_every') or 0)
        if every and not self.frame_every:
            self.frames.set_every(every)
        dt = status.get('dt')
        if dt and abs(float(dt) - self.dt) > 1e-12 and not self._dt_warned:
            self._dt_warned = True
            self.get_logger().error(
                f'the simulator steps at dt = {dt} s but parameter dt is {self.dt} s: '
                'frames are filed under the wrong steps'
            )
        if status.get('phase') == 'done' and self.stop_on_done and self.phase == 'recording':
            self.phase = 'finishing'
            self.final_step = int(status['final_step'])
            self._done_wall = time.monotonic()
            self._maybe_save()

    def _on_timer(self) -> None:
        self._publish_status()
        if self._published_progress >= 0:  # the simulator may have missed the last one
            self.progress_pub.publish(Int64(data=self._published_progress))
        if self.phase == 'finishing':
            self._maybe_save()

    def _maybe_save(self) -> None:
        complete = self.frames.progress >= self.final_step
        late = time.monotonic() - self._done_wall > self.grace_period
        if not (complete or late):
            return
        if not complete:
            self.get_logger().warning(
                f'frames up to step {self.final_step} are still incomplete after '
                f'{self.grace_period:g} s: filling gaps from neighbouring frames'
            )
        try:
            self.save(last=self.final_step)
        except (OSError, ValueError) as exc:
            self.get_logger().error(f'cannot write {self.output}: {exc}')
            self._finish(EXIT_FAILURE)
            return
        self.phase = 'saved'
        self._publish_status()
        # Make sure the simulator hears "saved" before this participant goes away.
        self.status_pub.wait_for_all_acked(Duration(seconds=2.0))
        self._finish(EXIT_OK)

    def _publish_status(self) -> None:
        self.status_pub.publish(
            String(
                data=status_json(
                    phase=self.phase,
                    ready=self.frames.ready,
                    heard=len(self.frames.heard),
                    robots=self.frames.n,
                    progress=self.frames.progress,
                    output=self.output,
                    saved=self.saved_path,
                )
            )
        )

    def _finish(self, code: int) -> None:
        if not self.finished.done():
            self.exit_code = code
            self.finished.set_result(code)

    # --- saving --------------------------------------------------------------------
    def save(self, last=None, interrupted: bool = False) -> None:
        """Write the trajectory file (atomically) with what has been recorded."""
        from knode_swarm_ros.core.trajectory import save_trajectories

        every = self.frame_every or int(self.source.get('publish_every') or 0) or None
        states, info = self.frames.build(every, last)
        meta = {
            'generator': 'knode_swarm_ros recorder',
            'source': self.source,
            'interrupted': interrupted,
            'counters': dict(self.frames.counters),
            'silent': self.silent,
            **info,
        }
        if self.fleet.path:
            meta.update(self.fleet.meta())
        if self.poses is not None:  # the velocities are estimates, as the agents heard them
            meta['velocity_estimator'] = self.fleet.state.velocity_window
        save_trajectories(self.output, states[None], self.dt * info['frame_every'], self.scenario, meta)
        self.saved_path = self.output
        if self.bag:
            # The same topics and messages a rosbag2 recording of the run would hold.
            from knode_swarm_ros.bag import write_odometry_bag

            write_odometry_bag(self.bag, states, self.dt * info['frame_every'], self.scenario, overwrite=True)
            self.get_logger().info(f'wrote the bag {self.bag}')
        a0, m0 = swarm_metrics(states[0], self.scenario)
        a1, m1 = swarm_metrics(states[-1], self.scenario)
        self.get_logger().info(
            f'wrote {self.output}: {info["frames"]} frames of {self.frames.n} robots, dt '
            f'{self.dt * info["frame_every"]:g} s{" (interrupted)" if interrupted else ""}; avd {a0:.3f} -> {a1:.3f}, '
            f'amd {m0:.3f} -> {m1:.3f}; {info["incomplete_frames"]} incomplete frame(s)'
        )

    def save_on_exit(self) -> None:
        """Ctrl-C / SIGTERM: save what there is, unless already saved."""
        if self.saved_path is not None or not self.frames.frames:
            return
        try:
            self.save(interrupted=True)
        except (OSError, ValueError) as exc:
            print(f'knode_swarm_ros recorder: cannot write {self.output}: {exc}', file=sys.stderr)


def main(args=None):
    """Entry point of the ``recorder`` executable."""
    run_node('recorder', RecorderNode, RecorderNode.save_on_exit, args)
