"""The ``simulator`` executable: integrates the swarm and publishes every robot's state.

Publishes ``robot_<i>/odom`` for robots 0 .. n-1, ``/clock`` (the simulated time; every other
node runs with ``use_sim_time``), ``markers`` (RViz) and ``simulator/status`` (JSON: phase,
step, readiness); subscribes to each robot's command and to the agents' and the recorder's
status. The physics and the lockstep bookkeeping live in :class:`SwarmSim`.

Phases: ``waiting`` (the initial state is re-published every ``republish_period`` until every
agent has heard every robot, and the recorder too when ``wait_for_recorder``), ``running``,
``done`` (after ``steps`` steps: the final state stays published until the recorder says it
has saved, then the node exits with status 0). Startup that does not complete within
``startup_timeout`` exits with status 1 and names who is missing.
"""
from __future__ import annotations

import sys
import time
from functools import partial

from nav_msgs.msg import Odometry
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.task import Future
from rosgraph_msgs.msg import Clock as ClockMsg
from std_msgs.msg import Int64, String
from visualization_msgs.msg import MarkerArray

from ..core.scenarios import get_scenario
from . import qos
from .common import (CLOCK_TOPIC, EXIT_CONFIG, EXIT_FAILURE, EXIT_OK, MARKERS_TOPIC, MODES,
                     RECORDER_PROGRESS_TOPIC, RECORDER_STATUS_TOPIC, SIMULATOR_STATUS_TOPIC, ConfigError,
                     agent_status_topic, command_topic, dt_mismatch, odom_topic, parse_status, status_json)
from .conversions import command_msg_type, msg_to_command, odom_to_cdr, time_msg
from .executor import run_node
from .markers import swarm_markers
from .reporting import Throttle, throttled_log, write_json_report
from .params import check_overrides, declare
from .simulator_logic import SwarmSim, initial_state, initial_state_from_file, make_ground_truth

__all__ = ['SimulatorNode', 'main']

_WATCHDOG_PERIOD = 0.01   # wall seconds
_LOCKSTEP_BURST = 20      # ground-truth lockstep: steps per watchdog call at most


