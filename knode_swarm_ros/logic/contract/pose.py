"""States of robots heard as poses (geometry_msgs/PoseStamped, motion capture): the one mapping.

A pose carries a position ``[3]`` and an orientation ``(x, y, z, w)``, no velocity. The state
``z [d]`` takes the position (and the heading, when the state has one) as REP 105 does for an
Odometry (:func:`.rep105.fields_to_state`), and a velocity, when the state has one, estimated
from that robot's own pose stream by the core's causal estimator
(:class:`knode_swarm_ros.core.estimator.VelocityEstimator`, one per robot): the estimate the
offline rollout's :class:`knode_swarm_ros.core.rollout.PoseObserver` makes, bit for bit, when the
same poses arrive with the same stamps.

Used by the agents (their own and their neighbours' poses) and the recorder.

A stream faster than the policy (motion capture at 100 Hz under a 20 Hz policy): the agents
take :meth:`PoseStates.filed`, which feeds every pose to the estimator but maps (and fits) only
the poses that stand for a step, the newest at or before the step's time
(:class:`knode_swarm_ros.core.estimator.StepSampler`); :meth:`PoseStates.state` maps every pose.

A robot's own state (``own``: the robots an agent process controls) also gets its velocity from
its poses and its own commands (:class:`knode_swarm_ros.core.estimator.CommandAidedEstimator`,
fed by :meth:`PoseStates.command`, ``OWN_WINDOW_FACTOR`` times the window) when the scenario
commands accelerations: that is the own row of its Y; its neighbours (and the recorder) hear
the plain estimate. The offline rollout's ``PoseObserver`` does the same.
"""

from __future__ import annotations

from typing import Dict, List, Optional, Sequence, Tuple, Union

import numpy as np

from knode_swarm_ros.core.estimator import (
    DEFAULT_WINDOW,
    OWN_WINDOW_FACTOR,
    CommandAidedEstimator,
    StepSampler,
    VelocityEstimator,
)
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

    def __init__(
        self,
        scenario: Union[str, Scenario],
        window: int = DEFAULT_WINDOW,
        dt: Optional[float] = None,
        own: Sequence[int] = (),
    ):
        self.spec = scenario if isinstance(scenario, Scenario) else get_scenario(scenario)
        self.window = int(window)
        self.dt = dt
        self.estimators: Dict[int, VelocityEstimator] = {}
        self._samplers: Dict[int, StepSampler] = {}
        self._previous: Dict[int, tuple] = {}  # robot -> its previous pose (stamp, position, quaternion)
        self._last_filed: Dict[int, tuple] = {}  # robot -> (step, stamp, z, own z)
        aided = self.estimates and self.spec.command == 'acceleration'
        self.own: Dict[int, CommandAidedEstimator] = (
            {int(r): CommandAidedEstimator(OWN_WINDOW_FACTOR * self.window) for r in own} if aided else {}
        )

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

    def filed(
        self, robot: int, stamp_ns: int, position: Sequence[float], quaternion: Sequence[float]
    ) -> List[Tuple[Optional[int], int, np.ndarray, Optional[np.ndarray]]]:
        """The states to file on hearing robot ``robot``'s pose: ``[(step, stamp_ns, z [d], own)]``,
        at most two (the previous pose, once this one is past its step; this pose, when it is
        stamped on a step), usually none. ``own``: for an ``own`` robot, its state with the
        command-aided velocity (the own row of its Y), else None. Every pose feeds the velocity
        fits; a pose is mapped and fitted only when filed (needs ``dt``).

        A repeated stamp gives the state filed for it again (a retransmission, counted a
        duplicate by the caller); an older one nothing. A non-finite position gives
        ``[(None, stamp_ns, z, None)]`` (the caller drops it as ``non_finite``) and is forgotten.
        """
        robot, stamp_ns = int(robot), int(stamp_ns)
        if not all(np.isfinite(position[: self.spec.position_dim])):
            return [(None, stamp_ns, self.state(robot, stamp_ns, position, quaternion), None)]
        sampler = self._samplers.get(robot)
        if sampler is None:
            sampler = self._samplers[robot] = StepSampler(self.dt)
        last = self._last_filed.get(robot)
        if last is not None and last[1] == stamp_ns:
            return [last]
        previous_step, this_step = sampler.push(stamp_ns)
        out = []
        if previous_step is not None:  # the previous pose is the newest at or before that step
            stamp, p, q = self._previous[robot]
            out.append((previous_step, stamp, *self._map(robot, p, q)))
        self._previous[robot] = (stamp_ns, position, quaternion)
        if self.estimates:
            estimator = self.estimators.get(robot)
            if estimator is None:
                estimator = self.estimators[robot] = VelocityEstimator(self.window)
            estimator.push(stamp_ns, position[: self.spec.position_dim])
            if robot in self.own:
                self.own[robot].push(stamp_ns, position[: self.spec.position_dim])
        if this_step is not None:
            out.append((this_step, stamp_ns, *self._map(robot, position, quaternion)))
        if out:
            self._last_filed[robot] = out[-1]
        return out

    def command(self, robot: int, stamp_ns: int, u) -> None:
        """Own robot ``robot`` commanded the acceleration ``u [m]`` from ``stamp_ns`` on."""
        aided = self.own.get(int(robot))
        if aided is not None:
            aided.command(stamp_ns, u)

    def _map(self, robot: int, position, quaternion) -> Tuple[np.ndarray, Optional[np.ndarray]]:
        """The state of a pose with the estimates at the newest sample fed (the filed pose's),
        and an own robot's state with its command-aided velocity (else None)."""
        z = fields_to_state(position, quaternion, _NO_TWIST, self.spec, 'world')
        if not self.estimates:
            return z, None
        z[self.spec.velocity] = self.estimators[robot].velocity
        aided = self.own.get(robot)
        if aided is None:
            return z, None
        own = z.copy()
        own[self.spec.velocity] = aided.velocity
        return z, own

    def velocity(self, robot: int) -> Optional[np.ndarray]:
        """Robot ``robot``'s newest velocity estimate ``[m]`` (None before its first pose)."""
        estimator = self.estimators.get(int(robot))
        return None if estimator is None else estimator.velocity
