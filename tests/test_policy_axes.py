"""Laws that rotations change. The equivariant encoder that sees the coordinate axes
(``policy.axes``): a known answer (a swirl about the vertical, which the rotation-equivariant pair
terms cannot give), equivariance under the arena's half turns only, a neighbour in the own state
adding nothing, TorchScript and ONNX parity, the config's refusals, old files, and what the recipe
derives; the half turn about one axis (``symmetric: z``), which keeps a swirl about it, and the
recipe's choice of half turns from the data's senses of rotation."""

import json
import os

import numpy as np
import pytest
import torch
from equivariant_checks import assert_a_copy_of_the_robot_adds_nothing
from export_parity import assert_exports_equal
from scipy.stats import special_ortho_group

from knode_swarm_ros.core import KNODEPolicy, PolicyConfig
from knode_swarm_ros.core.equivariant_encoder import DISTANCE_BASIS
from knode_swarm_ros.core.errors import ConfigError
from knode_swarm_ros.core.policy import half_turns
from knode_swarm_ros.core.scenarios import scenario_from_dict
from training.learning.config import load_config, resolve_config

torch.set_num_threads(1)
RECIPE = os.path.join(os.path.dirname(__file__), '..', 'config', 'train_custom.yaml')


def spec(dims, state, command, arena=None):
    return scenario_from_dict(
        dict(name=f'ax{dims}{state}', dimensions=dims, state=state, command=command, dt=0.05, arena=arena)
    )


ROOM = {'half_width': 2.5}
KINDS = [
    (spec(3, 'position', 'velocity', ROOM), 3, 3),
    (spec(3, 'position_velocity', 'acceleration', ROOM), 3, 6),
    (spec(2, 'position_heading', 'velocity', ROOM), 2, 4),
    (spec(2, 'position', 'velocity'), 2, 2),
]
IDS = ['position3d-room', 'double-integrator3d-room', 'heading2d-room', 'position2d']


def batch(d, k=6, B=7, seed=0):
    """``Y [B, k, d]`` (robots within the room) and ``mask [B, k]``, one robot with fewer neighbours."""
    g = torch.Generator().manual_seed(seed)
    Y = torch.randn(B, k, d, generator=g)
    mask = torch.ones(B, k)
    mask[0, 4:] = 0.0
    return Y, mask


def make(scenario, seed=0, **overrides):
    torch.manual_seed(seed)
    base = dict(
        encoder='equivariant', k=6, d_cr=3.0, hidden=16, position_scale=0.7, velocity_scale=0.8, axes=True
    )
    base.update(overrides)
    return KNODEPolicy(PolicyConfig(scenario, **base)).eval()


def test_hand_set_weights_give_a_swirl_about_the_vertical():
    """Two hidden units read the x and y components of r_hat (small weight e: tanh(e x) = e x to
    O(e^3)) and are the coefficients of e_y and -e_x in the sum channel: u_i = sum_j e_z x r_hat_ij,
    a swirl about the vertical through the neighbours that no function of rotation-invariant
    scalars times the pair's own vectors (r_hat alone, for positions) can give."""
    scenario, _, d = KINDS[0]
    policy = make(scenario, hidden=2, collision=False, wall=False, command_limit=1e6, symmetric=False)
    enc, e = policy.encoder, 1e-3
    first = 1 + DISTANCE_BASIS  # log(1 + d), the basis, then the components of r_hat
    assert enc.vectors == 1 + 3 and enc.pair.in_features == first + 3
    with torch.no_grad():
        for param in enc.parameters():
            param.zero_()
        enc.pair.weight[0, first] = e  # r_hat_x
        enc.pair.weight[1, first + 1] = e  # r_hat_y
        out = torch.zeros(2 * enc.vectors, 2)  # rows: sum channel (r_hat, e_x, e_y, e_z), mean channel
        out[2, 0] = 1.0 / e  # e_y gets r_hat_x
        out[1, 1] = -1.0 / e  # e_x gets -r_hat_y
        enc.pair_out.weight.copy_(out)
    Y, mask = batch(d)
    with torch.no_grad():
        u = policy(Y, mask).numpy().astype(np.float64)
    r = (Y[:, 1:] - Y[:, :1]).numpy().astype(np.float64)
    rh = r / np.linalg.norm(r, axis=-1, keepdims=True) * mask[:, 1:].numpy()[..., None]
    swirl = np.cross(np.array([0.0, 0.0, 1.0]), rh).sum(1)
    np.testing.assert_allclose(u, swirl, atol=1e-4)
    assert np.abs(swirl).max() > 0.5


