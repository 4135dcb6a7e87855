"""The simulator's robot models (parameter ``robot_model``), by name.

:data:`ROBOT_MODELS` maps each name to a :class:`~.base.RobotModel` class; :func:`check_robot_model`
is the one place that checks a name and the model's requirements (the simulator through
:func:`make_robot_model`, the launcher's ``--robot-model`` directly).

Adding a robot model: one file here with a :class:`~.base.RobotModel` subclass, and its line in
:data:`ROBOT_MODELS`. The simulator node and the launcher take its name, parameters, command
message and Odometry from the class.
"""

from __future__ import annotations

from typing import Dict, Mapping, Optional, Type

import numpy as np

from knode_swarm_ros.core.scenarios import Scenario
from knode_swarm_ros.logic.common import ConfigError

from .base import CommandWire, OdomFields, RobotModel
from .point import PointRobots
from .unicycle import UnicycleBases

__all__ = [
    'ROBOT_MODELS',
    'DEFAULT_ROBOT_MODEL',
    'RobotModel',
    'CommandWire',
    'OdomFields',
    'check_robot_model',
    'make_robot_model',
    'model_parameters',
]

ROBOT_MODELS: Dict[str, Type[RobotModel]] = {
    'double_integrator': PointRobots,
    'unicycle': UnicycleBases,
}

#: The scenario's own point robots (double integrators for flock2d, first order for boids3d).
DEFAULT_ROBOT_MODEL = 'double_integrator'


def check_robot_model(
    name: str, scenario: str, ground_truth: bool, label: Optional[str] = None
) -> Type[RobotModel]:
    """The class of robot model ``name`` if it can run ``scenario`` (driven by the ground truth
    or not).

    Raises:
        ConfigError: unknown name, or a requirement not met; the message starts with ``label``
            (default ``parameter 'robot_model' = 'NAME'``).
    """
    label = label or f"parameter 'robot_model' = {name!r}"
    cls = ROBOT_MODELS.get(name)
    if cls is None:
        raise ConfigError(f'{label} is not one of {", ".join(ROBOT_MODELS)}')
    reason = cls.refusal(scenario, ground_truth)
    if reason:
        raise ConfigError(f'{label} {reason}')
    return cls


def model_parameters() -> Dict[str, str]:
    """Every model's float parameters, name -> ``'MODEL: description'`` (the simulator declares
    them all; a model reads its own)."""
    out: Dict[str, str] = {}
    for name, cls in ROBOT_MODELS.items():
        for param, text in cls.parameters.items():
            out.setdefault(param, f'{name}: {text}')
    return out


def make_robot_model(
    name: str,
    spec: Scenario,
    z0: np.ndarray,
    ground_truth: bool = False,
    parameters: Optional[Mapping[str, float]] = None,
) -> RobotModel:
    """Robot model ``name`` for the robots at ``z0 [n, d]``, given its own ``parameters``
    (others are ignored).

    Raises:
        ConfigError: see :func:`check_robot_model`; a bad parameter.
    """
    cls = check_robot_model(name, spec.name, ground_truth)
    own = {k: float(v) for k, v in (parameters or {}).items() if k in cls.parameters}
    return cls(spec, z0, **own)
