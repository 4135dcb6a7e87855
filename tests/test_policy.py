"""KNODE policy module, TorchScript export and the policy file loader."""

import json
import warnings

import numpy as np
import pytest
import torch

from knode_swarm_ros.core import (
    DEFAULTS,
    KNODEPolicy,
    PolicyConfig,
    PolicyError,
    export_policy,
    load_policy,
    neighbour_matrix,
)


def make_policy(scenario='flock2d', **overrides):
    torch.manual_seed(0)
    cfg = dict(DEFAULTS[scenario])
    cfg.update(overrides)
    return KNODEPolicy(PolicyConfig(scenario, **cfg))


def batch(scenario='flock2d', n=8, seed=0):
    rng = np.random.default_rng(seed)
    d, p = (4, 2) if scenario == 'flock2d' else (6, 3)
    z = rng.normal(scale=2.0, size=(n, d))
    Y, mask = neighbour_matrix(z, z, p, 5.0, 6)
    return torch.tensor(Y, dtype=torch.float32), torch.tensor(mask, dtype=torch.float32)


def save_scripted(module, path, meta):
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        torch.jit.save(torch.jit.script(module), str(path), _extra_files={'knode.json': json.dumps(meta)})


@pytest.mark.parametrize('scenario', ['flock2d', 'boids3d'])
def test_torchscript_round_trip_is_bit_identical(tmp_path, scenario):
    policy = make_policy(scenario).eval()
    path = tmp_path / 'p.pt'
    export_policy(policy, path, policy.metadata())
    loaded = load_policy(path, expect={'scenario': scenario})
    Y, mask = batch(scenario)
    with torch.no_grad():
        eager = policy(Y, mask)
        scripted = loaded.module(Y, mask)
    assert torch.equal(eager, scripted)
    assert loaded.meta['format'] == 'knode-policy/1' and loaded.k == 6
    np.testing.assert_array_equal(loaded(Y.numpy(), mask.numpy()), eager.numpy().astype(np.float64))


def test_command_is_saturated_per_axis_as_the_last_operation():
    policy = make_policy(command_limit=2.5)
    Y = torch.zeros(1, 6, 4)
    Y[0, 1, 0] = 0.01  # a neighbour almost on top: an enormous repulsion along -x
    mask = torch.zeros(1, 6)
    mask[0, :2] = 1
    out = policy(Y, mask)
    assert out[0, 0].item() == -2.5
    Y, mask = batch()
    assert policy(Y * 50, mask).abs().max().item() <= 2.5


def test_relative_frame_is_translation_invariant_for_flock2d():
    policy = make_policy()
    Y, mask = batch()
    shifted = Y.clone()
    shifted[:, :, :2] += torch.tensor([100.0, -40.0]) * mask[..., None]
    torch.testing.assert_close(policy(shifted, mask), policy(Y, mask), atol=2e-4, rtol=1e-4)
    absolute = make_policy(frame='absolute')
    assert not torch.allclose(absolute(shifted, mask), absolute(Y, mask), atol=1e-3)


def test_translation_invariance_holds_for_rows_with_missing_neighbours():
    # 3 robots, k = 6: every matrix has padded rows. The mask must hide them from the
    # relative features, or the command depends on where the swarm is.
    policy = make_policy()
    Y, mask = batch(n=3, seed=4)
    assert (mask.sum(-1) < 6).all() and (mask.sum(-1) > 1).any()
    shifted = Y.clone()
    shifted[:, :, :2] += torch.tensor([30.0, -20.0]) * mask[..., None]
    torch.testing.assert_close(policy(shifted, mask), policy(Y, mask), atol=2e-4, rtol=1e-4)


def test_relative_features_tell_a_missing_row_from_a_coincident_neighbour():
    policy = make_policy(collision=False)
    Y = torch.zeros(2, 6, 4)
    mask = torch.zeros(2, 6)
    mask[:, 0] = 1
    mask[1, 1] = 1  # row 1 of sample 1 is a neighbour at the robot's own state
    f = policy.features(Y, mask)
    assert not torch.equal(f[0], f[1])


def test_boids3d_has_wall_knowledge_and_flock2d_has_none():
    assert make_policy('boids3d').use_wall and not make_policy('flock2d').use_wall
    policy = make_policy('boids3d')
    Y = torch.zeros(1, 6, 6)
    Y[0, 0, :3] = torch.tensor([4.8, 0.0, 0.0])
    mask = torch.zeros(1, 6)
    mask[0, 0] = 1
    k = policy.knowledge(Y, mask)
    assert k[0, 0] < 0 and k[0, 1] == 0 and k[0, 2] == 0


