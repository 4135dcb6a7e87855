"""The agent's link model: where it receives neighbour states (parameters ``link_*``).

The model itself is :class:`knode_swarm_ros.core.link.LinkModel` (the same semantics as the
offline :func:`knode_swarm_ros.core.link.link_rollout`); this module declares its parameters
on the agent node and decides, for every decoded neighbour state, whether it is heard now,
later or never. Times are the node's ROS clock in seconds. The robot's own state never goes
through a link. Off by default (every ``link_*`` at 0). While the ROS clock stands at 0 (the
simulator has not started: it waits until every agent has heard every robot) delays cannot
pass, so what the link lets through is delivered at once.

Real time only: in lockstep a withheld state would stall the step until ``state_timeout``
(wall), which measures the lockstep protocol, not the swarm; the agent refuses the
combination with a message naming the parameter.
"""

from __future__ import annotations

from typing import Any, Dict, List, Optional, Tuple

import numpy as np

from knode_swarm_ros.core.link import LinkConfig, LinkModel
from knode_swarm_ros.logic.common import ConfigError

__all__ = ['AgentLink', 'add_link_arguments', 'link_parameters']

Delivery = Tuple[int, int, np.ndarray]  # (robot, stamp ns, z)


class AgentLink:
    """Declares ``link_loss``, ``link_delay``, ``link_jitter``, ``link_range``, ``link_seed`` on
    ``node`` and filters neighbour states through the model (see the module doc)."""

    def __init__(self, node, robot_id: int, mode: str):
        from knode_swarm_ros.nodes.common.params import (
            declare,  # rclpy: here, so that the launcher's flags come without it
        )

        loss = declare(
            node,
            'link_loss',
            0.0,
            'probability that a neighbour state is lost (link model; 0: off)',
            float_range=(0.0, 0.999999),
        )
        delay = declare(
            node,
            'link_delay',
            0.0,
            'extra seconds before a neighbour state is heard (link model)',
            float_range=(0.0, 3600.0),
        )
        jitter = declare(
            node, 'link_jitter', 0.0, 'plus U[0, link_jitter] seconds (link model)', float_range=(0.0, 3600.0)
        )
        radio = declare(
            node,
            'link_range',
            0.0,
            'radio range: states of robots farther away are not heard '
            '(link model; 0: unlimited; separate from d_cr)',
            float_range=(0.0, 1e9),
        )
        seed = declare(
            node,
            'link_seed',
            0,
            'seed of the link model (add the robot id for distinct draws)',
            int_range=(0, 2**31 - 1),
        )
        self.config = LinkConfig(loss, delay, jitter, radio, seed + int(robot_id))
        self.me = int(robot_id)
        self.model: Optional[LinkModel] = None
        if self.config.enabled:
            if mode != 'realtime':
                raise ConfigError(
                    "parameters 'link_*' (the link model) need mode 'realtime', got mode "
                    f'{mode!r}: a withheld state would stall every lockstep step'
                )
            self.model = LinkModel(self.config)

    @property
    def enabled(self) -> bool:
        return self.model is not None

    def offer(
        self,
        now_s: float,
        robot: int,
        stamp_ns: int,
        z: np.ndarray,
        own: Optional[np.ndarray],
        position_dim: int,
    ) -> str:
        """Put robot ``robot``'s state through its link to this robot (``own``: this robot's newest
        state, for the radio range); returns its fate. Delivered states come out of :meth:`due`."""
        z = np.asarray(z, dtype=np.float64)
        receiver = None if own is None else np.asarray(own)[:position_dim]
        sender = z[:position_dim] if z.shape[0] >= position_dim else None
        return self.model.offer(now_s, (robot, stamp_ns, z), sender, receiver)

    def due(self, now_s: float) -> List[Delivery]:
        """States whose delay has passed by ``now_s``."""
        return [] if self.model is None else self.model.due(now_s)

    def status(self) -> Dict[str, Any]:
        """Counters for the agent status (empty when off)."""
        if self.model is None:
            return {}
        return {**self.model.counters, 'pending': self.model.pending}


# --- the launcher's flags (swarm --link-loss P --link-delay S --link-jitter S --link-range M) ----
def add_link_arguments(parser) -> None:
    """Add the ``--link-*`` flags of the ``swarm`` launcher to an argparse parser."""
    g = parser.add_argument_group('link model (realtime only; every agent, off by default)')
    g.add_argument(
        '--link-loss', type=float, default=0.0, metavar='P', help='probability a neighbour state is lost'
    )
    g.add_argument('--link-delay', type=float, default=0.0, metavar='S', help='extra delay in seconds')
    g.add_argument('--link-jitter', type=float, default=0.0, metavar='S', help='plus U[0, S] seconds')
    g.add_argument('--link-range', type=float, default=0.0, metavar='M', help='radio range (0: unlimited)')
    g.add_argument('--link-seed', type=int, default=0, help='seed (each agent adds its id)')


def link_parameters(args, mode: str) -> Dict[str, Any]:
    """The agents' ``link_*`` parameters from the launcher's flags ({} when the model is off).

    Raises:
        ConfigError: a bad value, or the model with a mode other than realtime (names the flag).
    """
    config = LinkConfig(args.link_loss, args.link_delay, args.link_jitter, args.link_range, args.link_seed)
    try:
        config.validate(prefix='--link-')
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    if not config.enabled:
        return {}
    if mode != 'realtime':
        raise ConfigError(f'--link-* (the link model) needs --mode realtime, got --mode {mode}')
    return {
        'link_loss': float(config.loss),
        'link_delay': float(config.delay),
        'link_jitter': float(config.jitter),
        'link_range': float(config.range),
        'link_seed': int(config.seed),
    }
