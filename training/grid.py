"""Grid search over the information network: one training per (d_cr, k) cell, heat maps of final metrics.

    python -m training.grid --config config/train_flock2d.yaml --data data/flock2d.npz --out runs/grid_flock2d \\
        --d-cr 2 3.5 5 --k 3 6 9 [--set training.epochs=6]
    python -m training.grid --config config/train_boids3d.yaml --data data/boids3d.npz --out runs/grid_boids3d \
        --d-cr 1 2 3 --k 3 6 9 --rollouts 5      # boids are chaotic: 5 rollouts per test start

Parallel-safe and resumable: every cell trains in its own directory ``OUT/dcr<d>_k<k>/``,
claimed with an exclusive lock file; a finished cell (``cell.json``) is skipped, an
interrupted one resumes from its checkpoint (run the same command again). ``--workers N`` runs N
cells at a time on a local Ray (``--address``: a Ray cluster), as ``training.sweep`` does
(training/learning/sweep.py: a failed cell retried once, progress in ``OUT/sweep.log``, every
cell's status in ``OUT/sweep.json``); several copies of the command at once also share the cells.
``--collect`` only gathers finished cells; a finished cell evaluated with other
``--trajectories``/``--rollouts``/``--perturb`` is evaluated again without training. Writes
``heatmap_<metric>_<mean|median>.png``, ``results.json`` and ``summary.md`` under ``--out``
(boids3d: amd, POD-KLD, share of boids leaving the cube, share of rollouts with an escape,
subswarms). ``--seeds 0 1 2`` runs the whole grid once per training seed, each an ordinary grid
in ``OUT/seed<S>/``, and writes the mean and spread over the seeds of every cell's metrics to
``OUT/results.json``, ``OUT/summary.md`` and ``OUT/heatmap_<metric>_<stat>.png`` (the means).
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import sys
from typing import Any, Dict, List, Optional

import numpy as np
import torch

from knode_swarm_ros.core import get_scenario, load_policy
from knode_swarm_ros.core.cli import cli, parse_set
from knode_swarm_ros.core.errors import EXIT_RUN_FAILED, KnodeError
from training.assessment.scores import final_metrics, perturbed_starts, rollout_policy
from training.assessment.stats import mean_ci
from training.learning.config import load_config
from training.learning.records import write_json
from training.learning.sweep import Cell, check_files, run_cells
from training.learning.trainer import DivergenceError, Trainer

from .assessment import figures


def cell_name(d_cr: float, k: int) -> str:
    return f'dcr{d_cr:g}_k{k}'


def evaluate_cell(
    policy_path: str,
    data_path: str,
    trajectories: int,
    rollouts: int = 1,
    perturb: float = 1e-3,
    steps: Optional[int] = None,
) -> Dict[str, Any]:
    """Metrics of a cell's policy: ``rollouts`` rollouts from each of the first ``trajectories`` test
    starts (:func:`perturbed_starts`) over ``steps`` steps (default: the test trajectories' length),
    each compared with its start's ground truth. boids3d adds
    the share of boids leaving the cube (``escaped``) and the subswarms of :mod:`training.assessment.scaling`."""
    from knode_swarm_ros.core import load_trajectories

    policy = load_policy(policy_path)
    spec = get_scenario(policy.scenario)
    data = load_trajectories(data_path)
    truth = data.states[data.split('test')[:trajectories]]
    truth = truth if steps is None else truth[:, : steps + 1]
    z0 = perturbed_starts(truth[:, 0], rollouts, perturb, spec.position_dim)
    pred = rollout_policy(policy, z0, truth.shape[1] - 1)
    truth = np.repeat(truth, rollouts, axis=0)
    if spec.name == 'boids3d':
        from training.assessment.scaling import size_metrics

        return size_metrics(pred, truth, policy.dt)
    return final_metrics(spec, pred, truth, dt=policy.dt)


def run_cell(
    cfg: Dict[str, Any],
    data_path: str,
    cell_dir: str,
    test_trajectories: int,
    log=print,
    rollouts: int = 1,
    perturb: float = 1e-3,
    steps: Optional[int] = None,
) -> Optional[Dict]:
    """Train and evaluate one cell unless finished or claimed by another process.

    A finished cell evaluated with other settings (``cell.json`` → ``evaluation``) is evaluated
    again from its ``policy.pt`` without training.
    """
    done = os.path.join(cell_dir, 'cell.json')
    evaluation = {
        'trajectories': test_trajectories,
        'rollouts': rollouts,
        'perturb': perturb if rollouts > 1 else 0.0,
    }
    if steps is not None:
        evaluation['steps'] = steps
    previous = json.load(open(done)) if os.path.exists(done) else None
    if previous is not None and (previous.get('evaluation') == evaluation or 'error' in previous):
        return previous
    os.makedirs(cell_dir, exist_ok=True)
    lock = os.path.join(cell_dir, '.lock')
    try:
        fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
    except FileExistsError:
        log(f'{cell_dir}: claimed by another process (remove {lock} if that process died)')
        return None
    try:
        os.write(fd, str(os.getpid()).encode())
        os.close(fd)
        result: Dict[str, Any] = {
            'd_cr': cfg['policy']['d_cr'],
            'k': cfg['policy']['k'],
            'evaluation': evaluation,
        }
        if previous is None:
            resume = os.path.exists(os.path.join(cell_dir, 'checkpoint.pt'))
            try:
                Trainer(cfg, data_path, cell_dir, resume=resume, progress=False, log=lambda *a: None).run()
            except DivergenceError as exc:
                result['error'] = str(exc)
        summary = os.path.join(cell_dir, 'summary.json')
        if os.path.exists(summary):
            result['training'] = {
                k: v
                for k, v in json.load(open(summary)).items()
                if k in ('epochs', 'selected', 'train_seconds')
            }
        if 'error' not in result:
            result.update(
                evaluate_cell(
                    os.path.join(cell_dir, 'policy.pt'),
                    data_path,
                    test_trajectories,
                    rollouts,
                    perturb,
                    steps,
                )
            )
        write_json(done, result)
        log(f'{cell_dir}: done')
        return result
    finally:
        if os.path.exists(lock):
            os.unlink(lock)


#: Heat-map metrics per scenario: name -> statistics. ``left_cube``: share of rollouts in which a boid
#: leaves the cube (a 0/1 per rollout, so only its mean).
GRID_METRICS = {
    'flock2d': {'avd_final': ('mean', 'median'), 'amd_final': ('mean', 'median')},
    'boids3d': {
        'amd_final': ('mean', 'median'),
        'pod_kld': ('mean', 'median'),
        'escaped': ('mean',),
        'left_cube': ('mean',),
        'subswarms': ('mean', 'median'),
    },
}


def _cell_values(cell: Dict[str, Any], name: str) -> Optional[np.ndarray]:
    if name == 'left_cube':  # boids3d cells: no_boid_leaves (training.assessment.scaling.leaving)
        key = 'no_boid_leaves' if 'no_boid_leaves' in cell else 'stays_inside'
        if key in cell:
            return 1.0 - np.asarray(cell[key], dtype=np.float64)
    return np.asarray(cell[name], dtype=np.float64) if name in cell else None


def _table_lines(title: str, d_crs: List[float], ks: List[int], text) -> List[str]:
    """A markdown table of a grid, one row per d_cr and one column per k, under ``title``;
    ``text(i, j)`` is cell (d_crs[i], ks[j])'s text."""
    lines = [title, '', '| d_cr \\ k | ' + ' | '.join(map(str, ks)) + ' |', '| --- ' * (len(ks) + 1) + '|']
    for i, d in enumerate(d_crs):
        lines.append(f'| {d:g} | ' + ' | '.join(text(i, j) for j in range(len(ks))) + ' |')
    return lines + ['']


def _truth_lines(truth: Optional[Dict[str, float]]) -> List[str]:
    return ['Ground truth: ' + ', '.join(f'{k} {v:.3g}' for k, v in truth.items())] if truth else []


def collect(out: str, scenario: str, d_crs: List[float], ks: List[int]) -> Dict[str, Any]:
    cells = {}
    for d in d_crs:
        for k in ks:
            path = os.path.join(out, cell_name(d, k), 'cell.json')
            if os.path.exists(path):
                cells[(d, k)] = json.load(open(path))
    tables: Dict[str, Any] = {}
    spread: Dict[str, Any] = {}
    for name, stats in GRID_METRICS[scenario].items():
        quart = np.full((len(d_crs), len(ks), 2), np.nan)
        for stat in stats:
            fn = np.mean if stat == 'mean' else np.median
            grid = np.full((len(d_crs), len(ks)), np.nan)
            for i, d in enumerate(d_crs):
                for j, k in enumerate(ks):
                    c = cells.get((d, k))
                    v = None if c is None else _cell_values(c, name)
                    if v is not None and v.size:
                        grid[i, j] = fn(v)
                        quart[i, j] = np.percentile(v, [25, 75])
            tables[f'{name}_{stat}'] = grid.tolist()
            figures.heatmap(
                os.path.join(out, f'heatmap_{name}_{stat}.png'),
                grid,
                d_crs,
                ks,
                f'{stat} {name.replace("_final", " (final)")}',
            )
        spread[name] = quart.tolist()
    truth = next((c for c in cells.values() if 'truth_amd_final' in c), None)
    results = {
        'scenario': scenario,
        'd_cr': d_crs,
        'k': ks,
        'tables': tables,
        'quartiles': spread,
        'finished': [cell_name(d, k) for (d, k) in cells],
        'evaluation': {cell_name(d, k): c.get('evaluation') for (d, k), c in cells.items()},
        'training': {cell_name(d, k): c.get('training') for (d, k), c in cells.items()},
        'errors': {cell_name(d, k): c['error'] for (d, k), c in cells.items() if 'error' in c},
        'truth': None
        if truth is None
        else {key: float(np.mean(truth[key])) for key in truth if key.startswith('truth_')},
    }
    write_json(os.path.join(out, 'results.json'), results)
    lines = [f'# Grid search: {scenario}', '', f'{len(cells)} of {len(d_crs) * len(ks)} cells finished.', '']
    for key, grid in tables.items():
        name = key.rsplit('_', 1)[0]

        def text(i: int, j: int) -> str:
            v = grid[i][j]
            if not np.isfinite(v):
                return '-'
            if key.endswith('median'):
                return f'{v:.3g} [{spread[name][i][j][0]:.3g}, {spread[name][i][j][1]:.3g}]'
            return f'{v:.3g}'

        title = f'## {key}' + (' [quartiles over rollouts]' if key.endswith('median') else '')
        lines += _table_lines(title, d_crs, ks, text)
    lines += _truth_lines(results['truth'])
    open(os.path.join(out, 'summary.md'), 'w').write('\n'.join(lines) + '\n')
    return results


def collect_seeds(out: str, seeds: List[int], per_seed: List[Dict[str, Any]]) -> Dict[str, Any]:
    """Mean and spread over training seeds of every table of the per-seed grids ``per_seed``
    (:func:`collect`'s results, one per seed, run in ``OUT/seed<S>``).

    A cell's value for a seed is that seed's statistic over its rollouts (e.g. the mean final amd);
    over the seeds: the mean, the sample standard deviation and the 95 % t half-width
    (:func:`~training.assessment.stats.mean_ci`), with the number of seeds that finished the cell.
    """
    first = per_seed[0]
    d_crs, ks = first['d_cr'], first['k']
    tables: Dict[str, Any] = {}
    for key in first['tables']:
        stack = np.array([r['tables'][key] for r in per_seed], dtype=np.float64)  # [seeds, d_cr, k]
        mean, sd, half = (np.full(stack.shape[1:], np.nan) for _ in range(3))
        n = np.isfinite(stack).sum(axis=0)
        for i, j in np.ndindex(*stack.shape[1:]):
            v = stack[:, i, j][np.isfinite(stack[:, i, j])]
            if v.size:
                m, h = mean_ci(v, t=True)
                mean[i, j], half[i, j] = m, h
                sd[i, j] = v.std(ddof=1) if v.size > 1 else 0.0
        tables[key] = {'mean': mean.tolist(), 'sd': sd.tolist(), 'ci95': half.tolist(), 'seeds': n.tolist()}
        figures.heatmap(
            os.path.join(out, f'heatmap_{key}.png'),
            mean,
            d_crs,
            ks,
            f'{key.replace("_final", " (final)")}, mean over {len(seeds)} seeds',
        )
    results = {'scenario': first['scenario'], 'd_cr': d_crs, 'k': ks, 'seeds': seeds, 'tables': tables}
    results['truth'] = first.get('truth')
    write_json(os.path.join(out, 'results.json'), results)
    lines = [
        f'# Grid search: {first["scenario"]}, {len(seeds)} training seeds ({", ".join(map(str, seeds))})',
        '',
        'Each cell: the mean over the seeds of the per-seed statistic ± the 95 % t half-width over the '
        'seeds and their standard deviation; a cell fewer seeds finished says how many.',
        '',
    ]
    for key, table in tables.items():

        def text(i: int, j: int) -> str:
            mean, half, sd, count = (table[f][i][j] for f in ('mean', 'ci95', 'sd', 'seeds'))
            if not count:
                return '-'
            txt = f'{mean:.3g}' if count == 1 else f'{mean:.3g} ± {half:.2g} (sd {sd:.2g})'
            return txt + ('' if count == len(seeds) else f' [{count} seeds]')

        lines += _table_lines(f'## {key}', d_crs, ks, text)
    lines += _truth_lines(results['truth'])
    open(os.path.join(out, 'summary.md'), 'w').write('\n'.join(lines) + '\n')
    return results


@cli('python -m training.grid')
def main(argv: Optional[List[str]] = None) -> int:
    parser = argparse.ArgumentParser(prog='python -m training.grid', description=__doc__.split('\n\n')[0])
    parser.add_argument('--config', required=True)
    parser.add_argument('--data', required=True)
    parser.add_argument('--out', required=True)
    parser.add_argument('--d-cr', type=float, nargs='+', default=[2.0, 3.5, 5.0])
    parser.add_argument('--k', type=int, nargs='+', default=[3, 6, 9])
    parser.add_argument('--set', action='append', metavar='SECTION.KEY=VALUE', help='override a config field')
    parser.add_argument('--trajectories', type=int, default=20, help='test trajectories per cell evaluation')
    parser.add_argument(
        '--rollouts',
        type=int,
        default=1,
        help='rollouts per test start (copies > 0 with perturbed positions; default 1)',
    )
    parser.add_argument(
        '--perturb', type=float, default=1e-3, help='std of the position perturbation (default 1e-3)'
    )
    parser.add_argument(
        '--steps', type=int, default=None, help='evaluation steps (default: test trajectory length)'
    )
    parser.add_argument(
        '--seeds',
        type=int,
        nargs='+',
        default=[],
        help='run the grid once per training seed (OUT/seed<S>) and report mean and spread over them',
    )
    parser.add_argument('--collect', action='store_true', help='only gather finished cells')
    parser.add_argument(
        '--workers', type=int, default=1, help='cells at a time (default 1: in this process; more: Ray)'
    )
    parser.add_argument(
        '--address', default=None, help='a Ray cluster (ray://host:10001) instead of a local Ray'
    )
    args = parser.parse_args(argv)
    for name in ('trajectories', 'rollouts', 'steps'):
        if getattr(args, name) is not None and getattr(args, name) < 1:
            raise KnodeError(f'--{name} must be >= 1, got {getattr(args, name)}')
    if not (np.isfinite(args.perturb) and args.perturb >= 0):
        raise KnodeError(f'--perturb must be a finite number >= 0, got {args.perturb}')
    base = parse_set(args.set)
    if args.seeds and 'seed' in base:
        raise KnodeError('--seeds and --set seed=... both set the training seed: give one of them')
    cfg0 = load_config(args.config, base)
    torch.set_num_threads(cfg0['training']['threads'])
    # one grid per training seed, each in its own directory (OUT itself without --seeds)
    grids = [(os.path.join(args.out, f'seed{s}'), {**base, 'seed': s}) for s in args.seeds] or [
        (args.out, base)
    ]
    failed = []
    if not args.collect:
        check_files('--data', [args.data])
        # Ray's workers may start elsewhere (a cluster): absolute paths for them
        ray = args.workers > 1 or args.address
        data = os.path.abspath(args.data) if ray else args.data
        cells = []
        for grid_out, overrides in grids:
            out = os.path.abspath(grid_out) if ray else grid_out
            prefix = '' if not args.seeds else f'seed{overrides["seed"]}/'
            for d in args.d_cr:
                for k in args.k:
                    cfg = load_config(args.config, {**overrides, 'policy.d_cr': d, 'policy.k': k})
                    run_dir = os.path.join(out, cell_name(d, k))
                    job = functools.partial(
                        run_cell,
                        cfg,
                        data,
                        run_dir,
                        args.trajectories,
                        rollouts=args.rollouts,
                        perturb=args.perturb,
                        steps=args.steps,
                    )
                    values = {'policy.d_cr': d, 'policy.k': k}
                    if args.seeds:
                        values['seed'] = overrides['seed']
                    cells.append(Cell(prefix + cell_name(d, k), values, run_dir, job))
        axes = {'policy.d_cr': args.d_cr, 'policy.k': args.k}
        if args.seeds:
            axes['seed'] = args.seeds
        header = {'config': args.config, 'data': args.data, 'set': base, 'axes': axes}
        records = run_cells(cells, args.out, args.workers, args.address, header=header)
        failed = [r['name'] for r in records if r['status'] == 'failed']
    per_seed = [collect(grid_out, cfg0['scenario'], args.d_cr, args.k) for grid_out, _ in grids]
    if args.seeds:
        collect_seeds(args.out, args.seeds, per_seed)
    finished = sum(len(r['finished']) for r in per_seed)
    print(f'{finished} cells finished; wrote {args.out}/results.json and heat maps')
    if failed:
        print(f'failed twice: {", ".join(failed)} (see {args.out}/sweep.json)', file=sys.stderr)
        return EXIT_RUN_FAILED
    return 0


if __name__ == '__main__':
    sys.exit(main())
