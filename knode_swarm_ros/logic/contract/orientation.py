"""Orientation maths of the message mapping, free of ROS (the bag writer and importer use it too).

The boids3d heading h travels as the unit quaternion (x, y, z, w) that rotates +x onto h
(see :mod:`knode_swarm_ros.nodes.common.conversions` for the whole mapping): for h_x >= 0 the
shortest arc q = normalise(w = 1 + h_x, (x, y, z) = (+x) x h = (0, -h_z, h_y)); for h_x < 0,
where that formula cancels, the rotation by pi about +z after the shortest arc onto
(-h_x, -h_y, h_z), i.e. (-y', x', w', -z'). Decoding takes the first column of the rotation
matrix. A zero h encodes as the identity, which decodes as +x.
"""

from __future__ import annotations

import math
from typing import Tuple

import numpy as np

__all__ = ['heading_to_quaternion', 'quaternion_to_heading', 'yaw_quaternion', 'rotate_by_quaternion']


def _shortest_arc(u: np.ndarray) -> np.ndarray:
    q = np.stack([np.zeros_like(u[..., 0]), -u[..., 2], u[..., 1], 1.0 + u[..., 0]], axis=-1)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def heading_to_quaternion(h) -> np.ndarray:
    """Unit quaternions ``[..., 4]`` (x, y, z, w) rotating +x onto headings ``h [..., 3]`` (normalised first)."""
    h = np.asarray(h, dtype=np.float64)
    norm = np.linalg.norm(h, axis=-1, keepdims=True)
    zero = ~(norm[..., 0] > 0.0)
    u = h / np.where(zero[..., None], 1.0, norm)
    forward = u[..., :1] >= 0.0
    x_axis = np.array([1.0, 0.0, 0.0])
    pos = _shortest_arc(np.where(forward, u, x_axis))
    flipped = _shortest_arc(np.where(forward, x_axis, u * np.array([-1.0, -1.0, 1.0])))
    neg = np.stack([-flipped[..., 1], flipped[..., 0], flipped[..., 3], -flipped[..., 2]], axis=-1)
    q = np.where(forward, pos, neg)
    return np.where(zero[..., None], np.array([0.0, 0.0, 0.0, 1.0]), q)


def quaternion_to_heading(q) -> np.ndarray:
    """Headings ``[..., 3]``: the image of +x under quaternions ``q [..., 4]`` (normalised first;
    a zero quaternion gives +x)."""
    q = np.asarray(q, dtype=np.float64)
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    q = np.where(norm > 0.0, q / np.where(norm > 0.0, norm, 1.0), np.array([0.0, 0.0, 0.0, 1.0]))
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y)], axis=-1)


def yaw_quaternion(vx: float, vy: float) -> Tuple[float, float, float, float]:
    """(x, y, z, w) of the rotation about +z by atan2(vy, vx); identity for a zero vector
    (flock2d's orientation, for RViz only: not part of the state)."""
    if vx == 0.0 and vy == 0.0:
        return 0.0, 0.0, 0.0, 1.0
    half = 0.5 * math.atan2(vy, vx)
    return 0.0, 0.0, math.sin(half), math.cos(half)


def rotate_by_quaternion(q, v) -> np.ndarray:
    """Rotate vectors ``v [..., 3]`` by quaternions ``q [..., 4]`` (x, y, z, w; normalised first):
    body -> world (e.g. a REP 105 Odometry twist into the world frame)."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    u, w = q[..., :3], q[..., 3:4]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)
