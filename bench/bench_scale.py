"""Benchmark of swarms of 10 to 200 robots: one agent process per robot vs hosted agents.

    python bench/bench_scale.py                          # everything below (long)
    python bench/bench_scale.py --only tick              # per-robot tick cost in a hosting process (seconds)
    python bench/bench_scale.py --only lockstep --robots 10,20,50,100 --steps 300
    python bench/bench_scale.py --only realtime --robots 100 --seconds 60
    python bench/bench_scale.py --only quality --robots 100 --steps 2000

Figures, each against a baseline of the same run:

* tick (CPU time of the thread, so that other jobs' load does not count): inside a hosting
  process at N robots (all hosted), the cost per robot and step of building Y_i plus its share of
  the one batched policy call (``HostedAgents.lockstep_poll`` after every state, as the node
  polls), and of filing the step's N states once for the process; baselines: a lone agent's
  polls at the same N (parity batch of N) and in a swarm of 10, and the bare policy forward of a
  batch of N per robot; objects built before the loop are frozen out of the garbage collector's
  sight, as the nodes do;
* lockstep: per robot count and layout (``lone``: ``--agents-per-process 1``; ``hosted``: the
  launcher's default split), steps/s after startup, startup seconds, state-to-command latency
  p50/p99 and the PSS of all processes while running, hosted / lone as ratios; the lone layout
  runs only up to ``--lone-max`` robots (an agent process holds about 330 MB);
* realtime: hosted at 20 Hz: missed commands (1 - distinct (robot, step) commands the simulator
  received / robots x state publications), p50/p99 latency, PSS;
* multihost (root): three network namespaces on a bridge (:mod:`knode_swarm_ros.nodes.swarm.netns`),
  simulator and recorder in the first, hosting agent processes spread over the three, subnet
  discovery over UDP: lockstep steps/s and parity with core.rollout, realtime misses and latency,
  against the same runs on one host with localhost discovery;
* quality: the learnt flock2d policy through ROS (hosted, lockstep) vs the offline
  :func:`core.rollout` from the recorded initial state (max difference; 0 = bit for bit) and vs
  the ground truth (Tanner) from the same state: avd/amd at the end and over the last 10 %.

Uses the shipped flock2d policy (realtime: the one for 20 Hz, as ``swarm`` deploys) unless
``--policy``, on TorchScript unless ``--policy-runtime``
(the offline rollout is torch: only TorchScript agents reproduce it bit for bit). PSS is read
from /proc/<pid>/smaps_rollup. The full measurement (about 60 to 90 minutes on a quiet 2-core
machine): ``python bench/bench_scale.py --robots 10,20,50,100,200 --steps 2000 --seconds 60
--lone-max 50``.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / 'bench'))

from bench_ros import machine  # noqa: E402


# --- tick ------------------------------------------------------------------------------------
def bench_tick(policy_path: str, n: int, steps: int) -> dict:
    """Per robot and step, as the nodes call the logic: after every state a poll."""
    import gc

    import torch

    torch.set_num_threads(1)
    from knode_swarm_ros.core import load_policy
    from knode_swarm_ros.logic.agent.agent_logic import AgentConfig, AgentLogic
    from knode_swarm_ros.logic.agent.hosted import HostedAgents
    from knode_swarm_ros.logic.common import stamp_ns
    from knode_swarm_ros.logic.simulator.swarm_sim import initial_state

    policy = load_policy(policy_path)
    z0, swarm = initial_state(policy.scenario, n, seed=0)
    frames = [z0] + [swarm.step()[0] for _ in range(steps)]
    ids = list(range(n))
    host = HostedAgents(ids, AgentConfig(0, ids, 'lockstep'), policy)
    lone = AgentLogic(AgentConfig(n // 2, ids, 'lockstep'), policy)
    small = min(n, 10)  # a lone agent in a swarm of 10 (the issue's reference tick)
    lone10 = AgentLogic(AgentConfig(small // 2, list(range(small)), 'lockstep'), policy)
    gc.freeze()  # as the nodes do once built (nodes/common/executor.py)
    filing, poll, lone_poll, lone_filing, lone10_poll = [], [], [], [], []
    clock = time.thread_time  # CPU time of this thread: on a loaded machine wall time counts others' slices
    for s, frame in enumerate(frames):
        ns = stamp_ns(s, policy.dt)
        got = 0
        for logic, file_acc, poll_acc, robots in (
            (host, filing, poll, n),
            (lone, lone_filing, lone_poll, n),
            (lone10, None, lone10_poll, small),
        ):
            t_file = t_poll = 0.0
            for r in range(robots):
                t0 = clock()
                logic.receive(r, ns, frame[r])
                t1 = clock()
                out = logic.lockstep_poll(0.0)
                t_poll += clock() - t1
                t_file += t1 - t0
                if logic is host:
                    got += len(out)
            if file_acc is not None:
                file_acc.append(t_file / robots if logic is host else t_file)
            poll_acc.append(t_poll / robots if logic is host else t_poll)
        assert got == n
    Y = np.zeros((n, policy.k, frames[0].shape[1]))
    Y[:, 1:, 0] = np.arange(1, policy.k)
    mask = np.ones((n, policy.k), dtype=bool)
    bare = []
    for _ in range(len(frames)):
        t = clock()
        policy(Y, mask)
        bare.append((clock() - t) / n)
    skip = min(5, len(frames) // 4)

    def q(xs):
        return (
            float(np.percentile(np.array(xs[skip:]) * 1e6, 50)),
            float(np.percentile(np.array(xs[skip:]) * 1e6, 99)),
        )

    return {
        'robots': n,
        'steps': len(frames),
        'hosted_y_and_policy_share_us': q(poll),
        'hosted_filing_per_robot_us': q(filing),
        'lone_poll_us': q(lone_poll),
        'lone_filing_us': q(lone_filing),
        'lone10_poll_us': q(lone10_poll),
        'bare_policy_share_us': q(bare),
        'policy_calls': host.calls,
    }


# --- runs ------------------------------------------------------------------------------------
def pss_kb(pid: int) -> int:
    try:
        for line in open(f'/proc/{pid}/smaps_rollup'):
            if line.startswith('Pss:'):
                return int(line.split()[1])
    except OSError:
        pass
    return 0


DOMAIN_ID = None
RUNTIME = 'torchscript'


def run_swarm(args: list, log_dir: Path, timeout: float) -> dict:
    """The launcher with ``args``; PSS of all its processes sampled twice while running."""
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
    if DOMAIN_ID is not None:  # concurrent benchmarks on one machine must not share a domain
        cmd += ['--domain-id', str(DOMAIN_ID)]
    cmd += ['--policy-runtime', RUNTIME]
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONUNBUFFERED='1')
    t0 = time.monotonic()
    out_path = log_dir.with_suffix('.out')
    log_dir.mkdir(parents=True, exist_ok=True)
    with open(out_path, 'w') as out:
        proc = subprocess.Popen(cmd, env=env, stdout=out, stderr=subprocess.STDOUT)
        pss, sampled = [], 0
        sim_log = log_dir / 'simulator.log'
        while proc.poll() is None and time.monotonic() - t0 < timeout:
            text = sim_log.read_text(errors='replace') if sim_log.exists() else ''
            if 'running' in text and 'done:' not in text and sampled < 2 and (log_dir / 'pids.json').exists():
                pids = json.loads((log_dir / 'pids.json').read_text())
                pss.append(sum(pss_kb(pid) for pid in pids.values()) / 1024)
                sampled += 1
                time.sleep(1.0)
            time.sleep(0.1)
        if proc.poll() is None:
            proc.kill()
        proc.wait()
    result = {
        'rc': proc.returncode,
        'wall_s': time.monotonic() - t0,
        'pss_mb': max(pss) if pss else None,
        'command': shlex.join(cmd),
    }
    try:
        result['report'] = json.loads((log_dir / 'simulator.json').read_text())
    except (OSError, ValueError):
        result['report'] = {}
        result['output'] = out_path.read_text(errors='replace')[-3000:]
    return result


def _lockstep_wait(a) -> list:
    """The agents' ``--state-timeout`` for lockstep runs: an agent gives up on a peer whose state
    is not filed within it (wall seconds), and a hosting process that a loaded machine slows down
    still has that state in its own queue; realtime runs keep the launcher's default."""
    return ['--state-timeout', a.state_timeout]


