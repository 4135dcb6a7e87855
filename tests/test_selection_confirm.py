"""Model selection's confirm stage (training.learning.selection): the best few epochs by the
selection score are scored again on more starts, and the best there is exported.

Tiny data (5 robots, 40 steps); the module runs in a few seconds.
"""

import json

import numpy as np
import pytest
import torch
import yaml

from knode_swarm_ros.core import get_scenario, load_policy, rollout, save_trajectories
from training.learning.config import ConfigError, build_policy, normalise_config
from training.learning.selection import Candidates, confirm_truths, rollout_metrics, selection_truths
from training.learning.trainer import Trainer

torch.set_num_threads(1)
FLOCK = get_scenario('flock2d')
QUIET = dict(progress=False, log=lambda *a: None)


def _data(tmp_path, trajectories=6, steps=40, n=5):
    """Tracks of a linear alignment-and-cohesion law; all in the train split."""

    def law(Y, mask):
        m = mask[:, 1:, None]
        count = np.maximum(m.sum(1), 1)
        return (
            ((Y[:, 1:, 2:] - Y[:, :1, 2:]) * m).sum(1) + 0.5 * ((Y[:, 1:, :2] - Y[:, :1, :2]) * m).sum(1)
        ) / count

    rng = np.random.default_rng(0)
    z0 = np.concatenate(
        [rng.uniform(-2, 2, (trajectories, n, 2)), rng.normal(0, 1, (trajectories, n, 2))], -1
    )
    states = rollout(law, z0, steps - 1, 'flock2d', 3.0, 4, 0, 0.01)
    path = tmp_path / 'tracks.npz'
    save_trajectories(path, states, 0.01, 'flock2d', {'split': {'train': list(range(trajectories))}})
    return str(path)


def _cfg(**selection):
    raw = {
        'scenario': 'flock2d',
        'seed': 1,
        'policy': {'hidden': 8, 'd_cr': 3.0, 'k': 4},
        'data': {'val_trajectories': 1},
        'training': {'epochs': 6, 'batch_size': 64, 'lr': 0.02, 'threads': 1},
        'selection': {'every': 1, 'trajectories': 1, 'rollouts': 2, **selection},
    }
    return normalise_config(raw)


def _module(cfg, state):
    module = build_policy(cfg)
    module.load_state_dict(state)
    return module


# ----------------------------------------------------------------------------- the candidates


@pytest.mark.parametrize(
    'size, scores, kept_epochs, best_at',
    [
        (1, [3.0, 1.0, 2.0], [2], [True, True, False]),
        (3, [3.0, 1.0, 2.0, 0.5], [4, 2, 3], [True, True, False, True]),
        (2, [1.0, 1.0, 1.0], [1, 2], [True, False, False]),  # a tie keeps the earlier epoch first
        (2, [float('inf'), 2.0, float('nan'), 4.0], [2, 4], [False, True, False, False]),
        (3, [5.0, 4.0, 3.0, 9.0], [3, 2, 1], [True, True, True, False]),
    ],
)
def test_candidates_keep_the_best_few_in_order(size, scores, kept_epochs, best_at):
    module = torch.nn.Linear(2, 1)
    c = Candidates(size)
    was_best = []
    for epoch, score in enumerate(scores, start=1):
        with torch.no_grad():
            module.bias.fill_(epoch)
        was_best.append(c.offer(epoch, {'score': score}, module))
    assert [e['epoch'] for e in c.kept] == kept_epochs and was_best == best_at
    # each kept state is a copy taken at its epoch, not a view of the module
    assert [float(e['state']['bias']) for e in c.kept] == [float(e) for e in kept_epochs]
    assert [e['score'] for e in c.kept] == sorted(e['score'] for e in c.kept)


# ----------------------------------------------------------------------------- the starts


def test_confirm_starts_are_the_validation_ones_plus_training_first_frames(tmp_path):
    cfg = _cfg(confirm=3, confirm_trajectories=2)
    trainer = Trainer(cfg, _data(tmp_path), str(tmp_path / 'run'), **QUIET)
    split = trainer.splits[0]
    sel = selection_truths(trainer.splits, cfg['selection'], 1)
    conf = confirm_truths(trainer.splits, cfg['selection'], 1)
    assert len(sel) == 1 and np.array_equal(sel[0], split['val'][:1])
    assert len(conf) == 2 and np.array_equal(conf[0], sel[0]) and np.array_equal(conf[1], split['train'][:2])
    # its rollouts cost three selections' (3 starts of 40 frames against 1)
    assert trainer.confirm_cost == pytest.approx(3.0)
    all_train = confirm_truths(trainer.splits, dict(cfg['selection'], confirm_trajectories=None), 1)
    assert all_train[1].shape[0] == split['train'].shape[0] == 5


# ----------------------------------------------------------------------------- the run


