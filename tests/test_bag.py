"""knode_swarm_ros.bag: bags of every format the robots record, written here by ``rosbags`` itself
(independently of the project's writer), import into the same trajectories; broken bags are
refused naming the file; the bags the project writes are read back by ``rosbags`` message for
message with their QoS.

Formats: rosbag2 sqlite3 (Jazzy, metadata v9, definitions in the file), rosbag2 sqlite3 as
Humble and earlier record it (no definitions in the file, metadata v5), rosbag2 MCAP, ROS 1 bag.
"""

import math
import shutil
import sqlite3
from pathlib import Path

import numpy as np
import pytest
import rosbags  # noqa: F401  (a broken install must fail, not skip)
import yaml
from rosbags.highlevel import AnyReader
from rosbags.rosbag1 import Writer as Ros1Writer
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin
from rosbags.rosbag2 import Reader as Ros2Reader
from rosbags.rosbag2 import Writer as Ros2Writer
from rosbags.typesys import Stores, get_typestore

from knode_swarm_ros.bag import (
    ODOMETRY,
    POSE_STAMPED,
    TF_MESSAGE,
    BagWriteError,
    BagWriter,
    ns_to_stamp,
    odometry_message,
    stamp_to_ns,
    write_odometry_bag,
)
from knode_swarm_ros.bag.messages import to_message, typestore
from knode_swarm_ros.core import load_trajectories
from knode_swarm_ros.logic.contract import qos_specs
from knode_swarm_ros.logic.contract.orientation import heading_to_quaternion, quaternion_to_heading
from training.import_bag import main

SEC = 1_000_000_000
START_NS = 1_700_000_000 * SEC  # an epoch-like start, as in a real recording


def run(capsys, *argv):
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


# --- bags written by rosbags ------------------------------------------------------------------------


def write_with_rosbags(path: Path, fmt: str, messages):
    """Write ``[(topic, type, dict, log_ns)]`` with rosbags' own writers: ``fmt`` sqlite3 | mcap
    (rosbag2, Jazzy definitions), humble / foxy (sqlite3 without definitions, metadata v5 / v4), zstd (mcap,
    the whole file zstd-compressed: ``compression_mode: file``), ros1."""
    if fmt == 'ros1':
        store = get_typestore(Stores.ROS1_NOETIC)
        with Ros1Writer(path) as writer:
            conns = {}
            for topic, type_name, value, ns in messages:
                if topic not in conns:
                    conns[topic] = writer.add_connection(topic, type_name, typestore=store)
                writer.write(
                    conns[topic], ns, store.serialize_ros1(to_message(type_name, value, store), type_name)
                )
        return path
    store = get_typestore(Stores.ROS2_JAZZY)
    plugin = StoragePlugin.MCAP if fmt in ('mcap', 'zstd') else StoragePlugin.SQLITE3
    writer = Ros2Writer(path, version=9, storage_plugin=plugin)
    if fmt == 'zstd':
        writer.set_compression(CompressionMode.FILE, CompressionFormat.ZSTD)
    with writer:
        conns = {}
        for topic, type_name, value, ns in messages:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, type_name, typestore=store)
            writer.write(
                conns[topic], ns, store.serialize_cdr(to_message(type_name, value, store), type_name)
            )
    if fmt in ('humble', 'foxy'):
        # What Humble's (Foxy's) rosbag2 leaves: no message definitions in the .db3 (schema 3),
        # metadata version 5 (4) without type hashes or distribution (nor per-file entries), QoS
        # as one YAML string with integer policies.
        qos = (
            '- history: 3\n  depth: 0\n  reliability: 1\n  durability: 2\n  deadline:\n    sec: 2147483647\n'
            '    nsec: 4294967295\n  lifespan:\n    sec: 2147483647\n    nsec: 4294967295\n  liveliness: 1\n'
            '  liveliness_lease_duration:\n    sec: 2147483647\n    nsec: 4294967295\n'
            '  avoid_ros_namespace_conventions: false'
        )
        (db,) = path.glob('*.db3')
        with sqlite3.connect(db) as conn:
            conn.execute('DELETE FROM message_definitions')
            conn.execute('UPDATE schema SET schema_version = 3')
            conn.execute("UPDATE topics SET offered_qos_profiles = ?, type_description_hash = ''", (qos,))
        meta = yaml.safe_load((path / 'metadata.yaml').read_text())
        info = meta['rosbag2_bagfile_information']
        info['version'] = 5 if fmt == 'humble' else 4
        for key in ('ros_distro', 'custom_data') + (('files',) if fmt == 'foxy' else ()):
            info.pop(key, None)
        for t in info['topics_with_message_count']:
            t['topic_metadata'].pop('type_description_hash', None)
            t['topic_metadata']['offered_qos_profiles'] = qos
        (path / 'metadata.yaml').write_text(yaml.safe_dump(meta, sort_keys=False))
    return path


