"""PolicyConfig.potential = "continuous" through the policy, its files and the training config.

* the config refuses an unknown form by name; the policy's knowledge() is the continuous
  functions of core.knowledge (collisions, and walls in boids3d);
* eager == TorchScript bit for bit; the exported file records ``potential`` in knode.json's
  config and keeps its baked-in form when loaded (a paper policy with the same weights differs);
* the ONNX twin equals TorchScript within 1e-5 (flock2d, and boids3d with walls);
* the training config accepts ``--set policy.potential=continuous`` (the trained file records
  it) and refuses a bad value with exit status 2 naming ``policy.potential``.
"""

import numpy as np
import onnxruntime  # noqa: F401  (a broken install must fail, not skip)
import pytest
import torch
import yaml

from knode_swarm_ros.core import (
    DEFAULTS,
    KNODEPolicy,
    PolicyConfig,
    export_policy,
    get_scenario,
    load_policy,
    load_runtime,
    save_trajectories,
)
from knode_swarm_ros.core.knowledge import (
    collision_avoidance,
    continuous_collision_avoidance,
    continuous_wall_avoidance,
    wall_avoidance,
)
from training.learning.config import ConfigError, build_policy, load_config, normalise_config
from training.learning.onnx_twin import check_inputs, compare, export_onnx
from training.train import main as train_main

torch.set_num_threads(1)
pytestmark = pytest.mark.filterwarnings('ignore:`torch.jit.script` is deprecated:DeprecationWarning')
SCENARIOS = ['flock2d', 'boids3d']


def make_policy(scenario, potential='continuous', seed=0, **overrides):
    torch.manual_seed(seed)
    return KNODEPolicy(PolicyConfig(scenario, **{**DEFAULTS[scenario], 'potential': potential, **overrides}))


def close_batch(scenario, B=32, seed=0):
    """Neighbour matrices ``[B, 6, d]``, neighbours 0.6 to 1.2 away (most within d0 = 1, few so
    close that the command saturates), some masked; in boids3d the robot is near the walls (box 5)
    half of the time."""
    spec = get_scenario(scenario)
    p, d = spec.position_dim, spec.state_dim
    g = torch.Generator().manual_seed(seed)
    Y = torch.randn(B, 6, d, generator=g)
    Y[:, 0, :p] = torch.where(torch.rand(B, 1, generator=g) < 0.5, 4.5, 0.0) * torch.sign(
        torch.randn(B, p, generator=g)
    )
    direction = torch.randn(B, 5, p, generator=g)
    direction = direction / direction.norm(dim=-1, keepdim=True)
    Y[:, 1:, :p] = Y[:, :1, :p] + (0.6 + 0.6 * torch.rand(B, 5, 1, generator=g)) * direction
    mask = (torch.rand(B, 6, generator=g) < 0.7).float()
    mask[:, 0] = 1
    return Y * mask[..., None], mask


# --- the config and the module ---------------------------------------------------------------


def test_config_accepts_both_forms_and_refuses_another_by_name():
    assert PolicyConfig('flock2d').potential == 'paper'  # the paper's form stays the default
    for form in ('paper', 'continuous'):
        assert PolicyConfig('flock2d', potential=form).potential == form
    for bad in ('bogus', 'Continuous', '', None):
        with pytest.raises(ValueError, match=f'invalid potential = {bad!r}'):
            PolicyConfig('flock2d', potential=bad)


