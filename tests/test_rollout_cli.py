"""training.rollout CLI: a policy file rolled out from a trajectory's first frame, written as a trajectory file."""

import numpy as np
import pytest
import torch

from knode_swarm_ros.core import (
    KNODEPolicy,
    PolicyConfig,
    export_policy,
    load_policy,
    load_trajectories,
    rollout,
    save_trajectories,
)
from training.rollout import main


@pytest.fixture
def files(tmp_path):
    torch.manual_seed(0)
    policy = KNODEPolicy(PolicyConfig('flock2d', k=4, d_cr=3.0, hidden=8, collision_phi=0.5))
    pol = tmp_path / 'p.pt'
    export_policy(policy, pol, policy.metadata())
    rng = np.random.default_rng(0)
    states = np.concatenate([rng.uniform(-2, 2, (3, 1, 5, 2)), rng.normal(0, 1, (3, 1, 5, 2))], axis=-1)
    data = tmp_path / 'init.npz'
    save_trajectories(data, states, 0.01, 'flock2d', {})
    return pol, data, states


def test_round_trip_equals_core_rollout(files, tmp_path):
    pol, data, states = files
    out = tmp_path / 'out.npz'
    assert main(['--policy', str(pol), '--init', f'{data}:2', '--steps', '25', '--out', str(out)]) == 0
    got = load_trajectories(out, scenario='flock2d')
    policy = load_policy(pol)
    want = rollout(policy, states[2, 0], 25, 'flock2d', policy.d_cr, policy.k, policy.tau, policy.dt)
    assert got.states.shape == (1, 26, 5, 4)
    np.testing.assert_array_equal(got.states[0], want)
    assert got.dt == policy.dt and got.meta['init'].endswith(':2')


def test_errors_exit_2(files, tmp_path, capsys):
    pol, data, _ = files
    out = str(tmp_path / 'o.npz')
    assert (
        main(['--policy', str(tmp_path / 'none.pt'), '--init', str(data), '--steps', '3', '--out', out]) == 2
    )
    assert 'none.pt' in capsys.readouterr().err
    assert main(['--policy', str(pol), '--init', f'{data}:7', '--steps', '3', '--out', out]) == 2
    assert 'index 7' in capsys.readouterr().err
    boids = tmp_path / 'b.npz'
    save_trajectories(boids, np.tile(np.array([0, 0, 0, 1.0, 0, 0]), (1, 1, 2, 1)), 1 / 60, 'boids3d', {})
    assert main(['--policy', str(pol), '--init', str(boids), '--steps', '3', '--out', out]) == 2
    assert 'scenario' in capsys.readouterr().err


def test_observe_pose_equals_core_rollout_with_poses(files, tmp_path):
    pol, data, states = files
    out = tmp_path / 'pose.npz'
    argv = ['--policy', str(pol), '--init', str(data), '--steps', '12', '--out', str(out)]
    assert main(argv + ['--observe', 'pose', '--velocity-window', '4']) == 0
    got = load_trajectories(out, scenario='flock2d')
    policy = load_policy(pol)
    want = rollout(
        policy,
        states[0, 0],
        12,
        'flock2d',
        policy.d_cr,
        policy.k,
        policy.tau,
        policy.dt,
        observe='pose',
        velocity_window=4,
    )
    np.testing.assert_array_equal(got.states[0], want)
    assert got.meta['observe'] == {'kind': 'pose', 'velocity_window': 4}
    assert main(argv + ['--velocity-window', '1']) == 2
    assert main(argv + ['--observe', 'pose', '--link-loss', '0.1']) == 2
