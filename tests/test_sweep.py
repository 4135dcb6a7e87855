"""Sweeps (training.sweep, training/learning/sweep.py): a 2 x 2 sweep of tiny trainings on a local Ray of
two workers gives the table of the same cells run in this process; resume, a failing cell, a killed
worker, Ray missing. One local Ray serves the module (its start costs seconds); no timing asserted.
"""

import functools
import json
import os
import sys

import numpy as np
import pytest
import ray  # the Ray path is tested: a broken install must fail, not skip
import yaml

from knode_swarm_ros.core import rollout, save_trajectories
from training.assessment.sweep_table import heatmaps, sweep_table, table_markdown
from training.learning.config import load_config
from training.learning.sweep import Cell, axis_product, cell_name, parse_axis, run_cells, train_cell
from training.sweep import main as sweep_main

AXES = ['--axis', 'policy.k=3,4', '--axis', 'seed=0,1']


@pytest.fixture(scope='module')
def tiny(tmp_path_factory):
    """A tiny flock2d data file and config: two epochs of a few hundred samples per cell."""
    root = tmp_path_factory.mktemp('sweep_inputs')
    rng = np.random.default_rng(0)
    z0 = np.concatenate([rng.uniform(-2, 2, (4, 5, 2)), rng.normal(0, 1, (4, 5, 2))], axis=-1)

    def teacher(Y, mask):  # alignment with the neighbour rows
        m = mask[:, 1:, None]
        return 1.5 * ((Y[:, 1:, 2:] - Y[:, :1, 2:]) * m).sum(1) / np.maximum(m.sum(1), 1)

    states = rollout(teacher, z0, 29, 'flock2d', 3.0, 4, 0, 0.01)
    data = root / 'tiny.npz'
    save_trajectories(data, states, 0.01, 'flock2d', {'split': {'train': [0, 1, 2], 'test': [3]}})
    config = root / 'tiny.yaml'
    config.write_text(
        yaml.safe_dump(
            {
                'scenario': 'flock2d',
                'policy': {'hidden': 8, 'd_cr': 3.0, 'k': 4},
                'data': {'val_trajectories': 1},
                'training': {'epochs': 2, 'batch_size': 64, 'lr': 0.01, 'threads': 1},
                'selection': {'every': 1, 'trajectories': 1, 'steps': 10},
            }
        )
    )
    return str(config), str(data)


@pytest.fixture(scope='module')
def local_ray():
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, object_store_memory=128 * 2**20)
    yield
    ray.shutdown()


def _sweep(tiny, out, *extra):
    config, data = tiny
    return sweep_main(['--config', config, '--data', data, '--out', str(out), *extra])


@pytest.fixture(scope='module')
def two_sweeps(tiny, local_ray, tmp_path_factory):
    """The 2 x 2 sweep on Ray (2 workers) and in this process with Ray not importable."""
    root = tmp_path_factory.mktemp('sweeps')
    on_ray = _sweep(tiny, root / 'ray', *AXES, '--workers', '2')
    saved = sys.modules['ray']
    sys.modules['ray'] = None  # `import ray` raises ImportError
    try:
        local = _sweep(tiny, root / 'local', *AXES)
    finally:
        sys.modules['ray'] = saved
    return root, on_ray, local


def _json(path):
    with open(path) as fh:
        return json.load(fh)


def test_the_table_on_ray_equals_the_table_in_process(two_sweeps):
    root, on_ray, local = two_sweeps
    assert on_ray == 0 and local == 0
    a, b = _json(root / 'ray' / 'sweep.json'), _json(root / 'local' / 'sweep.json')
    assert [c['name'] for c in a['cells']] == [
        'policy.k=3,seed=0',
        'policy.k=3,seed=1',
        'policy.k=4,seed=0',
        'policy.k=4,seed=1',
    ]
    assert all(c['status'] == 'done' and c['attempts'] == 1 for c in a['cells'] + b['cells'])
    assert [c['metrics'] for c in a['cells']] == [c['metrics'] for c in b['cells']]
    assert a['table'] == b['table']
    rows = a['table']['rows']
    assert [r['values'] for r in rows] == [{'policy.k': 3}, {'policy.k': 4}]
    assert all(r['seeds'] == 2 and r['metrics']['score']['count'] == 2 for r in rows)
    for cell in a['cells']:  # each cell an ordinary run directory
        assert {'summary.json', 'policy.pt', 'cell.json', 'train.log'} <= set(os.listdir(cell['run_dir']))
    assert (root / 'ray' / 'table.md').read_text().count('\n| ') == 4  # header, rule and two rows
    log = (root / 'ray' / 'sweep.log').read_text()
    assert 'sweep: 4/4 done, 0 running, 0 failed, 0 pending' in log


