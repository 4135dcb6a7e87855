"""The equivariant encoder that sees each neighbour's rank by distance (``policy.rank``): a known
answer from hand-set weights (a push that falls off with rank, not with distance, and stops
falling past the rank cap), the plain
encoder again when the rank's weights are zero, exact rotation equivariance kept, a neighbour in
the own state adding nothing, TorchScript and ONNX parity, the config's refusals and old files."""

import json
import os

import numpy as np
import pytest
import torch
from equivariant_checks import assert_a_copy_of_the_robot_adds_nothing
from equivariant_checks import swarm as random_swarm
from export_parity import assert_exports_equal
from scipy.stats import special_ortho_group

from knode_swarm_ros.core import KNODEPolicy, PolicyConfig
from knode_swarm_ros.core.equivariant_encoder import DISTANCE_BASIS
from knode_swarm_ros.core.scenarios import scenario_from_dict
from training.learning.config import load_config, resolve_config

torch.set_num_threads(1)


def spec(dims, state, command, arena=None):
    return scenario_from_dict(
        dict(name=f'rk{dims}{state}', dimensions=dims, state=state, command=command, dt=0.05, arena=arena)
    )


KINDS = [
    (spec(2, 'position', 'velocity'), 2, 2),
    (spec(3, 'position_velocity', 'acceleration'), 3, 6),
    (spec(2, 'position_heading', 'velocity'), 2, 4),
    (spec(3, 'position_heading', 'velocity', {'half_width': 2.5}), 3, 6),
]
IDS = ['position2d', 'double-integrator3d', 'heading2d', 'heading3d-tank']


def make(scenario, seed=0, **overrides):
    torch.manual_seed(seed)
    base = dict(
        encoder='equivariant', k=6, d_cr=3.0, hidden=16, position_scale=0.7, velocity_scale=0.8, rank=4
    )
    base.update(overrides)
    return KNODEPolicy(PolicyConfig(scenario, **base)).eval()


def swarm(scenario):
    return random_swarm(scenario, n=9, k=6, scale=1.2)


def test_hand_set_weights_give_a_push_that_falls_off_with_rank():
    """One hidden unit reads the rank alone (tanh(-log(1 + min(rank, 3)))) and is the coefficient
    of r_hat in the sum channel: u_i = sum_j tanh(-log(1 + min(j, 3))) r_hat_ij over the valid rows
    j = 1, 2, ...: the nearest neighbour pushes hardest whatever the distances, which no function
    of the pair's distance can give when the distances are all alike; the 4th and 5th rows push as
    the 3rd (the cap)."""
    scenario, _, d = KINDS[0]
    policy = make(scenario, hidden=1, collision=False, wall=False, command_limit=1e6, rank=3)
    enc = policy.encoder
    assert enc.pair.in_features == 1 + DISTANCE_BASIS + 1  # log(1 + d), the basis, the rank
    with torch.no_grad():
        for param in enc.parameters():
            param.zero_()
        enc.pair.weight[0, -1] = -1.0
        enc.pair_out.weight[0, 0] = 1.0  # the sum channel's r_hat
    Y, mask = swarm(scenario)
    mask[0, 3:] = 0.0  # a robot that hears two neighbours only
    with torch.no_grad():
        u = policy(Y, mask).numpy().astype(np.float64)
    r = (Y[:, 1:] - Y[:, :1]).numpy().astype(np.float64)
    rh = r / np.linalg.norm(r, axis=-1, keepdims=True)
    ranks = np.minimum(np.arange(1, r.shape[1] + 1), 3)
    assert r.shape[1] == 5
    weight = np.tanh(-np.log1p(ranks))[None, :, None] * mask[:, 1:].numpy()[..., None]
    np.testing.assert_allclose(u, (weight * rh).sum(1), rtol=1e-5, atol=1e-6)
    assert np.abs(u).max() > 0.3


@pytest.mark.parametrize('scenario,p,d', KINDS, ids=IDS)
def test_zero_rank_weights_give_the_plain_encoder(scenario, p, d):
    """The rank is one more pair scalar: with its weights zero the policy is the plain equivariant
    encoder with the same other weights, to float32 rounding."""
    ranked, plain = make(scenario), make(scenario, rank=0)
    with torch.no_grad():
        for name, param in plain.named_parameters():
            source = dict(ranked.named_parameters())[name]
            if name == 'encoder.pair.weight':
                assert source.shape[1] == param.shape[1] + 1
                param.copy_(source[:, :-1])
                source[:, -1].zero_()
            else:
                param.copy_(source)
        Y, mask = swarm(scenario)
        torch.testing.assert_close(ranked(Y, mask), plain(Y, mask), rtol=1e-5, atol=1e-6)
        ranked_again = make(scenario)
        assert not torch.allclose(ranked_again(Y, mask), plain(Y, mask), atol=1e-4)


