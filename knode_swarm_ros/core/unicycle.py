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

Limits, applied in this order each period: |v| <= ``max_linear_speed``,
|omega| <= ``max_angular_speed`` (saturation keeps the sign), then the change from the
previous command |dv| <= ``max_linear_accel`` T and |domega| <= ``max_angular_accel`` T (a
limit of 0 means none). When a limit binds, P no longer follows the policy exactly; the
agent counts those periods.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Tuple

import numpy as np

__all__ = ['UnicycleLimits', 'UnicycleMapper', 'unicycle_step', 'point_ahead']


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


def point_ahead(x: float, y: float, theta: float, v: float, omega: float, lookahead: float
                ) -> Tuple[np.ndarray, np.ndarray]:
    """Position ``[2]`` and velocity ``[2]`` of the point ``lookahead`` ahead of the axle."""
    c, s = math.cos(theta), math.sin(theta)
    pos = np.array([x + lookahead * c, y + lookahead * s])
    vel = np.array([c * v - s * lookahead * omega, s * v + c * lookahead * omega])
    return pos, vel


def _clip(value: float, limit: float) -> float:
    return max(-limit, min(limit, value)) if limit > 0 else value


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

    def __call__(self, u, theta: float, velocity_now=(0.0, 0.0)) -> Tuple[float, float]:
        """(v, omega) for the policy command ``u [2]`` at heading ``theta`` (rad); the velocity of
        the point ahead now, ``velocity_now [2]``, is needed for acceleration policies."""
        lim = self.limits
        ux, uy = self.desired_velocity(u, velocity_now)
        c, s = math.cos(theta), math.sin(theta)
        v_free = c * ux + s * uy
        w_free = (-s * ux + c * uy) / lim.lookahead
        v = _clip(v_free, lim.max_linear_speed)
        w = _clip(w_free, lim.max_angular_speed)
        bound = v != v_free or w != w_free
        for idx, (value, limit) in enumerate(((v, lim.max_linear_accel), (w, lim.max_angular_accel))):
            step = limit * self.period
            if limit > 0 and abs(value - self.last[idx]) > step:
                value = self.last[idx] + math.copysign(step, value - self.last[idx])
                bound = True
            v, w = (value, w) if idx == 0 else (v, value)
        self.periods += 1
        self.bound += int(bound)
        self.last = (v, w)
        return v, w

    def stop(self) -> Tuple[float, float]:
        """The command that brings the robot to rest as fast as the acceleration limits allow."""
        lim = self.limits
        v = self.last[0] - _clip(self.last[0], lim.max_linear_accel * self.period)
        w = self.last[1] - _clip(self.last[1], lim.max_angular_accel * self.period)
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
