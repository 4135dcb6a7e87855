"""Hosted agents (several robots in one process) without ROS: they equal lone agents.

* the same message stream (shuffled per step, with a duplicate and a hostile state) gives every
  hosted robot bit for bit the command its lone agent computes, in lockstep, with and without
  delay; in realtime within float32 rounding (a batch of K rounds unlike a batch of 1);
* any split of a swarm over hosting processes, stepped with the simulator's zoh_step, equals
  core.rollout bit for bit, with one policy call per process and step;
* ``ids`` as a list or a range; bad ids are refused with a message naming the parameter.
"""

import random
from dataclasses import replace

import numpy as np
import pytest

from knode_swarm_ros.core import load_policy
from knode_swarm_ros.core.rollout import rollout, zoh_step
from knode_swarm_ros.core.scenarios import get_scenario
from knode_swarm_ros.logic.agent.agent_logic import AgentConfig, AgentLogic
from knode_swarm_ros.logic.agent.hosted import HostedAgents, format_ids, parse_ids
from knode_swarm_ros.logic.common import ConfigError, stamp_ns
from knode_swarm_ros.logic.simulator.swarm_sim import initial_state


@pytest.fixture(scope='module')
def policies(untrained_policies):
    import torch

    torch.set_num_threads(1)
    return {name: load_policy(path) for name, path in untrained_policies.items()}


def _frames(scenario, n, steps, seed):
    z0, swarm = initial_state(scenario, n, seed=seed)
    return [z0] + [swarm.step()[0] for _ in range(steps)]


@pytest.mark.parametrize('scenario', ['flock2d', 'boids3d'])
def test_hosted_robots_equal_lone_agents_in_lockstep(policies, scenario):
    policy = policies[scenario]
    n, hosted = 7, [1, 4, 5]
    ids = list(range(n))
    frames = _frames(scenario, n, 40, seed=2)
    lone = {rid: AgentLogic(AgentConfig(rid, ids, 'lockstep'), policy) for rid in hosted}
    host = HostedAgents(hosted, AgentConfig(0, ids, 'lockstep'), policy)
    rng = random.Random(5)
    got_lone, got_host = {r: [] for r in hosted}, {r: [] for r in hosted}
    for s, frame in enumerate(frames):
        ns = stamp_ns(s, policy.dt)
        order = list(range(n))
        rng.shuffle(order)
        messages = [(r, frame[r]) for r in order]
        if s == 10:
            messages.insert(2, (order[0], frame[order[0]]))  # a duplicate
            messages.insert(3, (3, np.full(frame.shape[1], np.nan)))  # hostile: dropped and counted
        for robot, z in messages:
            for rid, logic in lone.items():
                logic.receive(robot, ns, z)
                cmd = logic.lockstep_poll(0.0)
                if cmd is not None:
                    got_lone[rid].append((cmd.step, cmd.stamp_ns, cmd.value))
            host.receive(robot, ns, z)
            for rid, cmd in host.lockstep_poll(0.0):
                got_host[rid].append((cmd.step, cmd.stamp_ns, cmd.value))
    for rid in hosted:
        assert len(got_lone[rid]) == len(frames)
        assert [c[:2] for c in got_host[rid]] == [c[:2] for c in got_lone[rid]]
        assert np.array_equal(
            np.stack([c[2] for c in got_host[rid]]), np.stack([c[2] for c in got_lone[rid]])
        )
        assert host.logics[rid].counters == lone[rid].counters
    assert host.logics[1].counters['non_finite'] == 1 and host.logics[1].counters['duplicate'] >= 1
    assert host.calls == len(frames)  # one batched call per step for all hosted robots


