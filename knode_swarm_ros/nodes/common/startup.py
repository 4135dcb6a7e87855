"""Ctrl-C / SIGTERM while an executable is still starting: exit quietly with status 0.

Importing rclpy, the messages and torch takes a second or more; a signal then would print a
KeyboardInterrupt traceback (from every process of a swarm) although nothing has been started
that needs cleaning up: no ROS context, no DDS participant, no file. Each executable's ``main``
calls :func:`quiet_until_running` first; :func:`executor.run_node` replaces the handlers before
``rclpy.init``. Imports nothing heavy (this must be fast).

Before ``main`` runs, Python itself starts (site, the ros wheels' re-exec with their library
path, the import of the package): a SIGINT there raises KeyboardInterrupt in code no module of
this package can reach (a traceback, or "Fatal Python error: init_import_site"). A parent that
starts a node (the launcher, the tests) therefore starts it with SIGINT and SIGTERM blocked
(:func:`block_stop_signals` as ``preexec_fn``): a signal that arrives then stays pending, and
:func:`quiet_until_running` unblocks it once its quiet handler is in. A node started by hand
from a shell keeps that first window (Python's start, ~0.1 s).
"""

import os
import signal
import sys

__all__ = [
    'STOP_SIGNALS',
    'block_stop_signals',
    'note_stop_signals',
    'quiet_until_running',
    'started_as_launcher',
    'started_as_program',
]

_PROGRAMS = ('agent', 'agents', 'simulator', 'recorder', 'monitor', 'lifecycle_manager')
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def started_as_program() -> bool:
    """Whether this process is one of the node executables (``python -m
    knode_swarm_ros.nodes.<node>`` or its console script), not another program that imports
    them (a test, the launcher)."""
    argv = list(getattr(sys, 'orig_argv', None) or [])
    modules = {f'knode_swarm_ros.nodes.{name}' for name in _PROGRAMS}
    if any(a == '-m' and b in modules for a, b in zip(argv, argv[1:])):
        return True
    return os.path.basename(sys.argv[0] if sys.argv else '') in _PROGRAMS


def started_as_launcher() -> bool:
    """Whether this process is the ``swarm`` launcher (``python -m knode_swarm_ros.nodes.swarm``
    or its console script)."""
    argv = list(getattr(sys, 'orig_argv', None) or [])
    if any(a == '-m' and b == 'knode_swarm_ros.nodes.swarm' for a, b in zip(argv, argv[1:])):
        return True
    return os.path.basename(sys.argv[0] if sys.argv else '') == 'swarm'


_noted: list = []


def _note(signum, _frame) -> None:
    _noted.append(signum)


def note_stop_signals(carry: bool = False) -> list:
    """From now on SIGINT, SIGTERM and SIGHUP are appended to the list returned instead of
    raising KeyboardInterrupt wherever the main thread is; with ``carry``, the list holds those
    noted since an earlier call already. For the launcher, which acts on them once its own
    handlers are in: a user starts it from a shell, with nothing blocked, and its imports and
    checks take a second or more (the policy's ``import torch`` even swallows a KeyboardInterrupt
    raised inside it)."""
    global _noted
    _noted = list(_noted) if carry else []
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, _note)
    return _noted


def block_stop_signals() -> None:
    """Block SIGINT and SIGTERM in this thread: for a child between fork and exec, so that a
    signal during its interpreter start waits for :func:`quiet_until_running` (the mask survives
    exec; Python's start-up leaves it alone)."""
    signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)


def _leave(_signum, _frame) -> None:
    os._exit(0)  # nothing to clean up yet; no traceback


def quiet_until_running() -> None:
    """Make SIGINT and SIGTERM end the process silently (status 0) until run_node takes over,
    in a node executable only (idempotent); then unblock them, so that one that arrived while
    the parent had them blocked (:func:`block_stop_signals`) ends the process here."""
    if started_as_program():
        signal.signal(signal.SIGINT, _leave)
        signal.signal(signal.SIGTERM, _leave)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)
