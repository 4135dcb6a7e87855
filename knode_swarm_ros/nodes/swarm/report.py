"""The launcher's closing summary: the recording's metrics, the simulator's figures and a PNG.

For a run of a learnt policy in a shipped scenario the ground-truth swarm from the recording's first frame
(:func:`knode_swarm_ros.core.groundtruth.follow`: Tanner's law, or the boids at their spawn
speed) is summarised and drawn beside it, so that one sees at a glance how close the learnt
swarm comes to the one it learnt from.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Dict, Optional

from .console import say as _say

__all__ = ['summarise', 'write_figure', 'CAPTION', 'name_never_heard']

#: What good looks like, under every figure of a run.
CAPTION = (
    'Good: avd falls low (the robots move alike; lower is better) and amd settles near the '
    "ground truth's (the same spacing)."
)


def name_never_heard(plan) -> list:
    """Say which robots the agents never heard (the simulator's report, from the agents'
    ``missing_names``); returns the names (none: [], and nothing said)."""
    try:
        names = json.loads((plan.run_dir / 'simulator.json').read_text()).get('never_heard') or []
    except (OSError, ValueError, AttributeError):
        return []
    if names:
        _say(
            f'robot(s) never heard by the agents: {", ".join(map(str, names))} (check that they publish on '
            "the fleet's state topic)"
        )
    return list(names)


def summarise(plan) -> Optional[Dict]:
    """Print the recording's metrics (and the simulator's figures); returns them."""
    import numpy as np

    from knode_swarm_ros.core.trajectory import TrajectoryError, load_trajectories
    from knode_swarm_ros.logic.recorder import swarm_metrics

    try:
        data = load_trajectories(plan.record)
    except TrajectoryError as exc:
        _say(f'no recording to summarise: {exc}')
        return None
    states = data.states[0]
    metrics = np.array([swarm_metrics(f, data.scenario) for f in states])
    tail = max(1, len(states) // 10)
    last = metrics[-tail:].mean(axis=0)
    info = {
        'frames': int(states.shape[0]),
        'robots': int(states.shape[1]),
        'dt': float(data.dt),
        'avd_start': float(metrics[0, 0]),
        'avd_end': float(metrics[-1, 0]),
        'amd_start': float(metrics[0, 1]),
        'amd_end': float(metrics[-1, 1]),
        'avd_last10pct': float(last[0]),
        'amd_last10pct': float(last[1]),
        'incomplete_frames': data.meta.get('incomplete_frames'),
        'interrupted': data.meta.get('interrupted'),
    }
    which = _direction_word(data.spec)
    _say(
        f'recorded {plan.record}: {info["frames"]} frames x {info["robots"]} robots, dt {data.dt:g} s'
        f'{" (interrupted)" if info["interrupted"] else ""}'
    )
    _say(
        f'avd ({which}): {info["avd_start"]:.4f} at start, {info["avd_end"]:.4f} at the end '
        f'(mean of the last 10%: {info["avd_last10pct"]:.4f})'
    )
    _say(
        f'amd (nearest-neighbour distance): {info["amd_start"]:.4f} at start, {info["amd_end"]:.4f} at the end '
        f'(mean of the last 10%: {info["amd_last10pct"]:.4f})'
    )
    report = plan.run_dir / 'simulator.json'
    if report.is_file():
        try:
            sim = json.loads(report.read_text())
        except ValueError:
            sim = {}
        if sim.get('steps_per_s') is not None:
            lat = sim.get('latency_ms') or {}
            extra = (
                f'; state-to-command latency p50 {lat["p50"]:.2f} ms, p99 {lat["p99"]:.2f} ms'
                if lat.get('p50') is not None
                else ''
            )
            _say(
                f'simulator: {sim.get("steps_run")} steps in {sim.get("run_s", 0):.2f} s '
                f'({sim["steps_per_s"]:.1f} steps/s) after {sim.get("startup_s", 0):.1f} s of startup{extra}'
            )
        info['simulator'] = sim
    truth, truth_metrics = _ground_truth(plan, states, data, swarm_metrics)
    if truth is not None:
        tl = truth_metrics[-tail:].mean(axis=0)
        info['ground_truth'] = {
            'variant': _variant(plan),
            'avd_end': float(truth_metrics[-1, 0]),
            'amd_end': float(truth_metrics[-1, 1]),
            'avd_last10pct': float(tl[0]),
            'amd_last10pct': float(tl[1]),
        }
        law = 'Tanner law' if data.scenario == 'flock2d' else 'boids'
        _say(
            f'ground truth from the same start ({_variant(plan)} {law}): avd {tl[0]:.4f}, amd {tl[1]:.4f} '
            f'(mean of the last 10%; the learnt swarm: avd {last[0]:.4f}, amd {last[1]:.4f})'
        )
    if plan.figure is not None:
        write_figure(
            plan.figure,
            states,
            data.dt,
            data.spec,
            metrics,
            f'{data.spec.name}, {states.shape[1]} robots, {plan.mode}',
            truth,
            truth_metrics,
        )
    return info


def _direction_word(spec) -> str:
    """What avd measures for the scenario's state (NaN for a position-only state)."""
    if spec.velocity is not None:
        return 'velocity difference'
    return 'heading difference' if spec.heading is not None else 'none: the state holds no velocity'


