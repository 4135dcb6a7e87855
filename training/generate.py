"""Generate a ground-truth observation dataset (a trajectory file, docs/DESIGN.md "Trajectory files").

    python -m training.generate --scenario flock2d --out data/flock2d.npz
    python -m training.generate --scenario boids3d --preset published --out data/boids3d_published.npz
    python -m training.generate --scenario flock2d --trajectories 8 --robots 20 --steps 500 \\
        --seed 3 --variant gym_flock --train 6 --out data/small.npz

Defaults are the paper's: flock2d 50 trajectories of 10 robots, 2000 frames, 30 train / 20
test; boids3d 22 trajectories of 10 boids, 1700 frames (after 10 discarded), 2 train / 20 test.
flock2d files also carry ``meta["diagnostics"]`` (closest initial pair and largest speed per
trajectory), and a warning names trajectories that start with a pair closer than 0.1
(``--min-separation`` redraws such starts; the default is the paper's unconditioned draw).
For other trajectory counts N the default split keeps the paper's train fraction:
flock2d train = round(0.6 N), boids3d train = round(N / 11), each at least 1 and, when N >= 2,
at most N - 1. Train trajectories are the first ones, test the rest. The stored data is
clean; observation noise belongs to training. The same seed gives the same arrays and meta.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from typing import Optional, Sequence

import numpy as np

from knode_swarm_ros import __version__
from knode_swarm_ros.core.cli import cli
from knode_swarm_ros.core.errors import KnodeError
from knode_swarm_ros.core.geometry import min_pair_distance
from knode_swarm_ros.core.groundtruth import parameters, presets, simulate
from knode_swarm_ros.core.scenarios import get_scenario
from knode_swarm_ros.core.trajectory import save_trajectories

#: Paper defaults per scenario: trajectories, robots, steps (recorded frames), train trajectories.
PAPER_DEFAULTS = {
    'flock2d': {'trajectories': 50, 'robots': 10, 'steps': 2000, 'train': 30},
    'boids3d': {'trajectories': 22, 'robots': 10, 'steps': 1700, 'train': 2},
}

#: Train fraction used when --trajectories differs from the paper's (30/50 and 2/22).
TRAIN_FRACTION = {'flock2d': 0.6, 'boids3d': 1.0 / 11.0}


def default_train(scenario: str, trajectories: int) -> int:
    """Default number of train trajectories (see the module docstring)."""
    if trajectories == PAPER_DEFAULTS[scenario]['trajectories']:
        return PAPER_DEFAULTS[scenario]['train']
    train = int(math.floor(TRAIN_FRACTION[scenario] * trajectories + 0.5))
    train = max(train, 1)
    if trajectories >= 2:
        train = min(train, trajectories - 1)
    return train


def _checked(convert, ok, what: str):
    """An argparse ``type`` converting with ``convert`` and refusing values failing ``ok``."""

    def parse(text: str):
        try:
            value = convert(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f'must be {what}, got {text!r}') from None
        if not ok(value):
            raise argparse.ArgumentTypeError(f'must be {what}, got {text!r}')
        return value

    return parse


_positive_int = _checked(int, lambda v: v >= 1, 'a positive integer')
_non_negative_int = _checked(int, lambda v: v >= 0, 'a non-negative integer')
_positive_float = _checked(float, lambda v: math.isfinite(v) and v > 0, 'a positive number')


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog='python -m training.generate',
        description="Simulate a ground-truth swarm (flock2d: Tanner flocking, boids3d: Lague's boids) and "
        'write a trajectory file with its train/test split in meta.',
    )
    p.add_argument('--scenario', required=True, choices=sorted(PAPER_DEFAULTS), help='which ground truth')
    p.add_argument('--out', required=True, help='output .npz trajectory file (written atomically)')
    p.add_argument(
        '--trajectories',
        type=_positive_int,
        default=None,
        help='number of trajectories N (default: paper, flock2d 50, boids3d 22)',
    )
    p.add_argument('--robots', type=_positive_int, default=None, help='robots per swarm (default 10)')
    p.add_argument(
        '--steps',
        type=_positive_int,
        default=None,
        help='recorded frames T per trajectory (default: flock2d 2000, boids3d 1700; boids3d '
        'discards 10 frames before the first recorded one)',
    )
    p.add_argument('--seed', type=_non_negative_int, default=0, help='numpy default_rng seed (default 0)')
    p.add_argument(
        '--variant',
        choices=presets('flock2d'),
        default=None,
        help='flock2d only: initial conditions and clip (default paper)',
    )
    p.add_argument(
        '--preset',
        choices=presets('boids3d'),
        default=None,
        help='boids3d only: boid settings (default paper)',
    )
    p.add_argument(
        '--min-separation',
        type=_positive_float,
        default=None,
        metavar='D',
        help='flock2d only: redraw initial positions until no pair is closer than D (default: the '
        "paper's unconditioned draw; gym-flock uses 0.1)",
    )
    p.add_argument(
        '--train',
        type=_non_negative_int,
        default=None,
        help="number of train trajectories, the first ones (default: paper's 30/50 or 2/22, "
        'else round(0.6 N) for flock2d and round(N/11) for boids3d)',
    )
    p.add_argument('--no-progress', action='store_true', help='hide the progress bar')
    return p


def resolve(args: argparse.Namespace, parser: argparse.ArgumentParser) -> argparse.Namespace:
    """Fill scenario defaults and check the flags that depend on each other (parser.error exits 2)."""
    defaults = PAPER_DEFAULTS[args.scenario]
    if args.scenario == 'flock2d' and args.preset is not None:
        parser.error('argument --preset: only for --scenario boids3d (flock2d takes --variant)')
    if args.scenario == 'boids3d' and args.variant is not None:
        parser.error('argument --variant: only for --scenario flock2d (boids3d takes --preset)')
    if args.scenario == 'boids3d' and args.min_separation is not None:
        parser.error('argument --min-separation: only for --scenario flock2d')
    args.option = (args.variant if args.scenario == 'flock2d' else args.preset) or 'paper'
    for name in ('trajectories', 'robots', 'steps'):
        if getattr(args, name) is None:
            setattr(args, name, defaults[name])
    if os.path.isdir(args.out):
        parser.error(
            f'argument --out: {args.out!r} is a directory; give a file name such as data/{args.scenario}.npz'
        )
    if args.train is None:
        args.train = default_train(args.scenario, args.trajectories)
    elif args.train > args.trajectories:
        parser.error(f'argument --train: {args.train} exceeds --trajectories {args.trajectories}')
    return args


def split_indices(trajectories: int, train: int) -> dict:
    """``{"train": [0 .. train-1], "test": [train .. trajectories-1]}``."""
    return {'train': list(range(train)), 'test': list(range(train, trajectories))}


#: flock2d runs whose closest initial pair is nearer than this get a warning (see docs/groundtruth.md).
CLOSE_START = 0.1


def flock2d_diagnostics(states: np.ndarray) -> dict:
    """Per trajectory: the closest initial pair distance and the largest speed over the run."""
    p = states[:, 0, :, :2]
    closest = min_pair_distance(p)
    speed = np.linalg.norm(states[..., 2:4], axis=-1).max(axis=(1, 2))
    return {
        'initial_min_distance': [round(float(x), 6) for x in closest],
        'max_speed': [round(float(x), 6) for x in speed],
    }


@cli('python -m training.generate')
def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = build_parser()
    args = resolve(parser.parse_args(argv), parser)
    spec = get_scenario(args.scenario)
    states = simulate(
        args.scenario,
        args.trajectories,
        args.robots,
        args.steps,
        args.seed,
        preset=args.option,
        progress=not args.no_progress,
        min_separation=args.min_separation,
    )
    meta = {
        'generator': 'training.generate',
        'version': __version__,
        'scenario': args.scenario,
        'preset': args.option,
        'trajectories': args.trajectories,
        'robots': args.robots,
        'steps': args.steps,
        'seed': args.seed,
        'state_layout': list(spec.state_layout),
        'parameters': parameters(args.scenario, args.option, args.min_separation),
        'split': split_indices(args.trajectories, args.train),
        'noise': 'none (observation noise is added in training)',
    }
    if args.scenario == 'flock2d' and args.robots > 1:
        meta['diagnostics'] = flock2d_diagnostics(states)
        close = [i for i, x in enumerate(meta['diagnostics']['initial_min_distance']) if x < CLOSE_START]
        if close:
            speeds = ', '.join(f'{i}: {meta["diagnostics"]["max_speed"][i]:.3g}' for i in close)
            print(
                f'warning: trajectories {close} start with a pair closer than {CLOSE_START}, where dt = 0.01 '
                f'under-resolves the repulsion (max speed per trajectory {speeds}; a clean run stays below '
                f"~10); --min-separation 0.15 avoids this for data of your own (the paper's datasets "
                "keep such starts, as README.md's 'Ground truth' explains)",
                file=sys.stderr,
            )
    try:
        save_trajectories(args.out, states, spec.dt, args.scenario, meta)
    except (OSError, ValueError) as exc:
        raise KnodeError(f'cannot write --out {args.out}: {exc}') from None
    print(
        f'wrote {args.out}: states {list(states.shape)} ({args.scenario}, {args.option}, seed {args.seed}), '
        f'{args.train} train / {args.trajectories - args.train} test',
        file=sys.stderr,
    )
    return 0


if __name__ == '__main__':
    sys.exit(main())
