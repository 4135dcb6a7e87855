"""Training: known answers of the one-step loss, gradients, resume, divergence guard, configs.

Tiny data only (a few hundred samples); the whole module runs in a few seconds.
"""

import contextlib
import json
import os

import numpy as np
import pytest
import torch
import torchdiffeq  # noqa: F401  (a broken install must fail, not skip)
import yaml

from knode_swarm_ros.core import (
    KNODEPolicy,
    PolicyConfig,
    get_scenario,
    load_policy,
    load_runtime,
    rollout,
    save_trajectories,
    zoh_step,
)
from training.assessment.scores import module_policy_fn
from training.learning.config import ConfigError, build_policy, normalise_config
from training.learning.objectives.one_step import loss_scales, one_step_loss, predict_next
from training.learning.samples import implied_command, make_samples
from training.learning.trainer import DivergenceError, Trainer
from training.train import main as train_main

torch.set_num_threads(1)
FLOCK = get_scenario('flock2d')
BOIDS = get_scenario('boids3d')


def _swarm(rng, S, n, spec):
    z = np.zeros((S, n, spec.state_dim))
    z[..., : spec.position_dim] = rng.uniform(-2, 2, size=(S, n, spec.position_dim))
    if spec.name == 'flock2d':
        z[..., 2:] = rng.normal(0, 1, size=(S, n, 2))
    else:
        h = rng.normal(size=(S, n, 3))
        z[..., 3:] = h / np.linalg.norm(h, axis=-1, keepdims=True)
    return z


def _config(tmp_path, **sections):
    raw = {
        'scenario': 'flock2d',
        'seed': 3,
        'policy': {'hidden': 16, 'd_cr': 3.0, 'k': 4},
        'data': {'val_trajectories': 1},
        'training': {'epochs': 2, 'batch_size': 64, 'lr': 0.01, 'threads': 1},
        'selection': {'every': 1, 'trajectories': 1},
    }
    for key, value in sections.items():
        raw.setdefault(key, {}).update(value) if isinstance(value, dict) else raw.__setitem__(key, value)
    path = tmp_path / 'cfg.yaml'
    path.write_text(yaml.safe_dump(raw))
    try:
        return str(path), normalise_config(raw)
    except ConfigError:
        return str(path), None


def linear_teacher(Y, mask):
    """A linear decentralised controller: alignment + cohesion on the neighbour rows of Y."""
    m = mask[:, 1:, None]
    count = np.maximum(m.sum(1), 1)
    dv = ((Y[:, 1:, 2:] - Y[:, :1, 2:]) * m).sum(1) / count
    dp = ((Y[:, 1:, :2] - Y[:, :1, :2]) * m).sum(1) / count
    return 1.5 * dv + 0.5 * dp


@contextlib.contextmanager
def spy_on_selection_rollouts(record):
    """Within the block, the trainer's selection rollouts call ``record(z0, steps, dt)`` first."""
    import training.learning.selection as selection_module

    real = selection_module.rollout_module

    def spy(module, spec, z0, steps, cfg_policy, dt):
        record(z0, steps, dt)
        return real(module, spec, z0, steps, cfg_policy, dt)

    selection_module.rollout_module = spy
    try:
        yield
    finally:
        selection_module.rollout_module = real


def _teacher_data(tmp_path, steps=40, trajectories=4, n=5, seed=0):
    """Trajectories of :func:`linear_teacher`."""
    linear = linear_teacher
    z0 = _swarm(np.random.default_rng(seed), trajectories, n, FLOCK)
    states = rollout(linear, z0, steps - 1, 'flock2d', 3.0, 4, 0, 0.01)
    path = tmp_path / 'teacher.npz'
    save_trajectories(
        path,
        states,
        0.01,
        'flock2d',
        {'split': {'train': list(range(trajectories - 1)), 'test': [trajectories - 1]}},
    )
    return str(path), linear


# ----------------------------------------------------------------------------- known answers


