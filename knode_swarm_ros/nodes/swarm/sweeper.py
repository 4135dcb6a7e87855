"""The sweeper: sweeps the run's FastDDS files when the launcher was killed before it could.

The living launcher sweeps at its end (:func:`.shm.shm_cleanup`); one killed by SIGKILL cannot,
and its children (SIGTERM from PR_SET_PDEATHSIG) sometimes leave their segments and ports (a stop
cut short under load). The launcher therefore starts this small process first: plain Python, no
DDS participant, no numpy, rclpy or torch (started by its path, so the package's ``__init__`` is
not imported), in its own session (a SIGKILL to the launcher's process group misses it).

The launcher writes one JSON object a line to its stdin: the FastDDS files present before the run
(``{"before": [...]}``), each process it starts (``{"pid": N}``) and, once it has swept itself,
``{"end": true}``. On ``end`` the sweeper exits at once. End of file without it means the launcher
died: the sweeper waits until every process of the run has ended (at most :data:`WAIT_S`), sweeps
with :func:`.shm.shm_cleanup` and the launcher's snapshot (the same rule: only files new since the
run's start that no live process holds a lock on, so nothing of another run is touched), says what
it removed, and exits. It writes no file.
"""

from __future__ import annotations

import argparse
import json
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable, Dict, Iterable, List, Optional, Tuple

if __package__:
    from . import shm
else:  # started by path (Sweeper.start): this folder is sys.path[0], shm.py needs only the stdlib
    import shm

__all__ = ['Sweeper', 'WAIT_S', 'read_orders', 'wait_for', 'sweep_after', 'main']

#: Seconds a killed launcher's processes get to end before the sweeper sweeps anyway (only files
#: no live process holds) and exits: they stop on SIGTERM within seconds, a hang must not keep it.
WAIT_S = 120.0
POLL_S = 0.2


class Sweeper:
    """The launcher's end of the sweeper: its pipe, which the sweeper alone reads."""

    def __init__(self, proc: subprocess.Popen):
        self.proc = proc

    @property
    def pid(self) -> int:
        return self.proc.pid

    @classmethod
    def start(cls, before: Iterable[str]) -> Optional['Sweeper']:
        """Start the sweeper with the snapshot ``before``; None if it cannot start (the run goes on
        without it)."""
        try:
            proc = subprocess.Popen(
                [sys.executable, str(Path(__file__).resolve()), '--shm-dir', str(shm.SHM_DIR)],
                stdin=subprocess.PIPE,
                stdout=None,  # its one line goes where the launcher's went
                stderr=None,
                start_new_session=True,  # survives a SIGKILL of the launcher's process group
                text=True,
            )
        except OSError:
            return None
        sweeper = cls(proc)
        sweeper._send({'before': sorted(before)})
        return sweeper

    def add(self, pid: int) -> None:
        """Tell the sweeper about a process of the run."""
        self._send({'pid': pid})

    def end(self) -> None:
        """The launcher has swept: the sweeper exits at once."""
        self._send({'end': True})
        self._close()
        try:
            self.proc.wait(timeout=2.0)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()

    def _send(self, order: dict) -> None:
        if self.proc.stdin is None or self.proc.stdin.closed:
            return
        try:
            self.proc.stdin.write(json.dumps(order) + '\n')
            self.proc.stdin.flush()
        except OSError:  # the sweeper is gone: nothing to tell
            self._close()

    def _close(self) -> None:
        try:
            self.proc.stdin.close()
        except OSError:
            pass


# --- the sweeper process ------------------------------------------------------------------------


def _start_time(pid: int) -> Optional[str]:
    """Start time of process ``pid`` (field 22 of /proc/<pid>/stat, so that a reused pid is not
    taken for it); None once it has ended (gone or a zombie)."""
    try:
        fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    except (OSError, IndexError):
        return None
    return None if fields[0] in ('Z', 'X') else fields[19]


def read_orders(lines: Iterable[str]) -> Tuple[Optional[set], Dict[int, str], bool]:
    """The snapshot (None if none came), the run's live processes (pid -> start time) and whether
    ``end`` came, read until ``end`` or the end of ``lines``. Lines that are not orders (one cut
    short by the launcher's death) are skipped."""
    before: Optional[set] = None
    procs: Dict[int, str] = {}
    for line in lines:
        try:
            order = json.loads(line)
        except ValueError:
            continue
        if not isinstance(order, dict):
            continue
        if order.get('end') is True:
            return before, procs, True
        if isinstance(order.get('before'), list):
            before = (before or set()) | {n for n in order['before'] if isinstance(n, str)}
        pid = order.get('pid')
        if isinstance(pid, int) and pid > 0:
            started = _start_time(pid)
            if started is not None:
                procs[pid] = started
    return before, procs, False


def wait_for(procs: Dict[int, str], seconds: float) -> List[int]:
    """Wait until every process of ``procs`` has ended, at most ``seconds``; returns those still
    running."""
    deadline = time.monotonic() + seconds
    while True:
        alive = [pid for pid, started in procs.items() if _start_time(pid) == started]
        if not alive or time.monotonic() >= deadline:
            return alive
        time.sleep(POLL_S)  # polling /proc: the run's processes are not our children


def sweep_after(
    before: set, procs: Dict[int, str], wait_s: float = WAIT_S, say: Callable[[str], None] = print
) -> List[str]:
    """What the sweeper does once the launcher has died without its ``end`` (see the module doc):
    wait for ``procs`` (:func:`read_orders`), sweep the files new since ``before``. Returns the
    names removed."""
    alive = wait_for(procs, wait_s)
    removed = shm.shm_cleanup(before)
    if removed or alive:
        still = (
            f'; {len(alive)} of its processes still ran after {wait_s:g} s (pids {alive})' if alive else ''
        )
        say(
            f'[swarm sweeper] the launcher ended without its clean-up: removed {len(removed)} FastDDS '
            f'shared-memory file(s) left by the run{still}'
        )
    return removed


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description='(started by the swarm launcher) ' + __doc__.splitlines()[0])
    parser.add_argument('--shm-dir', default=str(shm.SHM_DIR))
    parser.add_argument('--wait', type=float, default=WAIT_S)
    args = parser.parse_args(argv)
    shm.SHM_DIR = Path(args.shm_dir)
    for sig in (signal.SIGINT, signal.SIGTERM):  # a stray signal ends it quietly, whatever it inherited
        signal.signal(sig, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, (signal.SIGINT, signal.SIGTERM))

    def say(text: str) -> None:
        try:
            print(text, flush=True)
        except OSError:  # the launcher's output went with it
            pass

    before, procs, ended = read_orders(iter(sys.stdin.readline, ''))
    # Without the snapshot every FastDDS file would look new, other runs' too; the launcher died
    # before it had started anything.
    if not ended and before is not None:
        signal.alarm(int(args.wait) + 30)  # whatever hangs now, the sweeper ends (SIGALRM's default)
        sweep_after(before, procs, args.wait, say)
    return 0


if __name__ == '__main__':
    sys.exit(main())
