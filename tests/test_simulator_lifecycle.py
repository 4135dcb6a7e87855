"""The simulator's phases and timeouts (logic/simulator/run_phases.py), driven without ROS."""

import numpy as np
import pytest

from knode_swarm_ros.logic.simulator.run_phases import LifecycleConfig, SimLifecycle
from knode_swarm_ros.logic.simulator.swarm_sim import SwarmSim, initial_state


class _Out:
    """The node's side: records what the lifecycle asks for."""

    def __init__(self, sim):
        self.sim, self.frames, self.statuses, self.logs, self.finished, self.physics = sim, [], 0, [], [], []

    def publish_frame(self):
        self.frames.append(self.sim.step)

    def publish_status(self):
        self.statuses += 1

    def log(self, level, text):
        self.logs.append((level, text))

    def start_physics(self, period):
        self.physics.append(period)

    def stop_physics(self):
        self.physics.append('stop')

    def finish(self, code):
        self.finished.append(code)


def _make(robots=3, steps=5, mode='lockstep', ground_truth=False, **config):
    z0, gt = initial_state('flock2d', robots, 0)
    sim = SwarmSim('flock2d', z0, 0.01, mode, 0.5, gt if ground_truth else None, 0.0)
    now = [100.0]
    out = _Out(sim)
    config.setdefault('wait_for_agents', not ground_truth)
    life = SimLifecycle(
        sim,
        LifecycleConfig(steps=steps, mode=mode, **config),
        out,
        {'scenario': 'flock2d'},
        clock=lambda: now[0],
    )
    return life, sim, out, now


def _answer(life, sim, robots, now):
    for r in robots:
        life.on_command(r, sim.stamp_ns, np.zeros(2), now)


def test_waits_for_every_agent_and_the_recorder_then_runs_in_lockstep_to_done():
    life, sim, out, now = _make(steps=3, wait_for_recorder=True, republish_period=0.5)
    life.publish()
    assert (
        life.phase == 'waiting' and out.frames == [0] and life.frames == 0
    )  # waiting frames are not counted
    for r in range(3):
        life.on_agent_status(r, {'ready': True, 'dt': 0.01})
    now[0] += 0.6
    life.on_watchdog(now[0])
    assert life.phase == 'waiting' and out.frames == [0, 0]  # the recorder is not ready: again
    assert any(t.endswith('waiting for the recorder') for _, t in out.logs)  # not "0 agent(s) []"
    assert not any('0 agent(s)' in t for _, t in out.logs)
    life.on_recorder_status({'ready': True})
    life.on_watchdog(now[0])
    assert life.phase == 'running' and any('ready after 0.6 s: running' in t for _, t in out.logs)
    assert life.status_fields()['phase'] == 'running'
    for step in range(3):
        _answer(life, sim, range(3), now[0])
        life.on_recorder_progress(sim.step)
    assert sim.step == 3 and life.phase == 'done' and out.frames[2:] == [1, 2, 3] and life.frames == 3
    assert life.status_fields()['final_step'] == 3
    life.on_watchdog(now[0])
    assert out.finished == []  # done, but the recorder has not saved yet
    life.on_recorder_status({'phase': 'saved'})
    life.on_watchdog(now[0])
    life.on_watchdog(now[0])
    assert out.finished == [0] and life.exit_code == 0
    report = life.report()
    assert (
        report['steps_run'] == 3
        and report['frames_published'] == 3
        and report['startup_s'] == pytest.approx(0.6)
    )


def test_the_recorder_lag_holds_the_steps():
    life, sim, out, now = _make(
        steps=0, wait_for_agents=False, ground_truth=True, wait_for_recorder=True, recorder_max_lag=2
    )
    life.on_recorder_status({'ready': True})
    life.on_watchdog(now[0])
    assert life.phase == 'running' and sim.step == 1  # at most 2 steps ahead of the recorder (at -1)
    life.on_recorder_progress(1)
    assert sim.step == 3