@pytest.mark.parametrize('scenario,p,d', KINDS[:3], ids=IDS[:3])
def test_the_rank_keeps_rotation_equivariance(scenario, p, d):
    """Ranks are distances' order, which rotations keep: u(R Y) = R u(Y) without an arena."""
    policy = make(scenario)
    Y, mask = swarm(scenario)
    R = torch.tensor(special_ortho_group.rvs(p, random_state=5), dtype=torch.float32)
    turn = torch.block_diag(*[R] * (d // p))
    with torch.no_grad():
        torch.testing.assert_close(
            policy.network(Y @ turn.T, mask), policy.network(Y, mask) @ R.T, rtol=1e-4, atol=1e-5
        )


@pytest.mark.parametrize('scenario,p,d', KINDS, ids=IDS)
def test_a_neighbour_in_the_own_state_adds_nothing_at_its_rank(scenario, p, d):
    """The own-state subtraction is taken at the row's rank: with the means off (the mean channel,
    the own term), a copy of the robot in the last row changes nothing."""
    policy = make(scenario, symmetric=False)
    Y, mask = swarm(scenario)
    Y, mask = Y[:, :5], torch.ones(len(Y), 5)
    assert_a_copy_of_the_robot_adds_nothing(policy, Y, mask)


@pytest.mark.parametrize('scenario,p,d', KINDS, ids=IDS)
def test_torchscript_and_onnx_equal_the_eager_module(tmp_path, scenario, p, d):
    policy = make(scenario, **({'symmetric': True, 'axes': True} if scenario.arena else {}))
    loaded = assert_exports_equal(policy, tmp_path / 'rank.pt', *swarm(scenario))
    assert loaded.meta['config']['rank'] == 4
    assert PolicyConfig(**loaded.meta['config']).rank == 4


def test_the_config_refuses_rank_for_other_encoders_and_non_integers_and_old_files_have_none():
    scenario = KINDS[0][0]
    bad_values = (
        dict(encoder='set', rank=4),
        dict(encoder='flat', rank=4),
        dict(rank=True),
        dict(rank=-1),
        dict(rank=2.5),
        dict(rank='yes'),
    )
    for bad in bad_values:
        with pytest.raises(ValueError, match='rank'):
            PolicyConfig(scenario, **{'encoder': 'equivariant', **bad})
    meta = make(scenario, rank=0).metadata()
    assert meta['config']['rank'] == 0
    del meta['config']['rank']  # as files written before the field existed
    old = KNODEPolicy(PolicyConfig(**meta['config']))
    assert old.encoder.rank == 0
    assert old.encoder.pair.in_features == 1 + DISTANCE_BASIS


RECIPE = os.path.join(os.path.dirname(__file__), '..', 'config', 'train_custom.yaml')


@pytest.mark.parametrize(
    'overrides,rank',
    [
        ({}, 4),  # the middle robots of the line have 4 others within 2.5 m, the ends 2
        ({'policy.encoder': 'set'}, 0),  # no rank input
        ({'policy.rank': 7}, 7),  # an explicit value wins
    ],
    ids=['derived', 'set-encoder', 'explicit'],
)
def test_the_recipe_derives_the_largest_rank_the_data_hold(overrides, rank):
    """Nine robots on a line 1 m apart (moving together) with d_cr = 2.5 m: at most 4 neighbours
    within d_cr, so ranks up to 4 are told apart."""
    scenario = KINDS[0][0]
    line = np.stack([np.arange(9.0), np.zeros(9)], axis=-1)
    tracks = (line[None, None] + 0.1 * np.arange(6.0)[None, :, None, None]).repeat(2, axis=0)
    ref = json.dumps(scenario.to_dict(), sort_keys=True)
    raw = load_config(RECIPE, {'policy.d_cr': 2.5, 'policy.rank': 'auto', **overrides})
    cfg, derived = resolve_config(raw, [tracks], ref, scenario.dt)
    assert cfg['policy']['rank'] == rank
    if 'policy.rank' not in overrides:
        assert derived['policy.rank']['value'] == rank and derived['policy.rank']['how']
    policy = KNODEPolicy(PolicyConfig(**{**cfg['policy'], 'scenario': ref}))
    assert getattr(policy.encoder, 'rank', 0) == rank
