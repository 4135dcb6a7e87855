"""One saturation rule (core.saturation) for the offline rollout and
the agent, and stops that brake acceleration-commanded robots to rest instead of letting them coast."""

import numpy as np
import pytest

from knode_swarm_ros.core.rollout import rollout
from knode_swarm_ros.core.saturation import effective_limit, saturate, stop_command
from knode_swarm_ros.core.scenarios import get_scenario
from knode_swarm_ros.logic.agent.agent_logic import AgentConfig, AgentLogic
from knode_swarm_ros.logic.common import dt_mismatch
from knode_swarm_ros.logic.simulator.swarm_sim import SwarmSim

SEC = 1_000_000_000


class HugePolicy:
    """Returns 1e30 on every axis: a policy file whose own saturation is missing."""

    def __init__(self, scenario='flock2d', limit=10.0, k=4):
        spec = get_scenario(scenario)
        self.scenario, self.k, self.d_cr, self.tau, self.dt = scenario, k, 5.0, 0, spec.dt
        self.command_limit = limit
        self.m = spec.command_dim

    def __call__(self, Y, mask):
        return np.full((Y.shape[0], self.m), 1e30)


def test_saturate_clips_per_axis_and_limits_only_lower():
    np.testing.assert_array_equal(
        saturate([[1e30, -3.0], [-1e30, 12.0]], 10.0), [[10.0, -3.0], [-10.0, 10.0]]
    )
    np.testing.assert_array_equal(saturate([5.0, -50.0], None), [5.0, -50.0])
    assert effective_limit(10.0, 0.0) == 10.0
    assert effective_limit(10.0, 4.0) == 4.0
    assert effective_limit(10.0, 40.0) == 10.0  # a parameter never raises the policy's limit
    assert effective_limit(None, 3.0) == 3.0
    assert effective_limit(None, None) is None
    with pytest.raises(ValueError, match='command_limit'):
        effective_limit(-1.0)


def test_offline_rollout_and_agent_apply_the_same_saturation():
    policy = HugePolicy(limit=10.0)
    spec = get_scenario('flock2d')
    z0 = np.array([[0.0, 0.0, 1.0, 0.0], [1.0, 0.0, 0.0, 1.0]])
    traj = rollout(policy, z0, 1, 'flock2d', policy.d_cr, policy.k, policy.tau, policy.dt)
    # Before: states of 1e30 * dt; now the command is clipped at 10 per axis, as the agent does.
    expected_v = z0[:, 2:] + 10.0 * spec.dt
    np.testing.assert_allclose(traj[1, :, 2:], expected_v, rtol=0, atol=1e-12)
    logic = AgentLogic(AgentConfig(0, [0, 1], mode='lockstep'), policy)
    for r in (0, 1):
        logic.receive(r, 0, z0[r], wall=0.0)
    cmd = logic.lockstep_poll(0.0)
    offline = (traj[1, 0, 2:] - z0[0, 2:]) / spec.dt
    np.testing.assert_allclose(cmd.value, offline, rtol=1e-12)
    # An agent parameter lowers the limit, the rollout can be told the same.
    low = AgentLogic(AgentConfig(0, [0, 1], mode='lockstep', command_limit=2.0), policy)
    for r in (0, 1):
        low.receive(r, 0, z0[r], wall=0.0)
    np.testing.assert_array_equal(low.lockstep_poll(0.0).value, [2.0, 2.0])
    high = AgentLogic(AgentConfig(0, [0, 1], mode='lockstep', command_limit=50.0), policy)
    assert high.limit == 10.0


def test_stop_command_brakes_to_rest_without_reversing():
    v = np.array([[3.0, -0.05], [0.0, 0.0]])
    c = stop_command('acceleration', v, 10.0, 0.01)
    np.testing.assert_allclose(c, [[-10.0, 5.0], [0.0, 0.0]])
    np.testing.assert_array_equal(stop_command('velocity', v, 10.0, 0.01), np.zeros((2, 2)))
    # Held step after step, a double integrator comes to rest and stays there.
    spec = get_scenario('flock2d')
    sim = SwarmSim('flock2d', np.array([[0.0, 0.0, 3.0, -2.0]]), spec.dt, 'realtime', stop_limit=10.0)
    for _ in range(40):
        sim.advance()
    np.testing.assert_array_equal(sim.states[0, 2:], [0.0, 0.0])


