"""The executor every node spins in, and the loop that spins it.

rclpy 7.1's experimental EventsExecutor costs far less CPU per message than the default
executor (it matters with 20 agent processes on 2 cores), but its ``spin()`` and its
``spin_until_future_complete()`` without a timeout neither return on Ctrl-C nor sleep while
idle (measured: one core at 100 %). :func:`spin_until` therefore spins in slices with a
timeout, which both sleeps and notices the shutdown that rclpy's SIGINT/SIGTERM handler
triggers (``ExternalShutdownException``).
"""
from rclpy.executors import ExternalShutdownException
from rclpy.task import Future

__all__ = ['make_executor', 'spin_until']

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
