"""RViz markers of the simulated swarm (visualization_msgs/MarkerArray on ``markers``).

Namespaces: ``robots`` (one sphere list, one point per robot), ``headings`` (one arrow per
robot along its velocity, flock2d, or heading, boids3d) and ``links`` (a line list joining every
pair of robots within d_cr of each other; none when d_cr is 0). Frame ``world``.
"""

from __future__ import annotations

import numpy as np
from geometry_msgs.msg import Point
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from knode_swarm_ros.core.scenarios import Scenario
from knode_swarm_ros.logic.common import WORLD_FRAME

from .conversions import time_msg

__all__ = ['swarm_markers']


def _point(p) -> Point:
    return Point(x=float(p[0]), y=float(p[1]), z=float(p[2]) if len(p) > 2 else 0.0)


def _marker(ns: str, mid: int, kind: int, stamp, rgba) -> Marker:
    m = Marker()
    m.header.frame_id = WORLD_FRAME
    m.header.stamp = stamp
    m.ns = ns
    m.id = mid
    m.type = kind
    m.action = Marker.ADD
    m.pose.orientation.w = 1.0
    m.color = ColorRGBA(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])
    return m


def swarm_markers(states: np.ndarray, spec: Scenario, d_cr: float, ns: int) -> MarkerArray:
    """Markers of ``states [n, d]`` at stamp ``ns``."""
    stamp = time_msg(ns)
    p = spec.position_dim
    pos = np.asarray(states)[:, :p]
    direction = np.asarray(states)[:, p:]
    out = MarkerArray()

    robots = _marker('robots', 0, Marker.SPHERE_LIST, stamp, (0.1, 0.4, 0.9, 1.0))
    robots.scale.x = robots.scale.y = robots.scale.z = 0.3
    robots.points = [_point(x) for x in pos]
    out.markers.append(robots)

    length = 0.5 if spec.command == 'velocity' else 0.25  # boids: unit heading; flock: velocity scaled
    for i, (x, v) in enumerate(zip(pos, direction)):
        arrow = _marker('headings', i, Marker.ARROW, stamp, (0.9, 0.3, 0.1, 1.0))
        arrow.scale.x, arrow.scale.y, arrow.scale.z = 0.05, 0.1, 0.1
        arrow.points = [_point(x), _point(x + length * v)]
        out.markers.append(arrow)

    links = _marker('links', 0, Marker.LINE_LIST, stamp, (0.5, 0.5, 0.5, 0.6))
    links.scale.x = 0.02
    out.markers.append(links)
    if d_cr <= 0:
        return out
    diff = pos[:, None, :] - pos[None, :, :]
    close = np.sqrt((diff * diff).sum(-1)) <= d_cr
    for i, j in zip(*np.nonzero(np.triu(close, 1))):
        links.points += [_point(pos[i]), _point(pos[j])]
    return out
