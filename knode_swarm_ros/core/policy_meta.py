"""The policy file's ``knode.json`` contract, free of torch (docs/DESIGN.md, "Policy file contract").

Both runtimes check metadata here: the TorchScript loader (:mod:`.policy_io`) and the
onnxruntime one (:mod:`.policy_runtime`), so a robot that runs the ONNX twin checks exactly
what a TorchScript robot checks without importing torch. :func:`read_pt_meta` reads the
``knode.json`` of a TorchScript archive with :mod:`zipfile` alone (a TorchScript file is a zip
archive with the extra files under ``<root>/extra/``), which lets the ONNX path compare a twin
with its ``.pt`` without torch.
"""

from __future__ import annotations

import json
import math
import os
import zipfile
from importlib import resources
from pathlib import Path
from typing import Any, Dict, Optional, Union

from .errors import KnodeError
from .scenarios import SCENARIOS, ScenarioError, get_scenario

__all__ = [
    'PolicyError',
    'PolicyMismatchError',
    'FORMAT',
    'ENCODERS',
    'REQUIRED_KEYS',
    'BOUNDS',
    'check_meta',
    'parse_meta',
    'meta_scenario',
    'read_pt_meta',
    'shipped_policy_path',
]

FORMAT = 'knode-policy/1'
REQUIRED_KEYS = (
    'format',
    'scenario',
    'state_dim',
    'command_dim',
    'command',
    'k',
    'd_cr',
    'tau',
    'dt',
    'state_layout',
)
PathLike = Union[str, os.PathLike]
#: The policy network's encoders (key ``encoder``; absent means ``flat``).
ENCODERS = ('flat', 'set', 'equivariant')

#: Allowed ranges of the numeric knode.json keys (inclusive; d_cr and command_limit exclude 0).
#: Every robot builds and evaluates tensors and buffers from these numbers before checking
#: anything else, so a file must not be able to ask for absurd sizes (k = 10**9 allocates 32 GB
#: in the first forward call) or times that break the stamp arithmetic (dt = 1e-300).
BOUNDS = {
    'k': (1, 1024),
    'tau': (0, 10_000),
    'd_cr': (0.0, 1e6),
    'dt': (1e-6, 3600.0),
    'command_limit': (0.0, 1e9),
}
_WHY = {
    'k': 'rows of Y: the robot plus at most 1023 neighbours; Y [B, k, d] is built every step',
    'tau': 'delay in steps: every robot buffers 4 tau + 8 states of every robot',
    'd_cr': 'communication radius in metres',
    'dt': 'seconds per step: stamps are integer nanoseconds, so a step spans at least 1000 ns; '
    'at most an hour',
    'command_limit': 'per-axis saturation of the command',
}


class PolicyError(KnodeError, ValueError):
    """A policy file is missing, corrupt or does not match what the caller needs."""


class PolicyMismatchError(PolicyError):
    """A valid policy file whose knode.json ``key`` is ``got`` where the caller required ``required``
    (``expect=`` of the loaders); callers that name the key differently (a node's parameter) read
    the fields."""

    def __init__(self, where: str, key: str, got: Any, required: Any):
        super().__init__(f'{where}: knode.json key {key!r} is {got!r} but {required!r} was required')
        self.key, self.got, self.required = key, got, required


def _is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_num(v) -> bool:
    if not isinstance(v, (int, float)) or isinstance(v, bool):
        return False
    try:
        return math.isfinite(v)
    except OverflowError:  # an integer beyond float's range (JSON has no limit)
        return False


