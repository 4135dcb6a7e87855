"""What every node shares for its log and its exit report (no rclpy here).

:class:`Throttle`: at most one log line per key every ``period`` seconds (a flood of dropped
messages must not flood the log). :func:`throttled_log` logs through it. :func:`write_json_report`:
a node's JSON report, written atomically (:func:`core.trajectory.atomic_write`), so a reader
never sees half a file, also when the node is stopped while writing.
"""

from __future__ import annotations

import json
import time
from typing import Any, Callable, Dict, Optional

from knode_swarm_ros.core.trajectory import atomic_write

__all__ = ['Throttle', 'throttled_log', 'write_json_report', 'LOG_EVERY_S']

LOG_EVERY_S = 5.0


class Throttle:
    """Says whether a key may log now: once per ``period`` seconds of ``clock`` per key."""

    def __init__(self, period: float = LOG_EVERY_S, clock: Callable[[], float] = time.monotonic):
        self.period = period
        self.clock = clock
        self._last: Dict[str, float] = {}

    def ready(self, key: str, now: Optional[float] = None) -> bool:
        """True (and the key's time restarts) when ``key`` has not logged for ``period`` s."""
        now = self.clock() if now is None else now
        if now - self._last.get(key, -1e9) >= self.period:
            self._last[key] = now
            return True
        return False


def throttled_log(logger, throttle: Throttle, key: str, text: str, warn: bool = False) -> None:
    """``text`` at info (warning when ``warn``) through ``logger``, if ``throttle`` lets ``key`` log."""
    if throttle.ready(key):
        if warn:  # two call sites: rclpy refuses one call site logging at two severities
            logger.warning(text)
        else:
            logger.info(text)


def write_json_report(path: str, data: Any, **dump_kwargs) -> None:
    """``data`` as JSON at ``path`` (nothing when ``path`` is empty), atomically."""
    if not path:
        return

    def write(tmp):
        with open(tmp, 'w') as fh:
            json.dump(data, fh, **dump_kwargs)

    atomic_write(path, write)
