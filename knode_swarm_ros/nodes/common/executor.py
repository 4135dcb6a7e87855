"""The executor every node spins in, and the loop that spins it.

rclpy 7.1's experimental EventsExecutor costs far less CPU per message than the default
executor (it matters with 20 agent processes on 2 cores), but its ``spin()`` and its
``spin_until_future_complete()`` without a timeout neither return on Ctrl-C nor sleep while
idle (measured: one core at 100 %). :func:`spin_until` therefore spins in slices with a
timeout, which both sleeps and notices the shutdown that rclpy's SIGINT/SIGTERM handler
triggers (``ExternalShutdownException``).
"""

import gc
import os
import signal
import sys
import traceback
from typing import Callable, Optional

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future

from knode_swarm_ros.core.errors import first_line
from knode_swarm_ros.logic.common import EXIT_CONFIG, EXIT_FAILURE, EXIT_OK, ConfigError

from . import exit_watchdog
from .native_preload import preloading
from .startup import STOP_SIGNALS

__all__ = ['make_executor', 'spin_until', 'run_node', 'destroy_node']

RCLError = _rclpy.RCLError

_SLICE_S = 0.25


def make_executor():
    """rclpy's EventsExecutor where this rclpy has it, else the SingleThreadedExecutor."""
    try:
        from rclpy.experimental import EventsExecutor
    except ImportError:  # pragma: no cover - rclpy before Jazzy
        from rclpy.executors import SingleThreadedExecutor

        return SingleThreadedExecutor()
    return EventsExecutor()


def spin_until(
    executor, future: Future = None, context=None, stop: Optional[Callable[[], bool]] = None
) -> None:
    """Spin ``executor`` until ``future`` is done (forever when None) or ``stop()`` says so.

    Raises:
        ExternalShutdownException: the context was shut down (Ctrl-C, SIGTERM).
    """
    if future is None:
        future = Future()
    if context is None:
        from rclpy.utilities import get_default_context

        context = get_default_context()
    while not future.done():
        executor.spin_until_future_complete(future, timeout_sec=_SLICE_S)
        if not context.ok() or (stop is not None and stop()):
            raise ExternalShutdownException()


class _Interrupts:
    """Ctrl-C / SIGTERM as a flag, never as a KeyboardInterrupt in the middle of cleanup.

    Python's own SIGINT handler raises KeyboardInterrupt wherever the main thread happens to be
    (inside rclpy.init, a callback, the recorder's save, the executor's teardown: an exception
    thrown through the EventsExecutor's C++ aborts the process). This handler only records the
    signal; while the node is built it raises :class:`_StartupInterrupted` (the start-up is
    abandoned, not finished first), and afterwards :func:`spin_until` sees the flag between
    slices (rclpy's handlers are off, so the EventsExecutor installs none of its own). Once
    everything is saved and the clean-up has begun (``ending``: the exit status), a signal ends
    the process at once (if the main thread runs Python; a native hang waits for the watchdog).
    """

    def __init__(self):
        self.signal: Optional[int] = None
        self.raising = False  # while the node is built (torch import, policy load: seconds)
        self.ending: Optional[int] = None  # the exit status, once only the clean-up is left
        self._old = {}

    def __enter__(self):
        for sig, handler in (
            (signal.SIGINT, self._note),
            (signal.SIGTERM, self._note),
            (signal.SIGALRM, self._retry),
        ):
            try:
                self._old[sig] = signal.signal(sig, handler)
            except ValueError:  # not the main thread (tests): leave the handlers alone
                pass
        if self._old:  # a node started with them blocked (startup.block_stop_signals) hears them now
            signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)
        return self

    def _note(self, signum, frame) -> None:
        self.signal = signum
        if self.ending is not None:  # nothing left to save: a second signal need not wait
            _end_process(self.ending)
        if self.raising:  # do not finish a slow start-up first; nothing of it needs saving
            if not _safe_to_raise(frame):
                if _inside_torch(frame):
                    _abandon_in_place(frame)  # no unwinding through torch's C++; does not return
                signal.setitimer(signal.ITIMER_REAL, _RETRY_S)  # importlib: try again from a later frame
                return
            self.raising = False
            raise _StartupInterrupted()

    def _retry(self, _signum, frame) -> None:
        # Only while the node is still built. A retry armed just before the build ended fires
        # later, perhaps once the clean-up has begun, where _note would take it for a second
        # signal and end the process before the node and the context are destroyed: the DDS
        # participant's /dev/shm segment would stay behind.
        if self.signal is not None and self.raising:
            self._note(self.signal, frame)

    def __exit__(self, *exc):
        if signal.SIGALRM in self._old:
            signal.setitimer(signal.ITIMER_REAL, 0)
        for sig, old in self._old.items():
            signal.signal(sig, old)
        return False


