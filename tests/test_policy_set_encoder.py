"""The permutation-invariant neighbour encoders (``policy.encoder: set`` and ``equivariant``):
invariance to the order of the neighbour rows and to masked padding rows, TorchScript and ONNX
parity with the eager module, metadata (old files are flat, a bad value is named) and the
config field."""

import json
import os
import warnings

import numpy as np
import pytest
import torch
from export_parity import assert_exports_equal

from knode_swarm_ros.core import (
    DEFAULTS,
    KNODEPolicy,
    PolicyConfig,
    PolicyError,
    load_policy,
    neighbour_matrix,
)
from knode_swarm_ros.core.errors import ConfigError
from knode_swarm_ros.core.scenarios import scenario_from_dict
from training.learning.config import load_config, resolve_config
from training.learning.derive import lattice_neighbours

torch.set_num_threads(1)
ARENA = scenario_from_dict(
    dict(
        name='box3d',
        dimensions=3,
        state='position_velocity',
        command='acceleration',
        dt=0.05,
        arena={'half_width': 4.0},
    )
)


ROW_FREE = ['set', 'equivariant']


def make(scenario, seed=0, **overrides):
    torch.manual_seed(seed)
    base = dict(DEFAULTS.get(scenario if isinstance(scenario, str) else '', {}))
    base.update(encoder='set', hidden=16, position_scale=1.7, velocity_scale=0.6)
    base.update(overrides)
    return KNODEPolicy(PolicyConfig(scenario, **base)).eval()


def swarm_batch(spec_dims, k, n=12, seed=0, d_cr=3.0):
    p, d = spec_dims
    rng = np.random.default_rng(seed)
    z = rng.normal(scale=2.0, size=(n, d))
    Y, mask = neighbour_matrix(z, z, p, d_cr, k)
    return torch.tensor(Y, dtype=torch.float32), torch.tensor(mask, dtype=torch.float32)


FIRST_ORDER = scenario_from_dict(
    dict(name='gather2d', dimensions=2, state='position', command='velocity', dt=0.05, arena=None)
)
CASES = [('flock2d', (2, 4)), ('boids3d', (3, 6)), (ARENA, (3, 6)), (FIRST_ORDER, (2, 2))]
IDS = ['flock2d', 'boids3d', 'arena3d', 'position2d']


@pytest.mark.parametrize('scenario,dims', CASES, ids=IDS)
@pytest.mark.parametrize('potential', ['paper', 'continuous'])
@pytest.mark.parametrize('encoder', ROW_FREE)
def test_shuffling_neighbour_rows_gives_the_same_command(scenario, dims, potential, encoder):
    policy = make(scenario, k=8, potential=potential, encoder=encoder)
    Y, mask = swarm_batch(dims, 8)
    assert 0 < mask[:, 1:].sum() < mask[:, 1:].numel()  # some neighbours, some empty rows
    perm = torch.cat(
        [torch.zeros(1, dtype=torch.long), 1 + torch.randperm(7, generator=torch.Generator().manual_seed(1))]
    )
    with torch.no_grad():
        a, b = policy(Y, mask), policy(Y[:, perm], mask[:, perm])
    assert not torch.equal(perm, torch.arange(8))
    torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize('scenario,dims', CASES, ids=IDS)
@pytest.mark.parametrize('encoder', ROW_FREE)
def test_masked_padding_rows_change_nothing(scenario, dims, encoder):
    """A policy learnt with k = 6 runs unchanged with k = 20: the extra rows are masked."""
    policy = make(scenario, k=6, encoder=encoder)
    Y, mask = swarm_batch(dims, 6, n=5)
    pad = 14
    Yp = torch.cat([Y, torch.zeros(Y.shape[0], pad, Y.shape[2])], dim=1)
    mp = torch.cat([mask, torch.zeros(mask.shape[0], pad)], dim=1)
    with torch.no_grad():
        assert torch.equal(policy(Y, mask), policy(Yp, mp))
        # the same swarm with k = 20 from the neighbour matrix: the same rows, padded
        Y20, m20 = swarm_batch(dims, 20, n=5)
        torch.testing.assert_close(policy(Y20, m20), policy(Y, mask), rtol=0, atol=0)


def test_the_flat_encoder_is_not_permutation_invariant():
    """The property above is the set encoder's, not the test's (the flat MLP fails it)."""
    policy = make('flock2d', k=8, encoder='flat', position_scale=1.0, velocity_scale=1.0)
    Y, mask = swarm_batch((2, 4), 8)
    perm = torch.tensor([0, 2, 1, 3, 4, 5, 6, 7])
    with torch.no_grad():
        assert not torch.allclose(policy(Y, mask), policy(Y[:, perm], mask[:, perm]), atol=1e-4)


@pytest.mark.parametrize('encoder', ROW_FREE)
def test_more_neighbours_push_harder_through_the_sum_channel(encoder):
    """Weights do not depend on k, and a duplicated neighbour set changes the command (the sum)."""
    policy = make('flock2d', k=8, collision=False, encoder=encoder)
    Y, mask = swarm_batch((2, 4), 4, n=4, d_cr=50.0)
    twice = torch.cat([Y, Y[:, 1:]], dim=1), torch.cat([mask, mask[:, 1:]], dim=1)
    with torch.no_grad():
        assert not torch.allclose(policy(Y, mask), policy(*twice))


