"""A fleet: the robots' names and ids, where their states come from and where commands go (no ROS).

A fleet file (YAML; docs/ros.md, "Your own fleet")::

    robots:                              # name -> id (ids any distinct integers)
      cf231: {id: 0}
      cf5: {id: 7, initial_position: [1.0, 0.0, 0.5]}
    state:
      topic: /vrpn_mocap/{name}/pose     # template: {name}, {id}; relative: in the robot's namespace
      type: pose                         # odometry | pose (geometry_msgs/PoseStamped)
      rate: 100                          # pose: the stream's rate, Hz (optional; sets the default window)
      velocity_window: 10                # pose: samples of the velocity fit (core/estimator.py)
    command:
      topic: /{name}/cmd_vel
      type: twist_stamped                # accel_stamped | twist_stamped | twist
      interface: velocity_setpoint       # policy | velocity_setpoint | unicycle
      speed_limit: 1.0                   # velocity_setpoint: per-axis |v_sp| limit, m/s (optional)

``robots`` may also be the path of a Crazyswarm2 ``crazyflies.yaml`` (relative to the fleet
file), and a ``crazyflies.yaml`` itself is read as a fleet: its ``robots:`` section, robots with
``enabled: false`` left out, a robot without ``id`` numbered by the digits its name ends with
(``cf231`` is 231), its other keys (``uri``, ``type``, ...) ignored; state and command default.

The default fleet (no file) is the simulator's layout: ``robot_<id>``, Odometry on
``robot_<id>/odom``, the policy's own command on ``robot_<id>/cmd_accel`` (AccelStamped) or
``robot_<id>/cmd_vel`` (TwistStamped). Relative topics stay relative after resolution
(``robot_3/odom``), so a node's namespace or a remapping still moves them.
"""

from __future__ import annotations

import os
import re
import string
from dataclasses import dataclass, field
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple

from knode_swarm_ros.core.errors import ConfigError
from knode_swarm_ros.core.estimator import DEFAULT_WINDOW, window_for_rate
from knode_swarm_ros.core.yaml_file import read_yaml

__all__ = [
    'Fleet',
    'Robot',
    'StateSpec',
    'CommandSpec',
    'STATE_TYPES',
    'COMMAND_TYPES',
    'INTERFACES',
    'load_fleet',
    'parse_fleet',
    'default_fleet',
    'resolve_topic',
    'policy_command_type',
]

STATE_TYPES = ('odometry', 'pose')
COMMAND_TYPES = ('accel_stamped', 'twist_stamped', 'twist')
INTERFACES = ('policy', 'velocity_setpoint', 'unicycle')
TEMPLATE_FIELDS = ('name', 'id')

_TOP_KEYS = ('robots', 'state', 'command')
_ROBOT_KEYS = ('id', 'enabled', 'initial_position')
_STATE_KEYS = ('topic', 'type', 'rate', 'velocity_window')
_COMMAND_KEYS = ('topic', 'type', 'interface', 'speed_limit')
# What the last segment of a topic says its type is: a mismatch is almost always a copy-paste slip.
_TOPIC_HINTS = {
    'odom': ('odometry',),
    'pose': ('pose',),
    'cmd_accel': ('accel_stamped',),
    'cmd_vel': ('twist_stamped', 'twist'),
    'cmd_velocity_world': ('twist_stamped', 'twist'),
}
_CRAZYSWARM_KEYS = ('fileversion', 'robot_types', 'all')


def policy_command_type(command_kind: str) -> str:
    """The message type of a policy's own command: ``acceleration`` -> ``accel_stamped``,
    ``velocity`` -> ``twist_stamped``."""
    return 'accel_stamped' if command_kind == 'acceleration' else 'twist_stamped'


def resolve_topic(template: str, name: str, robot_id: int) -> str:
    """The topic of robot ``name`` (id ``robot_id``): ``{name}``/``{id}`` filled in; a relative
    template is put in the robot's namespace (``odom`` -> ``cf5/odom``), an absolute one kept."""
    topic = template.format(name=name, id=int(robot_id))
    return topic if topic.startswith('/') else f'{name}/{topic}'


@dataclass(frozen=True)
class Robot:
    """One robot of the fleet: its ``name``, ``id`` and optional ``initial_position [3]``."""

    name: str
    id: int
    initial_position: Optional[Tuple[float, ...]] = None


