"""training.evaluate end to end on tiny data: figures, results.json, summary.md (both scenarios)."""

import json

import matplotlib  # noqa: F401  (a broken install must fail, not skip)
import numpy as np
import pytest
import torch

from knode_swarm_ros.core import (
    DEFAULTS,
    KNODEPolicy,
    PolicyConfig,
    amd,
    avd,
    export_policy,
    get_scenario,
    load_policy,
    rollout,
    save_trajectories,
)
from knode_swarm_ros.core.groundtruth import simulate
from training.evaluate import main


@pytest.mark.parametrize('scenario', ['flock2d', 'boids3d'])
def test_evaluate_writes_results_and_figures(tmp_path, scenario):
    torch.manual_seed(0)
    policy = KNODEPolicy(PolicyConfig(scenario, **{**DEFAULTS[scenario], 'hidden': 8}))
    pol = tmp_path / 'p.pt'
    export_policy(policy, pol, policy.metadata())
    states = simulate(scenario, 3, 5, 30, seed=1, progress=False)
    data = tmp_path / 'd.npz'
    save_trajectories(
        data, states, policy.metadata()['dt'], scenario, {'split': {'train': [0], 'test': [1, 2]}}
    )
    out = tmp_path / 'eval'
    args = [
        '--policy',
        str(pol),
        '--data',
        str(data),
        '--out',
        str(out),
        '--scaling',
        '--sizes',
        '4',
        '6',
        '--ics',
        '2',
        '--scaling-steps',
        '15',
    ]
    assert main(args) == 0
    results = json.loads((out / 'results.json').read_text())
    assert results['test_trajectories'] == [1, 2] and results['steps'] == 29
    assert len(results['per_trajectory']['amd_final']) == 2
    assert [r['robots'] for r in results['scaling']['rows']] == [4, 6]
    names = ['metrics.png', 'snapshots.png', 'scaling.png', 'summary.md'] + (
        ['pod.png'] if scenario == 'boids3d' else []
    )
    for name in names:
        assert (out / name).stat().st_size > 0, name
    # The figures in results.json are the core metrics of the core rollout (not only present):
    # recompute them here from the policy file and the data.
    spec, loaded = get_scenario(scenario), load_policy(pol)
    pred = rollout(
        loaded, states[1:, 0], states.shape[1] - 1, scenario, loaded.d_cr, loaded.k, loaded.tau, loaded.dt
    )
    p = spec.position
    per = results['per_trajectory']
    np.testing.assert_allclose(per['amd_final'], amd(pred[:, -10:, :, p]).mean(axis=1), rtol=1e-12)
    np.testing.assert_allclose(per['truth_amd_final'], amd(states[1:, -10:, :, p]).mean(axis=1), rtol=1e-12)
    if spec.velocity is not None:
        np.testing.assert_allclose(
            per['avd_final'], avd(pred[:, -10:, :, spec.velocity]).mean(axis=1), rtol=1e-12
        )
    assert results['final']['amd_final']['mean'] == pytest.approx(np.mean(per['amd_final']), rel=1e-12)
