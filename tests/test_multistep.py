"""Trajectory (multi-step) training: the differentiable rollout against the canonical one,
gradients against finite differences, a known gain recovered, the curriculum, resume."""

import json

import numpy as np
import pytest
import torch
import yaml
from test_training import _swarm

from knode_swarm_ros.core import (
    DEFAULTS,
    KNODEPolicy,
    PolicyConfig,
    get_scenario,
    neighbour_matrix,
    rollout,
    save_trajectories,
)
from knode_swarm_ros.core.network import neighbour_matrix_torch
from knode_swarm_ros.core.rollout import rollout_torch
from training.learning.config import ConfigError, normalise_config
from training.learning.objectives.multi_step import (
    Windows,
    augment_windows,
    consensus_loss,
    horizon_at,
    rollout_windows,
    window_loss,
    window_scales,
)
from training.learning.objectives.one_step import loss_scales
from training.learning.trainer import Trainer

torch.set_num_threads(1)
FLOCK = get_scenario('flock2d')
BOIDS = get_scenario('boids3d')


def _numpy_fn(module):
    def fn(Y, mask):
        with torch.no_grad():
            return module(torch.from_numpy(Y), torch.from_numpy(mask.astype(np.float64))).numpy()

    return fn


class LinearFlocking(torch.nn.Module):
    """u = a * mean(v_j - v_i) + b * mean(p_j - p_i) over the masked neighbour rows."""

    def __init__(self, a: float, b: float):
        super().__init__()
        self.a = torch.nn.Parameter(torch.tensor(a, dtype=torch.float64))
        self.b = torch.nn.Parameter(torch.tensor(b, dtype=torch.float64))

    def forward(self, Y, mask):
        m = mask[:, 1:, None].to(Y.dtype)
        count = m.sum(1).clamp(min=1)
        dv = ((Y[:, 1:, 2:] - Y[:, :1, 2:]) * m).sum(1) / count
        dp = ((Y[:, 1:, :2] - Y[:, :1, :2]) * m).sum(1) / count
        return self.a * dv + self.b * dp


# ----------------------------------------------------------------------------- parity with the core


@pytest.mark.parametrize('spec,tau', [(FLOCK, 0), (FLOCK, 3), (BOIDS, 1)])
def test_rollout_torch_equals_the_canonical_rollout(spec, tau):
    torch.manual_seed(0)
    policy = KNODEPolicy(PolicyConfig(spec.name, **DEFAULTS[spec.name])).double()
    z0 = _swarm(np.random.default_rng(1), 3, 7, spec)
    want = rollout(_numpy_fn(policy), z0, 40, spec.name, 2.5, 6, tau, spec.dt)
    with torch.no_grad():
        got = rollout_torch(policy, torch.from_numpy(z0), 40, spec.name, 2.5, 6, tau, spec.dt).numpy()
    # flock2d: the same float64 operations in the same order; boids3d: the heading norm may round
    np.testing.assert_allclose(got, want, rtol=0, atol=0 if spec.name == 'flock2d' else 1e-12)


def test_torch_neighbour_matrix_equals_the_numpy_builder_and_carries_gradients():
    rng = np.random.default_rng(2)
    z_now, z_del = _swarm(rng, 4, 9, FLOCK), _swarm(rng, 4, 9, FLOCK)
    z_del[0, 1, :2] = z_del[0, 0, :2] + [1.5, 0.0]  # a pair exactly at d_cr (inclusive)
    Y, mask = neighbour_matrix(z_now, z_del, 2, 1.5, 5)
    zt = torch.from_numpy(z_del).requires_grad_(True)
    Yt, mt = neighbour_matrix_torch(torch.from_numpy(z_now), zt, 2, 1.5, 5)
    np.testing.assert_array_equal(Yt.detach().numpy(), Y)
    np.testing.assert_array_equal(mt.numpy().astype(bool), mask)
    Yt[..., 1:, :].sum().backward()
    # each delayed state receives one unit of gradient per row it fills
    uses = np.zeros(z_del.shape[:-1])
    from knode_swarm_ros.core.network import neighbour_index

    index, valid = neighbour_index(z_del, 2, 1.5, 5)
    for s in range(4):
        np.add.at(uses[s], index[s][valid[s]], 1)
    np.testing.assert_array_equal(zt.grad.numpy(), np.repeat(uses[..., None], 4, axis=-1))


