"""The generic recipe on three swarm laws of our own (:mod:`training.studies.laws`): tracks ->
``training.import_tracks`` -> ``training.train --config config/train_custom.yaml`` -> held-out
starts at 10 and 30 robots, learnt against the law (docs/scenarios.md, "Show it on swarms of
your own").

    python -m training.studies.custom_laws --out runs/laws                     # all three laws
    python -m training.studies.custom_laws --laws mill2d --out runs/laws --max-minutes 5
    python -m training.studies.custom_laws --laws mill2d --out runs/noise --noise-mm 2 --rate 120
    python -m training.studies.custom_laws --out runs/set --set policy.encoder=set --starts 32

With ``--noise-mm`` the tracks are a mocap recording of the law instead (:func:`write_noisy_tracks`:
positions only, sampled at ``--rate``, Gaussian noise, jittered stamps, dropped samples), so the
importer's smoother derives the velocities from noisy poses; the folder is then ``OUT/LAW_Nmm_RHz``.

Per law under ``OUT/LAW/``: ``scenario.yaml``, ``csv/run_*.csv`` (10 robots, written by the law's
simulator), ``tracks.npz`` (the import), ``run/`` (the training run), ``eval_n10``/``eval_n30``
(``orders.png``, ``results.json``) and ``summary.md``; ``OUT/results.json`` gathers the goals.
Goals (reported, not enforced): at 10 robots the nearest-neighbour distance within 15 % of the
law's, polarisation and rotation order within 0.10; at 30 robots 25 % and 0.15; no more escapes
than the law.
"""

from __future__ import annotations

import argparse
import csv
import os
import subprocess
import sys
import time
from typing import Any, Dict, List, Optional

import numpy as np
import yaml

from knode_swarm_ros.core import load_policy
from knode_swarm_ros.core.cli import cli
from training.assessment.order import compare_orders, order_figure, order_lines
from training.assessment.scores import rollout_policy
from training.learning.config import load_config
from training.learning.records import write_json

from .laws import LAWS, Law, initial_states, simulate

GOALS = {10: (0.15, 0.10), 30: (0.25, 0.15)}  # robots -> (relative nn error, order parameter error)
RECIPE = os.path.join(os.path.dirname(__file__), '..', '..', 'config', 'train_custom.yaml')


def write_tracks(law: Law, folder: str, trajectories: int, robots: int, seed: int) -> List[str]:
    """One long-format CSV per trajectory (t, id, x, y[, z][, vx, vy[, vz]]); returns the paths."""
    spec = law.scenario
    states = simulate(law, initial_states(law, trajectories, robots, seed), law.steps)
    axes = 'xyz'[: spec.dimensions]
    header = ['t', 'id', *axes] + ([f'v{a}' for a in axes] if spec.velocity is not None else [])
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
    if spec.velocity is None:
        raise ValueError(f'{law.name}: positions only; the noisy recording needs a velocity state')
    d = spec.dimensions
    states = simulate(law, initial_states(law, trajectories, robots, seed), law.steps)  # [S, T+1, n, 2d]
    p, v = states[..., :d], states[..., d:]
    times = np.arange(0.0, law.steps * spec.dt, 1.0 / rate_hz)
    k = np.minimum((times / spec.dt).astype(int), law.steps - 1)
    s = (times / spec.dt - k)[:, None, None]
    # cubic Hermite on positions and velocities: exact for the zero-order hold's quadratic steps
    h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
    rng = np.random.default_rng(seed + 7919)
    axes = 'xyz'[:d]
    os.makedirs(folder, exist_ok=True)
    paths = []
    for e in range(trajectories):
        pe, ve = p[e], v[e]
        pos = h00 * pe[k] + h10 * spec.dt * ve[k] + h01 * pe[k + 1] + h11 * spec.dt * ve[k + 1]
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


def evaluate_law(law: Law, policy_path: str, out: str, robots: int, starts: int, seed: int) -> Dict[str, Any]:
    """Learnt against the law from ``starts`` held-out starts of ``robots`` robots."""
    spec = law.scenario
    policy = load_policy(policy_path)
    z0 = initial_states(law, starts, robots, seed)
    truth = simulate(law, z0, law.steps)
    t0 = time.perf_counter()
    pred = rollout_policy(policy, z0, law.steps)
    orders = compare_orders(spec, pred, truth, spec.dt)
    os.makedirs(out, exist_ok=True)
    order_figure(
        os.path.join(out, 'orders.png'),
        spec,
        pred,
        truth,
        spec.dt,
        f'{law.name}: {robots} robots, {starts} held-out starts, learnt on 10',
    )
    rel_tol, order_tol = GOALS.get(robots, GOALS[30])
    mean = {name: (e['learnt']['mean'], e['observed']['mean']) for name, e in orders.items()}
    nn_rel = abs(mean['nn_distance'][0] - mean['nn_distance'][1]) / mean['nn_distance'][1]
    goals = {
        'finite': bool(np.all(np.isfinite(pred))),
        'nn_rel_error': float(nn_rel),
        f'nn_within_{int(rel_tol * 100)}%': bool(nn_rel <= rel_tol),
        'polarisation_error': float(abs(mean['polarisation'][0] - mean['polarisation'][1])),
        'rotation_error': float(abs(mean['rotation_order'][0] - mean['rotation_order'][1])),
    }
    goals[f'polarisation_within_{order_tol}'] = goals['polarisation_error'] <= order_tol
    goals[f'rotation_within_{order_tol}'] = goals['rotation_error'] <= order_tol
    if 'escapes' in mean:
        goals['escapes_not_more'] = bool(
            sum(orders['escapes']['per_rollout']['learnt'])
            <= sum(orders['escapes']['per_rollout']['observed'])
        )
    result = {
        'law': law.name,
        'robots': robots,
        'starts': starts,
        'seed': seed,
        'steps': law.steps,
        'rollout_seconds': round(time.perf_counter() - t0, 1),
        'orders': orders,
        'goals': goals,
    }
    write_json(os.path.join(out, 'results.json'), result)
    return result