@pytest.mark.parametrize('spec', [FLOCK, BOIDS])
def test_zero_network_one_step_is_knowledge_only_zoh(spec):
    """With the network zeroed, the predicted state is the exact ZOH step of the knowledge command."""
    torch.manual_seed(0)
    policy = KNODEPolicy(PolicyConfig(spec.name, k=4, d_cr=3.0, hidden=8, collision_phi=1.0))
    for p in policy.net.parameters():
        torch.nn.init.zeros_(p)
    states = _swarm(np.random.default_rng(1), 2, 6, spec)[:, None].repeat(2, axis=1)
    s = make_samples(states, spec, 3.0, 4, 0)
    with torch.no_grad():
        pred = predict_next(policy, spec, spec.dt, s.Y, s.mask, s.clean_own, 'zoh').double().numpy()
        command = torch.clamp(policy.knowledge(s.Y, s.mask), -10, 10).double().numpy()
    assert np.abs(command).max() > 0  # the knowledge term is active on this configuration
    expected = zoh_step(s.clean_own.double().numpy(), command, spec, spec.dt)
    np.testing.assert_allclose(pred, expected, atol=1e-5)


def test_loss_vanishes_on_data_of_the_policy_itself():
    """Roll a random policy out with core.rollout: at its own parameters the ZOH loss is ~0."""
    torch.manual_seed(1)
    policy = KNODEPolicy(PolicyConfig('flock2d', k=4, d_cr=3.0, hidden=16, collision_phi=0.5))
    z0 = _swarm(np.random.default_rng(2), 2, 5, FLOCK)
    states = rollout(module_policy_fn(policy), z0, 30, 'flock2d', 3.0, 4, 0, 0.01)
    s = make_samples(states, FLOCK, 3.0, 4, 0)
    scales = loss_scales(FLOCK, 0.01, 'command')
    with torch.no_grad():
        own = s.Y[:, 0]
        at_truth = one_step_loss(predict_next(policy, FLOCK, 0.01, s.Y, s.mask, own, 'zoh'), s.target, scales)
        for p in policy.net.parameters():
            p.add_(0.05 * torch.randn_like(p))
        perturbed = one_step_loss(
            predict_next(policy, FLOCK, 0.01, s.Y, s.mask, own, 'zoh'), s.target, scales
        )
    assert float(at_truth) < 1e-3  # float32 rounding of the observations only
    assert float(perturbed) > 100 * float(at_truth)


def test_direct_gradient_matches_adjoint():
    torch.manual_seed(2)
    policy = KNODEPolicy(PolicyConfig('flock2d', k=4, d_cr=3.0, hidden=8, collision_phi=0.7))
    states = _swarm(np.random.default_rng(3), 1, 6, FLOCK)[:, None].repeat(2, axis=1)
    s = make_samples(states, FLOCK, 3.0, 4, 0)
    target = s.target + 0.001 * torch.randn_like(s.target)

    def grads(solver, dt):
        policy.zero_grad()
        loss = one_step_loss(
            predict_next(policy, FLOCK, dt, s.Y, s.mask, s.clean_own, solver),
            target,
            loss_scales(FLOCK, dt, 'command'),
        )
        loss.backward()
        return torch.cat(
            [(p.grad if p.grad is not None else torch.zeros_like(p)).flatten() for p in policy.parameters()]
        )

    def rel(a, b):
        return float((a - b).norm() / a.norm())

    assert rel(grads('rk4', 0.01), grads('adjoint', 0.01)) < 1e-5  # measured 1.5e-7
    # The exact ZOH step and rk4 with the own state moving differ at first order in dt:
    # 0.33 % at dt = 0.01 and half that at dt / 2 (measured ratio 2.1; was "within 20 %").
    gap, half = rel(grads('rk4', 0.01), grads('zoh', 0.01)), rel(grads('rk4', 0.005), grads('zoh', 0.005))
    assert gap < 0.01 and 1.8 < gap / half < 2.5, (gap, half)


def test_implied_command_inverts_zoh():
    rng = np.random.default_rng(4)
    z = _swarm(rng, 1, 5, FLOCK)[0]
    c = rng.normal(size=(5, 2))
    nxt = zoh_step(z, c, FLOCK, 0.01)
    got = implied_command(torch.tensor(z), torch.tensor(nxt), FLOCK, 0.01).numpy()
    np.testing.assert_allclose(got, c, atol=1e-9)


# ----------------------------------------------------------------------------- training runs