def test_confirm_stage_exports_the_best_candidate_on_more_starts(tmp_path):
    cfg = _cfg(confirm=3, confirm_trajectories=4)
    data = _data(tmp_path)
    trainer = Trainer(cfg, data, str(tmp_path / 'run'), **QUIET)
    summary = trainer.run()
    log = [json.loads(line) for line in open(tmp_path / 'run' / 'metrics.jsonl')]
    scored = sorted((r['selection']['score'], r['epoch']) for r in log)
    confirmed = summary['confirmed']
    # the candidates are the three best epochs by the selection score, best first
    assert [c['epoch'] for c in confirmed] == [e for _, e in scored[:3]]
    assert [c['score'] for c in confirmed] == [s for s, _ in scored[:3]]
    # each confirm score is the rollout score of that epoch's state on the confirm starts
    truths = confirm_truths(trainer.splits, cfg['selection'], 1)
    for c, cand in zip(confirmed, trainer.candidates.kept):
        m = rollout_metrics(_module(cfg, cand['state']), FLOCK, truths, cfg['selection'], cfg['policy'], 0.01)
        assert m['score'] == pytest.approx(c['confirm_score'], rel=1e-12) and m['rollouts'] == 2 * (1 + 4)
    chosen = min(confirmed, key=lambda c: c['confirm_score'])
    assert chosen['epoch'] != confirmed[0]['epoch']  # on these data more starts change the choice
    assert summary['best']['epoch'] == chosen['epoch'] and str(chosen['epoch']) in summary['selected']
    assert summary['best']['confirm']['score'] == chosen['confirm_score']
    # the exported policy is that epoch's state
    state = next(c['state'] for c in trainer.candidates.kept if c['epoch'] == chosen['epoch'])
    s = trainer.train
    with torch.no_grad():
        want = _module(cfg, state)(s.Y, s.mask).numpy()
    np.testing.assert_allclose(load_policy(summary['policy'])(s.Y.numpy(), s.mask.numpy()), want, atol=1e-6)


def test_without_confirm_the_selection_best_is_exported(tmp_path):
    trainer = Trainer(_cfg(), _data(tmp_path), str(tmp_path / 'run'), **QUIET)
    summary = trainer.run()
    log = [json.loads(line) for line in open(tmp_path / 'run' / 'metrics.jsonl')]
    assert summary['confirmed'] is None and summary['confirm_seconds'] is None
    assert summary['best']['epoch'] == min(log, key=lambda r: r['selection']['score'])['epoch']
    assert len(trainer.candidates.kept) == 1


def test_an_interrupted_run_resumes_with_its_candidates(tmp_path):
    cfg = _cfg(confirm=3, confirm_trajectories=4)
    data = _data(tmp_path)
    whole = Trainer(cfg, data, str(tmp_path / 'a'), **QUIET).run()
    first = Trainer(cfg, data, str(tmp_path / 'b'), **QUIET)
    assert first.run(stop_after=3) is None
    resumed = Trainer(cfg, data, str(tmp_path / 'b'), resume=True, **QUIET)
    assert [c['epoch'] for c in resumed.candidates.kept] == [c['epoch'] for c in first.candidates.kept]
    again = resumed.run()
    assert again['confirmed'] == whole['confirmed'] and again['best']['epoch'] == whole['best']['epoch']


@pytest.mark.parametrize(
    'field, value',
    [
        ('confirm', -1),
        ('confirm', 2.5),
        ('confirm', True),
        ('confirm_trajectories', 0),
        ('confirm_trajectories', 'all'),
    ],
)
def test_bad_confirm_settings_are_refused_naming_the_field(field, value):
    with pytest.raises(ConfigError, match=f'selection.{field}'):
        _cfg(**{field: value})


def test_the_generic_recipe_confirms(tmp_path):
    recipe = yaml.safe_load(open('config/train_custom.yaml'))
    assert recipe['selection']['confirm'] >= 2 and recipe['selection']['confirm_trajectories'] >= 1


def test_the_selection_alone_is_exported_beside_the_run_for_the_paired_study(tmp_path):
    """training.studies.confirm_pairs: the epoch the selection alone would have kept, as a policy."""
    from training.studies.confirm_pairs import export_selection_best

    cfg = _cfg(confirm=3, confirm_trajectories=4)
    trainer = Trainer(cfg, _data(tmp_path), str(tmp_path / 'run'), **QUIET)
    summary = trainer.run()
    pair = export_selection_best(str(tmp_path / 'run'), str(tmp_path / 'selection'))
    first = trainer.candidates.kept[0]
    assert pair['selection_epoch'] == first['epoch'] != pair['confirm_epoch'] == summary['best']['epoch']
    alone, confirmed = load_policy(pair['policy']), load_policy(summary['policy'])
    s = trainer.train
    with torch.no_grad():
        want = _module(cfg, first['state'])(s.Y, s.mask).numpy()
    np.testing.assert_allclose(alone(s.Y.numpy(), s.mask.numpy()), want, atol=1e-6)
    assert not np.allclose(alone(s.Y.numpy(), s.mask.numpy()), confirmed(s.Y.numpy(), s.mask.numpy()))
    assert alone.meta['scenario'] == confirmed.meta['scenario'] and alone.dt == confirmed.dt
    # a run without the confirm stage has no pair
    Trainer(_cfg(), _data(tmp_path), str(tmp_path / 'plain'), **QUIET).run()
    assert export_selection_best(str(tmp_path / 'plain'), str(tmp_path / 'none')) is None


