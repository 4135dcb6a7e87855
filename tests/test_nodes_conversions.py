"""The one state/command <-> message mapping (knode_swarm_ros/nodes/common/conversions.py).

Message classes are plain Python: no rclpy.init, no ROS graph.
"""

import math

import nav_msgs.msg  # noqa: F401  (a broken install must fail, not skip)
import numpy as np
import pytest

from knode_swarm_ros.logic.contract.orientation import heading_to_quaternion, quaternion_to_heading
from knode_swarm_ros.logic.contract.rep105 import rotate
from knode_swarm_ros.nodes.common.conversions import (
    command_msg_type,
    command_to_msg,
    msg_to_command,
    odom_to_state,
    state_to_odom,
    time_msg,
    time_ns,
    yaw_quaternion,
)


def _rotation(x, y, z, w):
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def _headings():
    rng = np.random.default_rng(0)
    h = rng.normal(size=(500, 3))
    special = [
        [1, 0, 0],
        [-1, 0, 0],
        [0, 1, 0],
        [0, 0, -1],
        [-1, 1e-9, 0],
        [-1, 0, 1e-12],
        [-1 + 1e-12, 1e-6, 0],
        [1e-3, 0, 0],
        [-1e-3, 1e-3, 0],
    ]
    h = np.concatenate([h, np.array(special, dtype=np.float64)])
    return h / np.linalg.norm(h, axis=1, keepdims=True)


def test_heading_quaternion_rotates_x_onto_h_and_round_trips():
    for h in _headings():
        q = heading_to_quaternion(h)
        assert math.isclose(sum(c * c for c in q), 1.0, rel_tol=1e-12)
        R = _rotation(*q)
        assert np.allclose(R @ R.T, np.eye(3), atol=1e-12)
        assert np.allclose(R[:, 0], h, atol=1e-14)  # +x goes onto h
        assert np.abs(quaternion_to_heading(q) - h).max() <= 1e-15
    assert np.array_equal(heading_to_quaternion([0, 0, 0]), [0.0, 0.0, 0.0, 1.0])
    assert np.array_equal(quaternion_to_heading([0, 0, 0, 1]), [1.0, 0.0, 0.0])


def test_yaw_quaternion():
    x, y, z, w = yaw_quaternion(0.0, 2.0)
    assert np.allclose(_rotation(x, y, z, w)[:, 0], [0, 1, 0])
    assert yaw_quaternion(0.0, 0.0) == (0.0, 0.0, 0.0, 1.0)


def test_time_messages_are_exact_nanoseconds():
    for ns in (0, 1, 999_999_999, 1_000_000_000, 16_666_667, 123_456_789_012_345):
        assert time_ns(time_msg(ns)) == ns
    with pytest.raises(ValueError):
        time_msg(-1)


def test_flock2d_odometry_round_trip_and_fields():
    z = np.array([1.25, -3.5, 0.1, -2.0]) + 1e-13
    msg = state_to_odom(4, 1_230_000_000, z, 'flock2d')
    assert msg.header.frame_id == 'world' and msg.child_frame_id == 'robot_4/base_link'  # REP 105
    assert time_ns(msg.header.stamp) == 1_230_000_000
    p, v, o = msg.pose.pose.position, msg.twist.twist.linear, msg.pose.pose.orientation
    # A holonomic point mass reports a body that does not turn: the child frame is parallel to
    # the world frame, so the body-frame twist is the world velocity, exactly.
    assert (o.x, o.y, o.z, o.w) == (0.0, 0.0, 0.0, 1.0)
    assert (p.x, p.y, p.z, v.x, v.y, v.z) == (z[0], z[1], 0.0, z[2], z[3], 0.0)
    out = odom_to_state(msg, 'flock2d')
    assert out.dtype == np.float64 and np.array_equal(out, z)  # bit for bit


def test_boids3d_odometry_round_trip():
    rng = np.random.default_rng(1)
    for h in _headings()[::7]:
        z = np.concatenate([rng.uniform(-5, 5, 3), h])
        msg = state_to_odom(0, 5, z, 'boids3d', velocity=np.array([1.0, 2.0, 3.0]))
        out = odom_to_state(msg, 'boids3d')
        assert np.array_equal(out[:3], z[:3])
        assert np.abs(out[3:] - z[3:]).max() <= 1e-15
        # The informative velocity travels in the child frame (REP 105): the orientation maps it back.
        o, lin = msg.pose.pose.orientation, msg.twist.twist.linear
        back = rotate([o.x, o.y, o.z, o.w], [lin.x, lin.y, lin.z])
        assert np.allclose(back, [1.0, 2.0, 3.0], rtol=0, atol=1e-14)


