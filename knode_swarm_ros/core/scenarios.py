"""Swarm scenarios: a scenario is data (docs/scenarios.md), read from a YAML file or shipped by name.

A scenario file describes a swarm::

    name: my_swarm
    dimensions: 2                 # 2 or 3
    state: position               # position | position_velocity | position_heading
    command: velocity             # velocity (p += u dt) | acceleration (double integrator)
    dt: 0.05                      # s
    arena: null                   # or {half_width: 8.0}: walls on the faces of [-w, w]^dimensions

The paper's two, ``flock2d`` and ``boids3d``, ship as such files in ``knode_swarm_ros/scenarios``
and are referred to by name. A state vector z has ``state_dim`` entries laid out as
``state_layout``: the position first, then the velocity or the unit heading, if the state has one.

A *scenario reference* is what commands, trajectory files and policy files pass around: a shipped
name, a path to a YAML file, or the whole scenario as a JSON object (text or dict);
:func:`get_scenario` resolves any of them and :func:`scenario_ref` writes the canonical one (the
name of a shipped scenario, else the JSON object), so a file carries everything it needs.
"""

from __future__ import annotations

import functools
import json
import math
import os
from dataclasses import dataclass
from importlib import resources
from typing import Any, Dict, Mapping, Optional, Tuple, Union

from .errors import ConfigError
from .yaml_file import read_yaml

__all__ = [
    'Scenario',
    'ScenarioError',
    'SCENARIOS',
    'STATES',
    'COMMANDS',
    'VALID_COMBINATIONS',
    'get_scenario',
    'scenario_from_dict',
    'scenario_ref',
    'parse_scenario_argument',
]

#: state kind -> the command kind it goes with (the only valid combinations).
VALID_COMBINATIONS: Dict[str, str] = {
    'position': 'velocity',
    'position_heading': 'velocity',
    'position_velocity': 'acceleration',
}
STATES = tuple(VALID_COMBINATIONS)
COMMANDS = ('velocity', 'acceleration')
_FIELDS = ('name', 'dimensions', 'state', 'command', 'dt', 'arena')
_AXES = ('x', 'y', 'z')


class ScenarioError(ConfigError):
    """A scenario file or object is missing, unreadable or invalid; the message names the file
    (or where the object came from) and the field."""


@dataclass(frozen=True)
class Scenario:
    """Static description of a swarm (the fields of a scenario file).

    Attributes:
        name: a label (``flock2d``, ``boids3d`` or a scenario file's own).
        dimensions: 2 or 3, the number of position (and command) axes.
        state: ``position``, ``position_velocity`` or ``position_heading`` (unit heading).
        command: ``velocity`` (first order) or ``acceleration`` (double integrator).
        dt: the integration step in seconds.
        arena: half width w of the walls on the faces of ``[-w, w]^dimensions``, or None.
    """

    name: str
    dimensions: int
    state: str
    command: str
    dt: float
    arena: Optional[float]

    @property
    def position_dim(self) -> int:
        """p, the number of position entries (z[:p] is the position)."""
        return self.dimensions

    @property
    def command_dim(self) -> int:
        """m, the number of command entries (equals ``position_dim``)."""
        return self.dimensions

    @property
    def box(self) -> Optional[float]:
        """The arena's half width, or None (an unbounded space)."""
        return self.arena

    @property
    def state_layout(self) -> Tuple[str, ...]:
        """Names of the ``state_dim`` entries of z, e.g. ``('px', 'py', 'vx', 'vy')``."""
        axes = _AXES[: self.dimensions]
        extra = {'position': '', 'position_velocity': 'v', 'position_heading': 'h'}[self.state]
        return tuple('p' + a for a in axes) + (tuple(extra + a for a in axes) if extra else ())

    @property
    def state_dim(self) -> int:
        return len(self.state_layout)

    @property
    def position(self) -> slice:
        """Slice of z holding the position."""
        return slice(0, self.position_dim)

    @property
    def velocity(self) -> Optional[slice]:
        """Slice of z holding the velocity (``position_velocity``), else None."""
        return slice(self.position_dim, self.state_dim) if self.state == 'position_velocity' else None

    @property
    def heading(self) -> Optional[slice]:
        """Slice of z holding the unit heading (``position_heading``), else None."""
        return slice(self.position_dim, self.state_dim) if self.state == 'position_heading' else None

    @property
    def translation_invariant(self) -> bool:
        """Whether the dynamics ignore absolute position (no walls), which lets the ``relative``
        input frame drop the own position."""
        return self.arena is None

    @property
    def shipped(self) -> bool:
        """Whether this is one of the shipped scenarios, unchanged."""
        return SCENARIOS.get(self.name) == self

    def to_dict(self) -> Dict[str, Any]:
        """The scenario as a scenario file's mapping (JSON and YAML serialisable)."""
        return {
            'name': self.name,
            'dimensions': self.dimensions,
            'state': self.state,
            'command': self.command,
            'dt': self.dt,
            'arena': None if self.arena is None else {'half_width': self.arena},
        }


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def scenario_from_dict(data: Any, where: str = 'scenario') -> Scenario:
    """Validate a scenario file's mapping and build the :class:`Scenario`.

    Raises:
        ScenarioError: not a mapping, an unknown, missing or ill-typed field, an invalid
            ``state``/``command`` combination, or a shipped scenario's name on other values;
            the message starts with ``where`` and names the field.
    """

    def refuse(field: str, what: str) -> ScenarioError:
        return ScenarioError(f'{where}: field {field!r} {what}')

    if not isinstance(data, Mapping):
        raise ScenarioError(f'{where}: a scenario must be a mapping of fields, got {type(data).__name__}')
    unknown = sorted(str(key) for key in data if key not in _FIELDS)
    if unknown:
        raise refuse(unknown[0], f'is not a scenario field (fields: {", ".join(_FIELDS)})')
    missing = [key for key in _FIELDS if key not in data]
    if missing:
        raise refuse(
            missing[0], 'is missing (use null for no arena)' if missing[0] == 'arena' else 'is missing'
        )
    name, dims, state, command, dt, arena = (data[key] for key in _FIELDS)
    if not isinstance(name, str) or not name.strip() or name.lstrip().startswith('{'):
        raise refuse('name', f'must be a non-empty string, got {name!r}')
    if not isinstance(dims, int) or isinstance(dims, bool) or dims not in (2, 3):
        raise refuse('dimensions', f'must be 2 or 3, got {dims!r}')
    if not isinstance(state, str) or state not in STATES:
        raise refuse('state', f'must be one of {", ".join(STATES)}, got {state!r}')
    if not isinstance(command, str) or command not in COMMANDS:
        raise refuse('command', f'must be one of {", ".join(COMMANDS)}, got {command!r}')
    if VALID_COMBINATIONS[state] != command:
        raise refuse(
            'command',
            f'is {command!r} but state {state!r} needs command {VALID_COMBINATIONS[state]!r} '
            '(valid: position + velocity, position_heading + velocity, position_velocity + acceleration)',
        )
    if not _is_number(dt) or dt <= 0:
        raise refuse('dt', f'must be a positive number of seconds, got {dt!r}')
    if arena is not None:
        if not isinstance(arena, Mapping) or set(arena) != {'half_width'}:
            raise refuse('arena', f'must be null or a mapping {{half_width: W}}, got {arena!r}')
        width = arena['half_width']
        if not _is_number(width) or width <= 0:
            raise refuse('arena.half_width', f'must be a positive number, got {width!r}')
        arena = float(width)
    spec = Scenario(name, dims, state, command, float(dt), arena)
    if name in SCENARIOS and SCENARIOS[name] != spec:
        raise refuse('name', f'is {name!r}, a shipped scenario with other values; choose another name')
    return spec


