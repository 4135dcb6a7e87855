"""What the simulator asks of a robot model: the one interface every entry of ``ROBOT_MODELS`` implements.

A robot model owns the simulated robots' physical state (built from the scenario's initial
states ``z0 [n, d]``) and answers, with no ROS:

* :meth:`RobotModel.step`: advance every robot by ``dt`` under its command ``[n, m]`` held
  constant (zero-order hold); :meth:`RobotModel.states`: the scenario's states ``[n, d]`` of the
  robots (what the recorder and the agents read back);
* :meth:`RobotModel.stop_commands`: the command ``[n, m]`` that stops each robot now (a lost or
  silent robot's, docs/DESIGN.md);
* :meth:`RobotModel.odom_fields`: what robot ``r``'s ``nav_msgs/Odometry`` carries (REP 105);
* :attr:`RobotModel.wire`: which command message it takes, and which entries of it;
* its requirements (:attr:`RobotModel.scenarios`, :attr:`RobotModel.ground_truth`), its float
  parameters (:attr:`RobotModel.parameters`, declared by the simulator and offered by the
  launcher) and the agent ``command_interface`` that drives it.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import ClassVar, Dict, Optional, Tuple

import numpy as np

from knode_swarm_ros.logic.common import ConfigError, command_topic

__all__ = ['CommandWire', 'OdomFields', 'RobotModel']

#: (position [3], orientation (x, y, z, w) [4], twist.linear [3], twist.angular [3]); twist in the body frame.
OdomFields = Tuple[Tuple[float, ...], Tuple[float, ...], Tuple[float, ...], Tuple[float, ...]]


@dataclass(frozen=True)
class CommandWire:
    """How a robot takes its command on ROS, said without ROS.

    ``kind`` (``acceleration`` or ``velocity``) names the topic and message of
    :func:`knode_swarm_ros.logic.common.command_topic` (``robot_<i>/cmd_accel`` AccelStamped,
    ``robot_<i>/cmd_vel`` TwistStamped; both a header, then linear ``[3]`` and angular ``[3]``).
    The command ``u [m]`` is the entries ``fields`` of (linear.x, .y, .z, angular.x, .y, .z).
    """

    kind: str
    fields: Tuple[int, ...]

    def topic(self, robot: int) -> str:
        return command_topic(robot, self.kind)


class RobotModel(ABC):
    """``n`` simulated robots of one kind (see the module doc).

    Subclasses set the class attributes and take ``(spec, z0, **parameters)``; the registry's
    :func:`~knode_swarm_ros.logic.simulator.robot_models.make_robot_model` checks the
    requirements before building one.
    """

    #: One line for the ``robot_model`` parameter's help.
    summary: ClassVar[str] = ''
    #: Scenarios it can simulate (empty: every one).
    scenarios: ClassVar[Tuple[str, ...]] = ()
    #: Whether the ground truth may drive it (its laws command the scenario's own point robots).
    ground_truth: ClassVar[bool] = False
    #: Why not, when it may not (said after "cannot be driven by the ground truth").
    ground_truth_refusal: ClassVar[str] = ''
    #: Float parameters (name -> description; finite, >= 0, 0: none); declared by the simulator,
    #: offered as flags by the launcher.
    parameters: ClassVar[Dict[str, str]] = {}
    #: The agent's ``command_interface`` that drives it ('': the policy's own command).
    command_interface: ClassVar[str] = ''

    wire: CommandWire

    @classmethod
    def refusal(cls, scenario: str, ground_truth: bool) -> Optional[str]:
        """Why it cannot run ``scenario`` (with the ground truth driving it or not), or None."""
        if cls.scenarios and scenario not in cls.scenarios:
            return f'needs scenario {" or ".join(cls.scenarios)}, not {scenario}'
        if ground_truth and not cls.ground_truth:
            return f'cannot be driven by the ground truth {cls.ground_truth_refusal}'.rstrip()
        return None

    @property
    def command_dim(self) -> int:
        """m, the entries of one robot's command."""
        return len(self.wire.fields)

    @abstractmethod
    def states(self) -> np.ndarray:
        """``[n, d]`` the robots' states in the scenario's layout."""

    @abstractmethod
    def step(self, command: np.ndarray, dt: float) -> None:
        """Apply ``command [n, m]`` for ``dt`` seconds (zero-order hold)."""

    @abstractmethod
    def stop_commands(self, stop_limit: Optional[float], dt: float) -> np.ndarray:
        """``[n, m]``: the command that stops each robot from its current state; ``stop_limit``:
        the per-axis limit of a braking deceleration (None: rest in one step)."""

    @abstractmethod
    def odom_fields(self, robot: int) -> OdomFields:
        """What robot ``robot``'s Odometry carries now (REP 105, twist in its body frame)."""

    def place(self, states: np.ndarray) -> None:
        """The ground truth moved the robots to ``states [n, d]`` (models with ``ground_truth``)."""
        raise ConfigError(f'{type(self).__name__} cannot be driven by the ground truth')