@pytest.mark.parametrize('tau,with_history', [(0, False), (2, False), (2, True), (3, True)])
def test_checkpointed_rollout_equals_the_plain_one(tau, with_history):
    torch.manual_seed(0)
    policy = KNODEPolicy(PolicyConfig('flock2d', **DEFAULTS['flock2d'])).double()
    obs = torch.from_numpy(_swarm(np.random.default_rng(3), 2, 6, FLOCK)).unsqueeze(1).repeat(1, 23, 1, 1)
    history = (
        torch.from_numpy(_swarm(np.random.default_rng(4), 2, 6, FLOCK))[:, None].repeat(1, tau, 1, 1)
        if with_history
        else None
    )
    cfg = {'d_cr': 5.0, 'k': 6, 'tau': tau}
    plain = rollout_windows(policy, FLOCK, cfg, 0.01, obs, history, 0)
    seg = rollout_windows(policy, FLOCK, cfg, 0.01, obs, history, 5)
    assert torch.equal(plain, seg)
    g1 = torch.autograd.grad(plain[:, -1].sum(), list(policy.parameters()), allow_unused=True)
    g2 = torch.autograd.grad(seg[:, -1].sum(), list(policy.parameters()), allow_unused=True)
    for a, b in zip(g1, g2):
        assert (a is None) == (b is None)
        if a is not None:
            torch.testing.assert_close(a, b, rtol=1e-12, atol=1e-14)


# ----------------------------------------------------------------------------- gradients, known answers


def test_window_loss_gradient_matches_finite_differences():
    torch.manual_seed(0)
    policy = KNODEPolicy(PolicyConfig('flock2d', k=4, d_cr=3.0, hidden=8, collision_phi=1.0)).double()
    z = _swarm(np.random.default_rng(5), 2, 5, FLOCK)
    truth = rollout(lambda Y, m: np.zeros((Y.shape[0], 2)), z, 25, 'flock2d', 3.0, 4, 1, 0.01)
    obs = torch.from_numpy(truth)
    scales = window_scales(FLOCK, 0.01, 25, 'command').double()

    def loss():
        pred = rollout_windows(policy, FLOCK, {'d_cr': 3.0, 'k': 4, 'tau': 1}, 0.01, obs, None)
        return window_loss(pred, obs, scales)

    params = [policy.net[0].weight, policy.net[2].bias, policy.collision_gain.phi]
    grads = torch.autograd.grad(loss(), params)
    eps = 1e-6
    for p, g in zip(params, grads):
        flat = p.data.view(-1)
        for i in range(min(3, flat.numel())):
            old = flat[i].item()
            flat[i] = old + eps
            up = loss().item()
            flat[i] = old - eps
            down = loss().item()
            flat[i] = old
            fd = (up - down) / (2 * eps)
            assert abs(fd - g.view(-1)[i].item()) <= 1e-6 * max(1.0, abs(fd)), (
                p.shape,
                i,
                fd,
                g.view(-1)[i].item(),
            )


