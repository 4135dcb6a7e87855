"""What the install costs: the venv's size, its torch build, and the memory of
one agent process.

    python bench/bench_install.py

Prints the size of ``sys.prefix`` (the venv) and of its torch package, the torch version (a
``+cpu`` build unless ``TORCH_BUILD=cuda`` made it), how many nvidia-* packages are installed,
and the private and resident memory (``/proc/PID/smaps_rollup``) of an agent process for one
robot once it has loaded its policy, against the same figures of a bare ``python -c 'import
rclpy'`` process as the baseline.
"""

from __future__ import annotations

import datetime
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _du(path: Path) -> int:
    total = 0
    for root, _dirs, files in os.walk(path):
        for name in files:
            try:
                total += os.lstat(os.path.join(root, name)).st_size
            except OSError:
                pass
    return total


def _memory(pid: int):
    private = rss = 0
    with open(f'/proc/{pid}/smaps_rollup') as fh:
        for line in fh:
            key, _, rest = line.partition(':')
            if key in ('Private_Clean', 'Private_Dirty'):
                private += int(rest.split()[0])
            elif key == 'Rss':
                rss = int(rest.split()[0])
    return private / 1024, rss / 1024


def _measure(cmd, ready, log_path):
    env = dict(
        os.environ,
        PYTHONPATH=str(REPO),
        ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
        ROS_DOMAIN_ID=os.environ.get('ROS_DOMAIN_ID', '99'),
        OMP_NUM_THREADS='1',
    )
    with open(log_path, 'wb') as log:
        proc = subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline and proc.poll() is None and ready not in Path(log_path).read_text():
            time.sleep(0.1)
        time.sleep(1.0)
        return _memory(proc.pid)
    finally:
        proc.terminate()
        proc.wait(timeout=60)


def main() -> int:
    prefix = Path(sys.prefix)
    site = Path(next(p for p in sys.path if p.endswith('site-packages')))
    import torch

    nvidia = [p.name for p in site.iterdir() if p.name.lower().startswith('nvidia')]
    print(
        f'# bench_install {datetime.date.today()} on {platform.machine()} ({os.cpu_count()} cores, load '
        f'{os.getloadavg()[0]:.1f}); command: {sys.executable} {" ".join(sys.argv)}'
    )
    print(
        f'venv {prefix}: {_du(prefix) / 2**30:.2f} GiB; torch {torch.__version__}: '
        f'{_du(Path(torch.__file__).parent) / 2**20:.0f} MiB; nvidia-* entries in site-packages: {len(nvidia)}'
    )
    tmp = Path(os.environ.get('TMPDIR', '/tmp'))
    base = _measure(
        [sys.executable, '-c', 'import rclpy, time; print("ready", flush=True); time.sleep(600)'],
        'ready',
        tmp / 'bench_install_base.log',
    )
    agent = _measure(
        [sys.executable, '-m', 'knode_swarm_ros.nodes.agent', '--ros-args', '-p', 'id:=0', '-p', 'robots:=1'],
        'publishing',
        tmp / 'bench_install_agent.log',
    )
    print(f'baseline python + rclpy: private {base[0]:.0f} MiB, RSS {base[1]:.0f} MiB')
    print(
        f'agent (1 robot, shipped flock2d policy): private {agent[0]:.0f} MiB, RSS {agent[1]:.0f} MiB '
        f'({agent[0] / max(base[0], 1e-9):.1f}x the baseline private memory)'
    )
    return 0


if __name__ == '__main__':
    sys.exit(main())
