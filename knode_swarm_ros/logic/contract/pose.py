"""States of robots heard as poses (geometry_msgs/PoseStamped, motion capture): the one mapping.

A pose carries a position ``[3]`` and an orientation ``(x, y, z, w)``, no velocity. The state
``z [d]`` takes the position (and the heading, when the state has one) as REP 105 does for an
Odometry (:func:`.rep105.fields_to_state`), and a velocity, when the state has one, estimated
from that robot's own pose stream by the core's causal estimator
(:class:`knode_swarm_ros.core.estimator.VelocityEstimator`, one per robot): the estimate the
offline rollout's :class:`knode_swarm_ros.core.rollout.PoseObserver` makes, bit for bit, when the
same poses arrive with the same stamps.

Used by the agents (their own and their neighbours' poses) and the recorder.
"""

from __future__ import annotations

from typing import Dict, Optional, Sequence, Union

import numpy as np

from knode_swarm_ros.core.estimator import DEFAULT_WINDOW, VelocityEstimator
from knode_swarm_ros.core.scenarios import Scenario, get_scenario

from .rep105 import fields_to_state

__all__ = ['PoseStates']

_NO_TWIST = (0.0, 0.0, 0.0)


class PoseStates:
    """Per-robot states from poses: ``state(robot, stamp_ns, position [3], quaternion [4]) -> z [d]``.

    Args:
        scenario: the scenario (a name, a file's reference or a :class:`Scenario`).
        window: samples of each robot's velocity fit (the fleet's ``state.velocity_window``).

    A pose with a non-finite position is mapped (the caller drops it as ``non_finite``) but not
    fed to the estimator, so one bad sample does not spoil the next ``window`` estimates.
    """

    def __init__(self, scenario: Union[str, Scenario], window: int = DEFAULT_WINDOW):
        self.spec = scenario if isinstance(scenario, Scenario) else get_scenario(scenario)
        self.window = int(window)
        self.estimators: Dict[int, VelocityEstimator] = {}

    @property
    def estimates(self) -> bool:
        """Whether the state holds a velocity, estimated here."""
        return self.spec.velocity is not None

    def state(
        self, robot: int, stamp_ns: int, position: Sequence[float], quaternion: Sequence[float]
    ) -> np.ndarray:
        """Robot ``robot``'s state ``z [d]`` (float64) of a pose stamped ``stamp_ns``."""
        z = fields_to_state(position, quaternion, _NO_TWIST, self.spec, 'world')
        if not self.estimates:
            return z
        p = z[self.spec.position]
        if not np.all(np.isfinite(p)):
            return z
        estimator = self.estimators.get(int(robot))
        if estimator is None:
            estimator = self.estimators[int(robot)] = VelocityEstimator(self.window)
        z[self.spec.velocity] = estimator.update(stamp_ns, p)
        return z

    def velocity(self, robot: int) -> Optional[np.ndarray]:
        """Robot ``robot``'s newest velocity estimate ``[m]`` (None before its first pose)."""
        estimator = self.estimators.get(int(robot))
        return None if estimator is None else estimator.velocity
