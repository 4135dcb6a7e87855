"""The ``swarm`` executable: a whole swarm on this machine, one OS process per node.

``swarm --scenario flock2d --robots 10 --steps 2000 --mode lockstep --record run.npz``

Starts the simulator, the recorder and one agent per robot (``python -m
knode_swarm_ros.nodes.<node> --ros-args ...``) on a fresh ROS_DOMAIN_ID with localhost-only
discovery, lets the simulator wait until every agent has heard every robot, runs, and stops
every process (SIGTERM, then SIGKILL) on completion, on Ctrl-C / SIGTERM, on a
timeout, or when the simulator or the recorder dies. An agent that dies is reported (which,
and why) and the swarm goes on without it (``--on-agent-exit stop`` stops instead); the exit
status is then 3. Finally it prints the metrics of the recording and draws a figure.

This launcher imports neither rclpy nor a message package: it is process management.
Exit statuses: 0 done, 1 failed, 2 bad arguments or files, 3 done but an agent died,
130 interrupted.

FastDDS shared memory: with ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` this rmw_fastrtps
always adds its shared-memory transport (an XML profile or FASTDDS_BUILTIN_TRANSPORTS does not
remove it, measured), so processes create ``/dev/shm/fastrtps_*`` files; they remove them on a
clean exit, a killed process leaves them behind. After its processes have ended the launcher
deletes the FastDDS files that appeared during the run and that no live process holds a lock
on (the test ``fastdds shm clean`` uses, extended to the ports a killed process leaves without a
lock file), so nothing of another user's live processes is touched.
"""
from __future__ import annotations

import argparse
import fcntl
import json
import math
import os
import re
import selectors
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional, Sequence

from . import swarm_hosting as hosting
from .agent_link import add_link_arguments, link_parameters
from .common import (EXIT_AGENT_LOST, EXIT_CONFIG, EXIT_FAILURE, EXIT_INTERRUPTED, EXIT_OK, MODES,
                     ConfigError)

__all__ = ['main', 'build_parser', 'plan_run', 'Child', 'shm_snapshot', 'shm_cleanup', 'DOMAIN_RANGE']

PACKAGE = 'knode_swarm_ros'
DOMAIN_RANGE = (30, 101)   # valid ids with the default port mapping, away from the default 0
SHM_DIR = Path('/dev/shm')
_SHM_RE = re.compile(r'^(sem\.)?(fastrtps|fastdds)_')
# SIGTERM first: the nodes treat it as Ctrl-C once running (the recorder saves), and a process
# still importing ends silently (a SIGINT there could print a KeyboardInterrupt traceback).
_STOP_SIGNALS = ((signal.SIGTERM, 8.0), (signal.SIGKILL, 10.0))
#: The most robots any node accepts (the 'robots' parameter range of agent, simulator, recorder).
MAX_ROBOTS = 10_000
#: Private memory of one process, measured 2026-11-30 with the CPU build of torch (DESIGN.md):
#: an agent about 330 MB; the simulator and the recorder (numpy, no torch) far less.
AGENT_MB, NODE_MB = 330, 150
_ECHO_RE = re.compile(r'\[(WARN|WARNING|ERROR|FATAL)\]|Traceback|error:', re.IGNORECASE)


_T0 = time.monotonic()


def _say(text: str) -> None:
    print(f'[swarm {time.monotonic() - _T0:6.1f} s] {text}', flush=True)