def _fit_linear_student(units, steps, consensus_weight=0.0):
    """A linear alignment + cohesion teacher (gains 1.5, 0.5) generates 20-step windows; a student of
    the same form, started at (0.2, 2.0), is fitted by LBFGS on the window loss (+ the weighted
    consensus term). Returns the student."""
    teacher = LinearFlocking(1.5, 0.5)
    z0 = _swarm(np.random.default_rng(6), 4, 5, FLOCK)
    states = rollout(_numpy_fn(teacher), z0, 120, 'flock2d', 3.0, 4, 0, 0.01)
    windows = Windows(states, tau=0)
    student = LinearFlocking(0.2, 2.0)
    opt = torch.optim.LBFGS(student.parameters(), lr=0.5, max_iter=40, line_search_fn='strong_wolfe')
    obs, _ = windows.gather(windows.fixed_starts(16, 20), 20)
    obs = obs.double()
    scales = window_scales(FLOCK, 0.01, 20, units).double()

    def closure():
        opt.zero_grad()
        pred = rollout_windows(student, FLOCK, {'d_cr': 3.0, 'k': 4, 'tau': 0}, 0.01, obs, None)
        loss = window_loss(pred, obs, scales)
        if consensus_weight:
            loss = loss + consensus_weight * consensus_loss(pred, obs, scales, FLOCK.velocity)
        loss.backward()
        return loss

    for _ in range(steps):
        opt.step(closure)
    return student


def test_multi_step_loss_recovers_a_known_linear_gain():
    """A linear alignment + cohesion law generates the data; a student of the same form starts
    elsewhere and is fitted on 20-step windows: it recovers the teacher's gains."""
    student = _fit_linear_student('command', 5)
    # the data are float32 windows of a float64 rollout: the gains come back to that precision
    assert abs(student.a.item() - 1.5) < 1e-3 and abs(student.b.item() - 0.5) < 1e-3, (student.a, student.b)


def test_one_frame_window_scales_are_the_one_step_loss_scales():
    for spec in (FLOCK, BOIDS):
        for units in ('command', 'state'):
            torch.testing.assert_close(
                window_scales(spec, spec.dt, 1, units, 2.0)[0], loss_scales(spec, spec.dt, units, 2.0).float()
            )
    s = window_scales(FLOCK, 0.1, 3, 'command')
    torch.testing.assert_close(s[:, 0], torch.tensor([0.005, 0.02, 0.045]))  # (h dt)^2 / 2
    torch.testing.assert_close(s[:, 3], torch.tensor([0.1, 0.2, 0.3]))  # h dt


@pytest.mark.parametrize('epoch,want', [(1, 10), (2, 10), (3, 50), (5, 50), (6, 200), (7, 200), (99, 200)])
def test_curriculum_horizon_by_epoch(epoch, want):
    assert horizon_at(epoch, [10, 50, 200], [2, 3, 2]) == want


def test_windows_clamp_the_history_at_the_first_frame():
    states = np.arange(2 * 6 * 1 * 4, dtype=np.float64).reshape(2, 6, 1, 4)
    w = Windows(states, tau=2)
    obs, hist = w.gather(torch.tensor([[1, 0], [0, 3]]), 2)
    np.testing.assert_array_equal(obs[0].numpy(), states[1, 0:3])
    np.testing.assert_array_equal(obs[1].numpy(), states[0, 3:6])
    np.testing.assert_array_equal(hist[0].numpy(), states[1, [0, 0]])
    np.testing.assert_array_equal(hist[1].numpy(), states[0, [1, 2]])
    starts = w.starts(500, 4, torch.Generator().manual_seed(0))
    assert starts[:, 1].max() <= 6 - 1 - 4 and starts[:, 1].min() == 0


def test_window_augmentation_is_a_symmetry_of_the_motion():
    """Rotated and boosted windows keep pairwise distances up to the boost's common drift and
    keep the velocity change of every robot, rotated: the same physics, seen differently."""
    rng = np.random.default_rng(7)
    states = rollout(
        lambda Y, m: np.zeros((Y.shape[0], 2)) + Y[:, 1, :2] - Y[:, 0, :2],
        _swarm(rng, 3, 4, FLOCK),
        10,
        'flock2d',
        9.0,
        4,
        0,
        0.01,
    )
    obs = torch.from_numpy(states)
    aug, _ = augment_windows(obs, None, 0.01, True, 2.0, torch.Generator().manual_seed(1))
    d = lambda z: torch.cdist(z[..., :2], z[..., :2])  # noqa: E731
    torch.testing.assert_close(d(aug), d(obs))
    dv = lambda z: z[:, 1:, :, 2:] - z[:, :-1, :, 2:]  # noqa: E731
    torch.testing.assert_close(dv(aug).norm(dim=-1), dv(obs).norm(dim=-1))
    # position increments equal the (boosted) velocity integration, as in the original
    step = lambda z: z[:, 1:, :, :2] - z[:, :-1, :, :2] - 0.01 * z[:, :-1, :, 2:]  # noqa: E731
    torch.testing.assert_close(step(aug).norm(dim=-1), step(obs).norm(dim=-1))


