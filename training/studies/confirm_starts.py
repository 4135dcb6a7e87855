"""How many starts the selection's confirm stage needs: for every run of a
:mod:`training.studies.custom_laws` study trained with ``selection.confirm``, each kept candidate
is scored on the confirm stage's starts in several sizes (training tracks x perturbed copies) and,
as the reference, on held-out starts of the law itself; each size's choice is then compared with
the candidate the held-out starts rank first (docs/scenarios.md, "How many starts the confirm
stage needs").

    python -m training.studies.confirm_starts runs/laws/couzin2d --seeds 1000 2000 --out sizes.json

The reference is the mean score over the held-out sets of ``--seeds`` (two sets also show how
well 32 starts rank the candidates at all: how often the sets agree on the best). Every size is a
subset of one set of rollouts (the confirm stage's copies are prefixes of each
other: copy r is seeded r), so the sizes are compared on the same draws, and the current size
reproduces the run's own confirm scores. The score is the selection's
(:func:`training.assessment.scores.selection_score`); a choice's regret is its held-out score
minus the best candidate's. Writes ``--out`` (JSON, after every run) and a markdown table beside
it (``.md``); the runs already in ``--out`` with the same settings are not run again.
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import tempfile
from typing import Any, Dict, List, Optional, Sequence, Tuple

import numpy as np
import torch

from knode_swarm_ros.core.cli import cli
from knode_swarm_ros.core.errors import KnodeError
from training.assessment.scores import selection_score
from training.learning.selection import confirm_truths, rollout_groups
from training.learning.trainer import Trainer

from .laws import LAWS, initial_states, simulate

#: (training tracks, copies per start) of the confirm sizes compared; None: every training track.
SIZES: Tuple[Tuple[Optional[int], int], ...] = ((0, 2), (8, 2), (None, 2), (None, 4), (None, 8))


def _subset_score(spec, groups, counts: Sequence[int], copies: int, stored: int) -> float:
    """The selection score of the first ``counts[g]`` starts of each group, ``copies`` copies of
    each, out of per-rollout metrics stored with ``stored`` copies per start
    (:func:`~training.learning.selection.rollout_groups`; None, a rollout blew up: +inf)."""
    if groups is None:
        return float('inf')
    m: Dict[str, List[float]] = {}
    for group, count in zip(groups, counts):
        keep = [s * stored + c for s in range(count) for c in range(copies)]
        for key, values in group.items():
            m.setdefault(key, []).extend(values[i] for i in keep)
    return selection_score(spec, m)


def study_run(
    run_dir: str, robots: int, held_out: int, seeds: Sequence[int], sizes: bool = True, log=print
) -> Optional[Dict[str, Any]]:
    """One run ``OUT/LAW/run*`` (its tracks ``OUT/LAW/tracks.npz``): every candidate's scores on
    ``held_out`` starts of each seed in ``seeds`` and (``sizes``) on each confirm size."""
    folder = os.path.dirname(os.path.normpath(run_dir))
    law = LAWS[os.path.basename(folder)]
    ck = torch.load(os.path.join(run_dir, 'checkpoint.pt'), map_location='cpu', weights_only=False)
    with open(os.path.join(run_dir, 'summary.json')) as fh:
        summary = json.load(fh)
    if not summary.get('confirmed') or len(ck.get('candidates') or []) < 2:
        log(f'{run_dir}: trained without selection.confirm; left out')
        return None
    cfg = ck['config']
    with tempfile.TemporaryDirectory() as tmp:
        trainer = Trainer(cfg, os.path.join(folder, 'tracks.npz'), tmp, progress=False, log=lambda *a: None)
    sc, spec, dt = cfg['selection'], trainer.spec, trainer.dt
    if len(trainer.splits) != 1:
        raise KnodeError(f'{folder}: one tracks file expected, found {len(trainer.splits)}')
    truths = confirm_truths(trainer.splits, {**sc, 'confirm_trajectories': None}, trainer.ratio)
    val_count, train_count = truths[0].shape[0], truths[1].shape[0] if len(truths) > 1 else 0
    most = max(c for _, c in SIZES)
    references = [simulate(law, initial_states(law, held_out, robots, seed), law.steps) for seed in seeds]
    out = {'run': run_dir, 'law': law.name, 'robots': robots, 'held_out': held_out, 'seeds': list(seeds)}
    out.update(sizes=[], candidates=[])
    for t, c in SIZES if sizes else ():
        tracks = train_count if t is None else min(t, train_count)
        out['sizes'].append({'tracks': tracks, 'copies': c, 'rollouts': (val_count + tracks) * c})
    for cand in ck['candidates']:
        trainer.policy.load_state_dict(cand['state'])
        scores = []
        if sizes:
            groups = rollout_groups(trainer.policy, spec, truths, most, sc['perturb'], cfg['policy'], dt)
            for size in out['sizes']:
                counts = [val_count, size['tracks']][: len(groups)]
                scores.append(_subset_score(spec, groups, counts, size['copies'], most))
        held = [
            _subset_score(
                spec, rollout_groups(trainer.policy, spec, [ref], 1, 0.0, cfg['policy'], dt), [held_out], 1, 1
            )
            for ref in references
        ]
        out['candidates'].append(
            {
                'epoch': cand['epoch'],
                'selection_score': cand['score'],
                'scores': scores,
                'held_out_scores': held,
                'held_out_score': float(np.mean(held)),
            }
        )
        log(
            f'{run_dir}: epoch {cand["epoch"]} confirm scores {np.round(scores, 4).tolist()}, held out '
            f'{np.round(held, 4).tolist()}'
        )
    logged = {c['epoch']: c['confirm_score'] for c in summary['confirmed']}
    out['logged_confirm'] = [logged.get(c['epoch']) for c in out['candidates']]
    held = [c['held_out_score'] for c in out['candidates']]
    out['choices'] = []
    for i in range(len(out['sizes'])):
        won = min(range(len(held)), key=lambda j: (out['candidates'][j]['scores'][i], j))
        out['choices'].append({'epoch': out['candidates'][won]['epoch'], 'regret': held[won] - min(held)})
    return out


def table(results: List[Dict[str, Any]]) -> List[str]:
    """Markdown: per run the candidates' held-out scores, the best candidate by each held-out set
    alone, and each size's choice (its regret in brackets)."""
    if not results:
        return ['no run with a confirm stage']
    sizes = results[0]['sizes']
    head = ['run (candidates: epoch held-out score)', 'best by each held-out set'] + [
        'selection alone' if s['tracks'] == 0 else f'{s["tracks"]} tracks x {s["copies"]}' for s in sizes
    ]
    lines = ['| ' + ' | '.join(head) + ' |', '|' + '---|' * len(head)]
    total = np.zeros(len(sizes))
    for r in results:
        cands = ', '.join(f'{c["epoch"]} {c["held_out_score"]:.3f}' for c in r['candidates'])
        per_set = [
            min(r['candidates'], key=lambda c: c['held_out_scores'][i])['epoch']
            for i in range(len(r['seeds']))
        ]
        cells = [' / '.join(map(str, per_set))] + [
            f'{ch["epoch"]} (+{ch["regret"]:.3f})' for ch in r['choices']
        ]
        total += [ch['regret'] for ch in r['choices']]
        lines.append(f'| {r["law"]}{os.path.basename(r["run"])[3:]} ({cands}) | ' + ' | '.join(cells) + ' |')
    lines.append('| total regret | | ' + ' | '.join(f'{x:.3f}' for x in total) + ' |')
    return lines