# --- arguments -------------------------------------------------------------------------
def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog='swarm', description='Run a swarm of learnt controllers on this machine: the simulator, one agent '
        'process per robot and the recorder, on a fresh ROS domain with localhost-only discovery.')
    p.add_argument('--scenario', choices=('flock2d', 'boids3d'), help="default: the policy's, else flock2d")
    p.add_argument('--robots', type=int, help='number of robots (default: 10, or as many as --init has)')
    p.add_argument('--steps', type=int, default=2000, help='steps of dt to simulate (0: until Ctrl-C); default 2000')
    p.add_argument('--mode', choices=MODES, default='lockstep', help='default lockstep')
    p.add_argument('--policy', help='TorchScript policy file (default: the shipped policy of the scenario; realtime: '
                   'the one trained for --rate, e.g. policies/flock2d_20hz.pt, if shipped)')
    p.add_argument('--policy-runtime', choices=('auto', 'torchscript', 'onnxruntime'), default='auto',
                   help="agents' policy_runtime (auto: the ONNX twin on onnxruntime when it exists); default auto")
    p.add_argument('--init', metavar='FILE.npz[:TRAJ]', help='initial state: frame 0 of a trajectory file')
    p.add_argument('--seed', type=int, default=0, help='seed of the initial state (without --init); default 0')
    p.add_argument('--record', metavar='OUT.npz', required=True, help='trajectory file to write')
    p.add_argument('--bag', metavar='OUT.mcap', help='also write the run as a bag of /robot_<id>/odom (an .mcap '
                   'file, else a rosbag2 directory), for training.import_bag')
    p.add_argument('--ground-truth', action='store_true',
                   help='the simulator drives the robots with the Tanner / boids controller; no agents')
    p.add_argument('--variant', default='', help='ground-truth variant / preset (default: paper)')
    p.add_argument('--rate', type=float, default=20.0,
                   help='realtime: control and publishing rate in Hz (simulated time); default 20')
    p.add_argument('--rate-check', choices=('warn', 'refuse'), default='warn',
                   help="realtime: when 1 / --rate differs from the policy's dt the agents warn (default) or refuse")
    p.add_argument('--real-time-factor', type=float, default=1.0, help='realtime: default 1')
    p.add_argument('--state-timeout', type=float, default=0.5, help="agents' state_timeout in s; default 0.5")
    p.add_argument('--lockstep-timeout', type=float, default=5.0,
                   help='lockstep: wall seconds before a silent agent is held at its last command; default 5')
    p.add_argument('--startup-timeout', type=float, default=180.0,
                   help='wall seconds for every process to be ready; default 180')
    p.add_argument('--timeout', type=float, default=0.0, help='stop after this many wall seconds (0: no limit)')
    p.add_argument('--no-parity-batch', action='store_true',
                   help='agents evaluate a batch of 1 (faster; no bit-for-bit parity with core.rollout)')
    p.add_argument('--on-agent-exit', choices=('continue', 'stop'), default='continue',
                   help='when an agent process dies: go on without it (default) or stop the run')
    p.add_argument('--domain-id', type=int, help=f'ROS_DOMAIN_ID (default: a free one, claimed, in {DOMAIN_RANGE[0]}..'
                   f'{DOMAIN_RANGE[1]})')
    p.add_argument('--figure', metavar='PNG', help='figure path (default: the recording with .png)')
    p.add_argument('--no-figure', action='store_true', help='do not draw a figure')
    p.add_argument('--log-dir', help='where the processes\' logs, parameter files and reports go (default: a '
                   'temporary folder, removed after a successful run unless --keep-logs)')
    p.add_argument('--keep-logs', action='store_true', help='keep the temporary log folder')
    p.add_argument('--quiet', action='store_true', help="do not echo the nodes' output")
    add_link_arguments(p)
    p.add_argument('--managed', action='store_true', help='agents as managed (lifecycle) nodes: configure every '
                   'agent, then activate them together')
    hosting.add_arguments(p)
    return p


@dataclass
class Plan:
    """Everything decided before a process starts."""

    scenario: str
    robots: int
    steps: int
    mode: str
    dt: float
    d_cr: float
    policy: Optional[str]
    record: Path
    figure: Optional[Path]
    run_dir: Path
    temporary_dir: bool
    domain_id: int
    args: argparse.Namespace
    policy_meta: Dict = field(default_factory=dict)
    domain_claim: object = None  # held for the run (domains.DomainClaim) when the domain was drawn
    agents_per_process: int = 1


def _check_output_folder(option: str, given: str, folder: Path) -> None:
    """``folder`` exists, or can be created (``run`` creates it once the whole plan is checked):
    its nearest existing ancestor is a writable directory."""
    if folder.is_dir():
        return
    ancestor = folder
    while not ancestor.exists() and ancestor != ancestor.parent:
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise ConfigError(f'{option} {given}: cannot create folder {folder}: {ancestor} is not a folder')
    if not os.access(ancestor, os.W_OK | os.X_OK):
        raise ConfigError(f'{option} {given}: cannot create folder {folder}: {ancestor} is not writable')


def available_memory_mb() -> Optional[float]:
    """MemAvailable of /proc/meminfo in MB (None where unknown)."""
    try:
        with open('/proc/meminfo') as fh:
            for line in fh:
                if line.startswith('MemAvailable:'):
                    return int(line.split()[1]) / 1024.0
    except (OSError, ValueError, IndexError):
        pass
    return None


def _check_memory(robots: int, per_process: int = 1) -> None:
    """Refuse a swarm whose agent processes cannot fit in this machine's available memory."""
    processes = math.ceil(robots / per_process)
    need = processes * AGENT_MB + 2 * NODE_MB
    have = available_memory_mb()
    if have is not None and need > have:
        raise ConfigError(f'--robots {robots}: {processes} agent processes need about {need / 1024:.1f} GB '
                          f'({AGENT_MB} MB each, measured with the CPU build of torch) but this machine has '
                          f'{have / 1024:.1f} GB available; run fewer robots')