FORMATS = {
    'sqlite3': 'jazzy_db3',
    'humble': 'humble_db3',
    'foxy': 'foxy_db3',
    'mcap': 'mcap_bag',
    'zstd': 'zstd_bag',
    'ros1': 'run.bag',
}


def header(ns, frame='world'):
    return {'stamp': ns_to_stamp(ns), 'frame_id': frame}


def flock(t, n):
    """n robots on circles (radius 2, 1 rad/s): positions, velocities [len(t), n, 2]."""
    a = t[:, None] + 2 * math.pi * np.arange(n) / n
    centre = 3.0 * np.arange(n)
    p = np.stack([centre + 2 * np.cos(a), 2 * np.sin(a)], axis=-1)
    v = np.stack([-2 * np.sin(a), 2 * np.cos(a)], axis=-1)
    return p, v


def odometry_rep105(t, n):
    """Odometry of n robots as a REP 105 driver publishes it: twist in the body frame. The body
    yaw (0.3 t + i) is not the direction of motion, so a twist read in the wrong frame is wrong."""
    p, v = flock(t, n)
    messages = []
    for k, s in enumerate(t):
        ns = START_NS + round(s * SEC)
        for i in range(n):
            yaw = 0.3 * s + i
            c, si = math.cos(yaw), math.sin(yaw)
            body = (c * v[k, i, 0] + si * v[k, i, 1], -si * v[k, i, 0] + c * v[k, i, 1], 0.0)
            messages.append(
                (
                    f'/robot_{i}/odom',
                    ODOMETRY,
                    {
                        'header': header(ns),
                        'child_frame_id': f'robot_{i}',
                        'pose': {
                            'pose': {
                                'position': {'x': p[k, i, 0], 'y': p[k, i, 1]},
                                'orientation': {'z': math.sin(yaw / 2), 'w': math.cos(yaw / 2)},
                            }
                        },
                        'twist': {'twist': {'linear': dict(zip('xyz', body))}},
                    },
                    ns,
                )
            )
    return messages, p, v


def test_every_format_imports_to_the_same_states(tmp_path, capsys):
    """5 robots' Odometry at 50 Hz (REP 105 body twist) in each format (sqlite3, Humble's and Foxy's
    sqlite3, mcap, whole-file zstd mcap, ROS 1): identical trajectories;
    positions exact, velocities from the body twist exact, from differences within their bound."""
    n, t = 5, np.arange(101) * 0.02
    messages, p, v = odometry_rep105(t, n)
    results = {}
    for fmt, name in FORMATS.items():
        bag = write_with_rosbags(tmp_path / name, fmt, messages)
        for how, extra in (
            ('twist', ['--use-twist', '--twist-frame', 'body']),
            ('diff', ['--smooth', 'none']),
        ):
            out = tmp_path / f'{fmt}_{how}.npz'
            rc, stdout, err = run(
                capsys,
                bag,
                '--scenario',
                'flock2d',
                '--topics',
                '/robot_*/odom',
                '--rate',
                50,
                '--out',
                out,
                *extra,
            )
            assert rc == 0, (fmt, err)
            results[fmt, how] = load_trajectories(out, scenario='flock2d')
    ref = results['mcap', 'twist']
    assert ref.states.shape == (1, t.size, n, 4) and ref.meta['robot_ids'] == list(range(n))
    np.testing.assert_allclose(ref.states[0, :, :, :2], p, atol=1e-12)
    np.testing.assert_allclose(ref.states[0, :, :, 2:], v, atol=1e-12)
    # central differences of a circle: |p'''| dt^2 / 3 at the ends = 2 * 0.02^2 / 3
    assert np.abs(results['mcap', 'diff'].states[0, :, :, 2:] - v).max() <= 2 * 0.02**2 / 3
    for (fmt, how), f in results.items():
        np.testing.assert_array_equal(f.states, results['mcap', how].states, err_msg=f'{fmt} {how}')
        assert f.meta['t0_ns'] == START_NS
    assert results['ros1', 'twist'].meta['bag']['kind'] == 'ROS 1 bag'
    assert results['humble', 'twist'].meta['bag']['files'] == ['humble_db3.db3']
    assert results['zstd', 'twist'].meta['bag']['files'] == ['zstd_bag.mcap.zstd']

    # the same twist read as world-frame is not the velocity: the frame matters
    rc, _, err = run(
        capsys,
        tmp_path / FORMATS['ros1'],
        '--scenario',
        'flock2d',
        '--topics',
        '/robot_*/odom',
        '--rate',
        50,
        '--use-twist',
        '--twist-frame',
        'world',
        '--out',
        tmp_path / 'w.npz',
    )
    assert rc == 0, err
    assert np.abs(load_trajectories(tmp_path / 'w.npz').states[0, :, :, 2:] - v).max() > 0.5


