"""Per-agent health on ``/diagnostics`` (diagnostic_msgs/DiagnosticArray), every status period.

One DiagnosticStatus per robot (a lone agent publishes an array with its own; a process hosting
several robots, :class:`HostedHealth`, one array with one status per hosted robot, the
ROS-idiomatic form of an aggregated publisher), name ``knode_swarm agent <robot name>``,
hardware_id the robot's name in the fleet (``robot_<id>`` without a fleet file; the monitor maps
it back), with the key values: neighbours (real rows of the last Y), heard (robots heard
at least once) / robots, own state age (s, on the node's clock), command rate (Hz, since the
previous report), saturated share (commands clipped at the command limit since the previous
report), drops by reason (totals), link counters when the link model is on, lifecycle state.

Level: ERROR when no own state has been heard yet while active; WARN when the own state is
older than ``state_timeout`` (the agent is sending stops), when the policy saturated more than
half of the commands since the previous report, or when the agent is not active; else OK.
:func:`assess` is the ROS-free judgement; :class:`AgentHealth` only builds the message.
"""

from __future__ import annotations

import struct
from typing import Any, Dict, List, Optional, Tuple

from knode_swarm_ros.logic.agent.agent_logic import DROP_REASONS
from knode_swarm_ros.nodes.common.conversions import CDR_LE, cdr_pad, cdr_put_string

__all__ = ['assess', 'AgentHealth', 'HostedHealth', 'OK', 'WARN', 'ERROR']

OK, WARN, ERROR = 0, 1, 2
SATURATION_WARN = 0.5


def assess(
    status: Dict[str, Any],
    counts_before: Dict[str, int],
    seconds: float,
    own_age: Optional[float],
    state_timeout: float,
    neighbours: int,
) -> Tuple[int, str, List[Tuple[str, str]]]:
    """(level, message, key values) of one report.

    Args:
        status: the agent's status dict (its ``counters``, ``heard``, ``robots``, ``lifecycle``, ``link``).
        counts_before: the counters at the previous report (for rates and shares).
        seconds: time since the previous report (> 0; wall clock).
        own_age: seconds since the own state's stamp, None when none was heard.
        state_timeout: the agent's ``state_timeout``.
        neighbours: real neighbour rows of the last command.
    """
    c = status['counters']
    commands = c['commands'] - counts_before.get('commands', 0)
    clipped = c['clipped'] - counts_before.get('clipped', 0)
    share = clipped / commands if commands > 0 else 0.0
    rate = commands / seconds if seconds > 0 else 0.0
    active = status.get('lifecycle', 'active') == 'active'
    problems, level = [], OK
    if own_age is None and active:
        level, problems = ERROR, ['no own state heard yet']
    elif own_age is not None and own_age > state_timeout:
        level = WARN
        problems.append(f'own state is stale ({own_age:.2f} s > state_timeout {state_timeout:g} s): stopping')
    if share > SATURATION_WARN and commands >= 5:
        level = max(level, WARN)
        problems.append(f'policy saturated {100 * share:.0f} % of the commands')
    if not active:
        level = max(level, WARN)
        problems.append('not active (managed: waiting for activate)')
    values = [
        ('neighbours', str(neighbours)),
        ('heard', f'{status["heard"]}/{status["robots"]}'),
        ('own_state_age_s', 'none' if own_age is None else f'{own_age:.3f}'),
        ('command_rate_hz', f'{rate:.2f}'),
        ('saturated_share', f'{share:.3f}'),
        ('lifecycle', status.get('lifecycle', 'active')),
    ]
    values += [(f'drops_{reason}', str(c[reason])) for reason in DROP_REASONS]
    for key, value in (status.get('link') or {}).items():
        values.append((f'link_{key}', str(value)))
    return level, '; '.join(problems) if problems else 'ok', values