def plan_run(args: argparse.Namespace) -> Plan:
    """Check the arguments and the input files; raise :class:`ConfigError` naming the problem."""
    from ..core.scenarios import get_scenario
    if args.steps < 0:
        raise ConfigError(f'--steps must be >= 0, got {args.steps}')
    if args.robots is not None and not 1 <= args.robots <= MAX_ROBOTS:
        raise ConfigError(f'--robots must be in 1..{MAX_ROBOTS} (the nodes\' limit), got {args.robots}')
    for name in ('rate', 'real_time_factor', 'state_timeout', 'lockstep_timeout', 'startup_timeout'):
        value = getattr(args, name)
        if not value > 0:
            raise ConfigError(f"--{name.replace('_', '-')} must be > 0, got {value}")
    if args.timeout < 0:
        raise ConfigError(f'--timeout must be >= 0, got {args.timeout}')
    link_parameters(args, args.mode)  # checks the --link-* flags
    record = Path(args.record).expanduser().resolve()
    if record.suffix != '.npz':
        raise ConfigError(f'--record {args.record}: the trajectory file must end with .npz')
    _check_output_folder('--record', args.record, record.parent)
    scenario = args.scenario
    policy_path, meta = None, {}
    if args.ground_truth:
        if args.policy:
            raise ConfigError('--policy and --ground-truth exclude each other (no agents run with --ground-truth)')
        scenario = scenario or 'flock2d'
        dt = get_scenario(scenario).dt
        from ..core.policy import DEFAULTS
        d_cr = float(DEFAULTS[scenario]['d_cr'])
    else:
        from ..core.policy_meta import PolicyError, shipped_policy_path
        from ..core.policy_runtime import load_runtime  # the agents' backend: checks an ONNX twin up front
        try:
            if args.policy:
                policy_path = args.policy
            elif args.mode == 'realtime':  # the shipped policy trained for --rate, if there is one
                from .control_period import shipped_policy_for_rate
                policy_path = str(shipped_policy_for_rate(scenario or 'flock2d', args.rate)[0])
            else:
                policy_path = str(shipped_policy_path(scenario or 'flock2d'))
            policy = load_runtime(policy_path, args.policy_runtime)
        except PolicyError as exc:
            hint = '' if args.policy else ' (pass --policy FILE.pt)'
            raise ConfigError(f'--policy (--policy-runtime {args.policy_runtime}): {exc}{hint}') from None
        if scenario and policy.scenario != scenario:
            raise ConfigError(f'--scenario {scenario} but the policy {policy_path} is for {policy.scenario}')
        scenario = policy.scenario
        dt, d_cr, meta = policy.dt, policy.d_cr, dict(policy.meta)
        policy_path = str(Path(policy_path).resolve())
    robots = args.robots
    if args.init:
        from ..core.trajectory import TrajectoryError, load_trajectories, parse_trajectory_ref
        path, traj = parse_trajectory_ref(args.init)
        try:
            data = load_trajectories(path, scenario)
        except TrajectoryError as exc:
            raise ConfigError(f'--init: {exc}') from None
        if not 0 <= traj < data.states.shape[0]:
            raise ConfigError(f'--init {args.init}: trajectory {traj} does not exist '
                              f'({data.states.shape[0]} in the file)')
        n = data.states.shape[2]
        if robots is not None and robots != n:
            raise ConfigError(f'--robots {robots} but --init {args.init} has {n} robots')
        robots = n
        args.init = f'{Path(path).resolve()}:{traj}'
    robots = robots or 10
    if robots > MAX_ROBOTS:
        raise ConfigError(f'--init {args.init} has {robots} robots; the nodes take at most {MAX_ROBOTS}')
    per_process = hosting.resolve_agents_per_process(args.agents_per_process, robots)
    if args.managed and not args.ground_truth:
        if args.agents_per_process > 1:
            raise ConfigError('--managed runs one lifecycle agent process per robot; it cannot be combined with '
                              f'--agents-per-process {args.agents_per_process}')
        per_process = 1
    hosting.check_netns(args.netns)
    if not args.ground_truth:
        _check_memory(robots, per_process)
    if args.variant:
        from ..core import groundtruth
        if args.variant not in groundtruth.presets(scenario):
            raise ConfigError(f'--variant {args.variant!r}: known {scenario} variants are '
                              f"{', '.join(groundtruth.presets(scenario))}")
    claim = None
    if args.domain_id is None:  # a free one: another swarm on this machine may hold one
        from .domains import claim_domain
        try:
            claim = claim_domain(range(DOMAIN_RANGE[0], DOMAIN_RANGE[1] + 1))
        except RuntimeError as exc:
            raise ConfigError(f'{exc}; pass --domain-id') from None
    domain = args.domain_id if claim is None else claim.domain_id
    if not 0 <= domain <= 232:
        raise ConfigError(f'--domain-id must be in 0..232, got {domain}')
    figure = None if args.no_figure else Path(args.figure).resolve() if args.figure else record.with_suffix('.png')
    if figure is not None:
        _check_output_folder('--figure', str(args.figure or figure), figure.parent)
    if args.log_dir:
        run_dir, temporary = Path(args.log_dir).resolve(), False
        run_dir.mkdir(parents=True, exist_ok=True)
    else:
        run_dir, temporary = Path(tempfile.mkdtemp(prefix='knode_swarm_')), True
    return Plan(scenario, robots, args.steps, args.mode, dt, d_cr, policy_path, record, figure, run_dir,
                temporary, domain, args, meta, claim, per_process)