def test_hosted_robots_equal_lone_agents_in_realtime(policies):
    policy = policies['flock2d']
    n, hosted = 6, [0, 2, 3, 5]
    ids = list(range(n))
    frames = _frames('flock2d', n, 20, seed=1)
    lone = {rid: AgentLogic(AgentConfig(rid, ids, 'realtime'), policy) for rid in hosted}
    host = HostedAgents(hosted, AgentConfig(0, ids, 'realtime'), policy)
    assert host.tick(1) == [] and all(logic.tick(1) is None for logic in lone.values())  # no own state yet
    for s, frame in enumerate(frames):
        ns = stamp_ns(s, policy.dt)
        for robot in range(n):
            if (robot, s) == (4, 7):
                continue  # lost: both must bridge it with the last state heard
            for logic in lone.values():
                logic.receive(robot, ns, frame[robot], ns)
            host.receive(robot, ns, frame[robot], ns)
        got = dict(host.tick(ns))
        assert sorted(got) == hosted
        for rid, logic in lone.items():
            want = logic.tick(ns)
            assert (got[rid].step, got[rid].stamp_ns, got[rid].neighbours) == (
                want.step,
                want.stamp_ns,
                want.neighbours,
            )
            assert np.allclose(got[rid].value, want.value, rtol=1e-5, atol=1e-5)  # batch of 4 vs 1
    assert host.calls == len(frames)
    late = stamp_ns(len(frames) + 100, policy.dt)  # every own state 1 s old: each robot stops, as alone
    got = dict(host.tick(late))
    assert sorted(got) == hosted
    for rid, logic in lone.items():
        want = logic.tick(late)
        # the brake undoes the held command over 1 s, so the batch's 1e-5 differences grow 100-fold
        assert want.stop and got[rid].stop and np.allclose(got[rid].value, want.value, rtol=1e-3, atol=1e-3)


@pytest.mark.parametrize('scenario', ['flock2d', 'boids3d'])
def test_any_split_over_processes_equals_the_offline_rollout_bit_for_bit(policies, scenario):
    policy = policies[scenario]
    spec = get_scenario(scenario)
    n, steps = 10, 60
    z0, _ = initial_state(scenario, n, seed=7)
    ids = list(range(n))
    hosts = [
        HostedAgents(part, AgentConfig(0, ids, 'lockstep'), policy)
        for part in ([0, 3, 6, 9], [1, 4, 7], [2, 5, 8])
    ]
    rng = random.Random(1)
    states = [z0]
    for s in range(steps):
        ns = stamp_ns(s, policy.dt)
        order = ids[:]
        rng.shuffle(order)
        command = np.full((n, spec.command_dim), np.nan)
        for robot in order:
            for host in hosts:
                host.receive(robot, ns, states[-1][robot])
                for rid, cmd in host.lockstep_poll(0.0):
                    command[rid] = cmd.value
        assert np.all(np.isfinite(command)), f'step {s}: a robot got no command'
        states.append(zoh_step(states[-1], command, spec, policy.dt))
    ref = rollout(policy, z0, steps, scenario, policy.d_cr, policy.k, policy.tau, policy.dt)
    assert np.array_equal(np.stack(states), ref)
    assert [h.calls for h in hosts] == [steps] * 3


def test_ids_as_a_list_or_a_range():
    assert parse_ids('0..4') == [0, 1, 2, 3, 4]
    assert parse_ids('3-5') == [3, 4, 5]
    assert parse_ids([7, 2, 5]) == [2, 5, 7]
    assert parse_ids('[1, 2,9]') == [1, 2, 9]
    assert parse_ids(4) == [4]
    assert format_ids([3, 4, 5]) == '3..5' and format_ids([1, 4]) == '[1, 4]'
    assert format_ids([4, 3]) == '3..4' and format_ids([5]) == '[5]'  # a pair is a run; one id is not
    for bad, words in (
        ('5..2', 'ends before'),
        ('a..b', 'neither'),
        ([1, 1], 'duplicates'),
        ([], 'no robot'),
        ([-1, 2], 'negative'),
        (1.5, 'neither'),
    ):
        with pytest.raises(ConfigError, match=words) as info:
            parse_ids(bad)
        assert "'ids'" in str(info.value)


def test_a_hosted_id_outside_the_swarm_is_refused(policies):
    with pytest.raises(ConfigError, match=r"'ids'.*\[12\]"):
        HostedAgents([1, 12], AgentConfig(0, list(range(10)), 'lockstep'), policies['flock2d'])


