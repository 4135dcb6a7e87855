"""Figures of training and evaluation (matplotlib, Agg backend, PNG files).

Every function takes arrays and a path and writes one PNG; nothing here computes metrics.
"""

from __future__ import annotations

import json
from typing import Dict, List, Optional, Sequence

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt
import numpy as np

from .stats import mean_ci

PRED_COLOUR, TRUE_COLOUR = 'tab:red', 'tab:blue'

#: Axis labels with units (positions in metres, time in seconds; boids3d's avd compares unit headings).
METRIC_LABELS = {
    'avd': 'avd: velocity difference [m/s]',
    'avd_heading': 'avd: heading difference (unit vectors)',
    'amd': 'amd: mean nearest-neighbour distance [m]',
    'pod_kld': 'POD-KLD (0 = same motion modes)',
}
#: Under the snapshots: what good looks like.
SNAPSHOT_CAPTION = (
    'Good: at each time the learnt swarm (left) looks like the ground truth (right), same start.'
)
#: Under every metric figure: what good looks like.
CAPTION = (
    "Good: the learnt swarm's curves (red) lie on the ground truth's (blue); a low avd means the "
    'robots move alike (lower is better), amd is their spacing.'
)


def _save(fig, path: str, dpi: int = 100, caption: str = '') -> None:
    """Lay out and write ``fig``; ``caption``: one line under the panels."""
    if caption:
        fig.text(0.5, 0.005, caption, ha='center', va='bottom', fontsize=8)
    fig.tight_layout(rect=(0, 0.05 if caption else 0, 1, 1))
    fig.savefig(path, dpi=dpi)
    plt.close(fig)


def metric_curves(
    path: str,
    time: np.ndarray,
    curves: Dict[str, Dict[str, np.ndarray]],
    title: str = '',
    labels: Optional[Dict[str, str]] = None,
) -> None:
    """Mean and 95% confidence bands over trajectories.

    ``curves = {metric: {"prediction": [S, T], "ground truth": [S, T]}}``; one panel per metric,
    its y label ``labels[metric]`` (default :data:`METRIC_LABELS`); avd on a log scale.
    """
    labels = {**METRIC_LABELS, **(labels or {})}
    fig, axes = plt.subplots(1, len(curves), figsize=(5 * len(curves), 3.6), squeeze=False)
    for ax, (name, series) in zip(axes[0], curves.items()):
        for label, values in series.items():
            colour = PRED_COLOUR if label == 'prediction' else TRUE_COLOUR
            mean, half = mean_ci(values, axis=0)
            ax.plot(time[: len(mean)], mean, color=colour, label=f'{label} (mean)')
            ax.fill_between(
                time[: len(mean)],
                mean - half,
                mean + half,
                color=colour,
                alpha=0.25,
                lw=0,
                label=f'{label} 95% CI',
            )
        ax.set_xlabel('time [s]')
        ax.set_ylabel(labels.get(name, name))
        if name == 'avd':
            ax.set_yscale('log')  # the flocked state is orders of magnitude below the start
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    if title:
        fig.suptitle(title)
    _save(fig, path, caption=CAPTION)


