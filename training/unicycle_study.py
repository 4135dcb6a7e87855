"""The flock2d policy on differential-drive robots, offline: unicycles vs double integrators.

    python -m training.unicycle_study --policy knode_swarm_ros/policies/flock2d.pt --out out/unicycle

Every robot is a unicycle (pose x, y, theta; commands v, omega held over each step of the
policy's dt). Each step it reports what its REP 105 Odometry says, z = [x, y, v cos theta,
v sin theta], the policy computes its acceleration from the neighbour matrix as usual, and
:class:`knode_swarm_ros.core.unicycle.UnicycleMapper` (the agent's ``command_interface:
unicycle``) turns it into (v, omega). Starts: held-out Tanner draws (seed 2026), heading =
initial velocity direction. Compares final avd / amd (mean, 95 % interval) with the double
integrator rollout from the same starts, with loose limits and with limits that bind (top
speed below the swarm's flocking speed, turn rate 1.8 rad/s like a TurtleBot).
Writes ``DIR/results.json``.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from typing import Any, Dict, List, Optional

import numpy as np

from knode_swarm_ros.core import PolicyError, amd, avd, load_policy, rollout
from knode_swarm_ros.core.geometry import min_pair_distance
from knode_swarm_ros.core.cli import cli
from knode_swarm_ros.core.errors import KnodeError
from knode_swarm_ros.core.groundtruth import tanner
from knode_swarm_ros.core.network import neighbour_matrix
from knode_swarm_ros.core.unicycle import UnicycleLimits, UnicycleMapper, point_ahead, unicycle_step


def unicycle_rollout(policy, z0: np.ndarray, steps: int, limits: UnicycleLimits, d_cr: float, k: int,
                     dt: float) -> np.ndarray:
    """Observed states ``[S, steps + 1, n, 4]`` of unicycle swarms from ``z0 [S, n, 4]`` (tau 0)."""
    S, n, _ = z0.shape
    pose = np.concatenate([z0[..., :2], np.arctan2(z0[..., 3], z0[..., 2])[..., None]], axis=-1)
    speed = np.linalg.norm(z0[..., 2:], axis=-1)
    turn = np.zeros((S, n))
    mappers = [[UnicycleMapper(limits, 'acceleration', dt) for _ in range(n)] for _ in range(S)]
    for s in range(S):
        for i in range(n):
            mappers[s][i].last = (float(speed[s, i]), 0.0)
    out = np.empty((S, steps + 1, n, 4))
    for t in range(steps + 1):
        th = pose[..., 2]
        z = np.stack([pose[..., 0], pose[..., 1], speed * np.cos(th), speed * np.sin(th)], axis=-1)
        out[:, t] = z
        if t == steps:
            break
        Y, mask = neighbour_matrix(z, z, 2, d_cr, k)
        u = np.asarray(policy(Y.reshape(-1, k, 4), mask.reshape(-1, k)), dtype=np.float64).reshape(S, n, 2)
        for s in range(S):
            for i in range(n):
                _, pv = point_ahead(0.0, 0.0, th[s, i], speed[s, i], turn[s, i], limits.lookahead)
                v, w = mappers[s][i](u[s, i], th[s, i], pv)
                pose[s, i] = unicycle_step(pose[s, i], v, w, dt)
                speed[s, i], turn[s, i] = v, w
    return out


def _interval(x: np.ndarray) -> Dict[str, float]:
    from scipy import stats
    m = float(x.mean())
    h = float(stats.t.ppf(0.975, x.size - 1) * x.std(ddof=1) / np.sqrt(x.size))
    return {'mean': m, 'lo': m - h, 'hi': m + h}


def run(policy_path: str, out: str, starts: int = 10, robots: int = 10, steps: int = 1000, seed: int = 2026,
        log=print) -> Dict[str, Any]:
    policy = load_policy(policy_path)
    if policy.scenario != 'flock2d':
        raise PolicyError(f'{policy_path}: a flock2d policy is needed, got {policy.scenario}')
    z0 = tanner.initial_states(np.random.default_rng(seed), starts, robots, 'paper')
    di = rollout(policy, z0, steps, 'flock2d', policy.d_cr, policy.k, 0, policy.dt)
    flock_speed = float(np.linalg.norm(di[:, -1, :, 2:], axis=-1).mean())
    cases = {'double_integrator': None,
             'unicycle_loose': UnicycleLimits(0.2, 10.0, 20.0, 0.0, 0.0),
             'unicycle_binding': UnicycleLimits(0.2, round(0.5 * flock_speed, 2), 1.8, 1.0, 5.0)}
    rows: List[Dict[str, Any]] = []
    for name, lim in cases.items():
        states = di if lim is None else unicycle_rollout(policy, z0, steps, lim, policy.d_cr, policy.k, policy.dt)
        final = states[:, -1]
        p = states[:, int(1 / policy.dt):, :, :2]
        row = {'case': name, 'limits': None if lim is None else lim.__dict__,
               'avd': _interval(avd(final[..., 2:])), 'amd': _interval(amd(final[..., :2])),
               'speed': float(np.linalg.norm(final[..., 2:], axis=-1).mean()),
               'collisions': int((min_pair_distance(p).min(axis=1) < 0.3).sum())}
        rows.append(row)
        log(f"{name:18s} avd {row['avd']['mean']:.3f} [{row['avd']['lo']:.3f}, {row['avd']['hi']:.3f}] "
            f"amd {row['amd']['mean']:.3f} [{row['amd']['lo']:.3f}, {row['amd']['hi']:.3f}] "
            f"speed {row['speed']:.2f} collisions {row['collisions']}/{starts}")
    results = {'policy': os.fspath(policy_path), 'starts': starts, 'robots': robots, 'steps': steps,
               'seed': seed, 'flock_speed_double_integrator': flock_speed, 'rows': rows}
    os.makedirs(out, exist_ok=True)
    with open(os.path.join(out, 'results.json'), 'w') as fh:
        json.dump(results, fh, indent=1)
    return results


@cli("python -m training.unicycle_study")
def main(argv: Optional[List[str]] = None) -> int:
    p = argparse.ArgumentParser(prog='python -m training.unicycle_study', description=__doc__.split('\n\n')[0])
    p.add_argument('--policy', required=True)
    p.add_argument('--out', required=True)
    p.add_argument('--starts', type=int, default=10)
    p.add_argument('--steps', type=int, default=1000)
    p.add_argument('--seed', type=int, default=2026)
    a = p.parse_args(argv)
    if a.starts < 2 or a.steps < 1:
        raise KnodeError('--starts must be >= 2 and --steps >= 1')
    import torch
    torch.set_num_threads(1)
    run(a.policy, a.out, a.starts, 10, a.steps, a.seed)
    return 0


if __name__ == '__main__':
    sys.exit(main())