def test_resume_runs_only_the_cells_not_finished(two_sweeps, tiny, monkeypatch):
    root, _, _ = two_sweeps
    out = root / 'local'
    os.unlink(out / 'policy.k=4,seed=1' / 'cell.json')  # as if cut short before its end
    ran = []

    def spy(cfg, data, run_dir):
        ran.append(os.path.basename(run_dir))
        return train_cell(cfg, data, run_dir)

    monkeypatch.setattr('training.sweep.train_cell', spy)
    assert _sweep(tiny, out, *AXES) == 0
    assert ran == ['policy.k=4,seed=1']
    assert _sweep(tiny, out, *AXES) == 0
    assert ran == ['policy.k=4,seed=1']
    assert 'sweep: 4/4 done, 0 running, 0 failed, 0 pending' in (out / 'sweep.log').read_text()
    # another config in the same directory is refused
    assert _sweep(tiny, out, *AXES, '--set', 'training.lr=0.1') == 2


def test_a_cell_that_raises_is_reported_failed_and_the_others_finish(tiny, local_ray, tmp_path):
    # a policy dt of 1.5 data steps: a valid config that only the data refuses, in that cell's Trainer
    rc = _sweep(tiny, tmp_path, '--axis', 'data.policy_dt=0.01,0.015', '--workers', '2')
    assert rc == 1
    cells = {c['name']: c for c in _json(tmp_path / 'sweep.json')['cells']}
    good, bad = cells['data.policy_dt=0.01'], cells['data.policy_dt=0.015']
    assert good['status'] == 'done' and good['metrics']['score'] >= 0
    assert bad['status'] == 'failed' and bad['attempts'] == 2 and 'policy_dt' in bad['error']
    assert 'failed twice' in (tmp_path / 'sweep.log').read_text()


def kill_first_attempt(marker, fn):
    """A cell whose first attempt kills its worker process (as a crash or an OOM kill would)."""
    import signal

    if not os.path.exists(marker):
        open(marker, 'w').close()
        os.kill(os.getpid(), signal.SIGKILL)
    return fn()


def test_a_killed_worker_is_retried_once_and_the_sweep_finishes(tiny, local_ray, tmp_path):
    from ray import cloudpickle

    config, data = tiny
    cloudpickle.register_pickle_by_value(sys.modules[__name__])  # workers cannot import this module
    cells = []
    for values in axis_product([('policy.k', [3, 4])]):
        run_dir = str(tmp_path / cell_name(values))
        fn = functools.partial(train_cell, load_config(config, values), data, run_dir)
        if values['policy.k'] == 3:
            fn = functools.partial(kill_first_attempt, str(tmp_path / 'killed'), fn)
        cells.append(Cell(cell_name(values), values, run_dir, fn))
    try:
        records = run_cells(cells, str(tmp_path), workers=2, echo=lambda *a, **k: None)
    finally:
        cloudpickle.unregister_pickle_by_value(sys.modules[__name__])
    assert [(r['status'], r['attempts']) for r in records] == [('done', 2), ('done', 1)]
    assert 'retrying' in (tmp_path / 'sweep.log').read_text()


def test_several_workers_without_ray_are_refused_with_how_to_install(tiny, tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, 'ray', None)
    assert _sweep(tiny, tmp_path, *AXES, '--workers', '2') == 2
    assert 'pip install ray==2.60.0' in capsys.readouterr().err


def test_axes_names_table_and_heat_maps(tmp_path):
    assert parse_axis('policy.d_cr=2,3.5') == ('policy.d_cr', [2, 3.5])
    assert cell_name({'policy.d_cr': 3.5, 'training.solver': 'zoh', 'x': [1, 2]}) == (
        'policy.d_cr=3.5,training.solver=zoh,x=-1--2-'
    )
    for bad in ('policy.k', 'policy.k=', 'k=1,1'):
        with pytest.raises(ValueError, match='--axis'):
            parse_axis(bad)
    axes = [('policy.d_cr', [2, 5]), ('policy.k', [3, 6]), ('seed', [0, 1])]
    records = [
        {'values': v, 'status': 'done', 'metrics': {'score': v['policy.k'] + v['seed']}}
        for v in axis_product(axes)
    ]
    records[-1].update(status='failed', metrics=None)
    table = sweep_table(records, axes)
    last = table['rows'][-1]
    assert table['axes'] == ['policy.d_cr', 'policy.k'] and len(table['rows']) == 4
    assert table['rows'][0]['metrics']['score']['mean'] == 3.5  # k 3, seeds 0 and 1
    assert table['rows'][0]['metrics']['score']['ci95'] > 0
    assert (last['seeds'], last['failed'], last['metrics']['score']['mean']) == (1, 1, 6)
    assert '| 5 | 6 | 1 | 1 | 6 ± 0 |' in table_markdown(table)
    assert heatmaps(table, axes, str(tmp_path)) == [str(tmp_path / 'heatmap_score.png')]
    assert heatmaps(sweep_table(records, axes[1:]), axes[1:], str(tmp_path)) == []  # one axis: no map
