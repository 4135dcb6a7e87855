"""Benchmark of the policy network kinds: what the set and equivariant encoders and the half-turn
average cost.

    python bench/bench_encoders.py [--repeats 200] [--k 37]

For a custom 2D first-order and a 3D double-integrator scenario, each kind (flat, the paper's
MLP over k rows, is the baseline; set; equivariant; each also with ``symmetric``, which the
recipe derives for the equivariant encoder only with an arena) is timed in the same run:

* command: one TorchScript policy call for 1 robot (what an agent does each tick) and for 100,
  median over ``--repeats`` calls, in microseconds;
* training step: forward and backward of 2048 samples with 10 rows (the trainer builds only
  as many rows as the training swarm has), median over ``--repeats // 10`` steps, in ms.

Every figure is printed with its ratio to flat in the same scenario. A 2D heading scenario
times constant-speed steering (``policy.speed``, ``policy.turn_limit``: core/steering.py) on
the recipe's equivariant encoder, against the same encoder unsteered; the 3D arena scenario
times the equivariant encoder seeing the coordinate axes (``policy.axes``, which the recipe
derives with an arena), averaged over all half turns and over the half turn about z alone
(``symmetric: z``), against the same encoder without the axes. A 2D open scenario and the 3D
heading tank (steered, with the axes and the half turns, as the recipe derives them) time the
equivariant encoder that sees each neighbour's rank (``policy.rank``, capped at 9) against the
same encoder without it (``--only-rank`` runs that section alone). One thread, as the agents and
the recipe (``training.threads: 1``) run. The last section (``--only-tail`` runs it alone)
times the equivariant encoder's basis Gaussians with their far tail set to zero (as built)
against the same encoder without that cutoff, whose tail is float32 subnormals.
"""

from __future__ import annotations

import argparse
import io
import math
import os
import statistics
import sys
import time
import warnings

import torch

sys.path.insert(0, os.path.join(os.path.dirname(__file__), '..'))
from bench_ros import machine

from knode_swarm_ros.core import KNODEPolicy, PolicyConfig
from knode_swarm_ros.core.scenarios import scenario_from_dict, scenario_ref

KINDS = [
    ('flat', False),
    ('set', False),
    ('flat', True),
    ('set', True),
    ('equivariant', False),
    ('equivariant', True),
]


def scenario(dimensions: int, state: str, command: str, arena) -> str:
    spec = scenario_from_dict(
        dict(
            name=f'bench{dimensions}d',
            dimensions=dimensions,
            state=state,
            command=command,
            dt=0.05,
            arena=arena,
        )
    )
    return scenario_ref(spec)


SCENARIOS = {
    '2D position, velocity': scenario(2, 'position', 'velocity', None),
    '3D position_velocity, acceleration, arena': scenario(
        3, 'position_velocity', 'acceleration', {'half_width': 4.0}
    ),
}


def median_seconds(fn, repeats: int) -> float:
    fn()  # warm up (TorchScript's profiling runs)
    fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def scripted(policy: KNODEPolicy):
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        buffer = io.BytesIO()
        torch.jit.save(torch.jit.script(policy.eval()), buffer)
    buffer.seek(0)
    return torch.jit.load(buffer)


HEADINGS = scenario(2, 'position_heading', 'velocity', None)
STEERING = {'speed': 1.0, 'turn_limit': 0.15}