def test_invalid_config_names_the_field():
    with pytest.raises(ValueError, match='frame'):
        PolicyConfig('flock2d', frame='polar')
    with pytest.raises(ValueError, match='unknown scenario'):
        PolicyConfig('flock5d')


@pytest.mark.parametrize(
    'field,edge,bad',
    [
        ('k', 1, 0),
        ('d_cr', 1e-9, 0.0),
        ('tau', 0, -1),
        ('hidden', 1, 0),
        ('command_limit', 1e-9, 0.0),
        ('collision_d0', 1e-9, 0.0),
        ('wall_d0', 1e-9, 0.0),
        ('collision_a', 0.0, -1e-9),
        ('wall_a', 0.0, -1e-9),
    ],
)
def test_config_fields_are_checked_at_their_edges(field, edge, bad):
    """The smallest valid value is accepted (k = 1: the own row only), the next one out refused by name."""
    assert getattr(PolicyConfig('flock2d', **{field: edge}), field) == edge
    with pytest.raises(ValueError, match=f'invalid {field} = '):
        PolicyConfig('flock2d', **{field: bad})


# --- the loader refuses every kind of bad file with a message naming the problem ---


@pytest.fixture
def good(tmp_path):
    policy = make_policy()
    path = tmp_path / 'good.pt'
    export_policy(policy, path, policy.metadata())
    return policy, path


def test_missing_file(tmp_path):
    with pytest.raises(PolicyError, match='no such file'):
        load_policy(tmp_path / 'nope.pt')


def test_garbage_and_truncated_files(tmp_path, good):
    junk = tmp_path / 'junk.pt'
    junk.write_bytes(b'this is not a zip archive at all')
    with pytest.raises(PolicyError, match='not a readable TorchScript archive'):
        load_policy(junk)
    data = good[1].read_bytes()
    cut = tmp_path / 'cut.pt'
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(PolicyError, match='not a readable TorchScript archive'):
        load_policy(cut)


def test_archive_without_metadata(tmp_path, good):
    path = tmp_path / 'nometa.pt'
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        torch.jit.save(torch.jit.script(good[0]), str(path))
    with pytest.raises(PolicyError, match='no knode.json'):
        load_policy(path)


def test_invalid_json(tmp_path, good):
    path = tmp_path / 'badjson.pt'
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        torch.jit.save(torch.jit.script(good[0]), str(path), _extra_files={'knode.json': '{not json'})
    with pytest.raises(PolicyError, match='not valid JSON'):
        load_policy(path)


# The required keys of docs/DESIGN.md, spelt out here (not imported) so that dropping one from
# the loader's list is caught.
@pytest.mark.parametrize(
    'key',
    ['format', 'scenario', 'state_dim', 'command_dim', 'command', 'k', 'd_cr', 'tau', 'dt', 'state_layout'],
)
def test_every_missing_required_key_is_named(tmp_path, good, key):
    meta = good[0].metadata()
    del meta[key]
    path = tmp_path / 'missing.pt'
    save_scripted(good[0], path, meta)
    with pytest.raises(PolicyError, match=f'lacks required key.*\\b{key}\\b'):
        load_policy(path)


@pytest.mark.parametrize(
    'key,value,message',
    [
        ('k', None, 'lacks required key.*k'),
        ('state_dim', 6, "'state_dim'"),
        ('format', 'knode-policy/0', "'format'"),
        ('command', 'velocity', "'command'"),
        ('tau', -1, "'tau'"),
        ('d_cr', 'five', "'d_cr'"),
        ('scenario', 'flock5d', "'scenario'"),
    ],
)
def test_bad_metadata_names_the_key(tmp_path, good, key, value, message):
    meta = good[0].metadata()
    if value is None:
        del meta[key]
    else:
        meta[key] = value
    path = tmp_path / 'bad.pt'
    save_scripted(good[0], path, meta)
    with pytest.raises(PolicyError, match=message):
        load_policy(path)


