"""A motion capture faster than the policy (logic/simulator): each step of dt taken as k sub-steps
of dt / k, each integrating the command held at its start; every sub-step published in realtime."""

import numpy as np
import pytest

from knode_swarm_ros.core.rollout import zoh_step
from knode_swarm_ros.core.scenarios import get_scenario
from knode_swarm_ros.logic.common import ConfigError, stamp_ns
from knode_swarm_ros.logic.simulator.run_phases import LifecycleConfig, SimLifecycle
from knode_swarm_ros.logic.simulator.swarm_sim import SwarmSim, initial_state

DT = 0.05


def _sim(substeps, robots=4):
    z0, _ = initial_state('flock2d', robots, 0)
    return SwarmSim('flock2d', z0, DT, 'realtime', 0.5, None, 0.0, substeps=substeps)


def test_a_command_held_over_the_sub_steps_ends_where_one_step_ends():
    spec = get_scenario('flock2d')
    sim = _sim(5)
    u = np.random.default_rng(1).normal(size=(4, 2))
    z = sim.states.copy()
    for r in range(4):
        assert sim.offer(r, 0, u[r]) == 'accepted'
    stamps = []
    for _ in range(5):
        stamps.append(sim.stamp_ns)
        sim.advance()
    assert sim.step == 1 and sim.sub == 0 and sim.stamp_ns == stamp_ns(1, DT)
    assert stamps == [0, 10_000_000, 20_000_000, 30_000_000, 40_000_000]
    np.testing.assert_allclose(sim.states, zoh_step(z, u, spec, DT), rtol=0, atol=1e-12)  # exact integration


def test_one_sub_step_is_the_plain_step_bit_for_bit():
    plain, one = _sim(1), _sim(1)
    z0, _ = initial_state('flock2d', 4, 0)
    ref = SwarmSim('flock2d', z0, DT, 'realtime', 0.5, None, 0.0)
    u = np.random.default_rng(2).normal(size=(4, 2))
    for sim in (plain, one, ref):
        for r in range(4):
            sim.offer(r, 0, u[r])
        sim.advance()
    assert np.array_equal(one.states, ref.states) and one.stamp_ns == ref.stamp_ns == stamp_ns(1, DT)


def test_a_command_stamped_mid_step_acts_from_the_next_sub_step():
    spec = get_scenario('flock2d')
    sim = _sim(5, robots=1)
    z = sim.states.copy()
    u0, u1 = np.array([[0.3, 0.1]]), np.array([[1.0, -2.0]])
    sim.offer(0, 0, u0[0])
    sim.advance()
    sim.advance()  # t = 20 ms
    assert sim.offer(0, sim.stamp_ns, u1[0]) == 'accepted'  # stamped with the 20 ms pose: not 'future'
    assert sim.offer(0, sim.stamp_ns + stamp_ns(1, DT / 5), u1[0]) == 'future'
    for _ in range(3):
        sim.advance()
    h = DT / 5
    assert sim.step == 1
    expected = zoh_step(zoh_step(z, u0, spec, 2 * h), u1, spec, 3 * h)
    np.testing.assert_allclose(sim.states, expected, rtol=0, atol=1e-12)


def test_the_command_timeout_counts_simulated_time_not_sub_steps():
    sim = _sim(5, robots=1)
    sim.offer(0, 0, np.array([0.1, 0.0]))
    for _ in range(51):  # up to a command 0.5 s old: still held
        sim.advance()
    assert sim.counters.zeroed == 0
    sim.advance()
    assert sim.counters.zeroed == 1


def test_realtime_publishes_every_sub_step():
    sim = _sim(5, robots=2)
    frames = []

    class Out:
        def publish_frame(self):
            frames.append(sim.stamp_ns)

        def publish_status(self):
            pass

        def log(self, level, text):
            pass

        def start_physics(self, period):
            frames.append(('period', round(period, 9)))

        def stop_physics(self):
            pass

        def finish(self, code):
            pass

    now = 100.0
    life = SimLifecycle(
        sim, LifecycleConfig(steps=2, mode='realtime', wait_for_agents=False), Out(), {}, clock=lambda: now
    )
    life.on_watchdog(now)
    assert frames == [('period', 0.01)]
    life.on_physics(now + 0.0305)  # 3 sub-steps due
    assert frames[1:] == [10_000_000, 20_000_000, 30_000_000] and sim.step == 0
    life.on_physics(now + 1.0)
    assert sim.step == 2 and life.phase == 'done' and len(frames) == 1 + 10
    assert frames[-1] == stamp_ns(2, DT)


def test_sub_steps_are_refused_in_lockstep_and_with_the_ground_truth():
    z0, gt = initial_state('flock2d', 3, 0)
    with pytest.raises(ConfigError, match='realtime'):
        SwarmSim('flock2d', z0, DT, 'lockstep', substeps=2)
    with pytest.raises(ConfigError, match='realtime'):
        SwarmSim('flock2d', z0, DT, 'realtime', ground_truth=gt, substeps=2)
