"""Topic QoS profiles in rosbag2's own format (what ``ros2 bag play`` replays them with).

rosbag2 Jazzy (metadata version 9, ``rosbag2_storage/src/rosbag2_storage/qos.cpp`` and
``yaml.hpp`` on the jazzy branch) writes a topic's ``offered_qos_profiles``:

* in ``metadata.yaml``: a YAML sequence of maps (version 8 and earlier: one YAML string);
* in an MCAP channel's metadata: the same sequence dumped to a string;

each map: ``history``, ``depth``, ``reliability``, ``durability``, ``deadline`` {sec, nsec},
``lifespan``, ``liveliness``, ``liveliness_lease_duration``, ``avoid_ros_namespace_conventions``,
the policies as rmw's names (``keep_last``, ``reliable``, ``best_effort``, ``volatile``,
``transient_local``, ``automatic``). A recording of a publisher with default deadline, lifespan
and liveliness holds what the middleware reports for them: infinite durations
(``RMW_DURATION_INFINITE`` = 9223372036 s 854775807 ns) and ``automatic``; so do ours.
The dicts come from ``rosbags`` (:func:`rosbags.rosbag2.metadata.dump_qos_v9`).
"""

from __future__ import annotations

from typing import Any, Dict, List, Optional

from knode_swarm_ros.logic.contract.qos_specs import QosSpec

__all__ = ['rosbags_qos', 'qos_v9', 'INFINITE']

#: RMW_DURATION_INFINITE as rosbag2 writes it (sec, nsec).
INFINITE = (9223372036, 854775807)


def rosbags_qos(spec: Optional[QosSpec]) -> List[Any]:
    """``[rosbags Qos]`` of a project profile (``[]`` for None: no profile known)."""
    if spec is None:
        return []
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

    infinite = QosTime(*INFINITE)
    return [
        Qos(
            history=QosHistory.KEEP_LAST,
            depth=int(spec.depth),
            reliability=QosReliability[spec.reliability.upper()],
            durability=QosDurability[spec.durability.upper()],
            deadline=infinite,
            lifespan=infinite,
            liveliness=QosLiveliness.AUTOMATIC,
            liveliness_lease_duration=infinite,
            avoid_ros_namespace_conventions=False,
        )
    ]


def qos_v9(spec: Optional[QosSpec]) -> List[Dict[str, Any]]:
    """The ``offered_qos_profiles`` entry of ``metadata.yaml`` version 9 for a project profile."""
    from rosbags.rosbag2.metadata import dump_qos_v9

    return [dict(d) for d in dump_qos_v9(rosbags_qos(spec))]