def test_commands_round_trip():
    from geometry_msgs.msg import AccelStamped, TwistStamped

    assert command_msg_type('flock2d') is AccelStamped and command_msg_type('boids3d') is TwistStamped
    msg = command_to_msg(42, [1.5, -2.0], 'flock2d')
    assert isinstance(msg, AccelStamped) and msg.accel.linear.z == 0.0 and msg.header.frame_id == 'world'
    ns, u = msg_to_command(msg, 'flock2d')
    assert ns == 42 and np.array_equal(u, [1.5, -2.0])
    msg = command_to_msg(7, [0.1, 0.2, 0.3], 'boids3d')
    assert isinstance(msg, TwistStamped)
    ns, u = msg_to_command(msg, 'boids3d')
    assert ns == 7 and np.array_equal(u, [0.1, 0.2, 0.3])


def test_serialized_odometry_equals_rclpy_serialization_and_decodes_the_same():
    from nav_msgs.msg import Odometry
    from rclpy import serialization

    from knode_swarm_ros.nodes.common.conversions import CdrError, odom_from_cdr, odom_to_cdr

    rng = np.random.default_rng(2)
    for scenario, d in (('flock2d', 4), ('boids3d', 6)):
        for robot in (0, 7, 12, 345, 67890):
            for ns in (0, 1, 16_666_667, 1_234_567_890_123):
                z = rng.normal(size=d)
                if d == 6:
                    z[3:] /= np.linalg.norm(z[3:])
                v = rng.normal(size=3) if d == 6 else None
                msg = state_to_odom(robot, ns, z, scenario, v)
                data = serialization.serialize_message(msg)
                ours = odom_to_cdr(robot, ns, z, scenario, v)
                # rclpy leaves alignment padding uninitialised: compare lengths and decoded messages.
                assert len(ours) == len(data)
                assert serialization.deserialize_message(ours, Odometry) == msg
                got_ns, frame, got = odom_from_cdr(data, scenario)
                assert got_ns == ns and frame == f'robot_{robot}/base_link'
                assert np.array_equal(got, odom_to_state(msg, scenario))
    # A message from elsewhere (other frame names, covariances set) decodes the same way too.
    msg = state_to_odom(1, 5, np.array([1.0, 2.0, 3.0, 4.0]), 'flock2d')
    msg.header.frame_id = 'odom_frame_with_a_longer_name'
    msg.child_frame_id = ''
    msg.pose.covariance[0] = 0.5
    got_ns, frame, got = odom_from_cdr(serialization.serialize_message(msg), 'flock2d')
    assert (got_ns, frame) == (5, '') and np.array_equal(got, [1.0, 2.0, 3.0, 4.0])
    data = serialization.serialize_message(msg)
    for bad in (b'', b'garbage', data[:-8], data + b'\x00' * 8, b'\x00\x07' + data[2:]):
        with pytest.raises(CdrError):
            odom_from_cdr(bad, 'flock2d')


def test_markers_show_robots_headings_and_links_within_d_cr():
    from knode_swarm_ros.core.scenarios import get_scenario
    from knode_swarm_ros.nodes.common.markers import swarm_markers

    states = np.array([[0.0, 0.0, 1.0, 0.0], [1.0, 0.0, 0.0, 1.0], [5.0, 0.0, 0.0, 0.0]])
    out = swarm_markers(states, get_scenario('flock2d'), 1.5, 123)
    by_ns = {}
    for m in out.markers:
        by_ns.setdefault(m.ns, []).append(m)
    assert len(by_ns['robots'][0].points) == 3 and by_ns['robots'][0].header.frame_id == 'world'
    assert len(by_ns['headings']) == 3
    assert len(by_ns['links'][0].points) == 2  # only robots 0 and 1 are within 1.5
    assert swarm_markers(states, get_scenario('flock2d'), 0.0, 1).markers[-1].points == []


def test_serialized_commands_equal_rclpys_serialization():
    # the hosting agents node publishes commands as bytes built by command_to_cdr; rclpy leaves
    # alignment padding uninitialised: lengths and decoded messages
    from rclpy import serialization

    from knode_swarm_ros.nodes.common.conversions import command_to_cdr

    rng = np.random.default_rng(3)
    for scenario, m in (('flock2d', 2), ('boids3d', 3)):
        for ns in (0, 1, 999_999_999, 1_000_000_000, 12_345_678_901_234):
            u = rng.normal(scale=5.0, size=m)
            msg = command_to_msg(ns, u, scenario)
            ours = command_to_cdr(ns, u, scenario)
            assert len(ours) == len(serialization.serialize_message(msg))
            back = serialization.deserialize_message(ours, command_msg_type(scenario))
            assert back == msg and msg_to_command(back, scenario)[0] == ns
            assert np.array_equal(msg_to_command(back, scenario)[1], u)
    with pytest.raises(ValueError, match='before time 0'):
        command_to_cdr(-1, [0.0, 0.0], 'flock2d')


def test_serialized_strings_decode_as_rclpys():
    from rclpy import serialization
    from std_msgs.msg import String

    from knode_swarm_ros.nodes.common.conversions import string_to_cdr

    for text in ('', 'a', 'abc', 'abcd', '{"id":3,"ready":true}', 'ünïcödé ✓' * 7):
        ours = string_to_cdr(text)
        assert len(ours) == len(serialization.serialize_message(String(data=text)))
        assert serialization.deserialize_message(ours, String).data == text
