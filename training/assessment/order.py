"""Order parameters of learnt against observed swarms, for any scenario (docs/scenarios.md,
"Order parameters"): per-rollout values, their 95 % intervals, a markdown table and a figure.

Shapes: S rollouts, T frames, n robots, d state entries. A rollout's value of an order parameter
is its mean over the last ``last`` frames (the swarm's settled state); escapes and the closest
approach are over the whole rollout.
"""

from __future__ import annotations

from typing import Any, Dict, List, Optional

import numpy as np

from knode_swarm_ros.core.metrics import (
    closest_approach,
    escaped,
    group_count,
    nearest_neighbour_distance,
    polarisation,
    rotation_order,
    speed_quantiles,
    velocities,
)
from knode_swarm_ros.core.scenarios import Scenario

from .stats import interval, mean_ci

__all__ = ['ORDER_PARAMETERS', 'order_parameters', 'compare_orders', 'order_lines', 'order_figure']

#: name -> (label with unit, unit) of each reported order parameter.
ORDER_PARAMETERS = {
    'nn_distance': ('nearest-neighbour distance', 'm'),
    'polarisation': ('polarisation', ''),
    'rotation_order': ('rotation order', ''),
    'speed_q05': ('speed, 5th percentile', 'm/s'),
    'speed_median': ('speed, median', 'm/s'),
    'speed_q95': ('speed, 95th percentile', 'm/s'),
    'groups': ('groups (linked within 2 x median nn distance)', ''),
    'escapes': ('escapes from the arena', 'robots'),
    'closest_approach': ('closest approach', 'm'),
}


def _series(spec: Scenario, states: np.ndarray, dt: float) -> Dict[str, np.ndarray]:
    """Per-frame order parameters ``[S, T]`` of ``states [S, T, n, d]``."""
    p = states[..., spec.position]
    v = velocities(states, spec, dt)
    return {
        'nn_distance': nearest_neighbour_distance(p).mean(axis=-1),
        'polarisation': polarisation(v),
        'rotation_order': rotation_order(p, v),
    }


def order_parameters(
    spec: Scenario, states: np.ndarray, dt: float, last: int = 20, link: Optional[float] = None
) -> Dict[str, List[float]]:
    """Per-rollout order parameters ``{name: [S]}`` of ``states [S, T, n, d]`` (T >= 2).

    ``link``: the distance that links robots into groups (default twice the rollouts' median
    nearest-neighbour distance over the last frames; pass the observed swarm's to compare
    alike). Escapes only with an arena.
    """
    states = np.asarray(states, dtype=np.float64)
    last = max(1, min(last, states.shape[1]))
    series = _series(spec, states, dt)
    out = {name: values[:, -last:].mean(axis=1).tolist() for name, values in series.items()}
    v = velocities(states, spec, dt)[:, -last:]
    q = speed_quantiles(v.reshape(v.shape[0], -1, v.shape[-1]), (0.05, 0.5, 0.95))  # [S, 3]
    out['speed_q05'], out['speed_median'], out['speed_q95'] = (q[:, i].tolist() for i in range(3))
    p = states[..., spec.position]
    if link is None:
        link = 2.0 * float(np.median(nearest_neighbour_distance(p[:, -last:])))
    out['groups'] = group_count(p[:, -1], link).astype(float).tolist()
    if spec.arena is not None:
        out['escapes'] = escaped(p, spec.arena).sum(axis=-1).astype(float).tolist()
    out['closest_approach'] = closest_approach(p).tolist()
    return out


def compare_orders(
    spec: Scenario, learnt: np.ndarray, observed: np.ndarray, dt: float, last: int = 20
) -> Dict[str, Any]:
    """Learnt against observed rollouts ``[S, T, n, d]`` (the same starts): per order parameter
    ``{'learnt': interval, 'observed': interval, 'per_rollout': {...}}`` (:func:`.stats.interval`,
    a 95 % t interval of the mean over rollouts)."""
    obs = order_parameters(spec, observed, dt, last)
    link = 2.0 * float(np.median(nearest_neighbour_distance(observed[:, -last:, :, spec.position])))
    lrn = order_parameters(spec, learnt, dt, last, link)
    return {
        name: {
            'learnt': interval(lrn[name]),
            'observed': interval(obs[name]),
            'per_rollout': {'learnt': lrn[name], 'observed': obs[name]},
        }
        for name in obs
    }


def order_lines(orders: Dict[str, Any]) -> List[str]:
    """Markdown table of :func:`compare_orders`: mean [95 % interval] learnt and observed."""

    def cell(s):
        return f'{s["mean"]:.3g} [{s["lo"]:.3g}, {s["hi"]:.3g}]'

    lines = ['| order parameter | learnt | observed |', '| --- | --- | --- |']
    for name, entry in orders.items():
        label, unit = ORDER_PARAMETERS[name]
        label = f'{label} ({unit})' if unit else label
        lines.append(f'| {label} | {cell(entry["learnt"])} | {cell(entry["observed"])} |')
    return lines


def order_figure(
    path: str, spec: Scenario, learnt: np.ndarray, observed: np.ndarray, dt: float, title: str
) -> None:
    """Nearest-neighbour distance, polarisation and rotation order over time (mean and 95 %
    interval over the rollouts), learnt beside observed, and the speed distributions."""
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    t = np.arange(observed.shape[1]) * dt
    series = {'learnt (KNODE)': _series(spec, learnt, dt), 'observed (the law)': _series(spec, observed, dt)}
    colours = {'learnt (KNODE)': 'tab:blue', 'observed (the law)': 'black'}
    fig, axes = plt.subplots(1, 4, figsize=(17, 3.8))
    panels = [
        ('nn_distance', 'nearest-neighbour distance (m)'),
        ('polarisation', 'polarisation (1: aligned)'),
        ('rotation_order', 'rotation order (1: milling)'),
    ]
    for ax, (key, ylabel) in zip(axes, panels):
        for label, s in series.items():
            mean, half = mean_ci(s[key], axis=0, t=True)
            ax.plot(t, mean, color=colours[label], label=label)
            ax.fill_between(t, mean - half, mean + half, color=colours[label], alpha=0.2)
        ax.set_xlabel('time (s)')
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
    axes[0].legend(loc='best', fontsize=8)
    for label, states in (('learnt (KNODE)', learnt), ('observed (the law)', observed)):
        v = velocities(states, spec, dt)[:, -20:]
        axes[3].hist(
            np.linalg.norm(v, axis=-1).ravel(),
            bins=30,
            histtype='step',
            density=True,
            color=colours[label],
            label=label,
        )
    axes[3].set_xlabel('speed over the last 20 frames (m/s)')
    axes[3].set_ylabel('density')
    axes[3].legend(loc='best', fontsize=8)
    fig.suptitle(title + ' (mean and 95 % interval over the starts)')
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
