"""Write swarm states as a rosbag2-style MCAP bag, without ROS (``mcap`` + ``mcap-ros2-support``).

The bag holds what a real ``ros2 bag record`` of the swarm would hold: one topic per robot,
``/robot_<id>/odom``, nav_msgs/msg/Odometry per REP 105, ``header.stamp`` = the state's time,
``frame_id`` ``world``, ``child_frame_id`` ``robot_<id>/base_link``, pose in the world frame and
twist in the child frame (DESIGN.md, "ROS 2 interfaces"). The state goes into the message by
the ROS-free :func:`knode_swarm_ros.nodes.odom_mapping.state_to_fields`, the same function the
nodes' conversion module calls (the one mapping: flock2d p, identity orientation and v;
boids3d p, the heading quaternion and the optional velocity in the child frame). Only the
message layout is written here, as dicts for mcap-ros2-support; tests/test_import_bag.py checks
that both produce the same messages.

``mcap`` is not a robot runtime dependency: it is imported only when a bag is written.
``training.import_bag`` reads these bags (and real ones) back into trajectory files.

Message definitions (the ``ros2msg`` schema text every MCAP channel carries) are built from
the ``.msg`` files of the installed message packages (``<prefix>/share/<pkg>/msg/<Type>.msg``
for every prefix on ``AMENT_PREFIX_PATH`` and ``sys.prefix``), concatenated with their
dependencies the way rosbag2 does. Only a package that is not installed falls back to an
embedded definition (tf2_msgs/TFMessage, a one-liner).

Output layout: a path ending in ``.mcap`` is one MCAP file; any other path is a rosbag2 bag
directory laid out as rosbag2 (Jazzy) writes one: ``metadata.yaml`` (version 9, with type hashes
from the packages' ``.json`` type descriptions) plus ``<name>_0.mcap``, ``<name>_1.mcap``, ...
when split. (Checked here against the importer, not against ``ros2 bag``: no rosbag2 is
installed in this environment. Channels carry no ``offered_qos_profiles`` metadata, which
mcap-ros2-support's writer does not set; ``ros2 bag play`` then uses default QoS.)
"""
from __future__ import annotations

import json
import os
import re
import shutil
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np

from .common import WORLD_FRAME, robot_frame
from .odom_mapping import state_to_fields
from .orientation import heading_to_quaternion, yaw_quaternion

__all__ = ["write_odometry_bag", "BagWriter", "message_definition", "heading_to_quaternion",
           "odometry_message", "yaw_quaternion", "stamp_to_ns", "ns_to_stamp", "BagWriteError", "ODOMETRY",
           "POSE_STAMPED", "TF_MESSAGE"]

ODOMETRY = "nav_msgs/msg/Odometry"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"

#: The separator rosbag2 (and ROS 1) put between concatenated message definitions.
_SEPARATOR = "=" * 80

#: ros2msg primitive types (no dependency to resolve).
_PRIMITIVES = frozenset({"bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16",
                         "int32", "uint32", "int64", "uint64", "string", "wstring"})

#: Definitions used only when the package is not installed anywhere on the search path.
#: tf2_msgs is not among the ros-jazzy-* wheels this project installs.
_EMBEDDED = {
    "tf2_msgs/msg/TFMessage": "geometry_msgs/TransformStamped[] transforms\n",
}

PathLike = Union[str, os.PathLike]


class BagWriteError(ValueError):
    """The states, stamps or output path cannot be written as a bag; the message says which."""


# --- Message definitions ------------------------------------------------------------------

def _normalise_type(name: str) -> str:
    """``pkg/Type`` or ``pkg/msg/Type`` -> ``pkg/msg/Type``."""
    parts = name.strip().split("/")
    if len(parts) == 2:
        return f"{parts[0]}/msg/{parts[1]}"
    if len(parts) == 3 and parts[1] == "msg":
        return name.strip()
    raise BagWriteError(f"not a message type name: {name!r} (expected pkg/msg/Type)")


def _share_prefixes() -> List[Path]:
    prefixes = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    prefixes.append(sys.prefix)
    seen, out = set(), []
    for p in prefixes:
        if p not in seen:
            seen.add(p)
            out.append(Path(p) / "share")
    return out


def _msg_file(type_name: str) -> Optional[Path]:
    pkg, _, msg = type_name.split("/")
    for share in _share_prefixes():
        candidate = share / pkg / "msg" / f"{msg}.msg"
        if candidate.is_file():
            return candidate
    return None