def test_training_recovers_a_linear_controller(tmp_path):
    data, linear = _teacher_data(tmp_path, steps=60, trajectories=5, n=6)
    cfg_path, cfg = _config(
        tmp_path,
        policy={'collision': False, 'hidden': 32},
        noise={'mode': 'none'},
        selection={'every': 0},
        training={'epochs': 40, 'batch_size': 128, 'lr': 0.01, 'lr_min': 0.001},
    )
    trainer = Trainer(cfg, data, str(tmp_path / 'run'), progress=False, log=lambda *a: None)
    trainer.run()
    log = [json.loads(line) for line in open(tmp_path / 'run' / 'metrics.jsonl')]
    assert log[-1]['train_loss'] < log[0]['train_loss'] / 100
    policy = load_policy(tmp_path / 'run' / 'policy.pt')
    s = trainer.train
    want = linear(s.Y.double().numpy(), s.mask.double().numpy())
    got = policy(s.Y.numpy(), s.mask.numpy())
    rms = np.sqrt(np.mean((got - want) ** 2)) / np.sqrt(np.mean(want**2))
    assert rms < 0.1, (rms, log[0]['train_loss'], log[-1]['train_loss'])


def test_exported_policy_matches_module_and_has_provenance(tmp_path):
    data, _ = _teacher_data(tmp_path)
    cfg_path, cfg = _config(tmp_path)
    trainer = Trainer(cfg, data, str(tmp_path / 'run'), progress=False, log=lambda *a: None)
    trainer.run()
    loaded = load_policy(tmp_path / 'run' / 'policy.pt', expect={'scenario': 'flock2d', 'k': 4})
    best = trainer.best['state']
    module = build_policy(cfg)
    module.load_state_dict(best)
    s = trainer.train
    with torch.no_grad():
        want = module(s.Y, s.mask).numpy()
    np.testing.assert_allclose(loaded(s.Y.numpy(), s.mask.numpy()), want, atol=1e-6)
    prov = loaded.meta['provenance']
    assert prov['config'] == cfg and prov['data_file'] == 'teacher.npz' and 'git_commit' in prov
    for name in ('config.yaml', 'metrics.jsonl', 'checkpoint.pt', 'summary.json'):
        assert (tmp_path / 'run' / name).is_file()
    # Training writes the ONNX twin beside the policy, and it matches the module
    twin = load_runtime(tmp_path / 'run' / 'policy.pt', 'onnxruntime')
    assert twin.backend == 'onnxruntime' and twin.meta == loaded.meta
    np.testing.assert_allclose(twin(s.Y.numpy(), s.mask.numpy()), want, atol=1e-5)


def test_fixed_seed_is_deterministic_and_resume_matches(tmp_path):
    data, _ = _teacher_data(tmp_path)
    _, cfg = _config(tmp_path, training={'epochs': 3}, selection={'every': 0})
    quiet = dict(progress=False, log=lambda *a: None)
    Trainer(cfg, data, str(tmp_path / 'a'), **quiet).run()
    Trainer(cfg, data, str(tmp_path / 'b'), **quiet).run()
    first = Trainer(cfg, data, str(tmp_path / 'c'), **quiet)
    assert first.run(stop_after=1) is None
    Trainer(cfg, data, str(tmp_path / 'c'), resume=True, **quiet).run()
    states = [torch.load(tmp_path / d / 'checkpoint.pt', weights_only=False)['model'] for d in 'abc']
    for key in states[0]:
        assert torch.equal(states[0][key], states[1][key]), key
        assert torch.equal(states[0][key], states[2][key]), key
    logs = [[json.loads(line)['train_loss'] for line in open(tmp_path / d / 'metrics.jsonl')] for d in 'ac']
    assert logs[0] == logs[1]


def test_the_time_cap_starts_no_epoch_that_would_end_past_it(tmp_path, monkeypatch):
    # a clock that moves only while an epoch draws its batches (40 s) and takes its validation
    # loss (20 s): 60 s per epoch, a 3.8-minute cap. Epoch 3 ends at 180 s and a fourth would
    # end at 240 s, past 228 s: the run ends after epoch 3, within the cap (stopping after the
    # epoch that crossed it would end at 240 s, and so would an estimate without validation)
    import training.learning.trainer as trainer_module

    clock = {'now': 0.0}
    monkeypatch.setattr(
        trainer_module, 'time', type('Clock', (), {'perf_counter': staticmethod(lambda: clock['now'])})
    )
    data, _ = _teacher_data(tmp_path)
    _, cfg = _config(tmp_path, training={'epochs': 10, 'max_minutes': 3.8}, selection={'every': 0})
    trainer = Trainer(cfg, data, str(tmp_path / 'run'), progress=False, log=lambda *a: None)
    draw, validate = trainer.objective.batches, trainer.val_loss

    def batches(epoch, g):
        clock['now'] += 40.0
        return draw(epoch, g)

    def val_loss():
        clock['now'] += 20.0
        return validate()

    monkeypatch.setattr(trainer.objective, 'batches', batches)
    monkeypatch.setattr(trainer, 'val_loss', val_loss)
    summary = trainer.run()
    log = [json.loads(line) for line in open(tmp_path / 'run' / 'metrics.jsonl')]
    assert summary['epochs'] == 3 and [r['epoch'] for r in log] == [1, 2, 3]
    assert log[-1]['elapsed_s'] == 180.0 <= 60 * 3.8