@pytest.mark.parametrize('scenario,dims', CASES, ids=IDS)
@pytest.mark.parametrize('encoder', ROW_FREE)
def test_torchscript_and_onnx_equal_the_eager_module(tmp_path, scenario, dims, encoder):
    policy = make(scenario, k=9, potential='continuous', encoder=encoder)
    loaded = assert_exports_equal(policy, tmp_path / 'set.pt', *swarm_batch(dims, 9))
    assert loaded.meta['encoder'] == encoder and loaded.meta['config']['encoder'] == encoder


def test_a_policy_file_without_the_field_loads_as_flat(tmp_path):
    flat = make('flock2d', encoder='flat', position_scale=1.0, velocity_scale=1.0)
    meta = flat.metadata()
    del meta['encoder'], meta['config']['encoder']  # as files written before the field existed
    path = tmp_path / 'old.pt'
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        torch.jit.save(torch.jit.script(flat), str(path), _extra_files={'knode.json': json.dumps(meta)})
    loaded = load_policy(path)
    assert PolicyConfig(**loaded.meta['config']).encoder == 'flat'
    assert 'encoder' not in loaded.meta


def test_a_bad_encoder_in_knode_json_is_named(tmp_path):
    policy = make('flock2d')
    meta = {**policy.metadata(), 'encoder': 'graph'}
    path = tmp_path / 'bad.pt'
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        torch.jit.save(torch.jit.script(policy), str(path), _extra_files={'knode.json': json.dumps(meta)})
    with pytest.raises(PolicyError, match="'encoder' is 'graph'"):
        load_policy(path)


def test_the_config_field_is_validated_by_name(tmp_path):
    recipe = tmp_path / 'r.yaml'
    recipe.write_text('scenario: flock2d\npolicy:\n  encoder: graph\n')
    with pytest.raises(ConfigError, match='policy.encoder'):
        load_config(str(recipe))
    recipe.write_text('scenario: flock2d\npolicy:\n  encoder: set\n  frame: absolute\n')
    with pytest.raises(ConfigError, match='policy.encoder'):
        load_config(str(recipe))
    recipe.write_text('scenario: flock2d\npolicy:\n  encoder: set\n')
    assert load_config(str(recipe))['policy']['encoder'] == 'set'


def test_close_packed_lattice_counts():
    # hexagonal shells 1, sqrt 3, 2, sqrt 7, 3: 6 + 6 + 6 + 12 + 6
    assert lattice_neighbours(2, 1.0) == 6 and lattice_neighbours(2, 3.0) == 36
    # fcc shells up to 3: 12 + 6 + 24 + 12 + 24 + 8 + 48 + 6 + 36
    assert lattice_neighbours(3, 1.0) == 12 and lattice_neighbours(3, 3.0) == 176


def test_the_set_encoder_derives_its_range_and_k_from_the_data():
    """A 3 x 3 lattice of spacing 0.5: every pair is at most 2 sqrt(2) spacings apart, under
    3 spacings, so d_cr = 1.5; 36 lattice robots lie within it, and the data show 8 neighbours,
    so k = 1 + min(36, 4 x 8) = 33."""
    spacing = 0.5
    grid = spacing * np.array([[i, j] for i in range(3) for j in range(3)], dtype=float)
    tracks = np.stack([grid[None] + 0.1 * np.arange(5)[:, None, None] * np.array([0.3, 0.4])] * 2)
    spec = scenario_from_dict(
        dict(name='lattice', dimensions=2, state='position', command='velocity', dt=0.1, arena=None)
    )
    recipe = os.path.join(os.path.dirname(__file__), '..', 'config', 'train_custom.yaml')
    ref = json.dumps(spec.to_dict(), sort_keys=True)
    cfg, derived = resolve_config(load_config(recipe, {'policy.encoder': 'set'}), [tracks], ref, 0.1)
    assert cfg['policy']['d_cr'] == pytest.approx(1.5) and cfg['policy']['k'] == 33
    assert 'close-packed hexagonal lattice' in derived['policy.k']['how']
    # a wider swarm: the range is the 99th percentile of the distances between robots
    wide = tracks * np.array([4.0, 1.0])
    cfg, derived = resolve_config(load_config(recipe, {'policy.encoder': 'set'}), [wide], ref, 0.1)
    pairs = np.linalg.norm(wide[0, 0][None] - wide[0, 0][:, None], axis=-1)[~np.eye(9, dtype=bool)]
    assert cfg['policy']['d_cr'] == pytest.approx(np.quantile(pairs, 0.99), rel=1e-5)
    assert derived['policy.d_cr']['how'].startswith('the 99th percentile of the distances')


@pytest.mark.parametrize('scenario,dims', CASES, ids=IDS)
@pytest.mark.parametrize('encoder', ROW_FREE)
def test_a_neighbour_in_the_robots_own_state_adds_nothing_to_the_sum(scenario, dims, encoder):
    """No constant per neighbour: a denser swarm of copies of the robot does not drift."""
    policy = make(scenario, k=8, collision=False, wall=False, encoder=encoder)
    Y, mask = swarm_batch(dims, 2, n=6, d_cr=0.01)  # the robot alone
    copies = torch.cat([Y[:, :1]] * 8, dim=1), torch.ones(Y.shape[0], 8)
    with torch.no_grad():
        h_alone = policy(Y, mask)
        torch.testing.assert_close(policy(*copies), h_alone, rtol=1e-5, atol=1e-5)
