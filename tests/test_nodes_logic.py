"""The nodes' logic without ROS: agent, simulator and recorder classes, helpers, launcher checks.

These never import rclpy: they drive AgentLogic, SwarmSim and FrameCollector directly,
including a whole lockstep swarm (message delivery shuffled) that must equal core.rollout
bit for bit.
"""

import json
import math
import os

import numpy as np
import pytest

from knode_swarm_ros.core.scenarios import get_scenario
from knode_swarm_ros.logic.agent.agent_logic import AgentConfig, AgentLogic
from knode_swarm_ros.logic.common import (
    ConfigError,
    parse_status,
    percentiles,
    robot_id_list,
    stamp_ns,
    status_json,
    step_of,
)
from knode_swarm_ros.logic.recorder import FrameCollector, swarm_metrics
from knode_swarm_ros.logic.simulator.swarm_sim import (
    SwarmSim,
    initial_state,
    initial_state_from_file,
    make_ground_truth,
)

SEC = 1_000_000_000


class LinearPolicy:
    """A numpy stand-in for a policy file: u = sum of masked neighbour positions - own position."""

    def __init__(self, scenario='flock2d', k=4, d_cr=5.0, tau=0, limit=10.0, scale=1.0):
        spec = get_scenario(scenario)
        self.scenario, self.k, self.d_cr, self.tau, self.dt = scenario, k, d_cr, tau, spec.dt
        self.command_limit = limit
        self.p = spec.position_dim
        self.scale = scale
        self.calls = []

    def __call__(self, Y, mask):
        self.calls.append((np.array(Y), np.array(mask)))
        pos = Y[..., : self.p]
        rel = (pos[:, 1:] - pos[:, :1]) * mask[:, 1:, None]
        return self.scale * rel.sum(axis=1)


def make_logic(policy=None, robot=0, ids=range(4), mode='lockstep', **kw):
    policy = policy or LinearPolicy()
    return AgentLogic(AgentConfig(robot, list(ids), mode=mode, **kw), policy)


def z2(px, py, vx=0.0, vy=0.0):
    return np.array([px, py, vx, vy], dtype=np.float64)


# --- helpers -----------------------------------------------------------------------------
def test_stamps_round_trip_for_awkward_dt():
    for dt in (0.01, 1.0 / 60.0, 0.05):
        for step in list(range(0, 2000)) + [10**6, 10**7 + 3]:
            assert step_of(stamp_ns(step, dt), dt) == step


def test_robot_id_list_and_status_json():
    assert robot_id_list(3) == [0, 1, 2]
    assert robot_id_list(3, [7, 2]) == [2, 7]
    with pytest.raises(ConfigError, match="'robot_ids' holds duplicates"):
        robot_id_list(3, [1, 1])
    with pytest.raises(ConfigError, match="'robots' must be >= 1"):
        robot_id_list(0)
    text = status_json(a=float('nan'), b={3, 1}, c=np.float32(2.5))
    assert parse_status(text) == {'a': None, 'b': [1, 3], 'c': 2.5}
    assert parse_status('not json') is None and parse_status('[1]') is None
    stats = percentiles([1.0, 2.0, 3.0])
    assert stats['count'] == 3 and stats['p50'] == 2.0 and stats['max'] == 3.0
    assert percentiles([])['p99'] is None


# --- agent: input checks ----------------------------------------------------------------------
def test_agent_drops_and_counts_bad_states():
    logic = make_logic(state_timeout=0.5, future_tolerance=0.2)
    now = 10 * SEC
    assert logic.receive(9, now, z2(0, 0), now) == 'unknown_id'
    assert logic.receive(None, now, z2(0, 0), now) == 'unknown_id'
    assert logic.receive(1, now, z2(np.nan, 0), now) == 'non_finite'
    assert logic.receive(1, now, z2(0, np.inf), now) == 'non_finite'
    assert logic.receive(1, now, np.zeros(3), now) == 'bad_size'
    assert logic.receive(1, now - int(0.6 * SEC), z2(0, 0), now) == 'too_old'
    assert logic.receive(1, now + int(0.3 * SEC), z2(0, 0), now) == 'too_future'
    assert logic.receive(1, now + int(0.1 * SEC), z2(0, 0), now) == 'accepted'
    assert logic.receive(1, now + int(0.1 * SEC), z2(5, 5), now) == 'duplicate'
    c = logic.counters
    assert (
        c['unknown_id'],
        c['non_finite'],
        c['bad_size'],
        c['too_old'],
        c['too_future'],
        c['accepted'],
        c['duplicate'],
        c['received'],
    ) == (2, 2, 1, 1, 1, 1, 1, 9)
    assert logic.last_drop[0] == 'too_future'
    # An unknown clock (sim time before the first /clock) skips the age checks.
    assert logic.receive(2, 1 * SEC, z2(0, 0), 0) == 'accepted'
    assert logic.heard() == [1, 2] and logic.missing() == [0, 3] and not logic.ready