# --- parameter files -------------------------------------------------------------------
def _params_file(path: Path, params: Dict) -> Path:
    import yaml
    path.write_text(yaml.safe_dump({'/**': {'ros__parameters': params}}, sort_keys=True))
    return path


def _scalar(value) -> str:
    """A value as the YAML scalar ``-p name:=value`` expects."""
    import yaml
    text = yaml.safe_dump(value, default_flow_style=True).strip()
    return text[:-3].strip() if text.endswith('...') else text


def node_commands(plan: Plan) -> Dict[str, List[str]]:
    """The command line of every process, by name (``simulator``, ``recorder``, ``agent_<i>``)."""
    a = plan.args
    gt = bool(a.ground_truth)
    sim = {'scenario': plan.scenario, 'robots': plan.robots, 'steps': plan.steps, 'mode': plan.mode,
           'dt': float(plan.dt), 'seed': int(a.seed), 'init': a.init or '', 'variant': a.variant,
           'ground_truth': gt, 'real_time_factor': float(a.real_time_factor), 'publish_rate': float(a.rate),
           'command_timeout': max(0.5, 3.0 / a.rate), 'lockstep_timeout': float(a.lockstep_timeout),
           'startup_timeout': float(a.startup_timeout), 'wait_for_agents': not gt, 'wait_for_recorder': True,
           'd_cr': float(plan.d_cr), 'report': str(plan.run_dir / 'simulator.json'),
           'stop_limit': float(plan.policy_meta.get('command_limit') or 0.0)}
    rec = {'scenario': plan.scenario, 'robots': plan.robots, 'output': str(plan.record), 'dt': float(plan.dt),
           'bag': os.path.abspath(a.bag) if a.bag else '', 'use_sim_time': True}
    python = [sys.executable, '-m']
    out = {'simulator': python + [f'{PACKAGE}.nodes.simulator', '--ros-args', '--params-file',
                                  str(_params_file(plan.run_dir / 'simulator.yaml', sim))],
           'recorder': python + [f'{PACKAGE}.nodes.recorder', '--ros-args', '--params-file',
                                 str(_params_file(plan.run_dir / 'recorder.yaml', rec))]}
    if not gt:
        agent = {'scenario': plan.scenario, 'robots': plan.robots, 'policy': plan.policy, 'mode': plan.mode,
                 'control_rate': float(a.rate), 'rate_check': a.rate_check, 'state_timeout': float(a.state_timeout),
                 'parity_batch': not a.no_parity_batch, 'use_sim_time': True,
                 'policy_runtime': a.policy_runtime, **link_parameters(a, plan.mode)}
        agent['managed'] = bool(a.managed)
        params = str(_params_file(plan.run_dir / 'agent.yaml', agent))
        if a.managed:  # configures every agent, then activates them together, then exits 0
            out['lifecycle_manager'] = python + [f'{PACKAGE}.nodes.lifecycle_manager', '--ros-args', '-p',
                                                 f'robots:={plan.robots}', '-p', f'timeout:={float(a.startup_timeout)}']
        out.update(hosting.agent_commands(plan.robots, plan.agents_per_process, python, PACKAGE, params,
                                          plan.run_dir))
    return out


def child_environment(domain_id: int) -> Dict[str, str]:
    """The environment of every node: a copy of ours (the ROS wheels' LD_LIBRARY_PATH and
    bootstrap flag travel together), the domain, localhost-only discovery, one thread each."""
    env = dict(os.environ)
    env.update({'ROS_DOMAIN_ID': str(domain_id), 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
                'PYTHONUNBUFFERED': '1', 'RCUTILS_COLORIZED_OUTPUT': '0', 'OMP_NUM_THREADS': '1',
                'MKL_NUM_THREADS': '1'})
    env.pop('ROS_LOCALHOST_ONLY', None)  # deprecated; the discovery range above replaces it
    return env


# --- processes -------------------------------------------------------------------------
class _Interrupted(Exception):
    """Ctrl-C / SIGTERM / SIGHUP reached the launcher (raised by Children.pump)."""

