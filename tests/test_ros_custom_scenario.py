"""Scenarios of one's own through ROS: the launcher runs a first-order 2D swarm and a 3D double
integrator in an arena in lockstep, and each recording equals the offline rollout bit for bit
(docs/scenarios.md, "Deploying a scenario of your own")."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest
import rclpy  # noqa: F401  (a broken install must fail, not skip)
import yaml

from knode_swarm_ros.core import load_policy, load_trajectories, save_trajectories
from knode_swarm_ros.core.rollout import rollout
from knode_swarm_ros.core.scenarios import get_scenario, scenario_ref

pytestmark = pytest.mark.ros

RUN_TIMEOUT = 240

GROUND = {
    'name': 'ground_robots',
    'dimensions': 2,
    'state': 'position',
    'command': 'velocity',
    'dt': 0.05,
    'arena': None,
}
DRONES = {
    'name': 'room_drones',
    'dimensions': 3,
    'state': 'position_velocity',
    'command': 'acceleration',
    'dt': 0.04,
    'arena': {'half_width': 4.0},
}


@pytest.fixture(autouse=True)
def _own_domain(ros_domain_id):
    return ros_domain_id


def _scenario_file(tmp_path, fields):
    path = tmp_path / f'{fields["name"]}.yaml'
    path.write_text(yaml.safe_dump(fields))
    return path


def _policy(tmp_path, scenario_file, **network):
    """A seeded, untrained policy of the scenario (as conftest's ``untrained_policies``)."""
    import torch

    from knode_swarm_ros.core import KNODEPolicy, PolicyConfig, export_policy

    torch.manual_seed(5)
    policy = KNODEPolicy(PolicyConfig(scenario_ref(scenario_file), **network))
    path = tmp_path / 'policy.pt'
    export_policy(policy, path, policy.metadata())
    return path


def _run(tmp_path, *args):
    cmd = [
        sys.executable,
        '-m',
        'knode_swarm_ros.nodes.swarm',
        '--log-dir',
        str(tmp_path / 'logs'),
        '--no-figure',
        '--domain-id',
        os.environ['ROS_DOMAIN_ID'],
        *map(str, args),
    ]
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONUNBUFFERED='1')
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=RUN_TIMEOUT)
    return proc.returncode, proc.stdout + proc.stderr


def _difference(record, policy_path, steps):
    """Largest |recording - offline rollout| from the recording's first frame."""
    import torch

    data = load_trajectories(record)
    states = data.states[0]
    assert states.shape[0] == steps + 1
    assert data.meta['incomplete_frames'] == 0 and data.meta['filled_entries'] == 0
    # One intra-op thread, as every agent: a matrix product's rounding depends on the thread count.
    torch.set_num_threads(1)
    policy = load_policy(policy_path)
    ref = rollout(policy, states[0], steps, data.scenario, policy.d_cr, policy.k, policy.tau, policy.dt)
    return data, float(np.abs(ref - states).max())


@pytest.mark.parametrize(
    'network',
    [{'k': 5}, {'k': 12, 'encoder': 'set', 'symmetric': True}, {'k': 12, 'encoder': 'equivariant'}],
    ids=['flat', 'set-symmetric', 'equivariant'],  # the paper's network; the custom recipe's
)
def test_first_order_2d_scenario_file_runs_in_lockstep_equal_to_the_offline_rollout(tmp_path, network):
    scenario = _scenario_file(tmp_path, GROUND)
    policy = _policy(tmp_path, scenario, d_cr=2.0, tau=0, command_limit=1.5, **network)
    record = tmp_path / 'ground.npz'
    steps = 200
    rc, out = _run(
        tmp_path, '--scenario', scenario, '--policy', policy, '--robots', 10, '--steps', steps,
        '--seed', 2, '--record', record,
    )  # fmt: skip
    assert rc == 0, out
    data, diff = _difference(record, policy, steps)
    assert diff == 0.0, f'max state difference {diff}'  # bit for bit
    assert data.spec == get_scenario(scenario) and data.states.shape[-1] == 2
    # The seeded random start of a scenario without an arena: a box of about one robot per m^2.
    half = 0.5 * 10**0.5
    assert np.all(np.abs(data.states[0, 0]) <= half)
    assert float(np.abs(data.states[0, -1] - data.states[0, 0]).max()) > 0  # the swarm moved


def test_double_integrator_3d_in_an_arena_from_init_equals_the_offline_rollout(tmp_path):
    scenario = _scenario_file(tmp_path, DRONES)
    policy = _policy(tmp_path, scenario, k=4, d_cr=2.5, tau=1, command_limit=3.0, wall=True)
    rng = np.random.default_rng(8)
    z0 = np.concatenate([rng.uniform(-3.5, 3.5, (10, 3)), rng.uniform(-0.5, 0.5, (10, 3))], axis=1)
    init = tmp_path / 'init.npz'
    save_trajectories(init, np.stack([z0 * 0.5, z0])[:, None], DRONES['dt'], scenario)
    record = tmp_path / 'drones.npz'
    steps = 60
    # No --scenario: the policy's knode.json carries the scenario.
    rc, out = _run(tmp_path, '--policy', policy, '--init', f'{init}:1', '--steps', steps, '--record', record)
    assert rc == 0, out
    data, diff = _difference(record, policy, steps)
    assert np.array_equal(data.states[0, 0], z0)
    assert diff == 0.0, f'max state difference {diff}'  # bit for bit
    assert data.spec == get_scenario(scenario)