# ----------------------------------------------------------------------------- configs, trainer, resume


def _raw(**training):
    return {
        'scenario': 'flock2d',
        'seed': 3,
        'policy': {'hidden': 8, 'd_cr': 3.0, 'k': 4},
        'data': {'val_trajectories': 1},
        'training': {'objective': 'multi_step', 'lr': 0.003, **training},
        'selection': {'every': 1, 'trajectories': 1},
        'multistep': {'horizons': [3, 6], 'epochs': [1, 2], 'windows_per_epoch': 8, 'batch_windows': 4},
    }


@pytest.mark.parametrize(
    'change,field',
    [
        ({'training': {'objective': 'many'}}, 'training.objective'),
        ({'training': {'epochs': 7}}, 'training.epochs'),
        ({'multistep': {'epochs': [1]}}, 'multistep.epochs'),
        ({'multistep': {'horizons': [0, 5]}}, 'multistep.horizons'),
        ({'multistep': {'units': 'furlongs'}}, 'multistep.units'),
        ({'multistep': {'checkpoint': -1}}, 'multistep.checkpoint'),
        ({'multistep': {'velocity_weight': 0}}, 'multistep.velocity_weight'),
    ],
)
def test_bad_multistep_config_names_the_field(change, field):
    raw = _raw()
    for section, values in change.items():
        raw[section].update(values)
    with pytest.raises(ConfigError, match=field.replace('.', r'\.')):
        normalise_config(raw)


def test_multi_step_epochs_come_from_the_curriculum():
    assert normalise_config(_raw())['training']['epochs'] == 3
    assert normalise_config(_raw(epochs=3))['training']['epochs'] == 3


def _data(tmp_path):
    z0 = _swarm(np.random.default_rng(8), 3, 4, FLOCK)
    states = rollout(_numpy_fn(LinearFlocking(1.5, 0.5)), z0, 30, 'flock2d', 3.0, 4, 0, 0.01)
    path = tmp_path / 'd.npz'
    save_trajectories(path, states, 0.01, 'flock2d', {'split': {'train': [0, 1, 2], 'test': []}})
    return str(path)


def test_multi_step_training_resumes_bit_identically_and_starts_from_init(tmp_path):
    data = _data(tmp_path)
    cfg = normalise_config(_raw())
    Trainer(cfg, data, str(tmp_path / 'onestep_like'), progress=False, log=lambda *a: None).finish()
    cfg_init = normalise_config(
        {**_raw(), 'multistep': {**_raw()['multistep'], 'init': str(tmp_path / 'onestep_like')}}
    )
    straight = Trainer(cfg_init, data, str(tmp_path / 'a'), progress=False, log=lambda *a: None)
    init_state = {k: v.clone() for k, v in straight.policy.state_dict().items()}
    loaded = torch.jit.load(str(tmp_path / 'onestep_like' / 'policy.pt')).state_dict()
    for key, value in loaded.items():
        assert torch.equal(init_state[key], value), key
    straight.run()
    first = Trainer(cfg_init, data, str(tmp_path / 'b'), progress=False, log=lambda *a: None)
    assert first.run(stop_after=1) is None
    resumed = Trainer(cfg_init, data, str(tmp_path / 'b'), resume=True, progress=False, log=lambda *a: None)
    resumed.run()
    for key, value in straight.policy.state_dict().items():
        assert torch.equal(value, resumed.policy.state_dict()[key]), key
    lines = [json.loads(x) for x in (tmp_path / 'b' / 'metrics.jsonl').read_text().splitlines()]
    assert [x['epoch'] for x in lines] == [1, 2, 3]
    assert [x['train_loss'] for x in lines] == [
        json.loads(x)['train_loss'] for x in (tmp_path / 'a' / 'metrics.jsonl').read_text().splitlines()
    ]