def test_agent_config_validation_names_the_parameter():
    with pytest.raises(ConfigError, match="'id' = 7 is not one of the swarm's robot ids 0..3"):
        make_logic(robot=7)
    with pytest.raises(ConfigError, match="'mode' = 'fast'"):
        make_logic(mode='fast')
    with pytest.raises(ConfigError, match="'state_timeout' must be > 0"):
        make_logic(state_timeout=0.0)
    with pytest.raises(ConfigError, match="'future_tolerance' must be >= 0"):
        make_logic(future_tolerance=-1.0)
    with pytest.raises(ConfigError, match="'command_limit' must be >= 0"):
        make_logic(command_limit=float('nan'))


# --- agent: lockstep ----------------------------------------------------------------------------
def test_lockstep_waits_for_every_neighbour_of_the_current_step():
    policy = LinearPolicy(k=4)
    logic = make_logic(policy, robot=1)
    states = {r: z2(r, 0.5 * r) for r in range(4)}
    # Own state first: no command yet, whatever stale neighbour information exists.
    assert logic.receive(1, 0, states[1]) == 'accepted'
    assert logic.lockstep_poll(0.0) is None
    for r in (3, 0):
        logic.receive(r, 0, states[r])
        assert logic.lockstep_poll(0.0) is None
    logic.receive(2, 0, states[2])
    cmd = logic.lockstep_poll(0.0)
    assert cmd is not None and cmd.step == 0 and cmd.stamp_ns == 0 and not cmd.stop
    # Y as the core builds it for robot 1 from the same states.
    from knode_swarm_ros.core import neighbour_matrix

    Z = np.stack([states[r] for r in range(4)])
    Y, mask = neighbour_matrix(Z, Z, 2, policy.d_cr, policy.k)
    assert np.array_equal(policy.calls[-1][0][1], Y[1]) and np.array_equal(policy.calls[-1][1][1], mask[1])
    assert np.array_equal(cmd.value, policy(Y[1:2], mask[1:2])[0])
    assert logic.lockstep_poll(0.0) is None  # answered once
    # Step 1: a peer's state of step 1 before the own one must not trigger anything.
    logic.receive(0, stamp_ns(1, policy.dt), states[0])
    assert logic.lockstep_poll(0.0) is None
    logic.receive(1, stamp_ns(1, policy.dt), states[1])
    assert logic.lockstep_poll(0.0) is None  # robots 2 and 3 still missing for step 1


def test_lockstep_with_delay_needs_the_delayed_step_and_resends_on_repeat():
    policy = LinearPolicy(k=4, tau=1)
    logic = make_logic(policy, robot=0)
    dt = policy.dt
    for r in range(4):
        logic.receive(r, 0, z2(r, 0))
    first = logic.lockstep_poll(0.0)
    assert first is not None and first.step == 0  # t < tau: the earliest state is used
    logic.receive(0, stamp_ns(1, dt), z2(0.1, 0))
    second = logic.lockstep_poll(0.0)  # needs neighbours at step 0 only: all here
    assert second is not None and second.step == 1 and second.stamp_ns == stamp_ns(1, dt)
    Y = policy.calls[-1][0][0]
    assert np.array_equal(Y[0], z2(0.1, 0)) and np.array_equal(Y[1], z2(1, 0))  # own now, peer delayed
    # The simulator re-sends state 1 (a lost command): the same command again.
    assert logic.receive(0, stamp_ns(1, dt), z2(0.1, 0)) == 'duplicate'
    again = logic.lockstep_poll(0.0)
    assert again.resend and again.stamp_ns == second.stamp_ns and np.array_equal(again.value, second.value)
    assert logic.counters['resent'] == 1
    logic.receive(0, stamp_ns(2, dt), z2(0.2, 0))
    assert logic.lockstep_poll(0.0) is None  # step 1 of peers still missing