_IMPORT_MACHINERY = '<frozen importlib._bootstrap>'
_RETRY_S = 0.005


def _safe_to_raise(frame) -> bool:
    """Whether an exception raised in ``frame`` unwinds only through Python.

    Not in importlib's bootstrap: there the raise can land in the module lock's weakref
    callback, which ignores it ("Exception ignored in ... cb", measured). Not below a function
    of torch: torch calls back into Python from C++ (TorchScript compiles at import), and an
    exception thrown through that C++ aborted the agent once in 35 stops during start-up
    (status -6, measured under load). Nor in torch's own module-level code: a raise during
    ``import torch`` (torch/functional.py) aborted it once in 50 (bench_shutdown, 2026-11-30),
    so a signal then waits for the import to end (about a second under load).
    """
    if frame is not None and frame.f_code.co_filename == _IMPORT_MACHINERY:
        return False
    return not _inside_torch(frame)


def _inside_torch(frame) -> bool:
    """Whether torch's code (its import included) is on the stack below ``frame``."""
    while frame is not None:
        if '/torch/' in frame.f_code.co_filename:
            return True
        frame = frame.f_back
    return False


def _abandon_in_place(frame) -> None:
    """End a start-up that a signal caught inside torch, without unwinding through it.

    Waiting for torch to return took up to 4.6 s (``import torch`` under load: 15 of 50
    start-up stops over 2 s); raising through it aborted the process. Nothing of a half-built
    node needs saving: destroy it and the context (the DDS participant and its /dev/shm files)
    from here, then end the process with EXIT_OK.
    """
    frames = []
    while frame is not None:
        frames.append(frame)
        frame = frame.f_back
    try:
        exit_watchdog.arm(EXIT_OK)  # nothing of it is saved: only native clean-up follows
        _free_half_built(_outermost_node_init(reversed(frames)))
        _end_context()
    finally:
        _end_process(EXIT_OK)


class _StartupInterrupted(BaseException):
    """A signal while the node was being built (a BaseException: node code does not catch it)."""


def _teardown(executor, node: Optional[Node]) -> None:
    """Detach the node from the executor before anything is destroyed: the EventsExecutor aborts
    ("Destroying callback manager with callbacks remaining") when it is destroyed while entities
    that registered callbacks with it are still attached, or destroyed under it."""
    if executor is None:
        return
    if node is not None:
        try:
            executor.remove_node(node)
        except Exception:
            pass
    try:
        executor.shutdown()
    except Exception as exc:
        print(f'knode_swarm_ros: executor teardown: {type(exc).__name__}: {exc}', file=sys.stderr)


def destroy_node(node: Node) -> None:
    """Destroy ``node`` and everything that keeps its handle alive.

    rclpy's ``LifecycleNode.destroy_node`` (Jazzy) leaves its state machine, which holds the
    node handle: the node is then never really destroyed, nor the context after it, so the DDS
    participant outlives the process's clean-up and its shared-memory segment
    (``/dev/shm/fastrtps_<id>``, ``_el``) and port lock files stay behind (measured: the
    lifecycle agent on 49 of 50 stops, a plain node on none). Also frees a node whose
    constructor was cut short (raises what rclpy's ``destroy_node`` raised then)."""
    try:
        node.destroy_node()
    finally:
        # rclpy's destroy_node stops at the first part that a constructor cut short had not made
        # yet (its type description service comes last) before it reaches the handle.
        for part in (getattr(node, '_state_machine', None), getattr(node, '_Node__node', None)):
            if part is not None:
                part.destroy_when_not_in_use()


def _outermost_node_init(frames) -> Optional[Node]:
    """The ``self`` of the outermost node constructor among ``frames`` (outermost first)."""
    for frame in frames:
        candidate = frame.f_locals.get('self')
        if isinstance(candidate, Node) and frame.f_code.co_name == '__init__':
            return candidate
    return None


def _node_under_construction(tb) -> Optional[Node]:
    """The node whose ``__init__`` an exception (a signal, a bad parameter) cut short: the
    ``self`` of the outermost constructor frame in the traceback. It already owns a node handle
    (and so the DDS participant); unless destroyed, it keeps them past the context's end."""
    frames = []
    while tb is not None:
        frames.append(tb.tb_frame)
        tb = tb.tb_next
    return _outermost_node_init(frames)


def _free_half_built(node: Optional[Node]) -> None:
    """Destroy a node whose construction was cut short (no ``on_exit``: nothing of it is saved)."""
    if node is None:
        return
    try:
        destroy_node(node)
    except Exception:
        pass


def _end_context() -> None:
    """Shut down and destroy the default context: the DDS participant (and its /dev/shm files) go now."""
    rclpy.try_shutdown()
    rclpy.get_default_context().destroy()


