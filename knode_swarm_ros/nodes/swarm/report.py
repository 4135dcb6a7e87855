"""The launcher's closing summary: the recording's metrics, the simulator's figures and a PNG."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Dict, Optional

from .console import say as _say

__all__ = ['summarise', 'write_figure']


def summarise(plan) -> Optional[Dict]:
    """Print the recording's metrics (and the simulator's figures); returns them."""
    import numpy as np
    from ...core.trajectory import TrajectoryError, load_trajectories
    from ..recorder_logic import swarm_metrics
    try:
        data = load_trajectories(plan.record)
    except TrajectoryError as exc:
        _say(f'no recording to summarise: {exc}')
        return None
    states = data.states[0]
    metrics = np.array([swarm_metrics(f, data.scenario) for f in states])
    tail = max(1, len(states) // 10)
    last = metrics[-tail:].mean(axis=0)
    info = {'frames': int(states.shape[0]), 'robots': int(states.shape[1]), 'dt': float(data.dt),
            'avd_start': float(metrics[0, 0]), 'avd_end': float(metrics[-1, 0]), 'amd_start': float(metrics[0, 1]),
            'amd_end': float(metrics[-1, 1]), 'avd_last10pct': float(last[0]), 'amd_last10pct': float(last[1]),
            'incomplete_frames': data.meta.get('incomplete_frames'), 'interrupted': data.meta.get('interrupted')}
    which = 'velocity' if data.scenario == 'flock2d' else 'heading'
    _say(f'recorded {plan.record}: {info["frames"]} frames x {info["robots"]} robots, dt {data.dt:g} s'
         f'{" (interrupted)" if info["interrupted"] else ""}')
    _say(f'avd ({which} difference): {info["avd_start"]:.4f} at start, {info["avd_end"]:.4f} at the end '
         f'(mean of the last 10%: {info["avd_last10pct"]:.4f})')
    _say(f'amd (nearest-neighbour distance): {info["amd_start"]:.4f} at start, {info["amd_end"]:.4f} at the end '
         f'(mean of the last 10%: {info["amd_last10pct"]:.4f})')
    report = plan.run_dir / 'simulator.json'
    if report.is_file():
        try:
            sim = json.loads(report.read_text())
        except ValueError:
            sim = {}
        if sim.get('steps_per_s') is not None:
            lat = sim.get('latency_ms') or {}
            extra = (f'; state-to-command latency p50 {lat["p50"]:.2f} ms, p99 {lat["p99"]:.2f} ms'
                     if lat.get('p50') is not None else '')
            _say(f'simulator: {sim.get("steps_run")} steps in {sim.get("run_s", 0):.2f} s '
                 f'({sim["steps_per_s"]:.1f} steps/s) after {sim.get("startup_s", 0):.1f} s of startup{extra}')
        info['simulator'] = sim
    if plan.figure is not None:
        write_figure(plan.figure, states, data.dt, data.scenario, metrics,
                     f'{data.scenario}, {states.shape[1]} robots, {plan.mode}')
    return info


def write_figure(path: Path, states, dt: float, scenario: str, metrics, title: str) -> bool:
    """Trajectories and avd/amd over time as a PNG (matplotlib is imported only here)."""
    try:
        import matplotlib
        matplotlib.use('Agg')
        import matplotlib.pyplot as plt
    except ImportError:
        _say('matplotlib is not installed: no figure (pip install matplotlib)')
        return False
    import numpy as np
    t = np.arange(states.shape[0]) * dt
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.5))
    ax = axes[0]
    for i in range(states.shape[1]):
        ax.plot(states[:, i, 0], states[:, i, 1], lw=0.8)
    ax.scatter(states[0, :, 0], states[0, :, 1], c='k', s=10, marker='o', label='start')
    ax.scatter(states[-1, :, 0], states[-1, :, 1], c='r', s=14, marker='x', label='end')
    ax.set_xlabel('x')
    ax.set_ylabel('y')
    ax.set_aspect('equal', adjustable='datalim')
    ax.legend(loc='best', fontsize=8)
    ax.set_title('trajectories' + (' (x-y projection)' if scenario == 'boids3d' else ''))
    axes[1].plot(t, metrics[:, 0])
    axes[1].set_xlabel('t [s]')
    axes[1].set_title('avd: ' + ('velocity' if scenario == 'flock2d' else 'heading') + ' difference')
    axes[2].plot(t, metrics[:, 1])
    axes[2].set_xlabel('t [s]')
    axes[2].set_title('amd: nearest-neighbour distance')
    fig.suptitle(title)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    _say(f'figure: {path}')
    return True
