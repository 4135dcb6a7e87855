"""A SIGINT at each moment of an executable's first 2 s: exit 0 or 130, never a traceback.

    python bench/early_signal.py                                   # every 20 ms over 0-1.98 s: 100 starts each
    python bench/early_signal.py --programs recorder,swarm --step 0.1

Each node executable (agent, agents, simulator, recorder, monitor) is started as the launcher
starts it (``processes.start_child``: SIGINT and SIGTERM blocked until its quiet handler is in);
the launcher itself (``swarm``) as a shell starts it, with nothing blocked. One start per moment:
SIGINT ``delay`` s after the start, then the exit status and the output are checked (status 0
or 130, or -2: ended by SIGINT's default action before Python has a handler, which a shell
reports as 130; no ``Traceback``, ``KeyboardInterrupt`` or ``Fatal Python error``). A process
still there after 120 s counts as a hang.

Prints, per program, the starts that passed of those made, and each failure (moment, status,
the first lines of its output), with the command line, the machine and the load.
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Dict, List, Optional, Tuple

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from knode_swarm_ros.nodes.swarm.processes import catches_signal, start_child  # noqa: E402

PROGRAMS = ('agent', 'agents', 'simulator', 'recorder', 'monitor', 'swarm')
WAIT_S = 120
_BAD = ('Traceback', 'KeyboardInterrupt', 'Fatal Python error')


def command(program: str, policy: Path, out_dir: Path) -> List[str]:
    """The command line of ``program``: a small swarm's parameters (robots 2, the given policy)."""
    if program == 'swarm':
        return [sys.executable, '-m', 'knode_swarm_ros.nodes.swarm', '--robots', '2', '--steps', '100']
    params = {
        'agent': ['id:=0', 'robots:=2', f'policy:={policy}'],
        'agents': ['ids:=[0,1]', 'robots:=2', f'policy:={policy}'],
        'simulator': ['robots:=2', 'mode:=realtime', 'steps:=0', 'wait_for_agents:=false'],
        'recorder': ['robots:=2', f'output:={out_dir / "rec.npz"}'],
        'monitor': ['robots:=2', 'port:=0'],
    }[program]
    argv = [sys.executable, '-m', f'knode_swarm_ros.nodes.{program}', '--ros-args']
    for p in params:
        argv += ['-p', p]
    return argv


def environment(env: Optional[Dict[str, str]] = None) -> Dict[str, str]:
    env = dict(os.environ if env is None else env, PYTHONUNBUFFERED='1', OMP_NUM_THREADS='1')
    env.pop('_ROS_WHEELS_BOOTSTRAP_COMPLETE', None)  # the wheels' re-exec is part of the start
    return env


def signal_at(
    program: str, delay: float, policy: Path, work: Path, env: Dict[str, str], from_handler: bool = False
) -> Tuple[int, str]:
    """Start ``program``, SIGINT it ``delay`` s later (``from_handler``: after its first handler of
    this package is in, i.e. after Python's own start): ``(exit status, output)`` (None: hung)."""
    argv = command(program, policy, work)
    if program == 'swarm':  # as from a shell: nothing blocked
        log = open(work / 'swarm.log', 'wb')
        proc = subprocess.Popen(
            argv
            + ['--policy', str(policy), '--record', str(work / 'run.npz'), '--log-dir', str(work / 'logs')]
            + ['--no-figure'],
            env=env,
            stdin=subprocess.DEVNULL,
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
            cwd=str(work),
        )
        read = lambda: (work / 'swarm.log').read_text(errors='replace')  # noqa: E731
    else:
        name = {'agent': 'agent_0', 'agents': 'agents_0'}.get(program, program)
        child = start_child(name, argv, env, work, 'none')
        proc, log = child.proc, child.log
        chunks: List[bytes] = []

        def read() -> str:
            while True:
                try:
                    chunk = proc.stdout.read()
                except (BlockingIOError, ValueError):
                    chunk = None
                if not chunk:
                    return b''.join(chunks).decode(errors='replace')
                chunks.append(chunk)

    try:
        while from_handler and proc.poll() is None and not catches_signal(proc.pid, signal.SIGTERM):
            time.sleep(0.001)
        time.sleep(delay)
        proc.send_signal(signal.SIGINT)
        try:
            rc = proc.wait(timeout=WAIT_S)
        except subprocess.TimeoutExpired:
            rc = None
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        log.close()
    return rc, read()


def verdict(rc: Optional[int], text: str) -> Optional[str]:
    """None when the stop was as documented, else why not."""
    if rc is None:
        return 'hung'
    if rc not in (0, 130, -signal.SIGINT):
        return f'status {rc}'
    bad = [b for b in _BAD if b in text]
    return f'status {rc}, output has {", ".join(bad)}' if bad else None


def untrained_policy(path: Path) -> Path:
    import torch

    from knode_swarm_ros.core import DEFAULTS, KNODEPolicy, PolicyConfig, export_policy

    torch.manual_seed(0)
    policy = KNODEPolicy(PolicyConfig('flock2d', **DEFAULTS['flock2d']))
    export_policy(policy, path, policy.metadata())
    return path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--programs', default=','.join(PROGRAMS))
    ap.add_argument('--step', type=float, default=0.02, help='seconds between sampled moments')
    ap.add_argument('--until', type=float, default=2.0, help='sample moments in [0, UNTIL)')
    a = ap.parse_args(argv)
    from knode_swarm_ros.nodes.swarm.domains import claim_domain

    claim = claim_domain(range(30, 102))
    env = environment(dict(os.environ, ROS_DOMAIN_ID=str(claim.domain_id)))
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env['PYTHONPATH'] = os.pathsep.join([str(REPO)] + [p for p in [os.environ.get('PYTHONPATH')] if p])
    tmp = Path(tempfile.mkdtemp(prefix='early_signal_'))
    policy = untrained_policy(tmp / 'flock2d.pt')
    moments = [round(i * a.step, 3) for i in range(int(round(a.until / a.step)))]
    started = time.time()
    print(
        f'# early_signal {datetime.datetime.utcnow():%Y-%m-%d %H:%M} UTC on {platform.machine()} '
        f'({os.cpu_count()} cores, load {os.getloadavg()[0]:.1f}); {len(moments)} moments every '
        f'{a.step * 1000:.0f} ms; command: {" ".join([sys.executable] + sys.argv)}',
        flush=True,
    )
    failed = 0
    for program in a.programs.split(','):
        fails = []
        t0 = time.monotonic()
        for i, delay in enumerate(moments):
            work = tmp / f'{program}_{i}'
            work.mkdir()
            rc, text = signal_at(program, delay, policy, work, env)
            why = verdict(rc, text)
            if why:
                fails.append((delay, why, text.strip().splitlines()[-3:]))
        failed += len(fails)
        print(
            f'{program:9s}: {len(moments) - len(fails)} of {len(moments)} exited 0 or 130 without a '
            f'traceback ({time.monotonic() - t0:.0f} s, load {os.getloadavg()[0]:.1f})',
            flush=True,
        )
        for delay, why, lines in fails:
            print(f'  at {delay:.2f} s: {why}\n    ' + '\n    '.join(lines), flush=True)
    claim.release()
    print(f'# {time.time() - started:.0f} s in all, load {os.getloadavg()[0]:.1f} at the end', flush=True)
    return 1 if failed else 0


if __name__ == '__main__':
    sys.exit(main())
