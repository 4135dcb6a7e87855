"""Chaos run: kill or stop a random process of a running swarm, then check that nothing broke.

    python bench/chaos.py                      # 100 kills, seed 0
    python bench/chaos.py --kills 20 --seed 3 --minutes 15

Two swarms take turns: 100 robots in lockstep hosted 25 to a process (``swarm
--agents-per-process 25``) and 10 robots in realtime, one agent process each. Each round a driver
sends SIGKILL, SIGINT or SIGTERM to one process (an agent process, the recorder, the simulator or
the launcher itself) at a random wall moment of the run (seeded), and then checks
(:func:`check_round`):

* the launcher's report names what died and how (its pid, the signal or the exit status);
* every process of the run has ended within its timeout, the launcher's sweeper too (after a
  launcher's SIGKILL it sweeps once the others have ended: leftovers are counted after it);
* the exit status is the documented one (``swarm``: 0 done, 1 failed, 3 done but an agent died,
  130 interrupted; -9 for a launcher killed by SIGKILL, which reports nothing);
* no FastDDS shared-memory file of the run is left: none of the segments and ports its processes
  held (read from /proc/locks while they ran) without a live owner, no port file of its domain;
* the recording is complete and valid (``load_trajectories``) or absent with the sentinel file
  written there before the run intact; no temporary file beside it; where an agent process died
  mid-run, the file's meta ``silent`` names its robots (lockstep; in realtime once the simulator
  has stopped them, command_timeout later: an agent killed in the run's last half second is not).

Prints one line per round and the figures (kills by target and signal, outcomes, leftovers).
"""

from __future__ import annotations

import argparse
import collections
import datetime
import json
import os
import platform
import random
import re
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from knode_swarm_ros.core.trajectory import TrajectoryError, load_trajectories  # noqa: E402
from knode_swarm_ros.nodes.swarm.shm import shm_left_by, shm_lock_holders, shm_snapshot  # noqa: E402

SENTINEL = b'chaos sentinel: the file that was here before the run\n'
SIGNALS = (signal.SIGKILL, signal.SIGINT, signal.SIGTERM)
TARGETS = ('agent', 'recorder', 'simulator', 'launcher')
END_S = 240.0  # wall seconds for the launcher (or, killed, its children) to end: only a hang fails


@dataclass(frozen=True)
class Swarm:
    """A swarm of the chaos run: its ``swarm`` arguments and its expected wall duration."""

    name: str
    args: tuple
    seconds: float  # about how long a run takes on a loaded 2-core machine (start-up included)


SWARMS = {
    'hosted': Swarm('hosted', ('--robots', 100, '--agents-per-process', 25, '--steps', 300), 28.0),
    'lone': Swarm('lone', ('--robots', 10, '--mode', 'realtime', '--steps', 600), 35.0),
}


@dataclass
class Round:
    """One kill and what followed."""

    swarm: str
    target: str  # 'agent', 'recorder', 'simulator' or 'launcher'
    sig: str
    at_s: float = 0.0  # wall seconds after the launcher started
    process: str = ''  # the name of the process signalled (agent_3, agents_25_49, ...)
    phase: str = ''  # 'starting', 'running' or 'ended' (the target had already ended: no kill)
    rc: Optional[int] = None
    recording: str = ''  # 'valid', 'absent' (sentinel intact) or what is wrong
    problems: List[str] = field(default_factory=list)


def launcher_command(swarm: Swarm, record: Path, log_dir: Path, domain: Optional[int]) -> List[str]:
    cmd = [sys.executable, '-m', 'knode_swarm_ros.nodes.swarm', '--record', str(record)]
    cmd += ['--log-dir', str(log_dir), '--keep-logs', '--no-figure', '--quiet']
    cmd += ['--domain-id', str(domain)] if domain is not None else []
    return cmd + [str(a) for a in swarm.args]


def _read(path: Path) -> str:
    try:
        return path.read_text(errors='replace')
    except OSError:
        return ''


def _pids(log_dir: Path) -> Dict[str, int]:
    try:
        return json.loads((log_dir / 'pids.json').read_text())
    except (OSError, ValueError):
        return {}


def _sweeper_pid(log_dir: Path) -> Optional[int]:
    """The launcher's sweeper (``swarm/sweeper.py``), which outlives a killed launcher."""
    try:
        return int((log_dir / 'sweeper.pid').read_text())
    except (OSError, ValueError):
        return None


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:  # a zombie (ended, not yet reaped by its parent) has ended
        return Path(f'/proc/{pid}/stat').read_text().split(')')[-1].split()[0] != 'Z'
    except OSError:
        return False


