"""A newcomer's first hour: the documented path works on small data, errors say what to do next,
logs and figures read well. One test (or more) per finding; the README's own blocks run in
tests/test_readme.py, every documented command's ``--help`` in tests/test_docs_commands.py.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from knode_swarm_ros.core import save_trajectories
from knode_swarm_ros.core.cli import parse_set
from knode_swarm_ros.core.errors import ConfigError
from knode_swarm_ros.core.groundtruth import simulate

ROOT = Path(__file__).resolve().parents[1]
CONFIG = str(ROOT / 'config' / 'train_flock2d.yaml')  # the documented config, as the docs use it


def _data(tmp_path, trajectories, train, frames=60, name='d.npz'):
    """A small flock2d file with ``train`` train trajectories (the rest test), like an import."""
    states = simulate('flock2d', trajectories, 5, frames, seed=1, progress=False, min_separation=0.15)
    path = tmp_path / name
    split = {'train': list(range(train)), 'test': list(range(train, trajectories))}
    save_trajectories(path, states, 0.01, 'flock2d', {'split': split})
    return str(path)


def _train(argv, capsys=None):
    from training.train import main

    return main(['--config', CONFIG, '--no-progress', *argv])


QUICK = ['--set', 'training.epochs=1', '--set', 'training.batch_size=512']
VAL1 = ['--set', 'data.val_trajectories=1']  # tests of other points keep to what always worked


# 2 ----------------------------------------------------------------------------------------------
def test_held_out_count_is_a_fraction_with_a_floor_of_one_and_keeps_the_count_where_it_fits():
    from training.learning.config import normalise_config
    from training.learning.trainer import held_out_count

    cfg = normalise_config({'scenario': 'flock2d'})
    assert [held_out_count(cfg, n) for n in (1, 2, 3, 7, 10, 30)] == [0, 1, 1, 1, 2, 6]
    cfg = normalise_config({'scenario': 'flock2d', 'data': {'val_trajectories': 8}})
    assert [held_out_count(cfg, n) for n in (1, 7, 12, 30)] == [0, 1, 8, 8]  # the count where it fits
    cfg = normalise_config({'scenario': 'flock2d', 'data': {'val_trajectories': 0}})
    assert held_out_count(cfg, 5) == 0
    with pytest.raises(ConfigError, match='data.val_fraction'):
        normalise_config({'scenario': 'flock2d', 'data': {'val_fraction': 1.0}})


def test_the_documented_config_trains_on_one_recording_split_in_time(tmp_path, capsys):
    data = _data(tmp_path, 1, 1, frames=100)
    assert _train(['--data', data, '--out', str(tmp_path / 'run'), *QUICK]) == 0, capsys.readouterr().err
    out = capsys.readouterr().out
    assert 'one trajectory in the train split: training on its frames 0-79, validating on frames 80-99' in out
    summary = json.loads((tmp_path / 'run' / 'summary.json').read_text())
    assert summary['val_samples'] > 0 and summary['best'] is not None  # validated and selected


def test_the_documented_config_trains_on_a_small_generated_dataset(tmp_path, capsys):
    data = _data(tmp_path, 12, 7)
    assert _train(['--data', data, '--out', str(tmp_path / 'run'), *QUICK]) == 0, capsys.readouterr().err
    out = capsys.readouterr().out
    assert (
        "data.val_trajectories = 8 but the data's train split holds only 7 trajectories: holding out 1" in out
    )


def test_split_in_time_keeps_the_parts_apart():
    from training.learning.config import normalise_config
    from training.learning.trainer import split_data

    states = np.arange(50 * 3 * 4, dtype=float).reshape(1, 50, 3, 4)

    class One:
        def split(self, name):
            return np.array([0])

    One.states = states
    sp = split_data(normalise_config({'scenario': 'flock2d'}), One(), log=lambda *a: None)
    assert sp['val_from_frame'] == 40
    np.testing.assert_array_equal(sp['train'][0], states[0, :40])
    np.testing.assert_array_equal(sp['val'][0], states[0, 40:])


# 3 ----------------------------------------------------------------------------------------------
def test_evaluate_on_a_file_without_a_test_split_uses_what_it_has_and_says_so(tmp_path, capsys):
    from knode_swarm_ros.core import shipped_policy_path
    from training.evaluate import main

    data = _data(tmp_path, 2, 2)
    out = tmp_path / 'eval'
    assert main(['--policy', str(shipped_policy_path('flock2d')), '--data', data, '--out', str(out)]) == 0
    text = capsys.readouterr()
    assert 'has no test split' in text.out and 'optimistic' in text.out
    assert 'Mean of empty slice' not in text.err and 'log-scaled' not in text.err
    results = json.loads((out / 'results.json').read_text())
    assert results['test_trajectories'] == [0, 1] and results['trajectories_used'] == 'all (no test split)'
    assert 'no test split' in (out / 'summary.md').read_text()


# 4, 5, 6, 7 -------------------------------------------------------------------------------------
def test_a_log_file_gets_epoch_lines_not_carriage_returns(tmp_path):
    data = _data(tmp_path, 3, 3)
    log = tmp_path / 'train.log'
    cmd = [sys.executable, '-m', 'training.train', '--config', CONFIG, '--data', data]
    cmd += [
        '--out',
        str(tmp_path / 'run'),
        '--set',
        'training.epochs=2',
        '--set',
        'training.batch_size=64',
        *VAL1,
    ]
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    with open(log, 'w') as fh:  # progress on (the default), output a file
        assert subprocess.run(cmd, stdout=fh, stderr=subprocess.STDOUT, env=env, cwd=ROOT).returncode == 0
    text = log.read_bytes().decode()  # read_text would turn carriage returns into newlines
    assert '\r' not in text, repr(text[:300])
    assert len([line for line in text.splitlines() if line.startswith('epoch 1/2')]) == 1, text[:600]
    assert 'epoch 1/2 train' in text and 'epoch 2/2 train' in text


def test_progress_lines_within_a_long_epoch_off_a_terminal(tmp_path, monkeypatch):
    from training.learning import trainer as trainer_module
    from training.learning.config import load_config

    monkeypatch.setattr(trainer_module, 'PROGRESS_EVERY_S', 0.0)
    lines = []
    cfg = load_config(CONFIG, {'training.epochs': 1, 'training.batch_size': 256})
    trainer_module.Trainer(cfg, _data(tmp_path, 3, 3), str(tmp_path / 'r'), log=lines.append).run()
    assert any(line.startswith('epoch 1/1: batch 1/') for line in lines), lines


def test_training_into_an_existing_run_is_refused_unless_resume_or_overwrite(tmp_path, capsys):
    data, run = _data(tmp_path, 3, 3), str(tmp_path / 'run')
    assert _train(['--data', data, '--out', run, *QUICK, *VAL1]) == 0
    policy = (tmp_path / 'run' / 'policy.pt').read_bytes()
    capsys.readouterr()
    assert _train(['--data', data, '--out', run, *QUICK, *VAL1, '--set', 'seed=5']) == 2
    err = capsys.readouterr().err
    assert 'already holds a run' in err and '--resume' in err and '--overwrite' in err
    assert (tmp_path / 'run' / 'policy.pt').read_bytes() == policy
    assert _train(['--data', data, '--out', run, *QUICK, *VAL1, '--set', 'seed=5', '--overwrite']) == 0
    assert (tmp_path / 'run' / 'policy.pt').read_bytes() != policy


def test_resume_extends_a_finished_run_and_names_a_differing_field(tmp_path, capsys):
    data, run = _data(tmp_path, 3, 3), str(tmp_path / 'run')
    assert _train(['--data', data, '--out', run, *QUICK, *VAL1]) == 0
    capsys.readouterr()
    extend = ['--set', 'training.epochs=2', '--set', 'training.batch_size=512']
    assert _train(['--data', data, '--out', run, *extend, *VAL1, '--resume']) == 0, capsys.readouterr().err
    assert 'training.epochs 1 -> 2' in capsys.readouterr().out
    assert json.loads((tmp_path / 'run' / 'summary.json').read_text())['epochs'] == 2
    assert (
        _train(['--data', data, '--out', run, *extend, *VAL1, '--set', 'training.lr=0.01', '--resume']) == 2
    )
    err = capsys.readouterr().err
    assert '(training.lr: ' in err and ' in the checkpoint, 0.01 now)' in err


def test_ctrl_c_says_the_checkpoint_is_kept_and_how_to_resume(tmp_path, capsys, monkeypatch):
    from training import train
    from training.learning.trainer import Trainer

    class StoppedAfterOneEpoch(Trainer):
        def run(self, stop_after=None):
            super().run(stop_after=1)
            raise KeyboardInterrupt

    monkeypatch.setattr(train, 'Trainer', StoppedAfterOneEpoch)
    data, run = _data(tmp_path, 3, 3), str(tmp_path / 'run')
    assert _train(['--data', data, '--out', run, '--set', 'training.epochs=3', *VAL1]) == 130
    err = capsys.readouterr().err
    assert 'interrupted: checkpoint after epoch 1 kept at' in err and '--resume' in err


# 8, 9 -------------------------------------------------------------------------------------------
def test_set_reads_exponent_numbers_as_numbers():
    assert parse_set(['noise.variance=1e-4', 'a.b=1E3', 'name=abc', 'x.y=inf']) == {
        'noise.variance': 1e-4,
        'a.b': 1000.0,
        'name': 'abc',
        'x.y': 'inf',
    }
    from training.learning.config import load_config

    assert load_config(CONFIG, parse_set(['noise.variance=1e-4']))['noise']['variance'] == 1e-4


def test_a_typo_in_set_is_blamed_on_the_command_line():
    from training.learning.config import load_config

    with pytest.raises(ConfigError) as info:
        load_config(CONFIG, parse_set(['training.epoch=2']))
    assert str(info.value).startswith("--set training.epoch=2: config field 'training.epoch'")
    with pytest.raises(ConfigError, match='^config file'):  # a field of the file stays the file's
        load_config(str(ROOT / 'README.md'), {})


# 10 ---------------------------------------------------------------------------------------------
def test_swarm_realtime_runs_at_the_policys_rate_and_its_warning_names_rate(tmp_path):
    from knode_swarm_ros.logic.agent.control_period import check_control_period
    from knode_swarm_ros.nodes import swarm

    base = [
        '--robots',
        '3',
        '--record',
        str(tmp_path / 'r.npz'),
        '--domain-id',
        '40',
        '--log-dir',
        str(tmp_path),
    ]
    boids = swarm.plan_run(
        swarm.build_parser().parse_args(['--scenario', 'boids3d', '--mode', 'realtime', *base])
    )
    assert abs(boids.rate - 60.0) < 1e-9 and check_control_period(boids.rate, boids.dt).equal
    flock = swarm.plan_run(
        swarm.build_parser().parse_args(['--scenario', 'flock2d', '--mode', 'realtime', *base])
    )
    assert abs(flock.rate - 20.0) < 1e-9 and flock.policy.endswith('flock2d_20hz.pt')
    lock = swarm.plan_run(swarm.build_parser().parse_args(['--scenario', 'boids3d', *base]))
    assert lock.rate == 20.0  # lockstep unchanged
    text = check_control_period(20.0, 1 / 60).describe('--rate')
    assert '(--rate 20 Hz)' in text and text.endswith('or --rate 60') and 'control_rate' not in text


# 12, 13 -----------------------------------------------------------------------------------------
@pytest.fixture
def drawn(monkeypatch):
    """The figures saved while a test runs, ``{file name: matplotlib figure}``."""
    from matplotlib.figure import Figure

    saved = {}
    real = Figure.savefig

    def keep(fig, path, *args, **kwargs):
        saved[os.path.basename(str(path))] = fig
        real(fig, path, *args, **kwargs)

    monkeypatch.setattr(Figure, 'savefig', keep)
    return saved


def test_evaluation_figures_have_units_a_log_avd_axis_labels_legends_and_a_caption(tmp_path, drawn):
    from knode_swarm_ros.core import shipped_policy_path
    from training.assessment.evaluation import evaluate

    data = _data(tmp_path, 3, 1)
    evaluate(str(shipped_policy_path('flock2d')), data, str(tmp_path / 'e'), log=lambda *a: None)
    metrics = drawn['metrics.png']
    avd_ax, amd_ax = metrics.axes
    assert avd_ax.get_ylabel().endswith('[m/s]') and avd_ax.get_yscale() == 'log'
    assert amd_ax.get_ylabel().endswith('[m]') and avd_ax.get_xlabel() == 'time [s]'
    captions = [t.get_text() for t in metrics.texts]
    assert any('lower is better' in c for c in captions)
    snaps = drawn['snapshots.png']
    assert all(ax.get_xlabel() == 'x [m]' and ax.get_ylabel() == 'y [m]' for ax in snaps.axes)
    assert all(ax.get_legend() is not None for ax in snaps.axes) and snaps.texts
    for ax in snaps.axes:  # every robot inside its panel
        (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
        pts = ax.collections[-1].get_offsets()
        assert np.all((pts[:, 0] > x0) & (pts[:, 0] < x1) & (pts[:, 1] > y0) & (pts[:, 1] < y1))
    summary = (tmp_path / 'e' / 'summary.md').read_text()
    assert '95 % confidence interval' in summary


def test_the_swarm_figure_of_boids3d_has_the_ground_truth_beside_it_and_log_avd(
    tmp_path, monkeypatch, capsys
):
    import matplotlib.pyplot as plt

    from knode_swarm_ros.core import load_policy, shipped_policy_path
    from knode_swarm_ros.nodes.swarm import report
    from training.assessment.scores import rollout_policy

    z0 = simulate('boids3d', 1, 6, 1, seed=2, progress=False)[:, 0]
    policy = load_policy(shipped_policy_path('boids3d'))
    save_trajectories(tmp_path / 'b.npz', rollout_policy(policy, z0, 30), policy.dt, 'boids3d')

    class Plan:
        record, figure, run_dir, mode, ground_truth, variant = (
            tmp_path / 'b.npz',
            tmp_path / 'b.png',
            tmp_path,
            'realtime',
            False,
            None,
        )

    shown = {}
    monkeypatch.setattr(plt.Figure, 'savefig', lambda fig, *a, **k: shown.setdefault('fig', fig))
    info = report.summarise(Plan)
    assert 'ground_truth' in info
    assert 'ground truth from the same start (paper boids)' in capsys.readouterr().out
    axes = shown['fig'].axes
    assert len(axes) == 4 and axes[2].get_yscale() == 'log' and axes[0].get_xlabel() == 'x [m]'
    assert any('lower is better' in t.get_text() for t in shown['fig'].texts)


def test_small_things_of_the_first_hour():
    training_md = (ROOT / 'docs' / 'training.md').read_text()
    assert 'make demo-offline' in training_md and '(make demo)' not in training_md
    from training import demo

    assert '--out out/demo-offline' in demo.__doc__
    helps = subprocess.run(
        [sys.executable, '-m', 'training.generate', '--help'],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env=dict(os.environ, PYTHONPATH=str(ROOT)),
    ).stdout
    assert '(default: None)' not in helps and '(default 10)' in helps


def test_torchscript_deprecation_notices_are_filtered_and_documented(pytestconfig):
    assert any('torch.jit.script' in f for f in pytestconfig.getini('filterwarnings'))
    assert 'TorchScript' in (ROOT / 'docs' / 'testing.md').read_text().split('## Warnings')[1]


def test_with_an_explicit_rate_mismatch_the_launcher_warns_and_its_agents_do_not_repeat_it(tmp_path):
    """The launcher says a mismatch once (``--rate``); its agents run with ``rate_check: accept``,
    which keeps the check (``refuse`` still refuses) but logs nothing; a lone agent still warns."""
    from test_control_period import _logic

    from knode_swarm_ros.nodes import swarm

    args = ['--scenario', 'boids3d', '--mode', 'realtime', '--rate', '20', '--robots', '3']
    args += ['--record', str(tmp_path / 'r.npz'), '--domain-id', '40', '--log-dir', str(tmp_path)]
    plan = swarm.plan_run(swarm.build_parser().parse_args(args))
    _, files = swarm.build_commands(plan)
    agents = [p for name, p in files.items() if 'agent' in str(name)]
    assert agents and all('accept' in json.dumps(p) and '"warn"' not in json.dumps(p) for p in agents)
    assert _logic(20.0, 1 / 60, rate_check='warn').events  # a lone agent: one line
    assert _logic(20.0, 1 / 60, rate_check='accept').events == []  # a launcher's agent: none
    refuse = swarm.plan_run(swarm.build_parser().parse_args([*args, '--rate-check', 'refuse']))
    assert all(
        'refuse' in json.dumps(p) for n, p in swarm.build_commands(refuse)[1].items() if 'agent' in str(n)
    )