@pytest.mark.parametrize('scores, chosen', [((0.1, 0.5, 0.3, 0.2), 0), ((0.4, 0.5, 0.3, 0.35), 2)])
def test_fine_tuning_keeps_the_starting_model_unless_an_epoch_rolls_out_better(
    tmp_path, monkeypatch, scores, chosen
):
    # selection scores scripted per call: epoch 0 (the starting model), then epochs 1-3
    data = _data(tmp_path)
    Trainer(
        normalise_config(_raw()), data, str(tmp_path / 'init'), progress=False, log=lambda *a: None
    ).finish()
    cfg = normalise_config({**_raw(), 'multistep': {**_raw()['multistep'], 'init': str(tmp_path / 'init')}})
    run = Trainer(cfg, data, str(tmp_path / 'run'), progress=False, log=lambda *a: None)
    start = {k: v.clone() for k, v in run.policy.state_dict().items()}
    states, calls = [], iter(scores)
    monkeypatch.setattr(
        run,
        'select_metrics',
        lambda: (
            states.append({k: v.clone() for k, v in run.policy.state_dict().items()}),
            {'score': next(calls)},
        )[1],
    )
    summary = run.run()
    assert len(states) == 4 and summary['selected'].startswith(f'best rollout score (epoch {chosen}')
    exported = torch.jit.load(str(tmp_path / 'run' / 'policy.pt')).state_dict()
    for key, value in states[chosen].items():
        assert torch.equal(exported[key], value), key
    for key, value in start.items():  # epoch 0 is the starting model itself
        assert torch.equal(states[0][key], value), key
    assert chosen == 0 or any(not torch.equal(exported[k], start[k]) for k in start)


def test_a_run_cut_short_by_max_minutes_scores_the_epoch_it_ends_with(tmp_path, monkeypatch):
    # selection every 2 epochs, time up after epoch 1: epoch 1 must be a candidate, or the run would
    # throw its training away and return the starting model
    data = _data(tmp_path)
    Trainer(
        normalise_config(_raw()), data, str(tmp_path / 'init'), progress=False, log=lambda *a: None
    ).finish()
    raw = _raw(max_minutes=1e-9)
    cfg = normalise_config(
        {
            **raw,
            'selection': {**raw['selection'], 'every': 2},
            'multistep': {**raw['multistep'], 'init': str(tmp_path / 'init')},
        }
    )
    run = Trainer(cfg, data, str(tmp_path / 'run'), progress=False, log=lambda *a: None)
    calls = iter((0.5, 0.3))
    monkeypatch.setattr(run, 'select_metrics', lambda: {'score': next(calls)})
    summary = run.run()
    assert summary['epochs'] == 1 and summary['selected'] == 'best rollout score (epoch 1)'
    assert summary['start_selection'] == {'score': 0.5}  # the starting model's score is kept


def test_a_missing_init_policy_is_a_config_error_naming_the_field(tmp_path):
    data = _data(tmp_path)
    cfg = normalise_config({**_raw(), 'multistep': {**_raw()['multistep'], 'init': str(tmp_path / 'nope')}})
    with pytest.raises(ConfigError, match='multistep.init'):
        Trainer(cfg, data, str(tmp_path / 'run'), progress=False, log=lambda *a: None)


@pytest.mark.parametrize('field, value', [('potential', 'continuous'), ('collision_d0', 0.5), ('d_cr', 2.0)])
def test_an_init_policy_with_another_law_is_a_config_error_naming_both(tmp_path, field, value):
    # the state dict carries no knowledge form or network: without this check a paper-potential
    # model would be fine-tuned as a continuous one, its law silently changed
    data = _data(tmp_path)
    Trainer(
        normalise_config(_raw()), data, str(tmp_path / 'init'), progress=False, log=lambda *a: None
    ).finish()
    raw = _raw()
    cfg = normalise_config(
        {
            **raw,
            'policy': {**raw['policy'], field: value},
            'multistep': {**raw['multistep'], 'init': str(tmp_path / 'init')},
        }
    )
    with pytest.raises(ConfigError, match=rf"multistep.init.*policy\.{field} is .*, the config's {value!r}"):
        Trainer(cfg, data, str(tmp_path / 'run'), progress=False, log=lambda *a: None)


