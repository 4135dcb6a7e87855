"""RViz markers of a swarm (visualization_msgs/MarkerArray): the simulator's ``markers`` and the
monitor's ``monitor/markers``, one drawing for both.

Namespaces: ``robots`` (one sphere list, one point per robot, coloured by health when given),
``headings`` (one arrow per robot along the velocity or the heading its state holds; none for a
``position`` state), ``links`` (a
line list: the given pairs, else every pair of robots within d_cr of each other; none when d_cr
is 0) and, when given, ``trails`` (one line strip per robot). Frame ``world``.
"""

from __future__ import annotations

from typing import Optional, Sequence

import numpy as np
from geometry_msgs.msg import Point
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from knode_swarm_ros.core.scenarios import Scenario
from knode_swarm_ros.logic.common import WORLD_FRAME

from .conversions import time_msg

__all__ = ['swarm_markers', 'HEALTH_RGBA']

#: Robot colour by health (knode_swarm_ros.logic.monitor.HEALTH); the page uses the same.
HEALTH_RGBA = {
    'ok': (0.1, 0.4, 0.9, 1.0),
    'warn': (0.95, 0.75, 0.1, 1.0),
    'error': (0.85, 0.1, 0.1, 1.0),
    'stale': (0.95, 0.55, 0.1, 1.0),
    'lost': (0.5, 0.5, 0.5, 0.6),
    'unheard': (0.5, 0.5, 0.5, 0.0),
}


def _point(p) -> Point:
    return Point(x=float(p[0]), y=float(p[1]), z=float(p[2]) if len(p) > 2 else 0.0)


def _rgba(rgba) -> ColorRGBA:
    return ColorRGBA(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])


def _marker(ns: str, mid: int, kind: int, stamp, rgba) -> Marker:
    m = Marker()
    m.header.frame_id = WORLD_FRAME
    m.header.stamp = stamp
    m.ns = ns
    m.id = mid
    m.type = kind
    m.action = Marker.ADD
    m.pose.orientation.w = 1.0
    m.color = _rgba(rgba)
    return m


def swarm_markers(
    states: np.ndarray,
    spec: Scenario,
    d_cr: float,
    ns: int,
    links: Optional[np.ndarray] = None,
    health: Optional[Sequence[str]] = None,
    trails: Optional[Sequence[np.ndarray]] = None,
) -> MarkerArray:
    """Markers of ``states [n, d]`` at stamp ``ns``; ``links [L, 2]`` robot index pairs (None:
    every pair within ``d_cr``), ``health [n]`` names of :data:`HEALTH_RGBA` (None: all ok),
    ``trails [n]`` arrays ``[m_i, p]`` of past positions (None: no trails)."""
    stamp = time_msg(ns)
    p = spec.position_dim
    pos = np.asarray(states)[:, :p]
    direction = np.asarray(states)[:, p:]
    out = MarkerArray()

    robots = _marker('robots', 0, Marker.SPHERE_LIST, stamp, HEALTH_RGBA['ok'])
    robots.scale.x = robots.scale.y = robots.scale.z = 0.3
    robots.points = [_point(x) for x in pos]
    if health is not None:
        robots.colors = [_rgba(HEALTH_RGBA[h]) for h in health]
    out.markers.append(robots)

    length = 0.5 if spec.heading is not None else 0.25  # a unit heading; a velocity scaled
    for i, (x, v) in enumerate(zip(pos, direction) if direction.shape[1] else ()):
        arrow = _marker('headings', i, Marker.ARROW, stamp, (0.9, 0.3, 0.1, 1.0))
        arrow.scale.x, arrow.scale.y, arrow.scale.z = 0.05, 0.1, 0.1
        arrow.points = [_point(x), _point(x + length * v)]
        out.markers.append(arrow)

    line = _marker('links', 0, Marker.LINE_LIST, stamp, (0.5, 0.5, 0.5, 0.6))
    line.scale.x = 0.02
    out.markers.append(line)
    if trails is not None:
        for i, trail in enumerate(trails):
            strip = _marker('trails', i, Marker.LINE_STRIP, stamp, (0.1, 0.4, 0.9, 0.3))
            strip.scale.x = 0.03
            strip.points = [_point(x) for x in trail]
            out.markers.append(strip)
    if links is None:
        if d_cr <= 0:
            return out
        diff = pos[:, None, :] - pos[None, :, :]
        close = np.sqrt((diff * diff).sum(-1)) <= d_cr
        links = np.stack(np.nonzero(np.triu(close, 1)), axis=1)
    for i, j in np.asarray(links, dtype=np.int64).reshape(-1, 2):
        line.points += [_point(pos[i]), _point(pos[j])]
    return out
