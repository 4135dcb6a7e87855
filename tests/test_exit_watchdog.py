"""nodes.exit_watchdog: once armed, the process ends with the given status even when its main
thread is stuck in native code that keeps the GIL (as rclpy's teardown calls do), and what
Python had buffered for stdout is not lost.

Each case runs in a child process (arming ends the process). The hang is a ``pause()`` called
through ``ctypes.PyDLL``, which keeps the GIL: no Python thread, and no Python signal handler,
can run. The deadlines waited for here only bound a hang of the harness; no timing is asserted.
"""

import subprocess
import sys

WAIT_S = 120  # generous: only a hang fails

_CHILD = """
import ctypes, sys, time
from knode_swarm_ros.nodes.common import exit_watchdog
if {no_native}:
    exit_watchdog._native_exit_after = lambda code, seconds: False
print('saved', end='')  # stdout is a pipe: block-buffered, not flushed by this line
exit_watchdog.arm({code}, 0.3)
def stuck_in_native():
    while True:
        if {gil}:
            ctypes.PyDLL(None).pause()  # in C with the GIL held: nothing in Python can run
        else:
            time.sleep(3600)
stuck_in_native()
"""


def _run(code: int, gil: bool, no_native: bool = False):
    return subprocess.run(
        [sys.executable, '-c', _CHILD.format(code=code, gil=gil, no_native=no_native)],
        capture_output=True,
        text=True,
        timeout=WAIT_S,
    )


def test_a_hang_in_native_code_holding_the_gil_ends_with_the_armed_status():
    for code in (0, 7):
        proc = _run(code, gil=True)
        assert proc.returncode == code, proc.stdout + proc.stderr
        assert proc.stdout == 'saved'  # flushed when armed
        # faulthandler's dump before the end says where the main thread was stuck
        assert 'stuck_in_native' in proc.stderr, proc.stderr


def test_without_timer_create_a_thread_ends_a_hang_that_frees_the_gil():
    proc = _run(5, gil=False, no_native=True)
    assert proc.returncode == 5, proc.stdout + proc.stderr
    assert proc.stdout == 'saved'