def _definition_text(type_name: str) -> Tuple[str, str]:
    """(text of the .msg definition, where it came from)."""
    path = _msg_file(type_name)
    if path is not None:
        return path.read_text(encoding="utf-8"), str(path)
    if type_name in _EMBEDDED:
        return _EMBEDDED[type_name], "embedded"
    raise BagWriteError(f"no message definition for {type_name}: {type_name.split('/')[0]} is not installed "
                        f"(looked for share/{type_name.split('/')[0]}/msg/{type_name.split('/')[2]}.msg under "
                        f"{', '.join(str(s.parent) for s in _share_prefixes())})")


def _dependencies(type_name: str, text: str) -> List[str]:
    """Complex field types of a definition, as pkg/msg/Type, in order of appearance."""
    pkg = type_name.split("/")[0]
    deps: List[str] = []
    for raw in text.splitlines():
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        tokens = line.split()
        if len(tokens) < 2 or "=" in tokens[1]:  # constants are primitive: TYPE NAME=VALUE
            continue
        base = re.sub(r"\[.*\]$", "", tokens[0])     # arrays: T[], T[3], T[<=3]
        base = re.sub(r"<=\d+$", "", base)           # bounded strings: string<=5
        if base in _PRIMITIVES:
            continue
        if base == "Header":                         # ROS 1 shorthand, still accepted by rosidl
            base = "std_msgs/Header"
        dep = _normalise_type(base if "/" in base else f"{pkg}/{base}")
        if dep not in deps:
            deps.append(dep)
    return deps


def message_definition(type_name: str) -> str:
    """The full ros2msg schema text of ``type_name`` (``pkg/msg/Type`` or ``pkg/Type``).

    The type's own ``.msg`` text comes first, then one section per dependency (depth first,
    each once), each introduced by a line of 80 ``=`` and ``MSG: pkg/Type``, as rosbag2 writes
    it into MCAP schema records.
    """
    root = _normalise_type(type_name)
    order: List[str] = []
    texts: Dict[str, str] = {}

    def visit(name: str) -> None:
        if name in texts:
            return
        text, _ = _definition_text(name)
        texts[name] = text
        order.append(name)
        for dep in _dependencies(name, text):
            visit(dep)

    visit(root)
    sections = [texts[root].rstrip("\n") + "\n"]
    for name in order[1:]:
        pkg, _, msg = name.split("/")
        sections.append(f"{_SEPARATOR}\nMSG: {pkg}/{msg}\n{texts[name].rstrip(chr(10))}\n")
    return "".join(sections)


def _type_hash(type_name: str) -> str:
    """The RIHS01 type hash from the package's ``.json`` type description, or "" if unknown."""
    path = _msg_file(type_name)
    if path is None:
        return ""
    try:
        data = json.loads(path.with_suffix(".json").read_text(encoding="utf-8"))
        for entry in data.get("type_hashes", []):
            if entry.get("type_name") == type_name:
                return str(entry.get("hash_string", ""))
    except (OSError, ValueError):
        pass
    return ""


# --- Conversions ----------------------------------------------------------------------------

def stamp_to_ns(stamp: Any) -> int:
    """builtin_interfaces/Time (object or dict with sec, nanosec) -> integer nanoseconds."""
    if isinstance(stamp, Mapping):
        return int(stamp["sec"]) * 1_000_000_000 + int(stamp["nanosec"])
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def ns_to_stamp(ns: int) -> Dict[str, int]:
    """Integer nanoseconds -> ``{"sec", "nanosec"}`` with 0 <= nanosec < 1e9 (sec floors)."""
    sec, nanosec = divmod(int(ns), 1_000_000_000)
    if not (-2 ** 31 <= sec < 2 ** 31):
        raise BagWriteError(f"stamp {ns} ns does not fit builtin_interfaces/Time (int32 seconds)")
    return {"sec": sec, "nanosec": nanosec}


def odometry_message(scenario: str, z: np.ndarray, stamp_ns: int, robot_id: int, frame_id: str = WORLD_FRAME,
                     child_frame_id: Optional[str] = None, velocity: Optional[np.ndarray] = None) -> Dict[str, Any]:
    """One nav_msgs/Odometry as a dict (mcap-ros2-support encodes dicts) for state ``z[d]``,
    field for field what :func:`knode_swarm_ros.nodes.conversions.state_to_odom` publishes.

    ``velocity`` (boids3d only, optional, world frame) fills twist.linear (in the child frame),
    for information; ``child_frame_id`` defaults to ``robot_<id>/base_link``.
    """
    if scenario not in ("flock2d", "boids3d"):
        raise BagWriteError(f"unknown scenario {scenario!r}; known: boids3d, flock2d")
    (px, py, pz), (qx, qy, qz, qw), lin = state_to_fields(z, scenario, velocity)
    position = {"x": px, "y": py, "z": pz}
    linear = dict(zip("xyz", lin))
    zero36 = [0.0] * 36
    return {
        "header": {"stamp": ns_to_stamp(stamp_ns), "frame_id": frame_id},
        "child_frame_id": robot_frame(robot_id) if child_frame_id is None else child_frame_id,
        "pose": {"pose": {"position": position, "orientation": {"x": qx, "y": qy, "z": qz, "w": qw}},
                 "covariance": zero36},
        "twist": {"twist": {"linear": linear, "angular": {"x": 0.0, "y": 0.0, "z": 0.0}},
                  "covariance": zero36},
    }


