"""The one place that maps states and commands to and from ROS messages.

State z of robot ``i`` <-> ``nav_msgs/Odometry`` on ``robot_<i>/odom`` per REP 105 (all values
float64; ``header.frame_id`` = the world frame, ``world`` by default; ``child_frame_id`` =
``robot_<i>/base_link`` by default; ``header.stamp`` = the state's time): pose in the world
frame, twist in the child frame. The field-by-field mapping (which state entry goes where, and
why a robot without a heading in its state reports the identity orientation) is the ROS-free
:mod:`knode_swarm_ros.logic.contract.rep105`, shared with the bag writer; this module only moves
its vectors into and out of messages. Decoding reads the twist in the child frame (``body``,
REP 105) unless the caller says the publisher puts it in the world frame (``twist_frame``).

Heading quaternion (x, y, z, w): for a unit h with h_x >= 0, q = normalise(w = 1 + h_x,
(x, y, z) = (+x) x h = (0, -h_z, h_y)), the shortest rotation taking +x to h; for h_x < 0,
where that formula cancels, q = (0, 0, 1, 0) * q' (the rotation by pi about +z after the
shortest arc q' onto (-h_x, -h_y, h_z)), again a rotation taking +x to h. Decoding takes the
first column of the rotation matrix of q, h = (1 - 2(y^2 + z^2), 2(xy + wz), 2(xz - wy)), so
encode-then-decode returns h up to rounding (a few 1e-16) for every unit h; a zero h encodes
as the identity and decodes as +x.

Fast path: the simulator publishes, and the agents and the recorder receive, Odometry as
serialized CDR bytes (:func:`odom_to_cdr`, :func:`odom_from_cdr`; rclpy's ``publish(bytes)``
and ``raw=True`` subscriptions). The bytes are exactly what rclpy serializes for the message
of :func:`state_to_odom` (covariances zero; rclpy deserializes them to an equal message, and
only the alignment padding, which rclpy leaves uninitialised, is zero here), and the decoder reads the same fields that
:func:`odom_to_state` reads, so the mapping above is the only one; it only saves rclpy's
conversion of every Odometry (with its two 36-entry covariances) to and from a Python object,
which measured about 3x the CPU of the rest of a message's delivery.

Commands follow the scenario's ``command``: accelerations in
``geometry_msgs/AccelStamped.accel.linear`` (``robot_<i>/cmd_accel``), velocities in
``geometry_msgs/TwistStamped.twist.linear`` (``robot_<i>/cmd_vel``); x, y, and z in 3D (a 2D
command leaves z zero and ignores it on receipt); angular zero; ``header.stamp`` = the stamp of the robot's own state the
command was computed from, ``header.frame_id = 'world'``.
"""

from __future__ import annotations

import struct
from typing import Optional, Sequence, Tuple, Union

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import AccelStamped, PoseStamped, Twist, TwistStamped
from nav_msgs.msg import Odometry

from knode_swarm_ros.core.errors import KnodeError
from knode_swarm_ros.core.scenarios import Scenario, get_scenario
from knode_swarm_ros.logic.common import WORLD_FRAME, robot_frame
from knode_swarm_ros.logic.contract.orientation import yaw_quaternion
from knode_swarm_ros.logic.contract.rep105 import TWIST_FRAMES, fields_to_state, state_to_fields

__all__ = [
    'time_msg',
    'time_ns',
    'yaw_quaternion',
    'state_to_odom',
    'odom_to_state',
    'odom_to_cdr',
    'fields_to_cdr',
    'odom_from_cdr',
    'odom_fields_from_cdr',
    'CdrError',
    'TWIST_FRAMES',
    'command_msg_type',
    'command_to_msg',
    'command_to_cdr',
    'command_from_cdr',
    'command_fields_from_cdr',
    'string_to_cdr',
    'CDR_LE',
    'cdr_pad',
    'cdr_put_string',
    'msg_to_command',
    'STATE_MESSAGES',
    'COMMAND_MESSAGES',
    'pose_to_cdr',
    'pose_from_cdr',
    'twist_to_cdr',
    'twist_fields_from_cdr',
]