@pytest.mark.parametrize('tracks, copies', [(0, 2), (2, 2), (5, 1), (3, 4)])
def test_a_confirm_size_of_the_study_scores_as_the_confirm_stage_on_those_starts(tmp_path, tracks, copies):
    """training.studies.confirm_starts scores every size as a subset of one set of rollouts: the
    first ``tracks`` training tracks' starts, ``copies`` copies of each, score as the confirm
    stage itself scores them (0 tracks: the selection's own starts)."""
    from training.learning.selection import rollout_groups
    from training.studies.confirm_starts import _subset_score

    cfg = _cfg(confirm=3)
    trainer = Trainer(cfg, _data(tmp_path), str(tmp_path / 'run'), **QUIET)
    sc = cfg['selection']
    truths = confirm_truths(trainer.splits, dict(sc, confirm_trajectories=None), 1)
    groups = rollout_groups(trainer.policy, FLOCK, truths, 4, sc['perturb'], cfg['policy'], 0.01)
    size = dict(sc, confirm_trajectories=tracks, rollouts=copies)
    starts = confirm_truths(trainer.splits, size, 1) if tracks else selection_truths(trainer.splits, size, 1)
    want = rollout_metrics(trainer.policy, FLOCK, starts, size, cfg['policy'], 0.01)
    assert np.isfinite(want['score']) and want['rollouts'] == (1 + tracks) * copies
    # rel 1e-6: the float32 network rounds differently in a batch of another size; another subset
    # (other starts or copies) differs by orders of magnitude more
    assert _subset_score(FLOCK, groups, [1, tracks], copies, 4) == pytest.approx(want['score'], rel=1e-6)
    if copies < 4:
        other = _subset_score(FLOCK, groups, [1, tracks], copies + 1, 4)
        assert other != pytest.approx(want['score'], rel=1e-4)


def test_the_confirm_sizes_study_runs_a_law_study_folder_and_resumes(tmp_path, monkeypatch):
    """python -m training.studies.confirm_starts on a tiny custom_laws study: the recipe's size
    (8 tracks x 2) scores the candidates as the run's own confirm stage did and chooses its epoch,
    a regret is the choice's mean held-out score over the two sets less the best candidate's, and
    the same call again runs nothing (an interrupted study resumes)."""
    from training.studies import confirm_starts, custom_laws
    from training.studies.laws import LAWS, Law

    base = LAWS['aggregate2d']
    law = Law(base.name, base.scenario, base.command, base.start_radius_per_sqrt_n, base.start_speed, 30)
    monkeypatch.setitem(custom_laws.LAWS, 'aggregate2d', law)
    monkeypatch.setitem(confirm_starts.LAWS, 'aggregate2d', law)
    recipe = yaml.safe_load(open('config/train_custom.yaml'))
    recipe['training']['epochs'] = 4
    recipe['policy']['hidden'] = 8
    recipe['selection'].update(every=1, confirm=3)
    config = tmp_path / 'tiny.yaml'
    config.write_text(yaml.safe_dump(recipe))
    out = tmp_path / 'laws'
    argv = ['--laws', 'aggregate2d', '--out', str(out), '--config', str(config), '--trajectories', '12']
    assert custom_laws.main(argv + ['--eval-robots', '4', '--starts', '2']) == 0
    folder = str(out / 'aggregate2d')
    sizes = tmp_path / 'sizes.json'
    study = [folder, '--out', str(sizes), '--held-out', '3', '--robots', '4', '--seeds', '1000', '2000']
    assert confirm_starts.main(study) == 0
    (run,) = json.loads(sizes.read_text())
    summary = json.loads((out / 'aggregate2d' / 'run' / 'summary.json').read_text())
    recipe_size = [s['tracks'] for s in run['sizes']].index(8)
    assert run['choices'][recipe_size]['epoch'] == summary['best']['epoch']
    assert [c['epoch'] for c in run['candidates']] == [c['epoch'] for c in summary['confirmed']]
    # the recipe's size scores each candidate as the run's confirm stage did
    logged = [c['confirm_score'] for c in summary['confirmed']]
    assert [c['scores'][recipe_size] for c in run['candidates']] == pytest.approx(logged, rel=1e-6)
    by_epoch = {c['epoch']: c for c in run['candidates']}
    best = min(c['held_out_score'] for c in run['candidates'])
    for ch in run['choices']:
        c = by_epoch[ch['epoch']]
        assert c['held_out_score'] == pytest.approx(np.mean(c['held_out_scores']))
        assert ch['regret'] == pytest.approx(c['held_out_score'] - best) and ch['regret'] >= 0.0
    assert (tmp_path / 'sizes.md').read_text().count('| aggregate2d') == 1

    def must_not_run(*args, **kwargs):
        raise AssertionError('a run already in --out was run again')

    monkeypatch.setattr(confirm_starts, 'study_run', must_not_run)
    assert confirm_starts.main(study) == 0
    assert json.loads(sizes.read_text()) == [run]