# --- Writer --------------------------------------------------------------------------------

@dataclass
class _TopicInfo:
    type_name: str
    count: int = 0


@dataclass
class _FileInfo:
    name: str
    count: int = 0
    first_ns: Optional[int] = None
    last_ns: Optional[int] = None


class BagWriter:
    """Write ROS 2 messages (dicts or objects with the fields) into an MCAP file or a rosbag2 directory.

    ``BagWriter(path, split_messages=None)``: ``path`` ending in ``.mcap`` -> one file, else a
    bag directory with ``metadata.yaml``; ``split_messages`` starts a new ``<name>_<i>.mcap``
    after that many messages (directories only); ``compression`` (zstd, lz4, none) and
    ``chunk_size`` (bytes) are MCAP's chunk settings. Nothing appears at ``path`` until
    :meth:`close` succeeds (the bag is written in a temporary sibling and renamed); an
    existing ``path`` is refused unless ``overwrite``. Use as a context manager.

    ``write(topic, type_name, message, stamp_ns, log_time_ns=None)``: ``log_time_ns`` (the
    receive time in a real recording) defaults to ``stamp_ns``.
    """

    def __init__(self, path: PathLike, split_messages: Optional[int] = None, overwrite: bool = False,
                 compression: str = "zstd", chunk_size: int = 1024 * 1024):
        try:
            from mcap.writer import CompressionType
            from mcap_ros2.writer import Writer as Ros2Writer
        except ImportError as exc:  # pragma: no cover - exercised only without the dev requirements
            raise BagWriteError(f"writing bags needs the mcap and mcap-ros2-support packages ({exc}); "
                                "pip install mcap mcap-ros2-support") from None
        self._Ros2Writer = Ros2Writer
        self._chunk_size = int(chunk_size)
        self._compression = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                             "none": CompressionType.NONE}[compression]
        self.path = Path(path)
        self.single_file = self.path.suffix == ".mcap"
        if split_messages is not None and (self.single_file or int(split_messages) < 1):
            raise BagWriteError("split_messages needs a bag directory path (not .mcap) and a positive count")
        self.split_messages = None if split_messages is None else int(split_messages)
        if self.path.exists() and not overwrite:
            raise BagWriteError(f"{self.path}: already exists (a bag is never overwritten unless asked)")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._tmp = Path(tempfile.mkdtemp(prefix=f".{self.path.name}.", suffix=".tmp", dir=self.path.parent))
        self._topics: Dict[str, _TopicInfo] = {}
        self._files: List[_FileInfo] = []
        self._schemas: Dict[str, Any] = {}
        self._writer = None
        self._stream = None
        self._closed = False
        #: What :meth:`close` returned (None before).
        self.summary: Optional[Dict[str, Any]] = None

    # file handling
    def _file_name(self, index: int) -> str:
        return self.path.name if self.single_file else f"{self.path.name}_{index}.mcap"

    def _open_next(self) -> None:
        self._finish_current()
        info = _FileInfo(self._file_name(len(self._files)))
        self._files.append(info)
        self._stream = open(self._tmp / info.name, "wb")
        self._writer = self._Ros2Writer(self._stream, chunk_size=self._chunk_size, compression=self._compression)
        self._schemas = {}  # schemas and channels are per file

    def _finish_current(self) -> None:
        if self._writer is not None:
            self._writer.finish()
            self._stream.close()
            self._writer = None
            self._stream = None

    def write(self, topic: str, type_name: str, message: Any, stamp_ns: int,
              log_time_ns: Optional[int] = None) -> None:
        """Append one message (its ``header.stamp`` is the caller's; ``stamp_ns`` orders the bag)."""
        if self._closed:
            raise BagWriteError("write after close")
        type_name = _normalise_type(type_name)
        known = self._topics.get(topic)
        if known is not None and known.type_name != type_name:
            raise BagWriteError(f"topic {topic} already carries {known.type_name}, not {type_name}")
        log_ns = int(stamp_ns if log_time_ns is None else log_time_ns)
        if log_ns < 0:
            raise BagWriteError(f"topic {topic}: negative log time {log_ns} ns (MCAP times are unsigned)")
        if (self._writer is None or (self.split_messages is not None
                                     and self._files[-1].count >= self.split_messages)):
            self._open_next()
        schema = self._schemas.get(type_name)
        if schema is None:
            schema = self._writer.register_msgdef(type_name, message_definition(type_name))
            self._schemas[type_name] = schema
        self._writer.write_message(topic, schema, message, log_time=log_ns, publish_time=log_ns)
        info = self._files[-1]
        info.count += 1
        info.first_ns = log_ns if info.first_ns is None else min(info.first_ns, log_ns)
        info.last_ns = log_ns if info.last_ns is None else max(info.last_ns, log_ns)
        self._topics.setdefault(topic, _TopicInfo(type_name)).count += 1

    def _metadata(self) -> Dict[str, Any]:
        firsts = [f.first_ns for f in self._files if f.first_ns is not None]
        lasts = [f.last_ns for f in self._files if f.last_ns is not None]
        start = min(firsts) if firsts else 0
        duration = (max(lasts) - start) if lasts else 0
        return {"rosbag2_bagfile_information": {
            "version": 9,
            "storage_identifier": "mcap",
            "duration": {"nanoseconds": duration},
            "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": sum(f.count for f in self._files),
            "topics_with_message_count": [
                {"topic_metadata": {"name": topic, "type": info.type_name, "serialization_format": "cdr",
                                    "offered_qos_profiles": "", "type_description_hash": _type_hash(info.type_name)},
                 "message_count": info.count}
                for topic, info in self._topics.items()],
            "compression_format": "",
            "compression_mode": "",
            "relative_file_paths": [f.name for f in self._files],
            "files": [{"path": f.name,
                       "starting_time": {"nanoseconds_since_epoch": f.first_ns or 0},
                       "duration": {"nanoseconds": (f.last_ns or 0) - (f.first_ns or 0)},
                       "message_count": f.count} for f in self._files],
            "custom_data": None,
            "ros_distro": "jazzy",
        }}

    def close(self) -> Dict[str, Any]:
        """Finish the file(s), write ``metadata.yaml`` (directories) and move the bag into place.

        Returns (and keeps as :attr:`summary`): ``path``, ``files``, ``messages``, ``topics``
        ({topic: count}).
        """
        if self._closed:
            raise BagWriteError("close called twice")
        try:
            if self._writer is None:
                self._open_next()  # an empty bag is still a valid bag
            self._finish_current()
            if self.single_file:
                os.replace(self._tmp / self.path.name, self.path)
            else:
                import yaml
                with open(self._tmp / "metadata.yaml", "w", encoding="utf-8") as fh:
                    yaml.safe_dump(self._metadata(), fh, sort_keys=False)
                if self.path.exists():
                    shutil.rmtree(self.path) if self.path.is_dir() else self.path.unlink()
                os.replace(self._tmp, self.path)
        finally:
            self._closed = True
            if self._tmp.exists():
                shutil.rmtree(self._tmp, ignore_errors=True)
        self.summary = {"path": str(self.path), "files": [f.name for f in self._files],
                        "messages": sum(f.count for f in self._files),
                        "topics": {t: i.count for t, i in self._topics.items()}}
        return self.summary

    def abort(self) -> None:
        """Drop everything written so far; nothing appears at ``path``."""
        if not self._closed:
            self._closed = True
            try:
                if self._stream is not None:
                    self._stream.close()
            finally:
                shutil.rmtree(self._tmp, ignore_errors=True)

    def __enter__(self) -> "BagWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc_type is None:
            self.close()
        else:
            self.abort()
        return False


