"""Benchmark of the ROS 2 deployment: agent logic, lockstep and realtime swarms.

    python bench/bench_ros.py                 # everything (about 5 to 10 minutes on 2 cores)
    python bench/bench_ros.py --only tick     # the agent's per-tick cost only (seconds)
    python bench/bench_ros.py --quick         # shorter runs

Figures:

* agent tick: the cost of one lockstep step of :class:`AgentLogic` for robot 3 of 10 (file 10
  states, build Y_i, evaluate the policy, clip), p50/p99 in microseconds, against the raw
  policy call (a batch of 1 and the rollout-shaped batch of 10) as baselines;
* lockstep: steps per second of the real processes (``swarm --mode lockstep``) for 5, 10
  and 20 robots, and the wall time of a 2000-step 10-robot episode, startup included;
* realtime at 20 Hz for 10 and 20 robots: CPU of all processes while running (in cores),
  odometry and command loss, state-to-command latency p50/p99 (wall time from the simulator
  publishing a state to receiving the first command stamped with it).

Goals (this 2-core machine): 10 robots realtime at 20 Hz with no loss and p99
latency under 20 ms; a 2000-step 10-robot lockstep episode under 60 s; 20 robots realtime at
20 Hz with under 1 % loss. Uses the shipped flock2d policy.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import shlex
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def machine() -> str:
    model = ''
    try:
        for line in open('/proc/cpuinfo'):
            if line.startswith('model name'):
                model = line.split(':', 1)[1].strip()
                break
    except OSError:
        pass
    load = open('/proc/loadavg').read().split()[:3] if os.path.exists('/proc/loadavg') else ['?'] * 3
    return (
        f'{platform.node()}: {os.cpu_count()} cores ({model}), Python {platform.python_version()}, '
        f'load average before the run {" ".join(load)}'
    )


# --- agent tick ------------------------------------------------------------------------------
def bench_tick(policy_path: str, repeats: int) -> dict:
    import torch

    torch.set_num_threads(1)
    from knode_swarm_ros.core import load_policy
    from knode_swarm_ros.logic.agent.agent_logic import AgentConfig, AgentLogic
    from knode_swarm_ros.logic.simulator.swarm_sim import initial_state

    policy = load_policy(policy_path)
    n = 10
    z0, swarm = initial_state(policy.scenario, n, seed=0)
    frames = [z0] + [swarm.step()[0] for _ in range(repeats)]
    out = {}
    for parity in (True, False):
        logic = AgentLogic(AgentConfig(3, list(range(n)), 'lockstep', parity_batch=parity), policy)
        times = []
        for s, frame in enumerate(frames):
            ns = int(round(s * policy.dt * 1e9))
            t = time.perf_counter()
            for r in range(n):
                logic.receive(r, ns, frame[r])
                logic.lockstep_poll(0.0)
            times.append(time.perf_counter() - t)
        times = np.array(times[10:]) * 1e6
        out['agent_step_parity' if parity else 'agent_step_batch1'] = (
            np.percentile(times, 50),
            np.percentile(times, 99),
        )
    Y = np.zeros((1, policy.k, 4 if policy.scenario == 'flock2d' else 6))
    Y[0, 1:, 0] = np.arange(1, policy.k)
    mask = np.ones((1, policy.k), dtype=bool)
    for B, key in ((1, 'policy_batch1'), (n, 'policy_batch10')):
        Yb, mb = np.repeat(Y, B, 0), np.repeat(mask, B, 0)
        times = []
        for _ in range(len(frames)):
            t = time.perf_counter()
            policy(Yb, mb)
            times.append(time.perf_counter() - t)
        times = np.array(times[10:]) * 1e6
        out[key] = (np.percentile(times, 50), np.percentile(times, 99))
    return out


# --- swarm runs ------------------------------------------------------------------------------
def _cpu_seconds(pid: int) -> float:
    try:
        fields = open(f'/proc/{pid}/stat').read().rsplit(')', 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')
    except (OSError, IndexError, ValueError):
        return float('nan')


def run_swarm(args: list, log_dir: Path, timeout: float = 900.0) -> dict:
    """Run the launcher; sample every process's CPU when the simulator starts and finishes."""
    cmd = [
        sys.executable,
        '-m',
        'knode_swarm_ros.nodes.swarm',
        '--log-dir',
        str(log_dir),
        '--no-figure',
        '--quiet',
        *map(str, args),
    ]
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONUNBUFFERED='1')
    t0 = time.monotonic()
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    samples = {}

    def sample(tag):
        pids = json.loads((log_dir / 'pids.json').read_text())
        samples[tag] = (time.monotonic(), {name: _cpu_seconds(pid) for name, pid in pids.items()})

    watcher = {'lines': []}

    def read():
        for line in proc.stdout:
            watcher['lines'].append(line.rstrip())

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    log = log_dir / 'simulator.log'
    phase = 'start'
    while proc.poll() is None and time.monotonic() - t0 < timeout:
        text = log.read_text(errors='replace') if log.exists() else ''
        if phase == 'start' and 'running' in text:
            sample('running')
            phase = 'running'
        elif phase == 'running' and 'done:' in text:
            sample('done')
            phase = 'done'
        time.sleep(0.02)
    if proc.poll() is None:
        proc.kill()
    proc.wait()
    reader.join(timeout=5)
    wall = time.monotonic() - t0
    report = json.loads((log_dir / 'simulator.json').read_text())
    agents = [json.loads(p.read_text()) for p in sorted(log_dir.glob('agent_*.json'))]
    out = {
        'rc': proc.returncode,
        'wall_s': wall,
        'report': report,
        'agents': agents,
        'output': '\n'.join(watcher['lines'][-30:]),
    }
    if 'running' in samples and 'done' in samples:
        (t1, c1), (t2, c2) = samples['running'], samples['done']
        used = {k: c2[k] - c1[k] for k in c1 if k in c2 and np.isfinite(c2[k] - c1[k])}  # ended: left out
        out['cpu_cores'] = sum(used.values()) / max(t2 - t1, 1e-9)
        out['cpu_agents_cores'] = sum(v for k, v in used.items() if k.startswith('agent_')) / max(
            t2 - t1, 1e-9
        )
    return out