def test_the_launcher_splits_robots_over_hosting_processes():
    from knode_swarm_ros.nodes.swarm import hosting

    assert hosting.resolve_agents_per_process(0, 10, cores=2) == 1  # small swarms: one process per robot
    assert hosting.resolve_agents_per_process(0, 100, cores=2) == 50  # 2 processes on 2 cores
    assert hosting.resolve_agents_per_process(0, 200, cores=16) == 25  # at most 8 processes
    assert hosting.resolve_agents_per_process(4, 3) == 3
    with pytest.raises(ConfigError, match='--agents-per-process'):
        hosting.resolve_agents_per_process(-1, 10)
    assert hosting.split(range(11), 4) == [[0, 1, 2, 3], [4, 5, 6, 7], [8, 9, 10]]
    cmds = hosting.agent_commands(11, 4, ['py', '-m'], 'pkg', 'agent.yaml', __import__('pathlib').Path('/l'))
    assert list(cmds) == ['agents_0_3', 'agents_4_7', 'agents_8_10']
    assert cmds['agents_8_10'][:3] == ['py', '-m', 'pkg.nodes.agents'] and 'ids:=8..10' in cmds['agents_8_10']
    assert hosting.robots_of('agents_8_10') == [8, 9, 10] and hosting.robots_of('agent_3') == [3]
    assert hosting.is_agent_process('agent_3') and not hosting.is_agent_process('recorder')
    with pytest.raises(ConfigError, match='--netns: no network namespace nosuchns_i12'):
        hosting.check_netns('nosuchns_i12')
    hosting.check_netns(None)


@pytest.mark.parametrize('tau, timeout, wall0', [(0, 0.5, 0.0), (2, 0.5, 0.0), (0, 2.0, 100.0)])
def test_hosted_robots_equal_lone_agents_with_lost_states_and_timeouts(policies, tau, timeout, wall0):
    # Lost states make robots give up on a peer (state_timeout, on the wall clock of the polls),
    # hear it again, and lose their own state: the process files every state once and polls
    # only the robots a message concerns, and each hosted robot must still do what its lone
    # agent does (same commands, same counters, same notes). A frame takes 2 timeouts of wall
    # time; a timeout above 1 s late on the wall clock catches a deadline of t * timeout.
    from dataclasses import replace as _replace

    base = policies['flock2d']
    policy = _Retimed(base, tau)
    n, hosted = 8, [0, 3, 4, 7]
    ids = list(range(n))
    config = AgentConfig(0, ids, 'lockstep', state_timeout=timeout)
    frames = _frames('flock2d', n, 30, seed=4)
    lone = {rid: AgentLogic(_replace(config, robot_id=rid), policy) for rid in hosted}
    host = HostedAgents(hosted, config, policy)
    lost = {
        (5, 10),
        (5, 11),
        (3, 15),
        (2, 20),
        (0, 20),
    }  # a peer twice, a hosted robot's own state, two at once
    got_lone, got_host = {r: [] for r in hosted}, {r: [] for r in hosted}
    events_lone, events_host = [], []
    rng = random.Random(3)

    def collect(wall):
        for rid, logic in lone.items():
            cmd = logic.lockstep_poll(wall)
            if cmd is not None:
                got_lone[rid].append((cmd.step, cmd.stamp_ns, cmd.neighbours, cmd.value))
            events_lone.extend(f'robot {rid}: {text}' for text in logic.drain_events())
        for rid, cmd in host.lockstep_poll(wall):
            got_host[rid].append((cmd.step, cmd.stamp_ns, cmd.neighbours, cmd.value))
        events_host.extend(host.drain_events())

    for s, frame in enumerate(frames):
        ns, wall = stamp_ns(s, policy.dt), wall0 + 2 * timeout * s
        order = [r for r in range(n) if (r, s) not in lost]
        rng.shuffle(order)
        for robot in order:
            for logic in lone.values():
                logic.receive(robot, ns, frame[robot], None, wall)
            host.receive(robot, ns, frame[robot], None, wall)
            collect(wall)
        collect(wall + 0.6 * timeout)  # a timer before the timeout: nothing new
        collect(wall + 1.2 * timeout)  # after it: the robots give up on the missing peers
    for rid in hosted:
        assert len(got_host[rid]) == len(got_lone[rid]) >= len(frames) - 2
        assert [c[:3] for c in got_host[rid]] == [c[:3] for c in got_lone[rid]]
        assert np.array_equal(
            np.stack([c[3] for c in got_host[rid]]), np.stack([c[3] for c in got_lone[rid]])
        )
        assert dict(host.logics[rid].counters) == dict(lone[rid].counters)
        assert host.logics[rid].status() == lone[rid].status()
    assert lone[0].counters['gave_up'] >= 2 and any('heard again' in e for e in events_lone)
    assert sorted(events_host) == sorted(events_lone)