@cli('python -m training.studies.confirm_starts')
def main(argv: Optional[List[str]] = None) -> int:
    parser = argparse.ArgumentParser(
        prog='python -m training.studies.confirm_starts', description=__doc__.split('\n\n')[0]
    )
    parser.add_argument('folders', nargs='+', help='study folders OUT/LAW of training.studies.custom_laws')
    parser.add_argument('--out', required=True, help='results (JSON); the table goes beside it (.md)')
    parser.add_argument('--robots', type=int, default=10, help='robots of the held-out starts')
    parser.add_argument('--held-out', type=int, default=32, help='held-out starts (the reference)')
    parser.add_argument(
        '--seeds',
        type=int,
        nargs='+',
        default=[1000],
        help="the held-out starts' seeds (the reference: the mean score)",
    )
    parser.add_argument('--no-sizes', action='store_true', help='the held-out scores alone')
    args = parser.parse_args(argv)
    if args.held_out < 1 or args.robots < 2:
        raise KnodeError(f'--held-out {args.held_out} --robots {args.robots}: at least 1 start of 2 robots')
    for folder in args.folders:
        if os.path.basename(os.path.normpath(folder)) not in LAWS or not os.path.isdir(folder):
            raise KnodeError(f'{folder}: not a study folder OUT/LAW of a law in training.studies.laws')
    results = []
    if os.path.exists(args.out):  # an interrupted study resumes: its runs of the same settings stay
        with open(args.out) as fh:
            same = (args.robots, args.held_out, args.seeds, not args.no_sizes)
            results = [
                r for r in json.load(fh) if (r['robots'], r['held_out'], r['seeds'], bool(r['sizes'])) == same
            ]
    done = {r['run'] for r in results}
    for run_dir in [r for folder in args.folders for r in sorted(glob.glob(os.path.join(folder, 'run*')))]:
        if run_dir in done:
            print(f'{run_dir}: in {args.out} already')
            continue
        r = study_run(run_dir, args.robots, args.held_out, args.seeds, not args.no_sizes)
        if r is not None:
            results.append(r)
        with open(args.out + '.part', 'w') as fh:
            json.dump(results, fh, indent=1)
        os.replace(args.out + '.part', args.out)
    md = os.path.splitext(args.out)[0] + '.md'
    with open(md, 'w') as fh:
        fh.write('\n'.join(table(results)) + '\n')
    print('\n'.join(table(results)))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
