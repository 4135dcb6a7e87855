"""How a flock2d swarm degrades over lossy, delayed links: learnt policy vs the local Tanner law.

    python -m training.studies.robustness --policy knode_swarm_ros/policies/flock2d.pt --out out/robustness

For each controller (the learnt policy; the hand-written Tanner law restricted to the rows of
Y, clipped like the policy) and each link setting (loss 0, 5, 10, 20, 30 % at no extra delay;
extra delay 0 .. 5 units at no loss), rolls ``--starts`` held-out 10-robot swarms out through
:func:`knode_swarm_ros.core.link.link_rollout` (the agents' link model) and reports the final
avd and amd (mean and 95 % t interval over the starts) and collisions (runs with a pair
closer than 0.3 after the first second). Writes ``DIR/results.json`` and ``DIR/robustness.png``.

The delay unit is the policy's tau when it has one, else ``--delay-unit`` steps (the shipped
flock2d policy has tau = 0; default 10 steps = 0.1 s), so "5 units" is 0.5 s of extra delay.
Initial states are the ground truth's draw (``paper``) from ``--seed`` (2026: not the training
seed 0), and the link model's draws are seeded per setting.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from typing import Any, Callable, Dict, List, Optional

import numpy as np

from knode_swarm_ros.core import PolicyError, amd, avd, geometry, load_policy
from knode_swarm_ros.core.cli import cli
from knode_swarm_ros.core.errors import KnodeError
from knode_swarm_ros.core.groundtruth import tanner
from knode_swarm_ros.core.link import LinkConfig, link_rollout
from training.assessment.stats import interval
from training.learning.records import write_json

LOSSES = (0.0, 0.05, 0.1, 0.2, 0.3)
DELAY_UNITS = (0, 1, 2, 3, 4, 5)
COLLISION = 0.3


def local_tanner(limit: Optional[float]) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """The Tanner law over the real rows of ``Y [B, k, 4]`` (``mask [B, k]``) -> ``[B, 2]``:
    u = sum_j (v_j - v_0) - sum_j (2/r^2 - 2/r^4) (p_0 - p_j), clipped per axis at ``limit``."""

    def policy(Y: np.ndarray, mask: np.ndarray) -> np.ndarray:
        real = mask[:, 1:].astype(np.float64)
        rel = Y[:, :1, :2] - Y[:, 1:, :2]  # p_0 - p_j
        r2 = np.where(real > 0, np.sum(rel * rel, axis=-1), 1.0)
        c = (1.0 / r2 - 1.0 / (r2 * r2)) * real
        u = np.einsum('bj,bjd->bd', real, Y[:, 1:, 2:] - Y[:, :1, 2:]) - 2.0 * np.einsum('bj,bjd->bd', c, rel)
        return np.clip(u, -limit, limit) if limit else u

    return policy


def min_pair_distance(states: np.ndarray) -> np.ndarray:
    """Smallest distance between two robots over a run, ``states [S, T, n, 4]`` -> ``[S]``."""
    return geometry.min_pair_distance(states[..., :2]).min(axis=1)


def run(
    policy_path: str,
    out: str,
    starts: int = 12,
    robots: int = 10,
    steps: int = 1000,
    seed: int = 2026,
    delay_unit: int = 10,
    timeout_steps: Optional[int] = None,
    log=print,
) -> Dict[str, Any]:
    policy = load_policy(policy_path)
    if policy.scenario != 'flock2d':
        raise PolicyError(
            f'{policy_path}: the robustness study is for flock2d policies, got {policy.scenario}'
        )
    unit = policy.tau if policy.tau > 0 else int(delay_unit)
    timeout = timeout_steps if timeout_steps is not None else max(1, round(0.5 / policy.dt))
    z0 = tanner.initial_states(np.random.default_rng(seed), starts, robots, 'paper')
    controllers = {'learnt': policy, 'local_tanner': local_tanner(policy.command_limit)}
    settings = [(loss, 0) for loss in LOSSES] + [(0.0, u) for u in DELAY_UNITS if u]
    after = min(int(round(1.0 / policy.dt)), steps)  # collisions count after 1 s (short runs: the last frame)
    rows: List[Dict[str, Any]] = []
    for name, ctrl in controllers.items():
        for number, (loss, units) in enumerate(settings):
            t0 = time.perf_counter()
            link = LinkConfig(loss=loss, delay=float(units * unit), seed=seed + 1000 * number)
            states, stats = link_rollout(
                ctrl, z0, steps, 'flock2d', policy.d_cr, policy.k, policy.tau, policy.dt, link, timeout
            )
            final = states[:, -1]
            closest = min_pair_distance(states[:, after:])
            row = {
                'controller': name,
                'loss': loss,
                'delay_units': units,
                'delay_steps': units * unit,
                'delay_s': units * unit * policy.dt,
                'avd': interval(avd(final[..., 2:])),
                'amd': interval(amd(final[..., :2])),
                'collisions': int((closest < COLLISION).sum()),
                'closest': float(closest.min()),
                'finite': bool(np.all(np.isfinite(states))),
                'link': {k: v for k, v in stats.items() if k != 'delays'},
                'seconds': time.perf_counter() - t0,
            }
            rows.append(row)
            log(
                f'{name:12s} loss {loss:4.2f} delay {units * unit * policy.dt:4.2f} s: avd {row["avd"]["mean"]:.3f} '
                f'amd {row["amd"]["mean"]:.3f} collisions {row["collisions"]}/{starts} ({row["seconds"]:.0f} s)'
            )
    base = next(r for r in rows if r['controller'] == 'learnt' and r['loss'] == 0 and r['delay_units'] == 0)
    ten = next(r for r in rows if r['controller'] == 'learnt' and r['loss'] == 0.1 and r['delay_units'] == 0)
    change = abs(ten['amd']['mean'] - base['amd']['mean']) / base['amd']['mean']
    goal = {
        'amd_change_at_10pct_loss': change,
        'amd_within_20pct': bool(change <= 0.2),
        'collisions_at_10pct_loss': ten['collisions'],
        'met': bool(change <= 0.2 and ten['collisions'] == 0),
    }
    results = {
        'policy': os.fspath(policy_path),
        'starts': starts,
        'robots': robots,
        'steps': steps,
        'dt': policy.dt,
        'seed': seed,
        'delay_unit_steps': unit,
        'timeout_steps': timeout,
        'collision_distance': COLLISION,
        'collision_after_s': 1.0,
        'initial_states': 'tanner paper draw',
        'rows': rows,
        'goal': goal,
    }
    write_json(os.path.join(out, 'results.json'), results, indent=1, sort_keys=False)
    figure(results, os.path.join(out, 'robustness.png'))
    return results


def figure(results: Dict[str, Any], path: str) -> None:
    """avd and amd against loss and against delay, both controllers, 95 % intervals."""
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(9, 6.5), sharey='row')
    for col, (axis, key, label) in enumerate(
        (('loss', 'loss', 'message loss'), ('delay', 'delay_s', 'extra link delay (s)'))
    ):
        for row, metric in enumerate(('avd', 'amd')):
            ax = axes[row, col]
            for name, style in (('learnt', 'o-'), ('local_tanner', 's--')):
                sel = [
                    r
                    for r in results['rows']
                    if r['controller'] == name
                    and (r['delay_units'] == 0 if axis == 'loss' else r['loss'] == 0)
                ]
                x = [r[key] for r in sel]
                m = np.array([r[metric]['mean'] for r in sel])
                lo = m - np.array([r[metric]['lo'] for r in sel])
                hi = np.array([r[metric]['hi'] for r in sel]) - m
                ax.errorbar(x, m, yerr=[lo, hi], fmt=style, capsize=3, label=name.replace('_', ' '))
            ax.set_xlabel(label)
            ax.set_ylabel(f'final {metric}')
            ax.grid(alpha=0.3)
    axes[0, 0].legend()
    fig.suptitle(
        f'flock2d over lossy, delayed links: {results["starts"]} starts x {results["robots"]} robots, '
        f'{results["steps"]} steps (mean, 95 % interval)',
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


@cli('python -m training.studies.robustness')
def main(argv: Optional[List[str]] = None) -> int:
    parser = argparse.ArgumentParser(
        prog='python -m training.studies.robustness', description=__doc__.split('\n\n')[0]
    )
    parser.add_argument('--policy', required=True, help='flock2d policy file (.pt)')
    parser.add_argument('--out', required=True, help='output folder (results.json, robustness.png)')
    parser.add_argument('--starts', type=int, default=12, help='held-out initial states (>= 2; default 12)')
    parser.add_argument('--robots', type=int, default=10, help='robots per swarm (default 10)')
    parser.add_argument('--steps', type=int, default=1000, help='steps per rollout (default 1000 = 10 s)')
    parser.add_argument('--seed', type=int, default=2026, help='seed of the initial states and link draws')
    parser.add_argument(
        '--delay-unit', type=int, default=10, help="delay unit in steps when the policy's tau is 0"
    )
    parser.add_argument(
        '--timeout-steps',
        type=int,
        default=None,
        help='peers silent longer are no neighbours (default 0.5 s)',
    )
    args = parser.parse_args(argv)
    for name in ('starts', 'robots', 'steps', 'delay_unit'):
        low = 2 if name in ('starts', 'robots') else 1
        if getattr(args, name) < low:
            raise KnodeError(f'--{name.replace("_", "-")} must be >= {low}, got {getattr(args, name)}')
    import torch

    torch.set_num_threads(1)
    results = run(
        args.policy,
        args.out,
        args.starts,
        args.robots,
        args.steps,
        args.seed,
        args.delay_unit,
        args.timeout_steps,
    )
    g = results['goal']
    print(
        f'wrote {args.out}/results.json and robustness.png; at 10 % loss the learnt amd changed by '
        f'{100 * g["amd_change_at_10pct_loss"]:.1f} % with {g["collisions_at_10pct_loss"]} collision run(s): '
        f'goal {"met" if g["met"] else "not met"}'
    )
    return 0


if __name__ == '__main__':
    sys.exit(main())
