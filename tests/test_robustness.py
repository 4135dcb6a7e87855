"""training.studies.robustness and training.rollout's link options: the hand-written baseline is the
Tanner law, the study writes what it says, bad input exits 2."""

import json

import numpy as np
import pytest

from knode_swarm_ros.core import load_trajectories, save_trajectories
from knode_swarm_ros.core.groundtruth import tanner
from knode_swarm_ros.core.network import neighbour_matrix
from training import rollout as rollout_cli
from training.assessment.stats import interval
from training.studies import robustness


def test_local_tanner_with_every_robot_in_view_is_the_global_law():
    z = tanner.initial_states(np.random.default_rng(3), 4, 7, 'paper')
    Y, mask = neighbour_matrix(z, z, 2, 1e9, 7)
    got = robustness.local_tanner(10.0)(Y.reshape(-1, 7, 4), mask.reshape(-1, 7)).reshape(4, 7, 2)
    assert np.allclose(got, tanner.tanner_acceleration(z, clip=10.0), rtol=1e-12, atol=1e-12)
    # Restricted to fewer rows it is a different (local) law.
    Y, mask = neighbour_matrix(z, z, 2, 1e9, 3)
    local = robustness.local_tanner(None)(Y.reshape(-1, 3, 4), mask.reshape(-1, 3)).reshape(4, 7, 2)
    assert not np.allclose(local, tanner.tanner_acceleration(z))


def test_interval_is_the_t_interval():
    r = interval(np.array([1.0, 2.0, 3.0]))
    assert r['mean'] == 2.0 and r['hi'] - 2.0 == pytest.approx(4.302652729911275 / np.sqrt(3))


def test_study_writes_results_and_figure(tmp_path, untrained_policies):
    out = tmp_path / 'rob'
    rc = robustness.main(
        [
            '--policy',
            str(untrained_policies['flock2d']),
            '--out',
            str(out),
            '--starts',
            '2',
            '--steps',
            '20',
            '--delay-unit',
            '2',
        ]
    )
    assert rc == 0 and (out / 'robustness.png').stat().st_size > 0
    res = json.loads((out / 'results.json').read_text())
    assert len(res['rows']) == 2 * 10 and res['starts'] == 2
    lossy = [r for r in res['rows'] if r['loss'] == 0.3]
    assert all(r['link']['lost'] > 0 for r in lossy)
    assert all(r['link']['lost'] == 0 for r in res['rows'] if r['loss'] == 0)
    assert all(r['avd']['lo'] <= r['avd']['mean'] <= r['avd']['hi'] for r in res['rows'])
    assert (
        robustness.main(['--policy', str(untrained_policies['flock2d']), '--out', str(out), '--starts', '1'])
        == 2
    )
    assert robustness.main(['--policy', str(tmp_path / 'missing.pt'), '--out', str(out)]) == 2


def test_rollout_cli_link_options(tmp_path, untrained_policies):
    init = tmp_path / 'init.npz'
    z0 = tanner.initial_states(np.random.default_rng(1), 1, 5, 'paper')
    save_trajectories(init, z0[:, None], 0.01, 'flock2d', {})
    pol = str(untrained_policies['flock2d'])
    plain, lossy = tmp_path / 'a.npz', tmp_path / 'b.npz'
    assert rollout_cli.main(['--policy', pol, '--init', str(init), '--steps', '30', '--out', str(plain)]) == 0
    assert (
        rollout_cli.main(
            [
                '--policy',
                pol,
                '--init',
                str(init),
                '--steps',
                '30',
                '--out',
                str(lossy),
                '--link-loss',
                '0.5',
                '--link-delay-steps',
                '2',
                '--link-range',
                '3',
                '--seed',
                '4',
            ]
        )
        == 0
    )
    a, b = load_trajectories(plain), load_trajectories(lossy)
    assert (
        'link' not in a.meta
        and b.meta['link']['lost'] > 0
        and b.meta['link']['delays'] == {'2': b.meta['link']['delivered']}
    )
    assert not np.array_equal(a.states, b.states)
    assert (
        rollout_cli.main(
            ['--policy', pol, '--init', str(init), '--steps', '3', '--out', str(lossy), '--link-loss', '1.5']
        )
        == 2
    )
