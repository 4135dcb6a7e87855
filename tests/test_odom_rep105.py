"""REP 105 Odometry: pose in the world frame, twist in the child (body) frame.

The ROS-free mapping (knode_swarm_ros/logic/contract/rep105.py) against a rotation written out
independently here, headings in every quadrant, and the message level: a foreign driver that
reports its real yaw and a body-frame twist decodes to the same state as this project's own
Odometry, in both the rclpy message and the serialized fast path.
"""

import math

import numpy as np
import pytest

from knode_swarm_ros.core.scenarios import Scenario
from knode_swarm_ros.logic.common import is_robot_frame, parse_robot_frame, robot_frame
from knode_swarm_ros.logic.contract.rep105 import (
    TWIST_FRAMES,
    fields_to_state,
    fields_to_states,
    rotate,
    rotate_inverse,
    state_to_fields,
)

# Yaws in all four quadrants, on the axes between them, and near the branch cut at +-pi.
YAWS = [0.0, 0.3, math.pi / 2, 2.0, math.pi, -2.5, -math.pi / 2, -0.4, 3.1, -3.1]


def _yaw_q(yaw):
    return np.array([0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)])


def _yaw_body(yaw, v):
    """World velocity v -> body frame of a robot at yaw (the 2D rotation by -yaw, written out)."""
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([c * v[0] + s * v[1], -s * v[0] + c * v[1], v[2]])


@pytest.mark.parametrize('yaw', YAWS)
def test_body_twist_round_trips_for_headings_in_every_quadrant(yaw):
    rng = np.random.default_rng(int(1000 * (yaw + 4)))
    q = _yaw_q(yaw)
    for _ in range(20):
        v = np.array([*rng.normal(size=2) * 3, 0.0])
        body = rotate_inverse(q, v)
        assert np.allclose(body, _yaw_body(yaw, v), rtol=0, atol=1e-14)
        assert np.allclose(rotate(q, body), v, rtol=0, atol=1e-14)
        # A robot driving forward along its heading reports (speed, 0, 0) in its body frame.
        ahead = 1.7 * np.array([math.cos(yaw), math.sin(yaw), 0.0])
        assert np.allclose(rotate_inverse(q, ahead), [1.7, 0.0, 0.0], rtol=0, atol=1e-14)
        # The decoding half of the mapping gives the world velocity back.
        z = fields_to_state((1.0, -2.0, 0.0), tuple(q), tuple(body), 'flock2d')
        assert np.allclose(z, [1.0, -2.0, v[0], v[1]], rtol=0, atol=1e-14)
        assert np.array_equal(
            fields_to_state((1.0, -2.0, 0.0), tuple(q), tuple(v), 'flock2d', 'world'), [1.0, -2.0, v[0], v[1]]
        )


def test_rotation_is_general_3d_and_handles_unnormalised_and_zero_quaternions():
    rng = np.random.default_rng(3)
    q = rng.normal(size=(50, 4))
    v = rng.normal(size=(50, 3))
    x, y, z, w = (q / np.linalg.norm(q, axis=1, keepdims=True)).T
    R = np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        1,
    )
    assert np.allclose(rotate(q, v), np.einsum('nij,nj->ni', R, v), atol=1e-13)
    assert np.allclose(rotate_inverse(q, rotate(q, v)), v, atol=1e-13)
    assert np.array_equal(rotate([0.0, 0.0, 0.0, 0.0], v[0]), v[0])  # zero quaternion = identity
    # The plain-float path the decoder uses agrees with the vectorised one.
    from knode_swarm_ros.logic.contract.rep105 import _rotate_one

    for qi, vi in zip(q[:10], v[:10]):
        assert np.allclose(_rotate_one(qi, vi), rotate(qi, vi), atol=1e-14)


def test_flock2d_mapping_is_exact_and_boids3d_twist_is_in_the_body_frame():
    rng = np.random.default_rng(4)
    for _ in range(200):
        z = rng.normal(size=4) * 10 ** rng.uniform(-8, 3)
        fields = state_to_fields(z, 'flock2d')
        assert fields[1] == (0.0, 0.0, 0.0, 1.0)
        assert np.array_equal(fields_to_state(*fields, 'flock2d'), z)  # bit for bit: parity needs it
    h = np.array([-0.6, 0.0, 0.8])  # heading with h_x < 0
    vel = 2.5 * h
    _, q, lin = state_to_fields(np.concatenate([[1.0, 2.0, 3.0], h]), 'boids3d', vel)
    assert np.allclose(lin, [2.5, 0.0, 0.0], atol=1e-14)  # forward along the body +x
    assert np.allclose(rotate(q, lin), vel, atol=1e-14)
    with pytest.raises(ValueError, match='twist_frame'):
        fields_to_state((0, 0, 0), (0, 0, 0, 1), (1, 0, 0), 'flock2d', 'odom')
    assert TWIST_FRAMES == ('body', 'world')


