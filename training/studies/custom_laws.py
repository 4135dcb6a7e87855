"""The generic recipe on the swarm laws of our own (:mod:`training.studies.laws`): tracks ->
``training.import_tracks`` -> ``training.train --config config/train_custom.yaml`` -> held-out
starts at 10 and 30 robots, learnt against the law (docs/scenarios.md, "Show it on swarms of
your own").

    python -m training.studies.custom_laws --out runs/laws                     # every law
    python -m training.studies.custom_laws --laws mill2d --out runs/laws --max-minutes 5
    python -m training.studies.custom_laws --laws mill2d --out runs/noise --noise-mm 0 2 10 \
        --rate 30 120 --train-seeds 0 1 --eval-robots 10
    python -m training.studies.custom_laws --out runs/flat --set policy.encoder=flat --starts 16
    python -m training.studies.custom_laws --laws mill2d --out runs/laws --track-robots 10 20

With ``--noise-mm`` the tracks are a mocap recording of the law instead (:func:`write_noisy_tracks`:
positions only, sampled at ``--rate``, Gaussian noise, jittered stamps, dropped samples), so the
importer's smoother derives the velocities from noisy poses; the folder is then ``OUT/LAW_Nmm_RHz``,
one per noise level and rate, and ``OUT/LAW_noise.md`` / ``OUT/LAW_noise.png`` compare them
(:mod:`training.studies.law_noise`: the import against the law, the order parameters against the
law and, per held-out start, against the 0-mm recording of the same rate and seed); with
``--track-robots`` the folders, results keys and tables carry its tail (``LAW_Nmm_RHz_tracks20``).
``--train-seeds`` trains once per seed on each import (``run_seedK/``, ``eval_nN_seedK/``; the
recipe's own seed keeps ``run/``).
``--track-robots 10 20`` tracks swarms of each size (``--trajectories`` of each, ``csv_nN/``,
``tracks_nN.npz``) and trains one policy on all of them, in ``OUT/LAW_tracks10+20``: a law
whose forces depend on the swarm's size shows how only in tracks of more than one size.

A step whose output exists is skipped (the tracks once imported, a training with its
``training.json``, an evaluation of it), so the same command resumes a killed study or extends it
by more cases or seeds.

Per law under ``OUT/LAW/``: ``scenario.yaml``, ``csv/run_*.csv`` (10 robots, written by the law's
simulator), ``tracks.npz`` (the import), ``run/`` (the training run), ``eval_n10``/``eval_n30``
(``orders.png``, ``results.json``) and ``summary.md``; ``OUT/results.json`` gathers the goals
of every law and case run into OUT (``seeds``: one entry per training seed).
Goals (reported, not enforced): at 10 robots the nearest-neighbour distance within 15 % of the
law's, polarisation and rotation order within 0.10; at 30 robots 25 % and 0.15; no more escapes
than the law.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import time
from typing import Any, Dict, List, Optional

import numpy as np
import yaml

from knode_swarm_ros.core.cli import cli
from knode_swarm_ros.core.errors import KnodeError
from training.assessment.order import order_lines
from training.learning.config import load_config
from training.learning.records import write_json

from .law_goals import evaluate_law
from .law_noise import import_against_law, law_at, noise_figure, noise_table
from .laws import LAWS, RECIPE, Law, initial_states, simulate


def write_tracks(law: Law, folder: str, trajectories: int, robots: int, seed: int) -> List[str]:
    """One long-format CSV per trajectory (t, id, x, y[, z][, vx, vy[, vz] or hx, hy[, hz]]);
    returns the paths."""
    spec = law.scenario
    states = simulate(law, initial_states(law, trajectories, robots, seed), law.steps)
    layout, dims = spec.state_layout, spec.dimensions  # ('px', 'py', 'vx', 'vy'): columns x, y, vx, vy
    header = ['t', 'id', *(name[1:] for name in layout[:dims]), *layout[dims:]]
    os.makedirs(folder, exist_ok=True)
    paths = []
    for s in range(trajectories):
        path = os.path.join(folder, f'run_{s:02d}.csv')
        with open(path, 'w', newline='') as fh:
            w = csv.writer(fh)
            w.writerow(header)
            for t in range(states.shape[1]):
                for i in range(robots):
                    w.writerow([f'{t * spec.dt:.6f}', 10 + 3 * i, *(f'{x:.9g}' for x in states[s, t, i])])
        paths.append(path)
    return paths


def write_noisy_tracks(
    law: Law,
    folder: str,
    trajectories: int,
    robots: int,
    seed: int,
    noise_m: float,
    rate_hz: float,
    jitter_s: float = 0.0005,
    drop: float = 0.01,
) -> List[str]:
    """Like :func:`write_tracks`, as a motion-capture system records the law: positions only
    (t, id, x, y[, z]) sampled at ``rate_hz``, Gaussian noise of ``noise_m`` per axis, stamps
    jittered by ``jitter_s`` (std) and a fraction ``drop`` of the samples missing."""
    spec = law.scenario
    d = spec.dimensions
    states = simulate(law, initial_states(law, trajectories, robots, seed), law.steps)  # [S, T+1, n, d]
    times = np.arange(0.0, law.steps * spec.dt, 1.0 / rate_hz)
    rng = np.random.default_rng(seed + 7919)
    axes = 'xyz'[:d]
    os.makedirs(folder, exist_ok=True)
    paths = []
    for e in range(trajectories):
        pos = law_at(law, states[e], times)[0]
        pos = pos + rng.normal(0.0, noise_m, pos.shape)
        stamps = times[:, None] + rng.normal(0.0, jitter_s, (len(times), robots))
        kept = rng.random((len(times), robots)) >= drop
        kept[0] = True  # every robot is seen at the start of the episode
        path = os.path.join(folder, f'run_{e:02d}.csv')
        with open(path, 'w', newline='') as fh:
            w = csv.writer(fh)
            w.writerow(['t', 'id', *axes])
            for t in range(len(times)):
                for i in np.flatnonzero(kept[t]):
                    w.writerow([f'{stamps[t, i]:.6f}', 10 + 3 * i, *(f'{x:.9g}' for x in pos[t, i])])
        paths.append(path)
    return paths


def _run(argv: List[str], log) -> None:
    env = dict(os.environ)
    log('$ ' + ' '.join(argv))
    subprocess.run([sys.executable, '-m', *argv], check=True, env=env)


def _recipe_seed(config: str) -> int:
    with open(config) as fh:
        return int((yaml.safe_load(fh) or {}).get('seed', 0))


def _train_and_evaluate(
    law: Law, folder: str, data: List[str], seed: int, args, log
) -> Optional[Dict[str, Any]]:
    """One training on ``data`` and its evaluation: ``run/`` with the recipe's seed, ``run_seedK/``
    with another; a step whose output exists is skipped, so a killed study resumes. With
    ``--report``, None where the training or an evaluation has not run."""
    tail = '' if seed == _recipe_seed(args.config) else f'_seed{seed}'
    run_dir = os.path.join(folder, 'run' + tail)
    policy = os.path.join(run_dir, 'policy.pt')
    record = os.path.join(folder, f'training{tail}.json')
    trained = not (os.path.exists(policy) and os.path.exists(record))
    evaluated = [
        os.path.exists(os.path.join(folder, f'eval_n{n}{tail}', 'results.json')) for n in args.eval_robots
    ]
    if args.report and (trained or not all(evaluated)):
        return None
    if args.evaluate_only and trained:
        raise KnodeError(f'--evaluate-only: no trained policy in {run_dir} (its policy.pt and {record})')
    if trained:
        train = [
            'training.train',
            '--config',
            args.config,
            '--data',
            *data,
            '--out',
            run_dir,
            '--no-progress',
        ]
        train += ['--set', f'training.max_minutes={args.max_minutes}']
        train += ['--set', f'seed={seed}'] if tail else []
        for item in args.set or []:
            train += ['--set', item]
        train += ['--overwrite'] if os.path.exists(run_dir) else []  # a killed training starts again
        load0, t0 = os.getloadavg()[0], time.perf_counter()
        _run(train, log)
        write_json(
            record,
            {'train_wall_seconds': round(time.perf_counter() - t0, 1), 'load': [load0, os.getloadavg()[0]]},
        )
    result: Dict[str, Any] = {'law': law.name, 'seed': seed, **_read_json(record)}
    result['load_after_training'] = result['load'][1]
    for robots in args.eval_robots:
        out = os.path.join(folder, f'eval_n{robots}{tail}')
        if not trained and not args.evaluate_only and os.path.exists(os.path.join(out, 'results.json')):
            r = _read_json(os.path.join(out, 'results.json'))
        else:
            r = evaluate_law(law, policy, out, robots, args.starts, args.seed + 1000, args.track_robots)
        result[f'n{robots}'] = r
        log(f'{law.name}{tail}, {robots} robots: ' + ', '.join(f'{k}={v}' for k, v in r['goals'].items()))
    lines = [f'# {law.name}: learnt (config/train_custom.yaml) against the law', '']
    lines.append(
        f'- training {result["train_wall_seconds"]:.0f} s wall clock, load average after it {result["load"][1]:.1f}'
    )
    for robots in args.eval_robots:
        lines += ['', f'## {robots} robots, {args.starts} held-out starts', ''] + order_lines(
            result[f'n{robots}']['orders']
        )
    with open(os.path.join(folder, f'summary{tail}.md'), 'w') as fh:
        fh.write('\n'.join(lines) + '\n')
    return result


def _read_json(path: str) -> Dict[str, Any]:
    with open(path) as fh:
        return json.load(fh)


def _tracks_tail(sizes: List[int]) -> str:
    """The folder's (and results key's) tail for tracks of other sizes than 10 robots alone."""
    return '' if sizes == [10] else '_tracks' + '+'.join(map(str, sizes))


def run_law(
    law: Law, out: str, args, log=print, noise_mm: Optional[float] = None, rate: float = 120.0
) -> Optional[Dict[str, Any]]:
    """One law (``noise_mm`` None: its exact tracks) or one recording of it: tracks, import, one
    training per ``--train-seeds`` (the recipe's seed without) and their evaluations."""
    noisy = noise_mm is not None
    folder = os.path.join(out, f'{law.name}_{noise_mm:g}mm_{rate:g}hz' if noisy else law.name)
    sizes = args.track_robots
    folder += _tracks_tail(sizes)
    # one file per tracked swarm size: the trainer takes them together (one size-free policy)
    data = [os.path.join(folder, 'tracks.npz' if n == 10 else f'tracks_n{n}.npz') for n in sizes]
    if args.report and not all(map(os.path.exists, data)):
        return None
    os.makedirs(folder, exist_ok=True)
    scenario = os.path.join(folder, 'scenario.yaml')
    with open(scenario, 'w') as fh:
        yaml.safe_dump(law.scenario.to_dict(), fh, sort_keys=False)
    for n, path in zip(sizes, data):
        if os.path.exists(path):
            continue
        csv_dir = os.path.join(folder, 'csv' if n == 10 else f'csv_n{n}')
        if noisy:
            csvs = write_noisy_tracks(law, csv_dir, args.trajectories, n, args.seed, noise_mm / 1000, rate)
        else:
            csvs = write_tracks(law, csv_dir, args.trajectories, n, args.seed)
        _run(['training.import_tracks', *csvs, '--scenario', scenario, '--out', path], log)
    seeds = args.train_seeds or [_recipe_seed(args.config)]
    results = [r for seed in seeds if (r := _train_and_evaluate(law, folder, data, seed, args, log))]
    if not results:
        return None
    # the first seed's at the top, as before; every seed's in seeds
    result = dict(results[0], seeds=results, track_robots=sizes)
    if noisy:
        imp = import_against_law(law, data[0], args.trajectories, sizes[0], args.seed)
        log(
            f'{os.path.basename(folder)}: noise estimate {imp["noise_estimate"] * 1e3:.3g} mm, import against '
            f'the law: positions {imp["position_rms"] * 1e3:.3g} mm, velocities {imp["velocity_rms"] * 1e3:.3g} mm/s, '
            f'headings {imp.get("heading_rms", float("nan")) * 1e3:.3g} mrad rms'
        )
        result.update(noise_mm=noise_mm, rate=rate, **{'import': imp})
    return result


def _noise_cases(results: Dict[str, Any]) -> List[Dict[str, Any]]:
    """The rows of :func:`law_noise.noise_table`: one per recording and training seed."""
    rows = []
    for r in results.values():
        for s in r.get('seeds', []):
            rows.append(
                {
                    'noise_mm': r['noise_mm'],
                    'rate': r['rate'],
                    'seed': s['seed'],
                    'import': r['import'],
                    'eval': s,
                    'train_seconds': s['train_wall_seconds'],
                    'load': s['load'],
                }
            )
    return rows


@cli('python -m training.studies.custom_laws')
def main(argv: Optional[List[str]] = None) -> int:
    parser = argparse.ArgumentParser(
        prog='python -m training.studies.custom_laws', description=__doc__.split('\n\n')[0]
    )
    parser.add_argument('--laws', nargs='+', default=list(LAWS), choices=list(LAWS))
    parser.add_argument('--out', required=True)
    parser.add_argument('--config', default=RECIPE, help='training recipe (default train_custom.yaml)')
    parser.add_argument(
        '--trajectories', type=int, default=12, help='training tracks per law and tracked swarm size'
    )
    parser.add_argument(
        '--track-robots',
        type=int,
        nargs='+',
        default=[10],
        metavar='N',
        help='robots in the tracked swarm (several: tracks of each size, one training on all; '
        'the folder is then LAW_tracksN+M)',
    )
    parser.add_argument('--max-minutes', type=float, default=10.0, help='training.max_minutes of each run')
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument(
        '--noise-mm',
        type=float,
        nargs='+',
        default=None,
        help='record the law as a mocap system: noise std, mm (several: one case each)',
    )
    parser.add_argument(
        '--rate',
        type=float,
        nargs='+',
        default=[120.0],
        help='sample rate of the noisy recording, Hz (several: each with every --noise-mm)',
    )
    parser.add_argument(
        '--train-seeds',
        type=int,
        nargs='+',
        default=None,
        metavar='SEED',
        help="one training per seed on each import (default the recipe's seed)",
    )
    parser.add_argument('--eval-robots', type=int, nargs='+', default=[10, 30], help='held-out swarm sizes')
    parser.add_argument(
        '--starts',
        type=int,
        default=32,
        help='held-out starts per swarm size (32 resolve ~0.1 on a bistable law)',
    )
    parser.add_argument(
        '--set', action='append', metavar='KEY=VALUE', help='a recipe field for training (repeatable)'
    )
    parser.add_argument(
        '--evaluate-only',
        action='store_true',
        help='train nothing: evaluate the trained policies again (with --starts)',
    )
    parser.add_argument(
        '--report',
        action='store_true',
        help='import and train nothing: rewrite results.json and the noise table and figure from '
        'the cases and seeds already run, leaving out the others',
    )
    args = parser.parse_args(argv)
    if args.noise_mm is not None and (min(args.noise_mm) < 0 or min(args.rate) <= 0):
        parser.error(f'--noise-mm must be >= 0 and --rate > 0, got {args.noise_mm} and {args.rate}')
    if min(args.track_robots) < 2:
        raise KnodeError(f'--track-robots must be at least 2 robots each, got {args.track_robots}')
    args.track_robots = sorted(set(args.track_robots))
    load_config(args.config)  # a bad recipe is refused (exit 2) before any law is simulated
    # an earlier invocation's laws and cases stay (this one replaces those it runs again)
    summary = os.path.join(args.out, 'results.json')
    results: Dict[str, Any] = _read_json(summary) if os.path.exists(summary) and not args.report else {}
    for name in args.laws:
        if args.noise_mm is None:
            r = run_law(LAWS[name], args.out, args)
            if r is not None:
                results[name + _tracks_tail(args.track_robots)] = r
            write_json(summary, results)
            continue
        for rate in args.rate:
            for noise_mm in args.noise_mm:
                r = run_law(LAWS[name], args.out, args, noise_mm=noise_mm, rate=rate)
                if r is None:
                    continue
                results[f'{name}_{noise_mm:g}mm_{rate:g}hz' + _tracks_tail(args.track_robots)] = r
                write_json(summary, results)
                # one noise table per tracked swarm size (results written before the key: 10 robots)
                cases = _noise_cases(
                    {
                        k: v
                        for k, v in results.items()
                        if v['law'] == name
                        and 'noise_mm' in v
                        and v.get('track_robots', [10]) == args.track_robots
                    }
                )
                if not cases:
                    continue
                robots = args.eval_robots[0]
                stem = os.path.join(args.out, name + _tracks_tail(args.track_robots) + '_noise')
                with open(stem + '.md', 'w') as fh:
                    fh.write(noise_table(cases, robots))
                noise_figure(
                    cases,
                    stem + '.png',
                    robots,
                    f'{name}: learnt from noisy recordings, {robots} robots, {args.starts} held-out starts',
                )
    return 0


if __name__ == '__main__':
    sys.exit(main())
