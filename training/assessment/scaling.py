"""The paper's 3D scaling study as a library: a boids3d policy at 10 to 90 boids in the
fixed ±5 cube (the study is described in :mod:`training.studies.scaling3d`; ``training.evaluate --scaling``
runs it, ``python -m training.studies.scaling3d --merge`` joins runs).

Shapes: S starts, T frames, n boids, d = 6 state entries.
"""

from __future__ import annotations

import math
import os
import time
from typing import Any, Dict, List, Sequence

import numpy as np

from knode_swarm_ros.core import amd, get_scenario

from . import figures
from .boids_stats import PERCEPTION_RADIUS, group_labels, subgroups
from .scores import final_metrics
from .stats import describe

__all__ = [
    'outside',
    'leaving',
    'escaped',
    'subswarm_count',
    'escape_events',
    'size_metrics',
    'scaling_study',
    'goal_check',
    'summary_lines',
    'GOALS',
]

#: Goals at these sizes: amd within 15 % of the ground truth, no boid leaving the cube
#: in at least 14 of 15 starts.
GOAL_SIZES = (50, 90)
GOAL_AMD_REL = 0.15
GOAL_INSIDE_SHARE = 14 / 15
GOALS = 'at 50 and 90 boids: mean final amd within 15% of the ground truth; no boid leaves the cube in >= 14 of 15 starts'
#: Tolerance of the cube test (the same as ``final_metrics``' ``stays_inside``).
BOX_TOL = 1e-9
LAST = 10
CURVE_POINTS = 60
#: Per-start metrics: box plot panels and table columns (name: prediction key, truth key or None).
PANELS = {
    'amd': ('amd_final', 'truth_amd_final'),
    'POD-KLD': ('pod_kld', None),
    'fraction of boids leaving the cube': ('escaped', 'truth_escaped'),
    'subswarms (radius 2.5)': ('subswarms', 'truth_subswarms'),
}


def outside(states: np.ndarray, box: float) -> np.ndarray:
    """Whether each boid is outside the cube [-box, box]^3: ``states [..., n, 6]`` -> ``[..., n]``."""
    return np.any(np.abs(states[..., :3]) > box + BOX_TOL, axis=-1)


def leaving(states: np.ndarray, box: float) -> np.ndarray:
    """Where each boid leaves the cube: ``states [S, T, n, 6]`` -> ``[S, T, n]``, True at frame t when
    the boid is outside at t and was inside at some frame before t.

    The one definition of "a boid leaves the cube": a boid that starts outside (the
    Unity spawn ball of radius 5 touches the walls) has not left; it leaves if it gets in and then
    goes out again. Frame 0 is never a leaving frame.
    """
    out = outside(states, box)  # [S, T, n]
    was_inside = np.maximum.accumulate(~out, axis=1)  # inside at some frame <= t
    left = np.zeros_like(out)
    left[:, 1:] = out[:, 1:] & was_inside[:, :-1]
    return left


def escaped(states: np.ndarray, box: float) -> np.ndarray:
    """Whether each boid leaves the cube (:func:`leaving`) in some frame: ``[S, T, n, 6]`` -> ``[S, n]``."""
    return leaving(states, box).any(axis=1)


def subswarm_count(states: np.ndarray, radius: float = PERCEPTION_RADIUS, last: int = LAST) -> np.ndarray:
    """Mean number of connected groups over the last ``last`` frames: ``[S, T, n, 6]`` -> ``[S]``."""
    return subgroups(states[:, -last:], radius).mean(axis=1)


