"""What the lone ``agent`` node and the hosting ``agents`` node share, so that neither imports
the other's node module: loading the policy and warming it up, subscribing to every robot's
state topic (the fleet's: Odometry, or PoseStamped with estimated velocities) and decoding it,
and the control timers of a mode.
"""

from __future__ import annotations

from functools import partial
from typing import Callable, Optional, Sequence, Tuple

import numpy as np

from knode_swarm_ros.logic.agent.control_period import shipped_policy_for_rate
from knode_swarm_ros.logic.agent.realtime_tick import GraceArm
from knode_swarm_ros.logic.common import ConfigError
from knode_swarm_ros.logic.contract.fleet import Fleet
from knode_swarm_ros.logic.contract.pose import PoseStates
from knode_swarm_ros.nodes.common import qos
from knode_swarm_ros.nodes.common.conversions import STATE_MESSAGES, CdrError, odom_from_cdr, pose_from_cdr

__all__ = ['load_agent_policy', 'warm_up_inputs', 'StateDecoder', 'control_timers', 'missing_names']


def load_agent_policy(
    path: str,
    scenario: str,
    k: int,
    d_cr: float,
    tau: int,
    dt: float,
    runtime: str = 'auto',
    threads: int = 1,
    control_rate: float = 0.0,
):
    """Load the policy and check the optional parameters against its metadata.

    ``path`` empty means the shipped policy of ``scenario`` (flock2d when empty too); with a
    realtime ``control_rate`` > 0 (and ``dt`` unset) the shipped one trained for that rate,
    if there is one (:func:`.control_period.shipped_policy_for_rate`).
    ``runtime`` (``policy_runtime``): ``auto`` runs the ONNX twin on onnxruntime when it exists
    and onnxruntime is installed, else TorchScript (only that path imports torch).
    ``scenario`` (empty), ``k`` (0), ``d_cr`` (0.0),
    ``tau`` (-1) and ``dt`` (0.0) at their "unset" values are taken from the policy.

    Raises:
        ConfigError: missing, corrupt or mismatched policy file; the message names the
            parameter or the file and both values.
    """
    from knode_swarm_ros.core.policy_meta import PolicyError, PolicyMismatchError, shipped_policy_path
    from knode_swarm_ros.core.policy_runtime import (
        load_runtime,  # imports torch only for the TorchScript backend
    )
    from knode_swarm_ros.core.scenarios import get_scenario

    if not path:
        scenario = scenario or 'flock2d'
        if not get_scenario(scenario).shipped:
            raise ConfigError(
                f"parameter 'policy' is empty, but no policy is shipped for scenario "
                f'{get_scenario(scenario).name}; pass -p policy:=/path/to/policy.pt'
            )
        try:
            path = str(
                shipped_policy_for_rate(scenario, control_rate)[0]
                if control_rate > 0 and dt <= 0
                else shipped_policy_path(scenario)
            )
        except PolicyError as exc:
            raise ConfigError(
                f"parameter 'policy' is empty, so the shipped policy of scenario "
                f'{scenario!r} is used, but {exc}; pass -p policy:=/path/to/policy.pt'
            ) from None
    wanted = {
        'scenario': scenario or None,
        'k': k if k > 0 else None,
        'd_cr': d_cr if d_cr > 0 else None,
        'tau': tau if tau >= 0 else None,
        'dt': dt if dt > 0 else None,
    }
    try:
        return load_runtime(path, runtime, expect=wanted, threads=threads)
    except PolicyMismatchError as exc:  # the parameter and the file disagree: name the parameter
        raise ConfigError(
            f'parameter {exc.key!r} = {exc.required!r} contradicts the policy file {path}, '
            f'whose knode.json has {exc.key} = {exc.got!r} (leave {exc.key!r} unset to use the '
            f"policy's value)"
        ) from None
    except PolicyError as exc:
        raise ConfigError(f"parameter 'policy' (policy_runtime {runtime}): {exc}") from None


def warm_up_inputs(batch: int, k: int, state_dim: int) -> Tuple[np.ndarray, np.ndarray]:
    """``Y [batch, k, d]`` zeros and ``mask [batch, k]`` with only the own row set: a first policy
    call at start, so that the runtime's lazy set-up does not delay the first command."""
    Y = np.zeros((batch, k, state_dim))
    mask = np.zeros((batch, k), dtype=bool)
    mask[:, 0] = True
    return Y, mask