def snapshots(
    path: str,
    pred: np.ndarray,
    truth: np.ndarray,
    frames: Sequence[int],
    dt: float,
    position_dim: int,
    box: Optional[float] = None,
) -> None:
    """Prediction beside ground truth (one trajectory ``[T, n, d]`` each) at ``frames``.

    2D: positions with velocity arrows (half a second of motion); 3D: positions with heading
    arrows in the cube. Limits hold every robot and arrow of both panels of a row.
    """
    rows = len(frames)
    three_d = position_dim == 3
    fig = plt.figure(figsize=(8, 3.6 * rows))
    for r, f in enumerate(frames):
        for c, (label, traj, colour) in enumerate(
            (('prediction', pred, PRED_COLOUR), ('ground truth', truth, TRUE_COLOUR))
        ):
            z = traj[f]
            if three_d:
                ax = fig.add_subplot(rows, 2, 2 * r + c + 1, projection='3d')
                ax.scatter(z[:, 0], z[:, 1], z[:, 2], color=colour, s=12)
                ax.quiver(z[:, 0], z[:, 1], z[:, 2], z[:, 3], z[:, 4], z[:, 5], length=0.8, color=colour)
                reach = np.abs(np.concatenate([pred[f, :, :3], truth[f, :, :3]])).max() + 1
                lim = max(box, reach) if box is not None else reach
                ax.set_xlim(-lim, lim)
                ax.set_ylim(-lim, lim)
                ax.set_zlim(-lim, lim)
                ax.set_xlabel('x [m]', fontsize=8)
                ax.set_ylabel('y [m]', fontsize=8)
                ax.set_zlabel('z [m]', fontsize=8)
            else:
                ax = fig.add_subplot(rows, 2, 2 * r + c + 1)
                ax.quiver(
                    z[:, 0],
                    z[:, 1],
                    z[:, 2],
                    z[:, 3],
                    color=colour,
                    angles='xy',
                    scale_units='xy',
                    scale=2,
                    width=0.006,
                )
                ax.scatter(z[:, 0], z[:, 1], color=colour, s=14, label='robot')
                # arrows drawn at scale 2 reach half a velocity beyond their robot
                tips = [s[f, :, :2] + s[f, :, 2:4] / 2 for s in (pred, truth)]
                both = np.concatenate([pred[f, :, :2], truth[f, :, :2], *tips])
                both = both[np.all(np.isfinite(both), axis=1)]
                centre = both.mean(0) if len(both) else np.zeros(2)
                half = max(np.abs(both - centre).max() + 0.5, 2.0) if len(both) else 2.0
                ax.set_xlim(centre[0] - half, centre[0] + half)
                ax.set_ylim(centre[1] - half, centre[1] + half)
                ax.set_aspect('equal')
                ax.set_xlabel('x [m]', fontsize=8)
                ax.set_ylabel('y [m]', fontsize=8)
                ax.plot([], [], color=colour, marker=r'$\rightarrow$', ls='', ms=10, label='velocity (0.5 s)')
                ax.legend(fontsize=7, loc='upper right')
            ax.set_title(f'{label}, t = {f * dt:.2f} s', fontsize=9)
    _save(fig, path, caption=SNAPSHOT_CAPTION)


def pod_bars(path: str, pred_energy: np.ndarray, true_energy: np.ndarray, kld: Sequence[float]) -> None:
    """Mean POD energy per mode (``[S, modes]`` each) with 95% CIs, and the POD-KLD box."""
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(10, 3.6), gridspec_kw={'width_ratios': [3, 1]})
    modes = np.arange(1, pred_energy.shape[1] + 1)
    for shift, (label, e, colour) in enumerate(
        (('ground truth', true_energy, TRUE_COLOUR), ('prediction', pred_energy, PRED_COLOUR))
    ):
        mean, half = mean_ci(e, axis=0)
        ax.bar(modes + (shift - 0.5) * 0.4, mean, width=0.4, yerr=half, color=colour, label=label, capsize=2)
    ax.set_yscale('log')
    ax.set_xlabel('POD mode')
    ax.set_ylabel('energy fraction')
    ax.set_xticks(modes)
    ax.legend(fontsize=8)
    bx.boxplot([list(kld)], tick_labels=['POD-KLD'])
    bx.grid(alpha=0.3)
    _save(fig, path)


def scaling_boxes(
    path: str,
    sizes: Sequence[int],
    metrics: Dict[str, Dict[str, List[List[float]]]],
    ylabel_prefix: str = 'final ',
) -> None:
    """Box plots per swarm size: ``metrics = {name: {"prediction": [[per-IC] per size], "ground truth": ...}}``."""
    fig, axes = plt.subplots(1, len(metrics), figsize=(5.5 * len(metrics), 3.8), squeeze=False)
    for ax, (name, series) in zip(axes[0], metrics.items()):
        width = 0.8 / max(len(series), 1)
        for s, (label, per_size) in enumerate(series.items()):
            colour = PRED_COLOUR if label == 'prediction' else TRUE_COLOUR
            pos = np.arange(len(sizes)) + (s - (len(series) - 1) / 2) * width
            bp = ax.boxplot(
                per_size, positions=pos, widths=width * 0.9, patch_artist=True, manage_ticks=False
            )
            for patch in bp['boxes']:
                patch.set_facecolor(colour)
                patch.set_alpha(0.5)
            ax.plot([], [], color=colour, lw=6, alpha=0.5, label=label)
        ax.set_xticks(np.arange(len(sizes)))
        ax.set_xticklabels([str(s) for s in sizes])
        ax.set_xlabel('robots')
        ax.set_ylabel(f'{ylabel_prefix}{name}')
        if name == 'avd':
            ax.set_yscale('log')
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    _save(fig, path)