def _read_yaml(path: str) -> Scenario:
    where = f'scenario file {path}'
    data = read_yaml(path, ScenarioError, where)
    return scenario_from_dict(data, where)


def _load_shipped() -> Dict[str, Scenario]:
    folder = resources.files('knode_swarm_ros') / 'scenarios'
    shipped = {}
    for entry in sorted(folder.iterdir(), key=lambda e: e.name):
        if entry.name.endswith('.yaml'):
            spec = _read_yaml(str(entry))
            if spec.name != entry.name[: -len('.yaml')]:
                raise ScenarioError(f'scenario file {entry}: field name is {spec.name!r}, not its file name')
            shipped[spec.name] = spec
    return shipped


#: The shipped scenarios by name (read from ``knode_swarm_ros/scenarios/*.yaml``).
SCENARIOS: Dict[str, Scenario] = {}
SCENARIOS.update(_load_shipped())


@functools.lru_cache(maxsize=64)
def _from_text(text: str) -> Scenario:
    text = text.strip()
    if text.startswith('{'):
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ScenarioError(f'scenario JSON object: not valid JSON ({exc})') from None
        return scenario_from_dict(data, 'scenario JSON object')
    if text in SCENARIOS:
        return SCENARIOS[text]
    if text.endswith(('.yaml', '.yml')) or os.path.isfile(text):
        if not os.path.isfile(text):
            raise ScenarioError(f'scenario file {text}: no such file')
        return _read_yaml(text)
    raise ScenarioError(
        f'unknown scenario {text!r}; known: {", ".join(sorted(SCENARIOS))}, or a scenario file (.yaml)'
    )


def get_scenario(ref: Union[str, os.PathLike, Mapping[str, Any], Scenario]) -> Scenario:
    """Resolve a scenario reference: a :class:`Scenario`, a shipped name, a YAML file's path, or
    the scenario as a mapping or a JSON object's text.

    Raises:
        ScenarioError: an unknown name, a missing or invalid file, an invalid scenario.
    """
    if isinstance(ref, Scenario):
        return ref
    if isinstance(ref, Mapping):
        return scenario_from_dict(ref, 'scenario object')
    if isinstance(ref, os.PathLike):
        ref = os.fspath(ref)
    if not isinstance(ref, str):
        raise ScenarioError(f'a scenario is a name, a file or a mapping, got {type(ref).__name__}')
    if ref in SCENARIOS:
        return SCENARIOS[ref]
    # YAML files are read again when they change, not served stale from the cache.
    return _read_yaml(ref) if not ref.lstrip().startswith('{') and os.path.isfile(ref) else _from_text(ref)


def scenario_ref(spec: Union[str, Mapping[str, Any], Scenario]) -> str:
    """The canonical reference of a scenario: a shipped scenario's name, else its JSON object
    (keys sorted), which :func:`get_scenario` resolves without any file."""
    spec = get_scenario(spec)
    if spec.shipped:
        return spec.name
    return json.dumps(spec.to_dict(), sort_keys=True)


def parse_scenario_argument(text: str) -> str:
    """``--scenario NAME|FILE.yaml`` of every command: the canonical reference (see
    :func:`scenario_ref`); raises :class:`ScenarioError` naming the file and field."""
    return scenario_ref(get_scenario(text))
