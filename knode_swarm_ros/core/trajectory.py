"""Trajectory files (docs/DESIGN.md, "Trajectory files"): read, validate and write atomically.

A file is an ``.npz`` with ``states`` float64 ``[trajectories, T, n, d]`` (T >= 1),
``dt`` (float), ``scenario`` (string: a shipped scenario's name, or the whole scenario as a JSON
object, see :func:`~.scenarios.scenario_ref`) and ``meta`` (a JSON string).
"""

from __future__ import annotations

import json
import math
import os
import tempfile
import tokenize
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, Optional, Tuple, Union

import numpy as np

from .errors import KnodeError
from .scenarios import SCENARIOS, Scenario, ScenarioError, get_scenario, scenario_ref

__all__ = [
    'TrajectoryFile',
    'TrajectoryError',
    'load_trajectories',
    'save_trajectories',
    'parse_trajectory_ref',
    'atomic_write',
    'npy_header',
]

PathLike = Union[str, os.PathLike]
#: What numpy's .npy header parser raises besides ValueError: a header it cannot tokenize (a NUL
#: byte and an unclosed bracket) fails in Python's own parser; one with a bytes key (b'shape')
#: fails sorting the keys.
NPY_HEADER_ERRORS = (SyntaxError, tokenize.TokenError, TypeError)


class TrajectoryError(KnodeError, ValueError):
    """A trajectory file is missing, malformed or inconsistent; the message names file and field."""


@dataclass
class TrajectoryFile:
    """Contents of a trajectory file.

    Attributes:
        states: float64 ``[trajectories, T, n, d]``.
        dt: seconds between frames.
        scenario: the scenario's reference: its name if shipped, else its JSON object's text
            (:func:`~.scenarios.get_scenario` resolves either; :attr:`spec` is the resolved one).
        meta: free-form metadata (generator, parameters, seeds, ``split`` with train/test indices).
    """

    states: np.ndarray
    dt: float
    scenario: str
    meta: Dict[str, Any] = field(default_factory=dict)

    @property
    def spec(self) -> Scenario:
        return get_scenario(self.scenario)

    def split(self, name: str) -> np.ndarray:
        """Indices of the trajectories in split ``name`` (``train`` or ``test``) from ``meta['split']``;
        all trajectories when the file records no split."""
        split = self.meta.get('split') or {}
        if name not in split:
            return np.arange(self.states.shape[0])
        return np.asarray(split[name], dtype=np.int64)


