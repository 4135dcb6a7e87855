"""Benchmark of the core: batched neighbour matrices vs a per-robot loop, and one policy call.

Run: python bench/bench_core.py [--trajectories 50 --steps 2000 --robots 10]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time

import numpy as np
import torch

sys.path.insert(0, os.path.join(os.path.dirname(__file__), '..'))
from knode_swarm_ros.core import (
    DEFAULTS,
    KNODEPolicy,
    PolicyConfig,
    export_policy,
    load_policy,
    neighbour_matrices,
    neighbour_matrix_single,
)


def per_robot_loop(states, d_cr, k, tau):
    """Baseline: the straightforward loop over trajectories, steps and robots."""
    S, T, n, d = states.shape
    Y = np.zeros((S, T, n, k, d))
    mask = np.zeros((S, T, n, k), dtype=bool)
    for s in range(S):
        for t in range(T):
            delayed = states[s, max(t - tau, 0)]
            for i in range(n):
                Y[s, t, i], mask[s, t, i] = neighbour_matrix_single(i, states[s, t, i], delayed, 2, d_cr, k)
    return Y, mask


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument('--trajectories', type=int, default=50)
    ap.add_argument('--steps', type=int, default=2000)
    ap.add_argument('--robots', type=int, default=10)
    ap.add_argument(
        '--loop-trajectories',
        type=int,
        default=1,
        help='trajectories timed for the loop baseline (extrapolated linearly)',
    )
    ap.add_argument('--calls', type=int, default=2000)
    args = ap.parse_args()
    torch.set_num_threads(1)
    rng = np.random.default_rng(0)
    n = args.robots
    states = np.concatenate(
        [
            rng.uniform(-np.sqrt(n), np.sqrt(n), (args.trajectories, args.steps, n, 2)),
            rng.normal(size=(args.trajectories, args.steps, n, 2)),
        ],
        axis=-1,
    )
    print(f'# {" ".join([os.path.basename(sys.executable), *sys.argv])}')
    print(
        f'# {time.strftime("%Y-%m-%d")} {platform.machine()} {os.cpu_count()} cores, '
        f'python {platform.python_version()}, numpy {np.__version__}, torch {torch.__version__}'
    )

    t0 = time.perf_counter()
    Y, mask = neighbour_matrices(states, 2, 5.0, 6, 0)
    batched = time.perf_counter() - t0
    sub = states[: args.loop_trajectories]
    t0 = time.perf_counter()
    Yl, ml = per_robot_loop(sub, 5.0, 6, 0)
    loop = (time.perf_counter() - t0) * args.trajectories / args.loop_trajectories
    assert np.array_equal(Yl, Y[: args.loop_trajectories]) and np.array_equal(
        ml, mask[: args.loop_trajectories]
    )
    print(
        f'neighbour matrices {args.trajectories} x {args.steps} x {n} (d_cr 5, k 6): batched {batched:.2f} s, '
        f'per-robot loop {loop:.1f} s (timed on {args.loop_trajectories} trajectories, extrapolated), '
        f'ratio {loop / batched:.0f}x'
    )

    policy = KNODEPolicy(PolicyConfig('flock2d', **DEFAULTS['flock2d']))
    path = '/tmp/knode_bench_policy.pt'
    export_policy(policy, path, policy.metadata())
    loaded = load_policy(path)
    z = states[0, 0]
    Yi, mi = neighbour_matrix_single(3, z[3], z, 2, 5.0, 6)
    Yt = torch.tensor(Yi[None], dtype=torch.float32)
    mt = torch.tensor(mi[None], dtype=torch.float32)
    with torch.no_grad():
        for _ in range(50):
            loaded.module(Yt, mt)
        raw = []
        for _ in range(args.calls):
            t0 = time.perf_counter()
            loaded.module(Yt, mt)
            raw.append(time.perf_counter() - t0)
    full = []
    for _ in range(args.calls):
        t0 = time.perf_counter()
        Yi, mi = neighbour_matrix_single(3, z[3], z, 2, 5.0, 6)
        loaded(Yi[None], mi[None])
        full.append(time.perf_counter() - t0)
    for name, xs in (('policy forward (TorchScript, 1 thread)', raw), ('Y_i build + policy call', full)):
        us = np.array(xs) * 1e6
        print(f'{name}, one robot: p50 {np.percentile(us, 50):.0f} us, p99 {np.percentile(us, 99):.0f} us')


if __name__ == '__main__':
    main()