def test_motion_capture_poses_in_a_ros1_bag_and_a_db3_bag_import_alike(tmp_path, capsys):
    """N = 4 robots' PoseStamped, as mocap drivers publish them (/vicon/cf<i>/pose, 100 Hz, each
    robot its own stamps), flying helices with orientation = tangent: the ROS 1 bag and the
    .db3 bag give the same boids3d trajectories; positions within the interpolation bound."""
    n, t = 4, 0.5 + np.arange(301) * 0.01
    messages = []
    for k, s in enumerate(t):
        for i in range(n):
            si = s + 0.002 * i  # robots' stamps 2 ms apart
            ns = START_NS + round(si * SEC)
            a = si + i
            pos = (2 * np.cos(a) + 5 * i, 2 * np.sin(a), 0.5 * si)
            tangent = np.array([-2 * np.sin(a), 2 * np.cos(a), 0.5])
            q = heading_to_quaternion(tangent)
            messages.append(
                (
                    f'/vicon/cf{i + 1}/pose',
                    POSE_STAMPED,
                    {
                        'header': header(ns, 'mocap'),
                        'pose': {'position': dict(zip('xyz', pos)), 'orientation': dict(zip('xyzw', q))},
                    },
                    ns,
                )
            )
    bags = {fmt: write_with_rosbags(tmp_path / FORMATS[fmt], fmt, messages) for fmt in ('ros1', 'sqlite3')}
    single = tmp_path / 'mocap.db3'
    shutil.copy(next(bags['sqlite3'].glob('*.db3')), single)  # a lone .db3 file reads too
    bags['db3 file'] = single
    got = {}
    for fmt, bag in bags.items():
        rc, out, err = run(
            capsys,
            bag,
            '--scenario',
            'boids3d',
            '--topics',
            '/vicon/*/pose',
            '--rate',
            25,
            '--use-orientation',
            '--out',
            tmp_path / f'{fmt}.npz',
        )
        assert rc == 0, (fmt, err)
        got[fmt] = load_trajectories(tmp_path / f'{fmt}.npz', scenario='boids3d')
    f = got['ros1']
    assert f.meta['robot_ids'] == [1, 2, 3, 4] and f.meta['frame_id'] == 'mocap'
    np.testing.assert_array_equal(f.states, got['sqlite3'].states)
    np.testing.assert_array_equal(f.states, got['db3 file'].states)
    grid = (f.meta['grid']['anchor_ns'] - START_NS) / SEC + np.arange(f.states.shape[1]) / 25
    for i in range(n):
        a = grid + i
        truth = np.stack([2 * np.cos(a) + 5 * i, 2 * np.sin(a), 0.5 * grid], axis=-1)
        assert np.abs(f.states[0, :, i, :3] - truth).max() <= 2.0 * 0.01**2 / 8 + 1e-12
        tangent = np.stack([-2 * np.sin(a), 2 * np.cos(a), 0.5 * np.ones_like(a)], axis=-1)
        tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
        assert np.abs(f.states[0, :, i, 3:] - tangent).max() <= (0.97 * 0.01) ** 2 / 8


# --- broken bags -------------------------------------------------------------------------------------


