"""``swarm --robot-model NAME``: the simulator's robot model and the agents that drive it (docs/ros.md).

Sets the simulator's ``robot_model`` and the model's parameters, and, for a model driven by an
agent ``command_interface`` of its own (``unicycle``: differential-drive robots), every agent's
``command_interface`` with the same parameters (``unicycle_stamped: true``, so lockstep works).
The limits go to both sides: the base enforces them as a real one does, the agent's mapping
respects them and counts the periods in which they bound. What each model needs is the
registry's rule (:func:`knode_swarm_ros.logic.simulator.robot_models.check_robot_model`).
"""

from __future__ import annotations

import math
from typing import Any, Dict

from knode_swarm_ros.logic.common import ConfigError
from knode_swarm_ros.logic.simulator.robot_models import (
    DEFAULT_ROBOT_MODEL,
    ROBOT_MODELS,
    check_robot_model,
    model_parameters,
)
from knode_swarm_ros.nodes.agent.unicycle import UNICYCLE_STATES

__all__ = ['add_arguments', 'robot_model_parameters']


def _flag(name: str) -> str:
    return '--' + name.replace('_', '-')


def add_arguments(parser) -> None:
    """The ``--robot-model`` flags of the launcher."""
    g = parser.add_argument_group('robot model')
    g.add_argument(
        '--robot-model',
        choices=tuple(ROBOT_MODELS),
        default=DEFAULT_ROBOT_MODEL,
        help='; '.join(f'{name}: {cls.summary}' for name, cls in ROBOT_MODELS.items())
        + f'; a model with an agent command interface of its own (unicycle) has every agent command '
        f'it so; default {DEFAULT_ROBOT_MODEL}',
    )
    for name, text in model_parameters().items():
        g.add_argument(_flag(name), type=float, default=0.0, metavar='X', help=f'{text} (0: none)')
    g.add_argument(
        '--unicycle-lookahead',
        type=float,
        default=0.2,
        metavar='M',
        help='unicycle: distance of the controlled point ahead of the axle; default 0.2',
    )
    g.add_argument(
        '--unicycle-state',
        choices=UNICYCLE_STATES,
        default='point',
        help='unicycle: what the policy sees of every robot; default point',
    )


def robot_model_parameters(args, scenario: str, agents_per_process: int) -> Dict[str, Dict[str, Any]]:
    """``{'simulator': {...}, 'agent': {...}}`` parameters for ``--robot-model`` ({} for the default).

    Raises:
        ConfigError: a bad parameter, a model that cannot run ``scenario`` or the ground truth, or
            agents hosted several to a process for a model with its own agent command interface
            (their host has none); names the flag.
    """
    name = args.robot_model
    if name == DEFAULT_ROBOT_MODEL:
        return {}
    cls = check_robot_model(name, scenario, bool(args.ground_truth), label=f'--robot-model {name}')
    params = {p: float(getattr(args, p)) for p in cls.parameters}
    for p, value in params.items():
        if not (math.isfinite(value) and value >= 0):
            raise ConfigError(f'{_flag(p)} must be finite and >= 0 (0: none), got {value}')
    interface = cls.command_interface
    if not interface:  # driven by the policy's own command: nothing to set on the agents
        return {'simulator': {'robot_model': name, **params}}
    if agents_per_process > 1:
        raise ConfigError(
            f'--robot-model {name} needs one agent process per robot: agents hosted several to a '
            f'process (--agents-per-process {agents_per_process}, or more than 10 robots) have no '
            f'{interface} output; pass --agents-per-process 1'
        )
    agent: Dict[str, Any] = {'command_interface': interface}
    if interface == 'unicycle':
        if not (math.isfinite(args.unicycle_lookahead) and args.unicycle_lookahead > 0):
            raise ConfigError(f'--unicycle-lookahead must be > 0, got {args.unicycle_lookahead}')
        agent.update(
            unicycle_stamped=True,
            unicycle_lookahead=float(args.unicycle_lookahead),
            unicycle_state=args.unicycle_state,
        )
    return {'simulator': {'robot_model': name, **params}, 'agent': {**agent, **params}}
