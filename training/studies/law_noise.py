"""A law recorded as a motion-capture system records it, and what the recording costs the learnt
swarm (docs/noise.md, "A swarm of our own"): the law between its steps, the import against the
law, and the table and figure over noise levels, rates and training seeds that
``python -m training.studies.custom_laws --noise-mm ... --rate ...`` writes.
"""

from __future__ import annotations

from typing import Any, Dict, List, Optional, Tuple

import numpy as np

from .laws import Law, initial_states, simulate

__all__ = [
    'ORDERS',
    'law_at',
    'import_against_law',
    'paired_difference',
    'noise_table',
    'noise_figure',
]

#: order parameters compared (results.json keys) and their column labels
ORDERS = (
    ('nn_distance', 'nn distance (m)'),
    ('polarisation', 'polarisation'),
    ('rotation_order', 'rotation'),
)


def law_at(law: Law, states: np.ndarray, times: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """Positions and velocities ``[len(times), n, dim]`` of one trajectory ``states [T + 1, n, d]``
    of ``law`` at any ``times`` in seconds, exact for the zero-order hold's steps: for
    acceleration commands the cubic Hermite of the steps' positions and velocities (a quadratic
    step), for velocity commands the straight line between the steps' positions (the velocity
    constant over a step)."""
    dt, d = law.scenario.dt, law.scenario.dimensions
    times = np.asarray(times, dtype=np.float64)
    k = np.clip((times / dt).astype(int), 0, states.shape[0] - 2)
    s = (times / dt - k)[:, None, None]
    p = states[..., :d]
    if law.scenario.command == 'velocity':
        step = (p[k + 1] - p[k]) / dt
        return p[k] + s * dt * step, step
    v = states[..., d : 2 * d]
    h = (2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2)
    dh = (6 * s**2 - 6 * s, 3 * s**2 - 4 * s + 1, -6 * s**2 + 6 * s, 3 * s**2 - 2 * s)
    pos = h[0] * p[k] + h[1] * dt * v[k] + h[2] * p[k + 1] + h[3] * dt * v[k + 1]
    vel = (dh[0] * p[k] + dh[2] * p[k + 1]) / dt + dh[1] * v[k] + dh[3] * v[k + 1]
    return pos, vel


def import_against_law(law: Law, data, trajectories: int, robots: int, seed: int) -> Dict[str, float]:
    """The imported file ``data`` against the law it recorded (the swarms of
    ``initial_states(law, trajectories, robots, seed)``), each frame at its time in the recording
    (``meta.trajectories[i].start_ns``): position RMS error per axis (m), the velocity's (m/s)
    where the state has one, the heading's (rad: the RMS angle to the law's heading) where it
    has one, and the importer's noise estimate (m, mean over the episodes)."""
    from knode_swarm_ros.core import load_trajectories

    loaded = load_trajectories(data)
    meta, spec = loaded.meta, law.scenario
    truth = simulate(law, initial_states(law, trajectories, robots, seed), law.steps)
    dp, dv, angle = [], [], []
    for states, traj in zip(loaded.states, meta['trajectories']):
        times = traj['start_ns'] * 1e-9 + np.arange(states.shape[0]) * loaded.dt
        pos, vel = law_at(law, truth[traj['episode']], times)
        dp.append(states[..., spec.position] - pos)
        if spec.velocity is not None:
            dv.append(states[..., spec.velocity] - vel)
        if spec.heading is not None:
            # the law's state whose step is nearest t: the grid samples the law's steps, late by
            # the stamps' offset, and a heading is the direction of the step that ended there
            k = np.clip(np.round(times / spec.dt).astype(int), 1, law.steps)
            h, ref = states[..., spec.heading], truth[traj['episode']][k][..., spec.heading]
            cos = (h * ref).sum(-1) / np.maximum(
                np.linalg.norm(h, axis=-1) * np.linalg.norm(ref, axis=-1), 1e-12
            )
            angle.append(np.arccos(np.clip(cos, -1.0, 1.0)))
    estimates = [s['noise']['noise_std'] for s in meta.get('sources', []) if s.get('noise')]

    def rms(parts):
        return (
            float(np.sqrt(np.mean(np.concatenate([np.square(x).ravel() for x in parts]))))
            if parts
            else float('nan')
        )

    out = {
        'position_rms': rms(dp),
        'velocity_rms': rms(dv),
        'noise_estimate': float(np.mean(estimates)) if estimates else float('nan'),
    }
    if spec.heading is not None:
        out['heading_rms'] = rms(angle)
    return out


def paired_difference(a: List[float], b: List[float]) -> Tuple[float, float]:
    """Mean and standard error of ``a - b`` over the same starts."""
    diff = np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64)
    se = float(np.std(diff, ddof=1) / np.sqrt(diff.size)) if diff.size > 1 else float('nan')
    return float(np.mean(diff)), se


def _per_start(result: Dict[str, Any], name: str, who: str = 'learnt') -> List[float]:
    return result['orders'][name]['per_rollout'][who]


def _goals_met(result: Dict[str, Any]) -> Tuple[int, int]:
    keys = [
        k for k in result['goals'] if k.startswith(('nn_within', 'polarisation_within', 'rotation_within'))
    ]
    return sum(bool(result['goals'][k]) for k in keys), len(keys)


