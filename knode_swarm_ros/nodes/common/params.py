"""Parameter declaration with descriptors, turning rclpy's exceptions into :class:`ConfigError`.

Every parameter is declared read-only with a description and, for numbers, a range, so that
``ros2 param describe`` documents it; a value of the wrong type or out of range stops the
node at start with a message that names the parameter.
"""

from __future__ import annotations

import difflib
from typing import Any, Iterable, List, Optional, Sequence, Tuple

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.exceptions import (
    InvalidParameterTypeException,
    InvalidParameterValueException,
    ParameterUninitializedException,
)
from rclpy.parameter import Parameter

from knode_swarm_ros.core.yaml_file import load_yaml
from knode_swarm_ros.logic.common import ConfigError

__all__ = [
    'declare',
    'declare_scenario',
    'scenario_parameter',
    'SCENARIO_HELP',
    'declare_int_array',
    'node_name_from_args',
    'check_overrides',
    'shadowed_overrides',
]

#: Parameters every rclpy node has without declaring them here.
_BUILTIN = ('use_sim_time', 'start_type_description_service')

_TYPE_WORDS = {
    bool: 'a boolean (true/false)',
    int: 'an integer',
    float: 'a floating-point number',
    str: 'a string',
}


def declare(
    node,
    name: str,
    default: Any,
    description: str,
    *,
    int_range: Optional[Tuple[int, int]] = None,
    float_range: Optional[Tuple[float, float]] = None,
    choices: Optional[Sequence[str]] = None,
) -> Any:
    """Declare ``name`` (read-only) with ``default`` and return its value.

    Raises:
        ConfigError: wrong type, out of ``int_range``/``float_range`` (inclusive), or not one
            of ``choices``; the message names the parameter and the value.
    """
    descriptor = ParameterDescriptor(description=description, read_only=True)
    if int_range is not None:
        descriptor.integer_range = [
            IntegerRange(from_value=int(int_range[0]), to_value=int(int_range[1]), step=0)
        ]
    if float_range is not None:
        descriptor.floating_point_range = [
            FloatingPointRange(from_value=float(float_range[0]), to_value=float(float_range[1]), step=0.0)
        ]
    if choices is not None:
        descriptor.additional_constraints = 'one of: ' + ', '.join(choices)
    try:
        value = node.declare_parameter(name, default, descriptor).value
    except InvalidParameterTypeException:
        word = _TYPE_WORDS.get(type(default), type(default).__name__)
        got = _override(node, name)
        hint = (
            f' (write {got}.0)'
            if isinstance(default, float) and isinstance(got, int) and not isinstance(got, bool)
            else ''
        )
        raise ConfigError(f'parameter {name!r} must be {word}{hint}, got {got!r}') from None
    except InvalidParameterValueException:
        if int_range is not None:
            limits = f'{int_range[0]} .. {int_range[1]}'
        elif float_range is not None:
            limits = f'{float_range[0]:g} .. {float_range[1]:g}'
        else:
            limits = 'its constraints'
        got = _override(node, name)
        raise ConfigError(f'parameter {name!r} = {got!r} is out of range ({limits}): {description}') from None
    if choices is not None and value not in choices:
        raise ConfigError(f'parameter {name!r} = {value!r} is not one of {", ".join(choices)}')
    return value


#: What every node's ``scenario`` parameter says of its value.
SCENARIO_HELP = 'flock2d, boids3d, a scenario file (.yaml) or the scenario as a JSON object'


def scenario_parameter(value: str, name: str = 'scenario') -> str:
    """The canonical reference (:func:`knode_swarm_ros.core.scenarios.scenario_ref`) of a
    scenario parameter's value ('' stays '': unset).

    Raises:
        ConfigError: an unknown name, a missing or invalid file; the message names the parameter.
    """
    from knode_swarm_ros.core.scenarios import ScenarioError, parse_scenario_argument

    if not value:
        return ''
    try:
        return parse_scenario_argument(value)
    except ScenarioError as exc:
        raise ConfigError(f'parameter {name!r} = {value!r}: {exc}') from None


