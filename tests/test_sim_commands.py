"""The simulator's command path at scale: commands read from their serialized bytes,
and the lockstep advance decided by a count instead of a scan of every robot."""

import random

import numpy as np
import pytest

from knode_swarm_ros.logic.simulator.swarm_sim import SwarmSim
from knode_swarm_ros.nodes.common.conversions import (
    CdrError,
    command_from_cdr,
    command_msg_type,
    command_to_cdr,
    command_to_msg,
    msg_to_command,
)


def _typed(data: bytes, scenario: str):
    """What the simulator got before: rclpy's deserialization, then msg_to_command (None: refused)."""
    from rclpy import serialization

    try:
        return msg_to_command(serialization.deserialize_message(data, command_msg_type(scenario)), scenario)
    except Exception:  # rclpy raises RMWError (a RuntimeError) for bytes it cannot read
        return None


def _raw(data: bytes, scenario: str):
    try:
        return command_from_cdr(data, scenario)
    except CdrError:
        return None


def _same(a, b) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return a[0] == b[0] and np.array_equal(a[1], b[1], equal_nan=True) and b[1].dtype == np.float64


@pytest.mark.parametrize('scenario,m', [('flock2d', 2), ('boids3d', 3)])
def test_raw_commands_decode_as_rclpys_typed_messages(scenario, m):
    from rclpy import serialization

    rng = np.random.default_rng(4)
    for ns in (0, 1, 999_999_999, 12_345_678_901_234):
        u = rng.normal(scale=5.0, size=m)
        for data in (
            command_to_cdr(ns, u, scenario),
            serialization.serialize_message(command_to_msg(ns, u, scenario)),
        ):
            got = command_from_cdr(data, scenario)
            assert got[0] == ns and np.array_equal(got[1], u) and _same(got, _typed(data, scenario))
    nan = command_to_cdr(
        5, [np.nan, np.inf, -np.inf][:m], scenario
    )  # decoded; the simulator drops it as non_finite
    assert _same(_raw(nan, scenario), _typed(nan, scenario))


@pytest.mark.parametrize('scenario,m', [('flock2d', 2), ('boids3d', 3)])
def test_raw_commands_refuse_exactly_what_rclpy_refuses_on_hostile_bytes(scenario, m):
    rng = random.Random(7)
    refused = 0
    for n in range(1500):
        good = bytearray(
            command_to_cdr(rng.randrange(10**12), np.random.default_rng(n).normal(size=m), scenario)
        )
        kind = n % 5
        if kind == 0:  # truncated
            data = good[: rng.randrange(len(good) + 1)]
        elif kind == 1:  # bytes flipped anywhere
            data = good
            for _ in range(rng.randrange(1, 3)):
                data[rng.randrange(len(data))] = rng.randrange(256)
        elif kind == 2:  # trailing garbage
            data = good + bytes(rng.randrange(256) for _ in range(rng.randrange(1, 12)))
        elif kind == 3:  # another encapsulation (byte order, XCDR2), sometimes truncated too
            data = good
            data[rng.randrange(4)] = rng.randrange(16)
            if rng.random() < 0.5:
                data = data[: rng.randrange(len(data) + 1)]
        else:  # a lying frame_id length
            data = good
            data[12:16] = rng.randrange(0, 1 << rng.choice((6, 32))).to_bytes(4, 'little')
        data = bytes(data)
        typed = _typed(data, scenario)
        refused += typed is None
        assert _same(_raw(data, scenario), typed), data.hex()
    assert 300 < refused < 1200  # both outcomes were exercised


def test_undecodable_commands_are_dropped_and_counted():
    from knode_swarm_ros.logic.simulator.run_phases import LifecycleConfig, SimLifecycle

    class Out:
        def __init__(self):
            self.logs = []

        def log(self, level, text):
            self.logs.append((level, text))

        def publish_frame(self): ...
        def publish_status(self): ...
        def start_physics(self, period): ...
        def stop_physics(self): ...
        def finish(self, code): ...

    sim = SwarmSim('flock2d', np.zeros((3, 4)), 0.05, 'realtime')
    out = Out()
    life = SimLifecycle(sim, LifecycleConfig(steps=10, mode='realtime'), out, {})
    assert life.on_malformed_command(1, 'truncated') == 'malformed'
    life.on_malformed_command(2, 'bad frame_id')
    assert sim.counters.malformed == 2 and sim.counters.accepted == 0
    assert sim.report()['counters']['malformed'] == 2
    assert out.logs[0][0] == 'warn' and "robot 1's topic" in out.logs[0][1]


def test_the_count_of_robots_answered_or_lost_equals_a_scan():
    rng = random.Random(11)
    n = 12
    sim = SwarmSim('flock2d', np.stack([np.array([i, 0.0, 0.0, 0.0]) for i in range(n)]), 0.05, 'lockstep')
    for _ in range(3000):
        op = rng.random()
        if op < 0.6:  # a command for the current step, an old one, or a repeat
            s = sim.step - (rng.random() < 0.1)
            sim.offer(rng.randrange(n), int(round(max(s, 0) * 0.05 * 1e9)), [0.1, 0.2])
        elif op < 0.7:
            sim.declare_lost(rng.sample(range(n), rng.randrange(1, 3)))
        elif op < 0.75:
            sim.declare_lost(sim.waiting()[:2])
        if sim.can_advance() != (not sim.waiting()):
            raise AssertionError(f'step {sim.step}: answered {sorted(sim.answered)}, lost {sorted(sim.lost)}')
        if sim.can_advance() and rng.random() < 0.8:
            sim.advance()
    assert sim.step > 50 and sim.counters.rejoined > 0 and sim.counters.lost_events > 0


def test_distinct_commands_are_counted_once_whatever_is_re_sent_or_overtaken():
    sim = SwarmSim('flock2d', np.zeros((3, 4)), 0.05, 'realtime')
    ns = [int(round(s * 0.05 * 1e9)) for s in range(4)]
    for s in range(3):
        for r in range(3):
            sim.offer(r, ns[s], [0.1, 0.0])
        sim.offer(0, ns[s], [0.2, 0.0])  # robot 0 re-sends each step (a re-opened tick)
        sim.advance()
    sim.offer(1, ns[1], [0.3, 0.0])  # an old step again: stale, not new
    sim.offer(2, ns[3], [0.3, 0.0])  # the current step
    assert sim.counters.commanded == 3 * 3 + 1
    assert sim.counters.accepted == 3 * 4 + 1 and sim.counters.stale == 1
