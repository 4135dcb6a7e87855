"""Read rosbag2 MCAP recordings: locate the files, list topics, pull robot poses out of messages.

The reading is done by the maintained ``mcap`` reader with ``mcap-ros2-support``'s CDR decoder
(no ROS install, no hand-written CDR parser). This module knows nothing about scenarios or
resampling; :mod:`training.import_bag` builds trajectories from what it returns.

Accepted inputs:

* a rosbag2 bag directory: ``metadata.yaml`` (storage ``mcap``) and its ``relative_file_paths``,
  read in that order (split bags);
* a bag directory without ``metadata.yaml`` (a recording that was killed): its ``*.mcap`` files
  in natural name order, with a note;
* a single ``.mcap`` file (or the ``metadata.yaml`` of a bag).

Supported message types (per robot): nav_msgs/msg/Odometry, geometry_msgs/msg/PoseStamped and
tf2_msgs/msg/TFMessage (each TransformStamped is one sample of its ``child_frame_id``).
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Dict, Iterator, List, Optional, Sequence, Tuple

import numpy as np

from knode_swarm_ros.nodes.orientation import quaternion_to_heading

__all__ = ["BagError", "Bag", "Sample", "SourceSamples", "open_bag", "normalise_type", "SUPPORTED_TYPES",
           "ODOMETRY", "POSE_STAMPED", "TF_MESSAGE", "quaternion_to_heading", "rotate_by_quaternion"]

ODOMETRY = "nav_msgs/msg/Odometry"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
SUPPORTED_TYPES = (ODOMETRY, POSE_STAMPED, TF_MESSAGE)

MCAP_MAGIC = b"\x89MCAP0\r\n"
SQLITE_MAGIC = b"SQLite format 3\x00"


class BagError(ValueError):
    """The input is not a readable bag, or its content does not fit the request; the message names
    the file, topic or frame."""


def normalise_type(name: str) -> str:
    """``pkg/Type`` -> ``pkg/msg/Type`` (schema names in MCAP files written outside rosbag2 may
    omit ``msg``); other names unchanged."""
    parts = name.split("/")
    if len(parts) == 2:
        return f"{parts[0]}/msg/{parts[1]}"
    return name


def _natural_key(path: Path):
    return [int(tok) if tok.isdigit() else tok for tok in re.split(r"(\d+)", path.name)]


@dataclass
class Bag:
    """A located bag: ``files`` in reading order, and what was noticed on the way (``notes``)."""

    path: Path
    kind: str                      # "rosbag2 directory" | "mcap file"
    files: List[Path]
    metadata: Optional[Dict[str, Any]] = None
    notes: List[str] = field(default_factory=list)
    _topics: Optional[Dict[str, str]] = None

    # --- topics ---------------------------------------------------------------------------
    def topics(self) -> Dict[str, str]:
        """``{topic: message type}`` over all files (types as ``pkg/msg/Type``)."""
        if self._topics is None:
            topics: Dict[str, str] = {}
            for path in self.files:
                for topic, type_name in _file_topics(path, self.notes).items():
                    known = topics.get(topic)
                    if known is not None and known != type_name:
                        raise BagError(f"{path}: topic {topic} carries {type_name} here but {known} in an earlier file")
                    topics[topic] = type_name
            self._topics = topics
        return dict(self._topics)

    # --- messages ---------------------------------------------------------------------------
    def messages(self, topics: Sequence[str]) -> Iterator[Tuple[Path, str, str, int, Any]]:
        """Decoded messages of ``topics``: ``(file, topic, type, log_time_ns, message)``, file by
        file in bag order and in log-time order within a file."""
        from mcap.exceptions import McapError
        from mcap.reader import NonSeekingReader, make_reader
        from mcap_ros2.decoder import DecoderFactory

        wanted = set(topics)
        for path in self.files:
            topic = "?"
            try:
                with open(path, "rb") as stream:
                    reader = make_reader(stream, decoder_factories=[DecoderFactory()])
                    try:
                        indexed = reader.get_summary() is not None
                    except (McapError, OSError, ValueError):
                        indexed = False
                    if indexed:
                        iterator = reader.iter_decoded_messages(topics=sorted(wanted), log_time_order=True)
                    else:
                        stream.seek(0)
                        iterator = _linear_decoded(NonSeekingReader(stream), wanted, path, self.notes)
                    for schema, channel, message, decoded in iterator:
                        topic = channel.topic
                        if topic not in wanted:
                            continue
                        type_name = normalise_type(schema.name) if schema is not None else "?"
                        yield path, topic, type_name, int(message.log_time), decoded
            except BagError:
                raise
            except (McapError, OSError, ValueError, KeyError, IndexError, NotImplementedError) as exc:
                raise BagError(f"{path}: cannot decode messages (last topic {topic}): "
                               f"{type(exc).__name__}: {exc}") from None


def _linear_decoded(reader, wanted, path: Path, notes: List[str]):
    """Decoded messages of a file without a summary section (a recording that was cut short):
    read front to back; a truncated tail ends the file with a note instead of an error."""
    from mcap.exceptions import McapError
    from mcap_ros2.decoder import DecoderFactory

    factory = DecoderFactory()
    decoders: Dict[int, Callable] = {}
    iterator = reader.iter_messages(log_time_order=False)   # file order; sorting would need the whole file
    while True:
        try:
            schema, channel, message = next(iterator)
        except StopIteration:
            return
        except (McapError, EOFError, ValueError) as exc:
            notes.append(f"{path}: file ends early ({type(exc).__name__}); read up to there")
            return
        if channel.topic not in wanted:
            continue
        decoder = decoders.get(channel.id)
        if decoder is None:
            decoder = factory.decoder_for(channel.message_encoding, schema)
            if decoder is None:
                raise BagError(f"{path}: topic {channel.topic}: no CDR/ros2msg decoder for encoding "
                               f"{channel.message_encoding!r}")
            decoders[channel.id] = decoder
        yield schema, channel, message, decoder(message.data)


def _file_topics(path: Path, notes: List[str]) -> Dict[str, str]:
    from mcap.exceptions import McapError
    from mcap.reader import NonSeekingReader, make_reader

    def schema_type(schema) -> str:
        return normalise_type(schema.name) if schema is not None else "(no schema)"

    try:
        with open(path, "rb") as stream:
            reader = make_reader(stream)
            try:
                summary = reader.get_summary()
            except (McapError, OSError, ValueError):
                summary = None
            if summary is not None:
                return {ch.topic: schema_type(summary.schemas.get(ch.schema_id)) for ch in summary.channels.values()}
            notes.append(f"{path}: no summary section (recording cut short?); scanned the whole file")
            stream.seek(0)
            topics: Dict[str, str] = {}
            iterator = NonSeekingReader(stream).iter_messages(log_time_order=False)
            while True:
                try:
                    schema, channel, _ = next(iterator)
                except StopIteration:
                    break
                except (McapError, EOFError, ValueError):
                    break
                topics.setdefault(channel.topic, schema_type(schema))
            return topics
    except (McapError, OSError) as exc:
        raise BagError(f"{path}: not a readable MCAP file ({type(exc).__name__}: {exc})") from None


def _check_mcap_file(path: Path) -> None:
    try:
        with open(path, "rb") as fh:
            head = fh.read(16)
    except OSError as exc:
        raise BagError(f"{path}: cannot read ({exc.strerror})") from None
    if head.startswith(MCAP_MAGIC):
        return
    if head.startswith(SQLITE_MAGIC):
        raise BagError(f"{path}: an SQLite3 (.db3) bag; only MCAP storage is read. Convert it with "
                       f"`ros2 bag convert` to storage_id mcap")
    raise BagError(f"{path}: not an MCAP file (it does not start with the MCAP magic bytes)")


def _read_metadata(path: Path) -> Dict[str, Any]:
    import yaml

    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise BagError(f"{path}: not a readable rosbag2 metadata.yaml ({type(exc).__name__}: {exc})") from None
    info = data.get("rosbag2_bagfile_information") if isinstance(data, dict) else None
    if not isinstance(info, dict):
        raise BagError(f"{path}: not a rosbag2 metadata.yaml (no rosbag2_bagfile_information)")
    return info


def open_bag(path) -> Bag:
    """Locate the MCAP files of ``path`` (bag directory, its metadata.yaml, or one .mcap file)."""
    path = Path(path)
    if not path.exists():
        raise BagError(f"{path}: no such file or directory")
    if path.is_file() and path.name == "metadata.yaml":
        path = path.parent
    if path.is_file():
        _check_mcap_file(path)
        return Bag(path, "mcap file", [path])
    meta_path = path / "metadata.yaml"
    if meta_path.is_file():
        info = _read_metadata(meta_path)
        storage = info.get("storage_identifier", "")
        if storage != "mcap":
            hint = " Convert it with `ros2 bag convert` to storage_id mcap." if storage == "sqlite3" else ""
            raise BagError(f"{meta_path}: storage_identifier is {storage!r}; only 'mcap' bags are read.{hint}")
        if str(info.get("compression_mode", "") or "").lower() not in ("", "none"):
            raise BagError(f"{meta_path}: compression_mode {info.get('compression_mode')!r} (whole-file "
                           f"{info.get('compression_format')} compression) is not read; decompress the bag first "
                           f"(e.g. `ros2 bag convert` without compression). MCAP chunk compression is fine.")
        names = info.get("relative_file_paths") or [f.get("path") for f in info.get("files") or []]
        if not names:
            raise BagError(f"{meta_path}: lists no files (relative_file_paths is empty)")
        files = []
        for name in names:
            f = path / str(name)
            if not f.is_file():
                raise BagError(f"{meta_path}: lists {name}, which is missing from {path}")
            _check_mcap_file(f)
            files.append(f)
        return Bag(path, "rosbag2 directory", files, metadata=info)
    files = sorted((p for p in path.iterdir() if p.is_file() and p.suffix == ".mcap"), key=_natural_key)
    if not files:
        raise BagError(f"{path}: not a bag (no metadata.yaml and no .mcap files)")
    for f in files:
        _check_mcap_file(f)
    bag = Bag(path, "rosbag2 directory", files)
    bag.notes.append(f"{path}: no metadata.yaml; reading its {len(files)} .mcap file(s) in name order")
    return bag


# --- Samples ------------------------------------------------------------------------------------

@dataclass
class Sample:
    """One observation of one robot, as carried by a message."""

    stamp_ns: int               # header.stamp
    log_ns: int                 # MCAP log time (receive time in a rosbag2 recording)
    position: Tuple[float, float, float]
    orientation: Tuple[float, float, float, float]   # x, y, z, w
    linear: Optional[Tuple[float, float, float]]     # Odometry twist.twist.linear, else None
    frame_id: str


@dataclass
class SourceSamples:
    """All samples of one source (a topic, or a child frame on a TF topic), in bag order."""

    name: str                   # topic, or child frame id for TF
    topic: str
    type_name: str
    samples: List[Sample] = field(default_factory=list)


def _xyz(v) -> Tuple[float, float, float]:
    return (float(v.x), float(v.y), float(v.z))


def _quat(q) -> Tuple[float, float, float, float]:
    return (float(q.x), float(q.y), float(q.z), float(q.w))


def _stamp_ns(stamp) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def samples_of(type_name: str, msg: Any, log_ns: int) -> List[Tuple[Optional[str], Sample]]:
    """``[(child frame or None, Sample)]`` carried by one decoded message of a supported type."""
    if type_name == ODOMETRY:
        pose = msg.pose.pose
        return [(None, Sample(_stamp_ns(msg.header.stamp), log_ns, _xyz(pose.position), _quat(pose.orientation),
                              _xyz(msg.twist.twist.linear), str(msg.header.frame_id)))]
    if type_name == POSE_STAMPED:
        pose = msg.pose
        return [(None, Sample(_stamp_ns(msg.header.stamp), log_ns, _xyz(pose.position), _quat(pose.orientation),
                              None, str(msg.header.frame_id)))]
    if type_name == TF_MESSAGE:
        out = []
        for tf in msg.transforms:
            out.append((str(tf.child_frame_id).lstrip("/"),
                        Sample(_stamp_ns(tf.header.stamp), log_ns, _xyz(tf.transform.translation),
                               _quat(tf.transform.rotation), None, str(tf.header.frame_id).lstrip("/"))))
        return out
    raise BagError(f"unsupported message type {type_name}")


# --- Quaternions ------------------------------------------------------------------------------

def rotate_by_quaternion(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors ``v[..., 3]`` by unit quaternions ``q[..., 4]`` (x, y, z, w): body -> world."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    u, w = q[..., :3], q[..., 3:4]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)