@pytest.mark.parametrize('scenario', SCENARIOS)
def test_knowledge_is_the_continuous_functions(scenario):
    policy = make_policy(scenario, collision_phi=1.3, wall_phi=0.7)
    spec = get_scenario(scenario)
    Y, mask = close_batch(scenario)
    p = spec.position_dim
    lam = torch.tensor(DEFAULTS[scenario]['collision_a'] + 1.3**2)  # lambda = a + phi^2
    lam_wall = torch.tensor(0.7**2)  # boids3d: wall_a = 0
    with torch.no_grad():
        expected = continuous_collision_avoidance(Y, mask, p, lam, 1.0)
        if scenario == 'boids3d':
            walls = continuous_wall_avoidance(Y[:, 0, :p], 5.0, lam_wall, 1.0)
            assert walls.abs().max() > 0
            expected = expected + walls
        got = policy.knowledge(Y, mask)
    torch.testing.assert_close(got, expected)
    assert (got.abs().sum(-1) > 0).float().mean() > 0.5  # the terms are active on most rows
    # the switch is real: the paper policy, same gains, has the paper's terms and differs
    paper = make_policy(scenario, 'paper', collision_phi=1.3, wall_phi=0.7)
    with torch.no_grad():
        expected = collision_avoidance(Y, mask, p, lam, 1.0)
        if scenario == 'boids3d':
            expected = expected + wall_avoidance(Y[:, 0, :p], 5.0, lam_wall, 1.0)
        torch.testing.assert_close(paper.knowledge(Y, mask), expected)
        assert not torch.allclose(expected, got)


@pytest.mark.parametrize('scenario', SCENARIOS)
def test_scripted_module_equals_eager_bit_for_bit(scenario):
    policy = make_policy(scenario).eval()
    scripted = torch.jit.script(policy)
    Y, mask = close_batch(scenario, seed=1)
    with torch.no_grad():
        assert torch.equal(scripted(Y, mask), policy(Y, mask))
        assert torch.equal(scripted.knowledge(Y, mask), policy.knowledge(Y, mask))


@pytest.mark.parametrize('scenario', SCENARIOS)
def test_file_round_trip_records_and_keeps_the_form(tmp_path, scenario):
    policy = make_policy(scenario).eval()
    path = tmp_path / 'continuous.pt'
    export_policy(policy, path, policy.metadata())
    loaded = load_policy(path, expect={'scenario': scenario})
    assert loaded.meta['config']['potential'] == 'continuous'
    Y, mask = close_batch(scenario, seed=2)
    with torch.no_grad():
        eager = policy(Y, mask)
        assert torch.equal(loaded.module(Y, mask), eager)
        # A paper policy with the very same weights: the file does not follow the config's
        # default, it carries its own form (TorchScript bakes in the code).
        paper = make_policy(scenario, 'paper')
        paper.load_state_dict(policy.state_dict())
        assert not torch.allclose(paper(Y, mask), eager)
    paper_path = tmp_path / 'paper.pt'
    export_policy(paper, paper_path, paper.metadata())
    assert load_policy(paper_path).meta['config']['potential'] == 'paper'
    # one neighbour just inside d0 = 1: the continuous file adds ~0, the paper file lambda / d0^3
    lam = DEFAULTS[scenario]['collision_a'] + DEFAULTS[scenario]['collision_phi'] ** 2
    Y1 = torch.zeros(1, 6, get_scenario(scenario).state_dim)
    Y1[0, 1, 0] = 0.999
    mask1 = torch.tensor([[1.0, 1, 0, 0, 0, 0]])
    with torch.no_grad():
        net = policy.net(policy.features(Y1, mask1))
        cont = load_policy(path).module(Y1, mask1) - net
        pap = load_policy(paper_path).module(Y1, mask1) - net
    assert cont.abs().max() < 1e-2 * lam and abs(pap[0, 0].item() + lam / 0.999**3) < 1e-4


# --- the ONNX twin -----------------------------------------------------------------------------