def _die_with_parent() -> None:  # runs in the child between fork and exec
    try:
        import ctypes
        ctypes.CDLL('libc.so.6', use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except OSError:
        pass


@dataclass
class Child:
    """One node process, its log and how it ended."""

    name: str
    proc: subprocess.Popen
    log_path: Path
    log: object
    echo: str  # 'all', 'problems' or 'none'
    buffer: bytes = b''
    tail: List[str] = field(default_factory=list)
    reported: bool = False
    marker: str = ''      # a log line fragment that says the process is past its checks
    marked: bool = False

    @property
    def pid(self) -> int:
        return self.proc.pid

    def feed(self, data: bytes) -> None:
        self.log.write(data)
        self.log.flush()  # so that the logs can be followed while the swarm runs
        self.buffer += data
        *lines, self.buffer = self.buffer.split(b'\n')
        for raw in lines:
            line = raw.decode(errors='replace').rstrip()
            self.tail = (self.tail + [line])[-15:]
            if self.marker and self.marker in line:
                self.marked = True
            if self.echo == 'all' or (self.echo == 'problems' and _ECHO_RE.search(line)):
                print(f'  [{self.name}] {line}', flush=True)

    def how_it_ended(self) -> str:
        rc = self.proc.returncode
        if rc is None:
            return 'still running'
        if rc < 0:
            try:
                return f'killed by {signal.Signals(-rc).name}'
            except ValueError:
                return f'killed by signal {-rc}'
        return f'exited with status {rc}'


#: What each node logs once its parameters, files and policy have passed its checks.
_STARTED = {'simulator': ' robots, ', 'recorder': ': recording ', 'agent': 'publishing ', 'agents': ' hosted) of '}


def start_child(name: str, cmd: Sequence[str], env: Dict[str, str], run_dir: Path, echo: str) -> Child:
    log_path = run_dir / f'{name}.log'
    proc = subprocess.Popen(list(cmd), env=env, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, start_new_session=True, preexec_fn=_die_with_parent,
                            cwd=str(run_dir))
    os.set_blocking(proc.stdout.fileno(), False)
    return Child(name, proc, log_path, open(log_path, 'wb'), echo, marker=_STARTED[name.split('_')[0]])


class Children:
    """The node processes, their output pumped into logs (and echoed) with one selector."""

    def __init__(self):
        self.items: Dict[str, Child] = {}
        self.selector = selectors.DefaultSelector()
        self.interrupted = False  # set by the launcher's signal handler; pump() raises _Interrupted

    def add(self, child: Child) -> None:
        self.items[child.name] = child
        self.selector.register(child.proc.stdout, selectors.EVENT_READ, child)

    def pump(self, timeout: float) -> None:
        if self.interrupted:
            raise _Interrupted()
        if not self.selector.get_map():
            time.sleep(timeout)
            return
        for key, _ in self.selector.select(timeout):
            child: Child = key.data
            try:
                data = os.read(key.fileobj.fileno(), 65536)
            except BlockingIOError:
                continue
            if data:
                child.feed(data)
            else:
                self.selector.unregister(key.fileobj)

    def alive(self) -> List[Child]:
        return [c for c in self.items.values() if c.proc.poll() is None]

    def stop(self, names: Optional[Sequence[str]] = None) -> List[str]:
        """SIGTERM, then SIGKILL to the (named) live processes; returns notes on those that
        needed more than SIGTERM."""
        targets = [c for c in self.items.values() if (names is None or c.name in names)]
        notes = []
        for n, (sig, grace) in enumerate(_STOP_SIGNALS):
            live = [c for c in targets if c.proc.poll() is None]
            if not live:
                break
            if n:
                notes.append(f'{", ".join(c.name for c in live)} did not stop in time: sending {sig.name}')
            for c in live:
                try:
                    c.proc.send_signal(sig)
                except ProcessLookupError:
                    pass
            end = time.monotonic() + grace
            while time.monotonic() < end and any(c.proc.poll() is None for c in live):
                self.pump(0.05)
        self.drain()
        return notes

    def drain(self) -> None:
        """Read what the ended processes wrote last, to the end of their pipes."""
        for key in list(self.selector.get_map().values()):
            child: Child = key.data
            if child.proc.poll() is None:
                continue
            fd = key.fileobj.fileno()
            os.set_blocking(fd, True)
            while True:
                try:
                    data = os.read(fd, 65536)
                except OSError:
                    data = b''
                if not data:
                    break
                child.feed(data)
            self.selector.unregister(key.fileobj)

    def close(self) -> None:
        for c in self.items.values():
            if c.buffer:
                c.feed(b'\n')
            c.log.close()
            try:
                c.proc.stdout.close()
            except OSError:
                pass
        self.selector.close()


# --- shared memory -----------------------------------------------------------------------
def shm_snapshot() -> set:
    """Names of the FastDDS files in /dev/shm now."""
    try:
        return {n for n in os.listdir(SHM_DIR) if _SHM_RE.match(n)}
    except OSError:
        return set()


def _locked(path: Path) -> bool:
    try:
        with open(path, 'ab') as fh:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return False
    except OSError:
        return True


def shm_cleanup(before: set) -> List[str]:
    """Delete FastDDS files that appeared since ``before`` and that no live process holds.

    A segment or port ``X`` comes with a lock file ``X_el`` (or ``X_sl``) that its live owner
    keeps locked, and a port with ``sem.X_mutex``. A group whose lock file is unlocked (its
    owner was killed: the rule of ``fastdds shm clean``) or gone (a port that a killed process
    had opened stays behind after its owner's clean exit, measured) is deleted, but only the
    files of it that are new. Returns the names removed.
    """
    new = shm_snapshot() - before
    bases = set()
    for name in new:
        if name.startswith('sem.') and name.endswith('_mutex'):
            bases.add(name[4:-6])
        elif name.endswith(('_el', '_sl')):
            bases.add(name[:-3])
        else:
            bases.add(name)
    removed = []
    for base in sorted(bases):
        locks = [SHM_DIR / f'{base}{tail}' for tail in ('_el', '_sl')]
        if any(lock.exists() and _locked(lock) for lock in locks):
            continue  # a live process owns it
        for victim in (base, f'{base}_el', f'{base}_sl', f'sem.{base}_mutex'):
            if victim in new:
                try:
                    (SHM_DIR / victim).unlink()
                    removed.append(victim)
                except OSError:
                    pass
    return removed


# --- results ---------------------------------------------------------------------------
def summarise(plan: Plan) -> Optional[Dict]:
    """Print the recording's metrics (and the simulator's figures); returns them."""
    import numpy as np
    from ..core.trajectory import TrajectoryError, load_trajectories
    from .recorder_logic import swarm_metrics
    try:
        data = load_trajectories(plan.record)
    except TrajectoryError as exc:
        _say(f'no recording to summarise: {exc}')
        return None
    states = data.states[0]
    metrics = np.array([swarm_metrics(f, data.scenario) for f in states])
    tail = max(1, len(states) // 10)
    last = metrics[-tail:].mean(axis=0)
    info = {'frames': int(states.shape[0]), 'robots': int(states.shape[1]), 'dt': float(data.dt),
            'avd_start': float(metrics[0, 0]), 'avd_end': float(metrics[-1, 0]), 'amd_start': float(metrics[0, 1]),
            'amd_end': float(metrics[-1, 1]), 'avd_last10pct': float(last[0]), 'amd_last10pct': float(last[1]),
            'incomplete_frames': data.meta.get('incomplete_frames'), 'interrupted': data.meta.get('interrupted')}
    which = 'velocity' if data.scenario == 'flock2d' else 'heading'
    _say(f'recorded {plan.record}: {info["frames"]} frames x {info["robots"]} robots, dt {data.dt:g} s'
         f'{" (interrupted)" if info["interrupted"] else ""}')
    _say(f'avd ({which} difference): {info["avd_start"]:.4f} at start, {info["avd_end"]:.4f} at the end '
         f'(mean of the last 10%: {info["avd_last10pct"]:.4f})')
    _say(f'amd (nearest-neighbour distance): {info["amd_start"]:.4f} at start, {info["amd_end"]:.4f} at the end '
         f'(mean of the last 10%: {info["amd_last10pct"]:.4f})')
    report = plan.run_dir / 'simulator.json'
    if report.is_file():
        try:
            sim = json.loads(report.read_text())
        except ValueError:
            sim = {}
        if sim.get('steps_per_s') is not None:
            lat = sim.get('latency_ms') or {}
            extra = (f'; state-to-command latency p50 {lat["p50"]:.2f} ms, p99 {lat["p99"]:.2f} ms'
                     if lat.get('p50') is not None else '')
            _say(f'simulator: {sim.get("steps_run")} steps in {sim.get("run_s", 0):.2f} s '
                 f'({sim["steps_per_s"]:.1f} steps/s) after {sim.get("startup_s", 0):.1f} s of startup{extra}')
        info['simulator'] = sim
    if plan.figure is not None:
        write_figure(plan.figure, states, data.dt, data.scenario, metrics,
                     f'{data.scenario}, {states.shape[1]} robots, {plan.mode}')
    return info


def write_figure(path: Path, states, dt: float, scenario: str, metrics, title: str) -> bool:
    """Trajectories and avd/amd over time as a PNG (matplotlib is imported only here)."""
    try:
        import matplotlib
        matplotlib.use('Agg')
        import matplotlib.pyplot as plt
    except ImportError:
        _say('matplotlib is not installed: no figure (pip install matplotlib)')
        return False
    import numpy as np
    t = np.arange(states.shape[0]) * dt
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.5))
    ax = axes[0]
    for i in range(states.shape[1]):
        ax.plot(states[:, i, 0], states[:, i, 1], lw=0.8)
    ax.scatter(states[0, :, 0], states[0, :, 1], c='k', s=10, marker='o', label='start')
    ax.scatter(states[-1, :, 0], states[-1, :, 1], c='r', s=14, marker='x', label='end')
    ax.set_xlabel('x')
    ax.set_ylabel('y')
    ax.set_aspect('equal', adjustable='datalim')
    ax.legend(loc='best', fontsize=8)
    ax.set_title('trajectories' + (' (x-y projection)' if scenario == 'boids3d' else ''))
    axes[1].plot(t, metrics[:, 0])
    axes[1].set_xlabel('t [s]')
    axes[1].set_title('avd: ' + ('velocity' if scenario == 'flock2d' else 'heading') + ' difference')
    axes[2].plot(t, metrics[:, 1])
    axes[2].set_xlabel('t [s]')
    axes[2].set_title('amd: nearest-neighbour distance')
    fig.suptitle(title)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    _say(f'figure: {path}')
    return True


