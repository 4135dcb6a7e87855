"""One QoS profile per topic, used by its publisher and by every subscriber (DESIGN.md).

* ``robot_<id>/odom``: :data:`ODOM`, reliable, volatile, keep last 200. Lockstep needs every
  state; 200 frames (2 s at 100 steps/s) absorb a subscriber descheduled for a while.
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
"""
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

__all__ = ['ODOM', 'COMMAND', 'CLOCK', 'STATUS', 'PROGRESS', 'METRICS', 'MARKERS', 'DIAGNOSTICS']


def _profile(depth, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE):
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=reliability,
                      durability=durability)


ODOM = _profile(200)
COMMAND = _profile(20)
CLOCK = _profile(1, reliability=ReliabilityPolicy.BEST_EFFORT)
STATUS = _profile(1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
PROGRESS = _profile(10)
METRICS = _profile(10)
MARKERS = _profile(1)
DIAGNOSTICS = _profile(10)
