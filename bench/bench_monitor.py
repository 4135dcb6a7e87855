"""Benchmark of the live monitor: a simulated swarm (ground truth, realtime) of ``--robots``
robots publishing at ``--rate`` Hz, watched by ``swarm --monitor`` with its page open in
headless Chromium (tests/browser.py).

Measured over ``--window`` wall seconds once the page has updates: the page's updates per
second (ticks its WebSocket delivered), the monitor process's CPU (% of one core, from
/proc/<pid>/stat) and its resident memory (VmRSS, the largest sample). Prints one JSON line.

    .venv/bin/python bench/bench_monitor.py [--robots 200] [--rate 20] [--window 30]
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / 'tests'))
from browser import Chromium  # noqa: E402  (the tests' DevTools client)

WAIT_S = 300


def _cpu_seconds(pid: int) -> float:
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')  # utime + stime


def _rss_mb(pid: int) -> float:
    text = Path(f'/proc/{pid}/status').read_text()
    return int(re.search(r'VmRSS:\s+(\d+)', text).group(1)) / 1024.0


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--robots', type=int, default=200)
    p.add_argument('--rate', type=float, default=20.0)
    p.add_argument('--window', type=float, default=30.0, help='wall seconds measured')
    args = p.parse_args(argv)

    tmp = Path(tempfile.mkdtemp(prefix='bench_monitor_'))
    cmd = [sys.executable, '-m', 'knode_swarm_ros.nodes.swarm', '--ground-truth', '--mode', 'realtime']
    cmd += ['--rate', str(args.rate), '--robots', str(args.robots), '--steps', '0', '--monitor', '0']
    cmd += ['--record', str(tmp / 'run.npz'), '--no-figure', '--log-dir', str(tmp / 'logs'), '--quiet']
    env = dict(os.environ, PYTHONUNBUFFERED='1', ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    env['PYTHONPATH'] = os.pathsep.join([str(ROOT), env.get('PYTHONPATH', '')])
    swarm = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines = []
    threading.Thread(target=lambda: lines.extend(line.rstrip() for line in swarm.stdout), daemon=True).start()
    browser = None
    try:
        deadline = time.monotonic() + WAIT_S
        pid = url = None
        while (pid is None or url is None) and time.monotonic() < deadline and swarm.poll() is None:
            time.sleep(0.2)
            text = '\n'.join(lines)
            found = re.search(r'monitor \(pid (\d+)\)', text)
            pid = int(found.group(1)) if found else None
            log = tmp / 'logs' / 'monitor.log'
            found = re.search(r'page at (http://\S+/)', log.read_text() if log.exists() else '')
            url = found.group(1) if found else None
        if url is None:
            raise SystemExit('the monitor did not start:\n' + '\n'.join(lines))
        browser = Chromium(url)
        browser.wait_until('window.monitor && monitor.received > 0', timeout=WAIT_S)
        time.sleep(3.0)  # past the page's start
        r0, c0, t0 = browser.evaluate('monitor.received'), _cpu_seconds(pid), time.monotonic()
        rss = _rss_mb(pid)
        while time.monotonic() - t0 < args.window:
            time.sleep(1.0)
            rss = max(rss, _rss_mb(pid))
        r1, c1, t1 = browser.evaluate('monitor.received'), _cpu_seconds(pid), time.monotonic()
        robots_shown = browser.evaluate('monitor.last.pos.length')
    finally:
        if browser is not None:
            browser.close()
        swarm.send_signal(signal.SIGINT)
        try:
            swarm.wait(timeout=WAIT_S)
        except subprocess.TimeoutExpired:
            swarm.kill()
            swarm.wait()
    print(
        json.dumps(
            {
                'date': datetime.date.today().isoformat(),
                'machine': f'{platform.machine()}, {os.cpu_count()} cores',
                'load_average_1min': os.getloadavg()[0],
                'robots': args.robots,
                'rate_hz': args.rate,
                'robots_on_page': robots_shown,
                'page_updates_per_s': round((r1 - r0) / (t1 - t0), 2),
                'monitor_cpu_percent_of_one_core': round(100.0 * (c1 - c0) / (t1 - t0), 1),
                'monitor_rss_mb': round(rss, 1),
                'window_s': round(t1 - t0, 1),
            }
        )
    )


if __name__ == '__main__':
    main()
