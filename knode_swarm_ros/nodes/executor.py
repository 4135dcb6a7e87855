"""The executor every node spins in, and the loop that spins it.

rclpy 7.1's experimental EventsExecutor costs far less CPU per message than the default
executor (it matters with 20 agent processes on 2 cores), but its ``spin()`` and its
``spin_until_future_complete()`` without a timeout neither return on Ctrl-C nor sleep while
idle (measured: one core at 100 %). :func:`spin_until` therefore spins in slices with a
timeout, which both sleeps and notices the shutdown that rclpy's SIGINT/SIGTERM handler
triggers (``ExternalShutdownException``).
"""
import sys
import traceback
from typing import Callable, Optional

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.task import Future

from .common import EXIT_CONFIG, EXIT_FAILURE, EXIT_OK, ConfigError

__all__ = ['make_executor', 'spin_until', 'run_node']

_SLICE_S = 0.25


def make_executor():
    """rclpy's EventsExecutor where this rclpy has it, else the SingleThreadedExecutor."""
    try:
        from rclpy.experimental import EventsExecutor
    except ImportError:  # pragma: no cover - rclpy before Jazzy
        from rclpy.executors import SingleThreadedExecutor
        return SingleThreadedExecutor()
    return EventsExecutor()


def spin_until(executor, future: Future = None, context=None) -> None:
    """Spin ``executor`` until ``future`` is done (forever when None).

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
        if not context.ok():
            raise ExternalShutdownException()


def run_node(name: str, make_node: Callable[[], Node], on_exit: Callable[[Node], None], args=None) -> None:
    """The ros2/examples ``main()`` shared by the executables: init, build, spin, clean up, exit.

    Spins until the node's ``finished`` future is done (forever without one), then exits with
    its ``exit_code``; a :class:`ConfigError` (bad parameter or policy) exits with EXIT_CONFIG
    and a message naming the problem; Ctrl-C / SIGTERM exit cleanly; anything else prints its
    traceback and exits with EXIT_FAILURE. ``on_exit(node)`` (reports, saving) always runs
    before the node is destroyed.
    """
    rclpy.init(args=args)
    node: Optional[Node] = None
    code = EXIT_OK
    try:
        node = make_node()
        executor = make_executor()
        executor.add_node(node)
        spin_until(executor, getattr(node, 'finished', None))
        code = getattr(node, 'exit_code', EXIT_OK)
    except ConfigError as exc:
        print(f'knode_swarm_ros {name}: error: {exc}', file=sys.stderr)
        code = EXIT_CONFIG
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception as exc:  # report, then exit non-zero instead of a bare traceback
        traceback.print_exc()
        print(f'knode_swarm_ros {name}: error: {type(exc).__name__}: {exc}', file=sys.stderr)
        code = EXIT_FAILURE
    finally:
        if node is not None:
            try:
                on_exit(node)
            except OSError as exc:
                print(f'knode_swarm_ros {name}: cannot write on exit: {exc}', file=sys.stderr)
            node.destroy_node()
        rclpy.try_shutdown()
    if code:
        sys.exit(code)
