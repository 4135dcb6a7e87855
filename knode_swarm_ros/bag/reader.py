"""Open recorded bags with the maintained ``rosbags`` readers (pure Python, no ROS install).

Accepted inputs (:func:`open_bag`):

* a rosbag2 bag directory (``metadata.yaml``, versions 1 to 9 of Foxy to Jazzy, storage
  ``sqlite3`` or ``mcap``, split files in the listed order, file or message compression);
* a bag directory without ``metadata.yaml`` (a recording that was killed before writing it):
  its ``.mcap`` / ``.db3`` files in natural name order, with a note;
* a single ``.mcap`` or ``.db3`` file, or the ``metadata.yaml`` of a bag;
* ROS 1 bags: one ``.bag`` file (or a directory of them, read as one recording).

Messages are decoded with the definitions the bag carries (MCAP schemas, ROS 1 connection
headers, Jazzy ``type_description``); bags without them (sqlite3 bags of Humble and earlier)
with ROS 2 Jazzy's definitions (:func:`~.messages.typestore`).

Anything the library cannot read (a truncated, corrupt or foreign file) raises
:class:`~.messages.BagError` naming the file: for a bag of several files, the first file that
does not read on its own.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, Iterator, List, Optional, Sequence, Tuple

from .messages import BagError, typestore

__all__ = ['Bag', 'open_bag']

_MAGIC = {b'\x89MCAP0\r\n': '.mcap', b'SQLite format 3\x00': '.db3', b'#ROSBAG V2.0\n': '.bag'}
_KINDS = {'.mcap': 'mcap file', '.db3': 'sqlite3 file', '.bag': 'ROS 1 bag'}


def _natural_key(path: Path):
    return [int(tok) if tok.isdigit() else tok for tok in re.split(r'(\d+)', path.name)]


def _describe(exc: BaseException) -> str:
    text = ' '.join(str(a) for a in exc.args) if exc.args else ''
    return f'{type(exc).__name__}: {text}' if text else type(exc).__name__


@dataclass
class Bag:
    """A located bag: what to hand to rosbags (``sources``), its storage ``files`` in reading
    order, and what was noticed on the way (``notes``)."""

    path: Path
    kind: str  # "rosbag2 directory" | "mcap file" | "sqlite3 file" | "ROS 1 bag"
    sources: List[Path]  # paths given to rosbags' AnyReader
    files: List[Path]  # storage files, for the error report and the metadata
    notes: List[str] = field(default_factory=list)

    def _reader(self):
        from rosbags.highlevel import AnyReader

        return AnyReader(self.sources, default_typestore=typestore())

    def _fail(self, exc: BaseException, what: str) -> BagError:
        culprit, cause = _broken_file(self.files)
        if culprit is None:
            culprit, cause = self.path, _describe(exc)
        return BagError(
            f'{culprit}: not readable (truncated, corrupt or an unsupported version): {what} ({cause})'
        )

    def topics(self) -> Dict[str, str]:
        """``{topic: message type}`` (``pkg/msg/Type``; ROS 1 names normalised by rosbags)."""
        try:
            with self._reader() as reader:
                out = {}
                for topic, info in reader.topics.items():
                    if info.msgtype is None:
                        kinds = sorted({c.msgtype for c in info.connections})
                        raise BagError(
                            f'{self.path}: topic {topic} carries several types ({", ".join(kinds)})'
                        )
                    out[topic] = info.msgtype
                return out
        except BagError:
            raise
        except Exception as exc:
            raise self._fail(exc, 'cannot be opened') from None

    def messages(self, topics: Sequence[str]) -> Iterator[Tuple[Path, str, str, int, Any]]:
        """Decoded messages of ``topics``: ``(bag path, topic, type, log_time_ns, message)`` in
        log-time order."""
        wanted = set(topics)
        topic = None
        try:
            with self._reader() as reader:
                connections = [c for c in reader.connections if c.topic in wanted]
                if not connections:
                    return
                for connection, log_ns, raw in reader.messages(connections=connections):
                    topic = connection.topic
                    yield (
                        self.path,
                        topic,
                        connection.msgtype,
                        int(log_ns),
                        reader.deserialize(raw, connection.msgtype),
                    )
        except BagError:
            raise
        except GeneratorExit:
            raise
        except Exception as exc:
            where = '' if topic is None else f' after a message on {topic}'
            raise self._fail(exc, f'cannot decode the messages{where}') from None


def _broken_file(files: Sequence[Path]) -> Tuple[Optional[Path], Optional[str]]:
    """The first of ``files`` that rosbags cannot read on its own to the end, and why; only called
    once reading failed, to name the file."""
    from rosbags.rosbag1 import Reader as Reader1
    from rosbags.rosbag2 import Reader as Reader2

    for path in files:
        try:
            with Reader1(path) if path.suffix == '.bag' else Reader2(path) as reader:
                for _ in reader.messages():
                    pass
        except Exception as exc:
            return path, _describe(exc)
    return None, None


def _check_file(path: Path) -> str:
    """The storage suffix of ``path`` after checking that its first bytes agree with it."""
    try:
        with open(path, 'rb') as fh:
            head = fh.read(16)
    except OSError as exc:
        raise BagError(f'{path}: cannot read ({exc.strerror})') from None
    found = next((suffix for magic, suffix in _MAGIC.items() if head.startswith(magic)), None)
    if found is None:
        raise BagError(f'{path}: not a bag file (neither MCAP, rosbag2 SQLite3 nor ROS 1 bag)')
    if path.suffix != found:
        raise BagError(
            f'{path}: holds a {_KINDS[found]} but is named {path.suffix or "without a suffix"}; '
            f'rename it to end in {found}'
        )
    return found


def _metadata_files(meta_path: Path) -> List[Path]:
    import yaml

    from ..core.yaml_file import load_yaml

    try:
        data = load_yaml(meta_path.read_text(encoding='utf-8'))
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise BagError(
            f'{meta_path}: not a readable rosbag2 metadata.yaml ({type(exc).__name__}: {exc})'
        ) from None
    info = data.get('rosbag2_bagfile_information') if isinstance(data, dict) else None
    if not isinstance(info, dict):
        raise BagError(f'{meta_path}: not a rosbag2 metadata.yaml (no rosbag2_bagfile_information)')
    names = info.get('relative_file_paths') or [
        f.get('path') for f in info.get('files') or [] if isinstance(f, dict)
    ]
    if not names:
        raise BagError(f'{meta_path}: lists no files (relative_file_paths is empty)')
    files = []
    for name in names:
        f = meta_path.parent / Path(str(name)).name
        if not f.is_file():
            raise BagError(f'{meta_path}: lists {name}, which is missing from {meta_path.parent}')
        files.append(f)
    return files


def open_bag(path) -> Bag:
    """Locate a bag (see the module docstring); raises :class:`BagError` naming the path."""
    path = Path(path)
    if not path.exists():
        raise BagError(f'{path}: no such file or directory')
    if path.is_file() and path.name == 'metadata.yaml':
        path = path.parent
    if path.is_file():
        suffix = _check_file(path)
        return Bag(path, _KINDS[suffix], [path], [path])
    meta_path = path / 'metadata.yaml'
    if meta_path.is_file():
        files = _metadata_files(meta_path)
        for f in files:
            if f.suffix in _KINDS:  # compressed files (.mcap.zstd) are checked by rosbags
                _check_file(f)
        return Bag(path, 'rosbag2 directory', [path], files)
    files = sorted(
        (p for p in path.iterdir() if p.is_file() and p.suffix in ('.mcap', '.db3')), key=_natural_key
    )
    ros1 = sorted((p for p in path.iterdir() if p.is_file() and p.suffix == '.bag'), key=_natural_key)
    if not files and not ros1:
        raise BagError(f'{path}: not a bag (no metadata.yaml and no .mcap, .db3 or .bag files)')
    if files and ros1:
        raise BagError(f'{path}: holds both rosbag2 files and ROS 1 .bag files; give one of them')
    files = files or ros1
    for f in files:
        _check_file(f)
    bag = Bag(path, 'ROS 1 bags' if ros1 else 'rosbag2 directory', files, files)
    if not ros1:
        bag.notes.append(f'{path}: no metadata.yaml; reading its {len(files)} storage file(s) in name order')
    return bag
