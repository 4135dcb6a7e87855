"""Roll a policy file out from a trajectory's initial state (canonical ZOH semantics).

    python -m training.rollout --policy P.pt --init FILE.npz[:TRAJ] --steps T --out OUT.npz [--runtime onnxruntime] \
        [--observe pose [--velocity-window N]] \
        [--link-loss P --link-delay-steps N --link-jitter-steps N --link-range M --seed S]

Any valid policy file works (whoever wrote it): the policy's ``k``, ``d_cr``, ``tau`` and
``dt`` come from its ``knode.json``; the initial state is frame 0 of trajectory ``TRAJ``
(default 0) of a trajectory file of the same scenario. The output is a trajectory file
with one trajectory of ``T + 1`` frames, produced by :func:`knode_swarm_ros.core.rollout`,
or, with any ``--link-*`` option, by :func:`knode_swarm_ros.core.link.link_rollout` (the agents'
link model: loss, delay and jitter in steps, radio range; seeded; its counters go into ``meta``).
``--runtime`` picks the policy backend as the agent's ``policy_runtime`` does (default
``torchscript``, the reference; ``onnxruntime`` rolls the ONNX twin out, as robots run it).
``--observe pose`` makes the robots hear poses only, as a motion-capture fleet does: every
velocity in what they hear is estimated by the agents' estimator (:mod:`knode_swarm_ros.core.estimator`,
``--velocity-window`` samples; a robot's own velocity also from its own commands, as the agents'
own row); the states written are the true ones.
"""

from __future__ import annotations

import argparse
import os
import sys
from typing import List, Optional

import numpy as np

from knode_swarm_ros.core import (
    RUNTIMES,
    TrajectoryError,
    load_runtime,
    load_trajectories,
    parse_trajectory_ref,
    rollout,
    save_trajectories,
)
from knode_swarm_ros.core.cli import cli
from knode_swarm_ros.core.errors import KnodeError
from knode_swarm_ros.core.estimator import DEFAULT_WINDOW
from knode_swarm_ros.core.link import LinkConfig, link_rollout
from knode_swarm_ros.core.rollout import OBSERVATIONS


def rollout_file(
    policy_path: str,
    init_ref: str,
    steps: int,
    out: str,
    dt: Optional[float] = None,
    runtime: str = 'torchscript',
    link: Optional[LinkConfig] = None,
    timeout_steps: Optional[int] = None,
    observe: str = 'state',
    velocity_window: int = DEFAULT_WINDOW,
) -> np.ndarray:
    """Roll ``policy_path`` out from frame 0 of ``init_ref`` and write ``out``; returns ``[T + 1, n, d]``."""
    policy = load_runtime(policy_path, runtime)
    path, index = parse_trajectory_ref(init_ref)
    data = load_trajectories(path, scenario=policy.scenario)
    if not 0 <= index < data.states.shape[0]:
        raise TrajectoryError(
            f'{path}: trajectory index {index} out of range (file holds {data.states.shape[0]} trajectories)'
        )
    if steps < 0:
        raise ValueError(f'--steps must be >= 0, got {steps}')
    step_dt = policy.dt if dt is None else float(dt)
    z0 = data.states[index, 0]
    extra = {}
    if observe != 'state':
        extra['observe'] = {'kind': observe, 'velocity_window': int(velocity_window)}
    if link is not None and link.enabled:
        if observe != 'state':
            raise KnodeError('--observe pose does not combine with the link model (--link-*)')
        timeout = timeout_steps if timeout_steps is not None else max(1, round(0.5 / step_dt))
        states, stats = link_rollout(
            policy, z0, steps, policy.scenario, policy.d_cr, policy.k, policy.tau, step_dt, link, timeout
        )
        extra = {
            'link': {
                'loss': link.loss,
                'delay_steps': int(link.delay),
                'jitter_steps': int(link.jitter),
                'range': link.range,
                'seed': int(link.seed),
                'timeout_steps': int(timeout),
                **stats,
            }
        }
    else:
        states = rollout(
            policy,
            z0,
            steps,
            policy.scenario,
            policy.d_cr,
            policy.k,
            policy.tau,
            step_dt,
            observe=observe,
            velocity_window=velocity_window,
        )
    meta = {
        **extra,
        'generator': 'training.rollout',
        'policy': os.fspath(policy_path),
        'init': init_ref,
        'steps': int(steps),
        'runtime': policy.backend,
        'k': policy.k,
        'd_cr': policy.d_cr,
        'tau': policy.tau,
        'policy_meta': {k: policy.meta.get(k) for k in ('scenario', 'frame', 'command_limit', 'hidden')},
    }
    save_trajectories(out, states[None], step_dt, policy.scenario, meta)
    return states