def atomic_write(path: PathLike, write) -> None:
    """Call ``write(tmp_path)`` then rename onto ``path``, so a crash never leaves half a file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f'.{path.name}.', suffix='.tmp', dir=path.parent)
    os.close(fd)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; give the file the usual permissions
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _scalar(where: str, name: str, value: np.ndarray, what: str, kinds: str):
    """The single value of field ``name`` (a 0-d array of dtype kind in ``kinds``), or a
    :class:`TrajectoryError` naming the field."""
    value = np.asarray(value)
    if value.ndim != 0 or value.dtype.kind not in kinds:
        shape = f'an array of shape {value.shape}' if value.ndim else f'dtype {value.dtype}'
        raise TrajectoryError(f'{where}: field {name!r} must be {what}, got {shape}')
    return str(value) if kinds == 'U' else float(value)


def npy_header(fh) -> Tuple[tuple, np.dtype, Optional[int]]:
    """Shape, dtype and bytes of data that the .npy header at ``fh`` declares (``fh`` is left at
    the data; bytes None for an object dtype, which ``allow_pickle=False`` refuses). A reader
    compares the bytes with what the file holds before numpy allocates the declared array (a few
    header bytes could claim terabytes).

    Raises:
        ValueError: not an .npy magic string or header (numpy's message).
    """
    fmt = np.lib.format
    version = fmt.read_magic(fh)
    read_header = fmt.read_array_header_1_0 if version == (1, 0) else fmt.read_array_header_2_0
    try:
        shape, _, dtype = read_header(fh)
    except NPY_HEADER_ERRORS as exc:
        raise ValueError(f'cannot parse the .npy header: {exc}') from None
    return shape, dtype, None if dtype.hasobject else math.prod(shape) * dtype.itemsize


def _check_declared_size(where: str, data, name: str) -> None:
    """Refuse a member whose .npy header declares more bytes than the member holds."""
    member = f'{name}.npy'
    if member not in data.zip.namelist():
        return  # numpy reports it
    with data.zip.open(member) as fh:
        shape, dtype, declared = npy_header(fh)
        if declared is not None and declared > data.zip.getinfo(member).file_size - fh.tell():
            raise TrajectoryError(
                f'{where}: field {name!r} declares shape {shape} of {dtype} ({declared} bytes), '
                'more than the file holds'
            )


def _check_split(where: str, split: Any, count: int) -> None:
    """``meta['split']`` (training reads it): absent, or ``train`` / ``test`` lists of indices into
    the ``count`` trajectories."""
    if not split:
        return
    if not isinstance(split, dict):
        raise TrajectoryError(f"{where}: field 'meta': 'split' must be an object, got {type(split).__name__}")
    for name in ('train', 'test'):
        idx = split.get(name, [])
        if not (isinstance(idx, list) and all(type(i) is int and 0 <= i < count for i in idx)):
            raise TrajectoryError(
                f"{where}: field 'meta': split {name!r} must be a list of trajectory indices "
                f'0 .. {count - 1}, got {str(idx)[:80]}'
            )


def _resolve(where: str, scenario) -> Scenario:
    try:
        return get_scenario(scenario)
    except ScenarioError as exc:
        raise TrajectoryError(f"{where}: field 'scenario': {exc}") from None


def _validate(where: str, states: np.ndarray, dt: float, scenario) -> None:
    spec = _resolve(where, scenario)
    if states.ndim != 4:
        raise TrajectoryError(
            f"{where}: field 'states' must be [trajectories, T, n, d], got shape {states.shape}"
        )
    if min(states.shape[:3]) < 1:
        raise TrajectoryError(f"{where}: field 'states' has an empty axis, shape {states.shape}")
    if states.shape[3] != spec.state_dim:
        raise TrajectoryError(
            f"{where}: field 'states' has d = {states.shape[3]}, scenario {spec.name} "
            f'needs d = {spec.state_dim} ({", ".join(spec.state_layout)})'
        )
    if not np.all(np.isfinite(states)):
        bad = np.argwhere(~np.isfinite(states))[0]
        raise TrajectoryError(
            f"{where}: field 'states' holds a non-finite value at index {tuple(int(i) for i in bad)}"
        )
    if not (np.isfinite(dt) and dt > 0):
        raise TrajectoryError(f"{where}: field 'dt' must be a positive number, got {dt}")


def save_trajectories(
    path: PathLike, states: np.ndarray, dt: float, scenario, meta: Optional[Dict[str, Any]] = None
) -> None:
    """Validate and write a trajectory file atomically (temporary file, then rename);
    ``scenario`` is any reference :func:`~.scenarios.get_scenario` resolves (the file carries a
    shipped scenario's name, else the whole scenario)."""
    states = np.asarray(states, dtype=np.float64)
    _validate(str(path), states, float(dt), scenario)
    scenario = scenario_ref(scenario)
    meta_json = json.dumps(meta or {}, sort_keys=True)

    def write(tmp):
        with open(tmp, 'wb') as fh:
            np.savez(
                fh, states=states, dt=np.float64(dt), scenario=np.str_(scenario), meta=np.str_(meta_json)
            )

    atomic_write(path, write)


def load_trajectories(path: PathLike, scenario=None) -> TrajectoryFile:
    """Read and validate a trajectory file; with ``scenario`` given (any reference), refuse another
    scenario."""
    where = str(path)
    if not os.path.isfile(path):
        raise TrajectoryError(f'{where}: no such file')
    try:
        with np.load(path, allow_pickle=False) as data:
            missing = [k for k in ('states', 'dt', 'scenario', 'meta') if k not in data.files]
            if missing:
                raise TrajectoryError(f'{where}: missing field(s) {", ".join(missing)}')
            _check_declared_size(where, data, 'states')
            states = np.asarray(data['states'], dtype=np.float64)
            dt = _scalar(where, 'dt', data['dt'], 'a number (seconds between frames)', 'fiu')
            name = _scalar(where, 'scenario', data['scenario'], 'a string', 'U')
            meta_text = _scalar(where, 'meta', data['meta'], 'a JSON string', 'U')
    except TrajectoryError:
        raise
    except (
        OSError,
        ValueError,
        TypeError,
        zipfile.BadZipFile,
        EOFError,
        zlib.error,
        *NPY_HEADER_ERRORS,
    ) as exc:
        raise TrajectoryError(f'{where}: not a readable .npz trajectory file ({exc})') from None
    try:
        meta = json.loads(meta_text) if meta_text else {}
    except (ValueError, RecursionError) as exc:  # also integers of > 4300 digits, brackets nested too deep
        raise TrajectoryError(f"{where}: field 'meta' is not valid JSON ({exc})") from None
    if not isinstance(meta, dict):
        raise TrajectoryError(f"{where}: field 'meta' must be a JSON object, got {type(meta).__name__}")
    if name not in SCENARIOS and not name.lstrip().startswith('{'):  # a file names no other file
        raise TrajectoryError(
            f"{where}: field 'scenario' is {name!r}; known: {', '.join(sorted(SCENARIOS))}, "
            'or the whole scenario as a JSON object'
        )
    _validate(where, states, dt, name)
    _check_split(where, meta.get('split'), states.shape[0])
    name = scenario_ref(name)
    if scenario is not None and get_scenario(name) != _resolve('expected scenario', scenario):
        raise TrajectoryError(f"{where}: field 'scenario' is {name!r}, expected {scenario_ref(scenario)!r}")
    return TrajectoryFile(states, dt, name, meta)


def parse_trajectory_ref(ref: str) -> Tuple[str, int]:
    """Split ``FILE.npz[:TRAJ]`` into (path, trajectory index), index 0 by default."""
    path, sep, index = ref.rpartition(':')
    if sep and index.isdigit() and path:
        return path, int(index)
    return ref, 0
