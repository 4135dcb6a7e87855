"""ROS-free helpers shared by the nodes, their logic classes and the launcher.

* topic names (relative, so that a namespace or a remapping moves them; docs/DESIGN.md,
  "ROS 2 interfaces"),
* stamps: a state of step ``s`` is stamped ``round(s * dt * 1e9)`` nanoseconds and a stamp
  maps back to ``round(ns / (dt * 1e9))`` (the core's :class:`DelayBuffer` uses the same
  rounding); stamps travel as integer nanoseconds so that a command can echo the exact
  stamp of the state it was computed from,
* :class:`ConfigError` and the exit codes every executable uses,
* percentiles for the latency and timing figures.

Nothing here imports rclpy or message packages.
"""

from __future__ import annotations

import json
import math
from typing import Any, Dict, Iterable, List, Optional, Sequence

import numpy as np

__all__ = [
    'ConfigError',
    'EXIT_OK',
    'EXIT_FAILURE',
    'EXIT_CONFIG',
    'EXIT_AGENT_LOST',
    'EXIT_INTERRUPTED',
    'MODES',
    'odom_topic',
    'command_topic',
    'agent_status_topic',
    'SIMULATOR_STATUS_TOPIC',
    'RECORDER_STATUS_TOPIC',
    'RECORDER_PROGRESS_TOPIC',
    'MARKERS_TOPIC',
    'CLOCK_TOPIC',
    'AVD_TOPIC',
    'AMD_TOPIC',
    'robot_frame',
    'parse_robot_frame',
    'is_robot_frame',
    'WORLD_FRAME',
    'stamp_ns',
    'step_of',
    'percentiles',
    'status_json',
    'parse_status',
    'robot_id_list',
    'dt_mismatch',
]

#: Exit statuses of the executables.
# The exit statuses are core's (one table for every executable); the nodes' names for them:
from knode_swarm_ros.core.errors import EXIT_BAD_INPUT as EXIT_CONFIG
from knode_swarm_ros.core.errors import EXIT_INTERRUPTED, EXIT_OK
from knode_swarm_ros.core.errors import EXIT_RUN_FAILED as EXIT_FAILURE

EXIT_AGENT_LOST = 3  # swarm: the run completed but at least one agent process died

#: Simulator / agent modes.
MODES = ('lockstep', 'realtime')

WORLD_FRAME = 'world'
CLOCK_TOPIC = '/clock'  # absolute: where use_sim_time listens
SIMULATOR_STATUS_TOPIC = 'simulator/status'  # std_msgs/String, JSON (see docs/ros.md)
RECORDER_STATUS_TOPIC = 'recorder/status'  # std_msgs/String, JSON
RECORDER_PROGRESS_TOPIC = 'recorder/progress'  # std_msgs/Int64: newest complete frame's step
AVD_TOPIC = 'recorder/avd'  # std_msgs/Float64
AMD_TOPIC = 'recorder/amd'  # std_msgs/Float64
MARKERS_TOPIC = 'markers'  # visualization_msgs/MarkerArray


# A parameter, argument or input file that prevents a node from starting: the message names the
# parameter (or file) and the offending value; executables print it and exit with EXIT_CONFIG.
# One class with the training config's (knode_swarm_ros.core.errors).
from knode_swarm_ros.core.errors import ConfigError  # noqa: E402


def odom_topic(robot: int) -> str:
    """``robot_<id>/odom`` (nav_msgs/Odometry)."""
    return f'robot_{int(robot)}/odom'


def command_topic(robot: int, command: str) -> str:
    """``robot_<id>/cmd_accel`` (AccelStamped) for ``acceleration``, ``robot_<id>/cmd_vel``
    (TwistStamped) for ``velocity``."""
    if command == 'acceleration':
        return f'robot_{int(robot)}/cmd_accel'
    if command == 'velocity':
        return f'robot_{int(robot)}/cmd_vel'
    raise ValueError(f'unknown command kind {command!r}')


def agent_status_topic(robot: int) -> str:
    """``robot_<id>/agent_status`` (std_msgs/String, JSON): readiness and counters."""
    return f'robot_{int(robot)}/agent_status'