def _stamps_ns(stamps: Optional[np.ndarray], T: int, n: int, dt: float) -> np.ndarray:
    """Per-robot stamps ``[T, n]`` in integer nanoseconds from seconds ``[T]``/``[T, n]`` (float)
    or nanoseconds (integer arrays)."""
    if stamps is None:
        s = np.rint(np.arange(T) * float(dt) * 1e9).astype(np.int64)
        return np.repeat(s[:, None], n, axis=1)
    s = np.asarray(stamps)
    if s.shape not in ((T,), (T, n)):
        raise BagWriteError(f"stamps must have shape [T] = [{T}] or [T, n] = [{T}, {n}], got {list(s.shape)}")
    if np.issubdtype(s.dtype, np.integer):
        ns = s.astype(np.int64)
    else:
        if not np.all(np.isfinite(s)):
            raise BagWriteError("stamps hold a non-finite value")
        ns = np.rint(s.astype(np.float64) * 1e9).astype(np.int64)
    if ns.ndim == 1:
        ns = np.repeat(ns[:, None], n, axis=1)
    return ns


def write_odometry_bag(path: PathLike, states: np.ndarray, dt: float, scenario: str,
                       stamps: Optional[np.ndarray] = None, topic_fmt: str = "/robot_{id}/odom",
                       ids: Optional[Sequence[int]] = None, mask: Optional[np.ndarray] = None,
                       velocities: Optional[np.ndarray] = None, frame_id: str = WORLD_FRAME,
                       child_frame_fmt: str = "robot_{id}/base_link", split_messages: Optional[int] = None,
                       overwrite: bool = False) -> Dict[str, Any]:
    """Write one swarm run ``states[T, n, d]`` as nav_msgs/Odometry messages, one topic per robot.

    Args:
        path: ``*.mcap`` for one MCAP file, anything else for a rosbag2 directory.
        states: float ``[T, n, d]`` in the layout of ``scenario`` (flock2d d = 4, boids3d d = 6).
        dt: seconds between frames; used for the stamps when ``stamps`` is None (frame k at k dt).
        scenario: ``flock2d`` or ``boids3d`` (decides the state -> Odometry mapping, see module doc).
        stamps: optional times of the frames: float seconds or integer nanoseconds, ``[T]`` (all
            robots alike) or ``[T, n]`` (per robot, e.g. with jitter). Must be >= 0.
        topic_fmt, child_frame_fmt: formatted with ``id=`` the robot's id.
        ids: robot ids, default 0 .. n-1.
        mask: optional bool ``[T, n]``; False = that robot published nothing at that frame (a
            dropped stretch). Masked-out states may be anything, unmasked ones must be finite.
        velocities: boids3d only, optional ``[T, n, 3]``: the velocity applied over the last step,
            written to twist.linear for information (as the simulator publishes it).
        frame_id: ``header.frame_id`` of every message.
        split_messages: bag directories only: start a new MCAP file after this many messages.
        overwrite: replace an existing bag at ``path``.

    Messages are written in time order (log time = header stamp). Returns the summary of
    :meth:`BagWriter.close`. Raises :class:`BagWriteError` on bad input (nothing is written).
    """
    states = np.asarray(states, dtype=np.float64)
    if scenario not in ("flock2d", "boids3d"):
        raise BagWriteError(f"unknown scenario {scenario!r}; known: boids3d, flock2d")
    d = 4 if scenario == "flock2d" else 6
    if states.ndim != 3 or states.shape[2] != d or states.shape[0] < 1 or states.shape[1] < 1:
        raise BagWriteError(f"states must be [T, n, {d}] for {scenario}, got {list(states.shape)}")
    T, n, _ = states.shape
    ids = list(range(n)) if ids is None else [int(i) for i in ids]
    if len(ids) != n or len(set(ids)) != n:
        raise BagWriteError(f"ids must be {n} distinct integers, got {ids}")
    mask = np.ones((T, n), dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
    if mask.shape != (T, n):
        raise BagWriteError(f"mask must have shape [T, n] = [{T}, {n}], got {list(mask.shape)}")
    if not np.all(np.isfinite(states[mask])):
        t, i = (int(v) for v in np.argwhere(mask & ~np.all(np.isfinite(states), axis=2))[0])
        raise BagWriteError(f"states[{t}, {i}] (robot {ids[i]}) is not finite and not masked out")
    if velocities is not None:
        velocities = np.asarray(velocities, dtype=np.float64)
        if scenario != "boids3d" or velocities.shape != (T, n, 3):
            raise BagWriteError(f"velocities are for boids3d, shape [T, n, 3] = [{T}, {n}, 3]; got "
                                f"{list(velocities.shape)} for {scenario}")
    ns = _stamps_ns(stamps, T, n, dt)
    if np.any(ns[mask] < 0):
        raise BagWriteError("stamps must be >= 0")
    order = sorted(((int(ns[t, i]), i, t) for t in range(T) for i in range(n) if mask[t, i]))
    with BagWriter(path, split_messages=split_messages, overwrite=overwrite) as writer:
        for stamp, i, t in order:
            msg = odometry_message(scenario, states[t, i], stamp, ids[i], frame_id, child_frame_fmt.format(id=ids[i]),
                                   None if velocities is None else velocities[t, i])
            writer.write(topic_fmt.format(id=ids[i]), ODOMETRY, msg, stamp)
    return writer.summary
