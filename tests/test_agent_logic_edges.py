"""AgentLogic at its edges: timeouts at exactly their limit, and an agent that
joins a run already under way.

Each test here fails on a mutation that the broader tests in test_nodes_logic.py let
through (a `<` turned into `<=`, the first-step clamp of the delayed step removed).
"""

import re

import numpy as np
import pytest

from knode_swarm_ros.core import neighbour_matrix_single
from knode_swarm_ros.core.scenarios import get_scenario
from knode_swarm_ros.logic.agent.agent_logic import AgentConfig, AgentLogic
from knode_swarm_ros.logic.common import ConfigError, stamp_ns

SEC = 1_000_000_000


class SumPolicy:
    """u = sum of the masked neighbour offsets (numpy stand-in for a policy file)."""

    def __init__(self, tau=0, k=4):
        spec = get_scenario('flock2d')
        self.scenario, self.k, self.d_cr, self.tau, self.dt = 'flock2d', k, 50.0, tau, spec.dt
        self.command_limit = None
        self.calls = []

    def __call__(self, Y, mask):
        self.calls.append((np.array(Y), np.array(mask)))
        return ((Y[..., 1:, :2] - Y[..., :1, :2]) * mask[..., 1:, None]).sum(axis=-2)


def logic_for(policy, robot=0, mode='lockstep', **kw):
    return AgentLogic(AgentConfig(robot, [0, 1, 2, 3], mode=mode, **kw), policy)


def z(px, py=0.0):
    return np.array([px, py, 0.0, 0.0])