def escape_events(
    pred: np.ndarray, box: float, d_cr: float, dt: float, radius: float = PERCEPTION_RADIUS
) -> List[Dict[str, Any]]:
    """The first exit of every boid that leaves the cube (:func:`leaving`), ``pred [S, T, n, 6]``.

    For each: start ``s``, ``boid``, ``frame`` (first leaving frame, >= 1) and time ``t``, ``wall`` (axis
    and sign, e.g. ``+z``), ``neighbours`` (other boids within ``d_cr``, what the policy senses) and
    ``group`` (size of its connected group within ``radius``) at the last frame inside,
    ``outward_speed`` (the displacement across the wall / dt) and ``inside_at_end``.
    """
    out = outside(pred, box)  # [S, T, n]
    left = leaving(pred, box)
    events: List[Dict[str, Any]] = []
    for s, boid in zip(*np.nonzero(left.any(axis=1))):
        f = int(np.argmax(left[s, :, boid]))
        before = pred[s, f - 1]  # [n, 6], inside by definition
        p = pred[s, f, boid, :3]
        axis = int(np.argmax(np.abs(p) - box))
        d = np.linalg.norm(before[:, :3] - before[boid, :3], axis=-1)
        labels = group_labels(before[None], radius)[0]
        step = (pred[s, f, boid, axis] - before[boid, axis]) * np.sign(p[axis]) / dt
        events.append(
            {
                'start': int(s),
                'boid': int(boid),
                'frame': f,
                't': f * dt,
                'wall': ('+' if p[axis] > 0 else '-') + 'xyz'[axis],
                'neighbours': int(np.sum(d < d_cr) - 1),
                'group': int(np.sum(labels == labels[boid])),
                'outward_speed': float(step),
                'inside_at_end': not bool(out[s, -1, boid]),
            }
        )
    return events


def size_metrics(
    pred: np.ndarray, truth: np.ndarray, dt: float, radius: float = PERCEPTION_RADIUS
) -> Dict[str, List[float]]:
    """Per-start metrics of one size (module docstring) for ``pred``, ``truth [S, T, n, 6]``: those
    of ``final_metrics`` plus ``escaped`` / ``truth_escaped`` (share of boids that leave the cube,
    :func:`leaving`), ``no_boid_leaves``, ``spawned_outside``, ``subswarms`` / ``truth_subswarms``."""
    spec = get_scenario('boids3d')
    m = final_metrics(spec, pred, truth, last=LAST, dt=dt)
    left, truth_left = escaped(pred, spec.box), escaped(truth, spec.box)  # [S, n]
    m['escaped'] = left.mean(axis=1).tolist()
    m['truth_escaped'] = truth_left.mean(axis=1).tolist()
    # Per start: no boid leaves (the goal's test; ``stays_inside`` above is every boid inside in
    # every frame, which a boid spawned outside fails) and a boid outside in the first frame.
    m['no_boid_leaves'] = (~left.any(axis=1)).tolist()
    m['spawned_outside'] = outside(pred[:, 0], spec.box).any(axis=1).tolist()
    m['subswarms'] = subswarm_count(pred, radius).tolist()
    m['truth_subswarms'] = subswarm_count(truth, radius).tolist()
    return m


def _curves(
    pred: np.ndarray, truth: np.ndarray, dt: float, box: float, radius: float
) -> Dict[str, List[float]]:
    """Means over starts of subswarms and of the share of boids that have left the cube, at
    ``CURVE_POINTS`` times (subswarms are costly, so not every frame)."""
    T = pred.shape[1]
    idx = np.unique(np.linspace(0, T - 1, min(CURVE_POINTS, T)).round().astype(int))
    gone = {
        k: np.maximum.accumulate(leaving(z, box), axis=1)[:, idx].mean(axis=(0, 2))
        for k, z in (('prediction', pred), ('ground truth', truth))
    }
    return {
        't': (idx * dt).tolist(),
        'subswarms': {
            'prediction': subgroups(pred[:, idx], radius).mean(0).tolist(),
            'ground truth': subgroups(truth[:, idx], radius).mean(0).tolist(),
        },
        'escaped': {k: v.tolist() for k, v in gone.items()},
        'amd': {
            'prediction': amd(pred[:, idx, :, :3]).mean(0).tolist(),
            'ground truth': amd(truth[:, idx, :, :3]).mean(0).tolist(),
        },
    }