def test_the_confirm_reserve_plans_with_the_median_selection_and_resume_keeps_the_times(tmp_path):
    # one selection slowed by a passing load (100 s among 2 s ones) must not reserve the cap for
    # the confirm stage: the reserve is K x the median selection x the confirm stage's size
    data, _ = _teacher_data(tmp_path)
    _, cfg = _config(tmp_path, training={'epochs': 3}, selection={'every': 1, 'confirm': 3})
    quiet = dict(progress=False, log=lambda *a: None)
    trainer = Trainer(cfg, data, str(tmp_path / 'run'), **quiet)
    assert trainer.select_s is None and trainer.confirm_reserve() == 0.0
    assert trainer.run(stop_after=2) is None
    assert len(trainer.select_times) == 2  # one per epoch
    trainer.select_times = [2.0, 100.0, 2.0]
    assert trainer.select_s == 2.0
    assert trainer.confirm_reserve() == pytest.approx(3 * 2.0 * trainer.confirm_cost)
    assert trainer.confirm_cost > 1.0  # the confirm stage rolls out more starts than a selection
    trainer._save_checkpoint()
    resumed = Trainer(cfg, data, str(tmp_path / 'run'), resume=True, **quiet)
    assert resumed.select_times == [2.0, 100.0, 2.0]
    # a checkpoint written before the times were kept has the last selection's seconds only
    ck = torch.load(tmp_path / 'run' / 'checkpoint.pt', weights_only=False)
    del ck['select_times']
    ck['select_s'] = 7.5
    torch.save(ck, tmp_path / 'run' / 'checkpoint.pt')
    old = Trainer(cfg, data, str(tmp_path / 'run'), resume=True, **quiet)
    assert old.select_times == [7.5] and old.select_s == 7.5


def test_divergence_guard_on_absurd_learning_rate(tmp_path, capsys):
    data, _ = _teacher_data(tmp_path)
    cfg_path, _ = _config(tmp_path, training={'epochs': 5, 'lr': 1.0e6, 'grad_clip': None})
    rc = train_main(['--config', cfg_path, '--data', data, '--out', str(tmp_path / 'run'), '--no-progress'])
    assert rc == 3
    assert 'diverged' in capsys.readouterr().err
    assert not (tmp_path / 'run' / 'policy.pt').exists()


def test_divergence_guard_on_poisoned_data(tmp_path):
    data, _ = _teacher_data(tmp_path)
    from knode_swarm_ros.core import load_trajectories

    f = load_trajectories(data)
    states = f.states.copy()
    states[0, 20:, 0, 2:] = 1e30  # an absurd glitch in one robot's velocity
    poisoned = tmp_path / 'poisoned.npz'
    save_trajectories(poisoned, states, f.dt, f.scenario, f.meta)
    _, cfg = _config(tmp_path, data={'drop_saturated': False}, training={'epochs': 2, 'batch_size': 'full'})
    with pytest.raises(DivergenceError, match='not finite|exploding'):
        Trainer(cfg, str(poisoned), str(tmp_path / 'run'), progress=False, log=lambda *a: None).run()


def test_a_failed_fresh_run_leaves_the_earlier_run_in_its_directory_intact(tmp_path):
    """A new run that fails before its first epoch must not delete the old
    summary and metrics, rewrite the config, or pass the old checkpoint off as its own."""
    data, _ = _teacher_data(tmp_path)
    _, cfg = _config(tmp_path, training={'epochs': 1})
    run = tmp_path / 'run'
    Trainer(cfg, data, str(run), progress=False, log=lambda *a: None).run()
    names = ('config.yaml', 'metrics.jsonl', 'checkpoint.pt', 'summary.json')
    before = {name: (run / name).read_bytes() for name in names}
    from knode_swarm_ros.core import load_trajectories

    f = load_trajectories(data)
    states = f.states.copy()
    states[0, 20:, 0, 2:] = 1e30
    poisoned = tmp_path / 'poisoned.npz'
    save_trajectories(poisoned, states, f.dt, f.scenario, f.meta)
    _, other = _config(
        tmp_path, seed=4, data={'drop_saturated': False}, training={'epochs': 2, 'batch_size': 'full'}
    )
    with pytest.raises(DivergenceError, match='left as they were'):
        Trainer(other, str(poisoned), str(run), progress=False, log=lambda *a: None).run()
    assert {name: (run / name).read_bytes() for name in names} == before
    # ... and the earlier run can still be resumed with its own config.
    Trainer(cfg, data, str(run), resume=True, progress=False, log=lambda *a: None)


