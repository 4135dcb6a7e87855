"""Robots' state messages taken when a node is ready for them, not one callback each.

A node that looks at the robots' states once per tick of its own (the monitor: 15 ticks a
second, against 4,000 Odometry a second from 200 robots at 20 Hz) need not wake its executor and
run a Python callback for every message. The subscriptions of a :class:`StateInbox` belong to a
node of their own that no executor spins: the middleware keeps each robot's last ``depth``
messages, and :meth:`StateInbox.take` takes everything queued since the last call (the take of
rclpy's executor, without the callback), decodes it and returns it as arrays: robot by robot in
the fleet's order, each robot's messages oldest first.

Decoded are the fields a state needs, as they are on the wire: the stamp, the position, the
orientation and, for an Odometry, twist.linear (all of a take's Odometries at once,
:class:`~.odom_batch.OdomBatch`; a pose has no twist: zeros). The caller maps them to states (``rep105.fields_to_states``, or
``PoseStates`` for poses). Dropped and counted: bytes that are not a message of the fleet's
state type (:attr:`StateInbox.malformed`) and an Odometry whose ``child_frame_id`` is not the
robot's own (:attr:`StateInbox.foreign`, ``Fleet.owns_frame``).
"""

from __future__ import annotations

from typing import Iterator, List, NamedTuple, Optional, Sequence, Tuple

import numpy as np
from rclpy.node import Node
from rclpy.qos import QoSProfile

from knode_swarm_ros.logic.contract import qos_specs
from knode_swarm_ros.logic.contract.fleet import Fleet

from . import qos
from .conversions import STATE_MESSAGES, CdrError, pose_from_cdr
from .odom_batch import OdomBatch

__all__ = ['StateInbox', 'Taken']


class Taken(NamedTuple):
    """States' fields taken from the inbox, ``m`` messages."""

    robots: np.ndarray  # [m] int64, the robots' ids
    stamps: np.ndarray  # [m] int64, header.stamp in ns
    positions: np.ndarray  # [m, 3]
    quaternions: np.ndarray  # [m, 4] (x, y, z, w)
    linears: np.ndarray  # [m, 3] twist.linear (Odometry: child frame, as sent); zeros for a pose


def _never_called(_msg) -> None:  # the inbox's node is never spun
    raise AssertionError('a StateInbox subscription was spun by an executor')


class StateInbox:
    """The state topics of ``fleet``'s robots, taken on demand (see the module doc).

    Args:
        context: the rclpy context of the node that owns the inbox.
        fleet: the robots (ids, state topics, state type).
        depth: messages kept per robot between two takes (keep last): 1 when only the newest
            matters; enough for a tick's worth when every message does (a velocity estimate).
        name: the inbox's node name (its own node, never added to an executor).
        ids: the robots to subscribe to (default: all of the fleet's).
        qos_profile: the subscriptions' QoS (default: the state QoS, keep last ``depth``);
            ``depth`` is then the profile's.
        namespace: the inbox node's namespace, where relative topic names resolve (an agent
            passes its own).
    """

    def __init__(
        self,
        context,
        fleet: Fleet,
        depth: int,
        name: str = 'state_inbox',
        ids: Optional[Sequence[int]] = None,
        qos_profile: Optional[QoSProfile] = None,
        namespace: Optional[str] = None,
    ):
        self.fleet = fleet
        self.msg_type = STATE_MESSAGES[fleet.state.type]
        self.depth = int(qos_profile.depth if qos_profile is not None else depth)
        ids = list(fleet.ids if ids is None else ids)
        self.malformed = 0  # bytes that are not a message of the state type
        self.foreign = 0  # an Odometry whose child_frame_id is another robot's
        # The process's remappings apply (topics, namespace) but not a node name given to the
        # owner (``-r __node:=...``): the inbox keeps its own name.
        self.node = Node(
            name,
            context=context,
            namespace=namespace,
            cli_args=['--ros-args', '-r', f'__node:={name}'],
            start_parameter_services=False,
            enable_rosout=False,
        )
        profile = qos_profile or qos.profile(qos_specs.ODOM._replace(depth=self.depth))
        odometry = fleet.state.type == 'odometry'
        try:
            self.subscriptions = [
                self.node.create_subscription(
                    self.msg_type, fleet.state_topic(rid), _never_called, profile, raw=True
                )
                for rid in ids
            ]
        except BaseException:  # a signal or a bad topic: the node's handle must not outlive us
            self.node.destroy_node()
            raise
        self._ids = np.array(ids, dtype=np.int64)
        self._handles = [sub.handle for sub in self.subscriptions]
        self._odometry = OdomBatch(len(ids)) if odometry else None
        self._own: List[Optional[str]] = [None] * len(ids)  # per robot, the child_frame_id last found its own

    def take_raw(self) -> Iterator[Tuple[int, bytes]]:
        """``(robot, bytes)`` of every message queued since the last call, robot by robot, each
        robot's oldest first, undecoded (for a caller with a decoder of its own, as the agent's)."""
        msg_type, depth = self.msg_type, self.depth
        for rid, handle in zip(self._ids.tolist(), self._handles):
            for _ in range(depth):
                got = handle.take_message(msg_type, True)
                if got is None:
                    break
                yield rid, got[0]

    def take(self) -> Taken:
        """Every message queued since the last call, decoded (see the module doc).

        Call it from the thread that destroys the inbox (the takes skip rclpy's guard against a
        handle destroyed meanwhile, which costs as much as a take)."""
        messages, rows = [], []
        msg_type, depth = self.msg_type, self.depth
        for row, handle in enumerate(self._handles):
            # At most ``depth`` are queued: no take that can only come back empty (a message
            # arriving meanwhile waits for the next call).
            for _ in range(depth):
                got = handle.take_message(msg_type, True)
                if got is None:
                    break
                messages.append(got[0])
                rows.append(row)
        rows = np.array(rows, dtype=np.int64)
        if self._odometry is not None:
            fields = self._odometry.read(rows, messages)
            stamps, poses, linears = fields.stamps, fields.poses, fields.linears
            self.malformed += int(fields.bad.sum())
            good, own = (~fields.bad).tolist(), self._own
            for j, (row, child) in enumerate(zip(rows.tolist(), fields.children)):
                if child != own[row] and good[j]:
                    if self.fleet.owns_frame(child, int(self._ids[row])):
                        own[row] = child
                    else:
                        self.foreign += 1
                        good[j] = False
            keep = np.array(good, dtype=bool)
        else:
            stamps, poses = np.zeros(len(rows), dtype=np.int64), np.zeros((len(rows), 7))
            linears, keep = np.zeros((len(rows), 3)), np.ones(len(rows), dtype=bool)
            for j, message in enumerate(messages):
                try:
                    stamps[j], _, poses[j] = pose_from_cdr(message)
                except CdrError:
                    self.malformed += 1
                    keep[j] = False
        if not keep.all():
            rows, stamps, poses, linears = rows[keep], stamps[keep], poses[keep], linears[keep]
        return Taken(
            robots=self._ids[rows],
            stamps=stamps,
            positions=poses[:, :3],
            quaternions=poses[:, 3:],
            linears=linears,
        )

    def destroy(self) -> None:
        """Destroy the inbox's node (its subscriptions)."""
        self.node.destroy_node()
