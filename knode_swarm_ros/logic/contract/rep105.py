"""State <-> Odometry fields per REP 105, free of ROS (the one mapping; numpy only).

A robot's ``nav_msgs/Odometry`` holds its pose in the shared world frame (``header.frame_id``,
``world`` by default) and its twist in the child frame (``child_frame_id``,
``robot_<id>/base_link`` by default): REP 105, as every robot driver publishes it. The
world-frame velocity is therefore the pose orientation applied to ``twist.linear``.

:func:`state_to_fields` and :func:`fields_to_state` are that mapping between a state ``z [d]``
and the three vectors of the message that carry it (position ``[3]``, orientation quaternion
(x, y, z, w) ``[4]``, twist.linear ``[3]``). The ROS conversions
(:mod:`knode_swarm_ros.nodes.common.conversions`, also their serialized fast path) and the ROS-free bag
writer (:func:`knode_swarm_ros.bag.odometry_message`) both call them, so there is one mapping.

The mapping follows the scenario's kind (its ``state`` and ``dimensions``), never its name; a 2D
state leaves the third axis zero (the robots move in the plane z = 0 of the world frame):

==================  ===============================  ================================================
state               state entry                      Odometry field
==================  ===============================  ================================================
every kind          px, py [, pz]                    pose.position (z = 0 in 2D)
position            (nothing more)                   identity orientation, zero twist: the pose only
position_velocity   vx, vy [, vz]                    twist.linear (child frame); published with the
                                                     identity orientation, so the child frame is
                                                     parallel to the world frame and twist.linear =
                                                     (vx, vy, vz or 0) exactly (flock2d)
position_heading    hx, hy [, hz] (unit heading)     pose.orientation = the rotation taking +x onto
                                                     h (:mod:`.orientation`; a yaw in 2D) (boids3d)
position_heading    (not part of z)                  twist.linear = the last applied velocity in the
                                                     child frame (informative; about (|v|, 0, 0))
==================  ===============================  ================================================

Why the identity orientation without a heading in the state: such a robot is a holonomic point
mass (a double integrator, or a first-order point) with no heading of its own, so the one REP 105
pose it can honestly report is a body that does not turn. Its twist is then the world velocity bit for bit, which keeps the
lockstep runs equal to the offline rollout bit for bit (a rotation and its inverse would
change the last bit of some velocities). Decoding does not rely on it: a foreign robot that
reports its real yaw and a body-frame twist decodes to the same world velocity
(``twist_frame='body'``, the default), and a robot that puts a world-frame twist in its
Odometry (not REP 105) is read with ``twist_frame='world'``.
"""

from __future__ import annotations

import math
from typing import Optional, Sequence, Tuple, Union

import numpy as np

from knode_swarm_ros.core.scenarios import Scenario, get_scenario

from .orientation import heading_to_quaternion, quaternion_to_heading

__all__ = [
    'TWIST_FRAMES',
    'rotate',
    'rotate_inverse',
    'state_to_fields',
    'fields_to_state',
    'fields_to_states',
    'unicycle_fields',
    'yaw_of',
    'fields_to_point_state',
]

#: Frames a twist may be given in: ``body`` (REP 105 child frame) or ``world``.
TWIST_FRAMES = ('body', 'world')

_IDENTITY = (0.0, 0.0, 0.0, 1.0)


def _spec(scenario: Union[str, Scenario]) -> Scenario:
    return scenario if isinstance(scenario, Scenario) else get_scenario(scenario)


