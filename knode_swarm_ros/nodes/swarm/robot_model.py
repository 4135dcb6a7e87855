"""``swarm --robot-model unicycle``: differential-drive robots end to end (docs/ros.md).

Sets the simulator's ``robot_model`` and the bases' limits, and every agent's
``command_interface: unicycle`` with the same limits (``unicycle_stamped: true``, so lockstep
works). The limits go to both sides: the base enforces them as a real one does, the agent's
mapping respects them and counts the periods in which they bound.
"""

from __future__ import annotations

import math
from typing import Any, Dict

from knode_swarm_ros.logic.common import ConfigError
from knode_swarm_ros.nodes.agent.unicycle import UNICYCLE_STATES
from knode_swarm_ros.nodes.simulator.robot_model import LIMIT_PARAMETERS, ROBOT_MODELS

__all__ = ['add_arguments', 'robot_model_parameters']


def add_arguments(parser) -> None:
    """The ``--robot-model`` flags of the launcher."""
    g = parser.add_argument_group('robot model (flock2d)')
    g.add_argument(
        '--robot-model',
        choices=ROBOT_MODELS,
        default='double_integrator',
        help='unicycle: the simulated robots are differential-drive bases taking cmd_vel (linear.x, '
        'angular.z) and every agent commands them so (command_interface unicycle); default '
        'double_integrator',
    )
    for name, text in LIMIT_PARAMETERS.items():
        g.add_argument(
            '--' + name.replace('_', '-'),
            type=float,
            default=0.0,
            metavar='X',
            help=f'unicycle: {text} (0: none)',
        )
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
        ConfigError: a bad limit, a unicycle with boids3d, ground truth or agents hosted several to
            a process (their host has no unicycle output); names the flag.
    """
    if args.robot_model == 'double_integrator':
        return {}
    limits = {name: float(getattr(args, name)) for name in LIMIT_PARAMETERS}
    for name, value in limits.items():
        if not (math.isfinite(value) and value >= 0):
            raise ConfigError(f'--{name.replace("_", "-")} must be finite and >= 0 (0: none), got {value}')
    if not (math.isfinite(args.unicycle_lookahead) and args.unicycle_lookahead > 0):
        raise ConfigError(f'--unicycle-lookahead must be > 0, got {args.unicycle_lookahead}')
    if scenario != 'flock2d':
        raise ConfigError(f'--robot-model unicycle needs a flock2d policy, not {scenario}')
    if args.ground_truth:
        raise ConfigError(
            '--robot-model unicycle cannot be combined with --ground-truth (the Tanner law commands '
            'point masses)'
        )
    if agents_per_process > 1:
        raise ConfigError(
            '--robot-model unicycle needs one agent process per robot: agents hosted several to a '
            f'process (--agents-per-process {agents_per_process}, or more than 10 robots) have no '
            'unicycle output; pass --agents-per-process 1'
        )
    return {
        'simulator': {'robot_model': 'unicycle', **limits},
        'agent': {
            'command_interface': 'unicycle',
            'unicycle_stamped': True,
            'unicycle_lookahead': float(args.unicycle_lookahead),
            'unicycle_state': args.unicycle_state,
            **limits,
        },
    }