def test_startup_timeout_names_who_is_missing_and_fails():
    life, sim, out, now = _make(robots=14, startup_timeout=10.0, wait_for_recorder=True)
    life.on_agent_status(3, {'ready': True})
    life.on_agent_status(4, None)  # unreadable: ignored
    now[0] += 10.5
    life.on_watchdog(now[0])
    assert out.finished == [1] and life.phase == 'waiting'
    level, text = out.logs[-1]
    assert (
        level == 'error'
        and 'not ready after 10 s' in text
        and 'and 1 more' in text
        and 'the recorder' in text
    )
    assert '[0, 1, 2, 4, 5' in text
    life.on_watchdog(now[0] + 1)
    assert out.finished == [1]  # finishes once


def test_an_agent_with_another_dt_stops_the_run_with_status_2():
    life, sim, out, now = _make()
    life.on_agent_status(1, {'ready': True, 'dt': 0.05})
    assert out.finished == [2] and out.logs[-1][0] == 'error' and "parameter 'dt': agent 1" in out.logs[-1][1]


def test_lockstep_timeout_declares_silent_robots_lost_and_a_late_answer_rejoins():
    life, sim, out, now = _make(steps=10, lockstep_timeout=3.0, republish_period=100.0)
    for r in range(3):
        life.on_agent_status(r, {'ready': True})
    life.on_watchdog(now[0])
    _answer(life, sim, [0, 1], now[0])
    assert sim.step == 0
    now[0] += 2.9
    life.on_watchdog(now[0])
    assert not sim.lost and sim.step == 0
    now[0] += 0.2
    life.on_watchdog(now[0])
    assert sim.lost == {2} and sim.step == 1  # held, and the others go on
    assert any(lv == 'warn' and 'robot(s) [2]: no command for step 0 within 3 s' in t for lv, t in out.logs)
    _answer(life, sim, [0, 1], now[0])
    assert sim.step == 2
    _answer(life, sim, [2], now[0])  # robot 2 answers again
    assert not sim.lost and any('robot 2 answered again at step 2' in t for _, t in out.logs)
    life.on_command(7, sim.stamp_ns, np.zeros(2), now[0])  # an unknown robot: dropped, logged once
    life.on_command(7, sim.stamp_ns, np.zeros(2), now[0])
    assert sum('unknown_id' in t for _, t in out.logs) == 1 and sim.counters.unknown_id == 2


def test_done_without_the_recorder_saving_fails_after_done_timeout():
    life, sim, out, now = _make(
        steps=1, wait_for_recorder=True, done_timeout=30.0, wait_for_agents=False, ground_truth=True
    )
    life.on_recorder_status({'ready': True})
    life.on_watchdog(now[0])
    life.on_recorder_progress(0)
    life.on_watchdog(now[0])
    assert life.phase == 'done'
    now[0] += 31.0
    life.on_watchdog(now[0])
    assert out.finished == [1] and 'did not report "saved" within 30 s' in out.logs[-1][1]


def test_realtime_steps_with_the_wall_clock_and_drops_what_it_cannot_catch_up():
    life, sim, out, now = _make(
        steps=30, mode='realtime', wait_for_agents=False, publish_every=5, real_time_factor=2.0
    )
    life.on_watchdog(now[0])
    assert life.phase == 'running' and out.physics == [0.005]
    life.on_physics(now[0] + 0.0225)  # 0.045 s simulated: 4 steps, no frame yet
    assert sim.step == 4 and out.frames == []
    life.on_physics(now[0] + 0.1025)  # 20 due, 16 more wanted, 10 at most
    assert sim.step == 14 and life.overruns == 6 and out.frames == [5, 10]
    life.on_physics(now[0] + 10.0)
    assert sim.step == 24
    life.on_physics(now[0] + 20.0)
    assert sim.step == 30 and life.phase == 'done' and out.physics[-1] == 'stop'
    life.on_watchdog(now[0])
    assert out.finished == [0]
