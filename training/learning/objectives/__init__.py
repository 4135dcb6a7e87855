"""Training objectives by name, the values of the config field ``training.objective``.

Adding an objective: a module here with an :class:`~.base.Objective` subclass, and its line in
:data:`OBJECTIVES` (the config accepts every name listed; its own settings, if any, go into
``DEFAULT_CONFIG`` of :mod:`training.learning.config`).
"""

from __future__ import annotations

from typing import Any, Dict, Type

from knode_swarm_ros.core.errors import ConfigError
from knode_swarm_ros.core.scenarios import Scenario

from .base import Objective, TrainingData
from .multi_step import MultiStepObjective
from .one_step import OneStepObjective

OBJECTIVES: Dict[str, Type[Objective]] = {
    'one_step': OneStepObjective,
    'multi_step': MultiStepObjective,
}

__all__ = ['OBJECTIVES', 'Objective', 'TrainingData', 'make_objective']


def make_objective(cfg: Dict[str, Any], spec: Scenario, dt: float, data: TrainingData) -> Objective:
    """The objective named by ``training.objective``, over ``data`` at the policy's ``dt``."""
    name = cfg['training']['objective']
    if name not in OBJECTIVES:
        raise ConfigError(
            f"config field 'training.objective' = {name!r}: must be one of {', '.join(OBJECTIVES)}"
        )
    return OBJECTIVES[name].from_data(cfg, spec, dt, data)
