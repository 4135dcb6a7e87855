"""The rclpy QoS profiles of the topics, one per topic (docs/DESIGN.md), built from the ROS-free
table :mod:`.qos_specs` (which says why each profile is what it is; the bags the project
writes carry the same profiles)."""

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from knode_swarm_ros.logic.contract import qos_specs

__all__ = [
    'ODOM',
    'POSE_STREAM',
    'COMMAND',
    'CLOCK',
    'STATUS',
    'PROGRESS',
    'METRICS',
    'MARKERS',
    'DIAGNOSTICS',
    'profile',
]

_RELIABILITY = {'reliable': ReliabilityPolicy.RELIABLE, 'best_effort': ReliabilityPolicy.BEST_EFFORT}
_DURABILITY = {'volatile': DurabilityPolicy.VOLATILE, 'transient_local': DurabilityPolicy.TRANSIENT_LOCAL}


def profile(spec: qos_specs.QosSpec) -> QoSProfile:
    """The rclpy profile of a :class:`~.qos_specs.QosSpec` (keep last ``depth``)."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=spec.depth,
        reliability=_RELIABILITY[spec.reliability],
        durability=_DURABILITY[spec.durability],
    )


ODOM = profile(qos_specs.ODOM)
POSE_STREAM = profile(qos_specs.POSE_STREAM)
COMMAND = profile(qos_specs.COMMAND)
CLOCK = profile(qos_specs.CLOCK)
STATUS = profile(qos_specs.STATUS)
PROGRESS = profile(qos_specs.PROGRESS)
METRICS = profile(qos_specs.METRICS)
MARKERS = profile(qos_specs.MARKERS)
DIAGNOSTICS = profile(qos_specs.DIAGNOSTICS)
