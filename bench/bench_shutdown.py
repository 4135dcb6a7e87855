"""Shutdown under traffic: agent, hosted agents, simulator and recorder
each stopped with SIGINT or SIGTERM (alternating) while messages flow, REPS times each.

    python bench/bench_shutdown.py              # 50 times each (about 15 minutes on 2 cores)
    python bench/bench_shutdown.py --reps 10 --nodes agent

For every stop it records the exit status, the wall time from the signal to the process's exit,
and the FastDDS shared-memory files of the process left behind: the files of every lock the
process held while it ran (/proc/locks, swarm.shm.shm_held_by) still there, unlocked, after it
ended; its segment at once, its ports once the series' peers have gone too (a port is open in
the peers that sent to it). Traffic: a realtime simulator of 3 robots at 20 Hz on a claimed
domain (the agent under test is robot 0 and publishes commands; the hosted agents are robots
0 and 1; the recorder records the 3 robots); the simulator under test publishes its own 3
robots. A node is signalled once it reports ready (heard every robot / running), after a
random 0-0.3 s; then, STARTUP_REPS times, during its start-up: at a random moment between the
installation of its own signal handlers and its median time to ready (importing torch, building
the node, loading the policy). Before its handlers exist (interpreter start-up and site,
0.1-0.3 s), SIGTERM kills silently and SIGINT raises KeyboardInterrupt: not measured here.

Prints, per node: clean exits (status 0), exits within 2 s, stops with leftovers, and the
stop time p50 / max, with the command line and the machine.
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from knode_swarm_ros.nodes.swarm import shm  # noqa: E402
from knode_swarm_ros.nodes.swarm.domains import claim_domain  # noqa: E402
from knode_swarm_ros.nodes.swarm.processes import catches_signal  # noqa: E402

ROBOTS = 3
READY = {
    'agent': 'heard all 3 robots: ready',
    'agents': 'heard all 3 robots: ready',
    'simulator': ': running',
    'recorder': 'heard all 3 robots: ready',
}


def _env(domain: int):
    env = dict(
        os.environ,
        ROS_DOMAIN_ID=str(domain),
        ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
        PYTHONUNBUFFERED='1',
        OMP_NUM_THREADS='1',
        PYTHONPATH=str(REPO),
    )
    return env


def _node(name, args, env, log):
    return subprocess.Popen(
        [sys.executable, '-m', f'knode_swarm_ros.nodes.{name}', '--ros-args', *args],
        env=env,
        stdout=log,
        stderr=subprocess.STDOUT,
        start_new_session=True,
    )


SIM_ARGS = [
    '-p',
    f'robots:={ROBOTS}',
    '-p',
    'mode:=realtime',
    '-p',
    'steps:=0',
    '-p',
    'wait_for_agents:=false',
    '-p',
    'publish_rate:=20.0',
]


def _held(proc) -> set:
    """The lock files ``proc`` holds, read a few times (a port may open late)."""
    held = set()
    for _ in range(3):
        held |= shm.shm_held_by(proc.pid)
        time.sleep(0.02)
    return held


def one_start_stop(name, args, env, sig, tmp: Path, delay: float):
    """Signal ``delay`` s after the process handles signals (importing, building the node, loading
    the policy)."""
    log_path = tmp / f'{name}_start.log'
    with open(log_path, 'wb') as log:
        proc = _node(name, args, env, log)
    while proc.poll() is None and not catches_signal(proc.pid):
        time.sleep(0.001)
    time.sleep(delay)
    held = shm.shm_held_by(proc.pid)
    rc, stop_s, text, note = _signal_and_wait(proc, sig, log_path)
    return {
        'rc': rc,
        'stop_s': stop_s,
        'left': shm.shm_left_by({n for n in held if 'port' not in n}),
        'held': held,
        'note': note,
        'traceback': 'Traceback' in text,
    }


def _signal_and_wait(proc, sig, log_path: Path):
    """Send ``sig``, wait for the exit (kill after 30 s): ``(rc, stop seconds, log text, note)``;
    the note is the log's tail when the stop was not clean."""
    t0 = time.monotonic()
    proc.send_signal(sig)
    try:
        rc = proc.wait(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        rc = proc.wait()
    stop_s = time.monotonic() - t0
    text = log_path.read_text(errors='replace')
    return rc, stop_s, text, text[-1500:] if rc != 0 or 'Traceback' in text or 'Aborted' in text else ''


def one_stop(name, args, env, domain, sig, tmp: Path, rng):
    log_path = tmp / f'{name}.log'
    t_start = time.monotonic()
    with open(log_path, 'wb') as log:
        proc = _node(name, args, env, log)
    deadline = time.monotonic() + 180
    while (
        time.monotonic() < deadline
        and proc.poll() is None
        and READY[name] not in log_path.read_text(errors='replace')
    ):
        time.sleep(0.02)
    if proc.poll() is not None:
        return {
            'rc': proc.returncode,
            'stop_s': None,
            'left': [],
            'note': 'exited before ready:\n' + log_path.read_text(errors='replace')[-2000:],
        }
    ready_s = time.monotonic() - t_start
    held = _held(proc)
    time.sleep(rng.uniform(0.0, 0.3))
    rc, stop_s, _, note = _signal_and_wait(proc, sig, log_path)
    segment = {n for n in held if 'port' not in n}
    return {
        'rc': rc,
        'stop_s': stop_s,
        'left': shm.shm_left_by(segment, domain),
        'held': held,
        'note': note,
        'ready_s': ready_s,
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--reps', type=int, default=50)
    ap.add_argument('--nodes', default='agent,agents,simulator,recorder')
    ap.add_argument('--startup-reps', type=int, default=None, help='stops during start-up (default: --reps)')
    ap.add_argument('--seed', type=int, default=0)
    a = ap.parse_args(argv)
    a.startup_reps = a.reps if a.startup_reps is None else a.startup_reps
    rng = random.Random(a.seed)
    claim = claim_domain(range(30, 102))
    domain = claim.domain_id
    env = _env(domain)
    tmp = Path(tempfile.mkdtemp(prefix='bench_shutdown_'))
    import torch

    from knode_swarm_ros.core import DEFAULTS, KNODEPolicy, PolicyConfig, export_policy

    torch.manual_seed(0)
    policy = KNODEPolicy(PolicyConfig('flock2d', **DEFAULTS['flock2d']))
    policy_path = tmp / 'flock2d.pt'
    export_policy(policy, policy_path, policy.metadata())
    print(
        f'# bench_shutdown {datetime.date.today()} on {platform.machine()} ({os.cpu_count()} cores, '
        f'load {os.getloadavg()[0]:.1f}), ROS_DOMAIN_ID {domain}; command: '
        f'{" ".join([sys.executable] + sys.argv)}',
        flush=True,
    )
    results = {}
    for name in a.nodes.split(','):
        traffic = None
        if name != 'simulator':
            traffic = _node('simulator', SIM_ARGS, env, open(tmp / 'traffic.log', 'wb'))
        args = {
            'agent': [
                '-p',
                'id:=0',
                '-p',
                f'robots:={ROBOTS}',
                '-p',
                f'policy:={policy_path}',
                '-p',
                'use_sim_time:=true',
            ],
            'agents': [
                '-p',
                'ids:=[0,1]',
                '-p',
                f'robots:={ROBOTS}',
                '-p',
                f'policy:={policy_path}',
                '-p',
                'use_sim_time:=true',
            ],
            'simulator': SIM_ARGS,
            'recorder': [
                '-p',
                f'robots:={ROBOTS}',
                '-p',
                f'output:={tmp / "rec.npz"}',
                '-p',
                'use_sim_time:=true',
            ],
        }[name]
        rows, starts = [], []
        series_before = frozenset(shm.shm_snapshot())  # ports that killed processes left earlier
        try:
            for i in range(a.reps):
                sig = signal.SIGINT if i % 2 == 0 else signal.SIGTERM
                row = one_stop(name, args, env, domain, sig, tmp, rng)
                rows.append(row)
                if row['note'] or row['left']:
                    print(
                        f'  {name} #{i} {sig.name}: rc {row["rc"]}, left {row["left"]}\n{row["note"]}',
                        flush=True,
                    )
            readies = sorted(r['ready_s'] for r in rows if r.get('ready_s'))
            for i in range(
                a.startup_reps if readies else 0
            ):  # uniform over the start-up: 0 .. median time to ready
                sig = signal.SIGINT if i % 2 == 0 else signal.SIGTERM
                row = one_start_stop(name, args, env, sig, tmp, rng.uniform(0.0, readies[len(readies) // 2]))
                starts.append(row)
                if row['note'] or row['left']:
                    print(
                        f'  {name} start #{i} {sig.name}: rc {row["rc"]}, left {row["left"]}\n{row["note"]}',
                        flush=True,
                    )
        finally:
            if traffic is not None:
                traffic.send_signal(signal.SIGINT)
                traffic.wait(timeout=30)
        series_left = shm.shm_left_by(
            set().union(*(r.get('held', set()) for r in rows)), domain, series_before
        )
        times = sorted(r['stop_s'] for r in rows if r['stop_s'] is not None)
        results[name] = rows
        clean = sum(r['rc'] == 0 for r in rows)
        fast = sum(r['rc'] == 0 and r['stop_s'] is not None and r['stop_s'] <= 2.0 for r in rows)
        left = sum(bool(r['left']) for r in rows)
        p50 = times[len(times) // 2] if times else float('nan')
        print(
            f'{name:9s}: exit 0 {clean}/{len(rows)}, exit 0 within 2 s {fast}/{len(rows)}, '
            f'stops leaving shm segments {left}/{len(rows)}, shm files left after the series '
            f'{len(series_left)} (of the files it held: {sum(len(r.get("held", ())) for r in rows)} locks in all), '
            f'stop time p50 {p50:.3f} s, max {max(times) if times else float("nan"):.3f} s'
            + (f' (left: {series_left[:6]})' if series_left else ''),
            flush=True,
        )
        if starts:
            times = sorted(r['stop_s'] for r in starts)
            print(
                f'{"":9s}  signalled during start-up ({len(starts)}, 0 .. {readies[len(readies) // 2]:.1f} s after '
                f"it handles signals): exit 0 {sum(r['rc'] == 0 for r in starts)}, ended by SIGTERM's default "
                f'action before any handler {sum(r["rc"] == -signal.SIGTERM for r in starts)}, other '
                f'{sum(r["rc"] not in (0, -signal.SIGTERM) for r in starts)}, tracebacks '
                f'{sum(r["traceback"] for r in starts)}, within 2 s {sum(r["stop_s"] <= 2.0 for r in starts)}, '
                f'leaving shm segments {sum(bool(r["left"]) for r in starts)}, stop time p50 '
                f'{times[len(times) // 2]:.3f} s, max {times[-1]:.3f} s',
                flush=True,
            )
    claim.release()
    return 0


if __name__ == '__main__':
    sys.exit(main())
