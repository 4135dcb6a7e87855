"""nodes/executor._Interrupts: a signal while the node is built abandons the start-up, except
where the raise would not unwind through Python alone: inside importlib's bootstrap (the module
lock's weakref callback ignores it and prints "Exception ignored") or below a function of torch
(which may be C++ calling back into Python: an exception through it aborts). There it is raised
again a moment later."""

import signal
import sys

import pytest

from knode_swarm_ros.nodes.common.executor import (
    _IMPORT_MACHINERY,
    _Interrupts,
    _safe_to_raise,
    _StartupInterrupted,
)


def _frame_in(filename, function=None):
    """A frame of code compiled as ``filename`` (module level, or inside ``function``)."""
    space = {}
    if function is None:
        exec(compile('import sys\nframe = sys._getframe()', filename, 'exec'), space)
    else:
        exec(
            compile(
                f'import sys\ndef {function}():\n    return sys._getframe()\nframe = {function}()',
                filename,
                'exec',
            ),
            space,
        )
    return space['frame']


def test_where_a_raise_unwinds_through_python_only():
    assert _safe_to_raise(sys._getframe())
    assert not _safe_to_raise(_frame_in(_IMPORT_MACHINERY))
    assert not _safe_to_raise(_frame_in('/venv/site-packages/torch/jit/_script.py', 'script'))
    # torch's module level too: a raise while importing torch aborted the agent (status -6)
    assert not _safe_to_raise(_frame_in('/venv/site-packages/torch/functional.py'))


def test_a_signal_while_building_raises_at_once_but_not_inside_importlib():
    before = signal.getsignal(signal.SIGALRM)
    with _Interrupts() as interrupts:
        try:
            interrupts.raising = True
            interrupts._note(signal.SIGTERM, _frame_in(_IMPORT_MACHINERY))  # deferred, not raised
            assert interrupts.signal == signal.SIGTERM and interrupts.raising
            assert signal.getitimer(signal.ITIMER_REAL)[0] > 0  # the retry is armed
            signal.setitimer(signal.ITIMER_REAL, 0)  # the test calls the retry itself
            with pytest.raises(_StartupInterrupted):
                interrupts._retry(signal.SIGALRM, sys._getframe())
            assert not interrupts.raising
            interrupts._note(signal.SIGINT, sys._getframe())  # built: only noted
            assert interrupts.signal == signal.SIGINT
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)
    assert signal.getsignal(signal.SIGALRM) == before  # the handlers are put back


def test_a_late_retry_during_the_clean_up_does_not_end_the_process(monkeypatch):
    """The retry armed by a signal inside importlib can fire after the build has ended, once the
    clean-up has begun (``ending`` set): it must not end the process as a second signal does,
    before the node and the context (the DDS participant, its /dev/shm segment) are destroyed."""
    from knode_swarm_ros.nodes.common import executor

    ended = []
    monkeypatch.setattr(executor, '_end_process', ended.append)
    with _Interrupts() as interrupts:
        try:
            interrupts.raising = True
            interrupts._note(signal.SIGINT, _frame_in(_IMPORT_MACHINERY))  # deferred: the retry is armed
            signal.setitimer(signal.ITIMER_REAL, 0)  # the test calls the retry itself
            interrupts.raising = False  # the build ended before the retry fired
            interrupts.ending = 0  # run_node's clean-up has begun
            interrupts._retry(signal.SIGALRM, sys._getframe())
            assert ended == []
            interrupts._note(signal.SIGTERM, sys._getframe())  # a second signal does end it
            assert ended == [0]
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)
