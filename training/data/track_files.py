"""Track files: what motion capture and video trackers export, read into :class:`~training.data.tracks.Track`
objects (docs/scenarios.md, "Data in").

* CSV in long format with a header: ``t, id, x, y[, z]`` (seconds, integer robot id, metres),
  optionally ``vx, vy[, vz]`` (world-frame velocities) or ``hx, hy[, hz]`` (headings); rows in any
  order, ids any integers, other columns ignored.
* ``.npy`` arrays ``[T, n, dimensions]`` of positions at ``--fps`` frames per second (the layout
  idtracker.ai and TRex export); robot ids are the column indices, NaN marks a lost robot.
"""

from __future__ import annotations

import csv
import math
import os
from pathlib import Path
from typing import Any, Dict, List, Optional, Tuple

import numpy as np

from knode_swarm_ros.core.scenarios import Scenario
from knode_swarm_ros.core.trajectory import npy_header

from .tracks import Track, TrackError

__all__ = ['read_track_file', 'single_frame']

_AXES = ('x', 'y', 'z')
#: Seconds either side of 0 that a time may have (146 years): its stamp in int64 nanoseconds,
#: and the difference of two stamps, fit (2**63 ns is 9.2e9 s).
TIME_LIMIT_S = 4.6e9
_ID_LIMIT = 2**63  # ids are int64


def _columns(header: List[str], spec: Scenario, where: str) -> Dict[str, Optional[List[str]]]:
    """The columns to read: ``{position: [...], velocity: [...] or None, heading: [...] or None}``."""
    axes = _AXES[: spec.dimensions]
    need = ['t', 'id', *axes]
    for name in need:
        if name not in header:
            raise TrackError(
                f'{where}: no column {name!r} (header: {", ".join(header)}); a {spec.dimensions}D '
                f'scenario needs {", ".join(need)}'
            )
    out: Dict[str, Optional[List[str]]] = {'position': list(axes), 'velocity': None, 'heading': None}
    for kind, prefix in (('velocity', 'v'), ('heading', 'h')):
        cols = [prefix + a for a in axes]
        present = [c for c in cols if c in header]
        if present and len(present) < len(cols):
            missing = next(c for c in cols if c not in header)
            raise TrackError(
                f'{where}: column {missing!r} is missing while {", ".join(present)} are there; '
                f'a {kind} needs {", ".join(cols)}'
            )
        if present:
            out[kind] = cols
    return out


def _read_csv(path: Path, spec: Scenario) -> Tuple[List[Track], Dict[str, Any]]:
    where = str(path)
    try:
        with open(path, newline='', encoding='utf-8-sig') as fh:  # a spreadsheet's byte-order mark
            rows = list(csv.reader(fh))
    except UnicodeDecodeError as exc:
        raise TrackError(f'{where}: not a text CSV file ({exc})') from None
    if not rows:
        raise TrackError(f'{where}: empty file; expected a header t, id, x, y, ...')
    header = [h.strip().lower() for h in rows[0]]
    cols = _columns(header, spec, where)
    wanted = ['t', *cols['position'], *(cols['velocity'] or []), *(cols['heading'] or [])]
    index = [header.index(c) for c in wanted]
    id_col = header.index('id')
    data = np.empty((len(rows) - 1, len(wanted)))
    ids = np.empty(len(rows) - 1, dtype=np.int64)
    for k, row in enumerate(rows[1:]):
        line = k + 2
        if len(row) != len(header):
            raise TrackError(f'{where}: line {line} has {len(row)} fields, the header {len(header)}')
        rid = _integer(row[id_col])
        if rid is None:
            raise TrackError(
                f'{where}: line {line}: id = {row[id_col]!r} is not an integer (of at most 18 digits)'
            )
        try:
            data[k] = [float(row[i]) for i in index]
        except ValueError:
            bad = next(c for c, i in zip(wanted, index) if not _is_float(row[i]))
            raise TrackError(
                f'{where}: line {line}: {bad} = {row[header.index(bad)]!r} is not a number'
            ) from None
        if not abs(data[k, 0]) <= TIME_LIMIT_S:  # NaN too
            raise TrackError(
                f'{where}: line {line}: t = {row[index[0]]!r} is not a time in seconds within '
                f'+-{TIME_LIMIT_S:.3g} (a stamp in nanoseconds)'
            )
        ids[k] = rid
    if ids.size == 0:
        raise TrackError(f'{where}: a header but no rows')
    p = spec.dimensions
    tracks = []
    for rid in np.unique(ids):
        rows_of = data[ids == rid]
        rows_of = rows_of[np.argsort(rows_of[:, 0], kind='stable')]
        ns = np.round(rows_of[:, 0] * 1e9).astype(np.int64)
        values = rows_of[:, 1:]
        tracks.append(
            _track(
                int(rid),
                f'id {rid}',
                ns,
                values[:, :p],
                values[:, p : 2 * p] if cols['velocity'] else None,
                values[:, -p:] if cols['heading'] else None,
            )
        )
    ignored = [h for h in header if h not in ('id', *wanted)]
    info = {
        'format': 'csv',
        'rows': int(ids.size),
        'columns': wanted[:1] + ['id'] + wanted[1:],
        'ignored_columns': ignored,
    }
    return tracks, info