@pytest.mark.parametrize('scenario,p,d', KINDS, ids=IDS)
def test_the_axes_break_rotations_the_half_turn_average_restores_the_arenas(scenario, p, d):
    """Seeing the axes, the network commutes with no rotation in general (unlike the plain
    equivariant encoder, tests/test_policy_equivariant.py), and averaged over the half turns
    (``symmetric``) it commutes with each of them."""
    Y, mask = batch(d)
    R = torch.tensor(special_ortho_group.rvs(p, random_state=3), dtype=torch.float32)
    turn = torch.block_diag(*[R] * (d // p))
    with torch.no_grad():
        plain, seeing = make(scenario, axes=False, symmetric=False), make(scenario, symmetric=False)
        if scenario.arena is None:  # the own position does not enter: the plain encoder commutes
            torch.testing.assert_close(plain.network(Y @ turn.T, mask), plain.network(Y, mask) @ R.T)
        assert not torch.allclose(seeing.network(Y @ turn.T, mask), seeing.network(Y, mask) @ R.T, atol=1e-3)
        averaged = make(scenario, symmetric=True)
        u = averaged.network(Y, mask)
        for signs in half_turns(p):
            s = torch.tensor(signs)
            torch.testing.assert_close(
                averaged.network(Y * s.repeat(d // p), mask), u * s, rtol=1e-5, atol=1e-6
            )


@pytest.mark.parametrize('scenario,p,d', KINDS, ids=IDS)
def test_a_neighbour_in_the_own_state_adds_nothing_to_the_sum(scenario, p, d):
    """The axes' coefficients are taken relative to a neighbour in the own state, as the own
    velocity's: with the means off (the mean channel, the own term), a copy of the robot among
    its neighbours changes nothing."""
    policy = make(scenario, symmetric=False)
    Y, mask = batch(d, k=5)
    mask[0, 4:] = 1.0
    assert_a_copy_of_the_robot_adds_nothing(policy, Y, mask)


@pytest.mark.parametrize('scenario,p,d', KINDS[:3], ids=IDS[:3])
def test_torchscript_and_onnx_equal_the_eager_module(tmp_path, scenario, p, d):
    policy = make(scenario, symmetric=True)
    loaded = assert_exports_equal(policy, tmp_path / 'axes.pt', *batch(d))
    assert loaded.meta['config']['axes'] is True
    assert PolicyConfig(**loaded.meta['config']).axes is True


def test_the_config_refuses_axes_for_other_encoders_and_non_booleans_and_old_files_have_none():
    room = KINDS[0][0]
    for bad in (dict(encoder='set', axes=True), dict(encoder='flat', axes=True), dict(axes='yes')):
        with pytest.raises(ValueError, match='axes'):
            PolicyConfig(room, **{'encoder': 'equivariant', **bad})
    meta = make(room, axes=False).metadata()
    assert meta['config']['axes'] is False
    del meta['config']['axes']  # as files written before the field existed
    old = KNODEPolicy(PolicyConfig(**meta['config']))
    assert old.encoder.axes is False
    assert set(old.state_dict()) == set(make(room, axes=False).state_dict())


def _recipe(scenario, **overrides):
    rng = np.random.default_rng(0)
    tracks = rng.uniform(-2.0, 2.0, size=(2, 6, 9, scenario.state_dim))
    if scenario.heading is not None:
        tracks[..., scenario.heading] /= np.linalg.norm(tracks[..., scenario.heading], axis=-1, keepdims=True)
    ref = json.dumps(scenario.to_dict(), sort_keys=True)
    return resolve_config(load_config(RECIPE, overrides), [tracks], ref, scenario.dt)


@pytest.mark.parametrize(
    'scenario,overrides,axes,symmetric',
    [
        (KINDS[0][0], {}, True, True),  # a room: no rotation symmetry, its half turns
        (KINDS[3][0], {}, False, False),  # open space: exact under rotations already
        (KINDS[3][0], {'augment.rotate': False}, True, False),  # a law declared to have a direction
        (KINDS[0][0], {'policy.axes': False}, False, True),  # an explicit value wins
        (KINDS[0][0], {'policy.encoder': 'set'}, False, True),  # it sees the coordinates already
    ],
    ids=['room', 'open', 'declared', 'explicit', 'set-encoder'],
)
def test_the_recipe_derives_the_axes_where_rotations_are_no_symmetry(scenario, overrides, axes, symmetric):
    cfg, derived = _recipe(scenario, **overrides)
    assert cfg['policy']['axes'] is axes and cfg['policy']['symmetric'] is symmetric
    if 'policy.axes' not in overrides:
        assert derived['policy.axes']['value'] is axes and derived['policy.axes']['how']


def test_a_law_with_a_direction_and_no_axes_is_refused_naming_both_fields():
    with pytest.raises(ConfigError, match="policy.encoder = 'equivariant'.*policy.axes.*augment.rotate"):
        _recipe(KINDS[3][0], **{'augment.rotate': False, 'policy.axes': False})


def _swirling(scenario, **overrides):
    """A policy whose network is the hand-set swirl about z of the test above (knowledge off)."""
    policy = make(scenario, collision=False, wall=False, command_limit=1e6, **overrides)
    enc, e = policy.encoder, 1e-3
    first = 1 + DISTANCE_BASIS
    with torch.no_grad():
        for param in enc.parameters():
            param.zero_()
        enc.pair.weight[0, first], enc.pair.weight[1, first + 1] = e, e
        enc.pair_out.weight[2, 0], enc.pair_out.weight[1, 1] = 1.0 / e, -1.0 / e
    return policy


def test_the_half_turn_about_one_axis_keeps_a_swirl_about_it_all_of_them_cancel_it():
    """The hand-set swirl about z (above), averaged over the half turns: about z alone
    (``symmetric='z'``) it is kept exactly, over all of them it cancels (those about x and y
    reverse it); the z-averaged network commutes with the half turn about z."""
    assert half_turns(3, 'z') == [[1.0, 1.0, 1.0], [-1.0, -1.0, 1.0]]
    for p, about in ((2, 'z'), (3, 'w')):
        with pytest.raises(ValueError, match='half turns'):
            half_turns(p, about)
    scenario, _, d = KINDS[0]
    Y, mask = batch(d)
    out = {}
    for symmetric in (False, 'z', True):
        policy = _swirling(scenario, hidden=2, symmetric=symmetric)
        with torch.no_grad():
            out[symmetric] = policy(Y, mask)
    torch.testing.assert_close(out['z'], out[False])
    assert out[False].abs().max() > 0.5 and out[True].abs().max() < 1e-5
    policy = make(scenario, symmetric='z')
    s = torch.tensor(half_turns(3, 'z')[1])
    with torch.no_grad():
        torch.testing.assert_close(
            policy.network(Y * s, mask), policy.network(Y, mask) * s, rtol=1e-5, atol=1e-6
        )


def test_symmetric_names_an_axis_only_in_3d_and_exports_with_it(tmp_path):
    for scenario, value in ((KINDS[2][0], 'z'), (KINDS[0][0], 'w'), (KINDS[0][0], 'Z')):
        with pytest.raises(ValueError, match='symmetric'):
            PolicyConfig(scenario, encoder='equivariant', symmetric=value)
    scenario, _, d = KINDS[1]
    loaded = assert_exports_equal(make(scenario, symmetric='z'), tmp_path / 'z.pt', *batch(d))
    assert loaded.meta['config']['symmetric'] == 'z'


def test_the_inversion_keeps_a_swirl_cancels_a_constant_push_and_exports(tmp_path):
    """A hand-set network of two parts, the swirl about z (above) and a push along z from each
    neighbour (a hidden unit reading log(1 + d), the coefficient of e_z): averaged over the half
    turn about z the push survives (it sums to a drift, the larger the denser), with the inversion added
    (``inversion=True``) it cancels and the swirl stays exactly; a network of random weights with
    both is odd (u(-Y) = -u(Y)) and commutes with the half turn about z; 2D refuses it (its half turn is
    the inversion); TorchScript and ONNX agree and knode.json records it."""
    scenario, _, d = KINDS[0]
    Y, mask = batch(d)
    out = {}
    for inversion in (False, True):
        policy = _swirling(scenario, hidden=3, symmetric='z', inversion=inversion)
        enc = policy.encoder
        with torch.no_grad():
            swirl = policy(Y, mask)
            enc.pair.weight[2, 0] = 1.0  # log(1 + d / scale) > 0
            enc.pair_out.weight[3, 2] = 1.0  # e_z, in the sum channel
            out[inversion] = (swirl, policy(Y, mask))
    swirl, both = out[False]
    torch.testing.assert_close(both[:, :2], swirl[:, :2])
    assert torch.all(both[:, 2] - swirl[:, 2] > 0.1)  # up, from every row
    swirl_i, both_i = out[True]
    torch.testing.assert_close(swirl_i, swirl)
    torch.testing.assert_close(both_i, swirl)

    policy = make(scenario, symmetric='z', inversion=True)
    s = torch.tensor(half_turns(3, 'z')[1])
    with torch.no_grad():
        torch.testing.assert_close(policy.network(-Y, mask), -policy.network(Y, mask), rtol=1e-5, atol=1e-6)
        torch.testing.assert_close(
            policy.network(Y * s, mask), policy.network(Y, mask) * s, rtol=1e-5, atol=1e-6
        )
    with pytest.raises(ValueError, match='inversion'):
        PolicyConfig(KINDS[2][0], encoder='equivariant', inversion=True)
    scenario, _, d = KINDS[1]
    loaded = assert_exports_equal(make(scenario, symmetric='z', inversion=True), tmp_path / 'i.pt', *batch(d))
    assert loaded.meta['config']['inversion'] is True


def _rings(axis_of, trajectories=12, robots=8, steps=40, seed=0):
    """``[N, T, n, 3]`` robots on rings turning about ``axis_of(i)`` (a unit vector) at 1 rad/s,
    each ring's centre and phase random, inside the room."""
    rng = np.random.default_rng(seed)
    t = np.arange(steps) * 0.05
    out = np.empty((trajectories, steps, robots, 3))
    for i in range(trajectories):
        a = np.asarray(axis_of(i, rng), dtype=float)
        a /= np.linalg.norm(a)
        u = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
        u /= np.linalg.norm(u)
        w = np.cross(a, u)
        phase = rng.uniform(0, 2 * np.pi, robots)[None, :] + t[:, None]  # [T, n]
        radius = rng.uniform(0.5, 1.5, robots)[None, :, None]
        ring = radius * (np.cos(phase)[..., None] * u + np.sin(phase)[..., None] * w)
        out[i] = ring + rng.uniform(-0.5, 0.5, 3)
    return out


@pytest.mark.parametrize(
    'axis_of,expected,named',
    [
        (lambda i, rng: [0.0, 0.0, 1.0], 'z', 'about z'),  # every ring turns one way about z
        (lambda i, rng: [0.0, -1.0, 0.0], 'y', 'about y'),
        (lambda i, rng: [1.0, 0.0, 1.0], False, 'about x and z'),  # no half turn keeps both
        (lambda i, rng: rng.normal(size=3), True, None),  # any sense about any axis: all half turns
    ],
    ids=['z', 'y', 'x-and-z', 'isotropic'],
)
def test_the_recipe_keeps_the_half_turns_that_keep_the_datas_senses_of_rotation(axis_of, expected, named):
    room = KINDS[0][0]
    ref = json.dumps(room.to_dict(), sort_keys=True)
    cfg, derived = resolve_config(load_config(RECIPE), [_rings(axis_of)], ref, room.dt)
    assert (
        cfg['policy']['symmetric'] is expected
        if isinstance(expected, bool)
        else cfg['policy']['symmetric'] == expected
    )
    how = derived['policy.symmetric']['how']
    assert (named in how) if named else ('turn one way' not in how)
    assert cfg['policy']['inversion'] is (expected is not True)  # unless all three half turns stay


@pytest.mark.parametrize('encoder', ['equivariant', 'set'])
@pytest.mark.parametrize(
    'axis_of,rotate,symmetric',
    [
        (lambda i, rng: [0.0, 0.0, 1.0], False, 'z'),  # a swirl about the vertical: its half turn stays
        (lambda i, rng: [1.0, 0.0, 1.0], False, False),
        (lambda i, rng: rng.normal(size=3), True, None),  # isotropic: rotations are a symmetry
    ],
    ids=['z', 'x-and-z', 'isotropic'],
)
def test_in_open_space_a_preferred_sense_turns_the_rotations_off(axis_of, rotate, symmetric, encoder):
    """Without an arena the recipe rotates the data at random, unless the data turn one way about
    an axis: a rotation would turn that sense away. Then the equivariant encoder sees the axes and
    the half turn about the one preferred axis stays, with the inversion (set: the same half turn);
    isotropic data keep the rotations (equivariant: exact already, no average; set: every half
    turn)."""
    space = spec(3, 'position', 'velocity')
    cfg, derived = resolve_config(
        load_config(RECIPE, {'policy.encoder': encoder}),
        [_rings(axis_of)],
        json.dumps(space.to_dict(), sort_keys=True),
        space.dt,
    )
    assert cfg['augment']['rotate'] is rotate
    assert ('turn one way' in derived['augment.rotate']['how']) is not rotate
    assert cfg['policy']['axes'] is (encoder == 'equivariant' and not rotate)
    # the half turns kept leave a constant along an axis: the inversion cancels it
    assert cfg['policy']['inversion'] is (encoder == 'equivariant' and not rotate)
    if symmetric is None:
        symmetric = encoder == 'set'
    got = cfg['policy']['symmetric']
    assert got is symmetric if isinstance(symmetric, bool) else got == symmetric


@pytest.mark.parametrize('field,value', [('symmetric', 'z'), ('inversion', True)])
def test_an_explicit_3d_symmetry_with_the_datas_scenario_is_checked_against_that_scenario(field, value):
    """``--set policy.symmetric=z`` or ``policy.inversion=true`` with the recipe (``scenario:
    auto``): valid for 3D data, refused for 2D data naming the field, once the data's scenario is
    known."""
    room = KINDS[0][0]
    cfg, _ = resolve_config(
        load_config(RECIPE, {f'policy.{field}': value}),
        [_rings(lambda i, rng: rng.normal(size=3))],
        json.dumps(room.to_dict(), sort_keys=True),
        room.dt,
    )
    assert cfg['policy'][field] == value
    flat = KINDS[3][0]
    with pytest.raises(ConfigError, match=f'policy.{field}'):
        resolve_config(
            load_config(RECIPE, {f'policy.{field}': value}),
            [_rings(lambda i, rng: [0.0, 0.0, 1.0])[..., :2]],
            json.dumps(flat.to_dict(), sort_keys=True),
            flat.dt,
        )
