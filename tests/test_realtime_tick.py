"""Realtime ticks on the arrival of the robot's own state (logic/agent/realtime_tick.py).

A realtime agent computes the command of step s when its own state of step s arrives and its
live neighbours' states of step s - tau are in (or a grace has passed), at most once per
control period; the control timer only stops a robot whose own state went stale. The lone
agent and the hosting process run this through the same AgentLogic.
"""

import random

import numpy as np
import pytest

from knode_swarm_ros.core import neighbour_matrix_single
from knode_swarm_ros.logic.agent.agent_logic import AgentConfig, AgentLogic
from knode_swarm_ros.logic.agent.hearing import Hearing
from knode_swarm_ros.logic.agent.hosted import HostedAgents
from knode_swarm_ros.logic.common import ConfigError, stamp_ns

SEC = 1_000_000_000
DT = 0.05  # a 20 Hz policy


class SumPolicy:
    """u = sum of the masked neighbour offsets (numpy stand-in for a policy file); records calls."""

    def __init__(self, tau=0, k=4):
        self.scenario, self.k, self.d_cr, self.tau, self.dt = 'flock2d', k, 50.0, tau, DT
        self.command_limit = None
        self.calls = []

    def __call__(self, Y, mask):
        self.calls.append((np.array(Y), np.array(mask)))
        return ((Y[..., 1:, :2] - Y[..., :1, :2]) * mask[..., 1:, None]).sum(axis=-2)


def logic_for(policy, robot=0, rate=20.0, **kw):
    return AgentLogic(AgentConfig(robot, [0, 1, 2, 3], mode='realtime', control_rate=rate, **kw), policy)


def z(px, py=0.0):
    return np.array([px, py, 0.0, 0.0])


def frame(s):
    """Step s's states of robots 0..3 (they move, so a stale row would show)."""
    return {r: z(r + 0.1 * s, 0.05 * r * s) for r in range(4)}


def test_tick_opens_on_the_own_state_and_waits_for_the_neighbours_of_the_same_step():
    policy = SumPolicy()
    logic = logic_for(policy)
    for r in range(4):  # the waiting phase: every robot heard once
        logic.receive(r, 0, frame(0)[r], 0, wall=0.0)
    assert logic.realtime_poll(0, 0.0).step == 0
    clock = 0
    for s in range(1, 6):
        ns = stamp_ns(s, DT)
        states = frame(s)
        assert logic.receive(0, ns, states[0], clock, wall=s) == 'accepted'  # own state first
        for r in (1, 2):
            logic.receive(r, ns, states[r], clock, wall=s)
            assert logic.realtime_poll(clock, wall=s) is None  # robot 3's state of step s not yet here
        logic.receive(3, ns, states[3], clock, wall=s)
        cmd = logic.realtime_poll(clock, wall=s)
        assert cmd is not None and (cmd.step, cmd.stamp_ns, cmd.neighbours) == (s, ns, 3)
        assert logic.realtime_poll(clock, wall=s) is None  # once per own state
        # Y is the offline rollout's: every robot's state of step s (tau = 0)
        Y, mask = neighbour_matrix_single(0, states[0], np.stack([states[r] for r in range(4)]), 2, 50.0, 4)
        assert np.array_equal(policy.calls[-1][0][0], Y) and np.array_equal(policy.calls[-1][1][0], mask)
        clock = ns  # the simulator's /clock follows the states of its step
    assert logic.counters['commands'] == 6 and logic.counters['late_ticks'] == 0


def test_a_duplicate_or_older_own_state_opens_no_second_tick():
    logic = logic_for(SumPolicy())
    ns = stamp_ns(3, DT)
    for r in range(4):
        logic.receive(r, ns, frame(3)[r], 0, wall=0.0)
    assert logic.realtime_poll(0, 0.0).step == 3
    assert logic.receive(0, ns, frame(3)[0], 0, wall=0.0) == 'duplicate'
    assert logic.realtime_poll(0, 1.0) is None
    assert logic.receive(0, stamp_ns(2, DT), frame(2)[0], 0, wall=1.0) == 'accepted'  # late, older
    assert logic.realtime_poll(0, 2.0) is None
    assert logic.counters['commands'] == 1