def test_lockstep_leaves_out_a_silent_peer_after_the_timeout_and_takes_it_back():
    logic = make_logic(LinearPolicy(k=4), robot=0, state_timeout=0.5)
    for r in range(4):
        logic.receive(r, 0, z2(r, 0))
    assert logic.lockstep_poll(0.0) is not None
    dt = logic.dt
    for r in (0, 1, 2):
        logic.receive(r, stamp_ns(1, dt), z2(r, 0), wall=10.0)
    assert logic.lockstep_poll(10.2) is None
    cmd = logic.lockstep_poll(10.6)
    assert cmd is not None and cmd.step == 1 and cmd.neighbours == 2
    assert logic.counters['gave_up'] == 1 and logic.status()['gone'] == [3]
    assert any('robot(s) [3]' in e for e in logic.drain_events())
    # Step 2: robot 3 is gone, so nobody waits for it ...
    for r in (0, 1, 2):
        logic.receive(r, stamp_ns(2, dt), z2(r, 0), wall=11.0)
    assert logic.lockstep_poll(11.0).step == 2
    # ... until it is heard again.
    logic.receive(3, stamp_ns(3, dt), z2(3, 0), wall=12.0)
    assert logic.status()['gone'] == []
    logic.receive(0, stamp_ns(4, dt), z2(0, 0), wall=12.0)
    assert logic.lockstep_poll(12.0) is None


# --- agent: realtime --------------------------------------------------------------------------
def test_realtime_stale_own_state_gives_a_stop_command():
    logic = make_logic(LinearPolicy(k=4), robot=0, mode='realtime', state_timeout=0.5)
    assert logic.tick(1 * SEC) is None  # nothing heard yet
    for r in range(4):
        logic.receive(r, 1 * SEC, z2(r, 0), 1 * SEC)
    cmd = logic.tick(1 * SEC + int(0.1 * SEC))
    assert not cmd.stop and cmd.stamp_ns == 1 * SEC and cmd.neighbours == 3
    stop = logic.tick(2 * SEC)
    assert stop.stop and stop.step is None and stop.stamp_ns == 2 * SEC
    # flock2d is acceleration-commanded: the stop brakes against the held command (+6, 0), it does
    # not coast with zero acceleration (tests/test_saturation_and_stop.py has the details).
    assert stop.value[0] < 0 and stop.value[1] == 0
    assert logic.counters['stop_commands'] == 1


def test_realtime_drops_silent_neighbours_and_uses_delayed_states():
    policy = LinearPolicy(k=4, tau=2)
    logic = make_logic(policy, robot=0, mode='realtime', state_timeout=0.5)
    dt = policy.dt
    logic.receive(3, stamp_ns(0, dt), z2(3, 0), 0)  # heard once, long ago
    for s in range(100, 106):
        for r in (0, 1, 2):
            logic.receive(r, stamp_ns(s, dt), z2(r + s / 100.0, 0), 0)
    now = stamp_ns(105, dt)
    cmd = logic.tick(now)
    assert cmd.step == 105 and cmd.neighbours == 2  # robot 3 silent for > 0.5 s
    Y = policy.calls[-1][0][0]
    assert np.allclose(Y[0], z2(1.05, 0))  # own row: now
    assert np.allclose(Y[1], z2(1 + 1.03, 0))  # robot 1 at step 103 = 105 - tau


def test_commands_are_clipped_and_non_finite_policy_output_gives_zero():
    logic = make_logic(
        LinearPolicy(k=4, scale=100.0, limit=None), robot=0, mode='realtime', command_limit=2.5
    )
    for r in range(4):
        logic.receive(r, SEC, z2(r, r), SEC)
    cmd = logic.tick(SEC)
    assert np.all(np.abs(cmd.value) <= 2.5) and np.any(np.abs(cmd.value) == 2.5)
    assert logic.counters['clipped'] == 1
    # The tighter of the parameter and the policy's limit applies.
    assert make_logic(LinearPolicy(limit=10.0), command_limit=3.0).limit == 3.0
    assert make_logic(LinearPolicy(limit=1.0), command_limit=3.0).limit == 1.0
    assert make_logic(LinearPolicy(limit=1.0)).limit == 1.0

    class Broken(LinearPolicy):
        def __call__(self, Y, mask):
            return np.full((Y.shape[0], 2), np.nan)

    broken = make_logic(Broken(k=4), robot=0, mode='realtime')
    for r in range(4):
        broken.receive(r, SEC, z2(r, r), SEC)
    out = broken.tick(SEC)
    assert np.all(out.value == 0) and broken.counters['non_finite_command'] == 1