def _damage(path: Path, how: str) -> None:
    """Cut the file in half, or overwrite 1 KiB with 0xFF from the 4 KiB boundary a third of the way
    in: that hits structure in every format (an SQLite page header; an MCAP or ROS 1 record header,
    as one Odometry record is < 1 KiB). Damage confined to a message's payload is not detectable
    in these files (rosbags verifies MCAP chunk CRCs, but its writer writes none); it decodes to other numbers."""
    data = bytearray(path.read_bytes())
    if how == 'truncated':
        data = data[: len(data) // 2]
    else:
        at = (len(data) // 3) // 4096 * 4096
        data[at : at + 1024] = b'\xff' * 1024
    path.write_bytes(bytes(data))


@pytest.mark.parametrize('fmt', ['sqlite3', 'mcap', 'ros1'])
@pytest.mark.parametrize('how', ['truncated', 'corrupt'])
def test_a_truncated_or_corrupt_bag_exits_2_naming_the_file(tmp_path, capsys, fmt, how):
    messages, _, _ = odometry_rep105(np.arange(200) * 0.02, 3)
    bag = write_with_rosbags(tmp_path / FORMATS[fmt], fmt, messages)
    broken = bag if fmt == 'ros1' else next(p for p in bag.iterdir() if p.name != 'metadata.yaml')
    _damage(broken, how)
    out = tmp_path / 'x.npz'
    rc, _, err = run(
        capsys, bag, '--scenario', 'flock2d', '--topics', '/robot_*/odom', '--rate', 50, '--out', out
    )
    assert rc == 2 and str(broken) in err and 'nothing written' in err, err
    assert 'not readable (truncated, corrupt' in err, err
    assert not out.exists()


# --- the project's writer ------------------------------------------------------------------------


def test_project_bags_read_back_by_rosbags_message_for_message_with_their_qos(tmp_path):
    """A split bag directory and an .mcap file written by write_odometry_bag: rosbags (a second
    implementation of rosbag2) reads every message with every field as written, the topics'
    offered QoS equal the nodes' odometry profile, and metadata.yaml is what rosbag2 Jazzy writes."""
    rng = np.random.default_rng(5)
    T, n = 30, 3
    h = rng.normal(size=(T, n, 3))
    states = np.concatenate(
        [rng.uniform(-4, 4, (T, n, 3)), h / np.linalg.norm(h, axis=2, keepdims=True)], axis=2
    )
    vel = rng.normal(size=(T, n, 3))
    stamps = START_NS + np.arange(T)[:, None] * 10_000_000 + np.arange(n)[None, :] * 1_000
    for path in (tmp_path / 'dir_bag', tmp_path / 'one.mcap'):
        split = 40 if path.suffix != '.mcap' else None
        info = write_odometry_bag(
            path, states, 0.01, 'boids3d', stamps=stamps, velocities=vel, ids=[2, 5, 7], split_messages=split
        )
        assert info['messages'] == T * n
        seen = 0
        with AnyReader([path]) as reader:
            assert sorted(c.topic for c in reader.connections) == [
                '/robot_2/odom',
                '/robot_5/odom',
                '/robot_7/odom',
            ]
            for conn in reader.connections:
                (qos,) = conn.ext.offered_qos_profiles
                spec = qos_specs.ODOM
                assert (qos.history.name, qos.depth, qos.reliability.name, qos.durability.name) == (
                    'KEEP_LAST',
                    spec.depth,
                    spec.reliability.upper(),
                    spec.durability.upper(),
                )
                assert conn.msgtype == ODOMETRY
                if (
                    path.suffix != '.mcap'
                ):  # the hash travels in metadata.yaml (rosbags' MCAP channels lack it)
                    assert conn.digest == typestore().hash_rihs01(ODOMETRY)
            for conn, log_ns, raw in reader.messages():
                msg = reader.deserialize(raw, conn.msgtype)
                rid = int(conn.topic.split('_')[1].split('/')[0])
                i = [2, 5, 7].index(rid)
                t = int(round((stamp_to_ns(msg.header.stamp) - START_NS - i * 1_000) / 10_000_000))
                assert log_ns == stamp_to_ns(msg.header.stamp) == stamps[t, i]
                want = odometry_message('boids3d', states[t, i], int(stamps[t, i]), rid, velocity=vel[t, i])
                assert msg.header.frame_id == want['header']['frame_id'] == 'world'
                assert msg.child_frame_id == want['child_frame_id'] == f'robot_{rid}/base_link'
                for c in 'xyz':
                    assert getattr(msg.pose.pose.position, c) == want['pose']['pose']['position'][c]
                    assert getattr(msg.twist.twist.linear, c) == want['twist']['twist']['linear'][c]
                for c in 'xyzw':
                    assert getattr(msg.pose.pose.orientation, c) == want['pose']['pose']['orientation'][c]
                np.testing.assert_array_equal(msg.pose.covariance, np.zeros(36))
                seen += 1
        assert seen == T * n

    meta = yaml.safe_load((tmp_path / 'dir_bag' / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    # the keys, in the order rosbag2 Jazzy's yaml.hpp encodes BagMetadata / TopicMetadata / FileInformation
    assert list(meta) == [
        'version',
        'storage_identifier',
        'duration',
        'starting_time',
        'message_count',
        'topics_with_message_count',
        'compression_format',
        'compression_mode',
        'relative_file_paths',
        'files',
        'custom_data',
        'ros_distro',
    ]
    assert list(meta['topics_with_message_count'][0]['topic_metadata']) == [
        'name',
        'type',
        'serialization_format',
        'offered_qos_profiles',
        'type_description_hash',
    ]
    assert list(meta['files'][0]) == ['path', 'starting_time', 'duration', 'message_count']
    assert meta['version'] == 9 and meta['storage_identifier'] == 'mcap' and meta['ros_distro'] == 'jazzy'
    assert meta['relative_file_paths'] == ['dir_bag_0.mcap', 'dir_bag_1.mcap', 'dir_bag_2.mcap']
    assert sum(f['message_count'] for f in meta['files']) == meta['message_count'] == T * n
    topic = meta['topics_with_message_count'][0]['topic_metadata']
    # rosbag2 Jazzy, rosbag2_storage qos.cpp: version 9 profiles are a YAML sequence of maps with
    # the rmw policy names as strings and durations as {sec, nsec}
    inf = {'sec': 9223372036, 'nsec': 854775807}
    assert topic['offered_qos_profiles'] == [
        {
            'history': 'keep_last',
            'depth': 200,
            'reliability': 'reliable',
            'durability': 'volatile',
            'deadline': inf,
            'lifespan': inf,
            'liveliness': 'automatic',
            'liveliness_lease_duration': inf,
            'avoid_ros_namespace_conventions': False,
        }
    ]
    with Ros2Reader(tmp_path / 'dir_bag') as reader:  # rosbags' own metadata parser agrees
        assert all(c.ext.offered_qos_profiles[0].depth == 200 for c in reader.connections)


def test_project_qos_table_is_what_the_nodes_use():
    """The bag's QoS comes from nodes.qos_specs, which is also where the nodes' rclpy profiles come from."""
    qos = __import__('importlib').import_module('knode_swarm_ros.nodes.common.qos')
    for name in ('ODOM', 'POSE_STREAM', 'COMMAND', 'CLOCK', 'STATUS', 'PROGRESS', 'METRICS', 'MARKERS'):
        spec, prof = getattr(qos_specs, name), getattr(qos, name)
        assert (prof.history.name, prof.depth, prof.reliability.name, prof.durability.name) == (
            'KEEP_LAST',
            spec.depth,
            spec.reliability.upper(),
            spec.durability.upper(),
        ), name


def test_definitions_and_type_hashes_are_those_of_the_installed_jazzy_packages():
    """Bags are written with rosbags' Jazzy typestore; its RIHS01 hashes equal the ones the
    installed ros-jazzy message packages ship (share/<pkg>/msg/<Type>.json)."""
    import json
    import os
    import sys

    prefixes = [p for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p] + [sys.prefix]
    checked = 0
    for type_name in (ODOMETRY, POSE_STAMPED, 'geometry_msgs/msg/AccelStamped', 'std_msgs/msg/Header'):
        pkg, _, msg = type_name.split('/')
        files = [Path(p) / 'share' / pkg / 'msg' / f'{msg}.json' for p in prefixes]
        found = next((f for f in files if f.is_file()), None)
        if found is None:
            continue
        hashes = {e['type_name']: e['hash_string'] for e in json.loads(found.read_text())['type_hashes']}
        assert typestore().hash_rihs01(type_name) == hashes[type_name]
        checked += 1
    if checked == 0:
        pytest.skip('no ros-jazzy message package installed')
    assert TF_MESSAGE in typestore().types  # tf2_msgs needs no installed package any more


def test_writer_refuses_bad_messages_and_leaves_nothing(tmp_path):
    path = tmp_path / 'bad.mcap'
    with pytest.raises(BagWriteError, match="has no field 'positon'"):
        with BagWriter(path) as bag:
            bag.write('/p', POSE_STAMPED, {'header': header(0), 'pose': {'positon': {'x': 1.0}}}, 0)
    with pytest.raises(BagWriteError, match='not a message type name'):
        with BagWriter(path) as bag:
            bag.write('/p', 'PoseStamped', {}, 0)
    assert not path.exists() and list(tmp_path.iterdir()) == []
    with pytest.raises(BagWriteError, match='already exists'):
        write_odometry_bag(tmp_path, np.zeros((2, 1, 4)), 0.1, 'flock2d')


def test_heading_quaternion_rotates_x_onto_the_heading():
    rng = np.random.default_rng(0)
    h = rng.normal(size=(50, 3))
    h[0], h[1] = (-1.0, 0.0, 0.0), (1.0, 0.0, 0.0)
    np.testing.assert_allclose(
        quaternion_to_heading(heading_to_quaternion(h)),
        h / np.linalg.norm(h, axis=1, keepdims=True),
        atol=1e-12,
    )


def test_bag_messages_match_the_nodes_conversion_module():
    """The bag's Odometry mapping writes what knode_swarm_ros.nodes.common.conversions (which needs the ROS
    messages) publishes."""
    conv = __import__('importlib').import_module('knode_swarm_ros.nodes.common.conversions')
    rng = np.random.default_rng(4)
    h = rng.normal(size=(40, 3))
    h[:4] = [(-1.0, 0.0, 0.0), (1.0, 0.0, 0.0), (-0.3, 1e-9, 0.0), (0.0, 0.0, 0.0)]
    cases = [
        ('flock2d', np.array([1.5, -2.0, 0.0, 0.0]), None),
        ('flock2d', np.array([1.5, -2.0, -0.3, 0.7]), None),
    ]
    cases += [
        ('boids3d', np.concatenate([rng.normal(size=3), hk]), rng.normal(size=3) if k % 2 else None)
        for k, hk in enumerate(h)
    ]
    for scenario, z, vel in cases:
        ours = odometry_message(scenario, z, 1_234_567_891_011, 7, velocity=vel)
        ref = conv.state_to_odom(7, 1_234_567_891_011, z, scenario, velocity=vel)
        assert ours['header']['stamp'] == {'sec': ref.header.stamp.sec, 'nanosec': ref.header.stamp.nanosec}
        assert (ours['header']['frame_id'], ours['child_frame_id']) == (
            ref.header.frame_id,
            ref.child_frame_id,
        )
        for key, msg in (('position', ref.pose.pose.position), ('orientation', ref.pose.pose.orientation)):
            for c, v in ours['pose']['pose'][key].items():
                assert v == pytest.approx(getattr(msg, c), abs=1e-15), (scenario, z, key, c)
        for c, v in ours['twist']['twist']['linear'].items():
            assert v == getattr(ref.twist.twist.linear, c)


def test_writer_takes_ros_message_objects(tmp_path):
    """BagWriter.write takes an rclpy message as it is (any object with the fields): what the
    nodes publish goes into a bag unchanged."""
    conv = __import__('importlib').import_module('knode_swarm_ros.nodes.common.conversions')
    z = np.array([0.5, -1.0, 2.0, 0.3, -0.4, 0.8])
    ref = conv.state_to_odom(3, 2 * SEC + 5, z, 'boids3d', velocity=np.array([1.0, 2.0, 3.0]))
    path = tmp_path / 'ros.mcap'
    with BagWriter(path) as bag:
        bag.write('/robot_3/odom', ODOMETRY, ref, 2 * SEC + 5)
    with AnyReader([path]) as reader:
        ((conn, log_ns, raw),) = list(reader.messages())
        msg = reader.deserialize(raw, conn.msgtype)
    assert log_ns == stamp_to_ns(msg.header.stamp) == 2 * SEC + 5 and msg.child_frame_id == ref.child_frame_id
    for c in 'xyzw':
        assert getattr(msg.pose.pose.orientation, c) == getattr(ref.pose.pose.orientation, c)
    for c in 'xyz':
        assert getattr(msg.pose.pose.position, c) == getattr(ref.pose.pose.position, c)
        assert getattr(msg.twist.twist.linear, c) == getattr(ref.twist.twist.linear, c)