@pytest.mark.parametrize('name', ['train_flock2d_multistep.yaml', 'train_boids3d_multistep.yaml'])
def test_config_files_of_the_multistep_runs_are_valid(name):
    import os

    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    with open(os.path.join(here, 'config', name)) as fh:
        cfg = normalise_config(yaml.safe_load(fh))
    with open(os.path.join(here, 'config', name.replace('_multistep', ''))) as fh:
        one_step = normalise_config(yaml.safe_load(fh))
    assert cfg['training']['objective'] == 'multi_step'
    assert cfg['policy'] == one_step['policy']  # the starting model must have the same law
    assert cfg['training']['epochs'] == sum(cfg['multistep']['epochs'])


def test_windows_never_hold_a_bad_step():
    states = np.zeros((2, 12, 1, 4))
    bad = np.zeros((2, 11), bool)
    bad[0, 4] = True  # step 4 -> 5 of trajectory 0
    bad[1, 0] = True  # step 0 -> 1 of trajectory 1
    w = Windows(states, tau=0, bad_steps=bad)
    clean = {tuple(x) for x in w.clean_starts(3).tolist()}
    assert clean == {(0, t) for t in (0, 1, 5, 6, 7, 8)} | {(1, t) for t in range(1, 9)}
    drawn = w.starts(300, 3, torch.Generator().manual_seed(0))
    assert {tuple(x) for x in drawn.tolist()} <= clean
    with pytest.raises(ValueError, match='no window of 11 steps'):
        w.starts(1, 11, None)


def test_velocity_weight_scales_only_the_velocity_errors():
    one, four = (
        window_scales(FLOCK, 0.05, 4, 'command'),
        window_scales(FLOCK, 0.05, 4, 'command', velocity_weight=4.0),
    )
    torch.testing.assert_close(four[:, :2], one[:, :2])
    torch.testing.assert_close(four[:, 2:], one[:, 2:] / 2)  # squared error x 4
    torch.testing.assert_close(
        window_scales(FLOCK, 0.05, 2, 'state', velocity_weight=4.0), torch.tensor([[1.0, 1.0, 0.5, 0.5]] * 2)
    )
    boids = get_scenario('boids3d')  # velocity commands: no velocity entries
    torch.testing.assert_close(
        window_scales(boids, 0.1, 2, 'command', 1.0, 9.0), window_scales(boids, 0.1, 2, 'command')
    )


@pytest.mark.parametrize('lead', [(), (2, 3)])
def test_torch_neighbour_matrix_equals_the_numpy_builder_for_any_leading_shape(lead):
    """One snapshot [n, d] and a run [S, T, n, d], not only [S, n, d] (a mutation survivor
    put the own-state row at a fixed dimension)."""
    rng = np.random.default_rng(3)
    z_now, z_del = (
        _swarm(rng, int(np.prod(lead, dtype=int)), 6, FLOCK).reshape(lead + (6, 4)) for _ in range(2)
    )
    Y, mask = neighbour_matrix(z_now, z_del, 2, 1.5, 4)
    Yt, mt = neighbour_matrix_torch(torch.from_numpy(z_now), torch.from_numpy(z_del), 2, 1.5, 4)
    assert Yt.shape == lead + (6, 4, 4)
    np.testing.assert_array_equal(Yt.numpy(), Y)
    np.testing.assert_array_equal(mt.numpy().astype(bool), mask)


# ----------------------------------------------------------------------------- consensus_weight