def _entry(
    name: str,
    status: Dict[str, Any],
    before: Dict[str, int],
    seconds: float,
    now_ns: int,
    own_ns: Optional[int],
    state_timeout: float,
    neighbours: int,
):
    """(level, name, message, hardware_id, key values) of one robot's report (see :func:`assess`)."""
    own_age = None if own_ns is None else max(0.0, (now_ns - own_ns) * 1e-9) if now_ns > 0 else 0.0
    level, message, values = assess(status, before, seconds, own_age, state_timeout, neighbours)
    return level, f'knode_swarm agent {name}', message, name, values


def diagnostics_to_cdr(stamp_ns: int, entries) -> bytes:
    """The serialized form of a DiagnosticArray stamped ``stamp_ns`` (frame_id empty) holding one
    DiagnosticStatus per ``(level, name, message, hardware_id, [(key, value), ...])``, built
    directly: a hosting process reports 100s of robots (rclpy's message objects cost 10x)."""
    buf = bytearray(CDR_LE)
    buf.extend(struct.pack('<iII', stamp_ns // 1_000_000_000, stamp_ns % 1_000_000_000, 1))
    buf.append(0)  # frame_id '' (length 1 above, its NUL here)
    cdr_pad(buf, 4)
    buf.extend(struct.pack('<I', len(entries)))
    for level, name, message, hardware_id, values in entries:
        buf.append(level)
        for text in (name, message, hardware_id):
            cdr_put_string(buf, text)
        cdr_pad(buf, 4)
        buf.extend(struct.pack('<I', len(values)))
        for key, value in values:
            cdr_put_string(buf, key)
            cdr_put_string(buf, value)
    return bytes(buf)


class HostedHealth:
    """Publishes :func:`assess` of every robot of a hosting ``agents`` node on ``/diagnostics``:
    one DiagnosticArray per report (serialized by :func:`diagnostics_to_cdr`) with one status per
    hosted robot, each as its lone agent's. ``name_of``: a robot's name (hardware_id), by
    default the default fleet's ``robot_<id>``."""

    def __init__(self, node, robot_ids, state_timeout: float, qos_profile, name_of=None):
        from diagnostic_msgs.msg import DiagnosticArray

        self.node = node
        self.robot_ids = [int(r) for r in robot_ids]
        self.names = {r: (name_of(r) if name_of is not None else f'robot_{r}') for r in self.robot_ids}
        self.state_timeout = float(state_timeout)
        self.publisher = node.create_publisher(DiagnosticArray, '/diagnostics', qos_profile)
        self._before: Dict[int, Dict[str, int]] = {r: {} for r in self.robot_ids}
        self._last_wall: Optional[float] = None

    def publish(
        self, reports: Dict[int, Tuple[Dict[str, Any], Optional[int], int]], now_ns: int, wall: float
    ) -> Dict[int, int]:
        """Publish one array from ``{robot: (status, own stamp ns or None, neighbours)}``;
        returns each robot's level."""
        seconds = wall - self._last_wall if self._last_wall is not None else 0.0
        entries = []
        for rid in self.robot_ids:
            status, own_ns, neighbours = reports[rid]
            entries.append(
                _entry(
                    self.names[rid],
                    status,
                    self._before[rid],
                    seconds,
                    now_ns,
                    own_ns,
                    self.state_timeout,
                    neighbours,
                )
            )
            self._before[rid] = dict(status['counters'])
        self._last_wall = wall
        self.publisher.publish(diagnostics_to_cdr(self.node.get_clock().now().nanoseconds, entries))
        return {rid: entry[0] for rid, entry in zip(self.robot_ids, entries)}


class AgentHealth(HostedHealth):
    """Publishes :func:`assess` of a lone agent node on ``/diagnostics``: a :class:`HostedHealth`
    of its one robot (the same report and bytes)."""

    def __init__(self, node, robot_id: int, state_timeout: float, qos_profile, name_of=None):
        super().__init__(node, [robot_id], state_timeout, qos_profile, name_of)
        self.robot_id = int(robot_id)

    def publish(
        self, status: Dict[str, Any], now_ns: int, own_ns: Optional[int], neighbours: int, wall: float
    ) -> int:
        """Publish one report; returns its level."""
        return super().publish({self.robot_id: (status, own_ns, neighbours)}, now_ns, wall)[self.robot_id]
