"""The equivariant encoder that sees each neighbour's rank by distance (``policy.rank``): a known
answer from hand-set weights (a push that falls off with rank, not with distance), the plain
encoder again when the rank's weights are zero, exact rotation equivariance kept, a neighbour in
the own state adding nothing, TorchScript and ONNX parity, the config's refusals and old files."""

import numpy as np
import pytest
import torch
from export_parity import assert_exports_equal
from scipy.stats import special_ortho_group

from knode_swarm_ros.core import KNODEPolicy, PolicyConfig, neighbour_matrix
from knode_swarm_ros.core.equivariant_encoder import DISTANCE_BASIS
from knode_swarm_ros.core.scenarios import scenario_from_dict

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
        encoder='equivariant', k=6, d_cr=3.0, hidden=16, position_scale=0.7, velocity_scale=0.8, rank=True
    )
    base.update(overrides)
    return KNODEPolicy(PolicyConfig(scenario, **base)).eval()


def swarm(scenario, n=9, seed=0):
    """Neighbour matrices of a random swarm, rows sorted by distance as every caller builds them."""
    rng = np.random.default_rng(seed)
    z = rng.normal(scale=1.2, size=(n, scenario.state_dim))
    if scenario.state == 'position_heading':
        p = scenario.position_dim
        z[:, p:] /= np.linalg.norm(z[:, p:], axis=1, keepdims=True)
    Y, mask = neighbour_matrix(z, z, scenario.position_dim, 3.0, 6)
    return torch.tensor(Y, dtype=torch.float32), torch.tensor(mask, dtype=torch.float32)


def test_hand_set_weights_give_a_push_that_falls_off_with_rank():
    """One hidden unit reads the rank alone (tanh(-log(1 + rank))) and is the coefficient of
    r_hat in the sum channel: u_i = sum_j tanh(-log(1 + j)) r_hat_ij over the valid rows j = 1, 2,
    ...: the nearest neighbour pushes hardest whatever the distances, which no function of the
    pair's distance can give when the distances are all alike."""
    scenario, _, d = KINDS[0]
    policy = make(scenario, hidden=1, collision=False, wall=False, command_limit=1e6)
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
    weight = np.tanh(-np.log1p(np.arange(1, r.shape[1] + 1)))[None, :, None] * mask[:, 1:].numpy()[..., None]
    np.testing.assert_allclose(u, (weight * rh).sum(1), rtol=1e-5, atol=1e-6)
    assert np.abs(u).max() > 0.3


@pytest.mark.parametrize('scenario,p,d', KINDS, ids=IDS)
def test_zero_rank_weights_give_the_plain_encoder(scenario, p, d):
    """The rank is one more pair scalar: with its weights zero the policy is the plain equivariant
    encoder with the same other weights, to float32 rounding."""
    ranked, plain = make(scenario), make(scenario, rank=False)
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
    enc = policy.encoder
    with torch.no_grad():
        enc.pair_out.weight[enc.vectors :].zero_()
        if hasattr(enc, 'own'):
            enc.own[-1].weight.zero_()
            enc.own[-1].bias.zero_()
        Y, mask = swarm(scenario)
        Y, mask = Y[:, :5], mask[:, :5].clone()
        mask[:, :] = 1.0
        with_copy = torch.cat([Y, Y[:, :1]], dim=1)
        torch.testing.assert_close(
            policy.network(with_copy, torch.cat([mask, torch.ones(len(Y), 1)], dim=1)),
            policy.network(Y, mask),
            rtol=1e-5,
            atol=1e-6,
        )


@pytest.mark.parametrize('scenario,p,d', KINDS, ids=IDS)
def test_torchscript_and_onnx_equal_the_eager_module(tmp_path, scenario, p, d):
    policy = make(scenario, **({'symmetric': True, 'axes': True} if scenario.arena else {}))
    loaded = assert_exports_equal(policy, tmp_path / 'rank.pt', *swarm(scenario))
    assert loaded.meta['config']['rank'] is True
    assert PolicyConfig(**loaded.meta['config']).rank is True


def test_the_config_refuses_rank_for_other_encoders_and_non_booleans_and_old_files_have_none():
    scenario = KINDS[0][0]
    for bad in (dict(encoder='set', rank=True), dict(encoder='flat', rank=True), dict(rank='yes')):
        with pytest.raises(ValueError, match='rank'):
            PolicyConfig(scenario, **{'encoder': 'equivariant', **bad})
    meta = make(scenario, rank=False).metadata()
    assert meta['config']['rank'] is False
    del meta['config']['rank']  # as files written before the field existed
    old = KNODEPolicy(PolicyConfig(**meta['config']))
    assert old.encoder.rank is False
    assert old.encoder.pair.in_features == 1 + DISTANCE_BASIS