def scaling_study(
    policy,
    out: str,
    sizes: Sequence[int],
    ics: int,
    steps: int,
    seed: int,
    preset: str = 'paper',
    radius: float = PERCEPTION_RADIUS,
    log=print,
    rollout_fn=None,
) -> Dict[str, Any]:
    """Run the study (module docstring); writes ``scaling.png`` and ``departures.png`` into ``out``.

    Ground truth of size n: ``simulate('boids3d', ics, n, steps + 1, seed + n, preset)``. Returns
    ``rows`` (one per size: per-start lists and their statistics), ``escape_events``, ``curves``,
    ``goal_check`` and the settings.
    """
    from knode_swarm_ros.core.groundtruth import simulate

    if rollout_fn is None:
        from .scores import rollout_policy as rollout_fn
    spec = get_scenario('boids3d')
    if policy.scenario != 'boids3d':
        raise ValueError(f'scaling3d needs a boids3d policy, got {policy.scenario}')
    rows: List[Dict[str, Any]] = []
    events: Dict[str, List[Dict[str, Any]]] = {}
    curves: Dict[str, Any] = {}
    example = None
    for n in sizes:
        t0 = time.perf_counter()
        truth = simulate('boids3d', ics, n, steps + 1, seed + n, preset=preset, progress=False)
        pred = rollout_fn(policy, truth[:, 0], steps)
        m = size_metrics(pred, truth, policy.dt, radius)
        row: Dict[str, Any] = {
            'robots': int(n),
            'per_start': m,
            'starts_inside': int(np.sum(m['no_boid_leaves'])),
            'truth_starts_inside': int(np.sum(np.asarray(m['truth_escaped']) == 0)),
            'starts_spawned_outside': int(np.sum(m['spawned_outside'])),
        }
        row.update(
            {
                key: describe(v)
                for key, v in m.items()
                if key not in ('stays_inside', 'no_boid_leaves', 'spawned_outside')
            }
        )
        row['amd_rel_error'] = (row['amd_final']['mean'] - row['truth_amd_final']['mean']) / row[
            'truth_amd_final'
        ]['mean']
        events[str(n)] = escape_events(pred, spec.box, policy.d_cr, policy.dt, radius)
        curves[str(n)] = _curves(pred, truth, policy.dt, spec.box, radius)
        if n == max(sizes):
            s = int(np.argmax(m['subswarms']))
            example = (s, pred[s, -1], truth[s, -1])
        row['seconds'] = round(time.perf_counter() - t0, 1)
        rows.append(row)
        log(
            f'scaling3d: {n} boids, {ics} starts: amd {row["amd_final"]["mean"]:.3f} (truth '
            f'{row["truth_amd_final"]["mean"]:.3f}, {100 * row["amd_rel_error"]:+.1f}%), POD-KLD '
            f'{row["pod_kld"]["mean"]:.3f}, inside {row["starts_inside"]}/{ics}, subswarms '
            f'{row["subswarms"]["mean"]:.2f} (truth {row["truth_subswarms"]["mean"]:.2f}) [{row["seconds"]} s]'
        )
    s, zp, zt = example
    result = _assemble(
        rows,
        events,
        curves,
        {'robots': int(max(sizes)), 'start': s, 'prediction': zp.tolist(), 'ground truth': zt.tolist()},
        {'ics': ics, 'steps': steps, 'seed': seed, 'preset': preset, 'subswarm_radius': radius},
    )
    draw(result, out)
    return result


def _assemble(rows, events, curves, example, settings) -> Dict[str, Any]:
    return {
        'sizes': [r['robots'] for r in rows],
        **settings,
        'rows': rows,
        'escape_events': events,
        'curves': curves,
        'example': example,
        'goals': GOALS,
        'goal_check': goal_check(rows, settings['ics']),
        'amd_final_vs_first_size': [r['amd_final']['mean'] / rows[0]['amd_final']['mean'] for r in rows],
    }


def draw(s: Dict[str, Any], out: str) -> None:
    """``scaling.png`` and ``departures.png`` of a study's results ``s``."""
    rows, ex, radius = s['rows'], s['example'], s['subswarm_radius']
    boxes = {
        name: {
            'prediction': [r['per_start'][pk] for r in rows],
            **({'ground truth': [r['per_start'][tk] for r in rows]} if tk else {}),
        }
        for name, (pk, tk) in PANELS.items()
    }
    figures.scaling_boxes(os.path.join(out, 'scaling.png'), s['sizes'], boxes, ylabel_prefix='')
    zp, zt = np.asarray(ex['prediction']), np.asarray(ex['ground truth'])
    figures.departures(
        os.path.join(out, 'departures.png'),
        s['curves'],
        (zp, group_labels(zp[None], radius)[0]),
        (zt, group_labels(zt[None], radius)[0]),
        get_scenario('boids3d').box,
        f'{ex["robots"]} boids, start {ex["start"]} (most subswarms), final frame',
    )