def _variant(plan) -> str:
    return getattr(plan, 'variant', None) or 'paper'


def _ground_truth(plan, states, data, swarm_metrics):
    """The ground-truth swarm ``[T, n, d]`` from the recording's first frame and its (avd, amd)
    per frame, or (None, None): a run that is itself the ground truth, a bad start."""
    import numpy as np

    from knode_swarm_ros.core.groundtruth import follow
    from knode_swarm_ros.logic.simulator.swarm_sim import has_ground_truth

    if not has_ground_truth(data.spec) or getattr(plan, 'ground_truth', False):
        return None, None
    try:
        truth = follow(data.scenario, states[0], states.shape[0], float(data.dt), _variant(plan))
    except ValueError as exc:
        _say(f'no ground truth beside the run: {exc}')
        return None, None
    return truth, np.array([swarm_metrics(f, data.scenario) for f in truth])


def _draw_trajectories(ax, states, spec, title: str) -> None:
    # one grey path per robot: a swarm of colours is a tangle; start and end say the rest
    for i in range(states.shape[1]):
        ax.plot(states[:, i, 0], states[:, i, 1], lw=0.6, color='0.6')
    ax.scatter(states[0, :, 0], states[0, :, 1], c='k', s=10, marker='o', label='start')
    ax.scatter(states[-1, :, 0], states[-1, :, 1], c='r', s=14, marker='x', label='end')
    ax.set_xlabel('x [m]')
    ax.set_ylabel('y [m]')
    ax.set_aspect('equal', adjustable='datalim')
    ax.legend(loc='best', fontsize=8)
    ax.set_title(title + (' (x-y projection)' if spec.dimensions == 3 else ''))


def write_figure(
    path: Path, states, dt: float, scenario, metrics, title: str, truth=None, truth_metrics=None
) -> bool:
    """Trajectories and avd/amd over time as a PNG (matplotlib is imported only here); with
    ``truth [T, n, d]`` and its ``truth_metrics [T, 2]`` the ground-truth swarm from the same
    start gets its own trajectory panel and its curves beside the run's. ``scenario``: any
    scenario reference."""
    from knode_swarm_ros.core.scenarios import get_scenario

    spec = get_scenario(scenario)
    try:
        import matplotlib

        matplotlib.use('Agg')
        import matplotlib.pyplot as plt
    except ImportError:
        _say('matplotlib is not installed: no figure (pip install matplotlib)')
        return False
    import numpy as np

    t = np.arange(states.shape[0]) * dt
    panels = 3 if truth is None else 4
    fig, axes = plt.subplots(1, panels, figsize=(5 * panels, 4.5))
    _draw_trajectories(axes[0], states, spec, 'trajectories' if truth is None else 'learnt swarm')
    if truth is not None:
        _draw_trajectories(axes[1], truth, spec, 'ground truth, same start')
        both = np.concatenate([states[..., :2].reshape(-1, 2), truth[..., :2].reshape(-1, 2)])
        both = both[np.all(np.isfinite(both), axis=1)]
        if len(both):  # one scale for both swarms, so that they compare by eye
            lo, hi = both.min(axis=0), both.max(axis=0)
            pad = 0.05 * max(float((hi - lo).max()), 1e-6)
            for ax in axes[:2]:
                ax.set_aspect('equal', adjustable='box')
                ax.set_xlim(lo[0] - pad, hi[0] + pad)
                ax.set_ylim(lo[1] - pad, hi[1] + pad)
    ax_avd, ax_amd = axes[-2], axes[-1]
    avd_unit = '[m/s]' if spec.heading is None else '(unit headings)'
    for ax, col, name, unit in (
        (ax_avd, 0, 'avd: ' + _direction_word(spec), avd_unit),
        (ax_amd, 1, 'amd: nearest-neighbour distance', '[m]'),
    ):
        ax.plot(t, metrics[:, col], label='learnt' if truth is not None else None)
        if truth is not None:
            ax.plot(np.arange(truth.shape[0]) * dt, truth_metrics[:, col], '--', label='ground truth')
            ax.legend(loc='best', fontsize=8)
        ax.set_xlabel('t [s]')
        ax.set_ylabel(f'{name.split(":")[0]} {unit}')
        ax.set_title(name)
    # log, as in training.evaluate: the flocked state is orders of magnitude below the start
    ax_avd.set_yscale('log')
    fig.suptitle(title)
    fig.text(0.5, 0.01, CAPTION, ha='center', fontsize=9)
    fig.tight_layout(rect=(0, 0.05, 1, 1))
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    _say(f'figure: {path}')
    return True