def test_agent_command_matches_the_core_for_hand_made_neighbours(untrained_policies):
    from knode_swarm_ros.core import load_policy, neighbour_matrix_single

    policy = load_policy(untrained_policies['flock2d'])
    rng = np.random.default_rng(5)
    Z = np.concatenate([rng.uniform(-3, 3, (6, 2)), rng.normal(size=(6, 2))], axis=1)
    for parity in (True, False):
        logic = AgentLogic(AgentConfig(2, list(range(6)), 'lockstep', parity_batch=parity), policy)
        for r in range(6):
            logic.receive(r, 0, Z[r])
        cmd = logic.lockstep_poll(0.0)
        Y, mask = neighbour_matrix_single(2, Z[2], Z, 2, policy.d_cr, policy.k)
        expected = np.clip(policy(Y[None], mask[None])[0], -10, 10)
        assert np.allclose(cmd.value, expected, atol=1e-6)


# --- a whole lockstep swarm without ROS equals core.rollout bit for bit ---------------------------
def _lockstep_swarm(policy, z0, steps, rng, parity=True):
    n = z0.shape[0]
    agents = [
        AgentLogic(AgentConfig(i, list(range(n)), 'lockstep', parity_batch=parity), policy) for i in range(n)
    ]
    sim = SwarmSim(policy.scenario, z0, policy.dt, 'lockstep')
    frames = [sim.states.copy()]
    for _ in range(steps):
        ns = sim.stamp_ns
        deliveries = [(i, r) for i in range(n) for r in range(n)]
        rng.shuffle(deliveries)  # any arrival order, own state first or last
        for i, r in deliveries:
            agents[i].receive(r, ns, sim.states[r].copy())
            cmd = agents[i].lockstep_poll(0.0)
            if cmd is not None:
                assert sim.offer(i, cmd.stamp_ns, cmd.value) == 'accepted'
        assert sim.can_advance()
        frames.append(sim.advance().copy())
    return np.stack(frames)


@pytest.mark.parametrize('scenario', ['flock2d', 'boids3d'])
def test_lockstep_protocol_equals_core_rollout_exactly(untrained_policies, scenario):
    from knode_swarm_ros.core import load_policy
    from knode_swarm_ros.core.rollout import (
        rollout,  # not core.rollout: see the report (module shadows function)
    )

    policy = load_policy(untrained_policies[scenario])
    z0, _ = initial_state(scenario, 7, seed=1)
    steps = 40
    got = _lockstep_swarm(policy, z0, steps, np.random.default_rng(0))
    ref = rollout(policy, z0, steps, scenario, policy.d_cr, policy.k, policy.tau, policy.dt)
    assert np.array_equal(got, ref), np.abs(got - ref).max()


# --- simulator --------------------------------------------------------------------------------
def test_simulator_lockstep_bookkeeping_lost_and_rejoined_robots():
    spec = get_scenario('flock2d')
    z0 = np.array([z2(0, 0, 1, 0), z2(2, 0, 0, 1)])
    sim = SwarmSim('flock2d', z0, spec.dt, 'lockstep')
    assert not sim.can_advance() and sim.waiting() == [0, 1]
    assert sim.offer(0, stamp_ns(1, spec.dt), [1, 1]) == 'future'
    assert sim.offer(0, 0, [1.0, 0.0]) == 'accepted'
    assert sim.offer(0, 0, [9.0, 9.0]) == 'stale'  # a re-sent command does not replace the first
    assert sim.offer(5, 0, [0, 0]) == 'unknown_id'
    assert sim.offer(1, 0, [np.nan, 0]) == 'non_finite'
    assert sim.offer(1, 0, [0, 0, 0]) == 'bad_size'
    assert sim.waiting() == [1] and not sim.can_advance()
    # each counter is the number of times its outcome was returned, from 0
    assert sim.counters.__dict__ == dict(
        accepted=1,
        unknown_id=1,
        bad_size=1,
        non_finite=1,
        stale=1,
        future=1,
        rejoined=0,
        malformed=0,
        commanded=1,
        zeroed=0,
        lost_events=0,
    )
    sim.note_published(100.0)
    assert sim.overdue(101.0, 5.0) == [] and sim.overdue(106.0, 5.0) == [1]
    sim.declare_lost([1])
    assert sim.can_advance()
    before = sim.states.copy()
    sim.advance()
    from knode_swarm_ros.core import zoh_step

    # Robot 1 (velocity (0, 1)) is stopped, braking to rest (-v / dt without a stop_limit), and not waited for.
    assert np.array_equal(
        sim.states, zoh_step(before, np.array([[1.0, 0.0], [0.0, -1.0 / spec.dt]]), spec, spec.dt)
    )
    assert sim.states[1, 3] == 0.0
    assert sim.waiting() == [0]
    assert sim.offer(0, sim.stamp_ns, [2.0, 0.0]) == 'accepted'
    assert sim.offer(1, sim.stamp_ns, [0.0, 3.0]) == 'rejoined'
    assert sim.lost == set() and sim.counters.rejoined == 1 and sim.counters.lost_events == 1


