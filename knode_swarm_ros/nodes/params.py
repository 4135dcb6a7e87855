"""Parameter declaration with descriptors, turning rclpy's exceptions into :class:`ConfigError`.

Every parameter is declared read-only with a description and, for numbers, a range, so that
``ros2 param describe`` documents it; a value of the wrong type or out of range stops the
node at start with a message that names the parameter.
"""
from __future__ import annotations

from typing import Any, Iterable, List, Optional, Sequence, Tuple

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.exceptions import (InvalidParameterTypeException, InvalidParameterValueException,
                              ParameterUninitializedException)
from rclpy.parameter import Parameter

from .common import ConfigError

__all__ = ['declare', 'declare_int_array', 'node_name_from_args']

_TYPE_WORDS = {bool: 'a boolean (true/false)', int: 'an integer', float: 'a floating-point number',
               str: 'a string'}


def declare(node, name: str, default: Any, description: str, *,
            int_range: Optional[Tuple[int, int]] = None,
            float_range: Optional[Tuple[float, float]] = None,
            choices: Optional[Sequence[str]] = None) -> Any:
    """Declare ``name`` (read-only) with ``default`` and return its value.

    Raises:
        ConfigError: wrong type, out of ``int_range``/``float_range`` (inclusive), or not one
            of ``choices``; the message names the parameter and the value.
    """
    descriptor = ParameterDescriptor(description=description, read_only=True)
    if int_range is not None:
        descriptor.integer_range = [IntegerRange(from_value=int(int_range[0]),
                                                 to_value=int(int_range[1]), step=0)]
    if float_range is not None:
        descriptor.floating_point_range = [FloatingPointRange(
            from_value=float(float_range[0]), to_value=float(float_range[1]), step=0.0)]
    if choices is not None:
        descriptor.additional_constraints = 'one of: ' + ', '.join(choices)
    try:
        value = node.declare_parameter(name, default, descriptor).value
    except InvalidParameterTypeException:
        word = _TYPE_WORDS.get(type(default), type(default).__name__)
        got = _override(node, name)
        hint = f' (write {got}.0)' if isinstance(default, float) and isinstance(got, int) \
            and not isinstance(got, bool) else ''
        raise ConfigError(f'parameter {name!r} must be {word}{hint}, got {got!r}') from None
    except InvalidParameterValueException:
        if int_range is not None:
            limits = f'{int_range[0]} .. {int_range[1]}'
        elif float_range is not None:
            limits = f'{float_range[0]:g} .. {float_range[1]:g}'
        else:
            limits = 'its constraints'
        got = _override(node, name)
        raise ConfigError(f'parameter {name!r} = {got!r} is out of range ({limits}): '
                          f'{description}') from None
    if choices is not None and value not in choices:
        raise ConfigError(f"parameter {name!r} = {value!r} is not one of {', '.join(choices)}")
    return value


def declare_int_array(node, name: str, description: str) -> List[int]:
    """Declare an integer array without default; returns [] when no value was given."""
    descriptor = ParameterDescriptor(description=description, read_only=True)
    try:
        node.declare_parameter(name, Parameter.Type.INTEGER_ARRAY, descriptor)
        value = node.get_parameter(name).value
    except ParameterUninitializedException:
        return []
    except (InvalidParameterTypeException, InvalidParameterValueException):
        raise ConfigError(f'parameter {name!r} must be a list of integers, got '
                          f'{_override(node, name)!r}') from None
    return [int(v) for v in (value or [])]


def _override(node, name: str) -> Any:
    try:
        return node._parameter_overrides[name].value  # noqa: SLF001 (only for the message)
    except (AttributeError, KeyError):
        return '?'


def node_name_from_args(args: Optional[Iterable[str]], base: str, key: str = 'id') -> str:
    """``<base>_<id>`` when the command line sets ``-p id:=N`` (so that many agents get
    distinct node names), else ``base``; ``-r __node:=...`` still overrides either."""
    items = list(args or [])
    for flag, value in zip(items, items[1:]):
        if flag in ('-p', '--param') and value.startswith(key + ':='):
            tail = value[len(key) + 2:].strip()
            if tail.isdigit():
                return f'{base}_{int(tail)}'
    return base
