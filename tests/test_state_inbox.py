"""States taken on demand (knode_swarm_ros/nodes/common/state_inbox.py) and the Odometry
decoder it reads with (odom_batch.OdomBatch): known messages decoded, each robot's queue
taken in order, malformed bytes and another robot's Odometry dropped and counted.

The decoder without ROS; the inbox in this process on an isolated ROS domain."""

import struct
import time

import numpy as np
import pytest
import rclpy
import yaml
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.serialization import serialize_message

from knode_swarm_ros.logic.contract.fleet import default_fleet, load_fleet
from knode_swarm_ros.nodes.common import qos
from knode_swarm_ros.nodes.common.conversions import (
    CdrError,
    fields_to_cdr,
    odom_fields_from_cdr,
    odom_to_cdr,
    pose_to_cdr,
)
from knode_swarm_ros.nodes.common.odom_batch import OdomBatch

WAIT_S = 30.0


def _foreign_odometry(ns, x, y, yaw, child='robot_2/base_footprint'):
    """An Odometry as rclpy serializes it: a real yaw, covariances, a body twist."""
    msg = Odometry()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(ns, 1_000_000_000)
    msg.header.frame_id, msg.child_frame_id = 'odom', child
    msg.pose.pose.position.x, msg.pose.pose.position.y = x, y
    msg.pose.pose.orientation.z, msg.pose.pose.orientation.w = np.sin(yaw / 2), np.cos(yaw / 2)
    msg.pose.covariance = [0.01 * i for i in range(36)]
    msg.twist.twist.linear.x, msg.twist.twist.linear.y = 0.4, -0.1
    msg.twist.twist.angular.z = 0.3
    msg.twist.covariance = [-0.02 * i for i in range(36)]
    return serialize_message(msg)


def _full(data):
    """What the full decoder reads (stamp, child, pose, linear), or None where it refuses."""
    try:
        ns, child, pose, linear, _ = odom_fields_from_cdr(data)
    except CdrError:
        return None
    return ns, child, pose, linear


def _batch(fields, j):
    if fields.bad[j]:
        return None
    return int(fields.stamps[j]), fields.children[j], tuple(fields.poses[j]), tuple(fields.linears[j])


def _big_endian(ns, frame, child, pose, linear):
    """An Odometry in big-endian CDR (another DDS may send one; rmw_fastrtps sends little-endian)."""
    buf = bytearray(b'\x00\x00\x00\x00') + struct.pack('>iI', *divmod(ns, 10**9))
    for text in (frame, child):
        buf += b'\x00' * (-(len(buf) - 4) % 4) + struct.pack('>I', len(text) + 1) + text.encode() + b'\x00'
    buf += b'\x00' * (-(len(buf) - 4) % 8)
    return bytes(
        buf + struct.pack('>7d', *pose) + bytes(8 * 36) + struct.pack('>6d', *linear, 0, 0, 0) + bytes(8 * 36)
    )


def test_odom_batch_reads_what_the_full_decoder_reads():
    rng = np.random.default_rng(0)
    messages = [odom_to_cdr(3, 10**9 * k + 7, rng.normal(size=4), 'flock2d') for k in range(20)]
    messages += [_foreign_odometry(5 * 10**8 * k, *rng.normal(size=3)) for k in range(20)]  # other frames
    messages += [odom_to_cdr(12, 10**6 * k, rng.normal(size=4), 'flock2d') for k in range(5)]  # longer name
    messages += [fields_to_cdr(3, 99, (1, 2, 3), (0, 0, 0, 1), (4, 5, 6), (0, 0, 0), child_frame_id='')]
    messages += [odom_to_cdr(3, 2**31 * 10**9 - 1, np.full(4, np.nan), 'flock2d')]  # the largest stamp
    messages += [_big_endian(7, 'world', 'robot_3/base_link', np.arange(7.0), [0.5, -1.0, 2.0])]
    batch = OdomBatch(4)
    # the same messages on four topics, in batches of several sizes: the first of a layout is
    # read in full, those after it from the layout kept, and both read as the full decoder does
    topics = rng.integers(0, 4, size=len(messages))
    for size in (1, 7, len(messages)):
        for at in range(0, len(messages), size):
            fields = batch.read(topics[at : at + size], messages[at : at + size])
            for j, data in enumerate(messages[at : at + size]):
                expected, got = _full(data), _batch(fields, j)
                assert (got is None) == (expected is None)
                if got is not None:  # NaN != NaN: compare the bits
                    assert got[:2] == expected[:2]
                    bits = np.array(got[2] + got[3]).view(np.int64)
                    assert np.array_equal(bits, np.array(expected[2] + expected[3]).view(np.int64))