class StateDecoder:
    """Every robot's state topic of the fleet, subscribed raw and decoded to ``z [d]``.

    Odometry: the REP 105 mapping (:func:`.conversions.odom_from_cdr`), a ``child_frame_id``
    that is not the topic's robot's gives robot None (the logic files it as ``unknown_id``).
    PoseStamped: position (and heading) from the pose, the velocity (when the state has one)
    estimated from that robot's poses (:class:`knode_swarm_ros.logic.contract.pose.PoseStates`,
    shared by the robots of a process: they hear the same poses).
    """

    def __init__(
        self, fleet: Fleet, spec, twist_frame: str, dt: Optional[float] = None, own: Sequence[int] = ()
    ):
        self.fleet = fleet
        self.spec = spec
        self.twist_frame = twist_frame
        self.poses = (
            PoseStates(spec, fleet.state.velocity_window, dt, own) if fleet.state.type == 'pose' else None
        )

    def command(self, robot: int, stamp_ns: int, u) -> None:
        """Own robot ``robot`` commanded ``u`` from ``stamp_ns``: its command-aided velocity."""
        if self.poses is not None:
            self.poses.command(robot, stamp_ns, u)

    def subscribe(
        self, node, ids: Sequence[int], on_state: Callable[[int, bytes], None], qos_profile=qos.ODOM
    ) -> list:
        """One raw subscription per robot's state topic: ``on_state(j, bytes)`` (decoded by
        :meth:`decode`, 3x cheaper than rclpy's message objects)."""
        msg_type = STATE_MESSAGES[self.fleet.state.type]
        return [
            node.create_subscription(
                msg_type, self.fleet.state_topic(rid), partial(on_state, rid), qos_profile, raw=True
            )
            for rid in ids
        ]

    def decode(self, topic_robot: int, data: bytes) -> Tuple[Optional[int], int, str, np.ndarray]:
        """``(robot, stamp_ns, frame, z [d])`` of raw bytes heard on robot ``topic_robot``'s state
        topic (``frame``: Odometry's child_frame_id, a pose's header.frame_id).

        Raises:
            CdrError: undecodable bytes; the message names the topic.
        """
        try:
            if self.poses is not None:
                stamp, frame, pose = pose_from_cdr(data)
                return topic_robot, stamp, frame, self.poses.state(topic_robot, stamp, pose[:3], pose[3:])
            stamp, frame, z = odom_from_cdr(data, self.spec, self.twist_frame)
        except CdrError as exc:
            raise CdrError(f'{self.fleet.state_topic(topic_robot)}: {exc}') from None
        return (topic_robot if self.fleet.owns_frame(frame, topic_robot) else None), stamp, frame, z

    def filed(self, topic_robot: int, data: bytes) -> list:
        """What to file of raw bytes heard on robot ``topic_robot``'s state topic:
        ``[(robot, stamp_ns, frame, z [d], step, own)]``. Odometry: the one state (step None:
        the stamp's nearest; own None). Poses: the states that stand for a step
        (:meth:`.PoseStates.filed`; none for most poses of a stream faster than the policy),
        ``own`` an own robot's command-aided state (its own row of Y) or None.

        Raises:
            CdrError: undecodable bytes; the message names the topic.
        """
        if self.poses is None:
            return [(*self.decode(topic_robot, data), None, None)]
        try:
            stamp, frame, pose = pose_from_cdr(data)
        except CdrError as exc:
            raise CdrError(f'{self.fleet.state_topic(topic_robot)}: {exc}') from None
        return [
            (topic_robot, filed_stamp, frame, z, step, own)
            for step, filed_stamp, z, own in self.poses.filed(topic_robot, stamp, pose[:3], pose[3:])
        ]


def control_timers(
    node, mode: str, control_rate: float, grace_s: Optional[float], on_tick, on_grace, on_lockstep, wall
) -> Tuple[object, Optional[GraceArm]]:
    """The control timer of ``mode`` and, realtime with ticks on the own state (``grace_s`` set),
    the grace of ticks waiting for their neighbours' states: ``(control_timer, grace)``.

    Realtime ticks ``on_tick`` at ``control_rate`` on the ROS clock (sim time); lockstep polls
    ``on_lockstep`` every 50 ms of the wall clock ``wall``, so that silent peers time out."""
    if mode != 'realtime':
        return node.create_timer(0.05, on_lockstep, clock=wall), None
    control = node.create_timer(1.0 / control_rate, on_tick)
    if grace_s is None:
        return control, None
    return control, GraceArm(node.create_timer(grace_s, on_grace, clock=wall))


def missing_names(fleet, ids) -> str:
    """``cf5 (id 7) on /vrpn_mocap/cf5/pose, ...``: robots never heard, and where they were awaited."""
    return ', '.join(f'{fleet.name_of(i)} (id {i}) on {fleet.state_topic(i)}' for i in ids)