def test_a_state_exactly_state_timeout_old_or_future_tolerance_ahead_is_accepted():
    logic = logic_for(SumPolicy(), state_timeout=0.5, future_tolerance=0.25)
    now = 10 * SEC
    assert logic.receive(1, now - SEC // 2, z(1), now) == 'accepted'
    assert logic.receive(1, now - SEC // 2 - 1, z(1), now) == 'too_old'
    assert logic.receive(2, now + SEC // 4, z(2), now) == 'accepted'
    assert logic.receive(2, now + SEC // 4 + 1, z(2), now) == 'too_future'
    assert logic.counters['too_old'] == 1 and logic.counters['too_future'] == 1


def test_lockstep_gives_up_on_a_silent_peer_at_exactly_state_timeout():
    policy = SumPolicy()
    logic = logic_for(policy, state_timeout=0.5)
    for r in range(4):  # every robot heard at step 0; robot 3 then falls silent
        logic.receive(r, 0, z(r), wall=0.0)
    assert logic.lockstep_poll(0.0).step == 0
    for r in (0, 1, 2):
        logic.receive(r, stamp_ns(1, policy.dt), z(r), wall=10.0)
    assert logic.lockstep_poll(10.499) is None
    cmd = logic.lockstep_poll(10.5)  # 10.5 - 10.0 == 0.5 exactly in binary floating point
    assert cmd is not None and cmd.step == 1 and cmd.neighbours == 2
    assert logic.status()['gone'] == [3]


def test_realtime_own_state_exactly_state_timeout_old_still_gives_a_command():
    logic = logic_for(SumPolicy(), mode='realtime', state_timeout=0.5)
    for r in range(4):
        logic.receive(r, 1 * SEC, z(r), 1 * SEC)
    cmd = logic.tick(1 * SEC + SEC // 2)
    assert not cmd.stop and cmd.neighbours == 3
    np.testing.assert_array_equal(cmd.value, [1 + 2 + 3, 0.0])
    assert logic.tick(1 * SEC + SEC // 2 + 1).stop


def test_realtime_neighbour_exactly_state_timeout_silent_still_counts():
    logic = logic_for(SumPolicy(), mode='realtime', state_timeout=0.5)
    for r in range(3):
        logic.receive(r, 2 * SEC, z(r), 2 * SEC)
    logic.receive(3, 2 * SEC - SEC // 2, z(3), 2 * SEC)  # exactly state_timeout before own
    assert logic.tick(2 * SEC).neighbours == 3
    assert logic.tick(2 * SEC + 1).neighbours == 2  # one ns later: silent too long


def test_an_agent_joining_mid_run_with_delay_does_not_wait_for_steps_before_its_first():
    # The swarm is at step 100 when robot 0 starts (or restarts), tau = 2: it never hears the
    # steps before 100, so its first commands use the earliest states it has (as the offline
    # rollout does for t < tau) and come at once, without waiting state_timeout for step 98.
    policy = SumPolicy(tau=2)
    logic = logic_for(policy, state_timeout=0.5)
    dt = policy.dt
    states = {s: {r: z(r + 0.01 * s, 0.1 * r) for r in range(4)} for s in range(100, 106)}
    for s in range(100, 106):
        for r in (3, 1, 2, 0):
            logic.receive(r, stamp_ns(s, dt), states[s][r], wall=0.0)
        cmd = logic.lockstep_poll(0.0)
        assert cmd is not None and cmd.step == s and cmd.neighbours == 3, s
        need = max(s - 2, 100)
        Z = np.stack([states[need][r] for r in range(4)])
        Y, mask = neighbour_matrix_single(0, states[s][0], Z, 2, policy.d_cr, policy.k)
        np.testing.assert_array_equal(policy.calls[-1][0][0], Y)
    assert logic.counters['gave_up'] == 0 and logic.status()['gone'] == []


def test_a_state_without_a_robot_id_is_recorded_as_robot_minus_one():
    logic = logic_for(SumPolicy())
    assert logic.receive(None, 5, z(0)) == 'unknown_id'
    assert logic.last_drop == ('unknown_id', -1, 5)


def test_an_undecodable_message_is_counted_as_received_and_malformed():
    logic = logic_for(SumPolicy())
    assert logic.malformed() == 'malformed' and logic.malformed() == 'malformed'
    assert logic.counters['received'] == 2 and logic.counters['malformed'] == 2
    assert logic.counters['accepted'] == 0 and logic.last_drop == ('malformed', -1, -1)


def test_an_agent_lagging_its_neighbours_still_finds_their_delayed_states():
    # tau = 20: the history kept per robot (4 tau + 8 = 88 steps behind its newest) lets an
    # agent fall 50 steps behind its neighbours and still use their states of step s - tau
    # (a 64-step history would have pruned them and silently used step 86's instead of 80's).
    policy = SumPolicy(tau=20)
    logic = logic_for(policy, state_timeout=0.5)
    dt = policy.dt
    state = lambda s, r: z(r + 0.01 * s, 0.1 * r)  # noqa: E731
    for s in range(0, 151):
        for r in (1, 2, 3):
            logic.receive(r, stamp_ns(s, dt), state(s, r), wall=0.0)
    for s in range(0, 101):
        logic.receive(0, stamp_ns(s, dt), state(s, 0), wall=0.0)
    cmd = logic.lockstep_poll(0.0)
    assert cmd is not None and cmd.step == 100
    Z = np.stack([state(80, r) for r in range(4)])
    Y, _ = neighbour_matrix_single(0, state(100, 0), Z, 2, policy.d_cr, policy.k)
    np.testing.assert_array_equal(policy.calls[-1][0][0], Y)


def test_the_own_stamp_table_stays_bounded_after_late_own_states():
    """``stamps`` (own step -> exact stamp, echoed by the command) holds at most 4 horizon
    entries after any own state that is the newest, even after a burst of late own states in
    decreasing order (each cut only reaches below the late step itself)."""
    policy = SumPolicy()
    logic = logic_for(policy)
    h = logic.buffer.horizon
    sizes = {}
    for phase, steps in (
        ('forward', range(0, 10 * h)),
        ('late', range(9 * h - 2, 3 * h, -1)),
        ('forward again', range(10 * h, 12 * h)),
    ):
        for s in steps:
            assert logic.receive(0, stamp_ns(s, policy.dt), z(0), wall=0.0) == 'accepted'
        sizes[phase] = len(logic.stamps)
    assert sizes['forward'] <= 4 * h and sizes['late'] > 4 * h and sizes['forward again'] <= 4 * h
    # the first own state after the burst cut at its step - horizon (10 h - h): kept from there on
    assert sorted(s for _, s in logic.stamps) == list(range(9 * h, 12 * h))
    assert logic.stamps[(0, 12 * h - 1)] == stamp_ns(12 * h - 1, policy.dt)


def test_a_peer_left_out_whose_state_came_early_is_used_without_waiting():
    """Robot 3 sends its state of step 2 early, then loses step 1: it is left out at step 1,
    and at step 2 its state is already filed, so every needed state is here (more than the
    robots waited for) and the command comes at once, with robot 3 among the neighbours."""
    policy = SumPolicy()
    logic = logic_for(policy, state_timeout=0.5)
    dt = policy.dt
    for r in range(4):
        logic.receive(r, stamp_ns(0, dt), z(r), wall=0.0)
    assert logic.lockstep_poll(0.0).step == 0
    logic.receive(3, stamp_ns(2, dt), z(3.2), wall=0.0)  # early
    for r in (0, 1, 2):
        logic.receive(r, stamp_ns(1, dt), z(r), wall=10.0)  # robot 3's step 1 is lost
    assert logic.lockstep_poll(10.0) is None
    assert logic.lockstep_poll(10.5).neighbours == 2 and logic.left_out == {3}
    for r in (0, 1, 2):
        logic.receive(r, stamp_ns(2, dt), z(r), wall=20.0)
    cmd = logic.lockstep_poll(20.0)
    assert cmd is not None and cmd.step == 2 and cmd.neighbours == 3
    np.testing.assert_allclose(cmd.value, [1 + 2 + 3.2, 0.0])


@pytest.mark.parametrize(
    'ids, shown',
    [([0, 1], '0..1'), ([4, 5, 6], '4..6'), ([2], '[2]'), ([0, 2], '[0, 2]'), ([3, 1, 2], '[3, 1, 2]')],
)
def test_an_id_outside_the_swarm_names_the_ids_as_a_range_when_they_are_one(ids, shown):
    with pytest.raises(ConfigError, match=re.escape(f"is not one of the swarm's robot ids {shown} (")):
        AgentLogic(AgentConfig(9, ids), SumPolicy())


@pytest.mark.parametrize(
    'vx, vy, period_ms, limit',
    [
        (-0.6232744625373522, 0.0413259793472436, 81, 1.0),
        (0.5312512156361892, 0.08905603873921995, 187, 5.0),
        (-1.6979398304606041, 0.030887319354812974, 162, 5.0),
    ],
)
def test_a_braking_stop_ends_exactly_at_rest(vx, vy, period_ms, limit):
    """A stale own state: the robot brakes at most ``limit`` per axis each tick; once an axis'
    brake is below the limit (its velocity used up), every later command on it is exactly 0,
    not float dust (these cases leave ~1e-16 behind without the rest threshold)."""
    logic = logic_for(SumPolicy(), mode='realtime', state_timeout=0.5, command_limit=limit)
    for r in range(4):
        logic.receive(r, 0, np.array([float(r), 0.3 * r, vx if r == 0 else 0.0, vy if r == 0 else 0.0]), 0)
    logic.tick(0)
    values = np.array([logic.tick(SEC + k * period_ms * 1_000_000).value for k in range(8)])
    assert logic.last_command.stop and np.all(np.abs(values) <= limit)
    finished = [axis for axis in values.T if np.any(np.abs(axis) < limit)]
    assert finished
    for axis in finished:
        first = np.flatnonzero(np.abs(axis) < limit)[0]
        assert np.all(axis[first + 1 :] == 0.0), axis


def test_lockstep_never_gives_up_on_a_robot_not_yet_heard():
    """Discovery under load: robot 3's topic is matched long after the others'. Until it is heard
    once it is waited for, however long (the simulator's clock does not run before every agent
    heard every robot), and the first command then uses it."""
    policy = SumPolicy()
    logic = logic_for(policy, state_timeout=0.5)
    dt = policy.dt
    for r in (0, 1, 2):
        logic.receive(r, stamp_ns(0, dt), z(r), wall=0.0)
    assert logic.lockstep_poll(0.6) is None and logic.lockstep_poll(30.0) is None
    assert logic.counters['gave_up'] == 0 and logic.left_out == set()
    logic.receive(3, stamp_ns(0, dt), z(3), wall=30.0)
    cmd = logic.lockstep_poll(30.0)
    assert cmd is not None and cmd.step == 0 and cmd.neighbours == 3