def test_odom_batch_refuses_what_the_full_decoder_refuses():
    batch = OdomBatch(1)
    good = odom_to_cdr(3, 10**9, np.ones(4), 'flock2d')
    batch.read([0], [good])
    changed_frame = good.replace(b'robot_3', b'robot_4')
    for bad in (good[:-8], good + b'\x00' * 8, b'\x00\x01\x00\x00junk', b'', b'\x00\x05' + good[2:]):
        fields = batch.read([0, 0, 0], [good, bad, good])
        assert fields.bad.tolist() == [False, True, False]
        assert fields.stamps.tolist() == [10**9, 0, 10**9]  # a bad message spoils nothing after it
    assert batch.read([0, 0], [changed_frame, good]).children == ['robot_4/base_link', 'robot_3/base_link']


@pytest.fixture
def ros(monkeypatch, ros_domain_id):
    """An rclpy context on a claimed domain, localhost only, and a node publishing into it."""
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=ros_domain_id)
    node = Node('test_io', context=context)
    yield context, node
    node.destroy_node()
    rclpy.try_shutdown(context=context)


def _publishers(node, msg_type, topics, inbox):
    pubs = [node.create_publisher(msg_type, topic, qos.ODOM) for topic in topics]
    deadline = time.monotonic() + WAIT_S
    while time.monotonic() < deadline and not all(p.get_subscription_count() for p in pubs):
        time.sleep(0.05)
    assert all(p.get_subscription_count() for p in pubs), 'the inbox never matched'
    return pubs


def _take_until(inbox, count):
    """The inbox's takes until ``count`` messages (or the deadline): concatenated fields."""
    takes = []
    deadline = time.monotonic() + WAIT_S
    while time.monotonic() < deadline and sum(len(t.robots) for t in takes) < count:
        takes.append(inbox.take())
        time.sleep(0.05)
    return {field: np.concatenate([getattr(t, field) for t in takes]) for field in takes[0]._fields}


@pytest.mark.ros
def test_the_inbox_takes_each_robots_odometry_in_order_and_drops_the_bad(ros):
    from knode_swarm_ros.nodes.common.state_inbox import StateInbox

    context, node = ros
    fleet = default_fleet([0, 1, 2])
    inbox = StateInbox(context, fleet, depth=10, name='inbox')
    try:
        pubs = _publishers(node, Odometry, [fleet.state_topic(r) for r in fleet.ids], inbox)
        rng = np.random.default_rng(1)
        sent = {r: [] for r in fleet.ids}
        for k in range(4):
            for r, pub in zip(fleet.ids, pubs):
                z = rng.normal(size=4)
                pub.publish(odom_to_cdr(r, 10**9 + k * 10**7, z, 'flock2d'))
                sent[r].append((10**9 + k * 10**7, z))
        pubs[0].publish(b'\x00\x01\x00\x00 not an Odometry')  # malformed: dropped
        pubs[1].publish(odom_to_cdr(2, 5, np.ones(4), 'flock2d'))  # robot 2's frame on robot 1's topic
        got = _take_until(inbox, 12)
        deadline = time.monotonic() + WAIT_S  # the two bad ones come after, on their topics
        while time.monotonic() < deadline and inbox.malformed + inbox.foreign < 2:
            assert len(inbox.take().robots) == 0
            time.sleep(0.05)
        assert (inbox.malformed, inbox.foreign) == (1, 1)
        assert len(inbox.take().robots) == 0  # all taken
    finally:
        inbox.destroy()
    assert len(got['robots']) == 12
    for r in fleet.ids:
        mine = got['robots'] == r
        assert got['stamps'][mine].tolist() == [ns for ns, _ in sent[r]]  # oldest first
        z = np.array([z for _, z in sent[r]])
        assert np.array_equal(got['positions'][mine], np.c_[z[:, :2], np.zeros(4)])
        assert np.array_equal(got['linears'][mine], np.c_[z[:, 2:], np.zeros(4)])
        assert np.array_equal(got['quaternions'][mine], np.tile([0.0, 0.0, 0.0, 1.0], (4, 1)))