def run_law(law: Law, out: str, args, log=print) -> Dict[str, Any]:
    noisy = args.noise_mm is not None
    folder = os.path.join(out, f'{law.name}_{args.noise_mm:g}mm_{args.rate:g}hz' if noisy else law.name)
    os.makedirs(folder, exist_ok=True)
    scenario = os.path.join(folder, 'scenario.yaml')
    with open(scenario, 'w') as fh:
        yaml.safe_dump(law.scenario.to_dict(), fh, sort_keys=False)
    if noisy:
        csvs = write_noisy_tracks(
            law,
            os.path.join(folder, 'csv'),
            args.trajectories,
            10,
            args.seed,
            args.noise_mm / 1000,
            args.rate,
        )
    elif args.evaluate_only and os.path.isfile(os.path.join(folder, 'run', 'policy.pt')):
        csvs = []  # the tracks and the policy are there already
    else:
        csvs = write_tracks(law, os.path.join(folder, 'csv'), args.trajectories, 10, args.seed)
    data = os.path.join(folder, 'tracks.npz')
    run_dir = os.path.join(folder, 'run')
    t0 = time.perf_counter()
    if not (args.evaluate_only and os.path.isfile(os.path.join(run_dir, 'policy.pt'))):
        _run(['training.import_tracks', *csvs, '--scenario', scenario, '--out', data], log)
        train = ['training.train', '--config', args.config, '--data', data, '--out', run_dir, '--no-progress']
        train += ['--set', f'training.max_minutes={args.max_minutes}']
        for item in args.set or []:
            train += ['--set', item]
        _run(train, log)
    train_s = time.perf_counter() - t0
    load = os.getloadavg()
    result: Dict[str, Any] = {
        'law': law.name,
        'train_wall_seconds': round(train_s, 1),
        'load_after_training': load,
    }
    for robots in args.eval_robots:
        r = evaluate_law(
            law,
            os.path.join(run_dir, 'policy.pt'),
            os.path.join(folder, f'eval_n{robots}'),
            robots,
            args.starts,
            args.seed + 1000,
        )
        result[f'n{robots}'] = r
        log(f'{law.name}, {robots} robots: ' + ', '.join(f'{k}={v}' for k, v in r['goals'].items()))
    lines = [f'# {law.name}: learnt (config/train_custom.yaml) against the law', '']
    lines.append(f'- training {train_s:.0f} s wall clock, load average after it {load[0]:.1f}')
    for robots in args.eval_robots:
        lines += ['', f'## {robots} robots, {args.starts} held-out starts', ''] + order_lines(
            result[f'n{robots}']['orders']
        )
    with open(os.path.join(folder, 'summary.md'), 'w') as fh:
        fh.write('\n'.join(lines) + '\n')
    return result


@cli('python -m training.studies.custom_laws')
def main(argv: Optional[List[str]] = None) -> int:
    parser = argparse.ArgumentParser(
        prog='python -m training.studies.custom_laws', description=__doc__.split('\n\n')[0]
    )
    parser.add_argument('--laws', nargs='+', default=list(LAWS), choices=list(LAWS))
    parser.add_argument('--out', required=True)
    parser.add_argument(
        '--config', default=os.path.normpath(RECIPE), help='training recipe (default train_custom.yaml)'
    )
    parser.add_argument(
        '--trajectories', type=int, default=12, help='training tracks per law (10 robots each)'
    )
    parser.add_argument('--max-minutes', type=float, default=10.0, help='training.max_minutes of each run')
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument(
        '--noise-mm', type=float, default=None, help='record the law as a mocap system: noise std, mm'
    )
    parser.add_argument('--rate', type=float, default=120.0, help='sample rate of the noisy recording, Hz')
    parser.add_argument('--eval-robots', type=int, nargs='+', default=[10, 30], help='held-out swarm sizes')
    parser.add_argument('--starts', type=int, default=8, help='held-out starts per swarm size')
    parser.add_argument(
        '--set', action='append', metavar='KEY=VALUE', help='a recipe field for training (repeatable)'
    )
    parser.add_argument(
        '--evaluate-only', action='store_true', help='reuse OUT/LAW/run/policy.pt where it exists'
    )
    args = parser.parse_args(argv)
    flat = [name for name in args.laws if LAWS[name].scenario.velocity is None]
    if args.noise_mm is not None and flat:
        parser.error(f'--noise-mm needs a velocity state; {", ".join(flat)} has positions only')
    load_config(args.config)  # a bad recipe is refused (exit 2) before any law is simulated
    results = {}
    for name in args.laws:
        results[name] = run_law(LAWS[name], args.out, args)
        write_json(os.path.join(args.out, 'results.json'), results)
    return 0


if __name__ == '__main__':
    sys.exit(main())