class _Retimed:
    """A policy with another delay tau (the same network): the logic reads tau from the policy."""

    def __init__(self, policy, tau):
        self._policy, self.tau = policy, tau
        for name in ('k', 'd_cr', 'dt', 'scenario', 'command_limit'):
            setattr(self, name, getattr(policy, name))

    def __call__(self, Y, mask):
        return self._policy(Y, mask)


def test_hosted_commands_are_cleaned_like_a_lone_agents(policies):
    # A policy that answers NaN for some matrices and far beyond the limit for others: each hosted
    # robot publishes zero / the clipped command and counts it, as its lone agent does.
    base = policies['flock2d']

    class Wild(_Retimed):
        def __call__(self, Y, mask):
            u = np.array(self._policy(Y, mask))
            u[Y[:, 0, 0] > 0, 0] = np.nan  # robots right of the origin: non-finite
            u[Y[:, 0, 1] > 0, 1] = 1e6  # robots above it: far beyond the limit
            return u

    policy = Wild(base, base.tau)
    n, hosted = 6, [0, 1, 2, 3, 4, 5]
    ids = list(range(n))
    frames = _frames('flock2d', n, 5, seed=8)
    lone = {rid: AgentLogic(AgentConfig(rid, ids, 'lockstep'), policy) for rid in hosted}
    host = HostedAgents(hosted, AgentConfig(0, ids, 'lockstep'), policy)
    for s, frame in enumerate(frames):
        ns = stamp_ns(s, policy.dt)
        for robot in range(n):
            for logic in lone.values():
                logic.receive(robot, ns, frame[robot])
            host.receive(robot, ns, frame[robot])
        want = {rid: logic.lockstep_poll(0.0) for rid, logic in lone.items()}
        got = dict(host.lockstep_poll(0.0))
        for rid in hosted:
            assert np.array_equal(got[rid].value, want[rid].value)
    for rid in hosted:
        assert dict(host.logics[rid].counters) == dict(lone[rid].counters)
        assert lone[rid].drain_events() == host.logics[rid].drain_events()
    c = [lone[rid].counters for rid in hosted]
    assert sum(x['non_finite_command'] for x in c) > 0 and sum(x['clipped'] for x in c) > 0


def test_a_hosted_robot_missing_its_own_delayed_state_answers_when_the_last_peer_state_arrives(policies):
    """tau = 1; robot 0's state of step 1 is lost, robot 2's (not hosted) arrives after robot 0's
    state of step 2. Robot 0 then needs only the other n - 1 states of step 1: the process must
    poll it when the late one arrives (no message concerns it), at the same receive as a lone agent."""
    policy = _Retimed(policies['flock2d'], 1)
    ids, hosted = [0, 1, 2], [0, 1]
    config = AgentConfig(0, ids, 'lockstep', state_timeout=0.5)
    host = HostedAgents(hosted, config, policy, hold_s=0.0)  # no batching wait: answers as soon as due
    lone = {rid: AgentLogic(replace(config, robot_id=rid), policy) for rid in hosted}
    frames = _frames('flock2d', 3, 2, seed=2)
    sends = [(0, 0), (1, 0), (2, 0), (1, 1), (0, 2), (1, 2), (2, 2), (2, 1)]
    got_host, got_lone = [], []
    for i, (robot, s) in enumerate(sends):
        ns = stamp_ns(s, policy.dt)
        host.receive(robot, ns, frames[s][robot], None, 0.0)
        got_host += [(i, rid, cmd.step, cmd.neighbours) for rid, cmd in host.lockstep_poll(0.0)]
        for rid, logic in lone.items():
            logic.receive(robot, ns, frames[s][robot], None, 0.0)
            cmd = logic.lockstep_poll(0.0)
            if cmd is not None:
                got_lone.append((i, rid, cmd.step, cmd.neighbours))
    assert (7, 0, 2, 2) in got_lone  # robot 0's step 2, at the late state's arrival
    assert sorted(got_host) == sorted(got_lone)