@pytest.mark.parametrize(
    'section, value, field',
    [
        ({'training': {'solver': 'euler'}}, None, 'training.solver'),
        ({'training': {'lr': -1}}, None, 'training.lr'),
        ({'noise': {'mode': 'loud'}}, None, 'noise.mode'),
        ({'policy': {'k': 0}}, None, 'k'),
        ({'policy': {'radius': 3}}, None, 'policy.radius'),
        ({'bogus': 1}, None, 'bogus'),
        ({'scenario': 'flock9d'}, None, 'scenario'),
        ({'augment': {'rotate': True}, 'scenario': 'boids3d'}, None, 'augment.rotate'),
    ],
)
def test_bad_config_names_the_field(tmp_path, section, value, field):
    raw = {'scenario': 'flock2d'}
    for key, val in section.items():
        raw[key] = val
    with pytest.raises(ConfigError, match=field.replace('.', r'\.')):
        normalise_config(raw)


def test_cli_bad_config_and_data_exit_2(tmp_path, capsys):
    data, _ = _teacher_data(tmp_path)
    cfg_path, _ = _config(tmp_path, training={'batch_size': 0})
    assert train_main(['--config', cfg_path, '--data', data, '--out', str(tmp_path / 'r')]) == 2
    assert 'training.batch_size' in capsys.readouterr().err
    cfg_path, _ = _config(tmp_path)
    assert (
        train_main(
            ['--config', cfg_path, '--data', str(tmp_path / 'missing.npz'), '--out', str(tmp_path / 'r')]
        )
        == 2
    )
    assert 'missing.npz' in capsys.readouterr().err
    cfg_path, _ = _config(tmp_path, scenario='boids3d', augment={'rotate': False})
    assert train_main(['--config', cfg_path, '--data', data, '--out', str(tmp_path / 'r')]) == 2
    assert 'scenario' in capsys.readouterr().err


def test_grid_cells_are_resumable_and_skip_finished(tmp_path, monkeypatch):
    from training import grid
    from training.grid import main as grid_main

    trained = []  # the cell directories a Trainer was built for, in order

    class CountingTrainer(grid.Trainer):
        def __init__(self, cfg, data_path, out, *a, **kw):
            trained.append(os.path.basename(out))
            super().__init__(cfg, data_path, out, *a, **kw)

    monkeypatch.setattr(grid, 'Trainer', CountingTrainer)
    data, _ = _teacher_data(tmp_path)
    cfg_path, _ = _config(tmp_path, training={'epochs': 1}, selection={'every': 0})
    args = [
        '--config',
        cfg_path,
        '--data',
        data,
        '--out',
        str(tmp_path / 'grid'),
        '--d-cr',
        '2',
        '3',
        '--k',
        '3',
        '--trajectories',
        '1',
    ]
    (tmp_path / 'grid' / 'dcr3_k3').mkdir(parents=True)
    (tmp_path / 'grid' / 'dcr3_k3' / '.lock').write_text('123')  # claimed by another worker
    assert grid_main(args) == 0
    results = json.loads((tmp_path / 'grid' / 'results.json').read_text())
    assert results['finished'] == ['dcr2_k3'] and trained == ['dcr2_k3']
    cell = tmp_path / 'grid' / 'dcr2_k3' / 'cell.json'
    before = cell.read_bytes()
    (tmp_path / 'grid' / 'dcr3_k3' / '.lock').unlink()
    assert grid_main(args) == 0
    # The finished cell is skipped: not trained again, its result file untouched (a content
    # check, not an mtime one: two writes can share a timestamp).
    assert trained == ['dcr2_k3', 'dcr3_k3'] and cell.read_bytes() == before
    results = json.loads((tmp_path / 'grid' / 'results.json').read_text())
    assert sorted(results['finished']) == ['dcr2_k3', 'dcr3_k3']
    assert (tmp_path / 'grid' / 'heatmap_avd_final_mean.png').is_file()