def test_simulator_realtime_zeroes_old_commands_and_keeps_the_newest():
    spec = get_scenario('flock2d')
    sim = SwarmSim('flock2d', np.array([z2(0, 0), z2(3, 0)]), spec.dt, 'realtime', command_timeout=0.05)
    assert sim.offer(0, 0, [1.0, 0.0]) == 'accepted'
    for _ in range(3):
        sim.advance()
    assert sim.offer(0, stamp_ns(2, spec.dt), [2.0, 0.0]) == 'accepted'
    assert sim.offer(0, stamp_ns(1, spec.dt), [5.0, 0.0]) == 'stale'
    sim.advance()
    assert np.array_equal(sim.applied[0], [2.0, 0.0]) and np.array_equal(sim.applied[1], [0.0, 0.0])
    for _ in range(10):
        sim.advance()
    assert np.array_equal(sim.applied[0], [0.0, 0.0])  # older than 0.05 s
    assert sim.counters.zeroed > 10


def test_simulator_says_which_robots_it_stops_for_silence_and_since_when():
    spec = get_scenario('flock2d')
    sim = SwarmSim('flock2d', np.array([z2(0, 0), z2(3, 0)]), spec.dt, 'lockstep')
    assert sim.offer(0, 0, [0.0, 0.0]) == 'accepted'
    sim.declare_lost([1])
    sim.advance()
    assert sim.silent_since == {1: 0} and sim.report()['silent_since'] == {'1': 0}
    assert sim.offer(1, sim.stamp_ns, [0.0, 0.0]) == 'rejoined' and sim.silent_since == {}
    # realtime: a robot that never commanded is starting, not silent; one whose commands stopped is
    rt = SwarmSim('flock2d', np.array([z2(0, 0), z2(3, 0)]), spec.dt, 'realtime', command_timeout=0.05)
    assert rt.offer(0, 0, [1.0, 0.0]) == 'accepted'
    for _ in range(10):
        rt.advance()
    assert rt.silent_since == {0: 6}  # 0.05 s = 5 steps after its command of step 0
    assert rt.offer(0, rt.stamp_ns, [1.0, 0.0]) == 'accepted'
    rt.advance()
    assert rt.silent_since == {}


def test_simulator_latency_figures():
    spec = get_scenario('flock2d')
    sim = SwarmSim('flock2d', np.array([z2(0, 0), z2(3, 0)]), spec.dt, 'lockstep')
    sim.note_published(10.0)
    sim.offer(0, 0, [0, 0], wall=10.004)
    sim.offer(1, 0, [0, 0], wall=10.006)
    lat = sim.report()['latency_ms']
    assert lat['count'] == 2 and math.isclose(lat['max'], 6.0, abs_tol=1e-6)


@pytest.mark.parametrize('scenario', ['flock2d', 'boids3d'])
def test_seeded_initial_state_is_the_training_density(scenario):
    from knode_swarm_ros.core.groundtruth import simulate

    z0, swarm = initial_state(scenario, 6, seed=11)
    ref = simulate(scenario, 1, 6, 3, seed=11, progress=False)[0]
    assert np.array_equal(z0, ref[0])
    assert np.allclose(swarm.step()[0], ref[1])


