"""Message types, stamps and the state -> Odometry mapping of the bags, in one place (no ROS).

* type names: :data:`ODOMETRY`, :data:`POSE_STAMPED`, :data:`TF_MESSAGE` (``pkg/msg/Type``,
  as rosbag2 and rosbags name them; ROS 1 ``pkg/Type`` names are normalised by rosbags on
  reading and by :func:`normalise_type` on writing);
* stamps: ``builtin_interfaces/Time`` <-> integer nanoseconds (:func:`stamp_to_ns`,
  :func:`ns_to_stamp`);
* :func:`odometry_message`: a state as nav_msgs/Odometry, field for field what
  :func:`knode_swarm_ros.nodes.common.conversions.state_to_odom` publishes (tests/test_bag.py checks it);
* :func:`samples_of`: the robot poses a decoded message carries (reading);
* :func:`to_message`: a dict (or any object with the fields) as a typed rosbags message
  (writing), for the message definitions of ROS 2 Jazzy (:func:`typestore`).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any, Callable, Dict, List, Mapping, Optional, Tuple

import numpy as np

from knode_swarm_ros.core.errors import KnodeError
from knode_swarm_ros.logic.common import WORLD_FRAME, robot_frame
from knode_swarm_ros.logic.contract.rep105 import state_to_fields

__all__ = [
    'BagError',
    'BagWriteError',
    'ODOMETRY',
    'POSE_STAMPED',
    'TF_MESSAGE',
    'SUPPORTED_TYPES',
    'normalise_type',
    'stamp_to_ns',
    'ns_to_stamp',
    'odometry_message',
    'Sample',
    'samples_of',
    'typestore',
    'to_message',
]

ODOMETRY = 'nav_msgs/msg/Odometry'
POSE_STAMPED = 'geometry_msgs/msg/PoseStamped'
TF_MESSAGE = 'tf2_msgs/msg/TFMessage'
SUPPORTED_TYPES = (ODOMETRY, POSE_STAMPED, TF_MESSAGE)


class BagError(KnodeError, ValueError):
    """The input is not a readable bag, or its content does not fit the request; the message names
    the file, topic or frame."""


class BagWriteError(BagError):
    """The states, stamps or output path cannot be written as a bag; the message says which."""


def normalise_type(name: str) -> str:
    """``pkg/Type`` or ``pkg/msg/Type`` -> ``pkg/msg/Type``; anything else is refused."""
    parts = name.strip().split('/')
    if len(parts) == 2 and all(parts):
        return f'{parts[0]}/msg/{parts[1]}'
    if len(parts) == 3 and parts[1] == 'msg' and parts[0] and parts[2]:
        return name.strip()
    raise BagWriteError(f'not a message type name: {name!r} (expected pkg/msg/Type)')


# --- stamps ---------------------------------------------------------------------------------


def stamp_to_ns(stamp: Any) -> int:
    """builtin_interfaces/Time (object or dict with ``sec``, ``nanosec``) -> integer nanoseconds."""
    if isinstance(stamp, Mapping):
        return int(stamp['sec']) * 1_000_000_000 + int(stamp['nanosec'])
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def ns_to_stamp(ns: int) -> Dict[str, int]:
    """Integer nanoseconds -> ``{"sec", "nanosec"}`` with 0 <= nanosec < 1e9 (sec floors)."""
    sec, nanosec = divmod(int(ns), 1_000_000_000)
    if not (-(2**31) <= sec < 2**31):
        raise BagWriteError(f'stamp {ns} ns does not fit builtin_interfaces/Time (int32 seconds)')
    return {'sec': sec, 'nanosec': nanosec}


# --- writing: the state -> Odometry mapping ------------------------------------------------------


def odometry_message(
    scenario: str,
    z: np.ndarray,
    stamp_ns: int,
    robot_id: int,
    frame_id: str = WORLD_FRAME,
    child_frame_id: Optional[str] = None,
    velocity: Optional[np.ndarray] = None,
) -> Dict[str, Any]:
    """One nav_msgs/Odometry as a dict for state ``z[d]``, field for field what
    :func:`knode_swarm_ros.nodes.common.conversions.state_to_odom` publishes: REP 105 (pose in
    ``frame_id``, twist in the child frame), by the one mapping
    :func:`knode_swarm_ros.logic.contract.rep105.state_to_fields`. ``velocity`` (boids3d only,
    optional, world frame) fills twist.linear in the child frame, for information;
    ``child_frame_id`` defaults to ``robot_<id>/base_link``.
    """
    if scenario not in ('flock2d', 'boids3d'):
        raise BagWriteError(f'unknown scenario {scenario!r}; known: boids3d, flock2d')
    (px, py, pz), (qx, qy, qz, qw), lin = state_to_fields(z, scenario, velocity)
    position = {'x': px, 'y': py, 'z': pz}
    linear = dict(zip('xyz', lin))
    zero36 = [0.0] * 36
    return {
        'header': {'stamp': ns_to_stamp(stamp_ns), 'frame_id': frame_id},
        'child_frame_id': robot_frame(robot_id) if child_frame_id is None else child_frame_id,
        'pose': {
            'pose': {'position': position, 'orientation': {'x': qx, 'y': qy, 'z': qz, 'w': qw}},
            'covariance': zero36,
        },
        'twist': {
            'twist': {'linear': linear, 'angular': {'x': 0.0, 'y': 0.0, 'z': 0.0}},
            'covariance': zero36,
        },
    }


@functools.lru_cache(maxsize=None)
def typestore():
    """The rosbags typestore of ROS 2 Jazzy's message definitions (what the bags are written with,
    and what bags without embedded definitions, e.g. rosbag2 sqlite3 of Humble and earlier, are
    read with)."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