@dataclass(frozen=True)
class StateSpec:
    """Where a robot's state comes from: topic template and message type."""

    topic: str = 'odom'
    type: str = 'odometry'
    velocity_window: int = DEFAULT_WINDOW  # default: window_for_rate(rate), DEFAULT_WINDOW without a rate
    rate: Optional[float] = None  # the stream's nominal rate in Hz, when the file states it


@dataclass(frozen=True)
class CommandSpec:
    """Where a robot's command goes; ``topic``/``type`` None: the policy's own (``cmd_accel`` or
    ``cmd_vel``, :func:`policy_command_type`)."""

    topic: Optional[str] = None
    type: Optional[str] = None
    interface: str = 'policy'
    speed_limit: Optional[float] = None


@dataclass(frozen=True)
class Fleet:
    """Robots (ascending ids), their state source and command sink; ``path`` the file ('' default)."""

    robots: Tuple[Robot, ...]
    state: StateSpec = field(default_factory=StateSpec)
    command: CommandSpec = field(default_factory=CommandSpec)
    path: str = ''

    @property
    def ids(self) -> List[int]:
        """The robots' ids, ascending."""
        return [r.id for r in self.robots]

    @property
    def names(self) -> List[str]:
        """The robots' names, in id order."""
        return [r.name for r in self.robots]

    def robot(self, key) -> Robot:
        """The robot of name ``key`` (str) or id ``key`` (int); ConfigError naming it otherwise."""
        for r in self.robots:
            if (isinstance(key, str) and r.name == key) or (not isinstance(key, str) and r.id == int(key)):
                return r
        where = f' of {self.path}' if self.path else ''
        raise ConfigError(f'robot {key!r} is not in the fleet{where} (robots: {", ".join(self.names)})')

    def name_of(self, robot_id: int) -> str:
        """Robot ``robot_id``'s name."""
        return self.robot(int(robot_id)).name

    def state_topic(self, robot_id: int) -> str:
        """Robot ``robot_id``'s state topic."""
        return resolve_topic(self.state.topic, self.name_of(robot_id), robot_id)

    def command_topic(self, robot_id: int, command_kind: str) -> str:
        """Robot ``robot_id``'s command topic (``command_kind``: the policy's, used when the fleet
        leaves the command to the policy)."""
        template = self.command.topic
        if template is None:
            template = 'cmd_accel' if self.command_type(command_kind) == 'accel_stamped' else 'cmd_vel'
        return resolve_topic(template, self.name_of(robot_id), robot_id)

    def command_type(self, command_kind: str) -> str:
        """The command's message type (``accel_stamped``, ``twist_stamped`` or ``twist``)."""
        if self.command.type is not None:
            return self.command.type
        return policy_command_type(command_kind) if self.command.interface == 'policy' else 'twist_stamped'

    def status_topic(self, robot_id: int) -> str:
        """Robot ``robot_id``'s agent status topic, ``<name>/agent_status``."""
        return f'{self.name_of(robot_id)}/agent_status'

    def frame(self, robot_id: int) -> str:
        """Robot ``robot_id``'s body frame (REP 105), ``<name>/base_link``."""
        return f'{self.name_of(robot_id)}/base_link'

    def owns_frame(self, frame: str, robot_id: int) -> bool:
        """Whether a ``child_frame_id`` may belong to robot ``robot_id``: empty, its name, or
        ``<name>/<link>``."""
        name = self.name_of(robot_id)
        return frame == '' or frame == name or frame.startswith(name + '/')

    def check_scenario(self, command_kind: str, needs_velocity: bool) -> None:
        """Refuse a fleet whose command cannot carry this policy's command (``command_kind``)."""
        c = self.command
        if c.interface == 'policy' and c.type is not None and c.type != policy_command_type(command_kind):
            if not (command_kind == 'velocity' and c.type == 'twist'):
                raise ConfigError(
                    f"{self._where('command')}: type {c.type!r} cannot carry this policy's "
                    f'{command_kind} command (interface policy); use '
                    f'{policy_command_type(command_kind)!r} or interface velocity_setpoint'
                )
        if c.interface == 'velocity_setpoint' and command_kind != 'acceleration':
            raise ConfigError(
                f'{self._where("command")}: interface velocity_setpoint turns an acceleration command into '
                f'a velocity; this policy commands {command_kind} already (use interface policy)'
            )
        if c.interface == 'velocity_setpoint' and not needs_velocity:
            raise ConfigError(f'{self._where("command")}: velocity_setpoint needs a velocity in the state')

    def _where(self, entry: str) -> str:
        return f'{self.path or "fleet"}: {entry}'

    def meta(self) -> Dict[str, Any]:
        """What a recording's meta says of the fleet: ``robot_ids`` and ``robot_names``."""
        return {'robot_ids': self.ids, 'robot_names': self.names}