def test_ground_truth_mode_steps_the_ground_truth():
    from knode_swarm_ros.core.groundtruth import TannerSwarm

    z0, _ = initial_state('flock2d', 5, seed=2)
    sim = SwarmSim('flock2d', z0, 0.01, 'lockstep', ground_truth=make_ground_truth('flock2d', z0))
    ref = TannerSwarm(z0[None])
    assert sim.can_advance()
    for _ in range(20):
        assert np.array_equal(sim.advance(), ref.step()[0])
    with pytest.raises(ConfigError, match="'dt' = 0.02"):
        make_ground_truth('flock2d', z0, dt=0.02)
    with pytest.raises(ConfigError, match="'variant' = 'nope'"):
        make_ground_truth('flock2d', z0, 'nope')


@pytest.mark.parametrize(
    'limit, kept',
    [
        (None, None),
        (0.0, None),
        (0.5, 0.5),
        (-0.5, 'refused'),
        (-1.0, 'refused'),
        (float('inf'), 'refused'),
        (float('nan'), 'refused'),
    ],
)
def test_simulator_stop_limit_is_none_zero_or_a_finite_positive_value(limit, kept):
    z0 = np.array([z2(0, 0, 1, 0)])
    if kept == 'refused':
        with pytest.raises(ConfigError, match="'command_limit' must be >= 0"):
            SwarmSim('flock2d', z0, 0.01, 'realtime', stop_limit=limit)
    else:
        assert SwarmSim('flock2d', z0, 0.01, 'realtime', stop_limit=limit).stop_limit == kept


def test_simulator_latency_table_keeps_the_newest_257_to_512_published_steps():
    """A command stamped with step s gives a latency sample while step s's publish time is
    kept: all of the first 512 steps, then the table drops its oldest 256 at 513 entries."""
    sim = SwarmSim('flock2d', np.array([z2(0, 0), z2(3, 0)]), 0.01, 'realtime')
    for s in range(512):
        sim.note_published(float(s))
        sim.advance()
    sim.offer(0, stamp_ns(0, 0.01), [0.0, 0.0], wall=1000.0)  # 512 kept: step 0 among them
    sim.note_published(512.0)  # 513: steps 0..255 dropped
    sim.offer(1, stamp_ns(255, 0.01), [0.0, 0.0], wall=1000.0)
    sim.offer(1, stamp_ns(256, 0.01), [0.0, 0.0], wall=1000.0)
    assert sim.latency == [1000.0, 1000.0 - 256]


def test_initial_state_from_file_checks_the_file(tmp_path):
    from knode_swarm_ros.core import save_trajectories

    states = np.random.default_rng(0).normal(size=(2, 3, 4, 4))
    path = tmp_path / 'init.npz'
    save_trajectories(path, states, 0.01, 'flock2d')
    z0, where, traj = initial_state_from_file(f'{path}:1', 'flock2d')
    assert np.array_equal(z0, states[1, 0]) and traj == 1
    for traj in (2, 3, 10):  # every index past the end, not only the first one
        with pytest.raises(
            ConfigError, match=rf'trajectory {traj} does not exist \(.* holds 2, indices 0\.\.1\)'
        ):
            initial_state_from_file(f'{path}:{traj}', 'flock2d')
    with pytest.raises(ConfigError, match="'robots' = 5 but trajectory 0"):
        initial_state_from_file(str(path), 'flock2d', robots=5)
    with pytest.raises(ConfigError, match="field 'scenario'"):
        initial_state_from_file(str(path), 'boids3d')
    with pytest.raises(ConfigError, match='no such file'):
        initial_state_from_file(str(tmp_path / 'missing.npz'), 'flock2d')


# --- recorder ---------------------------------------------------------------------------------
def test_frame_collector_progress_fill_and_grid():
    fc = FrameCollector('flock2d', 2)
    fc.set_every(5)
    assert fc.add(0, 0, z2(0, 0)) == 'accepted' and fc.progress == -1
    assert fc.add(1, 0, z2(1, 0)) == 'accepted' and fc.progress == 0 and fc.ready
    assert fc.add(1, 0, z2(9, 9)) == 'duplicate'
    assert fc.add(2, 5, z2(0, 0)) == 'unknown_id'
    assert fc.add(0, 5, z2(np.nan, 0)) == 'non_finite'
    fc.add(0, 5, z2(0.5, 0))  # robot 1 lost at step 5
    fc.add(0, 10, z2(1.0, 0))
    fc.add(1, 10, z2(1.1, 0))
    assert fc.progress == 0 and fc.complete(10) and not fc.complete(5)
    states, info = fc.build(5)
    assert states.shape == (3, 2, 4)
    assert np.array_equal(states[1, 1], z2(1, 0))  # filled from the previous frame
    assert info == {
        'first_step': 0,
        'last_step': 10,
        'frame_every': 5,
        'frames': 3,
        'filled_entries': 1,
        'incomplete_frames': 1,
    }
    assert fc.infer_every() == 5
    fc.add(1, 5, z2(1.05, 0))
    assert fc.progress == 10