def test_grid_over_seeds_reports_the_mean_and_spread_of_each_seeds_grid(tmp_path, capsys):
    from training.grid import main as grid_main

    data, _ = _teacher_data(tmp_path)
    cfg_path, _ = _config(tmp_path, training={'epochs': 1}, selection={'every': 0})
    out = tmp_path / 'grid'
    args = ['--config', cfg_path, '--data', data, '--out', str(out), '--d-cr', '2', '3', '--k', '3']
    assert grid_main(args + ['--trajectories', '1', '--seeds', '0', '1']) == 0
    seeds = [json.loads((out / f'seed{s}' / 'results.json').read_text()) for s in (0, 1)]
    for s, r in zip((0, 1), seeds):
        assert sorted(r['finished']) == ['dcr2_k3', 'dcr3_k3']
        assert yaml.safe_load((out / f'seed{s}' / 'dcr2_k3' / 'config.yaml').read_text())['seed'] == s
    both = json.loads((out / 'results.json').read_text())
    assert both['seeds'] == [0, 1]
    for key, table in both['tables'].items():
        per_seed = np.array([r['tables'][key] for r in seeds])  # [2, d_cr, k]
        np.testing.assert_allclose(table['mean'], per_seed.mean(axis=0))
        np.testing.assert_allclose(table['sd'], per_seed.std(axis=0, ddof=1))
        assert table['seeds'] == [[2], [2]]
    # two seeds train two different models: the spread of some table is not zero
    assert any(np.any(np.array(t['sd']) > 0) for t in both['tables'].values())
    assert (out / 'heatmap_avd_final_mean.png').is_file() and 'sd ' in (out / 'summary.md').read_text()
    assert grid_main(args + ['--seeds', '0', '--set', 'seed=3']) == 2
    assert '--seeds' in capsys.readouterr().err


def test_selection_rolls_out_perturbed_copies_of_each_start(tmp_path):
    data, _ = _teacher_data(tmp_path, trajectories=5)
    starts = []

    def trainer(tag, **selection):
        _, cfg = _config(tmp_path, selection={'every': 1, 'trajectories': 1, **selection})
        return Trainer(cfg, data, str(tmp_path / tag), progress=False, log=lambda *a: None)

    with spy_on_selection_rollouts(lambda z0, steps, dt: starts.append(np.array(z0))):
        three = trainer('three', rollouts=3, perturb=1e-3).select_metrics()
        one = trainer('one').select_metrics()
        same = trainer('same', rollouts=3, perturb=0.0).select_metrics()
    z0 = starts[0]
    assert z0.shape[0] == 3 and starts[1].shape[0] == 1
    np.testing.assert_array_equal(z0[0], starts[1][0])  # copy 0 is the start itself
    np.testing.assert_array_equal(z0[1:, :, 2:], z0[[0, 0], :, 2:])  # velocities untouched
    moved = np.abs(z0[1:, :, :2] - z0[0, :, :2])
    assert 0 < moved.max() < 1e-2 and not np.array_equal(
        z0[1], z0[2]
    )  # positions moved ~1e-3, each copy its own
    assert three['rollouts'] == 3 and one['rollouts'] == 1 and three['avd_final_se'] >= 0
    assert 'avd_final_se' not in one  # no spread from one rollout
    # the log shows the medians the score's amd term compares (flock2d: mean avd + amd term + collisions)
    amd_term = abs(three['amd_median'] - three['truth_amd_median']) / three['truth_amd_median']
    assert three['min_distance'] >= 0.3 and three['score'] == pytest.approx(
        three['avd_final'] + amd_term, rel=1e-9
    )
    # three unperturbed copies are three equal rollouts: the score of one, a spread of 0
    assert same['score'] == pytest.approx(one['score'], rel=1e-12) and same['avd_final_se'] == pytest.approx(
        0.0, abs=1e-15
    )


@pytest.mark.parametrize(
    'field, value',
    [
        ('rollouts', 0),
        ('rollouts', 1.5),
        ('rollouts', '3'),
        ('perturb', -1e-3),
        ('perturb', float('inf')),
        ('perturb', 'x'),
    ],
)
def test_selection_rollouts_and_perturb_are_checked(field, value):
    with pytest.raises(ConfigError, match=f"'selection.{field}'"):
        normalise_config({'scenario': 'flock2d', 'selection': {field: value}})