def default_fleet(robot_ids: Sequence[int]) -> Fleet:
    """Today's layout: ``robot_<id>`` robots with Odometry on ``robot_<id>/odom``."""
    return Fleet(tuple(Robot(f'robot_{int(i)}', int(i)) for i in sorted(int(i) for i in robot_ids)))


def load_fleet(path: str) -> Fleet:
    """Read and validate a fleet file or a Crazyswarm2 ``crazyflies.yaml``.

    Raises:
        ConfigError: naming the file and the offending entry.
    """
    return parse_fleet(_read_yaml(path), os.fspath(path))


def parse_fleet(data: Any, path: str = 'fleet') -> Fleet:
    """Validate a fleet's mapping (:func:`load_fleet` reads it); ``path`` names it in errors and
    resolves a ``robots:`` file path."""
    if not isinstance(data, Mapping):
        raise ConfigError(f'{path}: a fleet file must be a YAML mapping, got {type(data).__name__}')
    crazyswarm = any(k in data for k in _CRAZYSWARM_KEYS)
    if not crazyswarm:
        _known(data, _TOP_KEYS, path, 'top level')
    if 'robots' not in data:
        raise ConfigError(f'{path}: no robots: section')
    robots_entry = data['robots']
    if isinstance(robots_entry, str):  # a crazyflies.yaml next to the fleet file
        other = os.path.join(os.path.dirname(path), robots_entry)
        robots = _robots(_read_yaml(other).get('robots'), other, foreign=True)
    else:
        robots = _robots(robots_entry, path, foreign=crazyswarm)
    if crazyswarm:
        return Fleet(robots, path=path)
    state = _state(data.get('state') or {}, path)
    command = _command(data.get('command') or {}, path)
    return Fleet(robots, state, command, path)


def _read_yaml(path: str) -> Any:
    data = read_yaml(path, ConfigError, f'fleet file {path}')
    if not isinstance(data, Mapping):
        raise ConfigError(f'{path}: a fleet file must be a YAML mapping')
    return data


def _known(entry: Mapping, keys: Sequence[str], path: str, where: str) -> None:
    unknown = sorted(str(k) for k in entry if k not in keys)
    if unknown:
        raise ConfigError(f'{path}: {where}: unknown key(s) {", ".join(unknown)} (known: {", ".join(keys)})')


def _robots(entry: Any, path: str, foreign: bool) -> Tuple[Robot, ...]:
    if not isinstance(entry, Mapping) or not entry:
        raise ConfigError(f'{path}: robots: must map robot names to their entries')
    robots: List[Robot] = []
    seen: Dict[int, str] = {}
    for name, spec in entry.items():
        where = f'robots: {name}'
        spec = {} if spec is None else spec
        if not isinstance(spec, Mapping):
            raise ConfigError(f'{path}: {where}: must be a mapping (id, enabled, initial_position)')
        if not foreign:
            _known(spec, _ROBOT_KEYS, path, where)
        name = str(name)
        if not re.fullmatch(r'[A-Za-z][A-Za-z0-9_]*', name):
            raise ConfigError(
                f'{path}: {where}: a robot name must be a ROS name token ([A-Za-z][A-Za-z0-9_]*)'
            )
        if spec.get('enabled', True) is False:
            continue
        robot_id = spec.get('id')
        if robot_id is None:
            digits = re.search(r'(\d+)$', name)
            if not foreign or digits is None:
                raise ConfigError(f'{path}: {where}: no id (give id: N)')
            robot_id = int(digits.group(1))
        if isinstance(robot_id, bool) or not isinstance(robot_id, int) or robot_id < 0:
            raise ConfigError(f'{path}: {where}: id must be an integer >= 0, got {robot_id!r}')
        if robot_id in seen:
            raise ConfigError(f"{path}: {where}: id {robot_id} is also robot {seen[robot_id]}'s")
        seen[robot_id] = name
        position = spec.get('initial_position')
        if position is not None:
            try:
                position = tuple(float(x) for x in position)
            except (TypeError, ValueError):
                raise ConfigError(f'{path}: {where}: initial_position must be a list of numbers') from None
        robots.append(Robot(name, robot_id, position))
    if not robots:
        raise ConfigError(f'{path}: robots: every robot is disabled')
    return tuple(sorted(robots, key=lambda r: r.id))


