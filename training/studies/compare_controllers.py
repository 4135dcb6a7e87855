"""Compare learnt and hand-made decentralised controllers on the same held-out flock2d starts.

    python -m training.studies.compare_controllers --data data/flock2d.npz --out out/compare \
        --policy one_step=knode_swarm_ros/policies/flock2d.pt --policy multi_step=runs/flock2d_ms/policy.pt \
        --policy no_knowledge=runs/flock2d_noknow/policy.pt --sizes 10 30 60 90 --ics 20 5

Controllers, all with the information network of the first policy (its k, d_cr, tau, command limit):
every ``--policy NAME=FILE`` (KNODE policy files), ``local_tanner`` (the Tanner law cut to the
neighbour matrix, :func:`core.groundtruth.tanner.local_tanner_acceleration`) and ``kernel`` (the
least-squares interaction-kernel baseline of :mod:`training.assessment.kernel_baseline`, fitted on the
data's train split). Starts: :func:`core.groundtruth.simulate` at each size with seeds the data
never used (``--seed`` + n), which also gives the observed (ground-truth) swarm. Metrics (core):
final avd, amd (last 10 frames), smallest pair distance after 1 s. Writes ``results.json``,
``table.md`` and ``compare.png`` under ``--out``; ``--docs DIR`` also puts the table and the figure
where the documentation shows them (``DIR/compare_controllers_flock2d.md``,
``DIR/figures/compare_controllers_flock2d.png``).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from typing import Any, Callable, Dict, List, Optional, Sequence

import numpy as np

from knode_swarm_ros.core import PolicyError, get_scenario, load_policy, load_trajectories, rollout
from knode_swarm_ros.core.cli import cli
from knode_swarm_ros.core.errors import KnodeError
from knode_swarm_ros.core.groundtruth import simulate
from knode_swarm_ros.core.groundtruth.tanner import local_tanner_acceleration
from training.assessment.kernel_baseline import fit_kernel
from training.assessment.scores import final_metrics
from training.assessment.stats import describe
from training.learning.records import write_json

METRICS = ('avd_final', 'amd_final', 'min_distance')


def controllers(
    policies: Dict[str, str], data_path: str, kernel_stride: int = 4, log=print
) -> Dict[str, Any]:
    """``{name: policy callable}`` plus the shared network settings ``net`` (k, d_cr, tau, dt, limit)."""
    loaded = {name: load_policy(path) for name, path in policies.items()}
    first = next(iter(loaded.values()))
    if first.scenario != 'flock2d':
        raise PolicyError(f'{policies[next(iter(loaded))]}: the comparison covers flock2d policies only')
    limit = first.meta.get('command_limit')
    net = {'k': first.k, 'd_cr': first.d_cr, 'tau': first.tau, 'dt': first.dt, 'command_limit': limit}
    for name, pol in loaded.items():
        got = {'k': pol.k, 'd_cr': pol.d_cr, 'tau': pol.tau, 'dt': pol.dt}
        if any(got[key] != net[key] for key in got):
            raise PolicyError(
                f"--policy {name}={policies[name]}: network {got} differs from the first policy's {net}"
            )
    data = load_trajectories(data_path, scenario='flock2d')
    train = data.states[data.split('train')]
    t0 = time.perf_counter()
    kernel = fit_kernel(
        train, data.dt, first.d_cr, first.k, first.tau, command_limit=limit, stride=kernel_stride
    )
    log(
        f'kernel baseline fitted on {train.shape[0]} trajectories (every {kernel_stride}th frame) '
        f'in {time.perf_counter() - t0:.1f} s'
    )
    out: Dict[str, Callable] = dict(loaded)
    out['local_tanner'] = lambda Y, mask: local_tanner_acceleration(Y, mask, limit)
    out['kernel'] = kernel
    return {'controllers': out, 'net': net, 'kernel': kernel}


def compare(
    policies: Dict[str, str],
    data_path: str,
    out: str,
    sizes: Sequence[int],
    ics: Sequence[int],
    steps: int,
    seed: int,
    log=print,
) -> Dict[str, Any]:
    spec = get_scenario('flock2d')
    c = controllers(policies, data_path, log=log)
    net = c['net']
    os.makedirs(out, exist_ok=True)
    rows: List[Dict[str, Any]] = []
    per_run: Dict[str, Dict[str, Dict[str, List[float]]]] = {}
    for n, count in zip(sizes, ics):
        truth = simulate('flock2d', count, n, steps + 1, seed + n, progress=False)
        fm_truth = final_metrics(spec, truth, dt=net['dt'])
        per_run[str(n)] = {'ground_truth': {m: fm_truth[m] for m in METRICS}}
        rows.append(
            {
                'robots': n,
                'starts': count,
                'controller': 'ground_truth',
                **{m: describe(fm_truth[m]) for m in METRICS},
            }
        )
        for name, fn in c['controllers'].items():
            t0 = time.perf_counter()
            with np.errstate(all='ignore'):
                pred = rollout(
                    fn, truth[:, 0], steps, 'flock2d', net['d_cr'], net['k'], net['tau'], net['dt']
                )
            fm = final_metrics(spec, pred, truth, dt=net['dt'])
            per_run[str(n)][name] = {m: fm[m] for m in METRICS}
            row = {
                'robots': n,
                'starts': count,
                'controller': name,
                'seconds': round(time.perf_counter() - t0, 1),
                **{m: describe(fm[m]) for m in METRICS},
                'amd_rel_error': abs(np.mean(fm['amd_final']) - np.mean(fm_truth['amd_final']))
                / np.mean(fm_truth['amd_final']),
            }
            rows.append(row)
            log(
                f'{n:3d} robots {name:>14}: avd {row["avd_final"]["mean"]:.3f} ± {row["avd_final"]["ci95"]:.3f}  '
                f'amd {row["amd_final"]["mean"]:.3f}  min dist {row["min_distance"]["min"]:.3f}  [{row["seconds"]} s]'
            )
    results = {
        'data': os.path.abspath(data_path),
        'policies': {k: os.path.abspath(v) for k, v in policies.items()},
        'network': net,
        'sizes': list(sizes),
        'ics': list(ics),
        'steps': steps,
        'seed': seed,
        'kernel': json_kernel(c['kernel']),
        'rows': rows,
        'per_run': per_run,
    }
    write_json(os.path.join(out, 'results.json'), results)
    write_table(os.path.join(out, 'table.md'), results)
    figure(os.path.join(out, 'compare.png'), results)
    return results


def json_kernel(kernel) -> Dict[str, Any]:
    import json

    return json.loads(kernel.to_json())


def write_table(path: str, r: Dict[str, Any]) -> None:
    lines = [
        f'Held-out starts per size: {dict(zip(r["sizes"], r["ics"]))}, {r["steps"]} steps; mean ± 95 % CI '
        '(min distance: smallest over the runs)',
        '',
        '| robots | controller | final avd | final amd | amd vs truth | min distance after 1 s |',
        '| --- | --- | --- | --- | --- | --- |',
    ]
    for row in r['rows']:
        rel = '' if 'amd_rel_error' not in row else f'{100 * row["amd_rel_error"]:.1f} %'
        lines.append(
            f'| {row["robots"]} | {row["controller"]} | {row["avd_final"]["mean"]:.3g} ± '
            f'{row["avd_final"]["ci95"]:.2g} | {row["amd_final"]["mean"]:.3g} ± {row["amd_final"]["ci95"]:.2g} '
            f'| {rel} | {row["min_distance"]["min"]:.3f} |'
        )
    with open(path, 'w') as fh:
        fh.write('\n'.join(lines) + '\n')


def figure(path: str, r: Dict[str, Any]) -> None:
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    names = [row['controller'] for row in r['rows'] if row['robots'] == r['sizes'][0]]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    width = 0.8 / len(names)
    x = np.arange(len(r['sizes']))
    for ax, metric, label in ((axes[0], 'avd_final', 'final avd (log)'), (axes[1], 'amd_final', 'final amd')):
        for i, name in enumerate(names):
            vals = [r['per_run'][str(n)][name][metric] for n in r['sizes']]
            ax.boxplot(
                vals,
                positions=x + (i - (len(names) - 1) / 2) * width,
                widths=width * 0.9,
                patch_artist=True,
                boxprops={'facecolor': f'C{i}'},
                medianprops={'color': 'k'},
                showfliers=False,
                manage_ticks=False,
            )
            ax.plot([], [], color=f'C{i}', lw=6, label=name)
        ax.set_xticks(x, [str(n) for n in r['sizes']])
        ax.set_xlabel('robots')
        ax.set_ylabel(label)
        if metric == 'avd_final':
            ax.set_yscale('log')
    axes[1].legend(fontsize=7)
    fig.suptitle('flock2d: learnt and hand-made decentralised controllers vs the observed swarm')
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _named(items: List[str]) -> Dict[str, str]:
    out = {}
    for item in items:
        name, sep, path = item.partition('=')
        if not sep or not name or not path:
            raise ValueError(f'--policy {item!r}: expected NAME=FILE')
        out[name] = path
    return out


@cli('python -m training.studies.compare_controllers')
def main(argv: Optional[List[str]] = None) -> int:
    parser = argparse.ArgumentParser(
        prog='python -m training.studies.compare_controllers', description=__doc__.split('\n\n')[0]
    )
    parser.add_argument(
        '--data', required=True, help='flock2d trajectory file (its train split fits the kernel baseline)'
    )
    parser.add_argument(
        '--policy', action='append', required=True, metavar='NAME=FILE', help='a KNODE policy file'
    )
    parser.add_argument('--out', required=True, help='output directory')
    parser.add_argument('--sizes', type=int, nargs='+', default=[10, 30, 60, 90])
    parser.add_argument(
        '--ics',
        type=int,
        nargs='+',
        default=[20, 10, 5, 5],
        help='held-out starts per size (one number: the same for all)',
    )
    parser.add_argument('--steps', type=int, default=2000)
    parser.add_argument(
        '--seed', type=int, default=50000, help='start seeds are SEED + n (the data used 0..)'
    )
    parser.add_argument(
        '--docs', default=None, help='also write the table and figure into this docs directory'
    )
    args = parser.parse_args(argv)
    import torch

    torch.set_num_threads(1)
    ics = args.ics * len(args.sizes) if len(args.ics) == 1 else args.ics
    if len(ics) != len(args.sizes) or min(ics) < 2 or min(args.sizes) < 2:
        raise KnodeError(f'--ics {args.ics}: one count >= 2, or one per size of --sizes {args.sizes}')
    compare(_named(args.policy), args.data, args.out, args.sizes, ics, args.steps, args.seed)
    if args.docs is not None:
        import shutil

        os.makedirs(os.path.join(args.docs, 'figures'), exist_ok=True)
        shutil.copyfile(
            os.path.join(args.out, 'table.md'), os.path.join(args.docs, 'compare_controllers_flock2d.md')
        )
        shutil.copyfile(
            os.path.join(args.out, 'compare.png'),
            os.path.join(args.docs, 'figures', 'compare_controllers_flock2d.png'),
        )
    return 0


if __name__ == '__main__':
    sys.exit(main())