def _integer(text: str) -> Optional[int]:
    """``text`` as an int64 id (``7``, ``7.0``, ``7e2``), else None. Parsed as an integer first:
    through a float, ids beyond 2**53 would merge."""
    try:
        value = int(text)
    except ValueError:
        try:
            f = float(text)
        except ValueError:
            return None
        if not (math.isfinite(f) and f == int(f) and abs(f) <= 2**53):
            return None
        value = int(f)
    return value if -_ID_LIMIT <= value < _ID_LIMIT else None


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _read_npy(path: Path, spec: Scenario, fps: Optional[float]) -> Tuple[List[Track], Dict[str, Any]]:
    where = str(path)
    if fps is None:
        raise TrackError(f'{where}: a .npy array has no time stamps; give its frame rate with --fps')
    if not (math.isfinite(fps) and fps > 0):
        raise TrackError(f'{where}: --fps must be a positive number, got {fps}')
    arr = _load_npy(path, where)
    if arr.ndim != 3 or arr.shape[2] != spec.dimensions or arr.dtype.kind not in 'fiu' or arr.shape[1] == 0:
        raise TrackError(
            f'{where}: expected positions [T, n, {spec.dimensions}] (a {spec.dimensions}D scenario, '
            f'n >= 1 robots), got {arr.dtype} {list(arr.shape)}'
        )
    if not max(arr.shape[0] - 1, 0) / fps <= TIME_LIMIT_S:
        raise TrackError(
            f'{where}: {arr.shape[0]} frames at --fps {fps:g} last beyond the {TIME_LIMIT_S:.3g} s '
            f'that nanosecond stamps hold'
        )
    ns = np.round(np.arange(arr.shape[0]) / fps * 1e9).astype(np.int64)
    tracks = [
        _track(i, f'column {i}', ns, arr[:, i].astype(np.float64), None, None) for i in range(arr.shape[1])
    ]
    return tracks, {
        'format': 'npy',
        'frames': int(arr.shape[0]),
        'fps': fps,
        'columns': ['x', 'y', 'z'][: spec.dimensions],
    }


def _load_npy(path: Path, where: str) -> np.ndarray:
    """The plain numeric array of an .npy file; its header is checked against the file's size
    first (a header can declare terabytes)."""
    hint = (
        "; from a tracker's dict (idtracker.ai trajectories.npy) save its 'trajectories' array with "
        'numpy.save'
    )
    try:
        with open(path, 'rb') as fh:
            shape, dtype, declared = npy_header(fh)
            if declared is not None and declared > os.fstat(fh.fileno()).st_size - fh.tell():
                raise TrackError(
                    f'{where}: its header declares {dtype} {list(shape)} ({declared} bytes), more '
                    'than the file holds'
                )
        arr = np.load(path, allow_pickle=False)
    except (ValueError, EOFError) as exc:  # (TrackError is a ValueError)
        if isinstance(exc, TrackError):
            raise
        raise TrackError(f'{where}: not a plain numeric .npy array ({exc}){hint}') from None
    return arr


def _track(rid, name, ns, pos, vel, heading) -> Track:
    """A :class:`Track` of the usable samples: a repeated stamp (the later row) and non-finite values
    (a lost robot) are dropped and counted."""
    keep = np.ones(ns.size, dtype=bool)
    keep[1:] = np.diff(ns) > 0
    finite = np.all(np.isfinite(pos), axis=1)
    for extra in (vel, heading):
        if extra is not None:
            finite &= np.all(np.isfinite(extra), axis=1)
    r = Track(
        rid, name, read=int(ns.size), duplicates=int((~keep).sum()), non_finite=int((keep & ~finite).sum())
    )
    keep &= finite
    r.ns, r.pos = ns[keep], pos[keep]
    r.vel = vel[keep] if vel is not None else None
    r.heading = heading[keep] if heading is not None else None
    return r


def read_track_file(path, spec: Scenario, fps: Optional[float] = None) -> Tuple[List[Track], Dict[str, Any]]:
    """The tracks of one file in ascending id order, and what was read (``format``, ``columns``...).

    Raises:
        TrackError: an unreadable file, a missing column (named), a bad value (line named), no usable
            sample for a robot.
    """
    path = Path(path)
    where = str(path)
    if not path.is_file():
        raise TrackError(f'{where}: no such file')
    suffix = path.suffix.lower()
    if suffix == '.npy':
        tracks, info = _read_npy(path, spec, fps)
    elif suffix in ('.csv', '.txt'):
        if fps is not None:
            raise TrackError(f'{where}: --fps is for .npy arrays; a CSV file carries its times in column t')
        tracks, info = _read_csv(path, spec)
    else:
        raise TrackError(
            f'{where}: not a track file; expected .csv (t, id, x, y, ...) or .npy [T, n, dim] with --fps'
        )
    for r in tracks:
        if r.ns.size == 0:
            raise TrackError(f'{where}: {r.label} has no usable sample ({r.non_finite} non-finite)')
    return tracks, info


def single_frame(tracks: List[Track]) -> Optional[float]:
    """The time (s) of a file that is one frame (every robot one sample, all at one stamp), else None."""
    if all(r.ns.size == 1 for r in tracks) and len({int(r.ns[0]) for r in tracks}) == 1:
        return float(tracks[0].ns[0]) * 1e-9
    return None