def measure(ref: str, encoder: str, symmetric, k: int, repeats: int, cutoff=None, **extra):
    """``cutoff``: the equivariant encoder's basis cutoff, if not its own (``math.inf``: none)."""
    torch.manual_seed(0)
    policy = KNODEPolicy(PolicyConfig(ref, k=k, d_cr=3.0, encoder=encoder, symmetric=symmetric, **extra))
    if cutoff is not None:
        policy.encoder.basis_cutoff = cutoff
    d = policy.state_dim
    module = scripted(policy)
    out = {}
    with torch.no_grad():
        for rows in (1, 100):
            Y, mask = torch.randn(rows, k, d), torch.ones(rows, k)
            out[f'command, {rows} robot(s) (us)'] = 1e6 * median_seconds(lambda: module(Y, mask), repeats)
    # training: the trainer's k is the training swarm's size (10 rows), k = 10 for both encoders
    train = KNODEPolicy(
        PolicyConfig(ref, k=10, d_cr=3.0, encoder=encoder, symmetric=symmetric, **extra)
    ).train()
    if cutoff is not None:
        train.encoder.basis_cutoff = cutoff
    Y, mask = torch.randn(2048, 10, d), torch.ones(2048, 10)
    target = torch.randn(2048, train.command_dim)

    def step():
        train.zero_grad()
        loss = ((train(Y, mask) - target) ** 2).mean()
        loss.backward()

    out['training step, 2048 samples (ms)'] = 1e3 * median_seconds(step, max(5, repeats // 10))
    return out


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--repeats', type=int, default=200)
    parser.add_argument(
        '--k', type=int, default=37, help='rows of Y at run time (the set encoder derives ~37)'
    )
    parser.add_argument('--only-tail', action='store_true', help='only the basis tail section')
    parser.add_argument('--only-rank', action='store_true', help='only the rank section')
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    print('$ python bench/bench_encoders.py ' + ' '.join(argv if argv is not None else sys.argv[1:]))
    print(machine())
    if args.only_rank:
        rank_cost(args)
        return
    if not args.only_tail:
        compare_encoders(args)
        rank_cost(args)
    basis_tail(args)


def compare_encoders(args) -> None:
    """The encoders, steering and the axes, each against its baseline."""
    for name, ref in SCENARIOS.items():
        print(f'\n{name} (k = {args.k} at run time, 10 in training)')
        rows = {
            encoder + (' + symmetric' if symmetric else ''): measure(
                ref, encoder, symmetric, args.k, args.repeats
            )
            for encoder, symmetric in KINDS
        }
        table(rows, 'flat')
    print(f'\n2D position_heading, velocity (k = {args.k} at run time, 10 in training)')
    rows = {
        'equivariant': measure(HEADINGS, 'equivariant', False, args.k, args.repeats),
        'equivariant + steering': measure(HEADINGS, 'equivariant', False, args.k, args.repeats, **STEERING),
    }
    table(rows, 'equivariant')
    arena = SCENARIOS['3D position_velocity, acceleration, arena']
    print(f'\n3D position_velocity, acceleration, arena: the axes (k = {args.k} at run time, 10 in training)')
    rows = {
        'equivariant + symmetric': measure(arena, 'equivariant', True, args.k, args.repeats),
        'equivariant + axes + symmetric': measure(
            arena, 'equivariant', True, args.k, args.repeats, axes=True
        ),
        'equivariant + axes + symmetric z': measure(
            arena, 'equivariant', 'z', args.k, args.repeats, axes=True
        ),
    }
    table(rows, 'equivariant + symmetric')


TANK = scenario(3, 'position_heading', 'velocity', {'half_width': 3.0})


def rank_cost(args) -> None:
    """The equivariant encoder with each neighbour's rank (capped at 9) against it without."""
    print(f"\nThe neighbours' rank (k = {args.k} at run time, 10 in training)")
    rows = {}
    for name, ref, extra in (
        ('2D position, velocity', SCENARIOS['2D position, velocity'], {'symmetric': False}),
        ('3D heading tank, steered, axes + symmetric', TANK, {'symmetric': True, 'axes': True, **STEERING}),
    ):
        for label, rank in (('no rank', 0), ('rank', 9)):
            rows[f'{name}, {label}'] = measure(
                ref, 'equivariant', k=args.k, repeats=args.repeats, rank=rank, **extra
            )
    table(rows, '2D position, velocity, no rank', pairs=True)


def basis_tail(args) -> None:
    """The equivariant encoder as the recipe builds it (2D open space; 3D arena with the axes and
    the half-turn average), its basis Gaussians' far tail zero against the same encoder without
    the cutoff (a tail of float32 subnormals)."""
    arena = SCENARIOS['3D position_velocity, acceleration, arena']
    print(
        f"\nThe basis Gaussians' zero tail against their subnormal one (k = {args.k} at run time, 10 in training)"
    )
    rows = {}
    for name, ref, extra in (
        ('2D position, velocity', SCENARIOS['2D position, velocity'], {'symmetric': False}),
        ('3D arena, axes + symmetric', arena, {'symmetric': True, 'axes': True}),
    ):
        for label, cutoff in (('subnormal tail', math.inf), ('zero tail', None)):
            rows[f'{name}, {label}'] = measure(
                ref, 'equivariant', k=args.k, repeats=args.repeats, cutoff=cutoff, **extra
            )
    table(rows, '2D position, velocity, subnormal tail', pairs=True)


def table(rows, base_label: str, pairs: bool = False) -> None:
    """Print ``rows`` (label -> figures) as a markdown table, each figure with its ratio to the
    row ``base_label``'s (``pairs``: each row's to the row before it, every second row)."""
    base = rows[base_label]
    print('| network | ' + ' | '.join(base) + ' |')
    print('|---' * (len(base) + 1) + '|')
    labels = list(rows)
    for i, (label, figures) in enumerate(rows.items()):
        ref = rows[labels[i - i % 2]] if pairs else base
        cells = [f'{v:.1f} ({v / ref[key]:.2f}x)' for key, v in figures.items()]
        print(f'| {label} | ' + ' | '.join(cells) + ' |')


if __name__ == '__main__':
    main()
