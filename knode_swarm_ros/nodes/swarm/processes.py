"""The launcher's child processes: start one node, pump every output into its log (and echo
problems), stop them (SIGTERM, then SIGKILL). No rclpy here."""

from __future__ import annotations

import os
import re
import selectors
import signal
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Dict, List, Optional, Sequence, Tuple

from ..common.startup import block_stop_signals

__all__ = ['Child', 'Children', 'start_child', 'Interrupted', 'catches_signal']

# SIGTERM first: the nodes treat it as Ctrl-C once running (the recorder saves), and a process
# still importing ends silently (a SIGINT there could print a KeyboardInterrupt traceback).
_STOP_SIGNALS = ((signal.SIGTERM, 8.0), (signal.SIGKILL, 10.0))
_ECHO_RE = re.compile(r'\[(WARN|WARNING|ERROR|FATAL)\]|Traceback|error:', re.IGNORECASE)


class Interrupted(Exception):
    """Ctrl-C / SIGTERM / SIGHUP reached the launcher (raised by Children.pump)."""


def _child_setup() -> None:  # runs in the child between fork and exec
    # A stop signal during the child's interpreter start waits for its quiet handler.
    block_stop_signals()
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
    marker: str = ''  # a log line fragment that says the process is past its checks
    marked: bool = False
    watch: Tuple[str, ...] = ()  # log line fragments whose latest line is kept in ``seen``
    seen: Dict[str, str] = field(default_factory=dict)

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
            for fragment in self.watch:
                if fragment in line:
                    self.seen[fragment] = line
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
_STARTED = {
    'simulator': ' robots, ',
    'recorder': ': recording ',
    'agent': 'publishing ',
    'agents': ' hosted) of ',
    'monitor': 'watching ',
}

#: What the supervisor needs to know of a node's progress: the simulator running, then done (its
#: last step), the recorder's file written (with '(interrupted)' when a signal stopped it).
WATCH = {'simulator': (' s: running', 'done: '), 'recorder': ('wrote ',)}


def start_child(name: str, cmd: Sequence[str], env: Dict[str, str], run_dir: Path, echo: str) -> Child:
    log_path = run_dir / f'{name}.log'
    proc = subprocess.Popen(
        list(cmd),
        env=env,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        start_new_session=True,
        preexec_fn=_child_setup,
        cwd=str(run_dir),
    )
    os.set_blocking(proc.stdout.fileno(), False)
    kind = name.split('_')[0]
    return Child(
        name, proc, log_path, open(log_path, 'wb'), echo, marker=_STARTED[kind], watch=WATCH.get(kind, ())
    )


class Children:
    """The node processes, their output pumped into logs (and echoed) with one selector."""

    def __init__(self, on_add: Optional[Callable[[int], None]] = None):
        self.items: Dict[str, Child] = {}
        self.on_add = on_add  # told each new process's pid (the sweeper)
        self.selector = selectors.DefaultSelector()
        self.interrupted = False  # set by the launcher's signal handler; pump() raises Interrupted

    def add(self, child: Child) -> None:
        self.items[child.name] = child
        if self.on_add is not None:
            self.on_add(child.pid)
        self.selector.register(child.proc.stdout, selectors.EVENT_READ, child)

    def pump(self, timeout: float) -> None:
        if self.interrupted:
            raise Interrupted()
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


def catches_signal(pid: int, sig: int = signal.SIGTERM) -> bool:
    """Whether process ``pid`` handles ``sig`` itself (``SigCgt`` in /proc/<pid>/status): before
    the package's start-up handler exists (interpreter start and site) SIGTERM kills silently and
    SIGINT raises KeyboardInterrupt. False once the process is gone."""
    try:
        with open(f'/proc/{pid}/status') as fh:
            caught = next(int(line.split()[1], 16) for line in fh if line.startswith('SigCgt:'))
    except (OSError, StopIteration):
        return False
    return bool(caught & (1 << (sig - 1)))