def robot_frame(robot: int) -> str:
    """child_frame_id of a robot's odometry (REP 105 body frame): ``robot_<id>/base_link``."""
    return f'robot_{int(robot)}/base_link'


def parse_robot_frame(frame: str) -> Optional[int]:
    """The id in ``robot_<id>`` or ``robot_<id>/<link>`` (e.g. ``robot_3/base_link``,
    ``robot_3/base_footprint``), or None for anything else."""
    if not frame.startswith('robot_'):
        return None
    tail = frame[len('robot_') :].split('/', 1)[0]
    return int(tail) if tail.isdigit() else None


def is_robot_frame(frame: str, robot: int) -> bool:
    """Whether an Odometry ``child_frame_id`` may belong to robot ``robot``: empty (unset),
    or one of its frames ``robot_<id>[/<link>]`` (a message naming another robot is not)."""
    return frame == '' or parse_robot_frame(frame) == int(robot)


def stamp_ns(step: int, dt: float) -> int:
    """Stamp in integer nanoseconds of step ``step`` of ``dt`` seconds."""
    return int(round(int(step) * float(dt) * 1e9))


def step_of(ns: int, dt: float) -> int:
    """Step index of a stamp in nanoseconds (inverse of :func:`stamp_ns`)."""
    return int(round(int(ns) / (float(dt) * 1e9)))


def dt_mismatch(policy_dt: Any, sim_dt: float) -> Optional[str]:
    """Why a policy stepping at ``policy_dt`` cannot drive a simulator stepping at ``sim_dt``
    (a sentence), or None when they agree (relative 1e-9) or ``policy_dt`` is unknown."""
    try:
        policy_dt = float(policy_dt)
    except (TypeError, ValueError):
        return None
    if not math.isfinite(policy_dt) or math.isclose(policy_dt, float(sim_dt), rel_tol=1e-9, abs_tol=0.0):
        return None
    return f'runs a policy with dt = {policy_dt:g} s but the simulator steps at dt = {float(sim_dt):g} s'


def robot_id_list(robots: int, robot_ids: Optional[Sequence[int]] = None) -> List[int]:
    """Sorted robot ids: ``robot_ids`` when given (non-empty), else ``0 .. robots - 1``.

    Raises:
        ConfigError: duplicate or negative ids, or no robot at all.
    """
    if robot_ids:
        ids = [int(i) for i in robot_ids]
        if len(set(ids)) != len(ids):
            raise ConfigError(f"parameter 'robot_ids' holds duplicates: {list(robot_ids)}")
        if min(ids) < 0:
            raise ConfigError(f"parameter 'robot_ids' holds a negative id: {list(robot_ids)}")
        return sorted(ids)
    if int(robots) < 1:
        raise ConfigError(f"parameter 'robots' must be >= 1, got {robots}")
    return list(range(int(robots)))


def percentiles(samples: Iterable[float], qs: Sequence[float] = (50, 99)) -> Dict[str, Optional[float]]:
    """``{'p50': .., 'p99': .., 'max': .., 'count': n}`` of ``samples`` (None when empty)."""
    arr = np.asarray(list(samples), dtype=np.float64)
    out: Dict[str, Optional[float]] = {'count': int(arr.size)}
    for q in qs:
        out[f'p{q:g}'] = float(np.percentile(arr, q)) if arr.size else None
    out['max'] = float(arr.max()) if arr.size else None
    return out


def status_json(**fields: Any) -> str:
    """Compact JSON text of a status message (non-finite floats become null)."""

    def clean(v):
        if isinstance(v, float) and not math.isfinite(v):
            return None
        if isinstance(v, dict):
            return {str(k): clean(x) for k, x in v.items()}
        if isinstance(v, (list, tuple, set)):
            return [clean(x) for x in (sorted(v) if isinstance(v, set) else v)]
        if isinstance(v, np.generic):
            return v.item()
        return v

    return json.dumps(clean(fields), separators=(',', ':'), sort_keys=True)


def parse_status(text: str) -> Optional[Dict[str, Any]]:
    """The JSON object of a status message, or None when it is not one."""
    try:
        value = json.loads(text)
    except (TypeError, ValueError):
        return None
    return value if isinstance(value, dict) else None