def test_simulator_brakes_a_lost_robot_instead_of_holding_its_last_acceleration():
    spec = get_scenario('flock2d')
    z0 = np.array([[0.0, 0.0, 1.0, 0.0], [5.0, 0.0, 0.0, 0.0]])
    sim = SwarmSim('flock2d', z0, spec.dt, 'lockstep', stop_limit=10.0)
    sim.note_published(0.0)
    sim.offer(0, sim.stamp_ns, [10.0, 0.0], 0.0)  # robot 0 accelerates, then falls silent
    sim.offer(1, sim.stamp_ns, [0.0, 0.0], 0.0)
    sim.advance()
    speed_when_lost = sim.states[0, 2]
    sim.declare_lost([0])
    for _ in range(200):
        sim.note_published(0.0)
        sim.offer(1, sim.stamp_ns, [0.0, 0.0], 0.0)
        assert sim.can_advance()
        sim.advance()
    assert speed_when_lost > 1.0
    np.testing.assert_array_equal(sim.states[0, 2:], [0.0, 0.0])  # held at 10 it would be at 21 m/s
    assert sim.states[0, 0] < 1.0


def test_simulator_stops_a_silent_velocity_robot_in_realtime():
    spec = get_scenario('boids3d')
    z0 = np.array([[0.0, 0.0, 0.0, 1.0, 0.0, 0.0]])
    sim = SwarmSim('boids3d', z0, spec.dt, 'realtime', command_timeout=0.05)
    sim.offer(0, 0, [2.0, 0.0, 0.0])
    for _ in range(10):
        sim.advance()
    p = sim.states[0, 0]
    sim.advance()
    assert sim.states[0, 0] == p  # zero velocity once the command is too old


def test_agent_stale_state_stop_brakes_an_acceleration_robot_to_rest():
    policy = HugePolicy(limit=10.0)
    logic = AgentLogic(AgentConfig(0, [0, 1], mode='realtime', state_timeout=0.5), policy)
    logic.receive(0, 1 * SEC, [0.0, 0.0, 2.0, -1.0], 1 * SEC)
    logic.receive(1, 1 * SEC, [3.0, 0.0, 0.0, 0.0], 1 * SEC)
    period = SEC // 20
    now, v, last = 1 * SEC, np.array([2.0, -1.0]), None
    values = []
    for _ in range(80):  # a robot that applies each command for one control period
        cmd = logic.tick(now)
        if last is not None:
            v = v + last * (period * 1e-9)
        last = cmd.value
        if cmd.stop:
            values.append(cmd.value)
        now += period
    assert len(values) > 40
    assert np.all(values[0] == -10.0)  # braking at the limit, not coasting (zero)
    np.testing.assert_allclose(v, 0.0, atol=1e-9)  # brought to rest ...
    np.testing.assert_allclose(values[-1], 0.0, atol=1e-9)  # ... and kept there
    assert max(abs(x).max() for x in values) <= 10.0


def test_agent_stale_state_stop_gives_zero_velocity_for_boids():
    policy = HugePolicy('boids3d', limit=10.0)
    logic = AgentLogic(AgentConfig(0, [0], mode='realtime', state_timeout=0.5), policy)
    logic.receive(0, 1 * SEC, [0.0, 0.0, 0.0, 1.0, 0.0, 0.0], 1 * SEC)
    logic.tick(1 * SEC)
    stop = logic.tick(3 * SEC)
    assert stop.stop and np.all(stop.value == 0.0)


def test_dt_mismatch_names_both_values():
    assert dt_mismatch(0.01, 0.01) is None
    assert dt_mismatch(None, 0.01) is None
    text = dt_mismatch(0.02, 0.01)
    assert '0.02' in text and '0.01' in text
    logic = AgentLogic(AgentConfig(0, [0], mode='lockstep'), HugePolicy())
    assert logic.status()['dt'] == HugePolicy().dt


def test_limits_and_stop_arguments_are_checked_at_their_edges():
    """Mutation survivors: every limit in (0, inf) is accepted as given, everything
    else refused; an unknown command kind is refused whatever its spelling sorts like; dt must be
    finite and > 0."""
    assert effective_limit(0.5) == 0.5 and effective_limit(None, 0.25) == 0.25  # below 1 is fine
    for bad in (-0.5, float('inf'), float('nan')):
        with pytest.raises(ValueError, match='policy command_limit'):
            effective_limit(bad)
        with pytest.raises(ValueError, match='requested command_limit'):
            effective_limit(10.0, bad)
    v = np.array([[2.0, -1.0]])
    for kind in ('aardvark', 'zebra', 'Velocity'):  # sorts before, after, between the two
        with pytest.raises(ValueError, match='unknown command kind'):
            stop_command(kind, v, None, 0.1)
    for dt in (0.0, -0.1, float('inf'), float('nan')):
        with pytest.raises(ValueError, match='dt must be > 0'):
            stop_command('acceleration', v, None, dt)
    np.testing.assert_array_equal(stop_command('acceleration', v, None, 0.5), [[-4.0, 2.0]])
