"""The network averaged over the half turns (``policy.symmetric``): exact equivariance under
them for every scenario kind and encoder, no drift of a neighbourhood without a direction,
TorchScript and ONNX parity, old files and the derived config field."""

import json
import os

import numpy as np
import pytest
import torch
from export_parity import assert_exports_equal

from knode_swarm_ros.core import DEFAULTS, KNODEPolicy, PolicyConfig
from knode_swarm_ros.core.policy import half_turns
from knode_swarm_ros.core.scenarios import scenario_from_dict
from training.learning.config import load_config, resolve_config

torch.set_num_threads(1)


def custom(name, dimensions, state, command, arena=None):
    return scenario_from_dict(
        dict(name=name, dimensions=dimensions, state=state, command=command, dt=0.05, arena=arena)
    )


ARENA = custom('box3d', 3, 'position_velocity', 'acceleration', {'half_width': 4.0})
FIRST_ORDER = custom('gather2d', 2, 'position', 'velocity')
HEADING2D = custom('school2d', 2, 'position_heading', 'velocity')
SCENARIOS = [('flock2d', 2, 4), ('boids3d', 3, 6), (ARENA, 3, 6), (FIRST_ORDER, 2, 2), (HEADING2D, 2, 4)]
IDS = ['flock2d', 'boids3d', 'arena3d', 'position2d', 'heading2d']


def make(scenario, encoder, symmetric=True, seed=0, **overrides):
    torch.manual_seed(seed)
    base = dict(DEFAULTS.get(scenario if isinstance(scenario, str) else '', {}))
    base.update(encoder=encoder, hidden=16, symmetric=symmetric, position_scale=1.3, velocity_scale=0.7)
    base.update(overrides)
    return KNODEPolicy(PolicyConfig(scenario, **base)).eval()


def batch(d, k=6, B=7, seed=0):
    g = torch.Generator().manual_seed(seed)
    Y = 2.0 * torch.randn(B, k, d, generator=g)
    mask = torch.ones(B, k)
    mask[0, 4:] = 0.0
    return Y, mask


def test_half_turns_are_rotations_that_average_a_constant_to_zero():
    for p in (2, 3):
        signs = np.array(half_turns(p))
        assert np.all(signs[0] == 1.0)  # the identity first (the policy starts its sum with it)
        assert np.all(np.prod(signs, axis=1) == 1.0)  # determinant +1: rotations, no mirror
        assert np.all(signs.sum(axis=0) == 0.0)  # the mean of g c over the group is 0
        assert {tuple(a * b) for a in signs for b in signs} == {tuple(s) for s in signs}  # a group
    with pytest.raises(ValueError, match='half turns'):
        half_turns(4)


@pytest.mark.parametrize('encoder', ['flat', 'set', 'equivariant'])
@pytest.mark.parametrize('scenario,p,d', SCENARIOS, ids=IDS)
def test_the_network_commutes_with_every_half_turn(scenario, p, d, encoder):
    policy = make(scenario, encoder)
    Y, mask = batch(d)
    with torch.no_grad():
        u = policy.network(Y, mask)
        for turn in half_turns(p):
            s = torch.tensor(turn)
            turned = policy.network(Y * s.repeat(d // p), mask)
            torch.testing.assert_close(turned, u * s, rtol=1e-5, atol=1e-6)
        # the whole policy too: knowledge terms and saturation commute with the half turns
        s = torch.tensor(half_turns(p)[1])
        torch.testing.assert_close(
            policy(Y * s.repeat(d // p), mask), policy(Y, mask) * s, rtol=1e-5, atol=1e-6
        )


@pytest.mark.parametrize('scenario,p,d', SCENARIOS, ids=IDS)
def test_without_the_field_the_network_is_not_equivariant(scenario, p, d):
    """The property above is the averaging's, not the test's."""
    policy = make(scenario, 'flat', symmetric=False)
    Y, mask = batch(d)
    s = torch.tensor(half_turns(p)[1])
    with torch.no_grad():
        assert not torch.allclose(
            policy.network(Y * s.repeat(d // p), mask), policy.network(Y, mask) * s, atol=1e-4
        )


def test_a_neighbourhood_symmetric_under_a_half_turn_gets_no_command():
    """A robot between neighbour pairs at +r and -r: whatever the weights, the set encoder gives
    no push (the half-turned neighbourhood is the same set). Unaveraged, a network gives such a
    robot a constant that the set encoder sums per neighbour: a dense swarm drifts."""
    policy = make(FIRST_ORDER, 'set', collision=False, k=7)
    offsets = torch.tensor(
        [[0.0, 0.0], [0.7, 0.2], [-0.7, -0.2], [0.1, -0.9], [-0.1, 0.9], [1.5, 1.0], [-1.5, -1.0]]
    )
    Y, mask = (offsets + torch.tensor([3.0, -2.0]))[None], torch.ones(1, 7)
    with torch.no_grad():
        assert policy(Y, mask).abs().max() < 1e-6
        assert make(FIRST_ORDER, 'set', symmetric=False, collision=False, k=7)(Y, mask).abs().max() > 1e-3


@pytest.mark.parametrize('scenario,p,d', [SCENARIOS[1], SCENARIOS[3]], ids=['boids3d', 'position2d'])
@pytest.mark.parametrize('encoder', ['flat', 'set'])
def test_torchscript_and_onnx_equal_the_eager_module(tmp_path, scenario, p, d, encoder):
    policy = make(scenario, encoder, k=6)
    loaded = assert_exports_equal(policy, tmp_path / 'sym.pt', *batch(d))
    assert loaded.meta['config']['symmetric'] is True
    assert PolicyConfig(**loaded.meta['config']).symmetric


def test_a_policy_config_without_the_field_is_not_averaged():
    meta = make('flock2d', 'flat', symmetric=False).metadata()
    del meta['config']['symmetric']  # as files written before the field existed
    assert PolicyConfig(**meta['config']).symmetric is False
    with pytest.raises(ValueError, match='symmetric'):
        PolicyConfig('flock2d', symmetric='yes')


RECIPE = os.path.join(os.path.dirname(__file__), '..', 'config', 'train_custom.yaml')


@pytest.mark.parametrize(
    'spec,overrides,expected',
    [
        (FIRST_ORDER, {}, True),
        (FIRST_ORDER, {'augment.rotate': False}, False),  # a law with a preferred direction
        (ARENA, {}, True),  # the half turns map the arena onto itself
        (ARENA, {'policy.symmetric': False}, False),  # an explicit value wins
    ],
    ids=['rotations', 'no-rotations', 'arena', 'explicit'],
)
def test_the_recipe_derives_the_field_from_the_scenarios_symmetry(spec, overrides, expected):
    rng = np.random.default_rng(0)
    tracks = rng.uniform(-2.0, 2.0, size=(2, 6, 5, spec.state_dim))
    tracks[..., spec.position] = np.cumsum(0.05 * tracks[..., spec.position], axis=1)
    ref = json.dumps(spec.to_dict(), sort_keys=True)
    # the set encoder's rule (the equivariant one needs no average without an arena)
    cfg, derived = resolve_config(
        load_config(RECIPE, {'policy.encoder': 'set', **overrides}), [tracks], ref, 0.05
    )
    assert cfg['policy']['symmetric'] is expected
    assert ('policy.symmetric' in derived) is ('policy.symmetric' not in overrides)