def test_fields_to_states_is_fields_to_state_bit_for_bit():
    rng = np.random.default_rng(6)
    m = 300
    positions = rng.normal(size=(m, 3)) * 10
    quaternions = rng.normal(size=(m, 4))
    quaternions[:100] /= np.linalg.norm(quaternions[:100], axis=1, keepdims=True)  # unit
    quaternions[100:110] = 0.0  # zero: the identity
    quaternions[110] = (0.0, 0.0, 0.0, 1.0)
    quaternions[111, 2] = np.nan
    linears = rng.normal(size=(m, 3))
    linears[112, 0] = np.inf
    own = [  # every state kind, in 2D and 3D
        Scenario('points3d', 3, 'position', 'velocity', 0.1, None),
        Scenario('double3d', 3, 'position_velocity', 'acceleration', 0.01, None),
        Scenario('unicycles2d', 2, 'position_heading', 'velocity', 0.05, None),
    ]
    for scenario in ['flock2d', 'boids3d', *own]:
        for frame in TWIST_FRAMES:
            one = np.array(
                [fields_to_state(*f, scenario, frame) for f in zip(positions, quaternions, linears)]
            )
            many = fields_to_states(positions, quaternions, linears, scenario, frame)
            assert many.shape == one.shape and np.array_equal(many, one, equal_nan=True), (scenario, frame)
    assert fields_to_states(np.zeros((0, 3)), np.zeros((0, 4)), np.zeros((0, 3)), 'flock2d').shape == (0, 4)
    with pytest.raises(ValueError, match='twist_frame'):
        fields_to_states(positions, quaternions, linears, 'flock2d', 'odom')


def test_child_frames_name_their_robot():
    assert robot_frame(3) == 'robot_3/base_link'
    for frame, rid in (
        ('robot_3/base_link', 3),
        ('robot_3', 3),
        ('robot_12/base_footprint', 12),
        ('robot_x', None),
        ('base_link', None),
        ('', None),
    ):
        assert parse_robot_frame(frame) == rid
    assert is_robot_frame('', 3) and is_robot_frame('robot_3/base_link', 3) and is_robot_frame('robot_3', 3)
    assert not is_robot_frame('robot_4/base_link', 3) and not is_robot_frame('base_link', 3)


def test_foreign_driver_with_real_yaw_decodes_like_our_own_odometry():
    import nav_msgs.msg  # noqa: F401  (a broken install must fail, not skip)
    from nav_msgs.msg import Odometry
    from rclpy.serialization import serialize_message

    from knode_swarm_ros.nodes.common.conversions import (
        odom_from_cdr,
        odom_to_cdr,
        odom_to_state,
        state_to_odom,
    )

    rng = np.random.default_rng(5)
    for yaw in YAWS:
        z = np.array([*rng.normal(size=2) * 4, *rng.normal(size=2)])
        ours = odom_to_state(state_to_odom(2, 7, z, 'flock2d'), 'flock2d')
        foreign = Odometry()  # e.g. a holonomic base facing `yaw`
        foreign.header.frame_id, foreign.child_frame_id = 'world', 'robot_2/base_footprint'
        foreign.pose.pose.position.x, foreign.pose.pose.position.y = z[0], z[1]
        o = foreign.pose.pose.orientation
        o.z, o.w = math.sin(yaw / 2), math.cos(yaw / 2)
        lin = foreign.twist.twist.linear
        lin.x, lin.y, _ = _yaw_body(yaw, [z[2], z[3], 0.0])
        foreign.twist.twist.angular.z = 0.7  # a turning robot: angular is not velocity
        assert np.allclose(odom_to_state(foreign, 'flock2d'), ours, rtol=0, atol=1e-14)
        ns, frame, got = odom_from_cdr(serialize_message(foreign), 'flock2d')
        assert frame == 'robot_2/base_footprint' and np.allclose(got, ours, rtol=0, atol=1e-14)
        # The same driver with a world-frame twist (not REP 105) is read with twist_frame='world'.
        lin.x, lin.y = z[2], z[3]
        assert np.array_equal(odom_to_state(foreign, 'flock2d', 'world'), z)
        assert np.array_equal(odom_from_cdr(serialize_message(foreign), 'flock2d', 'world')[2], z)
        assert np.array_equal(odom_from_cdr(odom_to_cdr(2, 7, z, 'flock2d'), 'flock2d')[2], z)