def test_expected_values_are_enforced(good):
    with pytest.raises(PolicyError, match=r"'k' is 6 but 4 was required"):
        load_policy(good[1], expect={'k': 4})
    with pytest.raises(PolicyError, match="'scenario'"):
        load_policy(good[1], expect={'scenario': 'boids3d'})
    assert load_policy(good[1], expect={'k': 6, 'd_cr': 5.0, 'tau': 0}).k == 6


class WrongShape(torch.nn.Module):
    def forward(self, Y: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        return torch.zeros(Y.shape[0], 3)


class WrongSignature(torch.nn.Module):
    def forward(self, Y: torch.Tensor) -> torch.Tensor:
        return Y[:, 0, :2]


@pytest.mark.parametrize(
    'module,message',
    [(WrongShape(), r'expected a tensor of shape \(2, 2\)'), (WrongSignature(), 'forward.*failed')],
)
def test_wrong_forward_is_refused(tmp_path, good, module, message):
    path = tmp_path / 'wrong.pt'
    save_scripted(module, path, good[0].metadata())
    with pytest.raises(PolicyError, match=message):
        load_policy(path)


def test_foreign_policy_with_only_required_keys_is_valid(tmp_path):
    class Foreign(torch.nn.Module):
        def forward(self, Y: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
            return -Y[:, 0, 2:4]

    meta = {
        'format': 'knode-policy/1',
        'scenario': 'flock2d',
        'state_dim': 4,
        'command_dim': 2,
        'command': 'acceleration',
        'k': 3,
        'd_cr': 2.0,
        'tau': 0,
        'dt': 0.01,
        'state_layout': ['px', 'py', 'vx', 'vy'],
        'unknown_key': {'ignored': True},
    }
    path = tmp_path / 'foreign.pt'
    save_scripted(Foreign(), path, meta)
    loaded = load_policy(path)
    assert loaded.k == 3 and loaded.command_limit is None


def test_export_is_atomic_and_keeps_the_old_file_on_failure(tmp_path, good):
    before = good[1].read_bytes()
    meta = good[0].metadata()
    del meta['dt']
    with pytest.raises(PolicyError):
        export_policy(good[0], good[1], meta)
    assert good[1].read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ['good.pt']


def test_export_refuses_a_module_whose_source_changed_on_disk_since_it_was_built(tmp_path, good, monkeypatch):
    """torch.jit.script compiles a class's source as the file holds it now: a module built before
    its file was edited (a training that runs while the package is changed or upgraded) would be
    exported as other code than the one that trained. The export compares the two and refuses,
    leaving the old file as it was."""
    source = tmp_path / 'drifting_policy.py'
    body = (
        'import torch\n\n\nclass Policy(torch.nn.Module):\n'
        '    def forward(self, Y: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:\n'
        '        return Y[:, 0, 2:] * {}\n'
    )
    source.write_text(body.format('0.5'))
    monkeypatch.syspath_prepend(str(tmp_path))
    import importlib

    module = importlib.import_module('drifting_policy').Policy()
    Y, mask = batch()
    np.testing.assert_allclose(module(Y, mask).numpy(), 0.5 * Y[:, 0, 2:].numpy())
    source.write_text(body.format('2.0 + 0.0'))  # edited on disk, the module in memory unchanged
    meta = good[0].metadata()
    before = good[1].read_bytes()
    with pytest.raises(PolicyError, match='differs from the module it was made from.*source changed'):
        export_policy(module, good[1], meta)
    assert good[1].read_bytes() == before


def test_expected_text_values_must_be_equal_not_merely_ordered():
    """A boids3d file where flock2d is required is refused although "boids3d" < "flock2d"
    (mutation survivor: only files whose text sorted after the required one were refused)."""
    from knode_swarm_ros.core.policy_meta import check_meta

    meta = make_policy('boids3d').metadata()
    check_meta('p.pt', meta, expect={'scenario': 'boids3d'})
    for other in ('flock2d', 'zeta'):
        with pytest.raises(PolicyError, match="'scenario'"):
            check_meta('p.pt', meta, expect={'scenario': other})


def test_command_limit_bounds_are_open_at_zero_only():
    from knode_swarm_ros.core.policy_meta import check_meta

    meta = make_policy().metadata()
    for ok in (1e-3, 0.5, 1e9):
        check_meta('p.pt', dict(meta, command_limit=ok))
    for bad in (0.0, -1.0, 1e9 * 1.5):
        with pytest.raises(PolicyError, match="'command_limit' has invalid value"):
            check_meta('p.pt', dict(meta, command_limit=bad))