def test_swarm_metrics_match_the_core():
    from knode_swarm_ros.core import amd, avd

    frame = np.random.default_rng(1).normal(size=(5, 6))
    a, m = swarm_metrics(frame, 'boids3d')
    assert a == pytest.approx(avd(frame[:, 3:])) and m == pytest.approx(amd(frame[:, :3]))
    assert all(math.isnan(x) for x in swarm_metrics(frame[:1], 'boids3d'))


# --- launcher (no processes started) --------------------------------------------------------------
def _swarm_main(argv, capsys):
    from knode_swarm_ros.nodes import swarm

    with pytest.raises(SystemExit) as exc:
        swarm.main(argv)
    return exc.value.code, capsys.readouterr()


def test_launcher_refuses_bad_arguments_before_starting_anything(tmp_path, capsys, untrained_policies):
    out = str(tmp_path / 'run.npz')
    code, cap = _swarm_main(['--robots', '0', '--record', out], capsys)
    assert code == 2 and '--robots must be in 1..10000' in cap.err and 'got 0' in cap.err
    code, cap = _swarm_main(['--policy', str(tmp_path / 'missing.pt'), '--record', out], capsys)
    assert code == 2 and 'missing.pt: no such file' in cap.err
    code, cap = _swarm_main(
        ['--scenario', 'boids3d', '--policy', str(untrained_policies['flock2d']), '--record', out], capsys
    )
    assert code == 2 and 'is for flock2d' in cap.err
    code, cap = _swarm_main(['--record', str(tmp_path / 'run.txt'), '--ground-truth'], capsys)
    assert code == 2 and 'must end with .npz' in cap.err
    from knode_swarm_ros.core import save_trajectories

    save_trajectories(tmp_path / 'init.npz', np.zeros((1, 1, 3, 4)) + np.arange(3)[:, None], 0.01, 'flock2d')
    code, cap = _swarm_main(
        ['--ground-truth', '--robots', '4', '--init', str(tmp_path / 'init.npz'), '--record', out], capsys
    )
    assert code == 2 and '--robots 4 but --init' in cap.err and 'has 3 robots' in cap.err
    code, cap = _swarm_main(['--ground-truth', '--variant', 'nope', '--record', out], capsys)
    assert code == 2 and "--variant 'nope'" in cap.err
    assert not os.path.exists(out)


def test_launcher_commands_carry_ros_args(tmp_path, untrained_policies):
    from knode_swarm_ros.nodes import swarm

    args = swarm.build_parser().parse_args(
        [
            '--robots',
            '3',
            '--policy',
            str(untrained_policies['boids3d']),
            '--record',
            str(tmp_path / 'r.npz'),
            '--log-dir',
            str(tmp_path / 'logs'),
        ]
    )
    plan = swarm.plan_run(args)
    assert plan.scenario == 'boids3d' and plan.dt == pytest.approx(1 / 60) and plan.figure.suffix == '.png'
    assert swarm.DOMAIN_RANGE[0] <= plan.domain_id <= swarm.DOMAIN_RANGE[1]
    cmds = swarm.node_commands(plan)
    assert sorted(cmds) == ['agent_0', 'agent_1', 'agent_2', 'recorder', 'simulator']
    agent = cmds['agent_2']
    assert agent[1:3] == ['-m', 'knode_swarm_ros.nodes.agent'] and agent[3] == '--ros-args'
    assert 'id:=2' in agent
    import yaml

    params = yaml.safe_load(open(agent[agent.index('--params-file') + 1]))['/**']['ros__parameters']
    assert params['scenario'] == 'boids3d' and params['mode'] == 'lockstep' and params['use_sim_time']
    sim = yaml.safe_load(open(cmds['simulator'][-1]))['/**']['ros__parameters']
    assert sim['dt'] == pytest.approx(1 / 60) and sim['wait_for_recorder'] and sim['robots'] == 3
    env = swarm.child_environment(77)
    assert env['ROS_DOMAIN_ID'] == '77' and env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'
    assert ('LD_LIBRARY_PATH' in env) == ('LD_LIBRARY_PATH' in os.environ)


