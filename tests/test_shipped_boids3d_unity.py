"""The shipped Unity-trained boids3d policy: what its file says it is, and that it flocks inside the cube.

Starts come from our boids (published preset: Unity's law frame by frame, docs/unity.md) at seeds no
study used; bounds sit well outside the values measured on 2026-11-30 (in the comments) so that other
float rounding, which changes these chaotic rollouts in detail, still passes.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch  # noqa: F401  (a broken install must fail, not skip)

from knode_swarm_ros.core import amd, load_policy, rollout, shipped_policy_path
from knode_swarm_ros.core.groundtruth import simulate


@pytest.fixture(scope='module')
def policy():
    return load_policy(shipped_policy_path('boids3d_unity'), expect={'scenario': 'boids3d'})


def test_metadata_names_the_recipe_of_the_docs(policy):
    assert (policy.k, policy.d_cr, policy.tau) == (6, 2.0, 1)
    prov = policy.meta['provenance']
    # trained with d0 = 1 on the retimed recordings 0, 1 (2 for selection), then d0 = 0.75 chosen on
    # our boids' validation starts (docs/unity.md, "The collision range chosen on validation starts")
    assert prov['config']['policy']['collision_d0'] == 1.0 and policy.meta['config']['collision_d0'] == 0.75
    assert prov['data'] == 'data/unity_s2_retimed.npz' and prov['val_trajectories'] == [2]
    assert prov['git_tree_clean'] is True and prov['knowledge_variant']['git_tree_clean'] is True
    assert prov['knowledge_variant']['changes'] == {'collision_d0': 0.75}


def _final_amd(policy, n, starts, steps):
    truth = simulate('boids3d', starts, n, steps + 1, seed=20261202 + n, preset='published', progress=False)
    pred = rollout(policy, truth[:, 0], steps, 'boids3d', policy.d_cr, policy.k, policy.tau, policy.dt)
    assert pred.shape == truth.shape and np.all(np.isfinite(pred))
    assert np.abs(pred[..., :3]).max() < 5.0  # every boid inside the cube [-5, 5]^3 (measured 4.77)
    return amd(pred[:, -10:, :, :3]).mean(axis=1), amd(truth[:, -10:, :, :3]).mean(axis=1)


def test_ten_boids_flock_at_the_observed_spacing(policy):
    pred, truth = _final_amd(policy, 10, 4, 1200)  # 20 s
    assert abs(pred.mean() - truth.mean()) < 0.25, (pred, truth)  # measured 1.15 vs 1.16
    assert np.all((pred > 0.7) & (pred < 2.0)), pred


def test_fifty_boids_keep_the_spacing_of_the_boids(policy):
    # five times the training size: the collision range sets the spacing here (d0 = 0.65: ~0.75, d0 = 1: ~0.97)
    pred, truth = _final_amd(policy, 50, 2, 900)
    assert np.all(np.abs(pred - 0.86) < 0.1), (pred, truth)  # measured 0.818, 0.820; truth 0.886, 0.857
