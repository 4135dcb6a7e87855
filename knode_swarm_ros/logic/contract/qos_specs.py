"""One QoS profile per topic, as plain data (no ROS): :mod:`.qos` builds the rclpy profiles from
it and :mod:`knode_swarm_ros.bag` writes it into bags as the topics' ``offered_qos_profiles``.

* ``robot_<id>/odom``: :data:`ODOM`, reliable, volatile, keep last 200. Lockstep needs every
  state; 200 frames (2 s at 100 steps/s) absorb a subscriber descheduled for a while.
* a realtime agent's subscriptions to a fleet's pose stream (motion capture, faster than the
  policy): :data:`POSE_STREAM`, best effort, keep last 10 (100 ms at 100 Hz). Only recent poses
  matter in real time: an agent descheduled for a while resumes at its newest poses instead of
  working through a backlog (which kept reliable readers half a second behind their clock on
  two loaded cores), and a lost pose is never waited for. A reliable publisher serves it.
* ``robot_<id>/cmd_accel``, ``cmd_vel``: :data:`COMMAND`, reliable, volatile, keep last 20.
  Every command counts in lockstep; only the newest matters in real time.
* ``/clock``: :data:`CLOCK`, best effort, keep last 1: what rclpy's time source subscribes
  with; only the newest time matters.
* ``robot_<id>/agent_status``, ``simulator/status``, ``recorder/status``: :data:`STATUS`,
  reliable, transient local, keep last 1: a late subscriber still gets the current state
  (readiness, done, saved).
* ``recorder/progress``: :data:`PROGRESS`, reliable, volatile, keep last 10: the simulator's
  lockstep flow control.
* ``recorder/avd``, ``recorder/amd``: :data:`METRICS`, reliable, volatile, keep last 10.
* ``/diagnostics``: :data:`DIAGNOSTICS`, reliable, volatile, keep last 10: what
  diagnostic_updater and the aggregator use.
* ``markers``: :data:`MARKERS`, reliable, volatile, keep last 1: RViz's default; only the
  newest picture matters.

Every profile keeps history (keep last ``depth``); deadline, lifespan and liveliness stay at
the middleware's defaults.
"""

from __future__ import annotations

from typing import NamedTuple

__all__ = [
    'QosSpec',
    'ODOM',
    'POSE_STREAM',
    'COMMAND',
    'CLOCK',
    'STATUS',
    'PROGRESS',
    'METRICS',
    'MARKERS',
    'DIAGNOSTICS',
]


class QosSpec(NamedTuple):
    """History keep-last ``depth``; ``reliability`` 'reliable' | 'best_effort'; ``durability``
    'volatile' | 'transient_local' (the rmw policy names)."""

    depth: int
    reliability: str = 'reliable'
    durability: str = 'volatile'


ODOM = QosSpec(200)
POSE_STREAM = QosSpec(10, reliability='best_effort')
COMMAND = QosSpec(20)
CLOCK = QosSpec(1, reliability='best_effort')
STATUS = QosSpec(1, durability='transient_local')
PROGRESS = QosSpec(10)
METRICS = QosSpec(10)
MARKERS = QosSpec(1)
DIAGNOSTICS = QosSpec(10)