def check_meta(where: str, meta: Any, expect: Optional[Dict[str, Any]] = None) -> None:
    """Raise :class:`PolicyError` (prefixed ``where``) unless ``meta`` is a valid knode.json
    object, every key within :data:`BOUNDS`, whose keys equal the non-None values of ``expect``."""
    if not isinstance(meta, dict):
        raise PolicyError(f'{where}: knode.json must be a JSON object, got {type(meta).__name__}')
    missing = [key for key in REQUIRED_KEYS if key not in meta]
    if missing:
        raise PolicyError(f'{where}: knode.json lacks required key(s) {", ".join(missing)}')
    for key in ('format', 'command'):
        if not isinstance(meta[key], str):
            raise PolicyError(f'{where}: knode.json key {key!r} must be a string, got {meta[key]!r}')
    if meta['format'] != FORMAT:
        raise PolicyError(f"{where}: knode.json key 'format' is {meta['format']!r}, expected {FORMAT!r}")
    spec = meta_scenario(where, meta)
    wanted = {
        'state_dim': spec.state_dim,
        'command_dim': spec.command_dim,
        'command': spec.command,
        'state_layout': list(spec.state_layout),
    }
    for key, value in wanted.items():
        got = list(meta[key]) if key == 'state_layout' and isinstance(meta[key], (list, tuple)) else meta[key]
        if got != value:
            raise PolicyError(
                f'{where}: knode.json key {key!r} is {meta[key]!r}, scenario {spec.name} needs {value!r}'
            )

    numeric = {
        'k': _is_int(meta['k']) and BOUNDS['k'][0] <= meta['k'] <= BOUNDS['k'][1],
        'tau': _is_int(meta['tau']) and BOUNDS['tau'][0] <= meta['tau'] <= BOUNDS['tau'][1],
        'd_cr': _is_num(meta['d_cr']) and BOUNDS['d_cr'][0] < meta['d_cr'] <= BOUNDS['d_cr'][1],
        'dt': _is_num(meta['dt']) and BOUNDS['dt'][0] <= meta['dt'] <= BOUNDS['dt'][1],
    }
    if 'command_limit' in meta and meta['command_limit'] is not None:
        numeric['command_limit'] = (
            _is_num(meta['command_limit'])
            and BOUNDS['command_limit'][0] < meta['command_limit'] <= BOUNDS['command_limit'][1]
        )
    if meta.get('encoder', 'flat') not in ENCODERS:  # files from before the set encoder are flat
        raise PolicyError(
            f"{where}: knode.json key 'encoder' is {meta['encoder']!r}; known: {', '.join(ENCODERS)}"
        )
    for key, ok in numeric.items():
        if not ok:
            low, high = BOUNDS[key]
            raise PolicyError(
                f'{where}: knode.json key {key!r} has invalid value {meta[key]!r} '
                f'(allowed: {low:g} .. {high:g}; {_WHY[key]})'
            )
    for key, value in (expect or {}).items():
        if value is None:
            continue
        got = meta.get(key)
        if key == 'scenario':
            same = spec == _expected_scenario(value)
        elif _is_num(got) and _is_num(value):
            same = math.isclose(float(got), float(value), rel_tol=1e-9)
        else:
            same = got == value
        if not same:
            raise PolicyMismatchError(where, key, got, value)


def meta_scenario(where: str, meta: Dict[str, Any]):
    """The :class:`~.scenarios.Scenario` of a knode.json object: key ``scenario`` holds a shipped
    scenario's name or the whole scenario as a JSON object; anything else raises PolicyError."""
    value = meta.get('scenario')
    if not isinstance(value, (str, dict)):
        raise PolicyError(
            f"{where}: knode.json key 'scenario' must be a scenario name or object, got {value!r}"
        )
    if isinstance(value, str) and value not in SCENARIOS:  # a policy names no file: it carries the object
        raise PolicyError(
            f"{where}: knode.json key 'scenario' is {value!r}; known: {', '.join(sorted(SCENARIOS))}, "
            'or the whole scenario as a JSON object'
        )
    try:
        return get_scenario(value)
    except ScenarioError as exc:
        raise PolicyError(f"{where}: knode.json key 'scenario': {exc}") from None


def _expected_scenario(value: Any):
    """A caller's required scenario (a reference), or the value itself when it is no scenario
    (then it equals no policy's scenario)."""
    try:
        return get_scenario(value)
    except ScenarioError:
        return value


def parse_meta(where: str, text: Union[str, bytes, None]) -> Dict[str, Any]:
    """The knode.json object from its text (not yet checked: see :func:`check_meta`)."""
    if isinstance(text, bytes):
        text = text.decode('utf-8', errors='replace')
    if not text:
        raise PolicyError(f'{where}: no knode.json metadata')
    try:
        return json.loads(text)
    except (ValueError, RecursionError) as exc:  # also integers of > 4300 digits, brackets nested too deep
        raise PolicyError(f'{where}: knode.json is not valid JSON ({exc})') from None


def read_pt_meta(path: PathLike) -> Dict[str, Any]:
    """knode.json of a TorchScript policy file, read as a zip archive (no torch).

    Raises:
        PolicyError: not a zip archive, or no ``extra/knode.json`` in it.
    """
    where = f'policy file {os.fspath(path)}'
    try:
        with zipfile.ZipFile(path) as archive:
            names = [n for n in archive.namelist() if n.split('/', 1)[-1] == 'extra/knode.json']
            if not names:
                raise PolicyError(f"{where}: no knode.json metadata in the archive's extra files")
            return parse_meta(where, archive.read(names[0]))
    except (OSError, zipfile.BadZipFile) as exc:
        raise PolicyError(f'{where}: not a readable TorchScript archive ({exc})') from None


def shipped_policy_path(name: str) -> Path:
    """Path of a policy shipped inside the package (``policies/<name>.pt``; its ONNX twin
    ``policies/<name>.onnx`` lies beside it)."""
    ref = resources.files('knode_swarm_ros') / 'policies' / f'{name}.pt'
    if not ref.is_file():
        raise PolicyError(f'no shipped policy named {name!r} (looked for {ref})')
    return Path(str(ref))
