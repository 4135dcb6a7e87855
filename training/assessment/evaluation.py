"""Evaluating a policy file against ground truth (the library behind ``python -m training.evaluate``
and ``training.demo``): rollouts from the test split, metric curves, snapshots, the goals,
the scaling study (boids3d through :mod:`training.assessment.scaling`), ``results.json`` and
``summary.md``. Shapes: S rollouts, T frames, n robots, d state entries.
"""

from __future__ import annotations

import os
import time
from typing import Any, Dict, List, Optional, Sequence

import numpy as np

from knode_swarm_ros.core import (
    TrajectoryError,
    amd,
    avd,
    get_scenario,
    load_policy,
    load_trajectories,
    pod_energy,
)
from knode_swarm_ros.core.errors import KnodeError
from knode_swarm_ros.core.metrics import velocities
from training.learning.period import period_ratio, subsample
from training.learning.records import write_json

from . import figures
from .order import compare_orders, order_figure, order_lines
from .scores import final_metrics, rollout_policy
from .stats import describe

# The goals a policy is reported against (not enforced).
GOALS = {
    'flock2d': 'mean final avd <= 0.05; mean final amd within 15% of ground truth; min distance after 1 s > 0.3',
    'boids3d': 'final amd within 25% of ground truth; mean POD-KLD <= 0.05; >= 18 of 20 rollouts stay in the cube',
}
# Any other scenario: the order parameters of the learnt swarm against the observed one.
CUSTOM_GOALS = (
    'nearest-neighbour distance within 15% of the observed; polarisation and rotation order within 0.10; '
    'no more escapes than observed'
)


def goal_check(scenario: str, fm: Dict[str, Any]) -> Dict[str, Any]:
    """Pass/fail per goal from :func:`final_metrics` of the test rollouts."""
    amd_p, amd_t = np.mean(fm['amd_final']), np.mean(fm['truth_amd_final'])
    rel = abs(amd_p - amd_t) / amd_t
    if scenario not in GOALS:
        out = {'amd_within_15%': bool(rel <= 0.15), 'amd_rel_error': float(rel)}
        for key in ('polarisation', 'rotation'):
            err = abs(np.mean(fm[f'order_{key}']) - np.mean(fm[f'truth_order_{key}']))
            out[f'{key}_within_0.10'] = bool(err <= 0.10)
            out[f'{key}_error'] = float(err)
        if 'order_escapes' in fm:
            out['escapes_not_more'] = bool(np.sum(fm['order_escapes']) <= np.sum(fm['truth_order_escapes']))
        return out
    if scenario == 'flock2d':
        return {
            'avd_final<=0.05': bool(np.mean(fm['avd_final']) <= 0.05),
            'amd_within_15%': bool(rel <= 0.15),
            'amd_rel_error': float(rel),
            'no_collision(min_dist>0.3)': bool(np.min(fm['min_distance']) > 0.3),
        }
    inside = int(np.sum(fm['stays_inside']))
    return {
        'amd_within_25%': bool(rel <= 0.25),
        'amd_rel_error': float(rel),
        'pod_kld<=0.05': bool(np.mean(fm['pod_kld']) <= 0.05),
        'stay_in_cube>=18/20': bool(inside >= 0.9 * len(fm['stays_inside'])),
        'rollouts_inside': inside,
    }


