"""Benchmark the ground-truth generators on the paper's full datasets.

    python bench/bench_groundtruth.py [--repeat 3] [--baseline-trajectories 2] [--baseline-steps 100]

Times, in one run:

* vectorised: ``simulate`` over all trajectories and robots at once (flock2d 50 x 2000 x 10,
  boids3d 22 x 1700 x 10; boids3d also steps the 10 discarded frames), best of --repeat;
* per-trajectory loop: the same vectorised step called once per trajectory (vectorised over
  robots only), timed on all trajectories for --baseline-steps steps and extrapolated linearly;
* per-robot loop: a plain Python loop over trajectories and robots (numpy only across the
  other robots; for boids the 300 golden-spiral directions are tried one by one until one is
  clear, as Lague's C# does), timed on --baseline-trajectories trajectories for --baseline-steps
  steps and extrapolated linearly to the full set.

Each baseline is checked against the vectorised result on the subset it ran (max abs difference).
The extrapolation is linear in trajectories and steps; for boids the per-robot cost depends on how
many boids need the direction search, so that figure is an estimate. Goals on 2 cores:
flock2d full set < 2 s, boids3d < 10 s. Nothing here asserts timings.
"""

from __future__ import annotations

import argparse
import datetime
import math
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from knode_swarm_ros.core.groundtruth import BoidsSwarm, simulate
from knode_swarm_ros.core.groundtruth import boids as B
from knode_swarm_ros.core.groundtruth import tanner as T

FULL = {'flock2d': (50, 2000, 10), 'boids3d': (22, 1700, 10)}  # trajectories, recorded frames, robots
GOAL_S = {'flock2d': 2.0, 'boids3d': 10.0}
SEED = 0


# --- per-robot Python loop baselines ------------------------------------------------------------


def loop_tanner_accel(z: np.ndarray) -> np.ndarray:
    """Tanner law for one swarm ``[n, 4]``, one robot at a time."""
    n = z.shape[0]
    a = np.empty((n, 2))
    for i in range(n):
        d = z[i, :2] - z[:, :2]
        r2 = np.einsum('jk,jk->j', d, d)
        r2[i] = np.inf
        c = 2.0 / r2 - 2.0 / r2**2
        a[i] = -(z[i, 2:] - z[:, 2:]).sum(axis=0) - (c[:, None] * d).sum(axis=0)
    return a


def loop_tanner_step(z: np.ndarray, dt: float) -> np.ndarray:
    def f(s):
        return np.concatenate([s[:, 2:], loop_tanner_accel(s)], axis=1)

    return T.rk4(f, z, dt)


def _steer(w, v, P):
    m = math.sqrt(w @ w)
    s = (w / m if m > B.NORMALISE_EPS else 0.0 * w) * P.max_speed - v
    ms = math.sqrt(s @ s)
    return s * (P.max_steer_force / ms) if ms > P.max_steer_force else s


def _hits(p, d, P):
    reach = P.box - P.bounds_radius
    for a in range(3):
        if d[a] > 0 and P.collision_avoid_dst * d[a] >= max(reach - p[a], np.finfo(float).tiny):
            return True
        if d[a] < 0 and -P.collision_avoid_dst * d[a] >= max(reach + p[a], np.finfo(float).tiny):
            return True
    return False


def loop_boids_step(p: np.ndarray, v: np.ndarray, P: B.BoidsParams):
    """One frame for one swarm ``[n, 3]``, one boid at a time (Lague's Boid.UpdateBoid)."""
    n = p.shape[0]
    spiral = B.golden_spiral_directions(P.num_directions)
    h = v / np.linalg.norm(v, axis=1, keepdims=True)
    p_new, v_new = np.empty_like(p), np.empty_like(v)
    for i in range(n):
        off = p - p[i]
        sq = np.einsum('jk,jk->j', off, off)
        mates = sq < P.perception_radius**2
        mates[i] = False
        acc = np.zeros(3)
        if mates.any():
            near = mates & (sq < P.avoidance_radius**2)
            align = h[mates].sum(axis=0)
            coh = p[mates].mean(axis=0) - p[i]
            sep = -(off[near] / sq[near, None]).sum(axis=0)
            acc += (
                P.align_weight * _steer(align, v[i], P)
                + P.cohesion_weight * _steer(coh, v[i], P)
                + P.separate_weight * _steer(sep, v[i], P)
            )
        if _hits(p[i], h[i], P):
            R = B.look_rotation(h[i])
            target = h[i]
            for k in range(spiral.shape[0]):
                d = spiral[k] @ R
                if not _hits(p[i], d, P):
                    target = d
                    break
            acc += P.avoid_collision_weight * _steer(target, v[i], P)
        w = v[i] + acc * P.dt
        speed = math.sqrt(w @ w)
        w = w / speed * min(max(speed, P.min_speed), P.max_speed)
        v_new[i] = w
        p_new[i] = p[i] + w * P.dt
    return p_new, v_new


# --- timing -----------------------------------------------------------------------------------


def best_of(repeat, fn):
    times, out = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), out


