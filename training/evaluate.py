"""Evaluate a policy file against ground truth: rollouts, metric curves, snapshots, scaling.

    python -m training.evaluate --policy knode_swarm_ros/policies/flock2d.pt --data data/flock2d.npz --out out/eval_flock2d
    python -m training.evaluate ... --scaling                       # + scaling study (default: 10, 50, 90 robots, 15 ICs)
    python -m training.evaluate ... --scaling --sizes 10 20 30 40 50 60 70 80 90 --ics 15   # the paper's full study
    python -m training.evaluate --policy knode_swarm_ros/policies/boids3d_unity.pt --preset published --out DIR \
        --scaling --sizes 10 20 30 40 50 60 70 80 90 --ics 15 --scaling-steps 1700   # scaling only (no --data)

Rollouts use the canonical semantics (:func:`knode_swarm_ros.core.rollout`) from the first
frame of the test trajectories (``meta.split.test``, the first ``--trajectories``, default 20)
for as many steps as the ground truth has. Writes ``metrics.png``, ``snapshots.png``
(boids3d also ``pod.png``; with ``--scaling`` ``scaling.png``), ``results.json`` and
``summary.md`` under ``--out``. Without ``--data`` only the scaling study runs (``--scaling`` and
``--scaling-steps`` required). boids3d scaling is :mod:`training.studies.scaling3d` (escapes, subswarms,
``departures.png``); ``--preset`` picks the ground truth the policy was trained on (boids3d
``paper`` for our boids, ``published`` for the Unity recordings).
"""

from __future__ import annotations

import argparse
import sys
from typing import List, Optional

import torch

from knode_swarm_ros.core import load_policy
from knode_swarm_ros.core.cli import cli
from knode_swarm_ros.core.errors import KnodeError
from training.assessment.evaluation import evaluate


@cli('python -m training.evaluate')
def main(argv: Optional[List[str]] = None) -> int:
    parser = argparse.ArgumentParser(prog='python -m training.evaluate', description=__doc__.split('\n\n')[0])
    parser.add_argument('--policy', required=True, help='policy file (.pt)')
    parser.add_argument(
        '--data',
        default=None,
        help='trajectory file (ground truth): its test split, or all its trajectories when it has none '
        '(said in the log and summary.md); without --data only --scaling runs',
    )
    parser.add_argument('--out', required=True, help='output directory')
    parser.add_argument(
        '--trajectories', type=int, default=20, help='test trajectories to roll out (default 20)'
    )
    parser.add_argument(
        '--steps', type=int, default=None, help='steps per rollout (default: ground-truth length)'
    )
    parser.add_argument('--scaling', action='store_true', help='also run the scaling study')
    parser.add_argument(
        '--sizes', type=int, nargs='+', default=[10, 50, 90], help='swarm sizes for --scaling'
    )
    parser.add_argument('--ics', type=int, default=15, help='initial conditions per size for --scaling')
    parser.add_argument('--scaling-steps', type=int, default=None, help='steps per scaling rollout')
    parser.add_argument('--seed', type=int, default=1234, help='seed of the scaling initial conditions')
    parser.add_argument(
        '--preset',
        default='paper',
        help='ground-truth preset of the scaling study (boids3d: paper | published; flock2d: a variant)',
    )
    parser.add_argument('--threads', type=int, default=1, help='torch threads (1 is fastest for rollouts)')
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    if args.data is None and not args.scaling:
        parser.error('--data is required unless --scaling is given')
    for name in ('sizes', 'ics', 'scaling_steps'):
        value = getattr(args, name)
        if value is not None and min(value if isinstance(value, list) else [value]) < (
            2 if name == 'sizes' else 1
        ):
            raise KnodeError(
                f'--{name.replace("_", "-")} must be >= {2 if name == "sizes" else 1}, got {value}'
            )
    from knode_swarm_ros.core.groundtruth import presets

    known = presets(load_policy(args.policy).scenario)
    if args.preset not in known:
        raise KnodeError(f'--preset {args.preset!r}: unknown; known: {", ".join(known)}')
    evaluate(
        args.policy,
        args.data,
        args.out,
        args.trajectories,
        args.steps,
        args.scaling,
        args.sizes,
        args.ics,
        args.scaling_steps,
        args.seed,
        preset=args.preset,
    )
    return 0


if __name__ == '__main__':
    sys.exit(main())
