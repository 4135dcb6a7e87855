"""The neighbours' state topics taken without a wake-up per message.

A motion capture at 100 Hz sends each agent 100 poses per second per robot: ten robots are a
thousand executor callbacks a second in every agent process, most of them for poses between
steps that only feed the velocity fit. Here those subscriptions sit on a helper node that is
never added to an executor, so nothing wakes for them; the agent takes what has arrived
(``take``: rcl's take, raw bytes) when it wakes anyway: its own state, its grace and poll
timers, its control timer. The reader's queue (the state QoS, keep last 200) holds them until
then.

The helper node takes no command-line arguments (a ``__node`` remap would give it the agent's
name) and lives in the agent's namespace, so relative topic names resolve as the agent's do.
"""

from __future__ import annotations

from typing import Callable, Iterator, Sequence, Tuple

from rclpy.node import Node

__all__ = ['StateInbox']


class StateInbox:
    """Raw subscriptions to ``topic_of(rid)`` for every ``rid`` of ``ids``, drained by :meth:`take`."""

    def __init__(self, node, msg_type, ids: Sequence[int], topic_of: Callable[[int], str], qos_profile):
        self.node = Node(
            f'{node.get_name()}_inbox',
            namespace=node.get_namespace(),
            context=node.context,
            use_global_arguments=False,
            start_parameter_services=False,
            enable_rosout=False,
        )
        self.subs = [
            (int(rid), self.node.create_subscription(msg_type, topic_of(rid), _never, qos_profile, raw=True))
            for rid in ids
        ]

    def take(self) -> Iterator[Tuple[int, bytes]]:
        """``(robot, bytes)`` of every message arrived since the last take, robot by robot, each
        robot's in order."""
        for rid, sub in self.subs:
            while True:
                got = sub.handle.take_message(sub.msg_type, True)
                if got is None:
                    break
                yield rid, got[0]

    def destroy(self) -> None:
        self.node.destroy_node()


def _never(_msg) -> None:  # pragma: no cover - the node is never spun
    pass