def bench_flock2d(args):
    S, Tn, n = FULL['flock2d']
    t_vec, states = best_of(args.repeat, lambda: simulate('flock2d', S, n, Tn, SEED, progress=False))
    z0 = states[:, 0]
    k = args.baseline_steps
    # per-trajectory loop: all trajectories, k steps
    t0 = time.perf_counter()
    traj_out = []
    for s in range(S):
        z = z0[s]
        for _ in range(k):
            z = T.rk4_step(z, T.DT)
        traj_out.append(z)
    t_traj = (time.perf_counter() - t0) * (Tn - 1) / k
    err_traj = np.abs(np.stack(traj_out) - states[:, k]).max()
    # per-robot loop: m trajectories, k steps
    m = args.baseline_trajectories
    t0 = time.perf_counter()
    robot_out = []
    for s in range(m):
        z = z0[s]
        for _ in range(k):
            z = loop_tanner_step(z, T.DT)
        robot_out.append(z)
    t_robot = (time.perf_counter() - t0) * (S / m) * (Tn - 1) / k
    err_robot = np.abs(np.stack(robot_out) - states[:m, k]).max()
    return t_vec, t_traj, err_traj, t_robot, err_robot


def bench_boids3d(args):
    S, Tn, n = FULL['boids3d']
    P = B.PRESETS['paper']
    frames = B.DISCARD_FRAMES + Tn - 1
    t_vec, _ = best_of(args.repeat, lambda: simulate('boids3d', S, n, Tn, SEED, progress=False))
    k = args.baseline_steps
    swarm = BoidsSwarm.spawn(np.random.default_rng(SEED), S, n, P)
    p0, v0 = swarm.positions.copy(), swarm.velocities.copy()
    for _ in range(k):
        swarm.step()
    ref_p = swarm.positions
    t0 = time.perf_counter()
    out = []
    for s in range(S):
        one = BoidsSwarm(p0[s : s + 1], v0[s : s + 1], P)
        for _ in range(k):
            one.step()
        out.append(one.positions[0])
    t_traj = (time.perf_counter() - t0) * frames / k
    err_traj = np.abs(np.stack(out) - ref_p).max()
    m = args.baseline_trajectories
    t0 = time.perf_counter()
    out = []
    for s in range(m):
        p, v = p0[s], v0[s]
        for _ in range(k):
            p, v = loop_boids_step(p, v, P)
        out.append(p)
    t_robot = (time.perf_counter() - t0) * (S / m) * frames / k
    err_robot = np.abs(np.stack(out) - ref_p[:m]).max()
    return t_vec, t_traj, err_traj, t_robot, err_robot


def cpu_model() -> str:
    try:
        with open('/proc/cpuinfo') as fh:
            for line in fh:
                if line.startswith('model name'):
                    return line.split(':', 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or 'unknown CPU'


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--repeat', type=int, default=3, help='vectorised runs per scenario (best is reported)')
    ap.add_argument(
        '--baseline-trajectories', type=int, default=2, help='trajectories the per-robot loop runs'
    )
    ap.add_argument('--baseline-steps', type=int, default=100, help='steps each baseline runs')
    args = ap.parse_args(argv)
    if min(args.repeat, args.baseline_trajectories, args.baseline_steps) < 1:
        ap.error('--repeat, --baseline-trajectories and --baseline-steps must be >= 1')
    command = 'python ' + ' '.join([os.path.relpath(sys.argv[0])] + sys.argv[1:])
    print(f'# ground-truth benchmark, {datetime.date.today().isoformat()}')
    print(f'command: {command}')
    print(
        f'machine: {platform.platform()}, {os.cpu_count()} CPUs (os.cpu_count), {cpu_model()}; '
        f'python {platform.python_version()}, numpy {np.__version__}'
    )
    print(
        f'baselines: per-trajectory loop on all trajectories x {args.baseline_steps} steps, per-robot loop on '
        f'{args.baseline_trajectories} trajectories x {args.baseline_steps} steps, both extrapolated linearly '
        f'to the full set; vectorised: best of {args.repeat} full runs'
    )
    print()
    print(
        '| dataset | vectorised (s) | goal (s) | per-trajectory loop (s, extrap.) | ratio | '
        'per-robot loop (s, extrap.) | ratio | max |diff| traj / robot |'
    )
    print('| --- | --- | --- | --- | --- | --- | --- | --- |')
    for name, fn in (('flock2d', bench_flock2d), ('boids3d', bench_boids3d)):
        S, Tn, n = FULL[name]
        t_vec, t_traj, e_traj, t_robot, e_robot = fn(args)
        print(
            f'| {name} {S} x {Tn} x {n} | {t_vec:.2f} | {GOAL_S[name]:.0f} | {t_traj:.1f} | {t_traj / t_vec:.1f}x | '
            f'{t_robot:.1f} | {t_robot / t_vec:.0f}x | {e_traj:.1e} / {e_robot:.1e} |',
            flush=True,
        )
    return 0


if __name__ == '__main__':
    sys.exit(main())