def noise_table(cases: List[Dict[str, Any]], robots: int = 10) -> str:
    """Markdown: one row per (rate, noise, training seed): the importer's noise estimate and
    errors against the law, the order parameters (mean ± std over the held-out starts), their
    differences to the law and, per start, to the 0-mm case of the same rate and seed (mean ±
    standard error). ``cases``: ``{'noise_mm', 'rate', 'seed', 'import', 'eval', 'train_seconds',
    'load'}`` with ``eval`` the ``results.json`` of :func:`law_goals.evaluate_law`."""
    key = f'n{robots}'
    head = [
        'noise (mm)',
        'rate (Hz)',
        'seed',
        'estimate (mm)',
        'position error (mm)',
        # a heading state's velocity is not in the state: its heading's error instead
        'heading error (mrad)' if 'heading_rms' in cases[0]['import'] else 'velocity error (mm/s)',
    ]
    head += [label for _, label in ORDERS] + [f'{label} vs law' for _, label in ORDERS]
    head += [f'{label} vs 0 mm' for _, label in ORDERS] + ['goals met', 'train s', 'load']
    lines = ['| ' + ' | '.join(head) + ' |', '|' + ' --- |' * len(head)]
    by = {(c['rate'], c['seed'], c['noise_mm']): c for c in cases}
    for c in sorted(cases, key=lambda c: (-c['rate'], c['seed'], c['noise_mm'])):
        r = c['eval'][key]
        if len(lines) == 2:  # the law from the same held-out starts, whatever the case
            cells = [
                f'{np.mean(_per_start(r, n, "observed")):.3g} ± {np.std(_per_start(r, n, "observed"), ddof=1):.2g}'
                for n, _ in ORDERS
            ]
            lines.append(
                '| '
                + ' | '.join(['law', '', '', '', '', ''] + cells + [''] * (len(head) - 6 - len(ORDERS)))
                + ' |'
            )
        imp = c['import']
        cells = [f'{c["noise_mm"]:g}', f'{c["rate"]:g}', str(c['seed'])]
        cells += [
            f'{imp["noise_estimate"] * 1e3:.3g}',
            f'{imp["position_rms"] * 1e3:.2g}',
            f'{imp.get("heading_rms", imp["velocity_rms"]) * 1e3:.3g}',
        ]
        cells += [
            f'{np.mean(_per_start(r, n)):.3g} ± {np.std(_per_start(r, n), ddof=1):.2g}' for n, _ in ORDERS
        ]
        for n, _ in ORDERS:
            learnt, law = r['orders'][n]['learnt']['mean'], r['orders'][n]['observed']['mean']
            cells.append(
                f'{100 * (learnt / law - 1):+.0f} %' if n == 'nn_distance' else f'{learnt - law:+.3f}'
            )
        base = by.get((c['rate'], c['seed'], 0.0))
        for n, _ in ORDERS:
            if base is None or base is c:
                cells.append('')
            else:
                mean, se = paired_difference(_per_start(r, n), _per_start(base['eval'][key], n))
                cells.append(f'{mean:+.3f} ± {se:.3f}')
        met, total = _goals_met(r)
        cells += [f'{met} / {total}', f'{c["train_seconds"]:.0f}', f'{c["load"][0]:.1f}-{c["load"][1]:.1f}']
        lines.append('| ' + ' | '.join(cells) + ' |')
    return '\n'.join(lines) + '\n'


def noise_figure(
    cases: List[Dict[str, Any]], path: str, robots: int = 10, title: Optional[str] = None
) -> None:
    """Order parameters against the noise, one line per (rate, seed): the mean over the held-out
    starts with its standard error; the law's mean as a dotted line."""
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    key = f'n{robots}'
    fig, axes = plt.subplots(1, len(ORDERS), figsize=(4.2 * len(ORDERS), 3.8))
    groups = sorted({(c['rate'], c['seed']) for c in cases}, key=lambda g: (-g[0], g[1]))
    for j, (rate, seed) in enumerate(groups):
        sel = sorted(
            (c for c in cases if (c['rate'], c['seed']) == (rate, seed)), key=lambda c: c['noise_mm']
        )
        # a log noise axis, 0 mm drawn at 0.2 mm; the groups side by side
        x = np.array([max(c['noise_mm'], 0.2) for c in sel]) * (1 + 0.03 * (j - len(groups) / 2))
        for ax, (name, label) in zip(axes, ORDERS):
            values = [_per_start(c['eval'][key], name) for c in sel]
            ax.errorbar(
                x,
                [np.mean(v) for v in values],
                [np.std(v, ddof=1) / np.sqrt(len(v)) for v in values],
                marker='o' if seed == groups[0][1] else 's',
                ls='-' if seed == groups[0][1] else '--',
                capsize=3,
                label=f'{rate:g} Hz, seed {seed}',
            )
    for ax, (name, label) in zip(axes, ORDERS):
        ax.axhline(cases[0]['eval'][key]['orders'][name]['observed']['mean'], ls=':', c='k', label='the law')
        ax.set(xscale='log', xlabel='position noise (mm)', ylabel=label)
        levels = sorted({c['noise_mm'] for c in cases})
        ax.set_xticks([max(x, 0.2) for x in levels], [f'{x:g}' for x in levels])
        ax.minorticks_off()
    axes[0].legend(fontsize=7)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
