"""How a swarm law itself changes with the swarm's size: can tracks of one size tell how the
law behaves at another? (docs/scenarios.md, "Why two 30-robot goals are missed".)

    python -m training.studies.law_sizes --law flock3d_arena --robots 10 20 30 --reach 2.5

For each size, the law is rolled out from ``--starts`` starts (the held-out starts of
:mod:`training.studies.custom_laws`, seed 1000) and its order parameters read as the study
reads them (the mean over the last 20 frames, then mean and standard deviation over the
starts), beside the size of its commands over those frames (median and 99th percentile of
|u|: summed forces grow with the neighbour count) and, with ``--reach`` (the law's interaction
range, m), the share of robot-frames in which a robot has every other robot within it: where
that share is about 1 at the tracked size, a force summed over the neighbours and one averaged
over them are the same data (the trainer's swarm size caveat).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from typing import Any, Dict, List, Optional

import numpy as np

from knode_swarm_ros.core.cli import cli
from knode_swarm_ros.core.errors import KnodeError
from knode_swarm_ros.core.geometry import pair_distances
from training.assessment.order import order_parameters

from .laws import LAWS, Law, initial_states, simulate

__all__ = ['size_rows', 'size_table', 'main']

LAST = 20  # frames the order parameters are read over, as the study's evaluation reads them


def size_rows(
    law: Law, sizes: List[int], starts: int, seed: int, reach: Optional[float] = None
) -> List[Dict[str, Any]]:
    """One row per swarm size: ``robots``, ``{name: (mean, std)}`` of nn distance, polarisation
    and rotation order over the starts, ``command_median`` / ``command_q99`` (|u| over the last
    frames) and, with ``reach``, ``all_within_reach`` (the share of robot-frames)."""
    spec = law.scenario
    rows = []
    for n in sizes:
        z = simulate(law, initial_states(law, starts, n, seed), law.steps)  # [S, T, n, d]
        orders = order_parameters(spec, z, spec.dt, LAST)
        row: Dict[str, Any] = {'robots': n}
        for name in ('nn_distance', 'polarisation', 'rotation_order'):
            row[name] = (float(np.mean(orders[name])), float(np.std(orders[name])))
        last = z[:, -LAST:].reshape((-1,) + z.shape[2:])  # [S * LAST, n, d]
        u = np.linalg.norm(law.command(last), axis=-1)
        row['command_median'], row['command_q99'] = float(np.median(u)), float(np.quantile(u, 0.99))
        if reach is not None:
            others = (pair_distances(z[..., spec.position]) < reach).sum(-1)  # [S, T, n]
            row['all_within_reach'] = float(np.mean(others == n - 1))
        rows.append(row)
    return rows


def size_table(rows: List[Dict[str, Any]], reach: Optional[float]) -> str:
    head = '| robots | nn distance (m) | polarisation | rotation order | median / 99th pct. of abs(u) |'
    rule = '|---|---|---|---|---|'
    if reach is not None:
        head += f' robot-frames with every other within {reach:g} m |'
        rule += '---|'
    lines = [head, rule]
    for r in rows:
        cells = [str(r['robots'])]
        cells += [f'{r[k][0]:.3f} ± {r[k][1]:.3f}' for k in ('nn_distance', 'polarisation', 'rotation_order')]
        cells.append(f'{r["command_median"]:.3g} / {r["command_q99"]:.3g}')
        if reach is not None:
            cells.append(f'{100 * r["all_within_reach"]:.0f} %')
        lines.append('| ' + ' | '.join(cells) + ' |')
    return '\n'.join(lines) + '\n'


@cli('python -m training.studies.law_sizes')
def main(argv: Optional[List[str]] = None) -> int:
    parser = argparse.ArgumentParser(
        prog='python -m training.studies.law_sizes', description=__doc__.split('\n\n')[0]
    )
    parser.add_argument('--law', required=True, choices=list(LAWS))
    parser.add_argument('--robots', type=int, nargs='+', default=[10, 20, 30], metavar='N')
    parser.add_argument('--starts', type=int, default=32)
    parser.add_argument(
        '--seed', type=int, default=1000, help="the starts' seed (the study's held-out starts)"
    )
    parser.add_argument('--reach', type=float, default=None, help="the law's interaction range, m")
    parser.add_argument('--steps', type=int, default=None, help="frames per rollout - 1 (default the law's)")
    args = parser.parse_args(argv)
    if min(args.robots) < 2:
        raise KnodeError(f'--robots must be at least 2 each, got {args.robots}')
    if args.starts < 1 or (args.steps is not None and args.steps < 1):
        raise KnodeError(f'--starts and --steps must be at least 1, got {args.starts} and {args.steps}')
    if args.reach is not None and not args.reach > 0:
        raise KnodeError(f'--reach must be > 0 m, got {args.reach:g}')
    law = LAWS[args.law]
    if args.steps is not None:
        law = dataclasses.replace(law, steps=args.steps)
    print(f'{law.name}: {args.starts} starts (seed {args.seed}), {law.steps} steps, the last {LAST} frames')
    print(size_table(size_rows(law, args.robots, args.starts, args.seed, args.reach), args.reach), end='')
    return 0


if __name__ == '__main__':
    sys.exit(main())