class SimulatorNode(Node):
    """Thin ROS server around :class:`SwarmSim` (see the module doc and docs/ros.md)."""

    def __init__(self, node_name: str = 'simulator', **kwargs):
        super().__init__(node_name, **kwargs)
        scenario = declare(self, 'scenario', 'flock2d', 'flock2d or boids3d', choices=('flock2d', 'boids3d'))
        robots = declare(self, 'robots', 10, 'number of robots, ids 0 .. robots-1 (0: as many as the init '
                         'trajectory has)', int_range=(0, 10_000))
        self.steps = declare(self, 'steps', 2000, 'steps to simulate, then finish (0: until stopped)',
                             int_range=(0, 2**31 - 1))
        mode = declare(self, 'mode', 'lockstep', 'lockstep: a step advances when every live agent has answered; '
                       'realtime: fixed rate, newest commands', choices=MODES)
        spec = get_scenario(scenario)
        dt = declare(self, 'dt', 0.0, f'seconds per step (0: the scenario\'s, {spec.dt:g}); must equal the '
                     "policy's dt", float_range=(0.0, 3600.0)) or spec.dt
        seed = declare(self, 'seed', 0, 'seed of the initial state (ignored with init)', int_range=(0, 2**31 - 1))
        init = declare(self, 'init', '', 'initial state: frame 0 of FILE.npz[:TRAJ] (empty: drawn from seed)')
        variant = declare(self, 'variant', '', 'ground-truth variant (flock2d: paper, gym_flock; boids3d: paper, '
                          'published); also shapes the seeded initial state (empty: paper)')
        ground_truth = declare(self, 'ground_truth', False, 'drive the robots with the ground-truth controller '
                               '(Tanner / boids) instead of commands; agents are not waited for')
        self.rtf = declare(self, 'real_time_factor', 1.0, 'realtime: simulated seconds per wall second',
                           float_range=(1e-3, 1000.0))
        publish_rate = declare(self, 'publish_rate', 20.0, 'realtime: odom and /clock rate in simulated Hz '
                               '(lockstep publishes every step)', float_range=(1e-3, 10_000.0))
        command_timeout = declare(self, 'command_timeout', 0.5, 'realtime: a command older than this many '
                                  'simulated seconds stops the robot', float_range=(1e-6, 3600.0))
        stop_limit = declare(self, 'stop_limit', 0.0, 'per-axis deceleration of a braking stop (lost or silent '
                             "acceleration-commanded robot); the policy's command_limit (0: rest in one step)",
                             float_range=(0.0, 1e9))
        self.lockstep_timeout = declare(self, 'lockstep_timeout', 5.0, 'lockstep: wall seconds to wait for an '
                                        'agent before stopping it (brake or zero velocity)', float_range=(1e-3, 3600.0))
        self.startup_timeout = declare(self, 'startup_timeout', 120.0, 'wall seconds to wait for every agent '
                                       '(and the recorder) to be ready', float_range=(1e-3, 86_400.0))
        self.republish_period = declare(self, 'republish_period', 0.5, 'wall seconds between re-publications '
                                        'of a state nobody has answered yet', float_range=(1e-3, 3600.0))
        self.wait_for_agents = declare(self, 'wait_for_agents', True, 'wait for every agent to be ready before '
                                       'starting (off in ground-truth mode)') and not ground_truth
        self.wait_for_recorder = declare(self, 'wait_for_recorder', False, 'wait for the recorder before starting, '
                                         'keep within recorder_max_lag steps of it, and until it saved at the end')
        self.recorder_max_lag = declare(self, 'recorder_max_lag', 50, 'steps the recorder may lag behind',
                                        int_range=(1, 150))
        self.done_timeout = declare(self, 'done_timeout', 30.0, 'wall seconds to wait for the recorder after '
                                    'the last step', float_range=(0.0, 3600.0))
        d_cr = declare(self, 'd_cr', 0.0, 'radius of the neighbour links drawn in the markers (0: no links)',
                       float_range=(0.0, 1e9))
        self.frame_id = declare(self, 'frame_id', 'world', "world frame of the odometry poses (header.frame_id; "
                                "REP 105: the twist is in child_frame_id robot_<id>/base_link)")
        marker_rate = declare(self, 'marker_rate', 10.0, 'markers per wall second (0: none)',
                              float_range=(0.0, 1000.0))
        self.report_path = declare(self, 'report', '', 'write a JSON report (timings, latency, counters) here at '
                                   'exit (empty: no)')
        self.progress_period = declare(self, 'progress_period', 5.0, 'wall seconds between progress lines in '
                                       'the log (0: none)', float_range=(0.0, 86_400.0))
        self.exit_when_done = declare(self, 'exit_when_done', True, 'exit after the last step (otherwise keep '
                                      'publishing the final state until stopped)')
        check_overrides(self, sys.argv)

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
        self.sim = SwarmSim(scenario, z0, dt, mode, command_timeout, gt, stop_limit)
        self.spec = spec
        self.mode = mode
        self.n = self.sim.n
        self.d_cr = d_cr
        self.publish_every = 1 if mode == 'lockstep' else max(1, int(round(1.0 / (publish_rate * dt))))
        self.meta = {'scenario': scenario, 'robots': self.n, 'mode': mode, 'dt': dt, 'steps': self.steps,
                     'publish_every': self.publish_every, 'ground_truth': ground_truth,
                     'variant': variant or 'paper', **origin}

        self.phase = 'waiting'
        self.finished = Future()
        self.exit_code = EXIT_OK
        self.agent_ready = {}
        self.recorder_ready = False
        self.recorder_saved = False
        self.recorder_progress = -1
        self.held_warned = set()
        self._wall0 = time.monotonic()
        self._run_wall0 = None
        self._run_step0 = 0
        self._done_wall = None
        self._last_publish = -1e9
        self._overruns = 0
        self._frames = 0
        self._log_throttle = Throttle()
        self._last_progress = (time.monotonic(), 0)

        wall = Clock(clock_type=ClockType.STEADY_TIME)
        self.odom_pubs = [self.create_publisher(Odometry, odom_topic(r), qos.ODOM) for r in range(self.n)]
        self.clock_pub = self.create_publisher(ClockMsg, CLOCK_TOPIC, qos.CLOCK)
        self.status_pub = self.create_publisher(String, SIMULATOR_STATUS_TOPIC, qos.STATUS)
        self.markers_pub = self.create_publisher(MarkerArray, MARKERS_TOPIC, qos.MARKERS)
        if gt is None:
            ctype = command_msg_type(spec)
            self.cmd_subs = [self.create_subscription(ctype, command_topic(r, spec.command),
                                                      partial(self._on_command, r), qos.COMMAND)
                             for r in range(self.n)]
        if self.wait_for_agents:
            self.agent_subs = [self.create_subscription(String, agent_status_topic(r),
                                                        partial(self._on_agent_status, r), qos.STATUS)
                               for r in range(self.n)]
        if self.wait_for_recorder:
            self.create_subscription(String, RECORDER_STATUS_TOPIC, self._on_recorder_status, qos.STATUS)
            self.create_subscription(Int64, RECORDER_PROGRESS_TOPIC, self._on_recorder_progress, qos.PROGRESS)
        self.watchdog = self.create_timer(_WATCHDOG_PERIOD, self._on_watchdog, clock=wall)
        self.status_timer = self.create_timer(0.5, self._publish_status, clock=wall)
        if marker_rate > 0:
            self.marker_timer = self.create_timer(1.0 / marker_rate, self._publish_markers, clock=wall)
        self.physics_timer = None
        self._wall_clock = wall
        source = f"init {origin['init']}" if init else f'seed {seed}'
        waiting = ' and '.join(w for w, on in (('agents', self.wait_for_agents),
                                               ('the recorder', self.wait_for_recorder)) if on) or 'nobody'
        kind = f'{mode} (ground truth {self.meta["variant"]})' if gt else mode
        self.get_logger().info(f'{self.n} robots, {scenario}, {kind}, dt {dt:g} s, {self.steps or "unlimited"} steps, '
                               f'initial state from {source}; waiting for {waiting}')
        self._publish_frame()
        self._publish_status()

    # --- publishing ----------------------------------------------------------------
    def _publish_frame(self) -> None:
        ns = self.sim.stamp_ns
        velocity = self.spec.command == 'velocity'
        for r, pub in enumerate(self.odom_pubs):
            # serialized directly: the bytes of conversions.state_to_odom, without rclpy's conversion
            pub.publish(odom_to_cdr(r, ns, self.sim.states[r], self.spec, self.sim.applied[r] if velocity else None,
                                    self.frame_id))
        self.clock_pub.publish(ClockMsg(clock=time_msg(ns)))
        self._last_publish = time.monotonic()
        if self.phase == 'running':
            self.sim.note_published(self._last_publish)
            self._frames += 1

    def _publish_status(self) -> None:
        fields = dict(self.meta, phase=self.phase, step=self.sim.step, lost=sorted(self.sim.lost))
        if self.phase == 'waiting':
            fields['agents_ready'] = sum(1 for v in self.agent_ready.values() if v)
        if self.phase == 'done':
            fields['final_step'] = self._final_frame()
        self.status_pub.publish(String(data=status_json(**fields)))

    def _publish_markers(self) -> None:
        if self.markers_pub.get_subscription_count() > 0:
            self.markers_pub.publish(swarm_markers(self.sim.states, self.spec, self.d_cr, self.sim.stamp_ns))

    def _final_frame(self) -> int:
        return (self.sim.step // self.publish_every) * self.publish_every

    # --- callbacks -----------------------------------------------------------------
    def _on_command(self, robot: int, msg) -> None:
        ns, u = msg_to_command(msg, self.spec)
        outcome = self.sim.offer(robot, ns, u, time.monotonic())
        if outcome in ('unknown_id', 'bad_size', 'non_finite', 'future'):
            self._throttled(f'cmd_{outcome}', f'dropped a command from robot {robot} ({outcome}, stamp '
                            f'{ns * 1e-9:.3f} s, current step {self.sim.step}); '
                            f'{getattr(self.sim.counters, outcome)} in all', warn=True)
        elif outcome == 'rejoined':
            self.held_warned.discard(robot)
            self.get_logger().info(f'robot {robot} answered again at step {self.sim.step}: waiting for it again')
        if self.mode == 'lockstep' and self.phase == 'running':
            self._lockstep_advance()

    def _on_agent_status(self, robot: int, msg: String) -> None:
        status = parse_status(msg.data)
        if status is None:
            return
        self.agent_ready[robot] = bool(status.get('ready'))
        problem = dt_mismatch(status.get('dt'), self.sim.dt)
        if problem and not self.finished.done():
            # Each step would be integrated over a different time than the policy assumes: refuse.
            self.get_logger().error(f"parameter 'dt': agent {robot} {problem}: stopping")
            self._finish(EXIT_CONFIG)

    def _on_recorder_status(self, msg: String) -> None:
        status = parse_status(msg.data) or {}
        self.recorder_ready = bool(status.get('ready'))
        self.recorder_saved = status.get('phase') == 'saved'

    def _on_recorder_progress(self, msg: Int64) -> None:
        if msg.data > self.recorder_progress:
            self.recorder_progress = int(msg.data)
            if self.mode == 'lockstep' and self.phase == 'running':
                self._lockstep_advance()

    def _on_watchdog(self) -> None:
        now = time.monotonic()
        if self.phase == 'waiting':
            self._check_startup(now)
        elif self.phase == 'running' and self.progress_period and now - self._last_progress[0] >= self.progress_period:
            wall0, step0 = self._last_progress
            self._last_progress = (now, self.sim.step)
            rate = (self.sim.step - step0) / max(now - wall0, 1e-9)
            self.get_logger().info(f'step {self.sim.step}{"/" + str(self.steps) if self.steps else ""} '
                                   f'(t = {self.sim.step * self.sim.dt:.2f} s), {rate:.1f} steps/s'
                                   f'{", held: " + str(sorted(self.sim.lost)) if self.sim.lost else ""}')
        if self.phase == 'running' and self.mode == 'lockstep':
            if self.sim.ground_truth is None:
                lost = [r for r in self.sim.overdue(now, self.lockstep_timeout) if r not in self.held_warned]
                if lost:
                    self.held_warned.update(lost)
                    self.sim.declare_lost(lost)
                    self.get_logger().warning(
                        f'robot(s) {lost}: no command for step {self.sim.step} within {self.lockstep_timeout:g} s: '
                        f'stopping them (brake or zero velocity) and no longer waiting for them')
            self._lockstep_advance()
            if self.phase == 'running' and now - self._last_publish >= self.republish_period:
                self._publish_frame()  # answers or frames went missing: send the current state again
        elif self.phase == 'done':
            if not self.exit_when_done:
                if now - self._last_publish >= self.republish_period:
                    self._publish_frame()
            elif not self.wait_for_recorder or self.recorder_saved:
                self._finish(EXIT_OK)
            elif now - self._done_wall > self.done_timeout:
                self.get_logger().error(f'the recorder did not report "saved" within {self.done_timeout:g} s '
                                        'after the last step')
                self._finish(EXIT_FAILURE)
            elif now - self._last_publish >= self.republish_period:
                self._publish_frame()

    def _check_startup(self, now: float) -> None:
        agents = [r for r in range(self.n) if not self.agent_ready.get(r)] if self.wait_for_agents else []
        recorder = self.wait_for_recorder and not self.recorder_ready
        if not agents and not recorder:
            took = now - self._wall0
            self.get_logger().info(f'{"all " + str(self.n) + " agents " if self.wait_for_agents else ""}'
                                   f'{"and " if self.wait_for_agents and self.wait_for_recorder else ""}'
                                   f'{"the recorder " if self.wait_for_recorder else ""}ready after {took:.1f} s: '
                                   f'running')
            self._start(now)
            return
        if now - self._wall0 > self.startup_timeout:
            who = ([f'agents {_ids(agents)}'] if agents else []) + (['the recorder'] if recorder else [])
            self.get_logger().error(f'not ready after {self.startup_timeout:g} s: {" and ".join(who)} '
                                    '(an agent is ready once it has heard every robot)')
            self._finish(EXIT_FAILURE)
            return
        if now - self._last_publish >= self.republish_period:
            self._publish_frame()
            self._throttled('waiting', f'waiting for {len(agents)} agent(s) {_ids(agents)}'
                            f'{" and the recorder" if recorder else ""}')

    def _start(self, now: float) -> None:
        self.phase = 'running'
        self._run_wall0 = now
        self._run_step0 = self.sim.step
        self._last_progress = (now, self.sim.step)
        self._publish_status()
        self.sim.note_published(now)
        self._last_publish = now
        if self.mode == 'realtime':
            self.physics_timer = self.create_timer(self.sim.dt / self.rtf, self._on_physics, clock=self._wall_clock)
        else:
            self._lockstep_advance()

    def _recorder_allows(self) -> bool:
        return not self.wait_for_recorder or self.sim.step - self.recorder_progress < self.recorder_max_lag

    def _lockstep_advance(self) -> None:
        burst = 0
        while self.phase == 'running' and self.sim.can_advance() and self._recorder_allows():
            if self.steps and self.sim.step >= self.steps:
                self._done()
                return
            self.sim.advance()
            self._publish_frame()
            burst += 1
            if self.sim.ground_truth is not None and burst >= _LOCKSTEP_BURST:
                return
        if self.phase == 'running' and self.steps and self.sim.step >= self.steps:
            self._done()

    def _on_physics(self) -> None:
        if self.phase != 'running':
            return
        elapsed = time.monotonic() - self._run_wall0
        due = int(elapsed * self.rtf / self.sim.dt) - (self.sim.step - self._run_step0)
        limit = 10
        if due > limit:  # too far behind (the machine is overloaded): drop time, count it
            self._overruns += due - limit
            self._run_wall0 += (due - limit) * self.sim.dt / self.rtf
            due = limit
        for _ in range(max(due, 0)):
            if self.steps and self.sim.step >= self.steps:
                break
            self.sim.advance()
            if self.sim.step % self.publish_every == 0:
                self._publish_frame()
        if self.steps and self.sim.step >= self.steps:
            self._done()

    def _done(self) -> None:
        if self.phase == 'done':
            return
        self.phase = 'done'
        self._done_wall = time.monotonic()
        if self.physics_timer is not None:
            self.physics_timer.cancel()
        ran = self._done_wall - self._run_wall0
        steps = self.sim.step - self._run_step0
        self.get_logger().info(f'done: {steps} steps in {ran:.2f} s ({steps / max(ran, 1e-9):.1f} steps/s)')
        self._publish_status()

    def _finish(self, code: int) -> None:
        if not self.finished.done():
            self.exit_code = code
            self.finished.set_result(code)

    def _throttled(self, key: str, text: str, warn: bool = False) -> None:
        throttled_log(self.get_logger(), self._log_throttle, key, text, warn)

    # --- report --------------------------------------------------------------------
    def report(self) -> dict:
        """Timings, counters and latency of the run so far."""
        out = dict(self.meta, phase=self.phase, exit_code=self.exit_code, frames_published=self._frames,
                   overruns=self._overruns, **self.sim.report())
        if self._run_wall0 is not None:
            end = self._done_wall or time.monotonic()
            out['startup_s'] = self._run_wall0 - self._wall0
            out['run_s'] = end - self._run_wall0
            out['steps_run'] = self.sim.step - self._run_step0
            out['steps_per_s'] = out['steps_run'] / max(out['run_s'], 1e-9)
        return out

    def write_report(self) -> None:
        """Write :meth:`report` to the ``report`` file (if set), atomically."""
        if getattr(self, 'report_path', ''):
            write_json_report(self.report_path, self.report(), indent=1, default=str)


def _ids(ids) -> str:
    ids = list(ids)
    return str(ids) if len(ids) <= 12 else f'{ids[:12]} and {len(ids) - 12} more'


def main(args=None):
    """Entry point of the ``simulator`` executable."""
    run_node('simulator', SimulatorNode, SimulatorNode.write_report, args)


if __name__ == '__main__':
    main()
