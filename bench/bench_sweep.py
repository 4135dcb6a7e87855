"""A 6-cell flock2d sweep (policy.k = 6, 10 x seed = 0, 1, 2) with one worker and with two, in one run.

    python bench/bench_sweep.py [--epochs 6] [--trajectories 20] [--steps 1000] [--out /tmp/bench_sweep]

Generates a small flock2d data file, then runs ``python -m training.sweep`` twice on it with the same
cells: ``--workers 1`` (in this process, no Ray) and ``--workers 2`` (a local Ray, its start
included in the time). Prints both wall-clock times, their ratio (the goal: at most 0.6) and the
load average around each, since other jobs on the machine slow the two-worker run most.
"""

from __future__ import annotations

import argparse
import os
import shlex
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def run(cmd):
    env = {**os.environ, 'PYTHONPATH': ROOT + os.pathsep + os.environ.get('PYTHONPATH', '')}
    t0 = time.perf_counter()
    subprocess.run(cmd, cwd=ROOT, env=env, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--epochs', type=int, default=6)
    parser.add_argument('--trajectories', type=int, default=20, help='generated trajectories (10 robots)')
    parser.add_argument('--steps', type=int, default=1000, help='frames per generated trajectory')
    parser.add_argument('--out', default=None, help='working folder (default: a temporary one)')
    args = parser.parse_args()
    out = args.out or tempfile.mkdtemp(prefix='bench_sweep_')
    data = os.path.join(out, 'flock2d.npz')
    py = sys.executable
    run(
        [py, '-m', 'training.generate', '--scenario', 'flock2d', '--trajectories', str(args.trajectories)]
        + ['--robots', '10', '--steps', str(args.steps), '--train', str(args.trajectories - 2)]
        + ['--no-progress', '--out', data]
    )
    times, loads = {}, {}
    for workers in (1, 2):
        cmd = [py, '-m', 'training.sweep', '--config', 'config/train_flock2d.yaml', '--data', data]
        cmd += ['--out', os.path.join(out, f'workers{workers}'), '--workers', str(workers)]
        cmd += ['--axis', 'policy.k=6,10', '--axis', 'seed=0,1,2', '--set', f'training.epochs={args.epochs}']
        cmd += ['--set', 'data.val_trajectories=2', '--set', 'selection.trajectories=2']
        before = os.getloadavg()[0]
        times[workers] = run(cmd)
        loads[workers] = (before, os.getloadavg()[0])
        print(
            f'workers {workers}: {times[workers]:.1f} s (load average {before:.1f} -> {loads[workers][1]:.1f})'
        )
        print('  ' + shlex.join(cmd), flush=True)
    print(f'ratio 2 workers / 1 worker: {times[2] / times[1]:.2f} (goal <= 0.6); cores {os.cpu_count()}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
