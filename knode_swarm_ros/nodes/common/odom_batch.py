"""Many topics' serialized Odometries decoded at once: a monitor's tick reads hundreds.

:class:`OdomBatch` reads what :func:`~.conversions.odom_fields_from_cdr` reads (the stamp, the
``child_frame_id``, the pose and twist.linear, as on the wire), bit for bit. A publisher's
header strings do not change from message to message, and the CDR layout depends only on them
and the encapsulation: a message whose length and bytes before the pose (the stamp aside) equal
those of the last message of its topic read in full has that message's layout and
``child_frame_id``. Such messages are read together with numpy, at the offsets found then (one
gather for all of them instead of a few Python calls each); anything else (a topic's first
message, new frames, big-endian CDR, bad bytes) is read in full, one by one.
"""

from __future__ import annotations

from typing import List, NamedTuple, Sequence

import numpy as np

from .conversions import CdrError, odom_fields_from_cdr

__all__ = ['OdomBatch', 'OdomFields']

_TAIL = 56 + 8 * 36 + 48 + 8 * 36  # pose, covariance, twist, covariance: fixed size
_LINEAR = 56 + 8 * 36  # twist.linear, after the pose and its covariance
_STAMP = np.arange(4, 12)
_POSE = np.arange(56)
_TWIST_LINEAR = _LINEAR + np.arange(24)


class OdomFields(NamedTuple):
    """Fields of ``m`` messages; those of a message that is not an Odometry (``bad``) are zeros."""

    stamps: np.ndarray  # [m] int64, header.stamp in ns
    children: List[str]  # [m] child_frame_id ('' where bad)
    poses: np.ndarray  # [m, 7] position, orientation (x, y, z, w)
    linears: np.ndarray  # [m, 3] twist.linear
    bad: np.ndarray  # [m] bool: not a serialized Odometry (CdrError)


class OdomBatch:
    """Decoder of the serialized Odometries of ``topics`` topics (see the module doc)."""

    def __init__(self, topics: int):
        self._size = np.full(topics, -1, dtype=np.int64)  # -1: no layout (big-endian is always read in full)
        self._child = [''] * topics
        # per topic, the layout's key bytes (0..4 and 12..pose) and where they are in a message;
        # short keys padded with position 0, whose byte is 0 in every Odometry
        self._key = np.zeros((topics, 4), dtype=np.uint8)
        self._where = np.zeros((topics, 4), dtype=np.int64)

    def read(self, topics: Sequence[int], messages: Sequence[bytes]) -> OdomFields:
        """The fields of ``messages`` (bytes), ``topics[j]`` the topic (0 .. topics-1) of the j-th."""
        m = len(messages)
        topics = np.asarray(topics, dtype=np.int64).reshape(m)
        stamps = np.zeros(m, dtype=np.int64)
        poses = np.zeros((m, 7))
        linears = np.zeros((m, 3))
        bad = np.zeros(m, dtype=bool)
        children = [''] * m
        if not m:
            return OdomFields(stamps, children, poses, linears, bad)
        lengths = np.fromiter(map(len, messages), dtype=np.int64, count=m)
        data = np.frombuffer(b''.join(messages), dtype=np.uint8)
        starts = np.zeros(m, dtype=np.int64)
        np.cumsum(lengths[:-1], out=starts[1:])
        fast = np.nonzero(lengths == self._size[topics])[0]
        if len(fast):
            t, start = topics[fast], starts[fast]
            same = (data[start[:, None] + self._where[t]] == self._key[t]).all(axis=1)
            fast, t, start = fast[same], t[same], start[same]
        if len(fast):
            stamp = data[start[:, None] + _STAMP].view('<i4').astype(np.int64)  # sec int32, nanosec uint32
            stamps[fast] = stamp[:, 0] * 1_000_000_000 + (stamp[:, 1] & 0xFFFFFFFF)
            pose_at = start + lengths[fast] - _TAIL
            poses[fast] = data[pose_at[:, None] + _POSE].view('<f8')
            linears[fast] = data[pose_at[:, None] + _TWIST_LINEAR].view('<f8')
            for j, topic in zip(fast.tolist(), t.tolist()):
                children[j] = self._child[topic]
        slow = np.ones(m, dtype=bool)
        slow[fast] = False
        for j in np.nonzero(slow)[0].tolist():
            message = messages[j]
            try:
                ns, child, pose, linear, _ = odom_fields_from_cdr(message)
            except CdrError:
                bad[j] = True
                continue
            stamps[j], children[j], poses[j], linears[j] = ns, child, pose, linear
            self._learn(int(topics[j]), message, child)
        return OdomFields(stamps, children, poses, linears, bad)

    def _learn(self, topic: int, message: bytes, child: str) -> None:
        """Keep the layout of ``message`` (an Odometry) as ``topic``'s."""
        if message[1] != 1:  # big-endian: the numpy path reads little-endian only
            self._size[topic] = -1
            return
        at = len(message) - _TAIL
        where = np.r_[0:4, 12:at]
        if len(where) > self._key.shape[1]:  # a longer key than any so far: widen the padding
            pad = len(where) - self._key.shape[1]
            self._key = np.pad(self._key, ((0, 0), (0, pad)))
            self._where = np.pad(self._where, ((0, 0), (0, pad)))
        self._key[topic] = 0
        self._where[topic] = 0
        self._key[topic, : len(where)] = np.frombuffer(message, dtype=np.uint8)[where]
        self._where[topic, : len(where)] = where
        self._size[topic] = len(message)
        self._child[topic] = child
