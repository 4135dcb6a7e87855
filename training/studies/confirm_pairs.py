"""What the selection's confirm stage changes, paired on the same trainings: for every run of a
:mod:`training.studies.custom_laws` study trained with ``selection.confirm``, the epoch the
selection alone would have exported (the best of its candidates by the selection score) is
exported beside the run and evaluated against the law from the same held-out starts as the
confirm stage's choice (docs/scenarios.md, "Confirming the selection on more starts").

    python -m training.studies.confirm_pairs runs/laws/mill2d runs/laws/couzin2d --out pairs.md

Per run directory ``LAW/run{tail}``: ``LAW/selection{tail}/policy.pt`` (the selection's best) and
``LAW/eval_selection_nN{tail}/`` (its evaluation at each size the study evaluated). A run whose
confirm stage kept the selection's best needs no second evaluation: its row says "same". The
table (markdown) compares the goals met and the three errors of the two choices.
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import re
import sys
from typing import Any, Dict, List, Optional

import torch

from knode_swarm_ros.core import export_policy, load_policy
from knode_swarm_ros.core.cli import cli
from knode_swarm_ros.core.errors import KnodeError
from training.learning.config import build_policy

from .law_goals import evaluate_law
from .laws import LAWS


def export_selection_best(run_dir: str, out_dir: str) -> Optional[Dict[str, Any]]:
    """Write the selection's best candidate of ``run_dir`` to ``out_dir/policy.pt``:
    ``{'selection_epoch', 'confirm_epoch', 'policy'}``, or None for a run without candidates."""
    ck = torch.load(os.path.join(run_dir, 'checkpoint.pt'), map_location='cpu', weights_only=False)
    with open(os.path.join(run_dir, 'summary.json')) as fh:
        summary = json.load(fh)
    if not ck.get('candidates') or not summary.get('confirmed'):
        return None
    first = ck['candidates'][0]
    out = {'selection_epoch': first['epoch'], 'confirm_epoch': summary['best']['epoch'], 'policy': None}
    if out['selection_epoch'] == out['confirm_epoch']:
        return out
    chosen = load_policy(os.path.join(run_dir, 'policy.pt'))
    module = build_policy(ck['config'])
    module.load_state_dict(first['state'])
    meta = module.metadata(dt=chosen.dt)
    meta['provenance'] = dict(
        chosen.meta['provenance'],
        selected=f'best rollout score (epoch {first["epoch"]}); the confirm stage left out',
    )
    os.makedirs(out_dir, exist_ok=True)
    out['policy'] = os.path.join(out_dir, 'policy.pt')
    export_policy(module, out['policy'], meta)
    return out


def _goals_met(goals: Dict[str, Any]) -> int:
    return sum(1 for k, v in goals.items() if k not in ('finite',) and isinstance(v, bool) and v)


def _goal_count(goals: Dict[str, Any]) -> int:
    return sum(1 for k, v in goals.items() if k not in ('finite',) and isinstance(v, bool))


def _cell(goals: Dict[str, Any]) -> str:
    return (
        f'{_goals_met(goals)} / {_goal_count(goals)} ({goals["nn_rel_error"]:.0%}, '
        f'{goals["polarisation_error"]:.3f}, {goals["rotation_error"]:.3f})'
    )


def pair_rows(folder: str, log=print) -> List[str]:
    """Markdown rows for every run in one study folder ``OUT/LAW``."""
    rows = []
    for run_dir in sorted(glob.glob(os.path.join(folder, 'run*'))):
        tail = os.path.basename(run_dir)[len('run') :]
        evals = sorted(glob.glob(os.path.join(folder, f'eval_n*{tail}', 'results.json')))
        evals = [
            p
            for p in evals
            if re.fullmatch(rf'eval_n\d+{re.escape(tail)}', os.path.basename(os.path.dirname(p)))
        ]
        if not os.path.exists(os.path.join(run_dir, 'summary.json')) or not evals:
            continue
        pair = export_selection_best(run_dir, os.path.join(folder, f'selection{tail}'))
        if pair is None:
            log(f'{run_dir}: trained without selection.confirm; left out')
            continue
        for path in evals:
            with open(path) as fh:
                confirmed = json.load(fh)
            robots = confirmed['robots']
            if pair['policy'] is None:
                alone = 'same'
            else:
                r = evaluate_law(
                    LAWS[confirmed['law']],
                    pair['policy'],
                    os.path.join(folder, f'eval_selection_n{robots}{tail}'),
                    robots,
                    confirmed['starts'],
                    confirmed['seed'],
                )
                alone = _cell(r['goals'])
            line = (
                f'| {os.path.basename(folder)}{tail} | {pair["selection_epoch"]} -> {pair["confirm_epoch"]} | '
                f'{robots} ({confirmed["starts"]}) | {alone} | {_cell(confirmed["goals"])} |'
            )
            log(line)
            rows.append(line)
    return rows


HEADER = [
    '| law, run | epoch: selection -> confirm | robots (starts) | selection alone: goals (nn, polarisation, '
    'rotation errors) | with the confirm stage |',
    '|---|---|---|---|---|',
]


@cli('python -m training.studies.confirm_pairs')
def main(argv: Optional[List[str]] = None) -> int:
    parser = argparse.ArgumentParser(
        prog='python -m training.studies.confirm_pairs', description=__doc__.split('\n\n')[0]
    )
    parser.add_argument('folders', nargs='+', help='study folders OUT/LAW of training.studies.custom_laws')
    parser.add_argument('--out', required=True, help='the markdown table to write')
    args = parser.parse_args(argv)
    for folder in args.folders:
        if not os.path.isdir(folder):
            raise KnodeError(f'{folder}: not a study folder (OUT/LAW of training.studies.custom_laws)')
    rows = [row for folder in args.folders for row in pair_rows(folder)]
    with open(args.out, 'w') as fh:
        fh.write('\n'.join(HEADER + rows) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
