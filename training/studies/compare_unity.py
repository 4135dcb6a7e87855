"""Compare our numpy boids (``published`` preset) with the Unity recordings of the paper.

    python -m training.studies.compare_unity --unity training/unity_boids/*.txt.xz --out out/unity_compare
    python -m training.studies.compare_unity --unity ... --out DIR --runs 30 --seed 0 --figures docs/figures
    python -m training.studies.compare_unity --unity ... --out DIR --save-runs data/unity_equivalent.npz

Three groups of 10-boid runs of the same length are compared on statistics that do not
depend on matching initial conditions (speeds, alignment and flockmates within the
perception radius, amd(t), subgroups, distance to the walls, POD energy and POD-KLD):

* ``unity``: the recordings (first 10 frames dropped, trimmed to the shortest);
* ``ours``: ``simulate('boids3d', runs, n, T, seed, preset='published')``, fixed dt = 1/60;
* ``ours_unity_dt``: the same spawns stepped with Unity's own frame times (run j replays
  the frame times estimated from recording j mod R), which isolates the effect of Unity's
  variable ``Time.deltaTime``.

The recordings hold no frame time and no speed. :func:`estimate_frame_times` recovers both:
Unity moves a boid by p(t+1) = p(t) + v(t+1) dt(t), so p(t+1) - p(t) is parallel to the
recorded heading h(t+1) and its length is |v(t+1)| dt(t); the one unknown per frame, dt(t),
is fitted so that our boids update (:func:`boids_step` with that dt) maps frame t to
frame t + 1 for all boids at once. The relative residual of that one-step prediction is
the model check reported in ``results.json``: where it is at the 7-decimal rounding level
(about 1e-5), our implementation reproduces Unity's frame exactly.

Writes ``results.json``, ``summary.md`` and ``unity_*.png`` figures (into ``--figures``,
default ``--out``). Exit status 0 ok, 2 bad input (the message names file and line).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from typing import Any, Dict, List, Optional, Sequence

import numpy as np

from knode_swarm_ros.core.cli import cli
from knode_swarm_ros.core.groundtruth import boids as gt_boids
from knode_swarm_ros.core.groundtruth import simulate
from knode_swarm_ros.core.metrics import amd, pod_energy
from training.assessment.boids_stats import alignment, flockmates, speeds, subgroups, wall_distance
from training.assessment.stats import describe, mean_ci
from training.data.unity.frames import MISMATCH, NOMINAL_DT, PRESET, model_check, simulate_with_frame_times
from training.data.unity.recordings import UnityFormatError, read_recording
from training.data.unity.statistics import STATS, compare_groups, pod_kld_pairs, run_statistics
from training.learning.records import write_json

__all__ = ['compare', 'write_summary', 'main']

GROUPS = ('unity', 'ours', 'ours_unity_dt')
LABELS = {'unity': 'Unity recordings', 'ours': 'ours, dt = 1/60', 'ours_unity_dt': 'ours, Unity frame times'}
COLOURS = {'unity': 'tab:blue', 'ours': 'tab:red', 'ours_unity_dt': 'tab:orange'}


# --------------------------------------------------------------------------- figures


def _figures(
    out: str,
    data: Dict[str, np.ndarray],
    frame_times: Dict[str, List[np.ndarray]],
    checks: List[Dict[str, Any]],
    kld: Dict[str, np.ndarray],
    pod: Dict[str, np.ndarray],
) -> List[str]:
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    os.makedirs(out, exist_ok=True)
    written = []

    def save(fig, name):
        fig.tight_layout()
        path = os.path.join(out, name)
        fig.savefig(path, dpi=72)
        plt.close(fig)
        written.append(path)

    groups = [g for g in GROUPS if g in data]

    def hist(ax, values, bins, g, density=True):
        ax.hist(
            values, bins=bins, density=density, histtype='step', lw=1.5, color=COLOURS[g], label=LABELS[g]
        )

    # frame times and model check
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.0))
    all_dt = np.concatenate(frame_times['unity']) * 60
    axes[0].hist(np.clip(all_dt, 0.95, 3.0), bins=np.linspace(0.95, 3.0, 83), color=COLOURS['unity'])
    axes[0].set_yscale('log')
    axes[0].set_xlabel('Unity frame time x 60 (estimated)')
    axes[0].set_ylabel('frames')
    res = np.concatenate([c['_residual'].ravel() for c in checks])
    axes[1].hist(np.log10(np.maximum(res, 1e-8)), bins=60, color='tab:green')
    axes[1].set_yscale('log')
    axes[1].axvline(np.log10(MISMATCH), color='k', ls='--', lw=1)
    axes[1].set_xlabel('log10 one-step residual (relative)')
    axes[1].set_ylabel('boid-frames')
    save(fig, 'unity_frame_times.png')

    # speeds
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.0))
    for g in groups:
        s = speeds(data[g], NOMINAL_DT).ravel()
        hist(axes[0], np.clip(s, 4.5, 12), np.linspace(4.5, 12, 76), g)
        dts = frame_times[g]
        true = np.concatenate(
            [
                (speeds(run, NOMINAL_DT) * NOMINAL_DT / dts[j % len(dts)][: run.shape[0] - 1, None]).ravel()
                for j, run in enumerate(data[g])
            ]
        )
        hist(axes[1], true, np.linspace(4.9, 8.1, 65), g)
    axes[0].set_xlabel('speed with dt = 1/60 (clipped at 12)')
    axes[1].set_xlabel('speed with actual frame times')
    for ax in axes:
        ax.set_yscale('log')
        ax.set_ylabel('density')
    axes[0].legend(fontsize=7)
    save(fig, 'unity_speed.png')

    # alignment and flockmates
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.0))
    for g in groups:
        al = alignment(data[g]).ravel()
        hist(axes[0], al[np.isfinite(al)], np.linspace(-1, 1, 51), g)
        fm = flockmates(data[g]).ravel()
        counts = np.bincount(fm, minlength=10)[:10] / fm.size
        off = {'unity': -0.25, 'ours': 0.0, 'ours_unity_dt': 0.25}[g]
        axes[1].bar(np.arange(10) + off, counts, width=0.25, color=COLOURS[g], label=LABELS[g])
    axes[0].set_yscale('log')
    axes[0].set_xlabel('alignment with flockmates (cosine)')
    axes[0].set_ylabel('density')
    axes[1].set_xlabel('flockmates within 2.5')
    axes[1].set_ylabel('fraction of boid-frames')
    axes[1].legend(fontsize=7)
    save(fig, 'unity_alignment_flockmates.png')

    # amd(t)
    fig, ax = plt.subplots(figsize=(6, 3.2))
    for g in groups:
        a = amd(data[g][..., :3])
        t = np.arange(a.shape[1]) * NOMINAL_DT
        mean, half = mean_ci(a, axis=0)
        ax.plot(t, mean, color=COLOURS[g], lw=1.2, label=f'{LABELS[g]} ({a.shape[0]} runs)')
        ax.fill_between(t, mean - half, mean + half, color=COLOURS[g], alpha=0.25, lw=0)
    ax.set_xlabel('time [s] (frame / 60)')
    ax.set_ylabel('amd')
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    save(fig, 'unity_amd.png')

    # subgroups and walls
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.0))
    for g in groups:
        sg = subgroups(data[g]).ravel()
        counts = np.bincount(sg, minlength=11)[1:11] / sg.size
        off = {'unity': -0.25, 'ours': 0.0, 'ours_unity_dt': 0.25}[g]
        axes[0].bar(np.arange(1, 11) + off, counts, width=0.25, color=COLOURS[g], label=LABELS[g])
        hist(axes[1], wall_distance(data[g]).ravel(), np.linspace(0, 5, 51), g)
    axes[0].set_xlabel('subgroups (radius 2.5)')
    axes[0].set_ylabel('fraction of frames')
    axes[0].legend(fontsize=7)
    axes[1].set_xlabel('distance to the nearest wall')
    axes[1].set_ylabel('density')
    save(fig, 'unity_subgroups_walls.png')

    # POD
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.0), gridspec_kw={'width_ratios': [3, 2]})
    modes = np.arange(1, pod['unity'].shape[1] + 1)
    width = 0.8 / len(groups)
    for k, g in enumerate(groups):
        e = pod[g]
        axes[0].bar(
            modes + (k - (len(groups) - 1) / 2) * width,
            e.mean(0),
            width=width,
            yerr=e.std(0),
            color=COLOURS[g],
            label=LABELS[g],
            error_kw={'lw': 0.8},
        )
    axes[0].set_yscale('log')
    axes[0].set_xlabel('POD mode')
    axes[0].set_ylabel('energy share')
    axes[0].legend(fontsize=7)
    names = list(kld)
    axes[1].boxplot([kld[k] for k in names], showfliers=True)
    axes[1].set_xticks(np.arange(1, len(names) + 1), [k.replace(' || ', '\n|| ') for k in names], fontsize=7)
    axes[1].set_ylabel('POD-KLD')
    axes[1].set_yscale('log')
    save(fig, 'unity_pod.png')
    return written


# --------------------------------------------------------------------------- report


def _fmt(x: float) -> str:
    if not np.isfinite(x):
        return '-'
    if x == 0:
        return '0'
    if abs(x) >= 100 or abs(x) < 1e-3:
        return f'{x:.2e}'
    return f'{x:.4g}'


def write_summary(path: str, r: Dict[str, Any]) -> None:
    groups = [g for g in GROUPS if g in r['statistics']]
    lines = [
        f'# Our boids ({PRESET} preset) against the Unity recordings',
        '',
        f'{r["unity"]["recordings"]} Unity recordings vs {r["runs"]} runs of ours, n = {r["robots"]}, '
        f'{r["frames"]} frames each (first 10 discarded), seed {r["seed"]}. Mean ± std over runs; '
        "p: Welch's t-test against Unity; d/s: difference over Unity's run-to-run std.",
        '',
    ]
    head = (
        '| statistic | '
        + ' | '.join(LABELS[g] for g in groups)
        + ' | '
        + ' | '.join(f'{LABELS[g]}: p, d/s' for g in groups if g != 'unity')
        + ' |'
    )
    lines += [head, '|' + ' --- |' * (1 + len(groups) + len(groups) - 1)]
    for name in STATS:
        cells = [
            f'{_fmt(r["statistics"][g][name]["mean"])} ± {_fmt(r["statistics"][g][name]["std"])}'
            for g in groups
        ]
        tests = []
        for g in groups:
            if g == 'unity':
                continue
            c = r['comparison'][g][name]
            flag = '**' if c['p_welch'] < 0.01 else ''
            tests.append(f'{flag}{_fmt(c["p_welch"])}{flag}, {_fmt(c["diff_over_spread"])}')
        lines.append(f'| {name} | ' + ' | '.join(cells) + ' | ' + ' | '.join(tests) + ' |')
    lines += [
        '',
        'POD-KLD (10 modes, KL(first || second) over all pairs):',
        '',
        '| pair | mean | median | min | max | pairs |',
        '| --- | --- | --- | --- | --- | --- |',
    ]
    for k, v in r['pod_kld'].items():
        lines.append(
            f'| {k} | {_fmt(v["mean"])} | {_fmt(v["median"])} | {_fmt(v["min"])} | {_fmt(v["max"])} | {v["count"]} |'
        )
    lines += [
        '',
        'Model check (our boids update, fitted frame time, one step from each recorded frame):',
        '',
        '| recording | frame time x 60: p50 / p95 / max | frames > 1.01/60 | residual p50 / p99.9 / max | '
        f'mismatches (> {MISMATCH:g}) | at ties |',
        '| --- | --- | --- | --- | --- | --- |',
    ]
    for c in r['unity']['model_check']:
        ft, rs = c['frame_time_x60_percentiles'], c['residual_percentiles']
        lines.append(
            f'| {os.path.basename(c["file"])} | {ft["p50"]} / {ft["p95"]} / {ft["max"]} | '
            f'{c["frames_longer_than_1.01/60"]:.1%} | {_fmt(rs["p50"])} / {_fmt(rs["p99.9"])} / {_fmt(rs["max"])} | '
            f'{c["mismatches"]} of {c["boid_frames"]} | {c["mismatches_at_ties"]} |'
        )
    lines += ['', STATS_LEGEND, '']
    with open(path, 'w') as fh:
        fh.write('\n'.join(lines))


STATS_LEGEND = 'Statistics: ' + '; '.join(f'`{k}`: {v}' for k, v in STATS.items()) + '.'


def compare(
    unity_files: Sequence[str],
    out: str,
    runs: int = 30,
    seed: int = 0,
    frames: Optional[int] = None,
    frame_times_mode: str = 'both',
    figures: Optional[str] = None,
    discard: int = 10,
    save_runs: Optional[str] = None,
    log=print,
) -> Dict[str, Any]:
    """Run the comparison and write ``results.json``, ``summary.md`` and figures; returns the results."""
    t0 = time.perf_counter()
    params = gt_boids.get_preset(PRESET)
    full = [read_recording(f, discard=0) for f in unity_files]
    short = [f for f, r in zip(unity_files, full) if r.shape[0] < discard + 3]
    if short:
        raise UnityFormatError(f'{short[0]}: fewer than {discard + 3} frames')
    recordings = [r[discard:] for r in full]
    counts = {r.shape[1] for r in recordings}
    if len(counts) != 1:
        raise UnityFormatError(f'recordings hold different boid counts {sorted(counts)}')
    n = counts.pop()
    T = min(r.shape[0] for r in recordings) if frames is None else int(frames)
    if T < 3 or any(r.shape[0] < T for r in recordings):
        raise UnityFormatError(
            f'need at least 3 frames and no more than the shortest recording '
            f'({min(r.shape[0] for r in recordings)}), got {T}'
        )
    log(f'{len(recordings)} recordings of {n} boids; comparing {T} frames; estimating frame times ...')
    checks = []
    for f, rec in zip(unity_files, full):
        c = model_check(rec, discard, params)
        c['file'] = str(f)
        c['frames'] = int(rec.shape[0] - discard)
        checks.append(c)
    unity_dt = [c['_dt'] for c in checks]
    data = {'unity': np.stack([r[:T] for r in recordings])}
    frame_times = {'unity': unity_dt}
    if frame_times_mode in ('fixed', 'both'):
        log(f'simulating {runs} runs with dt = 1/60 ...')
        data['ours'] = simulate('boids3d', runs, n, T, seed, preset=PRESET, progress=False)
        frame_times['ours'] = [np.full(T - 1, NOMINAL_DT)]
    if frame_times_mode in ('unity', 'both'):
        log(f"simulating {runs} runs with the recordings' frame times ...")
        data['ours_unity_dt'] = simulate_with_frame_times(
            runs,
            n,
            T,
            seed,
            unity_dt,
            params,
            [c['_preroll'] for c in checks] if discard == gt_boids.DISCARD_FRAMES else None,
        )
        frame_times['ours_unity_dt'] = unity_dt
    if save_runs and 'ours_unity_dt' in data:
        from knode_swarm_ros.core import save_trajectories

        save_trajectories(
            save_runs,
            data['ours_unity_dt'],
            NOMINAL_DT,
            'boids3d',
            {
                'generator': 'training.studies.compare_unity',
                'preset': PRESET,
                'seed': seed,
                'runs': runs,
                'robots': n,
                'frames': T,
                'parameters': params.as_dict(),
                'note': "our boids with the spawns of simulate(seed) stepped with the Unity recordings' frame times "
                '(run j: recording j mod R, pre-roll included); dt is nominal',
                'frame_times_from': [str(f) for f in unity_files],
                'split': {'test': list(range(runs))},
            },
        )
        log(f'wrote {save_runs}')
    stats = {
        g: [run_statistics(run, frame_times[g][j % len(frame_times[g])]) for j, run in enumerate(data[g])]
        for g in data
    }
    summary = {g: {k: describe([s[k] for s in stats[g]]) for k in STATS} for g in data}
    comparison = {
        g: {k: compare_groups([s[k] for s in stats['unity']], [s[k] for s in stats[g]]) for k in STATS}
        for g in data
        if g != 'unity'
    }
    pod = {g: np.stack([pod_energy(run, 10) for run in data[g]]) for g in data}
    kld = {'unity || unity': pod_kld_pairs(data['unity'])}
    for g in data:
        if g != 'unity':
            kld[f'unity || {g}'] = pod_kld_pairs(data['unity'], data[g])
    for g in data:
        if g != 'unity':
            kld[f'{g} || {g}'] = pod_kld_pairs(data[g][:12])
    results = {
        'preset': PRESET,
        'parameters': params.as_dict(),
        'runs': runs,
        'seed': seed,
        'robots': n,
        'frames': T,
        'discard': discard,
        'frame_times_mode': frame_times_mode,
        'unity': {
            'recordings': len(recordings),
            'files': [str(f) for f in unity_files],
            'model_check': [{k: v for k, v in c.items() if not k.startswith('_')} for c in checks],
        },
        'statistics': summary,
        'per_run': stats,
        'comparison': comparison,
        'pod_energy': {g: {'mean': pod[g].mean(0).tolist(), 'std': pod[g].std(0).tolist()} for g in pod},
        'pod_kld': {k: describe(v) for k, v in kld.items()},
        'statistics_legend': STATS,
    }
    os.makedirs(out, exist_ok=True)
    if figures != '':
        results['figures'] = _figures(figures or out, data, frame_times, checks, kld, pod)
    results['seconds'] = round(time.perf_counter() - t0, 1)
    write_json(os.path.join(out, 'results.json'), results, indent=1, sort_keys=False)
    write_summary(os.path.join(out, 'summary.md'), results)
    log(f'wrote {os.path.join(out, "results.json")} and summary.md ({results["seconds"]} s)')
    return results


@cli('python -m training.studies.compare_unity')
def main(argv: Optional[Sequence[str]] = None) -> int:
    ap = argparse.ArgumentParser(
        prog='python -m training.studies.compare_unity',
        description=__doc__.split('\n\n')[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument(
        '--unity', nargs='+', required=True, help='Unity recordings (simulation_data*.txt or .txt.xz)'
    )
    ap.add_argument('--out', required=True, help='output directory (results.json, summary.md)')
    ap.add_argument('--runs', type=int, default=30, help='runs of our boids per group (default 30)')
    ap.add_argument('--seed', type=int, default=0, help='seed of our spawns (default 0)')
    ap.add_argument(
        '--frames', type=int, default=None, help='frames compared (default: the shortest recording)'
    )
    ap.add_argument(
        '--frame-times',
        choices=['fixed', 'unity', 'both'],
        default='both',
        help="our runs with dt = 1/60, with Unity's frame times, or both (default)",
    )
    ap.add_argument(
        '--figures', default=None, help="directory of the unity_*.png figures (default --out; '' for none)"
    )
    ap.add_argument('--discard', type=int, default=10, help='leading recorded frames dropped (default 10)')
    ap.add_argument(
        '--save-runs',
        default=None,
        metavar='FILE.npz',
        help="also write our runs with Unity's frame times as a trajectory file (a Unity-equivalent test set)",
    )
    args = ap.parse_args(argv)
    if args.runs < 2:
        ap.error(f'--runs must be >= 2, got {args.runs}')
    if args.discard < 0:
        ap.error(f'--discard must be >= 0, got {args.discard}')
    if args.save_runs and args.frame_times == 'fixed':
        ap.error("--save-runs writes the runs with Unity's frame times; not with --frame-times fixed")
    compare(
        args.unity,
        args.out,
        args.runs,
        args.seed,
        args.frames,
        args.frame_times,
        args.figures,
        args.discard,
        args.save_runs,
    )
    return 0


if __name__ == '__main__':
    sys.exit(main())
