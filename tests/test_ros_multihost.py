"""A swarm whose robots live on three "hosts": network namespaces joined by a bridge.

The simulator and the recorder run in the first namespace, three hosting agent processes one
in each, discovery over the subnet with the UDP transport only (not localhost-only, no shared
memory): the lockstep recording equals core.rollout bit for bit. The namespaces (and with them
the bridge) are removed whatever happens. Skipped, with the reason, only where the machine
refuses to create namespaces (not root, no iproute2).
"""

import json
import os

import pytest
import rclpy  # noqa: F401  (a broken install must fail, not skip)
from test_ros_swarm import Launcher, _assert_no_strays, _parity, _pids

from knode_swarm_ros.core import load_trajectories
from knode_swarm_ros.nodes.swarm import netns

pytestmark = pytest.mark.ros


def _namespaces():
    return set(line.split()[0] for line in os.popen('ip netns list').read().splitlines() if line.strip())


def test_lockstep_with_agents_on_three_hosts_equals_the_offline_rollout(
    tmp_path, untrained_policies, ros_domain_id
):
    before = _namespaces()
    try:
        hosts_cm = netns.virtual_hosts(3)
        hosts = hosts_cm.__enter__()
    except netns.NetnsUnavailable as exc:
        print(f'skipped: this machine refuses to create network namespaces: {exc}')
        pytest.skip(f'this machine refuses to create network namespaces: {exc}')
    try:
        record = tmp_path / 'multihost.npz'
        steps = 150
        run = Launcher(
            tmp_path,
            '--policy',
            untrained_policies['flock2d'],
            '--robots',
            9,
            '--agents-per-process',
            3,
            '--steps',
            steps,
            '--seed',
            2,
            '--record',
            record,
            '--state-timeout',
            120,
            '--lockstep-timeout',
            120,
            '--netns',
            ','.join(h.name for h in hosts),
        )
        assert run.wait_for('ready after'), run.output
        # Every process really lives in its namespace: the agents in three different ones.
        pids = _pids(tmp_path)
        spaces = {}
        for name, pid in pids.items():
            try:
                spaces[name] = os.readlink(f'/proc/{pid}/ns/net')
            except OSError:
                pass
        own = os.readlink('/proc/self/ns/net')
        assert own not in spaces.values(), spaces
        assert spaces['simulator'] == spaces['recorder'] == spaces['agents_0_2'], spaces
        assert len({spaces['agents_0_2'], spaces['agents_3_5'], spaces['agents_6_8']}) == 3, spaces
        rc = run.finish()
        assert rc == 0, run.output
        assert load_trajectories(record).states[0].shape == (steps + 1, 9, 4)
        assert _parity(record, untrained_policies['flock2d'], steps) == 0  # bit for bit
        report = json.loads((tmp_path / 'logs' / 'simulator.json').read_text())
        assert report['steps_run'] == steps and report['lost'] == []
        _assert_no_strays(tmp_path)
    finally:
        hosts_cm.__exit__(None, None, None)
    # Nothing of this run is left behind (another copy of the suite may own namespaces meanwhile).
    tag = hosts[0].name[len('knh') :].rsplit('_', 1)[0]
    ours = {h.name for h in hosts} | {f'knsw{tag}'}
    assert not (_namespaces() & ours) and ours.isdisjoint(before)
