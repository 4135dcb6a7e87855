"""Benchmark a pose-only fleet in real time against exact Odometry, and the velocity estimator.

    python bench/bench_fleet.py [--starts 10] [--steps 400] [--noise 0.002] [--pose-rate 100] [--budget-s S]

Swarm part: ``--robots`` robots of the shipped 20 Hz flock2d policy in realtime at 20 Hz, from
each of ``--starts`` held-out seeded starts (seeds 100, 101, ...), run twice by the launcher:
once with exact Odometry (no fleet) and once with a fleet that gives PoseStamped only
(``swarm --fleet F --pose-noise SIGMA --pose-rate HZ``: the agents estimate every velocity).
Per run: the final avd of the true velocities (the simulator's final states, its report: a
pose-only recording holds the noisy poses, whose differences would measure the noise) and the
smallest pair distance after the first second (recorded positions). The fleet states the motion capture's rate,
so its velocity window is the default for that rate (``core.estimator.window_for_rate``: 10
samples at 100 Hz); above 1 / dt the simulator takes sub-steps and publishes every one.
``--budget-s``: start no new held-out start after that many seconds (the figures say how many ran).

Estimator part (no ROS): :class:`knode_swarm_ros.core.estimator.VelocityEstimator` on
``--streams`` simulated 100 Hz streams with 2 mm white position noise: the measured lag on a
constant acceleration and the velocity noise (1 sigma per axis), against their formulas.

Nothing here asserts; it prints one JSON object.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from knode_swarm_ros.core import load_trajectories
from knode_swarm_ros.core.estimator import (
    DEFAULT_WINDOW,
    VelocityEstimator,
    lag_s,
    noise_gain,
    window_for_rate,
)
from knode_swarm_ros.core.metrics import avd


def estimator_figures(window: int, rate: float, sigma: float, streams: int, seed: int = 0) -> dict:
    """Measured lag (constant acceleration) and velocity noise of the estimator at ``rate`` Hz."""
    h = 1.0 / rate
    est = VelocityEstimator(window)
    a = 1.0
    for j in range(window + 5):  # p = a t^2 / 2: the estimate is v(t - lag) = a (t - lag)
        t = j * h
        v = est.update(int(round(t * 1e9)), np.array([0.5 * a * t * t]))
    lag = t - float(v[0]) / a
    rng = np.random.default_rng(seed)
    est = VelocityEstimator(window)
    samples = window + 200
    noise = rng.normal(0.0, sigma, (samples, streams))
    errors = []
    for j in range(samples):
        v = est.update(int(round(j * h * 1e9)), noise[j])  # a robot at rest: the estimate is the error
        if j >= window:
            errors.append(v.copy())
    measured = float(np.std(np.concatenate(errors)))
    return {
        'window': window,
        'rate_hz': rate,
        'sigma_m': sigma,
        'lag_ms': 1e3 * lag,
        'lag_formula_ms': 1e3 * lag_s(window, h),
        'velocity_noise_mm_s': 1e3 * measured,
        'velocity_noise_formula_mm_s': 1e3 * sigma * noise_gain(window, h),
    }


def run_swarm(tmp: Path, name: str, seed: int, args, fleet=None) -> dict:
    record = tmp / f'{name}_{seed}.npz'
    logs = tmp / f'{name}_{seed}_logs'
    cmd = [
        sys.executable, '-m', 'knode_swarm_ros.nodes.swarm', '--mode', 'realtime', '--rate', '20',
        '--robots', str(args.robots), '--steps', str(args.steps), '--seed', str(seed), '--record', str(record),
        '--no-figure', '--quiet', '--agents-per-process', str(args.agents_per_process), '--log-dir', str(logs),
    ]  # fmt: skip
    if fleet is not None:
        cmd += ['--fleet', str(fleet), '--pose-noise', str(args.noise), '--pose-rate', str(args.pose_rate)]
    load_before = os.getloadavg()[0]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=args.timeout)
    if proc.returncode != 0:
        return {'seed': seed, 'error': proc.returncode, 'tail': (proc.stdout + proc.stderr)[-600:]}
    data = load_trajectories(record)
    p = data.states[0][..., data.spec.position]  # [T, n, 2]
    report = json.loads((logs / 'simulator.json').read_text())
    true = np.array(report['states'])
    final_avd = float(avd(true[:, data.spec.velocity]))
    after = int(round(1.0 / data.dt))
    gaps = np.linalg.norm(p[after:, :, None] - p[after:, None], axis=-1)
    n = p.shape[1]
    gaps[:, np.arange(n), np.arange(n)] = np.inf
    return {
        'seed': seed,
        'final_avd': final_avd,
        'min_pair_distance': float(gaps.min()),
        # how the run went: state-to-command latency, sub-steps the simulator had to drop
        # (overruns: it was descheduled) and robot-sub-steps without a fresh command (zeroed)
        'latency_ms_p50': report['latency_ms']['p50'],
        'latency_ms_p99': report['latency_ms']['p99'],
        'overruns': report['overruns'],
        'zeroed': report['counters']['zeroed'],
        'load_before': load_before,
        'load_after': os.getloadavg()[0],
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--starts', type=int, default=10)
    ap.add_argument('--robots', type=int, default=10)
    ap.add_argument('--steps', type=int, default=400, help='steps of 0.05 s (default 400: 20 s)')
    ap.add_argument('--noise', type=float, default=0.002)
    ap.add_argument('--pose-rate', type=float, default=100.0)
    ap.add_argument(
        '--window',
        type=int,
        default=0,
        help="the fleet's velocity_window (0: the fleet's default for --pose-rate, window_for_rate)",
    )
    ap.add_argument('--budget-s', type=float, default=0.0, help='start no new start after this (0: no limit)')
    ap.add_argument('--agents-per-process', type=int, default=1)
    ap.add_argument('--streams', type=int, default=2000)
    ap.add_argument('--timeout', type=float, default=300.0)
    ap.add_argument('--no-swarm', action='store_true', help='the estimator part only')
    args = ap.parse_args(argv)
    out = {
        'date': datetime.date.today().isoformat(),
        'machine': f'{platform.machine()}, {os.cpu_count()} cores',
        'load_average': os.getloadavg(),
        'estimator': estimator_figures(DEFAULT_WINDOW, 100.0, 0.002, args.streams),
    }
    if args.window and args.window != DEFAULT_WINDOW:
        out['estimator_window'] = estimator_figures(args.window, 100.0, 0.002, args.streams)
    if not args.no_swarm:
        with tempfile.TemporaryDirectory(prefix='bench_fleet_') as tmp:
            tmp = Path(tmp)
            fleet = tmp / 'fleet.yaml'
            robots = {f'cf{i}': {'id': i} for i in range(args.robots)}
            window = args.window or window_for_rate(args.pose_rate)
            state = {'topic': '/mocap/{name}/pose', 'type': 'pose', 'rate': args.pose_rate}
            if args.window:
                state['velocity_window'] = args.window
            fleet.write_text(json.dumps({'robots': robots, 'state': state}))
            runs = []
            wall0 = time.monotonic()
            for seed in range(100, 100 + args.starts):
                if args.budget_s and time.monotonic() - wall0 > args.budget_s:
                    break
                runs.append(
                    {
                        'odometry': run_swarm(tmp, 'odom', seed, args),
                        'pose': run_swarm(tmp, 'pose', seed, args, fleet),
                    }
                )
                print(json.dumps(runs[-1]), file=sys.stderr, flush=True)
        ok = [r for r in runs if 'final_avd' in r['odometry'] and 'final_avd' in r['pose']]
        odom = np.array([r['odometry']['final_avd'] for r in ok])
        pose = np.array([r['pose']['final_avd'] for r in ok])
        out['swarm'] = {
            'starts': len(runs),
            'wall_s': time.monotonic() - wall0,
            'completed': len(ok),
            'steps': args.steps,
            'pose_rate_hz': args.pose_rate,
            'pose_noise_m': args.noise,
            'velocity_window': window,
            'lag_ms': 1e3 * lag_s(window, 1.0 / args.pose_rate),
            'velocity_noise_mm_s': 1e3 * args.noise * noise_gain(window, 1.0 / args.pose_rate),
            'final_avd_odometry_mean': float(odom.mean()) if ok else None,
            'final_avd_pose_mean': float(pose.mean()) if ok else None,
            'final_avd_ratio_pose_over_odometry': float(pose.mean() / odom.mean()) if ok else None,
            'min_pair_distance_after_1s_pose': min(
                (r['pose']['min_pair_distance'] for r in ok), default=None
            ),
            'min_pair_distance_after_1s_odometry': min(
                (r['odometry']['min_pair_distance'] for r in ok), default=None
            ),
            'median_final_avd_odometry': float(np.median(odom)) if ok else None,
            'median_final_avd_pose': float(np.median(pose)) if ok else None,
            'starts_within_30_percent': int(np.sum(pose <= 1.3 * odom)) if ok else 0,
            'starts_pose_pair_closer_than_0.3': sum(r['pose']['min_pair_distance'] < 0.3 for r in ok),
            'load_average_after': os.getloadavg(),
            'command': ' '.join([Path(sys.executable).name, *sys.argv]),
            'runs': runs,
        }
        out['swarm']['load_average_after'] = os.getloadavg()
    print(json.dumps(out, indent=1))


if __name__ == '__main__':
    main()