def run_round(
    swarm: Swarm,
    target: str,
    sig: signal.Signals,
    moment: float,
    rng: random.Random,
    work: Path,
    domain: Optional[int] = None,
    when_running: bool = False,
    also: Optional[str] = None,
) -> Round:
    """Start ``swarm``, signal one ``target`` process ``moment`` wall seconds after the launcher
    started (once the run is running with ``when_running``), wait for the end, check it. ``also``:
    a process of the run killed by SIGKILL right after the target (a stop cut short, as under
    load), which leaves its FastDDS files for the launcher (or its sweeper) to remove."""
    work.mkdir(parents=True, exist_ok=True)
    record, log_dir = work / 'run.npz', work / 'logs'
    record.write_bytes(SENTINEL)
    shm_before = shm_snapshot()
    out_path = work / 'launcher.out'
    env = dict(os.environ, PYTHONUNBUFFERED='1', ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    r = Round(swarm.name, target, sig.name)
    with open(out_path, 'wb') as out:
        launcher = subprocess.Popen(
            launcher_command(swarm, record, log_dir, domain),
            env=env,
            stdout=out,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            start_new_session=True,
        )
    t0 = time.monotonic()
    sim_log = log_dir / 'simulator.log'
    held: set = set()  # the FastDDS lock files the run's processes held (their segments, ports)
    shared: set = set()  # those of them that a process outside the run held too (a port of all domains)
    try:
        pids: Dict[str, int] = {}
        while launcher.poll() is None and time.monotonic() - t0 < END_S:
            pids = pids or _pids(log_dir)
            if int((time.monotonic() - t0) * 20) % 10 == 0:  # every half second or so
                _sample_locks(set(pids.values()), held, shared)
            running = ': running' in _read(sim_log)
            due = time.monotonic() - t0 >= moment and (running or not when_running)
            if due and (target == 'launcher' or pids):
                break
            time.sleep(0.05)  # polling the run's own files for a condition
        r.phase = 'running' if ': running' in _read(sim_log) else 'starting'
        if target == 'launcher':
            r.process, victim = 'swarm', launcher.pid
        else:
            names = [n for n in pids if n.startswith('agent')] if target == 'agent' else [target]
            r.process = rng.choice(names) if names else target
            victim = pids.get(r.process)
        r.at_s = time.monotonic() - t0
        if victim is None or launcher.poll() is not None or not _alive(victim):
            r.phase = 'ended'
        else:
            os.kill(victim, sig)
            if also and pids.get(also) and _alive(pids[also]):
                os.kill(pids[also], signal.SIGKILL)
        try:
            r.rc = launcher.wait(timeout=END_S)
        except subprocess.TimeoutExpired:
            r.problems.append(f'the launcher still ran {END_S:g} s after the kill')
        pids = pids or _pids(log_dir)
        sweeper = _sweeper_pid(log_dir)
        waited = {**pids, **({'sweeper': sweeper} if sweeper else {})}  # it sweeps after them
        deadline = time.monotonic() + (END_S if r.rc == -signal.SIGKILL else 5.0)
        while time.monotonic() < deadline and any(_alive(p) for p in waited.values()):
            _sample_locks(set(pids.values()), held, shared)
            time.sleep(0.1)  # a killed launcher's children stop on their own (PR_SET_PDEATHSIG)
        left = [f'{n} ({p})' for n, p in waited.items() if _alive(p)]
        if left:
            r.problems.append(f'processes still running: {left}')
    finally:
        for pid in [launcher.pid, *_pids(log_dir).values(), *filter(None, [_sweeper_pid(log_dir)])]:
            if _alive(pid):
                try:
                    os.kill(pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
        launcher.poll()
    check_round(r, _read(out_path), record, log_dir, shm_before, held - shared)
    return r


def _sample_locks(run: set, held: set, shared: set) -> None:
    """Add the FastDDS lock files that the ``run``'s pids hold now to ``held``, and those that a
    process outside the run holds too to ``shared``: the ports every domain opens (7000...) are
    shared with a concurrent suite, whose killed process may be the last to hold one, so a file
    left there is not the run's."""
    for name, pids in shm_lock_holders().items():
        if pids & run:
            held.add(name)
            if pids - run:
                shared.add(name)


def expected_status(r: Round) -> tuple:
    """The documented exit statuses of the launcher after ``r``'s kill."""
    if r.phase == 'ended':
        return (0, 1, 3)  # nothing was killed (the run had ended): whatever it ended with
    if r.target == 'launcher':
        return (-signal.SIGKILL,) if r.sig == 'SIGKILL' else (130,)
    if r.target == 'agent':
        return (3,) if r.phase == 'running' else (1, 3)  # (the run may have started meanwhile)
    return (1,)


def check_round(r: Round, out: str, record: Path, log_dir: Path, shm_before: set, held: set) -> None:
    """Append to ``r.problems`` what the run did wrong (see the module doc)."""
    if r.rc is not None and r.rc not in expected_status(r):
        r.problems.append(f'exit status {r.rc}, expected {expected_status(r)}')
    pid = (_pids(log_dir).get(r.process) if r.target != 'launcher' else None) or 0
    if r.phase != 'ended' and not (r.target == 'launcher' and r.sig == 'SIGKILL'):
        if r.target == 'launcher':
            named = f'{r.sig}: stopping every process' in out
        else:
            hows = (f'killed by {r.sig}', 'exited with status')
            named = f'(pid {pid})' in out and r.process in out and any(h in out for h in hows)
        if not named:
            r.problems.append(f'the report does not name {r.process} (pid {pid}) and how it ended')
    r.recording = _check_recording(r, record)
    if r.recording not in ('valid', 'absent'):
        r.problems.append(f'recording: {r.recording}')
    left = leftovers(shm_before, held, _domain(out, log_dir))
    if left:
        r.problems.append(f'shared-memory files left: {left}')


def _domain(out: str, log_dir: Path) -> Optional[int]:
    m = re.search(r'ROS_DOMAIN_ID=(\d+)', out)
    return int(m.group(1)) if m else None


def _check_recording(r: Round, record: Path) -> str:
    strays = [p.name for p in record.parent.iterdir() if record.name in p.name and p != record]
    if strays:
        return f'temporary files beside it: {strays}'
    try:
        if record.read_bytes() == SENTINEL:
            return 'absent'
    except OSError:
        return 'missing, and the sentinel with it'
    try:
        data = load_trajectories(record)
    except TrajectoryError as exc:
        return f'corrupt: {exc}'
    if r.target == 'agent' and r.phase == 'running' and r.rc == 3:
        m = re.match(r'agents?_(\d+)(?:_(\d+))?$', r.process)
        robots = set(range(int(m.group(1)), int(m.group(2) or m.group(1)) + 1))
        silent = {int(k) for k in data.meta.get('silent', {})}
        if not robots <= silent:
            return f'meta silent {sorted(silent)} does not name the robots of {r.process}'
    return 'valid'


def leftovers(before: set, held: set, domain: Optional[int]) -> List[str]:
    """FastDDS files of the run left behind: those of the groups whose lock files its processes
    held (``held``, from /proc/locks while they ran: files of a concurrent suite's processes never
    count) that no live process holds now, and any new port file of the run's ``domain``."""
    left = set(shm_left_by(held, domain, frozenset(before)))
    if domain is not None:
        ours = range(7400 + 250 * domain, 7400 + 250 * (domain + 1))
        for name in shm_snapshot() - before:
            port = re.match(r'(?:sem\.)?fastrtps_port(\d+)', name)
            if port and int(port.group(1)) in ours:
                left.add(name)
    return sorted(left)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    p.add_argument('--kills', type=int, default=100, help='rounds whose target was still running')
    p.add_argument('--seed', type=int, default=0)
    p.add_argument('--minutes', type=float, default=0.0, help='stop starting rounds after this (0: none)')
    p.add_argument('--swarms', default='hosted,lone')
    p.add_argument('--work', help='folder for the runs (default: a temporary one)')
    args = p.parse_args(argv)
    rng = random.Random(args.seed)
    swarms = [SWARMS[s] for s in args.swarms.split(',')]
    work = Path(args.work or tempfile.mkdtemp(prefix='chaos_'))
    started = datetime.datetime.now(datetime.timezone.utc)
    load0 = os.getloadavg()
    t0 = time.monotonic()
    rounds: List[Round] = []
    i = 0
    while sum(r.phase != 'ended' for r in rounds) < args.kills:
        if args.minutes and time.monotonic() - t0 > args.minutes * 60:
            break
        swarm = swarms[i % len(swarms)]
        target, sig = rng.choice(TARGETS), rng.choice(SIGNALS)
        moment = rng.uniform(0.0, swarm.seconds)
        r = run_round(swarm, target, sig, moment, rng, work / f'round_{i:03d}')
        rounds.append(r)
        print(
            f'{i:3d} {r.swarm:6s} {r.sig:7s} {r.process:14s} at {r.at_s:5.1f} s ({r.phase}): rc {r.rc}, '
            f'recording {r.recording}' + (f'; PROBLEMS: {r.problems}' if r.problems else ''),
            flush=True,
        )
        i += 1
    report(rounds, started, load0, os.getloadavg(), time.monotonic() - t0, args)
    return 1 if any(r.problems for r in rounds) else 0


def report(rounds, started, load0, load1, seconds, args) -> None:
    kills = collections.Counter((r.target, r.sig) for r in rounds if r.phase != 'ended')
    print(
        f'\nchaos run, seed {args.seed}: {len(rounds)} rounds in {seconds / 60:.1f} min, {started:%Y-%m-%d %H:%M} UTC'
    )
    print(
        f'machine: {platform.machine()}, {os.cpu_count()} cores; load average {load0[0]:.1f} -> {load1[0]:.1f}'
    )
    for target in TARGETS:
        row = ', '.join(f'{s.name} {kills[(target, s.name)]}' for s in SIGNALS)
        print(f'  {target:10s} {row}')
    print(f'  target already ended (no kill): {sum(r.phase == "ended" for r in rounds)}')
    outcomes = collections.Counter((r.rc, r.recording) for r in rounds)
    for (rc, rec), n in sorted(outcomes.items(), key=lambda kv: str(kv[0])):
        print(f'  exit {rc}, recording {rec}: {n}')
    bad = [r for r in rounds if r.problems]
    print(f'handled as documented: {len(rounds) - len(bad)} of {len(rounds)}')
    left = sum(any('shared-memory' in p for p in r.problems) for r in rounds)
    print(f'rounds with leftover shared-memory files: {left}')


if __name__ == '__main__':
    sys.exit(main())
