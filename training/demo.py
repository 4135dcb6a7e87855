"""End-to-end demo (until the ROS swarm lands): ground truth, shipped policy, metrics, figures.

    python -m training.demo [--trajectories 5] [--steps 2000] [--out out/demo-offline]

Simulates a small flock2d dataset with the ground-truth module (Tanner flocking, paper
initial conditions, 10 robots), rolls the shipped flock2d policy out from the same initial
states with the canonical rollout, prints avd and amd against the ground truth and writes
figures (metrics.png, snapshots.png), results.json and summary.md under ``--out``.
Takes well under a minute on two cores.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from typing import List, Optional

import torch

from knode_swarm_ros.core import save_trajectories, shipped_policy_path
from knode_swarm_ros.core.cli import cli
from knode_swarm_ros.core.errors import RunError
from knode_swarm_ros.core.groundtruth import simulate
from training.assessment.evaluation import evaluate


@cli('python -m training.demo')
def main(argv: Optional[List[str]] = None) -> int:
    parser = argparse.ArgumentParser(prog='python -m training.demo', description=__doc__.split('\n\n')[0])
    parser.add_argument('--trajectories', type=int, default=5, help='test swarms (default 5)')
    parser.add_argument('--robots', type=int, default=10)
    parser.add_argument('--steps', type=int, default=2000, help='frames per swarm (default 2000 = 20 s)')
    parser.add_argument('--seed', type=int, default=2024, help='seed of the initial conditions')
    parser.add_argument('--policy', default=None, help='policy file (default: the shipped flock2d policy)')
    parser.add_argument(
        '--out',
        default=os.path.join('out', 'demo-offline'),
        help='output folder (default out/demo-offline; make demo, the ROS swarm, writes out/demo)',
    )
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    t0 = time.perf_counter()
    policy = args.policy or str(shipped_policy_path('flock2d'))
    print(
        f'1/3 simulating {args.trajectories} ground-truth flock2d swarms of {args.robots} robots, {args.steps} frames'
    )
    states = simulate('flock2d', args.trajectories, args.robots, args.steps, args.seed, progress=False)
    os.makedirs(args.out, exist_ok=True)
    data = os.path.join(args.out, 'groundtruth.npz')
    save_trajectories(
        data,
        states,
        0.01,
        'flock2d',
        {
            'generator': 'training.demo',
            'seed': args.seed,
            'split': {'train': [], 'test': list(range(args.trajectories))},
        },
    )
    print(f'2/3 rolling out {policy} from the same initial states')
    r = evaluate(policy, data, args.out, trajectories=args.trajectories, log=lambda *a: None)
    f = r['final']
    print('3/3 results (mean over swarms, last 10 frames):')
    print(f'    avd  learnt {f["avd_final"]["mean"]:.4f}   ground truth {f["truth_avd_final"]["mean"]:.4f}')
    print(f'    amd  learnt {f["amd_final"]["mean"]:.4f}   ground truth {f["truth_amd_final"]["mean"]:.4f}')
    print(
        f'    min pair distance after 1 s: learnt {f["min_distance"]["min"]:.3f}, '
        f'ground truth {f["truth_min_distance"]["min"]:.3f}'
    )
    print(
        f'figures: {os.path.join(args.out, "metrics.png")}, {os.path.join(args.out, "snapshots.png")} '
        f'({time.perf_counter() - t0:.1f} s)'
    )
    if not r['finite']:
        raise RunError(f'a learnt rollout of {policy} became non-finite (see {args.out})')
    return 0


if __name__ == '__main__':
    sys.exit(main())
