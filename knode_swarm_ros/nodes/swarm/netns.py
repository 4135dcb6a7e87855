"""Several "hosts" on one machine: Linux network namespaces joined by a bridge (needs root).

For the multi-host test and benchmark: :func:`virtual_hosts` creates ``n`` namespaces, each
with one veth interface and an address in a private /24, all plugged into a bridge that lives
in a namespace of its own (so the machine's own network is not touched and no traffic can
leave it), and removes every namespace on exit, whatever happens (deleting a namespace removes
its interfaces and the bridge with it). Processes run in a namespace with
``ip netns exec <name> <command>`` (:func:`wrap`). ``ip`` (iproute2) is the only tool used.
No rclpy here.
"""

from __future__ import annotations

import atexit
import os
import shutil
import signal
import subprocess
import threading
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Iterator, List, Sequence

__all__ = ['VirtualHost', 'virtual_hosts', 'wrap', 'NetnsUnavailable', 'remove']


class NetnsUnavailable(RuntimeError):
    """This machine refuses to create network namespaces (not root, no ``ip``, a kernel without them)."""


@dataclass
class VirtualHost:
    """A namespace ``name`` whose interface ``device`` has ``address`` (in ``subnet``)."""

    name: str
    device: str
    address: str
    subnet: str


def _ip(*args: str, check: bool = True) -> subprocess.CompletedProcess:
    proc = subprocess.run(['ip', *args], capture_output=True, text=True)
    if check and proc.returncode != 0:
        raise NetnsUnavailable(f"'ip {' '.join(args)}' failed: {(proc.stderr or proc.stdout).strip()}")
    return proc


def remove(names: Sequence[str]) -> None:
    """Delete the namespaces ``names`` (those that exist); never raises."""
    for name in names:
        subprocess.run(['ip', 'netns', 'delete', name], capture_output=True)


@contextmanager
def virtual_hosts(n: int, tag: str = '', subnet_byte: int = 0) -> Iterator[List[VirtualHost]]:
    """``n`` namespaces on a bridge, addresses ``10.213.<subnet_byte>.<1..n>/24``; removed on exit.

    Raises:
        NetnsUnavailable: the machine refuses (the message says what failed).
    """
    if shutil.which('ip') is None:
        raise NetnsUnavailable("the 'ip' command (iproute2) is not installed")
    if os.geteuid() != 0:
        raise NetnsUnavailable('creating network namespaces needs root (euid is not 0)')
    tag = tag or f'{os.getpid() % 100000}'
    byte = subnet_byte or (os.getpid() % 200 + 20)
    subnet = f'10.213.{byte}.0/24'
    switch = f'knsw{tag}'
    hosts = [VirtualHost(f'knh{tag}_{i}', f'kv{tag}_{i}', f'10.213.{byte}.{i + 1}', subnet) for i in range(n)]
    names = [switch] + [h.name for h in hosts]
    atexit.register(remove, names)  # even if the caller dies between here and the finally below
    # SIGTERM would end Python without the finally below or atexit: make it an exception meanwhile
    old_term = _raise_on_sigterm()
    try:
        _ip('netns', 'add', switch)
        _ip('-n', switch, 'link', 'add', 'br0', 'type', 'bridge')
        _ip('-n', switch, 'link', 'set', 'br0', 'up')
        _ip('-n', switch, 'link', 'set', 'lo', 'up')
        for i, h in enumerate(hosts):
            _ip('netns', 'add', h.name)
            # veth pair created inside the host namespace; its peer moves into the switch
            _ip(
                '-n',
                h.name,
                'link',
                'add',
                h.device,
                'type',
                'veth',
                'peer',
                'name',
                f'p{i}',
                'netns',
                switch,
            )
            _ip('-n', switch, 'link', 'set', f'p{i}', 'master', 'br0')
            _ip('-n', switch, 'link', 'set', f'p{i}', 'up')
            _ip('-n', h.name, 'addr', 'add', f'{h.address}/24', 'dev', h.device)
            _ip('-n', h.name, 'link', 'set', h.device, 'up')
            _ip('-n', h.name, 'link', 'set', 'lo', 'up')
            # DDS discovery multicasts (239.255.0.1): route multicast out of the veth
            _ip('-n', h.name, 'route', 'add', '224.0.0.0/4', 'dev', h.device)
        yield hosts
    finally:
        remove(names)
        atexit.unregister(remove)
        if old_term is not None:
            signal.signal(signal.SIGTERM, old_term)


def _raise_on_sigterm():
    """Turn SIGTERM into SystemExit (main thread only); returns the previous handler or None."""
    if threading.current_thread() is not threading.main_thread():
        return None
    previous = signal.getsignal(signal.SIGTERM)
    if previous not in (signal.SIG_DFL, None):
        return None  # someone handles it already

    def on_term(signum, _frame):
        raise SystemExit(128 + signum)

    signal.signal(signal.SIGTERM, on_term)
    return previous


def wrap(namespace: str, command: Sequence[str]) -> List[str]:
    """``command`` run inside ``namespace`` (``ip netns exec`` execs it: the pid is the command's)."""
    return ['ip', 'netns', 'exec', namespace, *command]