def _template(topic: Any, path: str, where: str) -> str:
    if not isinstance(topic, str) or not topic:
        raise ConfigError(f'{path}: {where}: topic must be a non-empty string')
    try:
        fields = [f for _, f, _, _ in string.Formatter().parse(topic) if f is not None]
    except ValueError as exc:
        raise ConfigError(f'{path}: {where}: topic {topic!r} is not a valid template ({exc})') from None
    unknown = sorted({f for f in fields if f not in TEMPLATE_FIELDS})
    if unknown:
        raise ConfigError(
            f'{path}: {where}: topic {topic!r} has unknown field(s) {", ".join("{" + f + "}" for f in unknown)} '
            f'(known: {{name}}, {{id}})'
        )
    return topic


def _type_matches_topic(topic: str, kind: str, path: str, where: str) -> None:
    last = topic.rstrip('/').rsplit('/', 1)[-1]
    hint = _TOPIC_HINTS.get(last)
    if hint is not None and kind not in hint:
        raise ConfigError(
            f'{path}: {where}: type {kind!r} does not match topic {topic!r} (a {hint[0]} topic)'
        )


def _choice(entry: Mapping, key: str, choices: Sequence[str], default, path: str, where: str):
    value = entry.get(key, default)
    if value is not None and value not in choices:
        raise ConfigError(f'{path}: {where}: {key} {value!r} is not one of {", ".join(choices)}')
    return value


def _state(entry: Any, path: str) -> StateSpec:
    if not isinstance(entry, Mapping):
        raise ConfigError(f'{path}: state: must be a mapping (topic, type)')
    _known(entry, _STATE_KEYS, path, 'state')
    kind = _choice(entry, 'type', STATE_TYPES, 'odometry', path, 'state')
    topic = _template(entry.get('topic', 'odom' if kind == 'odometry' else 'pose'), path, 'state')
    _type_matches_topic(topic, kind, path, 'state')
    rate = entry.get('rate')
    if rate is not None:
        if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not 0 < rate < 1e6:
            raise ConfigError(f'{path}: state: rate must be a number > 0 (Hz), got {rate!r}')
        rate = float(rate)
    window = entry.get('velocity_window', DEFAULT_WINDOW if rate is None else window_for_rate(rate))
    if isinstance(window, bool) or not isinstance(window, int) or window < 2:
        raise ConfigError(f'{path}: state: velocity_window must be an integer >= 2, got {window!r}')
    return StateSpec(topic, kind, window, rate)


def _command(entry: Any, path: str) -> CommandSpec:
    if not isinstance(entry, Mapping):
        raise ConfigError(f'{path}: command: must be a mapping (topic, type, interface)')
    _known(entry, _COMMAND_KEYS, path, 'command')
    kind = _choice(entry, 'type', COMMAND_TYPES, None, path, 'command')
    interface = _choice(entry, 'interface', INTERFACES, 'policy', path, 'command')
    topic = entry.get('topic')
    if topic is not None:
        _template(topic, path, 'command')
        if kind is None:
            raise ConfigError(f'{path}: command: a topic needs its type ({", ".join(COMMAND_TYPES)})')
        _type_matches_topic(topic, kind, path, 'command')
    if interface in ('velocity_setpoint', 'unicycle') and kind == 'accel_stamped':
        raise ConfigError(f'{path}: command: interface {interface} sends velocities, not type accel_stamped')
    limit = entry.get('speed_limit')
    if limit is not None:
        if isinstance(limit, bool) or not isinstance(limit, (int, float)) or not limit > 0:
            raise ConfigError(f'{path}: command: speed_limit must be a number > 0 (m/s), got {limit!r}')
        limit = float(limit)
    return CommandSpec(topic, kind, interface, limit)
