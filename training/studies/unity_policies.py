"""Roll several boids3d policies out from the first frames of test trajectories and compare them.

    python -m training.studies.unity_policies --out out/unity_policies --steps 2000 \\
        --policy unity_s2=runs/boids3d_unity_s2/policy.pt --policy ours=knode_swarm_ros/policies/boids3d.pt \\
        --data unity=data/unity_test5.npz --data unity_equivalent=data/unity_equivalent.npz

For every test set (its ``test`` split, or all trajectories) and policy: rollouts with the
canonical semantics (:func:`knode_swarm_ros.core.rollout`) from frame 0 for ``--steps`` steps,
then per run amd(t), the final amd (last 10 frames), POD-KLD(truth || rollout) (10 modes),
whether it stays in the cube, and the statistics of :func:`training.data.unity.statistics.run_statistics`
for rollouts and ground truth. ``--oracle`` adds our ground-truth boids started from the same
frames (speeds from the first displacement, dt 1/60): what a perfect learner could reach, since
boids are chaotic and no rollout stays on the recorded path. Writes ``results.json``, ``summary.md``,
``unity_policies_amd.png`` and ``unity_policies_pod.png`` (into ``--figures``, default ``--out``).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from typing import Any, Dict, List, Optional, Sequence, Tuple

import numpy as np

from knode_swarm_ros.core import PolicyError, amd, load_policy, load_trajectories, pod_kld, rollout
from knode_swarm_ros.core.cli import cli
from training.assessment.stats import describe, mean_ci
from training.data.unity.statistics import run_statistics
from training.learning.records import write_json

STATS = ('speed_mean', 'alignment', 'flockmates', 'subgroups_mean', 'wall_distance', 'amd_mean')
COLOURS = ['tab:red', 'tab:orange', 'tab:green', 'tab:purple', 'tab:brown', 'tab:pink', 'tab:gray']


def _pairs(items: Sequence[str], what: str) -> List[Tuple[str, str]]:
    out = []
    for item in items:
        name, sep, path = item.partition('=')
        if not sep or not name or not path:
            raise ValueError(f'--{what} {item!r}: expected NAME=PATH')
        out.append((name, path))
    return out


class _Oracle:
    """Our ground-truth boids (``published`` preset, dt 1/60) as a 'policy': started from frame 0 with
    speeds |p(1) - p(0)| x 60 (clamped to [5, 8]), the reference a perfect learner could reach."""

    scenario = 'boids3d'

    def rollout(self, truth: np.ndarray, steps: int) -> np.ndarray:
        from knode_swarm_ros.core.groundtruth import boids as gt_boids

        params = gt_boids.get_preset('published')
        speed = np.clip(
            np.linalg.norm(truth[:, 1, :, :3] - truth[:, 0, :, :3], axis=-1) * 60,
            params.min_speed,
            params.max_speed,
        )
        p, v = truth[:, 0, :, :3], truth[:, 0, :, 3:] * speed[..., None]
        out = [gt_boids.observe(p, v)]
        for _ in range(steps):
            p, v = gt_boids.boids_step(p, v, params)
            out.append(gt_boids.observe(p, v))
        return np.stack(out, axis=1)


ORACLE = 'oracle'


def evaluate_policies(
    policies: Sequence[Tuple[str, str]],
    datasets: Sequence[Tuple[str, str]],
    out: str,
    steps: int = 2000,
    figures: Optional[str] = None,
    oracle: bool = False,
    log=print,
    rollouts: int = 1,
    perturb: float = 1e-3,
) -> Dict[str, Any]:
    """``rollouts`` > 1: that many rollouts per test trajectory, copy 0 from its frame 0 and the others
    with N(0, ``perturb``^2) on the first positions (:func:`training.assessment.scores.perturbed_starts`: boids are
    chaotic, so one rollout per start says little); every copy is compared with its trajectory."""
    from training.assessment.scores import perturbed_starts

    loaded = []
    if oracle:
        loaded.append((ORACLE, 'our boids (published preset), dt 1/60', _Oracle()))
    for name, path in policies:
        if name == ORACLE:
            raise ValueError(f'--policy {name}=...: the name {ORACLE!r} is reserved for --oracle')
        pol = load_policy(path)
        if pol.scenario != 'boids3d':
            raise PolicyError(f'{path}: scenario {pol.scenario!r}, expected boids3d')
        loaded.append((name, path, pol))
    results: Dict[str, Any] = {
        'steps': steps,
        'policies': {n: p for n, p, _ in loaded},
        'data': {},
        'sets': {},
    }
    curves: Dict[str, Dict[str, np.ndarray]] = {}
    klds: Dict[str, Dict[str, List[float]]] = {}
    for dname, dpath in datasets:
        data = load_trajectories(dpath, scenario='boids3d')
        truth = data.states[data.split('test')]
        T = min(steps, truth.shape[1] - 1) + 1
        truth = truth[:, :T]
        results['data'][dname] = {
            'file': dpath,
            'trajectories': int(len(truth)),
            'frames': T,
            'rollouts': rollouts,
        }
        starts = perturbed_starts(truth[:, 0], rollouts, perturb, 3)  # [S * R, n, 6]
        truth = np.repeat(truth, rollouts, axis=0)
        moved = truth.copy()
        moved[:, 0] = starts
        entry: Dict[str, Any] = {'truth': {k: describe([run_statistics(r)[k] for r in truth]) for k in STATS}}
        entry['truth']['amd_final'] = describe(amd(truth[:, -10:, :, :3]).mean(1))
        curves[dname] = {'ground truth': amd(truth[..., :3])}
        klds[dname] = {}
        for pname, _, pol in loaded:
            t0 = time.perf_counter()
            with np.errstate(all='ignore'):
                pred = (
                    pol.rollout(moved, T - 1)
                    if isinstance(pol, _Oracle)
                    else rollout(pol, starts, T - 1, 'boids3d', pol.d_cr, pol.k, pol.tau, pol.dt)
                )
            finite = bool(np.all(np.isfinite(pred)))
            kl = [pod_kld(truth[s], pred[s]) if finite else float('nan') for s in range(len(truth))]
            inside = np.all(np.abs(pred[..., :3]) <= 5.0 + 1e-9, axis=(1, 2, 3))
            e = {k: describe([run_statistics(r)[k] for r in pred]) for k in STATS} if finite else {}
            e.update(
                {
                    'amd_final': describe(amd(pred[:, -10:, :, :3]).mean(1)),
                    'pod_kld': describe(kl),
                    'pod_kld_runs': kl,
                    'inside': int(inside.sum()),
                    'finite': finite,
                    'seconds': round(time.perf_counter() - t0, 1),
                }
            )
            entry[pname] = e
            curves[dname][pname] = amd(pred[..., :3])
            klds[dname][pname] = kl
            log(
                f'{dname} / {pname}: final amd {e["amd_final"]["mean"]:.3f} (truth {entry["truth"]["amd_final"]["mean"]:.3f}), '
                f'POD-KLD {e["pod_kld"]["mean"]:.4f}, inside {e["inside"]}/{len(truth)} [{e["seconds"]} s]'
            )
        results['sets'][dname] = entry
    os.makedirs(out, exist_ok=True)
    fig_dir = figures or out
    if figures != '':
        results['figures'] = _figures(fig_dir, curves, klds, [n for n, _, _ in loaded])
    write_json(os.path.join(out, 'results.json'), results, indent=1, sort_keys=False)
    _summary(os.path.join(out, 'summary.md'), results)
    log(f'wrote {out}/results.json and summary.md')
    return results


def _figures(out: str, curves, klds, names: List[str]) -> List[str]:
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    os.makedirs(out, exist_ok=True)
    written = []
    sets = list(curves)
    fig, axes = plt.subplots(1, len(sets), figsize=(4.6 * len(sets), 3.2), squeeze=False)
    for ax, dname in zip(axes[0], sets):
        for k, (label, a) in enumerate(curves[dname].items()):
            colour = 'tab:blue' if label == 'ground truth' else COLOURS[(k - 1) % len(COLOURS)]
            every = max(a.shape[1] // 150, 1)  # ~150 points per curve keep the PNG small
            a = a[:, ::every]
            mean, half = mean_ci(a)
            t = np.arange(a.shape[1]) * every / 60.0
            ax.plot(t, mean, color=colour, lw=1.1, label=label)
            ax.fill_between(t, mean - half, mean + half, color=colour, alpha=0.2, lw=0)
        ax.set_title(f'{dname} ({curves[dname]["ground truth"].shape[0]} runs)', fontsize=9)
        ax.set_xlabel('time [s]')
        ax.set_ylabel('amd')
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    path = os.path.join(out, 'unity_policies_amd.png')
    fig.savefig(path, dpi=72)
    plt.close(fig)
    written.append(path)
    fig, ax = plt.subplots(figsize=(min(9.0, max(5.0, 1.2 * len(names) * len(sets))), 3.0))
    width = 0.8 / len(sets)
    for j, dname in enumerate(sets):
        vals = [np.asarray(klds[dname][n], float) for n in names]
        x = np.arange(len(names)) + (j - (len(sets) - 1) / 2) * width
        ax.bar(
            x,
            [np.nanmean(v) for v in vals],
            width=width,
            yerr=[np.nanstd(v) for v in vals],
            label=dname,
            color=['tab:blue', 'tab:cyan', 'tab:olive', 'tab:gray'][j % 4],
            error_kw={'lw': 0.8},
        )
    ax.set_xticks(np.arange(len(names)), names, fontsize=8)
    ax.set_ylabel('POD-KLD(truth || rollout)')
    ax.set_yscale('log')
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3, axis='y')
    fig.tight_layout()
    path = os.path.join(out, 'unity_policies_pod.png')
    fig.savefig(path, dpi=72)
    plt.close(fig)
    written.append(path)
    return written


def _summary(path: str, r: Dict[str, Any]) -> None:
    lines = [
        '# boids3d policies on Unity test sets',
        '',
        'Policies: ' + ', '.join(f'`{n}` = `{p}`' for n, p in r['policies'].items()),
        '',
        f"Rollouts of {r['steps']} steps (or the ground truth's length) from frame 0. Mean ± std over runs.",
        '',
    ]
    for dname, entry in r['sets'].items():
        d = r['data'][dname]
        lines += [
            f'## {dname}: `{d["file"]}`, {d["trajectories"]} runs x {d.get("rollouts", 1)} rollouts, {d["frames"]} frames',
            '',
            '| | final amd | POD-KLD | in cube | ' + ' | '.join(STATS) + ' |',
            '| --- |' + ' --- |' * (3 + len(STATS)),
        ]
        for name, e in entry.items():
            if name == 'truth':
                row = [f'{e["amd_final"]["mean"]:.3f} ± {e["amd_final"]["std"]:.3f}', '0', '-']
            else:
                row = [
                    f'{e["amd_final"]["mean"]:.3f} ± {e["amd_final"]["std"]:.3f}',
                    f'{e["pod_kld"]["mean"]:.4f} ± {e["pod_kld"]["std"]:.4f}',
                    f'{e["inside"]}/{d["trajectories"] * d.get("rollouts", 1)}',
                ]
            row += [f'{e[k]["mean"]:.3g}' if k in e else '-' for k in STATS]
            lines.append(f'| {name} | ' + ' | '.join(row) + ' |')
        lines.append('')
    with open(path, 'w') as fh:
        fh.write('\n'.join(lines))


@cli('python -m training.studies.unity_policies')
def main(argv: Optional[Sequence[str]] = None) -> int:
    ap = argparse.ArgumentParser(
        prog='python -m training.studies.unity_policies',
        description=__doc__.split('\n\n')[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument(
        '--policy', action='append', required=True, metavar='NAME=FILE', help='policy file (repeat)'
    )
    ap.add_argument(
        '--data',
        action='append',
        required=True,
        metavar='NAME=FILE',
        help="test trajectories (its 'test' split, or all); repeat",
    )
    ap.add_argument('--out', required=True, help='output directory')
    ap.add_argument('--steps', type=int, default=2000, help='rollout steps (default 2000)')
    ap.add_argument('--figures', default=None, help="directory of the figures (default --out; '' for none)")
    ap.add_argument(
        '--oracle',
        action='store_true',
        help='also roll out our ground-truth boids (published preset, dt 1/60) from the same frames',
    )
    ap.add_argument(
        '--rollouts',
        type=int,
        default=1,
        help='rollouts per test trajectory, the others from starts perturbed by 1e-3 (default 1)',
    )
    args = ap.parse_args(argv)
    if args.steps < 10:
        ap.error(f'--steps must be >= 10, got {args.steps}')
    if args.rollouts < 1:
        ap.error(f'--rollouts must be >= 1, got {args.rollouts}')
    evaluate_policies(
        _pairs(args.policy, 'policy'),
        _pairs(args.data, 'data'),
        args.out,
        args.steps,
        args.figures,
        args.oracle,
        rollouts=args.rollouts,
    )
    return 0


if __name__ == '__main__':
    sys.exit(main())
