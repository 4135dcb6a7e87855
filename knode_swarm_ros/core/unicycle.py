"""Differential-drive (unicycle) robots: the policy's planar command -> (v, omega), no ROS.

A ground robot takes ``cmd_vel`` = forward speed v and turn rate omega, not a planar
acceleration. :class:`UnicycleMapper` turns the policy's command into (v, omega) by
**feedback linearisation about a point ahead of the axle**: the point P at distance ``l``
along the heading theta moves with

    dP/dt = R(theta) [v, l omega]^T ,   so   [v, omega] = diag(1, 1/l) R(theta)^T u_P

gives P exactly the planar velocity u_P asked for. Why this method and not "turn towards the
desired velocity, then drive": the map is exact and linear, defined at every heading and at
zero speed (a heading controller has no reference heading when the desired velocity is 0, and
is discontinuous when it reverses), it needs no gain tuning, and the policy's world-frame
velocity or acceleration maps onto it directly. The price: P, not the axle centre, follows the
command; the heading itself is not controlled but follows the direction of motion (while P
moves with speed s, theta relaxes towards it at rate s / l); reversing takes a turn of radius
about l. ``l`` trades these: small l turns sharply (omega ~ s / l), large l cuts corners.

Commands: for an ``acceleration`` policy (flock2d) the desired velocity of P is its velocity
now plus the commanded acceleration held over one control period T (the zero-order hold of the
rollout semantics); for a planar ``velocity`` policy it is the command itself.

The body turns by omega T while a command is held, and P's velocity turns with it; mapping at
the heading predicted for the middle of the period, theta + omega_now T / 2 (omega_now: the turn
rate now), cancels that rotation to first order. Without it P's velocity drifts by omega T each period:
offline (4 starts, 15 s, flock2d_20hz) the swarm kept half its speed (1.13 against 2.30 m/s for
the double integrators, |omega| 0.95 rad/s), and with the axle states as well it spun on the
spot (0.07 m/s, |omega| 4.9 rad/s); with both details 2.25 m/s (docs/ros.md).

Limits, applied in this order each period (:func:`limit_twist`, the one clamp, which the robot
model :class:`UnicycleRobots` applies too, as a real base does): |v| <= ``max_linear_speed``,
|omega| <= ``max_angular_speed`` (saturation keeps the sign), then the change from the
previous command |dv| <= ``max_linear_accel`` T and |domega| <= ``max_angular_accel`` T (a
limit of 0 means none). When a limit binds, P no longer follows the policy exactly; the
agent counts those periods.

:func:`point_state` is the state the policy sees of a unicycle in the agent's default
``unicycle_state: point``: position and velocity of its point ahead. With every robot seen
that way and no limit binding, the closed loop is the policy's double-integrator swarm
(to first order in omega T), which is why it is the default (docs/ros.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Tuple

import numpy as np

__all__ = [
    'UnicycleLimits',
    'UnicycleMapper',
    'UnicycleRobots',
    'unicycle_step',
    'point_ahead',
    'point_state',
    'limit_twist',
]


@dataclass(frozen=True)
class UnicycleLimits:
    """Actuator limits (0: none) and the look-ahead distance ``lookahead`` (> 0)."""

    lookahead: float = 0.2
    max_linear_speed: float = 0.0
    max_angular_speed: float = 0.0
    max_linear_accel: float = 0.0
    max_angular_accel: float = 0.0

    def validate(self) -> None:
        """Raise ValueError naming the first bad value."""
        if not (math.isfinite(self.lookahead) and self.lookahead > 0):
            raise ValueError(f'unicycle_lookahead must be > 0, got {self.lookahead}')
        for name in ('max_linear_speed', 'max_angular_speed', 'max_linear_accel', 'max_angular_accel'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f'{name} must be finite and >= 0 (0: no limit), got {value}')


def point_ahead(
    x: float, y: float, theta: float, v: float, omega: float, lookahead: float
) -> Tuple[np.ndarray, np.ndarray]:
    """Position ``[2]`` and velocity ``[2]`` of the point ``lookahead`` ahead of the axle."""
    c, s = math.cos(theta), math.sin(theta)
    pos = np.array([x + lookahead * c, y + lookahead * s])
    vel = np.array([c * v - s * lookahead * omega, s * v + c * lookahead * omega])
    return pos, vel


def point_state(pose, v, omega, lookahead: float) -> np.ndarray:
    """State ``[..., 4]`` = (position, velocity) of the point ``lookahead`` ahead of the axle of
    unicycles at ``pose [..., 3]`` = (x, y, theta) moving with ``v [...]``, ``omega [...]``."""
    pose = np.asarray(pose, dtype=np.float64)
    v, omega = np.asarray(v, dtype=np.float64), np.asarray(omega, dtype=np.float64)
    c, s = np.cos(pose[..., 2]), np.sin(pose[..., 2])
    return np.stack(
        [
            pose[..., 0] + lookahead * c,
            pose[..., 1] + lookahead * s,
            c * v - s * lookahead * omega,
            s * v + c * lookahead * omega,
        ],
        axis=-1,
    )


def _clip(value, limit: float):
    """``value`` (a float or an array) saturated at +-``limit``; unchanged for a limit of 0."""
    if not limit > 0:
        return value
    return max(-limit, min(limit, value)) if isinstance(value, float) else np.clip(value, -limit, limit)


def limit_twist(v, omega, last_v, last_omega, limits: UnicycleLimits, period: float):
    """(v, omega) within the speed limits, then within ``max_*_accel * period`` of
    (``last_v``, ``last_omega``): floats or arrays ``[n]`` alike. The one clamp of the project:
    the agent's mapping and the simulated base both call it."""
    return (
        _ramp(_clip(v, limits.max_linear_speed), last_v, limits.max_linear_accel * period),
        _ramp(_clip(omega, limits.max_angular_speed), last_omega, limits.max_angular_accel * period),
    )


