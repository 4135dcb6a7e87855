"""Node processes for the tests that start ROS nodes as children and stop them by signal.

``start`` runs ``python ARGV`` as the launcher starts a node (SIGINT and SIGTERM blocked until its
quiet handler is in) with the test's environment (a copy: the ros-jazzy wheels'
LD_LIBRARY_PATH / _ROS_WHEELS_BOOTSTRAP_COMPLETE pair travels together, conftest.py), ``wait_for``
polls its log for a line, ``stop`` sends a signal (or none) and waits. ``WAIT_S`` bounds every
wait generously: only a hang fails, never a slow machine.
"""

import os
import subprocess
import sys
import time

from knode_swarm_ros.nodes.common.startup import block_stop_signals

WAIT_S = 120


def start(argv, log):
    """``python *argv`` in its own session, stdout and stderr to the open file ``log``."""
    env = dict(os.environ, PYTHONUNBUFFERED='1', OMP_NUM_THREADS='1')
    return subprocess.Popen(
        [sys.executable, *argv],
        env=env,
        stdout=log,
        stderr=subprocess.STDOUT,
        start_new_session=True,
        preexec_fn=block_stop_signals,  # as the launcher does: a signal waits for the quiet handler
    )


def wait_for(proc, log_path, text):
    """Poll until ``text`` is in the log at ``log_path`` while ``proc`` runs (assert it got there)."""
    deadline = time.monotonic() + WAIT_S
    while (
        time.monotonic() < deadline
        and proc.poll() is None
        and text not in log_path.read_text(errors='replace')
    ):
        time.sleep(0.05)
    assert proc.poll() is None and text in log_path.read_text(errors='replace'), log_path.read_text(
        errors='replace'
    )


def stop(proc, sig=None):
    """Send ``sig`` (None: none) and return the exit status; a process still there after
    ``WAIT_S`` is killed (and the caller's status check fails)."""
    if sig is not None:
        proc.send_signal(sig)
    try:
        return proc.wait(timeout=WAIT_S)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
