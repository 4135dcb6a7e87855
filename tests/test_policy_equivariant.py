"""The rotation-equivariant encoder (``policy.encoder: equivariant``): exact equivariance under
rotations for every state kind without an arena, chirality (a mirror does not commute), a
known answer from hand-set weights, and what the recipe derives for it."""

import os

import numpy as np
import pytest
import torch
from equivariant_checks import swarm
from scipy.stats import special_ortho_group

from knode_swarm_ros.core import KNODEPolicy, PolicyConfig
from knode_swarm_ros.core.equivariant_encoder import DISTANCE_BASIS
from knode_swarm_ros.core.errors import ConfigError
from knode_swarm_ros.core.metrics import nearest_neighbour_distance
from knode_swarm_ros.core.scenarios import scenario_from_dict
from training.learning.config import load_config, resolve_config

torch.set_num_threads(1)
RECIPE = os.path.join(os.path.dirname(__file__), '..', 'config', 'train_custom.yaml')


def spec(dims, state, command, arena=None):
    return scenario_from_dict(
        dict(name=f'eq{dims}{state}', dimensions=dims, state=state, command=command, dt=0.05, arena=arena)
    )


KINDS = [
    (2, 'position', 'velocity'),
    (3, 'position', 'velocity'),
    (2, 'position_velocity', 'acceleration'),
    (3, 'position_velocity', 'acceleration'),
    (2, 'position_heading', 'velocity'),
    (3, 'position_heading', 'velocity'),
]
IDS = ['position2d', 'position3d', 'double-integrator2d', 'double-integrator3d', 'heading2d', 'heading3d']


def make(scenario, seed=0, **overrides):
    torch.manual_seed(seed)
    base = dict(encoder='equivariant', k=8, d_cr=3.0, hidden=16, position_scale=0.7, velocity_scale=0.8)
    base.update(overrides)
    return KNODEPolicy(PolicyConfig(scenario, **base)).eval()


def on_states(R, Y):
    """``R [p, p]`` applied to every position and velocity (heading) of ``Y [B, k, d]``."""
    blocks = Y.shape[-1] // R.shape[0]
    return Y @ torch.block_diag(*[R] * blocks).T