def evaluate(
    policy_path: str,
    data_path: str,
    out: str,
    trajectories: int = 20,
    steps: Optional[int] = None,
    scaling: bool = False,
    sizes: Sequence[int] = (10, 50, 90),
    ics: int = 15,
    scaling_steps: Optional[int] = None,
    seed: int = 1234,
    log=print,
    preset: str = 'paper',
) -> Dict[str, Any]:
    """Run the evaluation and write figures, ``results.json`` and ``summary.md``; returns the results."""
    policy = load_policy(policy_path)
    if data_path is None:
        return scaling_only(policy, policy_path, out, sizes, ics, scaling_steps, seed, preset, log)
    spec = get_scenario(policy.scenario)
    data = load_trajectories(data_path, scenario=policy.scenario)
    test, used = data.split('test')[:trajectories], 'test'
    if len(test) == 0:  # e.g. one imported bag: evaluate on what there is, and say so
        test, used = np.arange(data.states.shape[0])[:trajectories], 'all (no test split)'
        log(
            f'{data_path} has no test split (meta.split.test is empty): evaluating on its '
            f'{len(test)} trajectories, which training may have seen; the scores are optimistic'
        )
    if len(test) == 0:
        raise TrajectoryError(f'{data_path}: no trajectories to evaluate')
    truth = data.states[test]
    try:  # a policy trained for a longer period (data.policy_dt) is compared at its own dt
        ratio = period_ratio(data.dt, policy.dt, "the policy's dt")
        truth = subsample(truth, ratio)
    except ValueError:
        ratio = None  # not a whole multiple: warned below
    if steps is not None:
        truth = truth[:, : steps + 1]
    T = truth.shape[1]
    if T < 2:
        raise TrajectoryError(f'{data_path}: test trajectories hold {T} frame(s); evaluation needs >= 2')
    if ratio is None:
        log(
            f"warning: data dt {data.dt} differs from the policy's dt {policy.dt}; rolling out with the policy's"
        )
    os.makedirs(out, exist_ok=True)
    t0 = time.perf_counter()
    pred = rollout_policy(policy, truth[:, 0], T - 1)
    rollout_s = time.perf_counter() - t0
    finite = bool(np.all(np.isfinite(pred)))
    time_axis = np.arange(T) * policy.dt
    p = spec.position
    fm = final_metrics(spec, pred, truth, dt=policy.dt)
    curves: Dict[str, Dict[str, np.ndarray]] = {}
    if spec.velocity is not None:
        curves['avd'] = {
            'prediction': avd(pred[..., spec.velocity]),
            'ground truth': avd(truth[..., spec.velocity]),
        }
    curves['amd'] = {'prediction': amd(pred[..., p]), 'ground truth': amd(truth[..., p])}
    figures.metric_curves(
        os.path.join(out, 'metrics.png'),
        time_axis,
        curves,
        f'{spec.name}: {len(test)} test rollouts, mean and 95% CI',
    )
    # order parameters for every scenario, learnt against observed (beside avd/amd)
    orders = compare_orders(spec, pred, truth, policy.dt) if finite else None
    if orders is not None:
        order_figure(
            os.path.join(out, 'orders.png'),
            spec,
            pred,
            truth,
            policy.dt,
            f'{spec.name}: {len(test)} test rollouts of {truth.shape[2]} robots',
        )
    frames = sorted({0, T // 10, T // 2, T - 1})
    shown = [pred[0], truth[0]]
    if spec.state == 'position':  # the arrows show velocities: differences of the positions
        shown = [np.concatenate([z, velocities(z, spec, policy.dt)], axis=-1) for z in shown]
    figures.snapshots(
        os.path.join(out, 'snapshots.png'), *shown, frames, policy.dt, spec.position_dim, spec.box
    )
    results: Dict[str, Any] = {
        'policy': os.path.abspath(policy_path),
        'data': os.path.abspath(data_path),
        'scenario': spec.name,
        'scenario_spec': spec.to_dict(),
        'test_trajectories': test.tolist(),
        'trajectories_used': used,
        'robots': int(truth.shape[2]),
        'steps': T - 1,
        'dt': policy.dt,
        'rollout_seconds': round(rollout_s, 2),
        'finite': finite,
        'goals': GOALS.get(spec.name if spec.shipped else '', CUSTOM_GOALS),
        'policy_meta': {
            k: policy.meta.get(k) for k in ('k', 'd_cr', 'tau', 'frame', 'command_limit', 'hidden')
        },
        'per_trajectory': fm,
        'final': {key: describe(v) for key, v in fm.items() if key != 'stays_inside'},
        'curves_mean': {
            name: {label: np.mean(v, axis=0)[:: max(T // 200, 1)].tolist() for label, v in s.items()}
            for name, s in curves.items()
        },
    }
    if spec.name == 'boids3d':
        e_pred = np.stack([pod_energy(pred[s]) for s in range(len(test))])
        e_true = np.stack([pod_energy(truth[s]) for s in range(len(test))])
        figures.pod_bars(os.path.join(out, 'pod.png'), e_pred, e_true, fm['pod_kld'])
        results['pod_energy'] = {
            'prediction': e_pred.mean(0).tolist(),
            'ground truth': e_true.mean(0).tolist(),
        }
        results['rollouts_inside'] = int(np.sum(fm['stays_inside']))
    if orders is not None:
        results['orders'] = orders
    results['goal_check'] = goal_check(spec.name if spec.shipped else '', fm) if finite else {'finite': False}
    if scaling:
        results['scaling'] = scaling_study(
            policy, out, sizes, ics, scaling_steps or (T - 1), seed, log, preset
        )
    write_json(os.path.join(out, 'results.json'), results)
    write_summary(os.path.join(out, 'summary.md'), results)
    log(f'wrote {out}/results.json, summary.md and figures ({rollout_s:.1f} s of rollouts)')
    return results


def scaling_only(
    policy,
    policy_path: str,
    out: str,
    sizes: Sequence[int],
    ics: int,
    steps: Optional[int],
    seed: int,
    preset: str,
    log=print,
) -> Dict[str, Any]:
    """The scaling study without a test set: ``results.json`` and ``summary.md`` hold only it."""
    if steps is None:
        raise ValueError('--scaling-steps is required without --data (no ground truth sets the length)')
    os.makedirs(out, exist_ok=True)
    results = {
        'policy': os.path.abspath(policy_path),
        'scenario': policy.scenario,
        'dt': policy.dt,
        'policy_meta': {
            k: policy.meta.get(k) for k in ('k', 'd_cr', 'tau', 'frame', 'command_limit', 'hidden')
        },
        'scaling': scaling_study(policy, out, sizes, ics, steps, seed, log, preset),
    }
    write_json(os.path.join(out, 'results.json'), results)
    lines = [f'# Scaling study: {policy.scenario}', '', f'- policy: `{results["policy"]}`', '']
    lines += _scaling_lines(results['scaling'])
    with open(os.path.join(out, 'summary.md'), 'w') as fh:
        fh.write('\n'.join(lines + ['Figures: ' + ', '.join(_scaling_figures(policy.scenario)), '']))
    log(f'wrote {out}/results.json, summary.md and figures')
    return results


def _scaling_figures(scenario: str) -> List[str]:
    return ['scaling.png', 'departures.png'] if scenario == 'boids3d' else ['scaling.png']


def scaling_study(
    policy, out: str, sizes: Sequence[int], ics: int, steps: int, seed: int, log=print, preset: str = 'paper'
) -> Dict[str, Any]:
    """Roll the policy out at several swarm sizes from ground-truth initial conditions.

    Initial conditions come from :func:`knode_swarm_ros.core.groundtruth.simulate` with ``preset``
    (flock2d: the paper's disk of radius sqrt(n), i.e. the training density; boids3d: the spawn
    ball in the fixed cube, so density grows with n), which also gives the ground truth at each
    size. boids3d: :func:`training.assessment.scaling.scaling_study`.
    """
    from knode_swarm_ros.core.groundtruth import simulate

    spec = get_scenario(policy.scenario)
    if not spec.shipped:
        raise KnodeError(
            f'--scaling: scenario {spec.name} has no ground-truth law in the package; roll out '
            'held-out starts of your own law instead (training.studies.custom_laws shows how)'
        )
    if spec.name == 'boids3d':
        from . import scaling

        return scaling.scaling_study(policy, out, sizes, ics, steps, seed, preset, log=log)
    rows: List[Dict[str, Any]] = []
    boxes: Dict[str, Dict[str, List[List[float]]]] = {}
    names = ['avd', 'amd'] if spec.velocity is not None else ['amd', 'pod_kld']
    for name in names:
        boxes[name] = {'prediction': []} if name == 'pod_kld' else {'prediction': [], 'ground truth': []}
    for n in sizes:
        t0 = time.perf_counter()
        truth = simulate(spec.name, ics, n, steps + 1, seed + n, preset=preset, progress=False)
        pred = rollout_policy(policy, truth[:, 0], steps)
        fm = final_metrics(spec, pred, truth, dt=policy.dt)
        row = {'robots': int(n), 'seconds': round(time.perf_counter() - t0, 1)}
        for key, value in fm.items():
            row[key] = describe(value) if key != 'stays_inside' else int(np.sum(value))
        rows.append(row)
        if spec.velocity is not None:
            boxes['avd']['prediction'].append(fm['avd_final'])
            boxes['avd']['ground truth'].append(fm['truth_avd_final'])
        else:
            boxes['pod_kld']['prediction'].append(fm['pod_kld'])
        boxes['amd']['prediction'].append(fm['amd_final'])
        boxes['amd']['ground truth'].append(fm['truth_amd_final'])
        log(
            f'scaling: {n} robots, {ics} ICs: amd {row["amd_final"]["mean"]:.3f} (truth '
            f'{row["truth_amd_final"]["mean"]:.3f})'
            + (f', avd {row["avd_final"]["mean"]:.3f}' if 'avd_final' in row else '')
            + f' [{row["seconds"]} s]'
        )
    figures.scaling_boxes(os.path.join(out, 'scaling.png'), list(sizes), boxes)
    base = rows[0]['amd_final']['mean']
    return {
        'sizes': list(sizes),
        'ics': ics,
        'steps': steps,
        'seed': seed,
        'rows': rows,
        'amd_final_vs_first_size': [r['amd_final']['mean'] / base for r in rows],
    }


def write_summary(path: str, r: Dict[str, Any]) -> None:
    f = r['final']
    lines = [
        f'# Evaluation: {r["scenario"]}',
        '',
        f'- policy: `{r["policy"]}`',
        f'- data: `{r["data"]}` ({r.get("trajectories_used", "test")} trajectories {r["test_trajectories"]})',
        f'- {len(r["test_trajectories"])} rollouts of {r["robots"]} robots, {r["steps"]} steps of '
        f'{r["dt"]:.4g} s ({r["rollout_seconds"]} s)',
        '',
        '| metric (final) | prediction | ground truth |',
        '| --- | --- | --- |',
    ]

    def cell(key):
        s = f.get(key)
        return '-' if s is None else f'{s["mean"]:.4g} ± {s["ci95"]:.2g} (median {s["median"]:.4g})'

    if 'avd_final' in f:
        lines.append(f'| avd, last 10 frames | {cell("avd_final")} | {cell("truth_avd_final")} |')
    lines.append(f'| amd, last 10 frames | {cell("amd_final")} | {cell("truth_amd_final")} |')
    lines.append(
        f'| min pair distance after 1 s (min over runs) | {f["min_distance"]["min"]:.3f} | '
        f'{f["truth_min_distance"]["min"]:.3f} |'
    )
    if 'pod_kld' in f:
        lines.append(f'| POD-KLD (10 modes) | {cell("pod_kld")} | 0 |')
        lines.append(
            f'| rollouts staying in the cube | {r["rollouts_inside"]} / {len(r["test_trajectories"])} | |'
        )
    lines += [
        '',
        '± is the half-width of the 95 % confidence interval of the mean over the rollouts. Lower avd '
        'is better (the robots move alike); amd should match the ground truth (the same spacing).',
        '',
        f'Goals: {r["goals"]}',
        '',
        '```',
        *(f'{k}: {v}' for k, v in r['goal_check'].items()),
        '```',
    ]
    if 'orders' in r:
        lines += ['', '## Order parameters (last 20 frames; mean [95 % interval] over the rollouts)', '']
        lines += order_lines(r['orders'])
    if 'scaling' in r:
        lines += [''] + _scaling_lines(r['scaling'])
    lines += [
        '',
        'Figures: metrics.png, snapshots.png'
        + (', orders.png' if 'orders' in r else '')
        + (', pod.png' if 'pod_kld' in f else '')
        + (''.join(', ' + f for f in _scaling_figures(r['scenario'])) if 'scaling' in r else ''),
        '',
    ]
    with open(path, 'w') as fh:
        fh.write('\n'.join(lines))


def _scaling_lines(s: Dict[str, Any]) -> List[str]:
    """Markdown section of a scaling study's results."""
    if 'escape_events' in s:  # boids3d: training.assessment.scaling
        from .scaling import summary_lines

        return summary_lines(s)
    lines = [
        f'## Scaling ({s["ics"]} initial conditions per size, {s["steps"]} steps)',
        '',
        '| robots | amd pred | amd truth | avd pred | avd truth |',
        '| --- | --- | --- | --- | --- |',
    ]
    for row in s['rows']:
        lines.append(
            f'| {row["robots"]} | {row["amd_final"]["mean"]:.3g} | {row["truth_amd_final"]["mean"]:.3g} | '
            f'{row["avd_final"]["mean"]:.3g} | {row["truth_avd_final"]["mean"]:.3g} |'
        )
    return lines