def losses(result: dict) -> dict:
    """Odometry and command loss over the run (unique states and commands)."""
    rep, agents = result['report'], result['agents']
    n = rep['robots']
    published_steps = rep['frames_published'] + 1  # + the initial state
    odom_expected = published_steps * n * len(agents)
    odom_got = sum(a['counters']['accepted'] for a in agents)
    cmd_sent = sum(
        a['counters']['commands'] + a['counters']['stop_commands'] + a['counters']['resent'] for a in agents
    )
    c = rep['counters']
    cmd_got = c['accepted'] + c['stale'] + c['future'] + c['rejoined']
    return {
        'odom_loss': 1 - odom_got / odom_expected if odom_expected else float('nan'),
        'odom_got': odom_got,
        'odom_expected': odom_expected,
        'cmd_loss': 1 - cmd_got / cmd_sent if cmd_sent else float('nan'),
        'cmd_got': cmd_got,
        'cmd_sent': cmd_sent,
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--only', choices=('tick', 'lockstep', 'realtime'), action='append')
    p.add_argument('--quick', action='store_true', help='shorter runs')
    p.add_argument('--policy', help='policy file (default: the shipped flock2d policy)')
    a = p.parse_args(argv)
    only = set(a.only or ('tick', 'lockstep', 'realtime'))
    from knode_swarm_ros.core.policy_io import shipped_policy_path

    policy = a.policy or str(shipped_policy_path('flock2d'))
    print(f'# bench_ros, {datetime.datetime.now().isoformat(timespec="seconds")}')
    print(f'# command: {shlex.join([sys.executable, *sys.argv])}')
    print(f'# machine: {machine()}')
    print(f'# policy: {policy}')
    results = {}
    goals = []
    if 'tick' in only:
        t = bench_tick(policy, 300 if a.quick else 2000)
        results['tick'] = t
        print(
            '\n## agent logic, one lockstep step of robot 3 of 10 (10 states filed, Y_i, policy, clip), microseconds'
        )
        for key, label in (
            ('agent_step_parity', 'agent step, parity batch (default)'),
            ('agent_step_batch1', 'agent step, batch of 1'),
            ('policy_batch1', 'raw policy call, batch 1 (baseline)'),
            ('policy_batch10', 'raw policy call, batch 10 (baseline)'),
        ):
            print(f'{label:42s} p50 {t[key][0]:8.1f}   p99 {t[key][1]:8.1f}')
        print(
            f'ratio agent step (parity) / raw policy call (batch 1): p50 '
            f'{t["agent_step_parity"][0] / t["policy_batch1"][0]:.2f}x'
        )
    tmp = Path(tempfile.mkdtemp(prefix='bench_ros_'))
    if 'lockstep' in only:
        print('\n## lockstep (real processes; steps/s while running; wall includes startup and shutdown)')
        print(
            f'{"robots":>6} {"steps":>6} {"steps/s":>8} {"run s":>7} {"wall s":>7} {"startup s":>9} '
            f'{"CPU cores":>9} {"lat p50 ms":>10} {"lat p99 ms":>10} rc'
        )
        for n in (5, 10, 20):
            steps = 2000 if n == 10 else (300 if a.quick else 1000)
            if a.quick and n == 10:
                steps = 500
            r = run_swarm(
                [
                    '--policy',
                    policy,
                    '--robots',
                    n,
                    '--steps',
                    steps,
                    '--mode',
                    'lockstep',
                    '--record',
                    tmp / f'lockstep_{n}.npz',
                ],
                tmp / f'lockstep_{n}',
            )
            rep = r['report']
            lat = rep.get('latency_ms') or {}
            results[f'lockstep_{n}'] = r
            nan = float('nan')
            print(
                f'{n:6d} {steps:6d} {rep.get("steps_per_s", nan):8.1f} {rep.get("run_s", nan):7.1f} '
                f'{r["wall_s"]:7.1f} {rep.get("startup_s", nan):9.1f} {r.get("cpu_cores", nan):9.2f} '
                f'{lat.get("p50") or nan:10.2f} {lat.get("p99") or nan:10.2f} {r["rc"]}'
            )
            if r['rc'] != 0:
                print(r['output'])
            if n == 10 and steps == 2000:
                goals.append(
                    (
                        '2000-step 10-robot lockstep episode < 60 s (stepping)',
                        rep.get('run_s', 1e9) < 60,
                        f'{rep.get("run_s", nan):.1f} s stepping, {r["wall_s"]:.1f} s wall with startup',
                    )
                )
    if 'realtime' in only:
        print('\n## realtime at 20 Hz (control and odometry), real-time factor 1')
        print(
            f'{"robots":>6} {"sim s":>6} {"CPU cores":>9} {"agents":>7} {"odom loss":>10} {"cmd loss":>9} '
            f'{"lat p50 ms":>10} {"lat p99 ms":>10} {"lat max":>8} {"zeroed":>7} rc'
        )
        for n in (10, 20):
            steps = 1000 if a.quick else 3000
            r = run_swarm(
                [
                    '--policy',
                    policy,
                    '--robots',
                    n,
                    '--steps',
                    steps,
                    '--mode',
                    'realtime',
                    '--rate',
                    20,
                    '--record',
                    tmp / f'realtime_{n}.npz',
                ],
                tmp / f'realtime_{n}',
            )
            rep = r['report']
            lat = rep.get('latency_ms') or {}
            loss = losses(r)
            results[f'realtime_{n}'] = dict(r, loss=loss)
            print(
                f'{n:6d} {steps * rep["dt"]:6.0f} {r.get("cpu_cores", float("nan")):9.2f} '
                f'{r.get("cpu_agents_cores", float("nan")):7.2f} {loss["odom_loss"]:10.2%} {loss["cmd_loss"]:9.2%} '
                f'{lat.get("p50") or float("nan"):10.2f} {lat.get("p99") or float("nan"):10.2f} '
                f'{lat.get("max") or float("nan"):8.1f} {rep["counters"]["zeroed"]:7d} {r["rc"]}'
            )
            if r['rc'] != 0:
                print(r['output'])
            worst = max(loss['odom_loss'], loss['cmd_loss'])
            if n == 10:
                goals.append(
                    (
                        '10 robots realtime 20 Hz: no loss, p99 latency < 20 ms',
                        worst == 0 and (lat.get('p99') or 1e9) < 20,
                        f'loss {worst:.2%}, p99 {lat.get("p99") or float("nan"):.2f} ms',
                    )
                )
            else:
                goals.append(('20 robots realtime 20 Hz: < 1 % loss', worst < 0.01, f'loss {worst:.2%}'))
    if goals:
        print('\n## goals')
        for name, ok, detail in goals:
            print(f'{"MET " if ok else "MISS"}  {name}: {detail}')
    print(f'\n# logs and recordings: {tmp}')
    (tmp / 'results.json').write_text(json.dumps(results, indent=1, default=str))
    return 0


if __name__ == '__main__':
    sys.exit(main())