def rotate(q, v) -> np.ndarray:
    """``v [..., 3]`` rotated by the quaternions ``q [..., 4]`` (x, y, z, w; normalised first,
    a zero quaternion counts as the identity): v' = v + 2 w (u x v) + 2 u x (u x v).

    The identity leaves v unchanged bit for bit (both cross products are exact zeros).
    """
    q = np.asarray(q, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    q = np.where(norm > 0.0, q / np.where(norm > 0.0, norm, 1.0), np.array(_IDENTITY))
    u, w = q[..., :3], q[..., 3:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def _rotate_one(q: Sequence[float], v: Sequence[float]) -> Tuple[float, float, float]:
    """:func:`rotate` of one vector in plain floats (every received Odometry goes through it:
    numpy's per-call overhead would cost more than the message's decoding)."""
    x, y, z, w = (float(c) for c in q)
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if not n > 0.0:
        return float(v[0]), float(v[1]), float(v[2])
    if n != 1.0:
        x, y, z, w = x / n, y / n, z / n, w / n
    a, b, c = float(v[0]), float(v[1]), float(v[2])
    tx, ty, tz = 2.0 * (y * c - z * b), 2.0 * (z * a - x * c), 2.0 * (x * b - y * a)
    return (a + w * tx + (y * tz - z * ty), b + w * ty + (z * tx - x * tz), c + w * tz + (x * ty - y * tx))


def rotate_inverse(q, v) -> np.ndarray:
    """``v [..., 3]`` rotated by the inverse of ``q [..., 4]`` (world -> body)."""
    q = np.asarray(q, dtype=np.float64)
    return rotate(q * np.array([-1.0, -1.0, -1.0, 1.0]), v)


def state_to_fields(
    z, scenario: Union[str, Scenario], velocity: Optional[np.ndarray] = None
) -> Tuple[Tuple[float, float, float], Tuple[float, float, float, float], Tuple[float, float, float]]:
    """(position, orientation (x, y, z, w), twist.linear in the child frame) of state ``z [d]``.

    ``velocity [m]`` (``position_heading`` only, optional: the world-frame velocity applied
    last) fills twist.linear, rotated into the child frame; without it, and for a ``position``
    state, twist.linear is zero.
    """
    spec = _spec(scenario)
    z = np.asarray(z, dtype=np.float64)
    position = _padded(z[spec.position])
    if spec.velocity is not None:  # flock2d-like: identity orientation, world velocity (module doc)
        return position, _IDENTITY, _padded(z[spec.velocity])
    if spec.heading is None:
        return position, _IDENTITY, (0.0, 0.0, 0.0)
    q = heading_to_quaternion(np.array(_padded(z[spec.heading])))
    linear = (0.0, 0.0, 0.0)
    if velocity is not None:
        linear = tuple(float(x) for x in rotate_inverse(q, np.array(_padded(velocity))))
    return position, tuple(float(x) for x in q), linear


def _padded(v) -> Tuple[float, float, float]:
    """A 2- or 3-vector as three floats (z = 0 in 2D)."""
    return (float(v[0]), float(v[1]), float(v[2]) if len(v) > 2 else 0.0)


def fields_to_state(
    position, quaternion, linear, scenario: Union[str, Scenario], twist_frame: str = 'body'
) -> np.ndarray:
    """State ``z [d]`` float64 from an Odometry's position ``[3]``, orientation ``[4]`` and
    twist.linear ``[3]``, the twist read in ``twist_frame`` (``body``: REP 105, rotated by the
    orientation into the world frame; ``world``: taken as it is). A 2D state drops the z axis.
    No validation: callers check finiteness."""
    spec = _spec(scenario)
    dims = spec.dimensions
    if spec.velocity is not None:
        v = linear
        if twist_frame == 'body':
            v = _rotate_one(quaternion, linear)
        elif twist_frame != 'world':
            raise ValueError(f'twist_frame must be one of {", ".join(TWIST_FRAMES)}, got {twist_frame!r}')
        return np.array([*position[:dims], *v[:dims]], dtype=np.float64)
    if spec.heading is None:
        return np.array(position[:dims], dtype=np.float64)
    h = quaternion_to_heading(np.asarray(quaternion, dtype=np.float64))
    return np.array([*position[:dims], *h[:dims]], dtype=np.float64)


def _rotate_many(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """:func:`_rotate_one` of rows ``q [m, 4]``, ``v [m, 3]``, the same operations in the same
    order (so bit for bit the same results)."""
    x, y, z, w = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    n = np.sqrt(x * x + y * y + z * z + w * w)
    turns = n > 0.0  # else (zero, NaN) v as it is
    scale = np.where(turns & (n != 1.0), n, 1.0)
    x, y, z, w = x / scale, y / scale, z / scale, w / scale
    a, b, c = v[:, 0], v[:, 1], v[:, 2]
    with np.errstate(invalid='ignore'):  # a non-finite entry gives NaN, as one at a time
        tx, ty, tz = 2.0 * (y * c - z * b), 2.0 * (z * a - x * c), 2.0 * (x * b - y * a)
        out = np.stack(
            [a + w * tx + (y * tz - z * ty), b + w * ty + (z * tx - x * tz), c + w * tz + (x * ty - y * tx)],
            axis=1,
        )
    return np.where(turns[:, None], out, v)


def fields_to_states(
    positions, quaternions, linears, scenario: Union[str, Scenario], twist_frame: str = 'body'
) -> np.ndarray:
    """:func:`fields_to_state` of many messages at once: ``positions [m, 3]``, ``quaternions
    [m, 4]``, ``linears [m, 3]`` -> states ``[m, d]``, equal to it bit for bit (one tick of a
    monitor maps hundreds)."""
    spec = _spec(scenario)
    dims = spec.dimensions
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    quaternions = np.asarray(quaternions, dtype=np.float64).reshape(-1, 4)
    if spec.velocity is not None:
        v = np.asarray(linears, dtype=np.float64).reshape(-1, 3)
        if twist_frame == 'body':
            v = _rotate_many(quaternions, v)
        elif twist_frame != 'world':
            raise ValueError(f'twist_frame must be one of {", ".join(TWIST_FRAMES)}, got {twist_frame!r}')
        return np.concatenate([positions[:, :dims], v[:, :dims]], axis=1)
    if spec.heading is None:
        return positions[:, :dims].copy()
    return np.concatenate([positions[:, :dims], quaternion_to_heading(quaternions)[:, :dims]], axis=1)


# --- unicycle robots (simulator robot_model: unicycle; agent command_interface: unicycle) -------
def unicycle_fields(pose, v: float, omega: float):
    """(position, orientation, twist.linear, twist.angular) of a unicycle at ``pose [3]`` =
    (x, y, theta) moving with forward speed ``v`` and turn rate ``omega``, as a differential-drive
    driver publishes them (REP 105): the yaw quaternion, linear = (v, 0, 0) and angular =
    (0, 0, omega) in the body frame. :func:`fields_to_state` reads them back as (x, y, v cos theta,
    v sin theta)."""
    half = 0.5 * float(pose[2])
    return (
        (float(pose[0]), float(pose[1]), 0.0),
        (0.0, 0.0, math.sin(half), math.cos(half)),
        (float(v), 0.0, 0.0),
        (0.0, 0.0, float(omega)),
    )


def yaw_of(quaternion) -> float:
    """Rotation about +z (rad) of the orientation (x, y, z, w)."""
    x, y, z, w = (float(c) for c in quaternion)
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def fields_to_point_state(position, quaternion, linear, angular, lookahead: float) -> np.ndarray:
    """State ``[4]`` of the point ``lookahead`` ahead of the body origin along the body x axis,
    from Odometry fields (twist in the body frame, REP 105): position + l (cos yaw, sin yaw),
    velocity = R(yaw) (linear.x, linear.y + l angular.z). What the unicycle agent's policy sees
    (``unicycle_state: point``, :func:`knode_swarm_ros.core.unicycle.point_state`)."""
    yaw = yaw_of(quaternion)
    c, s = math.cos(yaw), math.sin(yaw)
    bx, by = float(linear[0]), float(linear[1]) + lookahead * float(angular[2])
    return np.array(
        [
            float(position[0]) + lookahead * c,
            float(position[1]) + lookahead * s,
            c * bx - s * by,
            s * bx + c * by,
        ],
        dtype=np.float64,
    )
