"""How crowded a boids3d swarm is for a policy that senses its k-1 closest neighbours within d_cr
(why the learnt swarm departs from the boids at larger sizes).

    python -m training.studies.crowding out/scaling3d_own/results.json --data data/boids3d.npz [--d-cr 2 --k 6]

Prints, for the final frame of the example start of each scaling study (``results.json`` of
``training.evaluate --scaling`` or ``training.studies.scaling3d --merge``; policy and ground truth) and
for the training trajectories of ``--data``: the nearest-neighbour distance (median and
quartiles) and the number of other boids within ``d_cr``, with the share of boids that have
more than k-1 of them, i.e. some neighbour in range that the policy does not see.
"""

from __future__ import annotations

import argparse
import json
from typing import Dict, Optional, Sequence

import numpy as np

from knode_swarm_ros.core.cli import cli
from knode_swarm_ros.core.errors import KnodeError
from knode_swarm_ros.core.geometry import pair_distances


def crowding(states: np.ndarray, d_cr: float, k: int) -> Dict[str, float]:
    """Statistics over all boids and frames of ``states [..., n, 6]`` (positions first)."""
    d = pair_distances(np.asarray(states)[..., :3])  # [..., n, n], inf on the diagonal
    nn = d.min(axis=-1)
    within = (d <= d_cr).sum(axis=-1)
    return {
        'nn_median': float(np.median(nn)),
        'nn_q1': float(np.percentile(nn, 25)),
        'nn_q3': float(np.percentile(nn, 75)),
        'in_range_mean': float(within.mean()),
        'unseen_share': float(np.mean(within > k - 1)),
    }


def line(label: str, c: Dict[str, float], d_cr: float, k: int) -> str:
    return (
        f'{label}: nearest neighbour {c["nn_median"]:.3f} [{c["nn_q1"]:.3f}, {c["nn_q3"]:.3f}]; '
        f'boids within d_cr {d_cr:g}: {c["in_range_mean"]:.2f} on average, '
        f'{100 * c["unseen_share"]:.0f}% of boids have more than k-1 = {k - 1}'
    )


@cli('python -m training.studies.crowding')
def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = argparse.ArgumentParser(
        prog='python -m training.studies.crowding', description=__doc__.split('\n')[0]
    )
    parser.add_argument('results', nargs='*', help='results.json of boids3d scaling studies')
    parser.add_argument('--data', default=None, help='trajectory file: its train split is summarised too')
    parser.add_argument('--d-cr', type=float, default=2.0)
    parser.add_argument('--k', type=int, default=6)
    args = parser.parse_args(argv)
    if args.k < 2 or not args.d_cr > 0:
        raise KnodeError(f'--k must be >= 2 and --d-cr > 0, got {args.k}, {args.d_cr}')
    for path in args.results:
        try:
            with open(path) as fh:
                ex = json.load(fh)['scaling']['example']
        except (OSError, ValueError, KeyError) as exc:
            raise KnodeError(f"{path}: not a scaling study's results.json ({exc})") from None
        for who in ('prediction', 'ground truth'):
            print(
                line(
                    f'{path}: {ex["robots"]} boids, start {ex["start"]}, final frame, {who}',
                    crowding(np.asarray(ex[who]), args.d_cr, args.k),
                    args.d_cr,
                    args.k,
                )
            )
    if args.data:
        from knode_swarm_ros.core import load_trajectories

        data = load_trajectories(args.data)
        train = data.states[data.split('train')]
        print(
            line(
                f'{args.data}: train split, {train.shape[0]} x {train.shape[1]} frames x {train.shape[2]} boids',
                crowding(train, args.d_cr, args.k),
                args.d_cr,
                args.k,
            )
        )
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