def _row(r: dict) -> dict:
    rep = r['report']
    lat = rep.get('latency_ms') or {}
    return {
        'steps_per_s': rep.get('steps_per_s'),
        'startup_s': rep.get('startup_s'),
        'p50': lat.get('p50'),
        'p99': lat.get('p99'),
        'pss_mb': r['pss_mb'],
        'rc': r['rc'],
        'wall_s': r['wall_s'],
        'lost': rep.get('lost'),
    }


def _fmt(x, spec='8.1f'):
    if isinstance(x, (int, float)) and not isinstance(x, bool):
        return format(x, spec)
    return format('-', '>' + spec.split('.')[0])


def _commanded(counters: dict) -> int:
    """Distinct (robot, step) commands the simulator received (a re-send of a step once); from a
    simulator without that counter, every command received."""
    if 'commanded' in counters:
        return counters['commanded']
    return sum(counters.get(key, 0) for key in ('accepted', 'stale', 'future', 'rejoined'))


def _ratio(a, b):
    return a / b if isinstance(a, (int, float)) and isinstance(b, (int, float)) and b else None


# --- quality ---------------------------------------------------------------------------------
def quality(record: Path, policy_path: str) -> dict:
    import torch

    torch.set_num_threads(1)
    from knode_swarm_ros.core import load_policy, load_trajectories, rollout
    from knode_swarm_ros.logic.recorder import swarm_metrics
    from knode_swarm_ros.logic.simulator.swarm_sim import make_ground_truth

    data = load_trajectories(record)
    states = data.states[0]
    steps = states.shape[0] - 1
    policy = load_policy(policy_path)
    ref = rollout(policy, states[0], steps, data.scenario, policy.d_cr, policy.k, policy.tau, policy.dt)
    gt_sim = make_ground_truth(data.scenario, states[0].copy())
    gt = np.stack([states[0]] + [np.array(gt_sim.step()[0]) for _ in range(steps)])

    def metrics(traj):
        m = np.array([swarm_metrics(f, data.scenario) for f in traj])
        tail = max(1, len(m) // 10)
        return {
            'avd_end': float(m[-1, 0]),
            'amd_end': float(m[-1, 1]),
            'avd_last10': float(m[-tail:, 0].mean()),
            'amd_last10': float(m[-tail:, 1].mean()),
        }

    return {
        'robots': int(states.shape[1]),
        'steps': steps,
        'max_diff_vs_rollout': float(np.abs(ref - states).max()),
        'bit_for_bit': bool(np.array_equal(ref, states)),
        'ros': metrics(states),
        'rollout': metrics(ref),
        'ground_truth': metrics(gt),
    }


# --- multihost --------------------------------------------------------------------------------
def bench_multihost(policy: str, counts, a, tmp: Path) -> dict:
    from knode_swarm_ros.nodes.swarm import netns

    out = {}
    print('\n## three hosts (network namespaces on a bridge, subnet discovery, UDP) vs one host (localhost)')
    print(
        f'{"robots":>6} {"where":>6} {"mode":>9} {"steps/s":>8} {"missed %":>9} {"p50 ms":>8} {"p99 ms":>8} '
        f'{"parity":>7} rc',
        flush=True,
    )
    try:
        with netns.virtual_hosts(3) as hosts:
            spaces = ','.join(h.name for h in hosts)
            for n in counts:
                k = max(1, -(-n // 3))  # three agent processes, one per host
                for where in ('1 host', '3 hosts'):
                    for mode, steps in (('lockstep', a.steps), ('realtime', int(round(a.seconds / 0.01)))):
                        tag = f'multihost_{n}_{where[0]}_{mode}'
                        args = [
                            '--policy',
                            policy,
                            '--robots',
                            n,
                            '--steps',
                            steps,
                            '--mode',
                            mode,
                            '--rate',
                            20,
                            '--agents-per-process',
                            k,
                            '--startup-timeout',
                            900,
                            '--lockstep-timeout',
                            a.lockstep_timeout,
                            *(_lockstep_wait(a) if mode == 'lockstep' else []),
                            '--record',
                            tmp / f'{tag}.npz',
                        ]
                        if where == '3 hosts':
                            args += ['--netns', spaces]
                        r = run_swarm(args, tmp / tag, a.timeout)
                        rep = r['report']
                        lat = rep.get('latency_ms') or {}
                        parity = missed = None
                        if mode == 'lockstep' and r['rc'] == 0:
                            parity = quality(tmp / f'{tag}.npz', policy)['bit_for_bit']
                        if mode == 'realtime':
                            c = rep.get('counters', {})
                            expected = rep.get('frames_published', 0) * n
                            got = _commanded(c)
                            missed = 100.0 * max(0, expected - got) / expected if expected else None
                        out[tag] = {'report': rep, 'parity': parity, 'missed_pct': missed, 'rc': r['rc']}
                        print(
                            f'{n:6d} {where:>6} {mode:>9} {_fmt(rep.get("steps_per_s"))} {_fmt(missed, "9.2f")} '
                            f'{_fmt(lat.get("p50"), "8.2f")} {_fmt(lat.get("p99"), "8.2f")} {str(parity):>7} {r["rc"]}',
                            flush=True,
                        )
                        if r['rc'] != 0:
                            print(r.get('output', ''))
    except netns.NetnsUnavailable as exc:
        print(f'not run: this machine refuses to create network namespaces: {exc}')
    return out


# --- main ------------------------------------------------------------------------------------
def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument(
        '--only', choices=('tick', 'lockstep', 'realtime', 'quality', 'multihost'), action='append'
    )
    p.add_argument('--robots', default='10,20,50,100,200', help='robot counts, comma-separated')
    p.add_argument('--steps', type=int, default=2000, help='lockstep / quality steps (default 2000)')
    p.add_argument('--seconds', type=float, default=60.0, help='realtime: simulated seconds (default 60)')
    p.add_argument('--tick-robots', type=int, default=100)
    p.add_argument('--lone-max', type=int, default=20, help='largest swarm run with one process per robot')
    p.add_argument(
        '--agents-per-process', type=int, default=0, help='hosted layout: K (0: the default split)'
    )
    p.add_argument('--timeout', type=float, default=1800.0, help='wall seconds per run')
    p.add_argument(
        '--lockstep-timeout',
        type=float,
        default=600.0,
        help="the simulator's wait for a late agent before holding its robot (the launcher's default, 5 s, "
        'drops agents that a loaded machine delays; a run with held robots is not a valid figure)',
    )
    p.add_argument(
        '--state-timeout',
        type=float,
        default=60.0,
        help="agents' state_timeout in lockstep runs (default 60 s: see _lockstep_wait)",
    )
    p.add_argument(
        '--domain-id', type=int, help='ROS_DOMAIN_ID of every run (default: the launcher draws one)'
    )
    p.add_argument(
        '--policy-runtime',
        choices=('auto', 'torchscript', 'onnxruntime'),
        default='torchscript',
        help="the agents' runtime (default torchscript: core.rollout runs torch, so a lockstep recording "
        'equals it bit for bit only on TorchScript; the ONNX twin agrees to about 1e-6)',
    )
    p.add_argument('--policy')
    p.add_argument('--out', help='results JSON (default: in the temporary folder)')
    a = p.parse_args(argv)
    global DOMAIN_ID, RUNTIME
    DOMAIN_ID, RUNTIME = a.domain_id, a.policy_runtime
    only = set(a.only or ('tick', 'lockstep', 'realtime', 'quality'))
    counts = [int(x) for x in a.robots.split(',') if x]
    from knode_swarm_ros.core.policy_io import shipped_policy_path

    policy = a.policy or str(shipped_policy_path('flock2d'))
    print(f'# bench_scale, {datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")}')
    print(f'# command: {shlex.join([sys.executable, *sys.argv])}')
    print(f'# machine: {machine()}')
    print(f'# policy: {policy}', flush=True)
    tmp = Path(tempfile.mkdtemp(prefix='bench_scale_'))
    results = {}
    if 'tick' in only:
        t = bench_tick(policy, a.tick_robots, 60)
        results['tick'] = t
        print(
            f'\n## per robot and step inside a hosting process of {t["robots"]} robots (CPU us of the thread, p50 / p99; '
            f'{t["policy_calls"]} policy calls for {t["steps"]} steps)'
        )
        for key, label in (
            ('hosted_y_and_policy_share_us', 'hosted: Y_i + share of the batched call'),
            ('hosted_filing_per_robot_us', "hosted: filing the step's states, per robot"),
            ('lone_poll_us', f'lone agent: Y_i + its own call (batch {t["robots"]})'),
            ('lone_filing_us', f"lone agent: filing the step's {t['robots']} states"),
            ('lone10_poll_us', 'lone agent of 10 robots: Y_i + its own call'),
            ('bare_policy_share_us', 'bare policy forward, share of a batch'),
        ):
            print(f'{label:48s} {t[key][0]:9.1f} {t[key][1]:9.1f}')
        h = t['hosted_y_and_policy_share_us'][0]
        print(
            f'ratio hosted / lone at {t["robots"]} robots (p50): {h / t["lone_poll_us"][0]:.3f}; '
            f'hosted / lone at 10 robots: {h / t["lone10_poll_us"][0]:.3f}; '
            f'hosted per robot incl. filing: {h + t["hosted_filing_per_robot_us"][0]:.1f} us (goal <= 50 us for '
            'Y_i + share of the call)',
            flush=True,
        )
    if 'lockstep' in only:
        print(f'\n## lockstep, {a.steps} steps (steps/s after startup; PSS of all processes while running)')
        print(
            f'{"robots":>6} {"layout":>7} {"procs":>5} {"steps/s":>8} {"startup s":>9} {"p50 ms":>8} {"p99 ms":>8} '
            f'{"PSS MB":>8} rc',
            flush=True,
        )
        from knode_swarm_ros.nodes.swarm.hosting import resolve_agents_per_process

        for n in counts:
            rows = {}
            for layout in ('lone', 'hosted'):
                k = 1 if layout == 'lone' else resolve_agents_per_process(a.agents_per_process, n)
                if layout == 'lone' and n > a.lone_max:
                    print(
                        f'{n:6d} {layout:>7} {n:5d}  not run (--lone-max {a.lone_max}: about {0.18 * n:.0f} GB)'
                    )  # 3.6 GB for 20
                    continue
                if layout == 'hosted' and k == 1:
                    k = max(2, -(-n // 2))  # the default is one process per robot here: host anyway
                r = run_swarm(
                    [
                        '--policy',
                        policy,
                        '--robots',
                        n,
                        '--steps',
                        a.steps,
                        '--mode',
                        'lockstep',
                        '--agents-per-process',
                        k,
                        '--startup-timeout',
                        900,
                        '--lockstep-timeout',
                        a.lockstep_timeout,
                        *_lockstep_wait(a),
                        '--record',
                        tmp / f'lockstep_{n}_{layout}.npz',
                    ],
                    tmp / f'lockstep_{n}_{layout}',
                    a.timeout,
                )
                rows[layout] = row = _row(r)
                procs = -(-n // k)
                print(
                    f'{n:6d} {layout:>7} {procs:5d} {_fmt(row["steps_per_s"])} {_fmt(row["startup_s"], "9.1f")} '
                    f'{_fmt(row["p50"], "8.2f")} {_fmt(row["p99"], "8.2f")} {_fmt(row["pss_mb"], "8.0f")} {row["rc"]}'
                    + (f'  INVALID: robots held {row["lost"]}' if row['lost'] else ''),
                    flush=True,
                )
                if r['rc'] != 0:
                    print(r.get('output', ''))
            if 'lone' in rows and 'hosted' in rows:
                lo, ho = rows['lone'], rows['hosted']
                print(
                    f'{n:6d}   ratio hosted/lone: steps/s {_fmt(_ratio(ho["steps_per_s"], lo["steps_per_s"]), "5.2f")}, '
                    f'p99 {_fmt(_ratio(ho["p99"], lo["p99"]), "5.2f")}, PSS {_fmt(_ratio(ho["pss_mb"], lo["pss_mb"]), "5.2f")}',
                    flush=True,
                )
            results[f'lockstep_{n}'] = rows
    if 'realtime' in only:
        # As `swarm --mode realtime` deploys: the policy trained for the control rate
        from knode_swarm_ros.core.policy_meta import read_pt_meta
        from knode_swarm_ros.logic.agent.control_period import shipped_policy_for_rate

        rt_policy = a.policy or str(shipped_policy_for_rate('flock2d', 20.0)[0])
        rt_dt = float(read_pt_meta(rt_policy)['dt'])
        print(
            f'\n## realtime at 20 Hz, {a.seconds:g} s simulated, hosted, policy {rt_policy} (dt {rt_dt:g} s)'
        )
        print(f'{"robots":>6} {"missed %":>9} {"p50 ms":>8} {"p99 ms":>8} {"PSS MB":>8} rc', flush=True)
        for n in counts:
            from knode_swarm_ros.nodes.swarm.hosting import resolve_agents_per_process as resolve

            k = resolve(a.agents_per_process, n)
            steps = int(round(a.seconds / rt_dt))
            r = run_swarm(
                [
                    '--policy',
                    rt_policy,
                    '--robots',
                    n,
                    '--steps',
                    steps,
                    '--mode',
                    'realtime',
                    '--rate',
                    20,
                    '--agents-per-process',
                    k,
                    '--startup-timeout',
                    900,
                    '--lockstep-timeout',
                    a.lockstep_timeout,
                    '--record',
                    tmp / f'realtime_{n}.npz',
                ],
                tmp / f'realtime_{n}',
                a.timeout,
            )
            rep = r['report']
            c = rep.get('counters', {})
            # one command per robot and control tick (20 Hz = every state publication) is expected
            expected = rep.get('frames_published', 0) * n
            got = _commanded(c)
            lat = rep.get('latency_ms') or {}
            missed = 100.0 * max(0, expected - got) / expected if expected else None
            results[f'realtime_{n}'] = {'report': rep, 'pss_mb': r['pss_mb'], 'missed_pct': missed}
            print(
                f'{n:6d} {_fmt(missed, "9.2f")} {_fmt(lat.get("p50"), "8.2f")} {_fmt(lat.get("p99"), "8.2f")} '
                f'{_fmt(r["pss_mb"], "8.0f")} {r["rc"]}  counters {json.dumps(c)}',
                flush=True,
            )
    if 'multihost' in only:
        results['multihost'] = bench_multihost(policy, counts, a, tmp)
    if 'quality' in only:
        for n in counts:
            record = tmp / f'lockstep_{n}_hosted.npz'
            if not record.exists():
                from knode_swarm_ros.nodes.swarm.hosting import resolve_agents_per_process as resolve

                r = run_swarm(
                    [
                        '--policy',
                        policy,
                        '--robots',
                        n,
                        '--steps',
                        a.steps,
                        '--mode',
                        'lockstep',
                        '--agents-per-process',
                        resolve(a.agents_per_process, n),
                        '--startup-timeout',
                        900,
                        '--lockstep-timeout',
                        a.lockstep_timeout,
                        *_lockstep_wait(a),
                        '--record',
                        record,
                    ],
                    tmp / f'quality_{n}',
                    a.timeout,
                )
                row = _row(r)
                results[f'quality_run_{n}'] = row
                print(
                    f'\n## lockstep run for the quality figures: {n} robots, {a.steps} steps, hosted: '
                    f'{_fmt(row["steps_per_s"], ".1f")} steps/s after {_fmt(row["startup_s"], ".1f")} s of startup, '
                    f'latency p50 {_fmt(row["p50"], ".2f")} / p99 {_fmt(row["p99"], ".2f")} ms, PSS of all processes '
                    f'{_fmt(row["pss_mb"], ".0f")} MB, wall {row["wall_s"]:.0f} s, rc {r["rc"]}, robots held: '
                    f'{row["lost"]}',
                    flush=True,
                )
                if r['rc'] != 0:
                    print(r.get('output', ''))
                    continue
            q = quality(record, policy)
            results[f'quality_{n}'] = q
            print(
                f'\n## learnt flock2d policy, {q["robots"]} robots, {q["steps"]} steps, ROS (hosted, lockstep) vs '
                f'offline rollout vs ground truth from the same initial state'
            )
            print(
                f'ROS recording vs core.rollout: max difference {q["max_diff_vs_rollout"]:.3g} '
                f'(bit for bit: {q["bit_for_bit"]})'
            )
            for name in ('ros', 'rollout', 'ground_truth'):
                m = q[name]
                print(
                    f'{name:13s} avd end {m["avd_end"]:.4f} (last 10 % {m["avd_last10"]:.4f})  '
                    f'amd end {m["amd_end"]:.4f} (last 10 % {m["amd_last10"]:.4f})',
                    flush=True,
                )
    out = Path(a.out) if a.out else tmp / 'results.json'
    out.write_text(json.dumps(results, indent=1, default=str))
    print(f'\n# results: {out}; logs and recordings: {tmp}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