@pytest.mark.parametrize('dims,state,command', KINDS, ids=IDS)
def test_every_rotation_commutes_with_the_whole_policy(dims, state, command):
    """Knowledge terms included; no saturation in reach (a per-axis clip is not equivariant)."""
    scenario = spec(dims, state, command)
    policy = make(scenario, command_limit=1e6, potential='continuous', collision_d0=1.0)
    Y, mask = swarm(scenario)
    assert 0 < mask[:, 1:].sum() < mask[:, 1:].numel()
    with torch.no_grad():
        u = policy(Y, mask)
        assert u.abs().max() > 1e-2  # the check below is not about zeros
        for seed in range(3):
            R = torch.tensor(special_ortho_group.rvs(dims, random_state=seed), dtype=torch.float32)
            torch.testing.assert_close(policy(on_states(R, Y), mask), u @ R.T, rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize('dims', [2, 3])
def test_a_mirror_does_not_commute_so_chiral_laws_keep_their_sense(dims):
    """The turned vectors (2D) and cross products (3D) flip under a reflection: a policy can
    learn a swarm that mills one way. The same policy commutes with rotations (above)."""
    scenario = spec(dims, 'position_velocity', 'acceleration')
    policy = make(scenario, command_limit=1e6, collision=False)
    Y, mask = swarm(scenario)
    mirror = torch.diag(torch.tensor([-1.0] + [1.0] * (dims - 1)))
    with torch.no_grad():
        mirrored = policy(on_states(mirror, Y), mask)
        assert not torch.allclose(mirrored, policy(Y, mask) @ mirror.T, atol=1e-3)


@pytest.mark.parametrize('column', [0, 1, 12, DISTANCE_BASIS])
def test_hand_set_weights_give_the_central_force_they_encode(column):
    """One hidden unit on one radial input as the coefficient of r_hat in the sum channel and,
    times 0.5, in the mean channel: u_i = (sum_j + 0.5 mean_j) tanh(x(d_ij)) r_hat_ij, where x is
    log(1 + d / s) (column 0) or the Gaussian of it centred at log(1 + d_cr / s) (column - 1) / 31
    (column >= 1: contact, between, the communication radius)."""
    scenario = spec(2, 'position', 'velocity')
    s, d_cr = 0.7, 5.0
    policy = make(scenario, hidden=1, collision=False, command_limit=1e6, position_scale=s, d_cr=d_cr)
    enc = policy.encoder
    with torch.no_grad():
        enc.pair.weight.zero_()
        enc.pair.weight[0, column] = 1.0
        enc.pair.bias.zero_()
        enc.pair_out.weight.copy_(
            torch.tensor([[1.0], [0.0], [0.5], [0.0]])
        )  # sum: r_hat, turn; mean: the same
    Y, mask = swarm(scenario)
    with torch.no_grad():
        u = policy(Y, mask).numpy()
    r = (Y[:, 1:] - Y[:, :1]).numpy().astype(np.float64)
    d = np.linalg.norm(r, axis=-1, keepdims=True)
    m = mask[:, 1:].numpy()[..., None]
    x = np.log1p(d / s)
    if column:
        width = np.log1p(d_cr / s) / (DISTANCE_BASIS - 1)
        x = np.exp(-(((x - (column - 1) * width) / width) ** 2))
    pull = np.tanh(x) * r / np.where(d > 0, d, 1.0) * m
    expected = pull.sum(1) + 0.5 * pull.sum(1) / np.maximum(m.sum(1), 1.0)
    np.testing.assert_allclose(u, expected, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize('dims', [2, 3])
def test_the_basis_holds_no_subnormal_numbers_and_is_the_gaussians_elsewhere(dims):
    """From contact to far past the radius, each basis value is a float32 normal number or
    exactly zero (subnormals slow CPU arithmetic many times over), zero only where the Gaussian
    is below exp(-80), and elsewhere the Gaussian."""
    enc = make(spec(dims, 'position', 'velocity'), d_cr=5.0).encoder
    d = torch.logspace(-4, 3, 4001).reshape(1, -1, 1)
    r = torch.cat([d, torch.zeros(1, d.shape[1], dims - 1)], dim=-1)
    zero = torch.zeros_like(r)
    with torch.no_grad():
        scalars, _ = enc.pair_terms(r, zero, zero)
    basis = scalars[..., 1 : 1 + DISTANCE_BASIS].double()
    assert not ((basis != 0) & (basis.abs() < torch.finfo(torch.float32).tiny)).any()
    x = torch.log1p(d.double())
    centres = torch.tensor(enc.basis_centres, dtype=torch.float64)
    q = ((x - centres) / enc.basis_width) ** 2
    expected = np.where(q.numpy() < 80.0, np.exp(-q.numpy()), 0.0)  # within atol where q is near 80
    np.testing.assert_allclose(basis.numpy(), expected, rtol=1e-4, atol=1e-30)
    assert (basis == 0).any() and (basis > 0.5).any()  # both the tail and the peaks were reached


def _recipe(scenario, tracks, **overrides):
    import json

    ref = json.dumps(scenario.to_dict(), sort_keys=True)
    sets = {'policy.encoder': 'equivariant', **overrides}
    return resolve_config(load_config(RECIPE, sets), [tracks], ref, scenario.dt)


def _tracks(dims, state, seed=0):
    rng = np.random.default_rng(seed)
    p = rng.uniform(-2.0, 2.0, size=(2, 6, 9, dims))
    if state == 'position':
        return p
    return np.concatenate([p, rng.normal(scale=0.5, size=p.shape)], axis=-1)


def test_the_recipe_derives_the_spacing_as_scale_and_no_half_turns_without_an_arena():
    scenario = spec(2, 'position', 'velocity')
    tracks = _tracks(2, 'position')
    cfg, derived = _recipe(scenario, tracks)
    expected = np.median(nearest_neighbour_distance(tracks.reshape(-1, 9, 2)))
    assert cfg['policy']['position_scale'] == pytest.approx(expected, rel=1e-5)
    assert derived['policy.position_scale']['how'].startswith('the median nearest-neighbour distance')
    assert cfg['policy']['symmetric'] is False and cfg['augment']['rotate'] is True
    assert 'exactly rotation-equivariant' in derived['policy.symmetric']['how']
    # with an arena the own position enters unturned: the half turns keep it symmetric
    box = spec(3, 'position_velocity', 'acceleration', arena={'half_width': 4.0})
    cfg, derived = _recipe(box, _tracks(3, 'position_velocity'))
    assert cfg['policy']['symmetric'] is True and cfg['augment']['rotate'] is False


def test_a_law_declared_not_rotation_invariant_sees_the_axes_or_is_refused_naming_the_encoder():
    scenario = spec(2, 'position', 'velocity')
    cfg, derived = _recipe(scenario, _tracks(2, 'position'), **{'augment.rotate': False})
    assert cfg['policy']['axes'] is True and cfg['policy']['symmetric'] is False
    with pytest.raises(ConfigError, match="policy.encoder = 'equivariant'.*augment.rotate"):
        _recipe(scenario, _tracks(2, 'position'), **{'augment.rotate': False, 'policy.axes': False})
