"""An acceleration policy's command as a velocity setpoint (a fleet's ``interface: velocity_setpoint``).

A robot whose controller takes velocities (a Crazyflie's ``cmd_velocity_world``) gets, for the
policy's acceleration ``u [m]``, the velocity the double integrator would reach after one
control period T from its estimated velocity: ``v_sp = v_est + u T``, clipped per axis at the
fleet's ``speed_limit`` (:func:`knode_swarm_ros.core.saturation.velocity_setpoint`; docs/ros.md,
"Velocity setpoints", says what it assumes of the robot's velocity loop). A stop command (stale
own state) becomes a zero setpoint: a velocity loop brakes by itself.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from knode_swarm_ros.core.saturation import velocity_setpoint

__all__ = ['SetpointOutput']


class SetpointOutput:
    """Velocity setpoints ``[m]`` of commands held ``period`` seconds, clipped at ``speed_limit``
    (None: no clip)."""

    def __init__(self, period: float, speed_limit: Optional[float] = None):
        if not period > 0:
            raise ValueError(f'the control period must be > 0, got {period}')
        self.period = float(period)
        self.speed_limit = speed_limit

    def value(self, command, velocity) -> np.ndarray:
        """The setpoint of ``command`` (an :class:`.agent_logic.Command`) for a robot whose
        estimated velocity is ``velocity [m]``."""
        if command.stop:
            return np.zeros_like(np.asarray(command.value, dtype=np.float64))
        return velocity_setpoint(velocity, command.value, self.period, self.speed_limit)
