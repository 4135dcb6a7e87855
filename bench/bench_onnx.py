"""Benchmark of the torch-free robot runtime: onnxruntime against TorchScript.

    python bench/bench_onnx.py                          # everything
    python bench/bench_onnx.py --only tick --only start # seconds, no swarm
    python bench/bench_onnx.py --swarm 50 --swarm-torchscript 10

Figures, each as onnxruntime against TorchScript measured in the same run:

* start: a fresh process that imports the runtime, loads the shipped flock2d policy and
  computes one command of :class:`AgentLogic` (no ROS): wall time from spawning it to its
  first command, and its private memory (Private_Clean + Private_Dirty of
  /proc/PID/smaps_rollup) then; the median of ``--repeats`` processes;
* node: the real agent node (``python -m knode_swarm_ros.nodes.agent``, one robot, lockstep),
  spawned while this process publishes the robot's odometry: wall time from spawning to the
  first command received (rclpy import and DDS discovery included) and the node's private memory;
* tick: one realtime tick of robot 3 of 10 (Y_i from the delay buffers + policy + clip), p50/p99
  in microseconds, and the raw policy call for 1 and 100 rows;
* parity: TorchScript against onnxruntime offline rollouts of the shipped policies, the state
  difference after 300, 1000 and 2000 steps (float32 rounding differs between the backends),
  against the baseline of TorchScript rolling each initial state out alone (the same backend,
  another batch shape, so another float32 rounding);
* swarm: ``swarm --mode realtime --rate 20`` with N lone agent processes, one per robot: missed
  commands (the simulator's robot-steps without a fresh command, ``zeroed``), odometry and
  command loss, state-to-command latency and the agents' summed private memory.

Goals: an onnxruntime agent <= 80 MB private memory, start to first command
<= 0.5 s plus discovery, tick p50 <= 50 us; 50 lone onnxruntime agents at 20 Hz with < 1 %
missed commands.
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
import threading
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / 'bench'))

from bench_ros import losses, machine, run_swarm  # noqa: E402

BACKENDS = ('onnxruntime', 'torchscript')


def private_mb(pid) -> float:
    """Private (unshared) resident memory of a process in MB (1e6 bytes)."""
    total = 0
    try:
        for line in open(f'/proc/{pid}/smaps_rollup'):
            if line.startswith(('Private_Clean:', 'Private_Dirty:')):
                total += int(line.split()[1]) * 1024
    except OSError:
        return float('nan')
    return total / 1e6


# --- start: a fresh process to its first command (no ROS) ---------------------------------------
_START = """
import sys, time
from knode_swarm_ros.core import load_runtime, shipped_policy_path
from knode_swarm_ros.logic.agent.agent_logic import AgentConfig, AgentLogic
policy = load_runtime(shipped_policy_path('flock2d'), sys.argv[1], threads=1)
logic = AgentLogic(AgentConfig(0, [0, 1], 'realtime'), policy)
logic.receive(0, 0, [0.0, 0.0, 0.1, 0.0]); logic.receive(1, 0, [1.0, 0.5, 0.0, 0.2])
cmd = logic.tick(None)
print(time.monotonic(), policy.backend, 'torch' in sys.modules, flush=True)
sys.stdin.readline()  # hold still while the parent reads our memory
"""


def bench_start(backend: str, repeats: int) -> dict:
    times, mems = [], []
    for _ in range(repeats):
        t0 = time.monotonic()
        proc = subprocess.Popen(
            [sys.executable, '-c', _START, backend],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            cwd=REPO,
        )
        t1, got, torch_loaded = proc.stdout.readline().split()
        times.append(float(t1) - t0)
        mems.append(private_mb(proc.pid))
        proc.communicate('\n', timeout=60)
        assert got == backend, (got, backend)
    return {
        'start_s': float(np.median(times)),
        'private_mb': float(np.median(mems)),
        'torch_imported': torch_loaded,
    }


# --- node: the real agent node to its first received command -------------------------------------
def bench_node(backend: str, repeats: int) -> dict:
    import rclpy
    from rclpy.node import Node

    from knode_swarm_ros.core import get_scenario
    from knode_swarm_ros.nodes.common import qos
    from knode_swarm_ros.nodes.common.conversions import command_msg_type, state_to_odom

    spec = get_scenario('flock2d')
    env = dict(
        os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', ROS_DOMAIN_ID=str(120 + os.getpid() % 40)
    )
    os.environ.update(ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', ROS_DOMAIN_ID=env['ROS_DOMAIN_ID'])
    rclpy.init()
    node = Node('bench_onnx')
    got = []
    node.create_subscription(
        command_msg_type(spec), 'robot_0/cmd_accel', lambda m: got.append(time.monotonic()), qos.COMMAND
    )
    pub = node.create_publisher(type(state_to_odom(0, 0, np.zeros(4), 'flock2d')), 'robot_0/odom', qos.ODOM)
    times, mems = [], []
    try:
        for rep in range(repeats):
            got.clear()
            t0 = time.monotonic()
            proc = subprocess.Popen(
                [
                    sys.executable,
                    '-m',
                    'knode_swarm_ros.nodes.agent',
                    '--ros-args',
                    '-p',
                    'id:=0',
                    '-p',
                    'robots:=1',
                    '-p',
                    'mode:=lockstep',
                    '-p',
                    f'policy_runtime:={backend}',
                ],
                env=env,
                cwd=REPO,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
            while not got and time.monotonic() - t0 < 60:
                # a new own state every 10 ms, stamped now (the node's clock: older ones are dropped),
                # until the first command comes back
                pub.publish(state_to_odom(0, time.time_ns(), np.array([0.0, 0.0, 0.1, 0.0]), 'flock2d'))
                rclpy.spin_once(node, timeout_sec=0.01)
            if got:
                times.append(got[0] - t0)
                mems.append(private_mb(proc.pid))
            proc.send_signal(2)
            proc.wait(timeout=30)
    finally:
        node.destroy_node()
        rclpy.shutdown()
    return {
        'first_command_s': float(np.median(times)) if times else float('nan'),
        'private_mb': float(np.median(mems)) if mems else float('nan'),
        'runs': len(times),
    }


# --- tick -----------------------------------------------------------------------------------------
def bench_tick(backend: str, repeats: int) -> dict:
    from knode_swarm_ros.core import load_runtime, shipped_policy_path
    from knode_swarm_ros.logic.agent.agent_logic import AgentConfig, AgentLogic
    from knode_swarm_ros.logic.simulator.swarm_sim import initial_state

    policy = load_runtime(shipped_policy_path('flock2d'), backend, threads=1)
    n = 10
    z0, _ = initial_state('flock2d', n, seed=0)
    logic = AgentLogic(AgentConfig(3, list(range(n)), 'realtime'), policy)
    for r in range(n):
        logic.receive(r, 0, z0[r])

    def timed(fn):
        times = []
        for _ in range(repeats):
            t = time.perf_counter()
            fn()
            times.append(time.perf_counter() - t)
        times = np.array(times[repeats // 10 :]) * 1e6
        return float(np.percentile(times, 50)), float(np.percentile(times, 99))

    Y, mask = logic.neighbour_matrix(z0[3], {r: z0[r] for r in range(n)})
    out = {'tick': timed(lambda: logic.tick(None))}
    for B in (1, 100):
        Yb, mb = np.repeat(Y[None], B, 0), np.repeat(mask[None], B, 0)
        out[f'policy_{B}'] = timed(lambda: policy(Yb, mb))
    return out


# --- parity ---------------------------------------------------------------------------------------
def bench_parity(scenario: str, steps: int, trials: int = 3) -> dict:
    """Largest state difference between the TorchScript and onnxruntime rollouts of the shipped
    policy (10 robots) after 300, 1000 and ``steps`` steps, over ``trials`` initial states."""
    from knode_swarm_ros.core import load_runtime, rollout, shipped_policy_path
    from knode_swarm_ros.logic.simulator.swarm_sim import initial_state

    ts, ox = (
        load_runtime(shipped_policy_path(scenario), b, threads=1) for b in ('torchscript', 'onnxruntime')
    )
    z0 = np.stack([initial_state(scenario, 10, seed=s)[0] for s in range(trials)])
    args = (steps, scenario, ts.d_cr, ts.k, ts.tau, ts.dt)
    ref = rollout(ts, z0, *args)

    out = {}
    for name in ('onnxruntime', 'torchscript_alone'):
        if name == 'onnxruntime':
            got = rollout(ox, z0, *args)
        else:  # each initial state rolled out alone: TorchScript on batches of 10 rows instead of
            # 10 x trials, so another float32 rounding on the same backend
            got = np.concatenate([rollout(ts, z0[i : i + 1], *args) for i in range(trials)])
        diff = np.abs(ref - got).max(axis=(2, 3))  # [trials, T + 1]
        out[name] = {t: (float(np.median(diff[:, t])), float(diff[:, t].max())) for t in (300, 1000, steps)}
    return out


# --- swarm ----------------------------------------------------------------------------------------
def bench_swarm(backend: str, robots: int, steps: int, tmp: Path) -> dict:
    log_dir = tmp / f'swarm_{backend}_{robots}'
    log_dir.mkdir()
    mems = {}
    done = threading.Event()

    def sample():  # the agents' memory once the simulator runs (all loaded, steady state)
        log = log_dir / 'simulator.log'
        while not done.is_set():
            if log.exists() and 'running' in log.read_text(errors='replace'):
                time.sleep(2.0)
                pids = json.loads((log_dir / 'pids.json').read_text())
                mems.update({k: private_mb(p) for k, p in pids.items() if k.startswith('agent_')})
                return
            time.sleep(0.1)

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    # startup timeout: many agents starting at once on a loaded machine take minutes to import
    r = run_swarm(
        [
            '--robots',
            robots,
            '--steps',
            steps,
            '--mode',
            'realtime',
            '--rate',
            20,
            '--policy-runtime',
            backend,
            '--startup-timeout',
            900,
            '--record',
            tmp / f'{backend}_{robots}.npz',
        ],
        log_dir,
        timeout=1800,
    )
    done.set()
    sampler.join(timeout=5)
    rep = r['report']
    loss = losses(r)
    robot_steps = rep.get('steps_run', steps) * robots
    finite = [v for v in mems.values() if np.isfinite(v)]
    return {
        'rc': r['rc'],
        'missed': rep['counters']['zeroed'] / max(robot_steps, 1),
        'loss': loss,
        'latency_ms': rep.get('latency_ms') or {},
        'agent_mb_mean': float(np.mean(finite)) if finite else float('nan'),
        'agents_mb_sum': float(np.sum(finite)),
        'cpu_agents_cores': r.get('cpu_agents_cores', float('nan')),
        'output': r['output'] if r['rc'] else '',
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--only', choices=('start', 'node', 'tick', 'parity', 'swarm'), action='append')
    p.add_argument('--repeats', type=int, default=5, help='processes per backend for start and node (median)')
    p.add_argument(
        '--swarm', type=int, default=50, help='robots of the onnxruntime realtime swarm (default 50)'
    )
    p.add_argument(
        '--swarm-torchscript',
        type=int,
        default=None,
        help='robots of the TorchScript swarm (default: as --swarm; lower it when memory is short, 0: skip)',
    )
    p.add_argument('--steps', type=int, default=600, help='swarm steps (0.01 s each of flock2d; default 600)')
    a = p.parse_args(argv)
    only = set(a.only or ('start', 'node', 'tick', 'parity', 'swarm'))
    print(f'# bench_onnx, {datetime.datetime.now().isoformat(timespec="seconds")}')
    print(f'# command: {shlex.join([sys.executable, *sys.argv])}')
    print(f'# machine: {machine()}')
    goals = []
    res = {}
    if 'start' in only:
        print(
            '\n## start: spawn -> import runtime, load the shipped flock2d policy, first AgentLogic command (no ROS)'
        )
        for b in BACKENDS:
            res[f'start_{b}'] = s = bench_start(b, a.repeats)
            print(
                f'{b:12s} start {s["start_s"]:6.3f} s   private memory {s["private_mb"]:6.1f} MB   '
                f'torch imported: {s["torch_imported"]}'
            )
        on, ts = res['start_onnxruntime'], res['start_torchscript']
        print(
            f'ratio onnxruntime / torchscript: start {on["start_s"] / ts["start_s"]:.2f}x, memory '
            f'{on["private_mb"] / ts["private_mb"]:.2f}x'
        )
    if 'node' in only:
        print(
            '\n## node: spawn the agent node -> first command received (rclpy import and discovery included)'
        )
        for b in BACKENDS:
            res[f'node_{b}'] = s = bench_node(b, a.repeats)
            print(
                f'{b:12s} first command {s["first_command_s"]:6.3f} s   node private memory '
                f'{s["private_mb"]:6.1f} MB   ({s["runs"]} runs)'
            )
        on, ts = res['node_onnxruntime'], res['node_torchscript']
        print(
            f'ratio onnxruntime / torchscript: first command {on["first_command_s"] / ts["first_command_s"]:.2f}x, '
            f'memory {on["private_mb"] / ts["private_mb"]:.2f}x'
        )
        goals.append(
            (
                'onnxruntime agent node private memory <= 80 MB',
                on['private_mb'] <= 80,
                f'{on["private_mb"]:.1f} MB (TorchScript {ts["private_mb"]:.1f} MB)',
            )
        )
        if 'start' in only:
            s = res['start_onnxruntime']['start_s']
            goals.append(
                (
                    'start to first command <= 0.5 s plus discovery (no-ROS start)',
                    s <= 0.5,
                    f'{s:.3f} s; the node with rclpy and discovery {on["first_command_s"]:.3f} s',
                )
            )
    if 'tick' in only:
        print(
            '\n## tick: robot 3 of 10, realtime (Y_i + policy + clip), and the raw policy call; microseconds'
        )
        for b in BACKENDS:
            res[f'tick_{b}'] = t = bench_tick(b, 2000)
            print(
                f'{b:12s} tick p50 {t["tick"][0]:7.1f} p99 {t["tick"][1]:7.1f}   policy 1 row p50 '
                f'{t["policy_1"][0]:7.1f}   100 rows p50 {t["policy_100"][0]:7.1f}'
            )
        on, ts = res['tick_onnxruntime'], res['tick_torchscript']
        print(
            f'ratio onnxruntime / torchscript (p50): tick {on["tick"][0] / ts["tick"][0]:.2f}x, policy 1 row '
            f'{on["policy_1"][0] / ts["policy_1"][0]:.2f}x, 100 rows {on["policy_100"][0] / ts["policy_100"][0]:.2f}x'
        )
        goals.append(('onnxruntime tick p50 <= 50 us', on['tick'][0] <= 50, f'{on["tick"][0]:.1f} us'))
    if 'parity' in only:
        print(
            '\n## parity: offline rollouts of the shipped policies, 10 robots, 3 initial states: '
            'max |state difference| to the TorchScript rollout (median / worst)'
        )
        for scenario in ('flock2d', 'boids3d'):
            res[f'parity_{scenario}'] = d = bench_parity(scenario, 2000)
            for name, label in (('onnxruntime', 'onnxruntime'), ('torchscript_alone', 'TS alone (baseline)')):
                print(
                    f'{scenario:8s} {label:20s} '
                    + '   '.join(f'{t} steps {m:.1e} / {w:.1e}' for t, (m, w) in d[name].items())
                )
    if 'swarm' in only:
        tmp = Path(tempfile.mkdtemp(prefix='bench_onnx_'))
        counts = {'onnxruntime': a.swarm, 'torchscript': a.swarm_torchscript or a.swarm}
        print(f'\n## swarm: lone agent processes, realtime 20 Hz, {a.steps} steps of 0.01 s')
        print(
            f'{"backend":12s} {"robots":>6} {"missed":>8} {"odom loss":>9} {"cmd loss":>9} {"lat p50":>8} '
            f'{"lat p99":>8} {"MB/agent":>9} {"MB all":>8} {"CPU agents":>10} rc'
        )
        for b in BACKENDS:
            if not counts[b]:
                continue  # --swarm-torchscript 0: skipped (memory)
            res[f'swarm_{b}'] = s = bench_swarm(b, counts[b], a.steps, tmp)
            lat = s['latency_ms']
            print(
                f'{b:12s} {counts[b]:6d} {s["missed"]:8.2%} {s["loss"]["odom_loss"]:9.2%} {s["loss"]["cmd_loss"]:9.2%} '
                f'{lat.get("p50") or float("nan"):8.2f} {lat.get("p99") or float("nan"):8.2f} '
                f'{s["agent_mb_mean"]:9.1f} {s["agents_mb_sum"]:8.0f} {s["cpu_agents_cores"]:10.2f} {s["rc"]}'
            )
            if s['rc']:
                print(s['output'])
        on = res['swarm_onnxruntime']
        goals.append(
            (
                f'{a.swarm} lone onnxruntime agents at 20 Hz: < 1 % missed commands',
                on['missed'] < 0.01,
                f'{on["missed"]:.2%} missed',
            )
        )
        print(f'# logs: {tmp}')
    if goals:
        print('\n## goals')
        for name, ok, detail in goals:
            print(f'{"MET " if ok else "MISS"}  {name}: {detail}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