_NUMPY = {
    'bool': np.bool_,
    'byte': np.uint8,
    'char': np.uint8,
    'int8': np.int8,
    'uint8': np.uint8,
    'int16': np.int16,
    'uint16': np.uint16,
    'int32': np.int32,
    'uint32': np.uint32,
    'int64': np.int64,
    'uint64': np.uint64,
    'float32': np.float32,
    'float64': np.float64,
}
_PYTHON = {'string': str, 'bool': bool, 'float32': float, 'float64': float}


def _converter(store, kind, spec) -> Tuple[Callable[[Any], Any], Callable[[], Any]]:
    """(build a field value from a dict/object value, the default of an unset field) for one field
    type: what a ROS message constructor leaves unset is zero or empty."""
    from rosbags.typesys.base import Nodetype

    if kind == Nodetype.NAME:  # a nested message
        return (lambda v, t=spec: to_message(t, v, store)), (lambda t=spec: to_message(t, {}, store))
    if kind == Nodetype.BASE:
        cast = _PYTHON.get(spec[0], int)
        return cast, (lambda: cast())
    (sub_kind, sub_spec), length = spec  # ARRAY (fixed length) or SEQUENCE
    size = length if kind == Nodetype.ARRAY else 0
    if sub_kind == Nodetype.BASE and sub_spec[0] in _NUMPY:
        dtype = _NUMPY[sub_spec[0]]
        return (lambda v: np.asarray(v, dtype=dtype)), (lambda: np.zeros(size, dtype=dtype))
    build, default = _converter(store, sub_kind, sub_spec)
    return (lambda v: [build(x) for x in v]), (lambda: [default() for _ in range(size)])


@functools.lru_cache(maxsize=None)
def _plan(store, type_name: str):
    """(message class, [(field, build, default)], field names) of ``type_name``, built once."""
    if type_name not in store.fielddefs:
        raise BagWriteError(f'no message definition for {type_name}')
    _, fields = store.fielddefs[type_name]
    plan = [(name, *_converter(store, kind, spec)) for name, (kind, spec) in fields]
    return store.types[type_name], plan, frozenset(name for name, _, _ in plan)


def to_message(type_name: str, value: Any, store=None) -> Any:
    """``value`` as a rosbags message of ``type_name``: a dict (fields left out take their default,
    zero or empty, as in a ROS message constructor; an unknown key is an error naming it), or an
    object with the fields (e.g. an rclpy message), nested alike."""
    store = store or typestore()
    cls, plan, names = _plan(store, type_name)
    if isinstance(value, cls):
        return value
    if isinstance(value, dict):
        if not value.keys() <= names:
            unknown = sorted(set(value) - names)
            raise BagWriteError(
                f'{type_name} has no field {unknown[0]!r} (fields: {", ".join(name for name, _, _ in plan)})'
            )
        return cls(
            **{name: build(value[name]) if name in value else default() for name, build, default in plan}
        )
    try:
        return cls(**{name: build(getattr(value, name)) for name, build, _ in plan})
    except AttributeError as exc:
        raise BagWriteError(f'{type_name}: a field is missing from the message ({exc})') from None


# --- reading: robot poses out of decoded messages ---------------------------------------------------


@dataclass
class Sample:
    """One observation of one robot, as carried by a message."""

    stamp_ns: int  # header.stamp
    log_ns: int  # bag log time (receive time in a recording)
    position: Tuple[float, float, float]
    orientation: Tuple[float, float, float, float]  # x, y, z, w
    linear: Optional[Tuple[float, float, float]]  # Odometry twist.twist.linear, else None
    frame_id: str


def _xyz(v) -> Tuple[float, float, float]:
    return (float(v.x), float(v.y), float(v.z))


def _quat(q) -> Tuple[float, float, float, float]:
    return (float(q.x), float(q.y), float(q.z), float(q.w))


def samples_of(type_name: str, msg: Any, log_ns: int) -> List[Tuple[Optional[str], Sample]]:
    """``[(child frame or None, Sample)]`` carried by one decoded message of a supported type
    (ROS 1 and ROS 2 alike: rosbags gives ROS 1 times as ``sec``/``nanosec``)."""
    if type_name in (ODOMETRY, POSE_STAMPED):
        odometry = type_name == ODOMETRY
        pose = msg.pose.pose if odometry else msg.pose
        linear = _xyz(msg.twist.twist.linear) if odometry else None  # a pose carries no twist
        sample = Sample(
            stamp_to_ns(msg.header.stamp),
            log_ns,
            _xyz(pose.position),
            _quat(pose.orientation),
            linear,
            str(msg.header.frame_id),
        )
        return [(None, sample)]
    if type_name == TF_MESSAGE:
        return [
            (
                str(tf.child_frame_id).lstrip('/'),
                Sample(
                    stamp_to_ns(tf.header.stamp),
                    log_ns,
                    _xyz(tf.transform.translation),
                    _quat(tf.transform.rotation),
                    None,
                    str(tf.header.frame_id).lstrip('/'),
                ),
            )
            for tf in msg.transforms
        ]
    raise BagError(f'unsupported message type {type_name}')
