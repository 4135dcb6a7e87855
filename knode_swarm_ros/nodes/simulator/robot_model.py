"""The simulator's ``robot_model`` parameter and the models' own parameters, on the node.

The models themselves (what each integrates, stops, publishes and takes) are ROS-free:
:mod:`knode_swarm_ros.logic.simulator.robot_models`.
"""

from __future__ import annotations

from typing import Dict, Tuple

from knode_swarm_ros.logic.simulator.robot_models import (
    DEFAULT_ROBOT_MODEL,
    ROBOT_MODELS,
    model_parameters,
)
from knode_swarm_ros.nodes.common.params import declare

__all__ = ['declare_robot_model']


def declare_robot_model(node) -> Tuple[str, Dict[str, float]]:
    """Declare ``robot_model`` and every model's parameters on ``node``; returns (model name,
    parameters) for :class:`~knode_swarm_ros.logic.simulator.swarm_sim.SwarmSim`."""
    model = declare(
        node,
        'robot_model',
        DEFAULT_ROBOT_MODEL,
        '; '.join(f'{name}: {cls.summary}' for name, cls in ROBOT_MODELS.items()),
        choices=tuple(ROBOT_MODELS),
    )
    params = {
        name: declare(node, name, 0.0, f'{text} (0: none)', float_range=(0.0, 1e6))
        for name, text in model_parameters().items()
    }
    return model, params
