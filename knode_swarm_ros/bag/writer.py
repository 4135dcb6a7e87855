"""Write rosbag2 (MCAP) bags without ROS, with the ``rosbags`` writer and ROS 2 Jazzy's message
definitions.

The bag of a swarm run holds what a ``ros2 bag record`` of it would hold: one topic per robot,
``/robot_<id>/odom``, nav_msgs/msg/Odometry (:func:`~.messages.odometry_message`), offered with
the odometry QoS of the nodes (:mod:`knode_swarm_ros.logic.contract.qos_specs`, in rosbag2's format:
:mod:`.qos`).

Output layout: a path ending in ``.mcap`` is one MCAP file (its channels carry the QoS);
any other path is a rosbag2 bag directory as rosbag2 Jazzy writes one: ``metadata.yaml``
(version 9, type hashes, QoS) plus ``<name>_0.mcap``, ``<name>_1.mcap``, ... when split. The
bag is written in a temporary sibling and renamed into place when complete.

Why rosbags' writer (and not the mcap-ros2-support writer used before): one library reads
and writes every format, its typestore gives the definitions and RIHS01 hashes of every
distribution (no .msg files to find), and its channels carry ``offered_qos_profiles``, which
mcap-ros2-support's writer cannot set. It writes one storage file per bag, so a split bag is
written as one rosbags bag per file and the directory's ``metadata.yaml`` is written here.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, List, Optional, Sequence, Union

import numpy as np

from knode_swarm_ros.logic.common import WORLD_FRAME
from knode_swarm_ros.logic.contract import qos_specs
from knode_swarm_ros.logic.contract.qos_specs import QosSpec

from .messages import ODOMETRY, BagWriteError, normalise_type, odometry_message, to_message, typestore
from .qos import qos_v9, rosbags_qos

__all__ = ['BagWriter', 'write_odometry_bag']

PathLike = Union[str, os.PathLike]


@dataclass
class _Topic:
    type_name: str
    qos: Optional[QosSpec]
    count: int = 0


@dataclass
class _Part:
    """One storage file: its rosbags writer and connections."""

    name: str
    writer: Any
    connections: Dict[str, Any] = field(default_factory=dict)
    count: int = 0
    first_ns: Optional[int] = None
    last_ns: Optional[int] = None


class BagWriter:
    """Write ROS 2 messages (dicts or objects with the fields) into an MCAP file or a rosbag2 directory.

    ``split_messages`` starts a new ``<name>_<i>.mcap`` after that many messages (directories
    only); ``compression`` zstd (MCAP chunks) or none. Nothing appears at ``path`` until
    :meth:`close` succeeds; an existing ``path`` is refused unless ``overwrite``. Use as a
    context manager.

    ``write(topic, type_name, message, stamp_ns, log_time_ns=None, qos=None)``: ``log_time_ns``
    (the receive time in a real recording) defaults to ``stamp_ns``; ``qos`` (a
    :class:`~knode_swarm_ros.logic.contract.qos_specs.QosSpec`, first write of a topic) is the topic's
    offered QoS.
    """

    def __init__(
        self,
        path: PathLike,
        split_messages: Optional[int] = None,
        overwrite: bool = False,
        compression: str = 'zstd',
    ):
        try:
            import rosbags  # noqa: F401
        except ImportError as exc:  # pragma: no cover - exercised only without the bag extra
            raise BagWriteError(
                f"writing bags needs the rosbags package ({exc}); pip install 'knode_swarm_ros[bag]'"
            ) from None
        if compression not in ('zstd', 'none'):
            raise BagWriteError(f'compression {compression!r}: choose zstd or none')
        self._compress = compression == 'zstd'
        self.path = Path(path)
        self.single_file = self.path.suffix == '.mcap'
        if split_messages is not None and (self.single_file or int(split_messages) < 1):
            raise BagWriteError('split_messages needs a bag directory path (not .mcap) and a positive count')
        self.split_messages = None if split_messages is None else int(split_messages)
        if self.path.exists() and not overwrite:
            raise BagWriteError(f'{self.path}: already exists (a bag is never overwritten unless asked)')
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._tmp = Path(tempfile.mkdtemp(prefix=f'.{self.path.name}.', suffix='.tmp', dir=self.path.parent))
        self._topics: Dict[str, _Topic] = {}
        self._parts: List[_Part] = []
        self._closed = False
        #: What :meth:`close` returned (None before).
        self.summary: Optional[Dict[str, Any]] = None

    def _open_next(self) -> None:
        from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer

        self._finish_current()
        name = self.path.stem if self.single_file else f'{self.path.name}_{len(self._parts)}'
        writer = Writer(self._tmp / name, version=9, storage_plugin=StoragePlugin.MCAP)
        if self._compress:
            writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        writer.open()
        self._parts.append(_Part(name, writer))

    def _finish_current(self) -> None:
        part = self._parts[-1] if self._parts else None
        if part is not None and part.writer is not None:
            part.writer.close()
            part.writer = None
            # rosbags writes <name>/<name>.mcap (+ its metadata.yaml): keep the storage file only
            os.replace(self._tmp / part.name / f'{part.name}.mcap', self._tmp / f'{part.name}.mcap')
            shutil.rmtree(self._tmp / part.name)

    def write(
        self,
        topic: str,
        type_name: str,
        message: Any,
        stamp_ns: int,
        log_time_ns: Optional[int] = None,
        qos: Optional[QosSpec] = None,
    ) -> None:
        """Append one message (its ``header.stamp`` is the caller's; ``log_time_ns`` orders the bag)."""
        if self._closed:
            raise BagWriteError('write after close')
        type_name = normalise_type(type_name)
        known = self._topics.get(topic)
        if known is not None and known.type_name != type_name:
            raise BagWriteError(f'topic {topic} already carries {known.type_name}, not {type_name}')
        log_ns = int(stamp_ns if log_time_ns is None else log_time_ns)
        if log_ns < 0:
            raise BagWriteError(f'topic {topic}: negative log time {log_ns} ns (bag times are unsigned)')
        store = typestore()
        if type_name not in store.types:
            raise BagWriteError(f"no message definition for {type_name} in ROS 2 Jazzy's message types")
        data = store.serialize_cdr(to_message(type_name, message, store), type_name)
        if known is None:
            known = self._topics[topic] = _Topic(type_name, qos)
        if not self._parts or (
            self.split_messages is not None and self._parts[-1].count >= self.split_messages
        ):
            self._open_next()
        part = self._parts[-1]
        connection = part.connections.get(topic)
        if connection is None:
            connection = part.connections[topic] = part.writer.add_connection(
                topic, type_name, typestore=store, offered_qos_profiles=rosbags_qos(known.qos)
            )
        part.writer.write(connection, log_ns, data)
        part.count += 1
        part.first_ns = log_ns if part.first_ns is None else min(part.first_ns, log_ns)
        part.last_ns = log_ns if part.last_ns is None else max(part.last_ns, log_ns)
        known.count += 1

    def _metadata(self) -> Dict[str, Any]:
        """metadata.yaml as rosbag2 Jazzy writes it (version 9)."""
        store = typestore()
        firsts = [p.first_ns for p in self._parts if p.first_ns is not None]
        lasts = [p.last_ns for p in self._parts if p.last_ns is not None]
        start = min(firsts) if firsts else 0
        files = [f'{p.name}.mcap' for p in self._parts]
        return {
            'rosbag2_bagfile_information': {
                'version': 9,
                'storage_identifier': 'mcap',
                'duration': {'nanoseconds': (max(lasts) - start) if lasts else 0},
                'starting_time': {'nanoseconds_since_epoch': start},
                'message_count': sum(p.count for p in self._parts),
                'topics_with_message_count': [
                    {
                        'topic_metadata': {
                            'name': topic,
                            'type': t.type_name,
                            'serialization_format': 'cdr',
                            'offered_qos_profiles': qos_v9(t.qos),
                            'type_description_hash': store.hash_rihs01(t.type_name),
                        },
                        'message_count': t.count,
                    }
                    for topic, t in self._topics.items()
                ],
                'compression_format': '',
                'compression_mode': '',
                'relative_file_paths': files,
                'files': [
                    {
                        'path': f,
                        'starting_time': {'nanoseconds_since_epoch': p.first_ns or 0},
                        'duration': {'nanoseconds': (p.last_ns or 0) - (p.first_ns or 0)},
                        'message_count': p.count,
                    }
                    for f, p in zip(files, self._parts)
                ],
                'custom_data': {},
                'ros_distro': 'jazzy',
            }
        }

    def close(self) -> Dict[str, Any]:
        """Finish the file(s), write ``metadata.yaml`` (directories) and move the bag into place.

        Returns (and keeps as :attr:`summary`): ``path``, ``files``, ``messages``, ``topics``
        ({topic: count}).
        """
        if self._closed:
            raise BagWriteError('close called twice')
        try:
            if not self._parts:
                self._open_next()  # an empty bag is still a valid bag
            self._finish_current()
            if self.single_file:
                os.replace(self._tmp / self.path.name, self.path)
            else:
                import yaml

                with open(self._tmp / 'metadata.yaml', 'w', encoding='utf-8') as fh:
                    yaml.safe_dump(self._metadata(), fh, sort_keys=False)
                if self.path.exists():
                    shutil.rmtree(self.path) if self.path.is_dir() else self.path.unlink()
                os.replace(self._tmp, self.path)
        finally:
            self._closed = True
            if self._tmp.exists():
                shutil.rmtree(self._tmp, ignore_errors=True)
        self.summary = {
            'path': str(self.path),
            'files': [f'{p.name}.mcap' for p in self._parts],
            'messages': sum(p.count for p in self._parts),
            'topics': {t: i.count for t, i in self._topics.items()},
        }
        return self.summary

    def abort(self) -> None:
        """Drop everything written so far; nothing appears at ``path``."""
        if not self._closed:
            self._closed = True
            for part in self._parts:
                if part.writer is not None:
                    part.writer.abort()
            shutil.rmtree(self._tmp, ignore_errors=True)

    def __enter__(self) -> 'BagWriter':
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
        raise BagWriteError(f'stamps must have shape [T] = [{T}] or [T, n] = [{T}, {n}], got {list(s.shape)}')
    if np.issubdtype(s.dtype, np.integer):
        ns = s.astype(np.int64)
    else:
        if not np.all(np.isfinite(s)):
            raise BagWriteError('stamps hold a non-finite value')
        ns = np.rint(s.astype(np.float64) * 1e9).astype(np.int64)
    if ns.ndim == 1:
        ns = np.repeat(ns[:, None], n, axis=1)
    return ns


def write_odometry_bag(
    path: PathLike,
    states: np.ndarray,
    dt: float,
    scenario: str,
    stamps: Optional[np.ndarray] = None,
    topic_fmt: str = '/robot_{id}/odom',
    ids: Optional[Sequence[int]] = None,
    mask: Optional[np.ndarray] = None,
    velocities: Optional[np.ndarray] = None,
    frame_id: str = WORLD_FRAME,
    child_frame_fmt: str = 'robot_{id}/base_link',
    split_messages: Optional[int] = None,
    overwrite: bool = False,
    qos: Optional[QosSpec] = qos_specs.ODOM,
) -> Dict[str, Any]:
    """Write one swarm run ``states[T, n, d]`` as nav_msgs/Odometry messages, one topic per robot.

    Args:
        path: ``*.mcap`` for one MCAP file, anything else for a rosbag2 directory.
        states: float ``[T, n, d]`` in the layout of ``scenario`` (flock2d d = 4, boids3d d = 6).
        dt: seconds between frames; used for the stamps when ``stamps`` is None (frame k at k dt).
        scenario: ``flock2d`` or ``boids3d`` (decides the state -> Odometry mapping).
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
        qos: the topics' offered QoS (default the nodes' odometry profile).

    Messages are written in time order (log time = header stamp). Returns the summary of
    :meth:`BagWriter.close`. Raises :class:`BagWriteError` on bad input (nothing is written).
    """
    states = np.asarray(states, dtype=np.float64)
    if scenario not in ('flock2d', 'boids3d'):
        raise BagWriteError(f'unknown scenario {scenario!r}; known: boids3d, flock2d')
    d = 4 if scenario == 'flock2d' else 6
    if states.ndim != 3 or states.shape[2] != d or states.shape[0] < 1 or states.shape[1] < 1:
        raise BagWriteError(f'states must be [T, n, {d}] for {scenario}, got {list(states.shape)}')
    T, n, _ = states.shape
    ids = list(range(n)) if ids is None else [int(i) for i in ids]
    if len(ids) != n or len(set(ids)) != n:
        raise BagWriteError(f'ids must be {n} distinct integers, got {ids}')
    mask = np.ones((T, n), dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
    if mask.shape != (T, n):
        raise BagWriteError(f'mask must have shape [T, n] = [{T}, {n}], got {list(mask.shape)}')
    if not np.all(np.isfinite(states[mask])):
        t, i = (int(v) for v in np.argwhere(mask & ~np.all(np.isfinite(states), axis=2))[0])
        raise BagWriteError(f'states[{t}, {i}] (robot {ids[i]}) is not finite and not masked out')
    if velocities is not None:
        velocities = np.asarray(velocities, dtype=np.float64)
        if scenario != 'boids3d' or velocities.shape != (T, n, 3):
            raise BagWriteError(
                f'velocities are for boids3d, shape [T, n, 3] = [{T}, {n}, 3]; got '
                f'{list(velocities.shape)} for {scenario}'
            )
    ns = _stamps_ns(stamps, T, n, dt)
    if np.any(ns[mask] < 0):
        raise BagWriteError('stamps must be >= 0')
    order = sorted(((int(ns[t, i]), i, t) for t in range(T) for i in range(n) if mask[t, i]))
    with BagWriter(path, split_messages=split_messages, overwrite=overwrite) as writer:
        for stamp, i, t in order:
            msg = odometry_message(
                scenario,
                states[t, i],
                stamp,
                ids[i],
                frame_id,
                child_frame_fmt.format(id=ids[i]),
                None if velocities is None else velocities[t, i],
            )
            writer.write(topic_fmt.format(id=ids[i]), ODOMETRY, msg, stamp, qos=qos)
    return writer.summary