#: A fleet's ``state.type`` / ``command.type`` (logic/contract/fleet.py) -> its message class.
STATE_MESSAGES = {'odometry': Odometry, 'pose': PoseStamped}
COMMAND_MESSAGES = {'accel_stamped': AccelStamped, 'twist_stamped': TwistStamped, 'twist': Twist}

ScenarioLike = Union[str, Scenario]


def _spec(scenario: ScenarioLike) -> Scenario:
    return scenario if isinstance(scenario, Scenario) else get_scenario(scenario)


def time_msg(ns: int) -> Time:
    """``builtin_interfaces/Time`` of a non-negative stamp in integer nanoseconds."""
    ns = int(ns)
    if ns < 0:
        raise ValueError(f'stamps before time 0 cannot be represented, got {ns} ns')
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def time_ns(stamp: Time) -> int:
    """Integer nanoseconds of a ``builtin_interfaces/Time``."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def state_to_odom(
    robot: int,
    ns: int,
    z,
    scenario: ScenarioLike,
    velocity: Optional[np.ndarray] = None,
    frame_id: str = WORLD_FRAME,
    child_frame_id: Optional[str] = None,
) -> Odometry:
    """Odometry of robot ``robot``'s state ``z [d]`` at stamp ``ns`` (see :mod:`.odom_mapping`).

    ``velocity`` (``position_heading`` only, optional, world frame) fills twist.linear, for information;
    ``child_frame_id`` defaults to ``robot_<robot>/base_link``.
    """
    position, quaternion, linear = state_to_fields(z, _spec(scenario), velocity)
    msg = Odometry()
    msg.header.stamp = time_msg(ns)
    msg.header.frame_id = frame_id
    msg.child_frame_id = robot_frame(robot) if child_frame_id is None else child_frame_id
    pos = msg.pose.pose.position
    o = msg.pose.pose.orientation
    lin = msg.twist.twist.linear
    pos.x, pos.y, pos.z = position
    o.x, o.y, o.z, o.w = quaternion
    lin.x, lin.y, lin.z = linear
    return msg


def odom_to_state(msg: Odometry, scenario: ScenarioLike, twist_frame: str = 'body') -> np.ndarray:
    """State ``z [d]`` float64 of an Odometry message, its twist read in ``twist_frame`` (``body``:
    REP 105; ``world``) (no validation: callers check finiteness)."""
    p = msg.pose.pose.position
    o = msg.pose.pose.orientation
    v = msg.twist.twist.linear
    return fields_to_state(
        (p.x, p.y, p.z), (o.x, o.y, o.z, o.w), (v.x, v.y, v.z), _spec(scenario), twist_frame
    )


# --- serialized Odometry (CDR, as rmw_fastrtps puts it on the wire) ---------------------------
class CdrError(KnodeError, ValueError):
    """Bytes that are not a serialized nav_msgs/Odometry."""


CDR_LE = b'\x00\x01\x00\x00'  # encapsulation: plain CDR, little endian
_ZEROS_36 = bytes(8 * 36)  # a zero covariance


def cdr_pad(buf: bytearray, to: int) -> None:
    """Zero bytes up to the next multiple of ``to`` after the 4-byte encapsulation header."""
    buf.extend(bytes((-(len(buf) - 4)) % to))


def cdr_put_string(buf: bytearray, text: str) -> None:
    """Append a CDR string (aligned length, UTF-8 bytes, NUL)."""
    raw = text.encode('utf-8') + b'\x00'
    cdr_pad(buf, 4)
    buf.extend(struct.pack('<I', len(raw)))
    buf.extend(raw)


def odom_to_cdr(
    robot: int,
    ns: int,
    z,
    scenario: ScenarioLike,
    velocity: Optional[np.ndarray] = None,
    frame_id: str = WORLD_FRAME,
    child_frame_id: Optional[str] = None,
) -> bytes:
    """The serialized form of ``state_to_odom(robot, ns, z, scenario, velocity, frame_id,
    child_frame_id)``, built directly."""
    position, quaternion, linear = state_to_fields(z, _spec(scenario), velocity)
    return fields_to_cdr(robot, ns, position, quaternion, linear, (0.0, 0.0, 0.0), frame_id, child_frame_id)


def fields_to_cdr(
    robot: int,
    ns: int,
    position,
    quaternion,
    linear,
    angular,
    frame_id: str = WORLD_FRAME,
    child_frame_id: Optional[str] = None,
) -> bytes:
    """A serialized Odometry of the given pose (position ``[3]``, orientation ``[4]``) and body
    twist (linear ``[3]``, angular ``[3]``), covariances zero (e.g. ``odom_mapping.unicycle_fields``)."""
    if ns < 0:
        raise ValueError(f'stamps before time 0 cannot be represented, got {ns} ns')
    buf = bytearray(CDR_LE)
    buf.extend(struct.pack('<iI', ns // 1_000_000_000, ns % 1_000_000_000))
    cdr_put_string(buf, frame_id)
    cdr_put_string(buf, robot_frame(robot) if child_frame_id is None else child_frame_id)
    cdr_pad(buf, 8)
    buf.extend(struct.pack('<7d', *position, *quaternion))
    buf.extend(_ZEROS_36)
    buf.extend(struct.pack('<6d', *linear, *angular))
    buf.extend(_ZEROS_36)
    return bytes(buf)


def odom_fields_from_cdr(
    data: bytes,
) -> Tuple[int, str, Tuple[float, ...], Tuple[float, ...], Tuple[float, ...]]:
    """(stamp ns, child_frame_id, pose (x, y, z, qx, qy, qz, qw), twist.linear [3], twist.angular [3])
    of a serialized Odometry, as it is on the wire (no frame change).

    Reads plain CDR (XCDR1) in either byte order, as rmw_fastrtps writes it.

    Raises:
        CdrError: not a serialized Odometry (unknown encapsulation, truncated, bad strings).
    """
    try:
        if len(data) < 4 or data[0] != 0 or data[1] not in (0, 1):
            raise CdrError(f'unknown CDR encapsulation {bytes(data[:4]).hex()}')
        e = '<' if data[1] == 1 else '>'
        pos = 4
        sec, nanosec = struct.unpack_from(e + 'iI', data, pos)
        pos += 8
        frames = []
        for _ in range(2):
            pos += (-(pos - 4)) % 4
            (length,) = struct.unpack_from(e + 'I', data, pos)
            pos += 4
            if length < 1 or pos + length > len(data) or data[pos + length - 1] != 0:
                raise CdrError('bad string in the header')
            frames.append(bytes(data[pos : pos + length - 1]).decode('utf-8', errors='replace'))
            pos += length
        pos += (-(pos - 4)) % 8
        pose = struct.unpack_from(e + '7d', data, pos)
        pos += 56 + 8 * 36
        twist = struct.unpack_from(e + '6d', data, pos)
        if pos + 48 + 8 * 36 != len(data):
            raise CdrError(f'{len(data)} bytes, expected {pos + 48 + 8 * 36}')
    except struct.error as exc:
        raise CdrError(f'truncated Odometry ({len(data)} bytes): {exc}') from None
    ns = int(sec) * 1_000_000_000 + int(nanosec)
    return ns, frames[1], pose, twist[:3], twist[3:]


def odom_from_cdr(
    data: bytes, scenario: ScenarioLike, twist_frame: str = 'body'
) -> Tuple[int, str, np.ndarray]:
    """(stamp ns, child_frame_id, state ``z [d]``) of a serialized Odometry, its twist read in
    ``twist_frame`` (as :func:`odom_to_state`).

    Raises:
        CdrError: not a serialized Odometry (see :func:`odom_fields_from_cdr`).
    """
    ns, child, pose, linear, _ = odom_fields_from_cdr(data)
    return ns, child, fields_to_state(pose[:3], pose[3:7], linear, _spec(scenario), twist_frame)


def command_msg_type(scenario: ScenarioLike):
    """AccelStamped (acceleration commands) or TwistStamped (velocity commands)."""
    return AccelStamped if _spec(scenario).command == 'acceleration' else TwistStamped


def command_to_msg(ns: int, u, scenario: ScenarioLike):
    """Command message for ``u [m]`` echoing the state stamp ``ns``."""
    spec = _spec(scenario)
    if spec.command == 'acceleration':
        msg = AccelStamped()
        vec = msg.accel.linear
    else:
        msg = TwistStamped()
        vec = msg.twist.linear
    vec.x, vec.y, vec.z = _command_linear(u)
    msg.header.stamp = time_msg(ns)
    msg.header.frame_id = WORLD_FRAME
    return msg


def _command_linear(u) -> Tuple[float, float, float]:
    """``u [m]`` (2 or 3 entries) as the three floats of ``linear`` (z = 0 in 2D)."""
    u = np.asarray(u, dtype=np.float64)
    return float(u[0]), float(u[1]), float(u[2]) if u.shape[0] > 2 else 0.0


def command_to_cdr(ns: int, u, scenario: ScenarioLike) -> bytes:
    """The serialized form of ``command_to_msg(ns, u, scenario)``, built directly (a hosting
    process publishes 100s of commands a step: no message objects)."""
    if ns < 0:
        raise ValueError(f'stamps before time 0 cannot be represented, got {ns} ns')
    linear = _command_linear(u)
    buf = bytearray(CDR_LE)
    buf.extend(struct.pack('<iI', ns // 1_000_000_000, ns % 1_000_000_000))
    cdr_put_string(buf, WORLD_FRAME)
    cdr_pad(buf, 8)
    buf.extend(struct.pack('<6d', *linear, 0.0, 0.0, 0.0))
    return bytes(buf)


_HEADER = struct.Struct('<iII')  # stamp sec, nanosec; frame_id's length
_LINEAR = struct.Struct('<3d')
# The encapsulations rclpy's deserializer (Fast CDR in rmw_fastrtps) takes, little endian only, and
# the alignment of a double in each: (PL_)CDR 8, XCDR2 (CDR2, D_CDR2, PL_CDR2) 4.
_COMMAND_ALIGN = {1: 8, 3: 8, 7: 4, 9: 4, 11: 4}


def command_from_cdr(data: bytes, scenario: ScenarioLike) -> Tuple[int, np.ndarray]:
    """(stamp ns, ``u [m]`` float64) of a serialized AccelStamped (acceleration commands) or
    TwistStamped (velocity commands), ``u`` = linear x, y (and z in 3D): :func:`msg_to_command` of the
    message rclpy would deserialize, read without building it (the simulator takes 100s a step).

    Raises:
        CdrError: see :func:`command_fields_from_cdr`.
    """
    return command_fields_from_cdr(data, range(_spec(scenario).command_dim))


def command_fields_from_cdr(data: bytes, fields: Sequence[int]) -> Tuple[int, np.ndarray]:
    """(stamp ns, ``u`` float64) of a serialized AccelStamped or TwistStamped, ``u`` = the entries
    ``fields`` of (linear.x, .y, .z, angular.x, .y, .z) (a robot model's
    :class:`~knode_swarm_ros.logic.simulator.robot_models.CommandWire`).

    Accepts and refuses what rclpy's deserializer does (tested on valid and mutated bytes): the
    little-endian encapsulations of :data:`_COMMAND_ALIGN`, the frame_id's NUL unchecked, bytes
    after the message ignored.

    Raises:
        CdrError: not a serialized command (unknown encapsulation, truncated, bad frame_id).
    """
    align = _COMMAND_ALIGN.get(data[1]) if len(data) >= 4 and data[0] == 0 else None
    if align is None:
        raise CdrError(f'unknown CDR encapsulation {bytes(data[:4]).hex()}')
    try:
        sec, nanosec, length = _HEADER.unpack_from(data, 4)
        end = 16 + length
        if end > len(data):
            raise CdrError(f'frame_id of {length} bytes in a message of {len(data)}')
        pos = end + (-(end - 4)) % align
        linear = _LINEAR.unpack_from(data, pos)
        if pos + 48 > len(data):
            raise CdrError(f'truncated command ({len(data)} bytes, expected {pos + 48})')
        vector = linear + _LINEAR.unpack_from(data, pos + 24)
    except struct.error as exc:
        raise CdrError(f'truncated command ({len(data)} bytes): {exc}') from None
    return sec * 1_000_000_000 + nanosec, np.array([vector[i] for i in fields], dtype=np.float64)


def string_to_cdr(text: str) -> bytes:
    """The serialized form of ``std_msgs/String(data=text)`` (a hosting process publishes a
    status per robot)."""
    buf = bytearray(CDR_LE)
    cdr_put_string(buf, text)
    return bytes(buf)


def msg_to_command(msg, scenario: ScenarioLike) -> Tuple[int, np.ndarray]:
    """(stamp ns, ``u [m]`` float64) of a command message: linear x, y (and z in 3D)."""
    spec = _spec(scenario)
    vec = msg.accel.linear if spec.command == 'acceleration' else msg.twist.linear
    u = np.array([vec.x, vec.y, vec.z][: spec.command_dim], dtype=np.float64)
    return time_ns(msg.header.stamp), u


# --- poses (geometry_msgs/PoseStamped: motion capture) and unstamped Twist -------------------
def pose_to_cdr(ns: int, position, quaternion, frame_id: str = WORLD_FRAME) -> bytes:
    """A serialized PoseStamped: header (stamp ``ns``, ``frame_id``), position ``[3]``,
    orientation ``(x, y, z, w)``; the bytes rclpy serializes for that message."""
    if ns < 0:
        raise ValueError(f'stamps before time 0 cannot be represented, got {ns} ns')
    buf = bytearray(CDR_LE)
    buf.extend(struct.pack('<iI', ns // 1_000_000_000, ns % 1_000_000_000))
    cdr_put_string(buf, frame_id)
    cdr_pad(buf, 8)
    buf.extend(struct.pack('<7d', *(float(x) for x in position), *(float(x) for x in quaternion)))
    return bytes(buf)


def pose_from_cdr(data: bytes) -> Tuple[int, str, Tuple[float, ...]]:
    """(stamp ns, header.frame_id, pose (x, y, z, qx, qy, qz, qw)) of a serialized PoseStamped,
    plain CDR in either byte order (as :func:`odom_fields_from_cdr`).

    Raises:
        CdrError: not a serialized PoseStamped (unknown encapsulation, truncated, bad string,
            wrong length).
    """
    try:
        if len(data) < 4 or data[0] != 0 or data[1] not in (0, 1):
            raise CdrError(f'unknown CDR encapsulation {bytes(data[:4]).hex()}')
        e = '<' if data[1] == 1 else '>'
        sec, nanosec, length = struct.unpack_from(e + 'iII', data, 4)
        pos = 16
        if length < 1 or pos + length > len(data) or data[pos + length - 1] != 0:
            raise CdrError('bad frame_id in the header')
        frame = bytes(data[pos : pos + length - 1]).decode('utf-8', errors='replace')
        pos += length
        pos += (-(pos - 4)) % 8
        pose = struct.unpack_from(e + '7d', data, pos)
        if pos + 56 != len(data):
            raise CdrError(f'{len(data)} bytes, expected {pos + 56}')
    except struct.error as exc:
        raise CdrError(f'truncated PoseStamped ({len(data)} bytes): {exc}') from None
    return int(sec) * 1_000_000_000 + int(nanosec), frame, pose


def twist_to_cdr(u) -> bytes:
    """A serialized geometry_msgs/Twist of the velocity ``u [m]`` (linear; angular zero)."""
    return CDR_LE + struct.pack('<6d', *_command_linear(u), 0.0, 0.0, 0.0)


def twist_fields_from_cdr(data: bytes, fields: Sequence[int]) -> np.ndarray:
    """``u`` float64: the entries ``fields`` of (linear.x, .y, .z, angular.x, .y, .z) of a
    serialized geometry_msgs/Twist (no header, so no stamp).

    Raises:
        CdrError: unknown encapsulation or fewer than 48 bytes after it.
    """
    if len(data) < 4 or data[0] != 0 or data[1] not in (0, 1):
        raise CdrError(f'unknown CDR encapsulation {bytes(data[:4]).hex()}')
    if len(data) < 52:
        raise CdrError(f'truncated Twist ({len(data)} bytes, expected 52)')
    vector = struct.unpack_from(('<' if data[1] == 1 else '>') + '6d', data, 4)
    return np.array([vector[i] for i in fields], dtype=np.float64)