@pytest.mark.parametrize('scenario', SCENARIOS)
def test_onnx_twin_equals_torchscript(tmp_path, scenario):
    policy = make_policy(scenario, seed=3)
    pt = tmp_path / f'{scenario}.pt'
    export_policy(policy, pt, policy.metadata())
    export_onnx(pt)
    ts, ox = load_runtime(pt, 'torchscript'), load_runtime(pt, 'onnxruntime')
    assert (
        ox.backend == 'onnxruntime' and ox.meta == ts.meta and ox.meta['config']['potential'] == 'continuous'
    )
    table = check_inputs(ts.meta, seed=11)
    assert ('walls' in table) == (scenario == 'boids3d')
    Y, mask = close_batch(scenario, B=64, seed=4)
    table['close neighbours'] = (Y.numpy(), mask.numpy())
    errors = compare(ts, ox, table)
    assert max(errors.values()) <= 1e-5, errors
    # the close batch is mostly unsaturated: the comparison sees the knowledge terms, not the clip
    u = ts(*table['close neighbours'])
    assert (np.abs(u).max(axis=1) < ts.command_limit).mean() > 0.3


# --- the training config and command line ----------------------------------------------------


def test_training_config_accepts_the_form_and_names_a_bad_one():
    cfg = normalise_config({'scenario': 'boids3d', 'policy': {'potential': 'continuous'}})
    assert cfg['policy']['potential'] == 'continuous' and build_policy(cfg).continuous
    assert not build_policy(normalise_config({'scenario': 'flock2d'})).continuous
    with pytest.raises(ConfigError, match=r"'policy\.potential'.*invalid potential = 'bogus'"):
        normalise_config({'scenario': 'flock2d', 'policy': {'potential': 'bogus'}})
    # the same for every policy field PolicyConfig checks (the message names it as --set spells it)
    with pytest.raises(ConfigError, match=r"'policy\.k'"):
        normalise_config({'scenario': 'flock2d', 'policy': {'k': 0}})
    cfg = load_config('config/train_flock2d.yaml', {'policy.potential': 'continuous'})
    assert cfg['policy']['potential'] == 'continuous'


def _tiny_data(tmp_path):
    from knode_swarm_ros.core.groundtruth import simulate

    states = simulate('flock2d', 3, 4, 30, 0, progress=False)
    path = tmp_path / 'data.npz'
    save_trajectories(path, states, 0.01, 'flock2d', {'split': {'train': [0, 1], 'test': [2]}})
    return str(path)


def _tiny_config(tmp_path):
    raw = {
        'scenario': 'flock2d',
        'seed': 1,
        'policy': {'hidden': 8, 'k': 3, 'd_cr': 3.0},
        'data': {'val_trajectories': 1},
        'training': {'epochs': 1, 'batch_size': 'full', 'threads': 1},
        'selection': {'every': 0},
    }
    path = tmp_path / 'cfg.yaml'
    path.write_text(yaml.safe_dump(raw))
    return str(path)


def test_cli_trains_a_continuous_policy_and_records_the_form(tmp_path, capsys):
    out = tmp_path / 'run'
    argv = [
        '--config',
        _tiny_config(tmp_path),
        '--data',
        _tiny_data(tmp_path),
        '--out',
        str(out),
        '--no-progress',
    ]
    assert train_main(argv + ['--set', 'policy.potential=continuous']) == 0, capsys.readouterr().err
    assert yaml.safe_load((out / 'config.yaml').read_text())['policy']['potential'] == 'continuous'
    loaded = load_policy(out / 'policy.pt')
    assert loaded.meta['config']['potential'] == 'continuous'


@pytest.mark.parametrize('value', ['bogus', '3', '[continuous]'])
def test_cli_refuses_a_bad_form_with_exit_2_naming_the_field(tmp_path, capsys, value):
    out = tmp_path / 'run'
    argv = [
        '--config',
        _tiny_config(tmp_path),
        '--data',
        str(tmp_path / 'never_read.npz'),
        '--out',
        str(out),
        '--set',
        f'policy.potential={value}',
    ]
    assert train_main(argv) == 2
    err = capsys.readouterr().err
    line = err.splitlines()[0]
    assert line.startswith('python -m training.train: error: ') and "'policy.potential'" in line, err
    assert 'never_read.npz' not in err and 'Traceback' not in err  # the config fails first, cleanly
    assert not out.exists()