def run_node(name: str, make_node: Callable[[], Node], on_exit: Callable[[Node], None], args=None) -> None:
    """The ros2/examples ``main()`` shared by the executables: init, build, spin, clean up, exit.

    Spins until the node's ``finished`` future is done (forever without one), then exits with
    its ``exit_code``; a :class:`ConfigError` (bad parameter or policy) or ROS arguments that
    rcl cannot parse (a broken ``--params-file``) exit with EXIT_CONFIG and a message naming the
    problem; Ctrl-C / SIGTERM at any time, during start-up included, exit cleanly with EXIT_OK;
    anything else prints its traceback and exits with EXIT_FAILURE. ``on_exit(node)`` (reports,
    saving) always runs first, before the node leaves the executor, and is not interrupted by a
    second Ctrl-C; a node whose construction a signal or an error cut short is destroyed without
    it (its handle holds the DDS participant). The clean-up after it (native: executor, node,
    context) runs under :func:`exit_watchdog.arm`'s deadline, and a signal then ends the process
    at once, with the same status. The process ends here (:func:`_end_process`): call it only as
    an executable's ``main()``.
    """
    node: Optional[Node] = None
    half_built: Optional[Node] = None  # a node whose construction was cut short: destroyed, no on_exit
    executor = None
    code = EXIT_OK
    with _Interrupts() as interrupts:
        try:
            try:
                # No rclpy signal handlers: they shut the context down from another thread, in the
                # middle of a callback that then fails to publish. The EventsExecutor's own handler
                # stops the spin and shuts the context down between callbacks; before it exists,
                # _Interrupts notes the signal.
                rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
            except RCLError as exc:
                raise ConfigError(f'cannot parse the ROS arguments: {first_line(exc)}') from None
            if interrupts.signal is None:
                interrupts.raising = True
                try:
                    with preloading():  # torch's libraries load where a signal is still seen
                        node = make_node()
                except BaseException as exc:
                    half_built = _node_under_construction(exc.__traceback__)
                    raise
                finally:
                    interrupts.raising = False
            if interrupts.signal is None:
                # Everything built so far (torch, rclpy, the policy: ~170k objects) lives as long as
                # the process: out of the collector's sight, so that its full passes over them do not
                # stall the message callbacks (a hosting process: 2x its per-step cost).
                gc.freeze()
                executor = make_executor()
                executor.add_node(node)
                spin_until(
                    executor, getattr(node, 'finished', None), stop=lambda: interrupts.signal is not None
                )
                code = getattr(node, 'exit_code', EXIT_OK)
        except ConfigError as exc:
            print(f'knode_swarm_ros {name}: error: {exc}', file=sys.stderr)
            code = EXIT_CONFIG
        except (KeyboardInterrupt, ExternalShutdownException, _StartupInterrupted):
            pass
        except Exception as exc:  # report, then exit non-zero instead of a bare traceback
            if interrupts.signal is None and rclpy.ok():  # not merely cut short by a shutdown
                traceback.print_exc()
                print(f'knode_swarm_ros {name}: error: {type(exc).__name__}: {exc}', file=sys.stderr)
                code = EXIT_FAILURE
        finally:
            if node is not None:
                code = _save_on_exit(name, node, on_exit, code)
            # Everything is saved: a stuck native clean-up must not keep the process (a recorder
            # hung here once, its file written, and was SIGKILLed: the launcher failed the run).
            interrupts.ending = code
            exit_watchdog.arm(code)
            _teardown(executor, node)
            if node is not None:
                destroy_node(node)
            _free_half_built(half_built)
            _end_context()
    _end_process(code)


def _save_on_exit(name: str, node: Node, on_exit: Callable[[Node], None], code: int) -> int:
    """Run ``on_exit(node)``; returns the exit status (EXIT_FAILURE if it failed unexpectedly)."""
    try:
        on_exit(node)
    except OSError as exc:
        print(f'knode_swarm_ros {name}: cannot write on exit: {exc}', file=sys.stderr)
    except Exception as exc:
        traceback.print_exc()
        print(f'knode_swarm_ros {name}: error on exit: {type(exc).__name__}: {exc}', file=sys.stderr)
        return EXIT_FAILURE
    return code


def _end_process(code: int) -> None:
    """Exit with ``code`` without running destructors.

    Everything that matters was cleaned up explicitly above (on_exit, node, context, DDS
    participant). What is left is the EventsExecutor object: when a signal cuts its first entity
    update short (a shutdown while it registers the node's subscriptions, measured under load),
    it keeps callbacks for entities it no longer tracks, and its destructor then aborts the
    process ("Destroying callback manager with callbacks remaining", status -6). Ending here
    never runs that destructor.
    """
    try:
        exit_watchdog.flush_std()
    finally:
        os._exit(code)
