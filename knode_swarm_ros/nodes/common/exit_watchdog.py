"""A deadline on a node's clean-up: once nothing is left to save, the process ends in time.

After ``on_exit`` has run (the recorder's file written and closed), what is left of a node's
exit is native code: detaching it from the EventsExecutor, destroying it and the context (the
DDS participant). That once hung (the recorder, file written, in a suite run beside a second
one: SIGTERM ignored for 8 s, then SIGKILL, launcher status 1). Nothing in Python can end such
a hang: a signal's Python handler runs only between the main thread's bytecodes, and rclpy's
native calls keep the GIL, so no Python thread runs either. :func:`arm` therefore sets a POSIX
timer whose expiry glibc hands to a fresh native thread (``SIGEV_THREAD``) that calls
``_exit(code)`` itself, GIL or not. Python's buffers are flushed when it is armed, and
faulthandler dumps every thread's stack shortly before it fires (where the clean-up hung).
Without ``timer_create`` (not glibc) a daemon thread does the same whenever the GIL is free.
No rclpy here.
"""

import ctypes
import faulthandler
import os
import sys
import threading
from typing import Optional

__all__ = ['arm', 'flush_std', 'TEARDOWN_S']

#: The clean-up after on_exit takes well under 0.1 s (stop p50 0.22 s including the 0.25 s spin
#: slice, bench_shutdown); this leaves the 2 s stop contract room for the slice and the save.
TEARDOWN_S = 1.0
_DUMP_LEAD_S = 0.2  # the stack dump comes this long before the end, so that it is complete

_CLOCK_MONOTONIC = 1
_SIGEV_THREAD = 2
_P = ctypes.sizeof(ctypes.c_void_p)


class _SigEvent(ctypes.Structure):
    """Linux ``struct sigevent`` (64 bytes), the ``SIGEV_THREAD`` member of its union."""

    _fields_ = [
        ('value', ctypes.c_void_p),  # union sigval: handed to ``function`` by value
        ('signo', ctypes.c_int),
        ('notify', ctypes.c_int),
        ('function', ctypes.c_void_p),  # void (*)(union sigval): here _exit(int)
        ('attributes', ctypes.c_void_p),
        ('_pad', ctypes.c_byte * (64 - 3 * _P - 8)),
    ]


class _TimeSpec(ctypes.Structure):
    _fields_ = [('sec', ctypes.c_long), ('nsec', ctypes.c_long)]


class _ITimerSpec(ctypes.Structure):
    _fields_ = [('interval', _TimeSpec), ('value', _TimeSpec)]


def flush_std() -> None:
    """Flush Python's stdout and stderr (nothing flushes them after ``os._exit``)."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except Exception:
            pass


def _native_exit_after(code: int, seconds: float) -> bool:
    """Arm a ``SIGEV_THREAD`` timer calling ``_exit(code)`` after ``seconds``; False where this
    libc has none. ``union sigval`` goes in the first integer register on the Linux ABIs, where
    ``_exit`` reads its ``int``."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        create, settime, end = libc.timer_create, libc.timer_settime, libc._exit
    except (OSError, AttributeError):
        return False
    event = _SigEvent(
        value=code or None, notify=_SIGEV_THREAD, function=ctypes.cast(end, ctypes.c_void_p).value
    )
    timer = ctypes.c_void_p()
    if create(_CLOCK_MONOTONIC, ctypes.byref(event), ctypes.byref(timer)) != 0:
        return False
    whole = int(seconds)
    spec = _ITimerSpec(value=_TimeSpec(whole, max(1, int((seconds - whole) * 1e9))))
    return settime(timer, 0, ctypes.byref(spec), None) == 0


def _exit_later(code: int, seconds: float) -> None:
    threading.Event().wait(seconds)
    flush_std()
    os._exit(code)


def arm(code: int, seconds: Optional[float] = None) -> None:
    """End the process with ``code`` ``seconds`` (default :data:`TEARDOWN_S`) from now, whatever
    the main thread is doing.

    Call it once nothing remains to save: the process may end at any moment after it. A clean-up
    that finishes first ends the process itself (``executor._end_process``)."""
    seconds = TEARDOWN_S if seconds is None else seconds
    flush_std()
    try:
        faulthandler.dump_traceback_later(max(seconds - _DUMP_LEAD_S, 0.01), exit=False, file=sys.stderr)
    except (AttributeError, ValueError, RuntimeError, OSError):  # no usable stderr: no diagnosis
        pass
    if not _native_exit_after(code, seconds):
        threading.Thread(target=_exit_later, args=(code, seconds), name='exit-watchdog', daemon=True).start()