def test_ticks_are_limited_to_the_control_rate_with_a_quarter_period_of_stamp_jitter():
    logic = logic_for(SumPolicy(), rate=10.0)  # 0.1 s period, states every 0.05 s
    ticked = []
    for s in range(8):
        ns = stamp_ns(s, DT)
        for r in range(4):
            logic.receive(r, ns, frame(s)[r], 0, wall=s)
        cmd = logic.realtime_poll(0, wall=s)
        if cmd is not None:
            ticked.append(cmd.step)
    assert ticked == [0, 2, 4, 6]
    # a robot's stamps jitter: 0.08 s after the last tick still opens one (>= 0.075 s), 0.07 s does not
    jitter = logic_for(SumPolicy(), rate=10.0)
    for ns, opens in ((SEC, True), (SEC + 70_000_000, False), (SEC + 80_000_000, True)):
        jitter.receive(0, ns, z(0), 0, wall=0.0)
        assert (jitter.ticks.pending is not None) == opens
        jitter.ticks.pending = None


def test_faster_odometry_gives_control_rate_ticks_on_average():
    from knode_swarm_ros.logic.agent.realtime_tick import TickOnState

    ticks = TickOnState(0.05, 0.025)  # 20 Hz control
    ms = 1_000_000
    opened = [t for t in range(0, 1000, 20) if ticks.own_state(t // 50, t * ms, 0.0)]  # 50 Hz odometry, 1 s
    assert len(opened) == 20 and opened[:4] == [0, 40, 100, 140]
    jittered = TickOnState(0.05, 0.025)  # 20 Hz odometry with +-10 ms jitter: every state ticks
    assert all(jittered.own_state(k, (50 * k + (10 if k % 2 else -10) + 10) * ms, 0.0) for k in range(40))
    assert not jittered.own_state(39, 1980 * ms, 0.0)  # a second state 10 ms after the last tick
    assert (
        jittered.own_state(80, 4000 * ms, 0.0) and jittered.next_ns == 4050 * ms
    )  # after a silence: a new grid


def test_a_late_neighbour_is_taken_at_its_newest_state_once_the_grace_has_passed():
    logic = logic_for(SumPolicy())
    grace = logic.ticks.grace_s
    assert grace == pytest.approx(DT / 2)
    for r in range(4):
        logic.receive(r, stamp_ns(0, DT), frame(0)[r], 0, wall=0.0)
    assert logic.realtime_poll(0, 0.0).neighbours == 3
    ns = stamp_ns(1, DT)
    for r in (0, 1, 2):  # robot 3's state of step 1 is late
        logic.receive(r, ns, frame(1)[r], ns, wall=10.0)
    assert logic.realtime_poll(ns, 10.0 + grace * 0.99) is None
    cmd = logic.realtime_poll(ns, 10.0 + grace)
    assert cmd is not None and cmd.step == 1 and cmd.neighbours == 3
    assert logic.counters['late_ticks'] == 1
    # the row of robot 3 is its state of step 0 (newest at or before step 1)
    Y = logic.policy.calls[-1][0][0]
    assert any(np.array_equal(row, frame(0)[3]) for row in Y)


def test_before_the_clock_runs_every_robot_is_awaited_and_a_late_state_reopens_the_tick():
    policy = SumPolicy()
    logic = logic_for(policy)
    logic.receive(0, 0, frame(0)[0], 0, wall=0.0)  # the simulator's initial state, clock not running
    logic.receive(1, 0, frame(0)[1], 0, wall=0.0)
    assert logic.realtime_poll(0, 0.0) is None  # robots 2 and 3 never heard: awaited all the same
    first = logic.realtime_poll(0, 1.0)  # the grace passed
    assert first.step == 0 and first.neighbours == 1 and logic.counters['late_ticks'] == 1
    logic.receive(2, 0, frame(0)[2], 0, wall=1.1)  # late: the tick opens again, still missing robot 3
    assert logic.realtime_poll(0, 1.1) is None
    logic.receive(3, 0, frame(0)[3], 0, wall=1.2)
    again = logic.realtime_poll(0, 1.2)  # complete now: computed again, same stamp
    assert again.step == 0 and again.stamp_ns == 0 and again.neighbours == 3
    assert logic.receive(0, 0, frame(0)[0], 0, wall=2.0) == 'duplicate'
    assert logic.realtime_poll(0, 9.0) is None  # complete: no third computation
    assert logic.counters['commands'] == 2 and logic.counters['late_ticks'] == 1


def test_a_repeated_own_state_reopens_a_tick_computed_with_states_missing():
    logic = logic_for(SumPolicy())
    logic.receive(0, 0, frame(0)[0], 0, wall=0.0)
    assert logic.realtime_poll(0, 1.0).neighbours == 0  # alone, at the grace
    assert logic.receive(0, 0, frame(0)[0], 0, wall=1.5) == 'duplicate'  # re-published while waiting
    assert logic.realtime_poll(0, 1.5) is None
    assert logic.realtime_poll(0, 9.5) is None  # a re-opened tick has no grace: computed only when complete
    for r in (1, 2):
        logic.receive(r, 0, frame(0)[r], 0, wall=10.0)
        assert logic.realtime_poll(0, 10.0) is None
    logic.receive(3, 0, frame(0)[3], 0, wall=10.0)
    assert logic.realtime_poll(0, 10.0).neighbours == 3 and logic.counters['late_ticks'] == 1
    assert logic.receive(0, 0, frame(0)[0], 0, wall=11.0) == 'duplicate'  # complete: nothing to re-open
    assert logic.realtime_poll(0, 11.0) is None and logic.counters['commands'] == 2
    later = stamp_ns(1, DT)  # a newer tick computed late, re-opened by a late state once
    for r in (0, 1, 2):
        logic.receive(r, later, frame(1)[r], 0, wall=12.0)
    assert logic.realtime_poll(0, 13.0).neighbours == 3 and logic.ticks.incomplete is not None
    assert logic.receive(0, later, frame(1)[0], 0, wall=13.1) == 'duplicate'  # re-opens (once)
    assert logic.ticks.pending is not None and logic.ticks.deadline == float('inf')
    logic.receive(0, stamp_ns(2, DT), frame(2)[0], 0, wall=13.2)  # a newer own state supersedes it
    assert logic.ticks.pending[0] == 2 and not logic.ticks.reopened


def test_a_neighbour_silent_longer_than_state_timeout_is_not_waited_for():
    logic = logic_for(SumPolicy(), state_timeout=0.5)
    for r in range(4):
        logic.receive(r, SEC, frame(0)[r], SEC, wall=0.0)
    logic.realtime_poll(SEC, 0.0)
    later = SEC + SEC  # robot 3 silent for 1 s > state_timeout: not live
    for r in (0, 1, 2):
        logic.receive(r, later, frame(1)[r], later, wall=5.0)
    cmd = logic.realtime_poll(later, 5.0)  # no grace needed
    assert cmd is not None and cmd.neighbours == 2 and logic.counters['late_ticks'] == 0


def test_the_watchdog_sends_only_stop_commands_for_a_stale_own_state():
    logic = logic_for(SumPolicy(), state_timeout=0.5)
    assert logic.watchdog(SEC) is None  # nothing heard
    for r in range(4):
        logic.receive(r, SEC, frame(0)[r], SEC, wall=0.0)
    assert logic.watchdog(SEC + SEC // 10) is None  # fresh: its arrival ticks, not the timer
    assert logic.realtime_poll(SEC, 0.0) is not None
    stop = logic.watchdog(2 * SEC)
    twin = logic_for(SumPolicy(), state_timeout=0.5, tick_on='timer')
    for r in range(4):
        twin.receive(r, SEC, frame(0)[r], SEC, wall=0.0)
    twin.tick(SEC)
    twin.tick(SEC + SEC // 10)
    assert twin.ticks is None and logic.watchdog(SEC) is None
    assert stop is not None and stop.stop and stop.stamp_ns == 2 * SEC
    assert logic.counters['stop_commands'] == 1


def test_tick_on_is_checked():
    with pytest.raises(ConfigError, match='realtime_tick'):
        logic_for(SumPolicy(), tick_on='clock')


def test_hosted_robots_tick_on_their_own_states_like_lone_agents_in_one_call_per_step():
    policy = SumPolicy()
    ids, hosted = [0, 1, 2, 3], [0, 2, 3]
    lone = {rid: AgentLogic(AgentConfig(rid, ids, 'realtime', control_rate=20.0), policy) for rid in hosted}
    host = HostedAgents(hosted, AgentConfig(0, ids, 'realtime', control_rate=20.0), policy)
    rng = random.Random(3)
    got_host, got_lone = {r: [] for r in hosted}, {r: [] for r in hosted}
    clock = 0
    for s in range(12):
        ns = stamp_ns(s, DT)
        order = ids[:]
        rng.shuffle(order)
        for robot in order:
            if (robot, s) in ((1, 6), (2, 9)):
                continue  # lost: both wait the grace, then use robot 1's state of step 5
            state = frame(s)[robot]
            for rid, logic in lone.items():
                logic.receive(robot, ns, state, clock, wall=s)
                cmd = logic.realtime_poll(clock, wall=s)
                if cmd is not None:
                    got_lone[rid].append(cmd)
            host.receive(robot, ns, state, clock, wall=s)
            for rid, cmd in host.realtime_poll(clock, wall=s):
                got_host[rid].append(cmd)
        late = s + 0.5  # the grace timer
        for rid, logic in lone.items():
            cmd = logic.realtime_poll(clock, wall=late)
            if cmd is not None:
                got_lone[rid].append(cmd)
        for rid, cmd in host.realtime_poll(clock, wall=late):
            got_host[rid].append(cmd)
        if s == 9:  # robot 2's state of step 9 comes after the grace: the ticks computed without it again
            for rid, logic in lone.items():
                logic.receive(2, ns, frame(s)[2], clock, wall=late)
                cmd = logic.realtime_poll(clock, wall=late)
                if cmd is not None:
                    got_lone[rid].append(cmd)
            host.receive(2, ns, frame(s)[2], clock, wall=late)
            got = host.realtime_poll(clock, wall=late)
            # robots 0 and 3 compute step 9 again; robot 2 (hosted), whose own state it is, for the first time
            assert sorted(rid for rid, _ in got) == [0, 2, 3] and all(cmd.neighbours == 3 for _, cmd in got)
            for rid, cmd in got:
                got_host[rid].append(cmd)
        clock = ns
        if s == 0:  # robots heard for the first time in step 0 were not awaited yet
            calls0 = host.calls
    for rid in hosted:
        want = list(range(12)) if rid == 2 else list(range(10)) + [9, 10, 11]
        assert [c.step for c in got_host[rid]] == want
        assert [(c.step, c.stamp_ns, c.neighbours) for c in got_host[rid]] == [
            (c.step, c.stamp_ns, c.neighbours) for c in got_lone[rid]
        ]
        assert np.allclose(
            [c.value for c in got_host[rid]], [c.value for c in got_lone[rid]], rtol=1e-12, atol=1e-12
        )
        assert host.logics[rid].counters == lone[rid].counters
        assert host.logics[rid].counters['late_ticks'] == (2 if rid != 2 else 1)
    assert (
        host.calls - calls0 == 12
    )  # the hosted robots of a step fall due together: one call each (+ step 9's late)


def test_live_count_kept_up_to_date_equals_a_fresh_count():
    rng = random.Random(5)
    ids = list(range(8))
    hearing = Hearing(4, ids, DT, 0, timeout_ns=SEC // 2, future_ns=10 * SEC)
    now = SEC
    for _ in range(400):
        if rng.random() < 0.1:
            now += rng.choice([SEC // 20, SEC // 3, SEC])
        robot = rng.choice(ids)
        stamp = now - rng.randrange(0, SEC)
        hearing.live_count(now)  # counted at this clock, then updated by filing
        hearing.file(robot, stamp, z(robot), None)  # no age check: old states are filed too
        fresh = sum(1 for ns in hearing.newest_ns.values() if ns >= now - SEC // 2)
        assert hearing.live_count(now) == fresh


def test_rate_study_counts_the_steps_a_recording_tracks_the_offline_rollout():
    from training.studies.rate_study import TRACK_TOL, tracked_steps

    rng = np.random.default_rng(0)
    pred = rng.normal(size=(50, 4, 4))
    assert tracked_steps(pred + rng.normal(scale=1e-7, size=pred.shape), pred) == 50  # float32 rounding
    late = pred.copy()
    late[17:, 2, 0] += 10 * TRACK_TOL  # one robot moved by a command applied a step late
    assert tracked_steps(late, pred) == 17
    assert tracked_steps(late[:10], pred) == 10 and tracked_steps(pred, pred[:3]) == 3


def test_a_hosting_process_computes_every_waiting_robot_when_the_first_grace_passes():
    policy = SumPolicy()
    ids = [0, 1, 2, 3]
    host = HostedAgents([0, 1, 2], AgentConfig(0, ids, 'realtime', control_rate=20.0), policy)
    for r in ids:
        host.receive(r, 0, frame(0)[r], 0, wall=0.0)
    assert sorted(rid for rid, _ in host.realtime_poll(0, 0.0)) == [0, 1, 2]
    ns, grace = stamp_ns(1, DT), host.logics[0].ticks.grace_s
    for r, wall in ((0, 10.0), (1, 10.01), (2, 10.02)):  # robot 3's state of step 1 never comes
        host.receive(r, ns, frame(1)[r], ns, wall=wall)
        assert host.realtime_poll(ns, wall) == []
    calls = host.calls
    got = host.realtime_poll(ns, 10.0 + grace)  # robot 0's grace: robots 1 and 2 go with it
    assert sorted(rid for rid, _ in got) == [0, 1, 2] and all(cmd.step == 1 for _, cmd in got)
    assert host.calls == calls + 1 and all(host.logics[r].counters['late_ticks'] == 1 for r in (0, 1, 2))


def test_grace_arm_resets_only_when_a_wait_starts_and_cancels_when_it_ends():
    from knode_swarm_ros.logic.agent.realtime_tick import GraceArm

    class Timer:
        def __init__(self):
            self.calls = []

        def reset(self):
            self.calls.append('reset')

        def cancel(self):
            self.calls.append('cancel')

    t = Timer()
    arm = GraceArm(t)
    for waiting in (False, True, True, True, False, False, True):
        arm.set(waiting)
    # cancelled at creation; a wait that goes on does not restart the grace
    assert t.calls == ['cancel', 'reset', 'cancel', 'reset'] and arm.armed


def test_a_tick_whose_own_state_went_stale_while_waiting_gives_no_command():
    # A process fallen behind its messages: the own state of the pending tick is older than
    # state_timeout by the time the grace passes, so no row of its own is live; the tick is
    # dropped (the watchdog stops the robot) instead of building Y without its own row.
    logic = logic_for(SumPolicy(), state_timeout=0.5)
    for r in range(4):
        logic.receive(r, stamp_ns(0, DT), frame(0)[r], 0, wall=0.0)
    assert logic.realtime_poll(0, 0.0) is not None
    ns = stamp_ns(1, DT)
    logic.receive(0, ns, frame(1)[0], ns, wall=10.0)  # neighbours' states of step 1 never come
    later = ns + SEC  # the clock moved on by a second before the process got to the grace
    assert logic.realtime_poll(later, 10.0 + logic.ticks.grace_s) is None
    assert logic.counters['commands'] == 1
    stop = logic.watchdog(later)
    assert stop is not None and stop.stop
