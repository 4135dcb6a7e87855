"""A policy learnt from a law's tracks against the law itself, from held-out starts, scored by
the goals of docs/scenarios.md ("Show it on swarms of your own"): at 10 robots the
nearest-neighbour distance within 15 % of the law's, polarisation and rotation order within
0.10; at 30 robots 25 % and 0.15; no more escapes than the law."""

from __future__ import annotations

import os
import time
from typing import Any, Dict

import numpy as np

from knode_swarm_ros.core import load_policy
from training.assessment.order import compare_orders, order_figure
from training.assessment.scores import rollout_policy
from training.learning.records import write_json

from .laws import Law, initial_states, simulate

GOALS = {10: (0.15, 0.10), 30: (0.25, 0.15)}  # robots -> (relative nn error, order parameter error)


def evaluate_law(
    law: Law, policy_path: str, out: str, robots: int, starts: int, seed: int, learnt_on=(10,)
) -> Dict[str, Any]:
    """Learnt against the law from ``starts`` held-out starts of ``robots`` robots (the policy
    learnt on tracks of ``learnt_on`` robots: the figure's title)."""
    spec = law.scenario
    policy = load_policy(policy_path)
    z0 = initial_states(law, starts, robots, seed)
    truth = simulate(law, z0, law.steps)
    t0 = time.perf_counter()
    pred = rollout_policy(policy, z0, law.steps)
    orders = compare_orders(spec, pred, truth, spec.dt)
    os.makedirs(out, exist_ok=True)
    order_figure(
        os.path.join(out, 'orders.png'),
        spec,
        pred,
        truth,
        spec.dt,
        f'{law.name}: {robots} robots, {starts} held-out starts, learnt on {" + ".join(map(str, learnt_on))}',
    )
    rel_tol, order_tol = GOALS.get(robots, GOALS[30])
    mean = {name: (e['learnt']['mean'], e['observed']['mean']) for name, e in orders.items()}
    nn_rel = abs(mean['nn_distance'][0] - mean['nn_distance'][1]) / mean['nn_distance'][1]
    goals = {
        'finite': bool(np.all(np.isfinite(pred))),
        'nn_rel_error': float(nn_rel),
        f'nn_within_{int(rel_tol * 100)}%': bool(nn_rel <= rel_tol),
        'polarisation_error': float(abs(mean['polarisation'][0] - mean['polarisation'][1])),
        'rotation_error': float(abs(mean['rotation_order'][0] - mean['rotation_order'][1])),
    }
    goals[f'polarisation_within_{order_tol}'] = goals['polarisation_error'] <= order_tol
    goals[f'rotation_within_{order_tol}'] = goals['rotation_error'] <= order_tol
    if 'escapes' in mean:
        goals['escapes_not_more'] = bool(
            sum(orders['escapes']['per_rollout']['learnt'])
            <= sum(orders['escapes']['per_rollout']['observed'])
        )
    result = {
        'law': law.name,
        'robots': robots,
        'starts': starts,
        'seed': seed,
        'steps': law.steps,
        'rollout_seconds': round(time.perf_counter() - t0, 1),
        'orders': orders,
        'goals': goals,
    }
    write_json(os.path.join(out, 'results.json'), result)
    return result