def merge(studies: Sequence[Dict[str, Any]]) -> Dict[str, Any]:
    """One study from several run at other sizes with the same settings (each size is independent:
    its ground truth is seeded with ``seed + n``), sizes in increasing order."""
    keys = ('ics', 'steps', 'seed', 'preset', 'subswarm_radius')
    for s in studies[1:]:
        for key in keys:
            if s[key] != studies[0][key]:
                raise ValueError(
                    f'cannot merge scaling studies with different {key}: {s[key]} vs {studies[0][key]}'
                )
    rows = sorted((r for s in studies for r in s['rows']), key=lambda r: r['robots'])
    if len({r['robots'] for r in rows}) != len(rows):
        raise ValueError('cannot merge scaling studies that share a size')
    events = {k: v for s in studies for k, v in s['escape_events'].items()}
    curves = {
        str(r['robots']): next(
            s['curves'][str(r['robots'])] for s in studies if str(r['robots']) in s['curves']
        )
        for r in rows
    }
    example = max((s['example'] for s in studies), key=lambda e: e['robots'])
    return _assemble(rows, events, curves, example, {k: studies[0][k] for k in keys})


def goal_check(rows: Sequence[Dict[str, Any]], ics: int) -> Dict[str, Any]:
    """Pass/fail of the goals at each of ``GOAL_SIZES`` present in ``rows``.

    ``starts_inside`` counts the starts in which no boid leaves the cube (:func:`leaving`: a boid
    spawned outside, which the Unity spawn ball of radius 5 allows, has not left). ``spawn_outside``
    (information only, where the row has it): starts with a boid outside in the first frame,
    shared by the policy and the ground truth.
    """
    need = math.ceil(GOAL_INSIDE_SHARE * ics - 1e-9)
    check: Dict[str, Any] = {}
    for r in rows:
        if r['robots'] in GOAL_SIZES:
            n = r['robots']
            check[f'{n}: amd_within_15%'] = bool(abs(r['amd_rel_error']) <= GOAL_AMD_REL)
            check[f'{n}: amd_rel_error'] = round(float(r['amd_rel_error']), 4)
            check[f'{n}: inside>={need}/{ics}'] = bool(r['starts_inside'] >= need)
            check[f'{n}: starts_inside'] = int(r['starts_inside'])
            if 'starts_spawned_outside' in r:
                check[f'{n}: spawn_outside'] = int(r['starts_spawned_outside'])
    return check


def summary_lines(s: Dict[str, Any]) -> List[str]:
    """Markdown table (mean, median [q1, q3] over starts) and goal check of a study's results."""

    def cell(r, key):
        x = r[key]
        return f'{x["mean"]:.3g} ({x["median"]:.3g} [{x["q1"]:.3g}, {x["q3"]:.3g}])'

    lines = [
        f'## Scaling ({s["ics"]} starts per size, {s["steps"]} steps, ground truth preset {s["preset"]})',
        '',
        'Per size: mean (median [quartiles]) over starts.',
        '',
        '| boids | amd policy | amd truth | rel. error | POD-KLD | starts with no escape (policy / truth) '
        '| share of boids leaving | subswarms policy | subswarms truth |',
        '| --- | --- | --- | --- | --- | --- | --- | --- | --- |',
    ]
    for r in s['rows']:
        lines.append(
            f'| {r["robots"]} | {cell(r, "amd_final")} | {cell(r, "truth_amd_final")} | '
            f'{100 * r["amd_rel_error"]:+.1f}% | {cell(r, "pod_kld")} | {r["starts_inside"]} / '
            f'{r["truth_starts_inside"]} of {s["ics"]} | {r["escaped"]["mean"]:.3g} | '
            f'{cell(r, "subswarms")} | {cell(r, "truth_subswarms")} |'
        )
    lines += [
        '',
        f'Goals: {s["goals"]}',
        '',
        '```',
        *(f'{k}: {v}' for k, v in s['goal_check'].items()),
        '```',
        '',
    ]
    ev = [e for n in s['sizes'] for e in s['escape_events'][str(n)]]
    if ev:
        lines += [
            f'Escapes of learnt boids (inside, then outside): {len(ev)} in all; '
            'sensed neighbours within d_cr just before leaving: '
            f'median {np.median([e["neighbours"] for e in ev]):.0f}, none in '
            f'{sum(e["neighbours"] == 0 for e in ev)}; group size median '
            f'{np.median([e["group"] for e in ev]):.0f}; back inside at the end: '
            f'{sum(e["inside_at_end"] for e in ev)}.',
            '',
        ]
    return lines