@cli('python -m training.rollout')
def main(argv: Optional[List[str]] = None) -> int:
    parser = argparse.ArgumentParser(prog='python -m training.rollout', description=__doc__.split('\n\n')[0])
    parser.add_argument('--policy', required=True, help='policy file (.pt, TorchScript with knode.json)')
    parser.add_argument(
        '--init', required=True, help='FILE.npz[:TRAJ], initial state = frame 0 of trajectory TRAJ'
    )
    parser.add_argument('--steps', required=True, type=int, help='number of steps to roll out')
    parser.add_argument('--out', required=True, help='output trajectory file (.npz)')
    parser.add_argument(
        '--runtime',
        choices=RUNTIMES,
        default='torchscript',
        help='policy backend (default torchscript; auto: the ONNX twin when it exists)',
    )
    parser.add_argument(
        '--observe',
        choices=OBSERVATIONS,
        default='state',
        help='what robots hear: exact states (default) or poses, velocities estimated',
    )
    parser.add_argument(
        '--velocity-window',
        type=int,
        default=DEFAULT_WINDOW,
        metavar='N',
        help=f'--observe pose: samples of the velocity fit (default {DEFAULT_WINDOW})',
    )
    parser.add_argument('--dt', type=float, default=None, help="step in seconds (default: the policy's dt)")
    parser.add_argument(
        '--link-loss', type=float, default=0.0, metavar='P', help='link model: loss probability'
    )
    parser.add_argument(
        '--link-delay-steps', type=int, default=0, metavar='N', help='link model: extra delay'
    )
    parser.add_argument(
        '--link-jitter-steps', type=int, default=0, metavar='N', help='link model: plus U{0..N}'
    )
    parser.add_argument(
        '--link-range', type=float, default=0.0, metavar='M', help='link model: radio range (0: none)'
    )
    parser.add_argument(
        '--link-timeout-steps',
        type=int,
        default=None,
        metavar='N',
        help='a peer silent longer than this is no neighbour (default: 0.5 s of steps)',
    )
    parser.add_argument('--seed', type=int, default=0, help='seed of the link model (default 0)')
    args = parser.parse_args(argv)
    for flag in ('link_delay_steps', 'link_jitter_steps'):
        if getattr(args, flag) < 0:
            raise KnodeError(f'--{flag.replace("_", "-")} must be >= 0, got {getattr(args, flag)}')
    link = LinkConfig(
        args.link_loss,
        float(args.link_delay_steps),
        float(args.link_jitter_steps),
        args.link_range,
        args.seed,
    )
    link.validate(prefix='--link-')
    if args.link_timeout_steps is not None and args.link_timeout_steps < 0:
        raise KnodeError(f'--link-timeout-steps must be >= 0, got {args.link_timeout_steps}')
    if args.velocity_window < 2:
        raise KnodeError(f'--velocity-window must be >= 2, got {args.velocity_window}')
    states = rollout_file(
        args.policy,
        args.init,
        args.steps,
        args.out,
        args.dt,
        args.runtime,
        link,
        args.link_timeout_steps,
        args.observe,
        args.velocity_window,
    )
    print(f'wrote {args.out}: {states.shape[0]} frames of {states.shape[1]} robots')
    return 0


if __name__ == '__main__':
    sys.exit(main())
