"""Benchmark of the live monitor: a simulated swarm (ground truth, realtime) of ``--robots``
robots publishing at ``--rate`` Hz, watched by a ``monitor`` process with its page open in
headless Chromium (tests/browser.py).

With ``--baseline REF`` (a git commit or branch of this repository) the monitor of REF is
measured too, on the same swarm, one after the other (so that the two never share the CPU):
its package is extracted from git (``git archive``) into a temporary directory and run from
there, with the same parameters, environment and ROS domain. Each monitor is measured over
``--window`` wall seconds once its page has updates: the page's updates per second (ticks its
WebSocket delivered), the monitor process's CPU (% of one core, from /proc/<pid>/stat), its
resident memory (VmRSS, the largest sample) and the wall seconds from SIGINT to its exit. The
1-minute load average is read before and after each. Prints one JSON line: the figures of each
monitor, and with a baseline the ratios (baseline / this tree's).

    flock /tmp/bench.lock .venv/bin/python bench/bench_monitor.py [--robots 200] [--rate 20] \\
        [--window 30] [--baseline REF]
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / 'tests'))
sys.path.insert(0, str(ROOT))
from browser import Chromium  # noqa: E402  (the tests' DevTools client)

from knode_swarm_ros.nodes.swarm import DOMAIN_RANGE  # noqa: E402
from knode_swarm_ros.nodes.swarm.commands import child_environment  # noqa: E402
from knode_swarm_ros.nodes.swarm.domains import claim_domain  # noqa: E402

WAIT_S = 300


def _cpu_seconds(pid: int) -> float:
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')  # utime + stime


def _rss_mb(pid: int) -> float:
    text = Path(f'/proc/{pid}/status').read_text()
    return int(re.search(r'VmRSS:\s+(\d+)', text).group(1)) / 1024.0


class Process:
    """A child process, its output lines collected as they come."""

    def __init__(self, cmd, env, cwd=None):
        self.lines = []
        self.proc = subprocess.Popen(
            cmd, env=env, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
        )
        threading.Thread(
            target=lambda: self.lines.extend(x.rstrip() for x in self.proc.stdout), daemon=True
        ).start()

    def wait_for(self, pattern: str) -> re.Match:
        deadline = time.monotonic() + WAIT_S
        while time.monotonic() < deadline and self.proc.poll() is None:
            found = re.search(pattern, '\n'.join(self.lines))
            if found:
                return found
            time.sleep(0.2)
        raise SystemExit(f'{pattern!r} not seen (status {self.proc.poll()}):\n' + '\n'.join(self.lines))

    def stop(self) -> float:
        """SIGINT, then the wall seconds until it exited (killed after WAIT_S)."""
        t0 = time.monotonic()
        self.proc.send_signal(signal.SIGINT)
        try:
            self.proc.wait(timeout=WAIT_S)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        return time.monotonic() - t0


def measure(label: str, pythonpath: str, env: dict, robots: int, window: float) -> dict:
    """Start a monitor of ``pythonpath``'s package, open its page, measure it, stop it."""
    env = dict(env, PYTHONPATH=pythonpath)
    cmd = [sys.executable, '-m', 'knode_swarm_ros.nodes.monitor', '--ros-args']
    cmd += ['-p', f'robots:={robots}', '-p', 'port:=0', '-r', f'__node:=monitor_{label}']
    load_before = os.getloadavg()[0]
    monitor = Process(cmd, env, cwd=pythonpath)
    browser = None
    try:
        url = monitor.wait_for(r'page at (http://\S+/)').group(1)
        browser = Chromium(url)
        browser.wait_until('window.monitor && monitor.received > 0', timeout=WAIT_S)
        time.sleep(3.0)  # past the page's start
        pid = monitor.proc.pid
        r0, c0, t0 = browser.evaluate('monitor.received'), _cpu_seconds(pid), time.monotonic()
        rss = _rss_mb(pid)
        while time.monotonic() - t0 < window:
            time.sleep(1.0)
            rss = max(rss, _rss_mb(pid))
        r1, c1, t1 = browser.evaluate('monitor.received'), _cpu_seconds(pid), time.monotonic()
        shown = browser.evaluate('monitor.last.pos.length')
    finally:
        if browser is not None:
            browser.close()
        stop_s = monitor.stop()
    return {
        'monitor': label,
        'load_average_1min_before': load_before,
        'load_average_1min_after': os.getloadavg()[0],
        'robots_on_page': shown,
        'page_updates_per_s': round((r1 - r0) / (t1 - t0), 2),
        'monitor_cpu_percent_of_one_core': round(100.0 * (c1 - c0) / (t1 - t0), 1),
        'monitor_rss_mb': round(rss, 1),
        'stop_on_sigint_s': round(stop_s, 2),
        'window_s': round(t1 - t0, 1),
    }


def extract(ref: str, into: Path) -> Path:
    """The package of git ``ref`` of this repository, extracted under ``into``."""
    archive = subprocess.run(
        ['git', '-C', str(ROOT), 'archive', ref, 'knode_swarm_ros'], check=True, capture_output=True
    ).stdout
    subprocess.run(['tar', '-x', '-C', str(into)], input=archive, check=True)
    return into


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--robots', type=int, default=200)
    p.add_argument('--rate', type=float, default=20.0)
    p.add_argument('--window', type=float, default=30.0, help='wall seconds measured per monitor')
    p.add_argument('--baseline', metavar='REF', help="also measure git REF's monitor, first")
    args = p.parse_args(argv)

    tmp = Path(tempfile.mkdtemp(prefix='bench_monitor_'))
    claim = claim_domain(range(DOMAIN_RANGE[0], DOMAIN_RANGE[1] + 1))
    env = child_environment(claim.domain_id)
    runs = []
    if args.baseline:
        (tmp / 'baseline').mkdir()
        runs.append(('baseline', str(extract(args.baseline, tmp / 'baseline'))))
    runs.append(('this_tree', str(ROOT)))
    cmd = [sys.executable, '-m', 'knode_swarm_ros.nodes.swarm', '--ground-truth', '--mode', 'realtime']
    cmd += ['--rate', str(args.rate), '--robots', str(args.robots), '--steps', '0']
    cmd += ['--domain-id', str(claim.domain_id), '--record', str(tmp / 'run.npz'), '--no-figure']
    cmd += ['--log-dir', str(tmp / 'logs'), '--quiet']
    swarm = Process(cmd, dict(env, PYTHONPATH=str(ROOT)))
    results = []
    try:
        for label, path in runs:
            results.append(measure(label, path, env, args.robots, args.window))
    finally:
        swarm.stop()
        claim.release()
        shutil.rmtree(tmp, ignore_errors=True)
    out = {
        'date': datetime.datetime.now(datetime.timezone.utc).isoformat(timespec='minutes'),
        'machine': f'{platform.machine()}, {os.cpu_count()} cores',
        'command': ' '.join(['bench/bench_monitor.py', *(argv if argv is not None else sys.argv[1:])]),
        'robots': args.robots,
        'rate_hz': args.rate,
        'runs': results,
    }
    if args.baseline:
        base, this = results
        out['baseline'] = args.baseline
        out['ratio_cpu_baseline_over_this'] = round(
            base['monitor_cpu_percent_of_one_core'] / max(this['monitor_cpu_percent_of_one_core'], 1e-9), 2
        )
        out['ratio_rss_baseline_over_this'] = round(base['monitor_rss_mb'] / this['monitor_rss_mb'], 2)
    print(json.dumps(out))


if __name__ == '__main__':
    main()