# --- the run ---------------------------------------------------------------------------


def run(plan: Plan) -> int:
    """Start, supervise and stop the processes of ``plan``; returns the exit status."""
    a = plan.args
    plan.record.parent.mkdir(parents=True, exist_ok=True)  # checked by plan_run (a fresh clone has no out/)
    env = child_environment(plan.domain_id)
    commands, env = hosting.place(node_commands(plan), env, a.netns)
    shm_before = shm_snapshot()
    record_before = _file_identity(plan.record)
    children = Children()
    stop_reason = {'signal': None}

    def on_signal(signum, _frame):
        # Only a flag: a signal handler that raises can have its exception swallowed (an at-fork
        # hook of the logging module runs pending handlers while a child is started and ignores
        # what they raise, measured) or raised in the forked child. Children.pump raises it.
        stop_reason['signal'] = signum
        children.interrupted = True

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    code = EXIT_OK
    lost_agents: List[str] = []
    t0 = time.monotonic()
    try:
        try:
            _say(f'{plan.robots} robots, {plan.scenario}, {plan.mode}, {plan.steps or "unlimited"} steps, '
                 f'ROS_DOMAIN_ID={plan.domain_id}, logs in {plan.run_dir}')
            if a.ground_truth:
                _say(f'ground truth ({a.variant or "paper"}): the simulator drives the robots, no agents')
            else:
                _say(f'policy {plan.policy} (k={plan.policy_meta.get("k")}, d_cr={plan.policy_meta.get("d_cr")}, '
                     f'tau={plan.policy_meta.get("tau")}, dt={plan.policy_meta.get("dt")})')
                if plan.mode == 'realtime':
                    from .control_period import check_control_period
                    _say(check_control_period(a.rate, plan.dt).describe() or f'control period = policy dt ({plan.dt:g} s)')
            failed = _start_in_stages(plan, commands, env, children, t0)
            pids = {name: c.pid for name, c in children.items.items()}
            (plan.run_dir / 'pids.json').write_text(json.dumps(pids, indent=1))
            if failed is not None:
                code = failed
            else:
                agents = [n for n in pids if hosting.is_agent_process(n)]
                _say(f'started simulator (pid {pids["simulator"]}), recorder (pid {pids["recorder"]})'
                     + (f', {len(agents)} agent processes for {plan.robots} robots (pids {pids[agents[0]]}..'
                        f'{pids[agents[-1]]})' if agents else '')
                     + ': waiting until every agent has heard every robot')
                code = _supervise(plan, children, lost_agents, t0)
        except _Interrupted:
            name = signal.Signals(stop_reason['signal']).name
            _say(f'{name}: stopping every process (the recorder saves what it has)')
            code = EXIT_INTERRUPTED
        # Stop whatever still runs; the recorder first waits for nothing: SIGTERM makes it save.
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        children.interrupted = False
        for note in children.stop():
            _say(note)
    finally:
        for s, handler in old.items():
            signal.signal(s, handler)
        for c in children.alive():  # never leave a process behind
            c.proc.kill()
            c.proc.wait()
        children.close()
        removed = shm_cleanup(shm_before)
        if removed:
            _say(f'removed {len(removed)} FastDDS shared-memory file(s) left by killed processes')
    _say(f'every process has stopped ({time.monotonic() - t0:.1f} s in all)')
    if code in (EXIT_OK, EXIT_AGENT_LOST, EXIT_INTERRUPTED):
        if _file_identity(plan.record) != record_before:
            summarise(plan)
        elif record_before is not None:
            _say(f'no recording was written in this run: {plan.record} is an earlier file, left as it was '
                 '(not summarised)')
        else:
            _say('no recording was written in this run')
    if lost_agents and code == EXIT_OK:
        code = EXIT_AGENT_LOST
    if lost_agents:
        _say(f'agent process(es) died during the run: {"; ".join(lost_agents)}')
    return code