def departures(path: str, curves: Dict[str, Dict], pred: tuple, truth: tuple, box: float, title: str) -> None:
    """Where a learnt 3D swarm departs from the boids, over sizes.

    ``curves = {size: {"t": [P], "subswarms"|"escaped"|"amd": {"prediction": [P], "ground truth": [P]}}}``
    (means over starts); ``pred``/``truth``: ``(frame [n, 6], group labels [n])`` of one final frame,
    drawn as x-y and x-z projections coloured by subswarm, with the cube.
    """
    fig = plt.figure(figsize=(15, 7.5))
    grid = fig.add_gridspec(2, 12)
    cmap = plt.get_cmap('viridis')
    sizes = list(curves)
    for i, (key, label) in enumerate(
        (
            ('subswarms', 'subswarms (radius 2.5)'),
            ('escaped', 'share of boids that have left the cube'),
            ('amd', 'amd'),
        )
    ):
        ax = fig.add_subplot(grid[0, 4 * i : 4 * i + 4])
        for j, n in enumerate(sizes):
            c = cmap(j / max(len(sizes) - 1, 1))
            ax.plot(curves[n]['t'], curves[n][key]['prediction'], color=c, label=f'{n}')
            ax.plot(curves[n]['t'], curves[n][key]['ground truth'], color=c, ls='--', lw=0.8)
        ax.set_xlabel('t (s)')
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        if i == 0:
            ax.legend(fontsize=7, ncol=3, title='boids (solid: policy, dashed: truth)', title_fontsize=7)
    for c, (name, (z, labels)) in enumerate((('policy', pred), ('ground truth', truth))):
        for r, (a, b) in enumerate(((0, 1), (0, 2))):
            ax = fig.add_subplot(grid[1, 6 * c + 3 * r : 6 * c + 3 * r + 3])
            _, groups = np.unique(labels, return_inverse=True)
            ax.scatter(z[:, a], z[:, b], c=groups, cmap='tab20', s=10)
            ax.plot([-box, box, box, -box, -box], [-box, -box, box, box, -box], color='k', lw=0.8)
            lim = max(box + 0.5, float(np.abs(z[:, [a, b]]).max()) + 0.5)
            ax.set_xlim(-lim, lim)
            ax.set_ylim(-lim, lim)
            ax.set_aspect('equal')
            ax.set_xlabel('xyz'[a])
            ax.set_ylabel('xyz'[b])
            ax.set_title(f'{name}: {groups.max() + 1} subswarms', fontsize=8)
    fig.suptitle(title, fontsize=10)
    _save(fig, path)


def heatmap(
    path: str,
    values: np.ndarray,
    rows: Sequence,
    cols: Sequence,
    title: str,
    row_label: str = 'd_cr',
    col_label: str = 'k',
) -> None:
    """One annotated heat map ``values [len(rows), len(cols)]`` (NaN = missing cell)."""
    fig, ax = plt.subplots(figsize=(1.2 * len(cols) + 2, 0.9 * len(rows) + 1.5))
    im = ax.imshow(values, cmap='viridis', origin='lower', aspect='auto')
    for i in range(len(rows)):
        for j in range(len(cols)):
            v = values[i, j]
            ax.text(
                j,
                i,
                '-' if not np.isfinite(v) else f'{v:.3g}',
                ha='center',
                va='center',
                color='w',
                fontsize=8,
            )
    ax.set_xticks(range(len(cols)))
    ax.set_xticklabels([str(c) for c in cols])
    ax.set_yticks(range(len(rows)))
    ax.set_yticklabels([str(r) for r in rows])
    ax.set_xlabel(col_label)
    ax.set_ylabel(row_label)
    ax.set_title(title, fontsize=10)
    fig.colorbar(im, ax=ax)
    _save(fig, path)


def training_curves(path: str, metrics_jsonl: str) -> None:
    """Train/validation loss and the selection score per epoch from a run's ``metrics.jsonl``."""
    with open(metrics_jsonl) as fh:
        recs = [json.loads(line) for line in fh if line.strip()]
    epochs = [r['epoch'] for r in recs]
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(10, 3.5))
    ax.plot(epochs, [r['train_loss'] for r in recs], label='train (noisy inputs)')
    if recs and recs[0].get('val_loss') is not None:
        ax.plot(epochs, [r['val_loss'] for r in recs], label='validation')
    ax.set_yscale('log')
    ax.set_xlabel('epoch')
    ax.set_ylabel('one-step loss')
    ax.legend()
    sel = [(r['epoch'], r['selection']['score']) for r in recs if 'selection' in r]
    if sel:
        bx.plot(*zip(*sel), marker='o')
    bx.set_xlabel('epoch')
    bx.set_ylabel('rollout selection score')
    bx.set_yscale('log')
    _save(fig, path)