def declare_scenario(node, default: str, description: str = SCENARIO_HELP) -> str:
    """Declare the ``scenario`` parameter (a shipped name, a scenario file or the JSON object)
    and return its canonical reference (:func:`scenario_parameter`)."""
    return scenario_parameter(declare(node, 'scenario', default, description))


def declare_int_array(node, name: str, description: str) -> List[int]:
    """Declare an integer array without default; returns [] when no value was given."""
    descriptor = ParameterDescriptor(description=description, read_only=True)
    try:
        node.declare_parameter(name, Parameter.Type.INTEGER_ARRAY, descriptor)
        value = node.get_parameter(name).value
    except ParameterUninitializedException:
        return []
    except (InvalidParameterTypeException, InvalidParameterValueException):
        raise ConfigError(
            f'parameter {name!r} must be a list of integers, got {_override(node, name)!r}'
        ) from None
    return [int(v) for v in (value or [])]


def _override(node, name: str) -> Any:
    try:
        return node._parameter_overrides[name].value
    except (AttributeError, KeyError):
        return '?'


def node_name_from_args(args: Optional[Iterable[str]], base: str, key: str = 'id') -> str:
    """``<base>_<id>`` when the command line sets ``-p id:=N`` (so that many agents get
    distinct node names), else ``base``; ``-r __node:=...`` still overrides either."""
    items = list(args or [])
    for flag, value in zip(items, items[1:]):
        if flag in ('-p', '--param') and value.startswith(key + ':='):
            tail = value[len(key) + 2 :].strip()
            if tail.isdigit():
                return f'{base}_{int(tail)}'
    return base


def check_overrides(node, argv: Optional[Sequence[str]] = None) -> None:
    """After every parameter is declared: values the user gave that would not take effect.

    The rule (the same for every node): a value that would be silently ignored is refused when
    it is certainly a mistake, and warned about otherwise.

    * an undeclared name close to a declared one (``state_timout``) is a typo: refused;
    * another undeclared name is warned about (a params file may be shared with other nodes);
    * ``-p NAME:=V`` followed by a ``--params-file`` that sets NAME again: ROS applies them in
      order, so the file wins without a word: refused (put ``-p`` after the file).

    Raises:
        ConfigError: naming the parameter (and the file).
    """
    declared = set(getattr(node, '_parameters', {}))
    overrides = getattr(node, '_parameter_overrides', {}) or {}
    for name in sorted(overrides):
        if name in declared or name in _BUILTIN or name.startswith('qos_overrides.'):
            continue
        close = difflib.get_close_matches(name, sorted(declared), n=1, cutoff=0.8)
        if close:
            raise ConfigError(
                f'unknown parameter {name!r}: did you mean {close[0]!r}? (an unknown name is '
                'ignored by ROS, so its value would not take effect)'
            )
        node.get_logger().warning(f'parameter {name!r} is not a parameter of this node: ignored')
    for name, path in shadowed_overrides(argv, node.get_name()):
        raise ConfigError(
            f'parameter {name!r} is given with -p before --params-file {path}, which sets it '
            'again and wins (ROS applies them in order): put -p after --params-file'
        )


def shadowed_overrides(argv: Optional[Sequence[str]], node_name: str) -> List[Tuple[str, str]]:
    """``(name, params file)`` for every ``-p name:=...`` that a later ``--params-file`` section
    for this node (``/**``, ``**`` or the node's name) sets again."""
    import yaml

    items = list(argv or [])
    if '--ros-args' not in items:
        return []
    items = items[items.index('--ros-args') + 1 :]
    given: List[str] = []
    out: List[Tuple[str, str]] = []
    for flag, value in zip(items, items[1:]):
        if flag in ('-p', '--param') and ':=' in value:
            given.append(value.split(':=', 1)[0])
        elif flag == '--params-file' and given:
            try:
                with open(value) as fh:
                    doc = load_yaml(fh) or {}
            except (OSError, yaml.YAMLError):
                continue  # rcl reports an unreadable file itself
            names = set()
            for section, body in doc.items() if isinstance(doc, dict) else []:
                key = str(section).strip('/')
                if key in ('**', node_name) or key.endswith('/' + node_name):
                    params = (body or {}).get('ros__parameters') if isinstance(body, dict) else None
                    names.update(params or {})
            out.extend((name, value) for name in given if name in names)
    return out
