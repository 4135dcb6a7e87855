"""Ctrl-C / SIGTERM while an executable is still importing: exit quietly with status 0.

Importing rclpy, the messages and torch takes a second or more; a signal then would print a
KeyboardInterrupt traceback (from every process of a swarm) although nothing has been started
that needs cleaning up: no ROS context, no DDS participant, no file. The ``nodes`` package calls
:func:`quiet_until_running` when it is imported, which in a node executable happens before the
node module is even compiled; :func:`executor.run_node` replaces the handlers before
``rclpy.init``. Imports nothing heavy (this must be fast). What comes before the package import
(interpreter start, site) is not covered: a SIGTERM there takes its default action (a silent
end), a SIGINT may still print a KeyboardInterrupt.
"""

import os
import signal
import sys

__all__ = ['quiet_until_running', 'started_as_program']

_PROGRAMS = ('agent', 'agents', 'simulator', 'recorder', 'monitor')


def started_as_program() -> bool:
    """Whether this process is one of the node executables (``python -m
    knode_swarm_ros.nodes.<node>`` or its console script), not another program that imports
    them (a test, the launcher)."""
    argv = list(getattr(sys, 'orig_argv', None) or [])
    modules = {f'knode_swarm_ros.nodes.{name}' for name in _PROGRAMS}
    if any(a == '-m' and b in modules for a, b in zip(argv, argv[1:])):
        return True
    return os.path.basename(sys.argv[0] if sys.argv else '') in _PROGRAMS


def _leave(_signum, _frame) -> None:
    os._exit(0)  # nothing to clean up yet; no traceback


def quiet_until_running() -> None:
    """Make SIGINT and SIGTERM end the process silently (status 0) until run_node takes over,
    in a node executable only (idempotent)."""
    if started_as_program():
        signal.signal(signal.SIGINT, _leave)
        signal.signal(signal.SIGTERM, _leave)