def _ramp(value, last, step: float):
    """``value`` moved to within ``step`` of ``last`` (unchanged, bit for bit, when it is; 0: no limit)."""
    if not step > 0:
        return value
    if isinstance(value, float):
        return last + math.copysign(step, value - last) if abs(value - last) > step else value
    value, last = np.asarray(value, dtype=np.float64), np.asarray(last, dtype=np.float64)
    return np.where(np.abs(value - last) > step, last + np.copysign(step, value - last), value)


class UnicycleMapper:
    """(v, omega) from the policy's planar command for one robot (see the module doc).

    Keeps the previous command for the acceleration limits; ``bound`` counts periods in which a
    limit changed the command.
    """

    def __init__(self, limits: UnicycleLimits, command: str, period: float):
        limits.validate()
        if command not in ('acceleration', 'velocity'):
            raise ValueError(f"command must be 'acceleration' or 'velocity', got {command!r}")
        if not (math.isfinite(period) and period > 0):
            raise ValueError(f'control period must be > 0 s, got {period}')
        self.limits = limits
        self.command = command
        self.period = float(period)
        self.last: Tuple[float, float] = (0.0, 0.0)
        self.bound = 0
        self.periods = 0

    def desired_velocity(self, u, velocity_now) -> np.ndarray:
        """Planar velocity ``[2]`` the point ahead should have: ``u`` (velocity policy) or
        ``velocity_now + u T`` (acceleration policy)."""
        u = np.asarray(u, dtype=np.float64)[:2]
        if self.command == 'velocity':
            return u
        return np.asarray(velocity_now, dtype=np.float64)[:2] + u * self.period

    def __call__(
        self, u, theta: float, velocity_now=(0.0, 0.0), omega_now: float = 0.0
    ) -> Tuple[float, float]:
        """(v, omega) for the policy command ``u [2]`` at heading ``theta`` (rad), turning at
        ``omega_now`` (rad/s; mapped at the mid-period heading, see the module doc); the velocity
        of the point ahead now, ``velocity_now [2]``, is needed for acceleration policies."""
        lim = self.limits
        ux, uy = self.desired_velocity(u, velocity_now)
        heading = theta + 0.5 * float(omega_now) * self.period
        c, s = math.cos(heading), math.sin(heading)
        v_free = c * ux + s * uy
        w_free = (-s * ux + c * uy) / lim.lookahead
        v, w = limit_twist(v_free, w_free, self.last[0], self.last[1], lim, self.period)
        self.periods += 1
        self.bound += int(v != v_free or w != w_free)
        self.last = (v, w)
        return v, w

    def stop(self) -> Tuple[float, float]:
        """The command that brings the robot to rest as fast as the acceleration limits allow."""
        lim = self.limits
        v, w = limit_twist(0.0, 0.0, self.last[0], self.last[1], lim, self.period)
        self.last = (v, w)
        return v, w


def unicycle_step(pose: np.ndarray, v: float, omega: float, dt: float) -> np.ndarray:
    """Exact integration of the unicycle ``pose [3]`` = (x, y, theta) over ``dt`` under a held
    (v, omega) (an arc; a straight line for omega = 0)."""
    x, y, th = (float(a) for a in pose)
    if abs(omega) < 1e-12:
        return np.array([x + v * dt * math.cos(th), y + v * dt * math.sin(th), th])
    th2 = th + omega * dt
    r = v / omega
    return np.array([x + r * (math.sin(th2) - math.sin(th)), y - r * (math.cos(th2) - math.cos(th)), th2])


class UnicycleRobots:
    """``n`` simulated differential-drive bases: pose ``[n, 3]`` (x, y, theta), forward speed and
    turn rate ``[n]``. Like a real base (and its velocity smoother) it takes (v, omega) commands
    and enforces its limits (:func:`limit_twist`) on what it does: each step of ``dt`` the speed
    and turn rate move towards the command within the limits, then the pose follows the held
    twist exactly (:func:`unicycle_step`).

    Args:
        z0: ``[n, 4]`` flock2d states (px, py, vx, vy): heading = direction of the velocity (+x
            at rest), speed = its norm, saturated at ``max_linear_speed``; turn rate 0.
        limits: the base's limits (``lookahead`` is not used here).
    """

    def __init__(self, z0, limits: UnicycleLimits):
        limits.validate()
        z0 = np.asarray(z0, dtype=np.float64)
        self.limits = limits
        self.pose = np.stack([z0[:, 0], z0[:, 1], np.arctan2(z0[:, 3], z0[:, 2])], axis=-1)
        self.speed = _clip(np.hypot(z0[:, 2], z0[:, 3]), limits.max_linear_speed)
        self.turn = np.zeros(z0.shape[0])

    def step(self, command, dt: float) -> None:
        """Apply ``command [n, 2]`` = (v, omega) for ``dt`` seconds, within the limits."""
        command = np.asarray(command, dtype=np.float64)
        self.speed, self.turn = limit_twist(
            command[:, 0], command[:, 1], self.speed, self.turn, self.limits, dt
        )
        for i in range(self.pose.shape[0]):
            self.pose[i] = unicycle_step(self.pose[i], self.speed[i], self.turn[i], dt)
        self.pose[:, 2] = np.remainder(self.pose[:, 2] + math.pi, 2 * math.pi) - math.pi

    def states(self) -> np.ndarray:
        """``[n, 4]`` flock2d states of the axle centres: (x, y, speed * heading)."""
        th = self.pose[:, 2]
        return np.stack(
            [self.pose[:, 0], self.pose[:, 1], self.speed * np.cos(th), self.speed * np.sin(th)], axis=-1
        )
