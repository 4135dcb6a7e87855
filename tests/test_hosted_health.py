"""/diagnostics of a hosting ``agents`` process: one DiagnosticArray per report with
one status per hosted robot, each equal to the one its lone agent publishes on the same input."""

import numpy as np
import rclpy  # noqa: F401  (a broken install must fail, not skip)

from knode_swarm_ros.core.scenarios import get_scenario
from knode_swarm_ros.logic.agent.agent_logic import AgentConfig, AgentLogic
from knode_swarm_ros.logic.agent.hosted import HostedAgents
from knode_swarm_ros.logic.common import stamp_ns
from knode_swarm_ros.nodes.agent.health import OK, WARN, AgentHealth, HostedHealth

SEC = 1_000_000_000


class _Policy:
    def __init__(self):
        self.scenario, self.k, self.d_cr, self.tau, self.dt = (
            'flock2d',
            4,
            50.0,
            0,
            get_scenario('flock2d').dt,
        )
        self.command_limit = 1.0

    def __call__(self, Y, mask):
        return ((Y[..., 1:, :2] - Y[..., :1, :2]) * mask[..., 1:, None]).sum(axis=-2)


class _Node:
    """What the health publishers use of a node: a publisher that keeps what it is given, a clock."""

    class _Clock:
        def now(self):
            from rclpy.time import Time

            return Time(nanoseconds=3 * SEC)

    def __init__(self):
        self.sent = []

    def create_publisher(self, msg_type, topic, qos):
        assert topic == '/diagnostics' and msg_type.__name__ == 'DiagnosticArray'
        node = self

        class _Pub:
            def publish(self, msg):
                node.sent.append(msg)

        return _Pub()

    def get_clock(self):
        return self._Clock()


def _entries(msg):
    if isinstance(msg, bytes):  # the hosting process publishes serialized bytes
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy import serialization

        msg = serialization.deserialize_message(msg, DiagnosticArray)
    return [
        (e.level, e.name, e.hardware_id, e.message, [(kv.key, kv.value) for kv in e.values])
        for e in msg.status
    ]


def test_hosted_robots_report_in_one_array_what_their_lone_agents_report():
    policy = _Policy()
    ids, hosted = [0, 1, 2, 3], [1, 3]
    lone = {
        rid: AgentLogic(AgentConfig(rid, ids, 'realtime', state_timeout=0.5, control_rate=100.0), policy)
        for rid in hosted
    }
    host = HostedAgents(
        hosted, AgentConfig(1, ids, 'realtime', state_timeout=0.5, control_rate=100.0), policy
    )
    for s in range(3):
        ns = stamp_ns(s, policy.dt)
        for r in ids:
            if r == 3 and s == 2:
                continue  # robot 3's own state stops: stale at the report
            z = np.array([r * 0.5 + s, 0.2 * r, 1.0, 0.0])
            for logic in lone.values():
                logic.receive(r, ns, z, ns, wall=s)
                logic.realtime_poll(ns, s + 1.0)
            host.receive(r, ns, z, ns, wall=s)
            host.realtime_poll(ns, s + 1.0)
    now = stamp_ns(2, policy.dt) + SEC  # a second later: every own state older than state_timeout
    node_h, node_l = _Node(), _Node()
    health = HostedHealth(node_h, hosted, 0.5, None)
    singles = {rid: AgentHealth(node_l, rid, 0.5, None) for rid in hosted}
    for wall in (10.0, 12.0):  # the second report has rates over 2 s
        reports = {
            rid: (
                host.logics[rid].status(),
                host.logics[rid].newest_ns.get(rid),
                host.logics[rid].last_command.neighbours,
            )
            for rid in hosted
        }
        levels = health.publish(reports, now if wall > 10 else stamp_ns(2, policy.dt), wall)
        for rid, logic in lone.items():
            singles[rid].publish(
                logic.status(),
                now if wall > 10 else stamp_ns(2, policy.dt),
                logic.newest_ns.get(rid),
                logic.last_command.neighbours,
                wall,
            )
    assert len(node_h.sent) == 2 and all(len(_entries(msg)) == 2 for msg in node_h.sent)
    assert len(node_l.sent) == 4
    for n, msg in enumerate(node_h.sent):
        assert _entries(msg) == [e for m in node_l.sent[2 * n : 2 * n + 2] for e in _entries(m)]
    first = _entries(node_h.sent[0])
    assert [e[1] for e in first] == ['knode_swarm agent robot_1', 'knode_swarm agent robot_3']
    assert [e[0] for e in first] == [bytes([OK])] * 2
    ages = [dict(e[4])['own_state_age_s'] for e in first]
    assert ages == ['0.000', '0.010']  # robot 3's own state of step 1 is one step old
    assert levels == {1: WARN, 3: WARN}  # a second later both own states are stale
    assert all('stale' in e[3] for e in _entries(node_h.sent[1]))
    # a named fleet's robots report under their names (the monitor maps them back to ids)
    named = HostedHealth(_Node(), hosted, 0.5, None, {1: 'cf1', 3: 'tb4_3'}.get)
    named.publish(reports, now, 14.0)
    assert [(e[1], e[2]) for e in _entries(named.node.sent[0])] == [
        ('knode_swarm agent cf1', 'cf1'),
        ('knode_swarm agent tb4_3', 'tb4_3'),
    ]


def test_serialized_diagnostics_equal_rclpys():
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from rclpy import serialization

    from knode_swarm_ros.nodes.agent.health import diagnostics_to_cdr

    cases = [
        [],
        [(0, 'a', '', 'r', [])],
        [
            (
                2,
                'knode_swarm agent robot_12',
                'no own state heard yet',
                'robot_12',
                [('neighbours', '0'), ('heard', '3/4'), ('x' * 7, 'ünï ✓')],
            )
        ]
        * 3,
        [(1, 'n' * k, 'm' * (k % 5), 'h' * (k % 3), [('k' * (k % 4), 'v' * k)] * (k % 3)) for k in range(9)],
    ]
    for stamp in (0, 1_500_000_007, 12_345_678_901_234):
        for entries in cases:
            msg = DiagnosticArray()
            msg.header.stamp.sec, msg.header.stamp.nanosec = stamp // SEC, stamp % SEC
            msg.status = [
                DiagnosticStatus(
                    level=bytes([lv]),
                    name=n,
                    message=m,
                    hardware_id=h,
                    values=[KeyValue(key=k, value=v) for k, v in vals],
                )
                for lv, n, m, h, vals in entries
            ]
            ours = diagnostics_to_cdr(stamp, entries)
            assert len(ours) == len(serialization.serialize_message(msg))
            assert serialization.deserialize_message(ours, DiagnosticArray) == msg