def test_shm_cleanup_removes_only_new_unlocked_fastdds_files(tmp_path, monkeypatch):
    import fcntl

    from knode_swarm_ros.nodes import swarm

    monkeypatch.setattr(swarm.shm, 'SHM_DIR', tmp_path)  # the module that reads it
    (tmp_path / 'fastrtps_old').write_bytes(b'')
    (tmp_path / 'fastrtps_old_el').write_bytes(b'')
    (tmp_path / 'fastrtps_port7417').write_bytes(b'')  # an old orphan: not ours to judge
    before = swarm.shm_snapshot()
    for name in (
        'fastrtps_0123456789abcdef',
        'fastrtps_0123456789abcdef_el',
        'fastrtps_port7411',
        'fastrtps_port7411_el',
        'sem.fastrtps_port7411_mutex',
        'fastrtps_1111111111111111',
        'fastrtps_1111111111111111_el',
        'fastrtps_port7413',
        'sem.fastrtps_port7413_mutex',
        'fastrtps_port7415',
        'fastrtps_port7415_el',
        'unrelated_file',
    ):
        (tmp_path / name).write_bytes(b'')
    with (
        open(tmp_path / 'fastrtps_1111111111111111_el', 'ab') as held,
        open(tmp_path / 'fastrtps_port7415_el', 'ab') as port,
    ):  # a live process's segment and port
        fcntl.flock(held, fcntl.LOCK_EX)
        fcntl.flock(port, fcntl.LOCK_EX)
        removed = swarm.shm_cleanup(before)
    assert sorted(removed) == [
        'fastrtps_0123456789abcdef',
        'fastrtps_0123456789abcdef_el',
        'fastrtps_port7411',
        'fastrtps_port7411_el',
        'fastrtps_port7413',
        'sem.fastrtps_port7411_mutex',
        'sem.fastrtps_port7413_mutex',
    ]
    left = sorted(os.listdir(tmp_path))
    assert left == [
        'fastrtps_1111111111111111',
        'fastrtps_1111111111111111_el',
        'fastrtps_old',
        'fastrtps_old_el',
        'fastrtps_port7415',
        'fastrtps_port7415_el',
        'fastrtps_port7417',
        'unrelated_file',
    ]


def test_shipped_config_files_are_valid_parameter_files():
    import yaml

    root = os.path.join(os.path.dirname(__file__), '..', 'config')
    for scenario in ('flock2d', 'boids3d'):
        for node in ('agent', 'simulator'):
            data = yaml.safe_load(open(os.path.join(root, f'{node}_{scenario}.yaml')))
            params = data['/**']['ros__parameters']
            assert params['scenario'] == scenario
            assert all(not isinstance(v, dict) for v in params.values())
    assert json.dumps(params)  # plain values only


def test_simulator_latency_dedup_set_is_cleared_only_past_100000_samples():
    """One latency sample per (robot, step): the set that remembers them holds up to 100 000
    and is cleared at the next one, so a repeat of the 100 000th pair is still not counted."""
    n = 1000
    sim = SwarmSim('flock2d', np.zeros((n, 4)), 0.01, 'realtime')
    u = np.zeros(2)
    for s in range(100):
        sim.note_published(float(s))
        ns = stamp_ns(s, 0.01)
        for r in range(n):
            sim.offer(r, ns, u, wall=s + 0.5)
        sim.advance()
    assert len(sim.latency) == 100_000 and set(sim.latency) == {0.5}
    sim.offer(n - 1, stamp_ns(99, 0.01), u, wall=200.0)  # the same pair again: no second sample
    assert len(sim.latency) == 100_000
    sim.offer(0, stamp_ns(100, 0.01), u, wall=200.0)  # step 100 was never published: no sample
    sim.note_published(300.0)
    sim.offer(0, stamp_ns(100, 0.01), u, wall=300.25)  # the 100 001st pair: counted, the set cleared
    assert len(sim.latency) == 100_001 and sim.latency[-1] == 0.25


@pytest.mark.parametrize('shape', [(0, 4), (3, 5), (4,), (2, 3, 4)])
def test_simulator_refuses_an_initial_state_of_the_wrong_shape(shape):
    with pytest.raises(ConfigError, match=r'initial state must be \[n, 4\]'):
        SwarmSim('flock2d', np.zeros(shape), 0.01)