def test_consensus_loss_ignores_a_common_drift_and_weighs_relative_velocities():
    """Hand-computed on 2 robots: a drift common to the swarm costs nothing; a disagreement costs its
    relative-velocity error (each robot's velocity minus the swarm mean)."""
    obs = torch.zeros(1, 3, 2, 4)
    scales = window_scales(FLOCK, 0.01, 2, 'state')
    drift = obs.clone()
    drift[:, 1:, :, 2] += 0.7  # every robot's vx + 0.7
    drift[:, 1:, :, :2] += 0.3  # and a common position error
    assert consensus_loss(drift, obs, scales, FLOCK.velocity).item() == 0.0
    assert window_loss(drift, obs, scales).item() > 0  # the plain loss does see it
    split = obs.clone()
    split[:, 1:, 0, 3] = 0.2  # robot 0 vy + 0.2: relative +0.1, -0.1
    # squared errors 0.01 at 2 robots x 1 entry of 2 velocity entries x 2 robots, every frame: mean 0.005
    assert abs(consensus_loss(split, obs, scales, FLOCK.velocity).item() - 0.005) < 1e-9


def test_consensus_weighted_multi_step_loss_still_recovers_the_known_gains():
    """The linear alignment + cohesion teacher: the window loss plus 10 x the consensus term, minimised
    from elsewhere, returns the teacher's gains (the added term vanishes at the truth too)."""
    student = _fit_linear_student('state', 8, consensus_weight=10.0)
    assert abs(student.a.item() - 1.5) < 1e-3 and abs(student.b.item() - 0.5) < 1e-3, (student.a, student.b)


@pytest.mark.parametrize(
    'scenario,value,ok',
    [
        ('flock2d', 0.0, True),
        ('flock2d', 5, True),
        ('flock2d', -1.0, False),
        ('flock2d', True, False),
        ('boids3d', 1.0, False),
        ('boids3d', 0.0, True),
    ],
)
def test_consensus_weight_config_check_names_the_field(scenario, value, ok):
    raw = _raw()
    raw['scenario'] = scenario
    if scenario == 'boids3d':
        raw['augment'] = {'rotate': False, 'velocity_boost': 0.0}
    raw['multistep']['consensus_weight'] = value
    if ok:
        assert normalise_config(raw)['multistep']['consensus_weight'] == value
    else:
        with pytest.raises(ConfigError, match=r'multistep\.consensus_weight'):
            normalise_config(raw)


def test_multi_step_objective_adds_the_weighted_consensus_term():
    """MultiStepObjective.loss = window loss + consensus_weight x consensus loss, on the same windows."""
    from training.learning.objectives.multi_step import MultiStepObjective

    states = rollout(
        lambda Y, m: np.zeros((Y.shape[0], 2)),
        _swarm(np.random.default_rng(8), 3, 5, FLOCK),
        30,
        'flock2d',
        3.0,
        4,
        0,
        0.01,
    ).astype(np.float32)
    torch.manual_seed(1)
    policy = KNODEPolicy(PolicyConfig('flock2d', k=4, d_cr=3.0, hidden=8, collision_phi=1.0))
    losses = {}
    for w in (0.0, 3.0):
        raw = _raw()
        raw['policy'].update({'k': 4, 'd_cr': 3.0, 'tau': 0})
        raw['augment'] = {'rotate': False, 'velocity_boost': 0.0}
        raw['multistep'].update({'consensus_weight': w, 'units': 'state'})
        cfg = normalise_config(raw)
        obj = MultiStepObjective(cfg, FLOCK, 0.01, states)
        obj.H = 5
        starts = obj.windows.fixed_starts(4, 5)
        with torch.no_grad():
            losses[w] = obj.loss(policy, starts, None).item()
            obs, _ = obj.windows.gather(starts, 5)
            pred = rollout_windows(policy, FLOCK, cfg['policy'], 0.01, obs, None)
            extra = consensus_loss(pred, obs, window_scales(FLOCK, 0.01, 5, 'state'), FLOCK.velocity).item()
    assert extra > 0
    assert abs(losses[3.0] - (losses[0.0] + 3.0 * extra)) < 1e-6 * max(1.0, losses[3.0])
