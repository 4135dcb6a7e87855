"""Per-agent health on ``/diagnostics`` (diagnostic_msgs/DiagnosticArray), every status period.

One DiagnosticStatus per robot (a lone agent publishes an array with its own; a process hosting
several robots, :class:`HostedHealth`, one array with one status per hosted robot, the
ROS-idiomatic form of an aggregated publisher), name ``knode_swarm agent robot_<id>``, hardware_id
``robot_<id>``, with the key values: neighbours (real rows of the last Y), heard (robots heard
at least once) / robots, own state age (s, on the node's clock), command rate (Hz, since the
previous report), saturated share (commands clipped at the command limit since the previous
report), drops by reason (totals), link counters when the link model is on, lifecycle state.

Level: ERROR when no own state has been heard yet while active; WARN when the own state is
older than ``state_timeout`` (the agent is sending stops), when the policy saturated more than
half of the commands since the previous report, or when the agent is not active; else OK.
:func:`assess` is the ROS-free judgement; :class:`AgentHealth` only builds the message.
"""
from __future__ import annotations

from typing import Any, Dict, List, Optional, Tuple

from .agent_logic import DROP_REASONS

__all__ = ['assess', 'AgentHealth', 'HostedHealth', 'OK', 'WARN', 'ERROR']

OK, WARN, ERROR = 0, 1, 2
SATURATION_WARN = 0.5


def assess(status: Dict[str, Any], counts_before: Dict[str, int], seconds: float, own_age: Optional[float],
           state_timeout: float, neighbours: int) -> Tuple[int, str, List[Tuple[str, str]]]:
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
    values = [('neighbours', str(neighbours)), ('heard', f"{status['heard']}/{status['robots']}"),
              ('own_state_age_s', 'none' if own_age is None else f'{own_age:.3f}'),
              ('command_rate_hz', f'{rate:.2f}'), ('saturated_share', f'{share:.3f}'),
              ('lifecycle', status.get('lifecycle', 'active'))]
    values += [(f'drops_{reason}', str(c[reason])) for reason in DROP_REASONS]
    for key, value in (status.get('link') or {}).items():
        values.append((f'link_{key}', str(value)))
    return level, '; '.join(problems) if problems else 'ok', values


def _entry(robot_id: int, status: Dict[str, Any], before: Dict[str, int], seconds: float, now_ns: int,
           own_ns: Optional[int], state_timeout: float, neighbours: int):
    """(level, DiagnosticStatus) of one robot's report (see :func:`assess`)."""
    from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
    own_age = None if own_ns is None else max(0.0, (now_ns - own_ns) * 1e-9) if now_ns > 0 else 0.0
    level, message, values = assess(status, before, seconds, own_age, state_timeout, neighbours)
    entry = DiagnosticStatus(level=bytes([level]), name=f'knode_swarm agent robot_{robot_id}',
                             message=message, hardware_id=f'robot_{robot_id}')
    entry.values = [KeyValue(key=k, value=v) for k, v in values]
    return level, entry


class AgentHealth:
    """Publishes :func:`assess` of an agent node on ``/diagnostics``."""

    def __init__(self, node, robot_id: int, state_timeout: float, qos_profile):
        from diagnostic_msgs.msg import DiagnosticArray
        self.node = node
        self.robot_id = int(robot_id)
        self.state_timeout = float(state_timeout)
        self.publisher = node.create_publisher(DiagnosticArray, '/diagnostics', qos_profile)
        self._before: Dict[str, int] = {}
        self._last_wall: Optional[float] = None

    def publish(self, status: Dict[str, Any], now_ns: int, own_ns: Optional[int], neighbours: int,
                wall: float) -> int:
        """Publish one report; returns its level."""
        from diagnostic_msgs.msg import DiagnosticArray
        seconds = wall - self._last_wall if self._last_wall is not None else 0.0
        level, entry = _entry(self.robot_id, status, self._before, seconds, now_ns, own_ns, self.state_timeout,
                              neighbours)
        self._before, self._last_wall = dict(status['counters']), wall
        msg = DiagnosticArray()
        msg.header.stamp = self.node.get_clock().now().to_msg()
        msg.status = [entry]
        self.publisher.publish(msg)
        return level


class HostedHealth:
    """Publishes :func:`assess` of every robot of a hosting ``agents`` node on ``/diagnostics``:
    one DiagnosticArray per report with one status per hosted robot, each as its lone agent's."""

    def __init__(self, node, robot_ids, state_timeout: float, qos_profile):
        from diagnostic_msgs.msg import DiagnosticArray
        self.node = node
        self.robot_ids = [int(r) for r in robot_ids]
        self.state_timeout = float(state_timeout)
        self.publisher = node.create_publisher(DiagnosticArray, '/diagnostics', qos_profile)
        self._before: Dict[int, Dict[str, int]] = {r: {} for r in self.robot_ids}
        self._last_wall: Optional[float] = None

    def publish(self, reports: Dict[int, Tuple[Dict[str, Any], Optional[int], int]], now_ns: int,
                wall: float) -> Dict[int, int]:
        """Publish one array from ``{robot: (status, own stamp ns or None, neighbours)}``;
        returns each robot's level."""
        from diagnostic_msgs.msg import DiagnosticArray
        seconds = wall - self._last_wall if self._last_wall is not None else 0.0
        msg = DiagnosticArray()
        msg.header.stamp = self.node.get_clock().now().to_msg()
        levels = {}
        for rid in self.robot_ids:
            status, own_ns, neighbours = reports[rid]
            levels[rid], entry = _entry(rid, status, self._before[rid], seconds, now_ns, own_ns, self.state_timeout,
                                        neighbours)
            self._before[rid] = dict(status['counters'])
            msg.status.append(entry)
        self._last_wall = wall
        self.publisher.publish(msg)
        return levels