def _file_identity(path: Path):
    """(inode, size, mtime) of ``path``, None when absent: the recorder replaces the file
    atomically, so any write of this run changes it."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return (st.st_ino, st.st_size, st.st_mtime_ns)


def _start_in_stages(plan: Plan, commands: Dict[str, List[str]], env: Dict[str, str], children: Children,
                     t0: float) -> Optional[int]:
    """Start the simulator and the recorder, then, once both are past their checks (their logs
    say so), the agents: a refused parameter or file stops the run before hundreds of agents
    load torch. (An agent that refuses its configuration stops the run in _supervise; agents are
    not staged further: under load, one agent's start-up is tens of seconds that the simulator's
    start-up timeout would lose.) Returns an exit status when the first stage failed."""
    a = plan.args
    names = list(commands)
    agents = [n for n in names if hosting.is_agent_process(n)]
    for stage in ([n for n in names if n not in agents], agents):
        for name in stage:
            echo = 'none' if a.quiet else 'problems' if hosting.is_agent_process(name) else 'all'
            children.add(start_child(name, commands[name], env, plan.run_dir, echo))
        if stage is agents:
            break  # supervised with the rest of the run
        waiting = [children.items[n] for n in stage]
        while any(not c.marked for c in waiting):
            children.pump(0.1)
            for c in waiting:
                if c.proc.poll() is not None and not c.marked:
                    c.reported = True
                    last = [line for line in c.tail if line.strip()][-3:]
                    detail = (' -- last output: ' + ' | '.join(last)) if last else ''
                    _say(f'the {c.name} (pid {c.pid}) {c.how_it_ended()} while starting{detail}: nothing else '
                         'is started')
                    return EXIT_CONFIG if c.proc.returncode == EXIT_CONFIG else EXIT_FAILURE
            if time.monotonic() - t0 > a.startup_timeout:
                late = [c.name for c in waiting if not c.marked]
                _say(f'{", ".join(late)} not started after --startup-timeout {a.startup_timeout:g} s: stopping')
                return EXIT_FAILURE
    return None


def _supervise(plan: Plan, children: Children, lost_agents: List[str], t0: float) -> int:
    a = plan.args
    sim = children.items['simulator']
    rec = children.items['recorder']
    while True:
        children.pump(0.1)
        for c in children.items.values():
            if c.reported or c.proc.poll() is None:
                continue
            c.reported = True
            rc = c.proc.returncode
            if c is rec and rc == 0:
                continue  # saved after the simulator said done
            if c.name == 'lifecycle_manager' and rc == 0:
                _say('every agent configured, then activated together')
                continue
            if c is sim and rc == 0:
                _say('the simulator has finished')
                end = time.monotonic() + 15.0
                while rec.proc.poll() is None and time.monotonic() < end:
                    children.pump(0.1)
                if rec.proc.poll() not in (0,):
                    _say(f'the recorder {rec.how_it_ended()} after the simulator finished')
                    return EXIT_FAILURE
                return EXIT_OK
            why = c.how_it_ended()
            last = [line for line in c.tail if line.strip()][-3:]
            detail = (' -- last output: ' + ' | '.join(last)) if last else ''
            if hosting.is_agent_process(c.name):
                held = hosting.robots_of(c.name)
                _say(f'{c.name} (pid {c.pid}) {why}{detail}')
                lost_agents.append(f'{c.name} (pid {c.pid}) {why}'
                                   + (f', hosting robots {held}' if c.name.startswith('agents_') else ''))
                if rc == EXIT_CONFIG:
                    _say('an agent refused its configuration: stopping the run')
                    return EXIT_CONFIG
                if a.on_agent_exit == 'stop':
                    _say('--on-agent-exit stop: stopping the run')
                    return EXIT_FAILURE
                _say(f'{c.name} is gone: the other agents go on; the simulator holds robot'
                     f'{"s" if len(held) > 1 else ""} {", ".join(map(str, held))} at '
                     f'{"their" if len(held) > 1 else "its"} last command')
            else:
                _say(f'the {c.name} (pid {c.pid}) {why}{detail}: stopping the run')
                return EXIT_CONFIG if rc == EXIT_CONFIG else EXIT_FAILURE
        if a.timeout and time.monotonic() - t0 > a.timeout:
            _say(f'--timeout {a.timeout:g} s reached: stopping the run')
            return EXIT_FAILURE


def main(argv=None):
    """Entry point of the ``swarm`` executable."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        plan = plan_run(args)
    except ConfigError as exc:
        print(f'swarm: error: {exc}', file=sys.stderr)
        sys.exit(EXIT_CONFIG)
    code = run(plan)
    if plan.temporary_dir:
        if code == EXIT_OK and not args.keep_logs:
            shutil.rmtree(plan.run_dir, ignore_errors=True)
        else:
            _say(f'logs kept in {plan.run_dir}')
    sys.exit(code)


if __name__ == '__main__':
    main()