@pytest.mark.ros
def test_the_inbox_takes_a_fleets_poses(ros, tmp_path):
    from geometry_msgs.msg import PoseStamped

    from knode_swarm_ros.nodes.common.state_inbox import StateInbox

    context, node = ros
    path = tmp_path / 'fleet.yaml'
    path.write_text(
        yaml.safe_dump(
            {
                'robots': {'cf7': {'id': 7}, 'cf2': {'id': 2}},
                'state': {'topic': '/mocap/{name}/pose', 'type': 'pose'},
            }
        )
    )
    fleet = load_fleet(str(path))
    inbox = StateInbox(context, fleet, depth=50, name='inbox')
    try:
        pubs = _publishers(node, PoseStamped, ['/mocap/cf2/pose', '/mocap/cf7/pose'], inbox)
        for k in range(25):
            for rid, pub in zip((2, 7), pubs):
                pub.publish(pose_to_cdr(k * 10**7, (rid, k, 0.5), (0.0, 0.0, 0.6, 0.8)))
        pubs[1].publish(b'\x00\x01\x00\x00\x01\x00\x00\x00')  # truncated: dropped
        got = _take_until(inbox, 50)
        deadline = time.monotonic() + WAIT_S
        while time.monotonic() < deadline and inbox.malformed < 1:
            inbox.take()
            time.sleep(0.05)
        assert inbox.malformed == 1 and inbox.foreign == 0
    finally:
        inbox.destroy()
    assert sorted(got['robots'].tolist()) == [2] * 25 + [7] * 25
    for rid in (2, 7):
        mine = got['robots'] == rid
        assert got['stamps'][mine].tolist() == [k * 10**7 for k in range(25)]  # oldest first
        assert np.array_equal(got['positions'][mine], np.array([(rid, k, 0.5) for k in range(25)], float))
    assert np.array_equal(got['quaternions'], np.tile([0.0, 0.0, 0.6, 0.8], (50, 1)))
    assert not got['linears'].any()  # a pose has no twist


@pytest.mark.ros
def test_the_inbox_takes_raw_bytes_of_some_robots_in_its_namespace(ros, tmp_path):
    """The agent's use: its neighbours only, relative topics resolved in its namespace, its QoS,
    the bytes undecoded."""
    from geometry_msgs.msg import PoseStamped

    from knode_swarm_ros.nodes.common.state_inbox import StateInbox

    context, node = ros
    path = tmp_path / 'fleet.yaml'
    path.write_text(
        yaml.safe_dump(
            {
                'robots': {'a': {'id': 0}, 'b': {'id': 1}, 'c': {'id': 2}},
                'state': {'topic': 'pose', 'type': 'pose'},  # relative: <name>/pose
            }
        )
    )
    fleet = load_fleet(str(path))
    inbox = StateInbox(
        context, fleet, 1, name='agent_inbox', ids=[1, 2], qos_profile=qos.ODOM, namespace='/lab'
    )
    try:
        assert inbox.depth == qos.ODOM.depth
        pubs = _publishers(node, PoseStamped, ['/lab/b/pose', '/lab/c/pose'], inbox)
        sent = {1: [], 2: []}
        for k in range(3):
            for rid, pub in zip((1, 2), pubs):
                data = pose_to_cdr(k * 10**7, (rid, k, 0.0), (0.0, 0.0, 0.0, 1.0))
                pub.publish(data)
                sent[rid].append(data)
        got = []
        deadline = time.monotonic() + WAIT_S
        while time.monotonic() < deadline and len(got) < 6:
            got += list(inbox.take_raw())
            time.sleep(0.05)
    finally:
        inbox.destroy()
    assert [d for r, d in got if r == 1] == sent[1]  # the bytes as sent, oldest first
    assert [d for r, d in got if r == 2] == sent[2]
    assert len(got) == 6  # robot 0 not subscribed
