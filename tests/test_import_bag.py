"""The bag importer (training.import_bag) on bags written by the project's writer (knode_swarm_ros.bag).

Bags are written here as rosbag2 MCAP by knode_swarm_ros.bag (rosbags' writer, Jazzy's message
definitions) and read back by the importer; tests/test_bag.py covers the other formats (sqlite3,
ROS 1), broken bags and the writer itself.
Tolerances are stated where they are used, each from the error bound of the numerics:

* linear interpolation of a signal with |f''| <= A between samples h apart errs by at most
  A h^2 / 8;
* central differences of exact samples dt apart err by at most |p'''| dt^2 / 6 inside and
  |p'''| dt^2 / 3 at the ends (second-order one-sided); an error e in the positions adds
  e / dt inside and 4 e / dt at the ends ((3 + 4 + 1) / 2 weights).
"""

import math
from pathlib import Path

import numpy as np
import pytest
import rosbags  # noqa: F401  (the importer needs it: a broken install must fail, not skip)

from knode_swarm_ros.bag import (
    ODOMETRY,
    POSE_STAMPED,
    TF_MESSAGE,
    BagWriter,
    ns_to_stamp,
    odometry_message,
    write_odometry_bag,
)
from knode_swarm_ros.core import load_trajectories
from knode_swarm_ros.logic.contract.orientation import heading_to_quaternion
from training.import_bag import main

SEC = 1_000_000_000


# --- helpers ---------------------------------------------------------------------------------------


def circle(t, radius=2.0, omega=1.0, phase=0.0, centre=(0.0, 0.0)):
    """Positions [len(t), 2] and velocities on a circle at constant speed radius * omega."""
    a = omega * t + phase
    p = np.stack([centre[0] + radius * np.cos(a), centre[1] + radius * np.sin(a)], axis=-1)
    v = radius * omega * np.stack([-np.sin(a), np.cos(a)], axis=-1)
    return p, v


def jittered_times(duration, period, jitter, rng, start=0.0):
    t = start + np.arange(int(round(duration / period)) + 1) * period
    return t + rng.uniform(-jitter, jitter, t.size)


def pose_stamped(p, q, stamp_ns, frame='world'):
    return {
        'header': {'stamp': ns_to_stamp(stamp_ns), 'frame_id': frame},
        'pose': {
            'position': dict(zip('xyz', map(float, p))),
            'orientation': dict(zip('xyzw', map(float, q))),
        },
    }


def transform(p, q, stamp_ns, child, parent='world'):
    return {
        'header': {'stamp': ns_to_stamp(stamp_ns), 'frame_id': parent},
        'child_frame_id': child,
        'transform': {
            'translation': dict(zip('xyz', map(float, p))),
            'rotation': dict(zip('xyzw', map(float, q))),
        },
    }


def run(capsys, *argv):
    """main(argv) -> (exit status, stdout, stderr). The bounds here are those of central
    differences, so ``--smooth none`` unless a test asks otherwise (tests/test_smoother.py tests the
    default smoother)."""
    argv = [str(a) for a in argv]
    rc = main(argv if '--smooth' in argv else argv + ['--smooth', 'none'])
    out, err = capsys.readouterr()
    return rc, out, err


def flock_circles(t, n=3):
    """flock2d states [len(t), n, 4] of n robots on circles (radius 2, 1 rad/s, speed 2)."""
    states = np.empty((t.size, n, 4))
    for i in range(n):
        p, v = circle(t, phase=2 * math.pi * i / n, centre=(3.0 * i, 0.0))
        states[:, i, :2], states[:, i, 2:] = p, v
    return states


# --- round trips ------------------------------------------------------------------------------------


def test_odometry_bag_round_trips_exactly_on_its_own_grid(tmp_path, capsys):
    """Same rate, no jitter: the importer returns the written states (boids3d via orientation,
    flock2d velocities via twist) to float precision, from a split bag directory read in order."""
    rng = np.random.default_rng(1)
    T, n = 40, 3
    h = rng.normal(size=(T, n, 3))
    boids = np.concatenate(
        [rng.uniform(-4, 4, (T, n, 3)), h / np.linalg.norm(h, axis=2, keepdims=True)], axis=2
    )
    info = write_odometry_bag(tmp_path / 'b3', boids, 0.05, 'boids3d', ids=[4, 7, 9], split_messages=25)
    assert len(info['files']) == math.ceil(T * n / 25) and info['topics']['/robot_7/odom'] == T
    rc, out, err = run(
        capsys,
        tmp_path / 'b3',
        '--scenario',
        'boids3d',
        '--topics',
        '/robot_*/odom',
        '--rate',
        20,
        '--use-orientation',
        '--min-duration',
        0.5,
        '--out',
        tmp_path / 'b3.npz',
    )
    assert rc == 0, err
    f = load_trajectories(tmp_path / 'b3.npz', scenario='boids3d')
    assert f.states.shape == (1, T, n, 6) and f.dt == pytest.approx(0.05)
    np.testing.assert_allclose(f.states[0], boids, atol=1e-9)
    assert f.meta['robot_ids'] == [4, 7, 9] and f.meta['bag']['files'] == info['files']
    assert 'robots: 3 (ids 4, 7, 9)' in out

    flock = flock_circles(np.arange(T) * 0.05)
    write_odometry_bag(tmp_path / 'f2.mcap', flock, 0.05, 'flock2d')
    rc, out, err = run(
        capsys,
        tmp_path / 'f2.mcap',
        '--scenario',
        'flock2d',
        '--topics',
        '/robot_*/odom',
        '--rate',
        20,
        '--use-twist',
        '--min-duration',
        0.5,
        '--out',
        tmp_path / 'f2.npz',
    )
    assert rc == 0, err
    np.testing.assert_allclose(load_trajectories(tmp_path / 'f2.npz').states[0], flock, atol=1e-12)


# --- resampling accuracy on an analytic trajectory --------------------------------------------------------


def test_circle_resampling_positions_and_velocities_within_the_error_bounds(tmp_path, capsys):
    """Circle radius R = 2 at omega = 1 rad/s (speed 2), Odometry at 100 Hz with +-3 ms stamp jitter,
    resampled at 20 Hz. |p''| = R w^2 = 2, |p'''| = R w^3 = 2; raw intervals h <= 16 ms."""
    rng = np.random.default_rng(2)
    n, R, w = 3, 2.0, 1.0
    stamps = np.stack([jittered_times(4.0, 0.01, 0.003, rng, start=0.004) for _ in range(n)], axis=1)
    states = np.empty(stamps.shape + (4,))
    for i in range(n):
        p, v = circle(stamps[:, i], R, w, phase=i, centre=(5.0 * i, 1.0))
        states[:, i, :2], states[:, i, 2:] = p, v
    write_odometry_bag(tmp_path / 'circle.mcap', states, 0.01, 'flock2d', stamps=stamps)
    rate = 20.0
    dt = 1 / rate
    rc, out, err = run(
        capsys,
        tmp_path / 'circle.mcap',
        '--scenario',
        'flock2d',
        '--topics',
        '/robot_*/odom',
        '--rate',
        rate,
        '--out',
        tmp_path / 'c.npz',
    )
    assert rc == 0, err
    f = load_trajectories(tmp_path / 'c.npz')
    grid = (
        f.meta['grid']['anchor_ns'] * 1e-9
        + (f.meta['trajectories'][0]['grid_index'] + np.arange(f.states.shape[1])) * dt
    )
    assert (
        f.states.shape[0] == 1 and grid[0] >= stamps[0].max() - 1e-9 and grid[-1] <= stamps[-1].min() + 1e-9
    )
    h = np.diff(np.sort(stamps, axis=0), axis=0).max()
    pos_tol = R * w**2 * h**2 / 8  # <= 6.4e-5
    inner_tol = R * w**3 * dt**2 / 6 + pos_tol / dt  # <= 2.1e-3
    edge_tol = R * w**3 * dt**2 / 3 + 4 * pos_tol / dt  # <= 6.8e-3
    for i in range(n):
        p, v = circle(grid, R, w, phase=i, centre=(5.0 * i, 1.0))
        assert np.abs(f.states[0, :, i, :2] - p).max() <= pos_tol
        err_v = np.abs(f.states[0, :, i, 2:] - v).max(axis=1)
        assert err_v[1:-1].max() <= inner_tol
        assert err_v[[0, -1]].max() <= edge_tol
    assert f.meta['derivation']['smoothing'] == {'method': 'none'}

    # --use-twist: velocities are interpolated like positions, |v''| = R w^2
    rc, out, err = run(
        capsys,
        tmp_path / 'circle.mcap',
        '--scenario',
        'flock2d',
        '--topics',
        '/robot_*/odom',
        '--rate',
        rate,
        '--use-twist',
        '--out',
        tmp_path / 'tw.npz',
    )
    assert rc == 0, err
    for i in range(n):
        _, v = circle(grid, R, w, phase=i, centre=(5.0 * i, 1.0))
        assert np.abs(load_trajectories(tmp_path / 'tw.npz').states[0, :, i, 2:] - v).max() <= pos_tol


def test_smoothing_reduces_velocity_noise(tmp_path, capsys):
    """1 mm position noise at 50 Hz: central differences amplify it to ~0.035 m/s; a 9-sample
    Savitzky-Golay (order 2) or moving-average filter of the differences cuts the RMS error."""
    rng = np.random.default_rng(3)
    t = np.arange(301) * 0.02
    states = flock_circles(t, n=2)
    noisy = states.copy()
    noisy[..., :2] += rng.normal(0, 1e-3, noisy[..., :2].shape)
    write_odometry_bag(tmp_path / 'noisy.mcap', noisy, 0.02, 'flock2d')
    rms = {}
    for method in ('none', 'savgol', 'moving-average'):
        rc, out, err = run(
            capsys,
            tmp_path / 'noisy.mcap',
            '--scenario',
            'flock2d',
            '--topics',
            '/robot_*/odom',
            '--rate',
            50,
            '--smooth',
            method,
            '--smooth-window',
            9,
            '--out',
            tmp_path / f'{method}.npz',
        )
        assert rc == 0, err
        f = load_trajectories(tmp_path / f'{method}.npz')
        rms[method] = float(np.sqrt(np.mean((f.states[0, 5:-5, :, 2:] - states[5:-5, :, 2:]) ** 2)))
        if method != 'none':
            assert f.meta['derivation']['smoothing']['window'] == 9
            assert np.abs(f.states[0, :, :, :2] - noisy[..., :2]).max() < 1e-12  # positions never smoothed
    assert rms['savgol'] < 0.5 * rms['none'] and rms['moving-average'] < 0.5 * rms['none']


# --- each message type -------------------------------------------------------------------------------


def helix(t, phase):
    """3D helix: circle R = 2 at 1 rad/s in xy, climbing 0.5 m/s. Returns p [.., 3], unit tangent."""
    p = np.stack([2 * np.cos(t + phase), 2 * np.sin(t + phase), 0.5 * t], axis=-1)
    v = np.stack([-2 * np.sin(t + phase), 2 * np.cos(t + phase), 0.5 * np.ones_like(t)], axis=-1)
    return p, v / np.linalg.norm(v, axis=-1, keepdims=True)


def test_pose_stamped_boids3d_headings_from_motion_and_orientation(tmp_path, capsys):
    """PoseStamped at 100 Hz (orientation = tangent), robot 2's stamps 4 ms after robot 1's, imported
    at 25 Hz on robot 2's stamps, so robot 1 is interpolated at 0.4 of its intervals.

    Bounds (speed |v| = 2.06, |p''| = 2, tangent turning at 0.97 rad/s, h = 10 ms, dt = 40 ms):
    positions A h^2 / 8 = 2.5e-5; backward differences give the chord direction, which for a
    helix (xy radius 2, climb 0.5 per rad) is the tangent at t - dt/2 up to the xy chord factor
    sin(x)/x = 1 - dt^2/24 (angle <= 0.25 x that), plus the interpolation error 2 x 2.5e-5 / dt
    / |v|; central differences give the tangent at t up to 1 - dt^2/6; interpolated orientations
    err by (0.97 h)^2 / 8."""
    path = tmp_path / 'mocap.mcap'
    with BagWriter(path) as bag:
        for k in range(301):
            for i in range(2):
                s = 1.0 + 0.004 * i + 0.01 * k
                ns = round(s * SEC)
                p, h = helix(np.array(s), phase=i)
                bag.write(
                    f'/vicon/cf{i + 1}/pose', POSE_STAMPED, pose_stamped(p, heading_to_quaternion(h), ns), ns
                )
    dt = 1 / 25
    results = {}
    for extra in ([], ['--heading-diff', 'central'], ['--use-orientation']):
        name = '-'.join(extra) or 'backward'
        rc, out, err = run(
            capsys,
            path,
            '--scenario',
            'boids3d',
            '--topics',
            '/vicon/*/pose',
            '--rate',
            25,
            '--out',
            tmp_path / f'{name}.npz',
            *extra,
        )
        assert rc == 0, err
        results[name] = f = load_trajectories(tmp_path / f'{name}.npz', scenario='boids3d')
        assert f.meta['robot_ids'] == [1, 2] and f.meta['message_types']['/vicon/cf1/pose'] == POSE_STAMPED
        np.testing.assert_allclose(np.linalg.norm(f.states[..., 3:], axis=-1), 1.0, atol=1e-12)
    t = 1.004 + np.arange(results['backward'].states.shape[1]) * dt
    pos_tol = 2.0 * 0.01**2 / 8
    interp_angle = 2 * pos_tol / dt / 2.06
    for i in range(2):
        p, tangent = helix(t, phase=i)
        _, mid = helix(t - dt / 2, phase=i)
        assert np.abs(results['backward'].states[0, :, i, :3] - p).max() <= pos_tol
        backward = results['backward'].states[0, :, i, 3:]
        assert np.abs(backward[1:] - mid[1:]).max() <= 0.25 * dt**2 / 24 + interp_angle
        np.testing.assert_array_equal(backward[0], backward[1])  # frame 0 takes frame 1's
        central = results['--heading-diff-central'].states[0, 1:-1, i, 3:]
        assert np.abs(central - tangent[1:-1]).max() <= 0.25 * dt**2 / 6 + interp_angle
        assert (
            np.abs(results['--use-orientation'].states[0, :, i, 3:] - tangent).max() <= (0.97 * 0.01) ** 2 / 8
        )


def test_tf_frames_select_robots_by_child_frame(tmp_path, capsys):
    """/tf with robot frames cf3, cf5 and other frames (base_link, cf_tower) in the same messages."""
    path = tmp_path / 'tf'
    t = np.arange(101) * 0.02
    states = flock_circles(t, n=2)
    q = (0.0, 0.0, 0.0, 1.0)
    with BagWriter(path, split_messages=40) as bag:
        for k, s in enumerate(t):
            ns = round(s * SEC)
            tfs = [
                transform((*states[k, 0, :2], 0.0), q, ns, 'cf3'),
                transform((1, 2, 3), q, ns, 'base_link', 'odom'),
                transform((*states[k, 1, :2], 0.0), q, ns, '/cf5'),
            ]
            bag.write('/tf', TF_MESSAGE, {'transforms': tfs}, ns)
            if k % 10 == 0:
                bag.write(
                    '/tf', TF_MESSAGE, {'transforms': [transform((0, 0, 0), q, ns, 'cf_tower', 'map')]}, ns
                )
    rc, out, err = run(
        capsys,
        path,
        '--scenario',
        'flock2d',
        '--frames',
        'cf[0-9]*',
        '--rate',
        50,
        '--out',
        tmp_path / 'tf.npz',
    )
    assert rc == 0, err
    f = load_trajectories(tmp_path / 'tf.npz')
    assert f.meta['robot_ids'] == [3, 5] and [r['source'] for r in f.meta['robots']] == ['cf3', 'cf5']
    np.testing.assert_allclose(f.states[0, :, :, :2], states[..., :2], atol=1e-12)
    assert f.meta['messages']['ignored_sources'] == {'base_link': 101, 'cf_tower': 11}
    assert f.meta['bag']['kind'] == 'rosbag2 directory' and len(f.meta['bag']['files']) == 3

    # an explicit mapping picks and renames frames
    rc, out, err = run(
        capsys,
        path,
        '--scenario',
        'flock2d',
        '--frames',
        'cf*',
        '--rate',
        50,
        '--id-map',
        'cf5=0',
        '--id-map',
        'cf3=1',
        '--out',
        tmp_path / 'tfmap.npz',
    )
    assert rc == 0, err
    g = load_trajectories(tmp_path / 'tfmap.npz')
    assert g.meta['robot_ids'] == [0, 1] and g.meta['id_map'] == {'cf5': 0, 'cf3': 1}
    np.testing.assert_allclose(g.states[0], f.states[0][:, ::-1])
    # without --frames a TF topic is refused with a hint
    rc, out, err = run(
        capsys, path, '--scenario', 'flock2d', '--topics', '/tf', '--rate', 50, '--out', tmp_path / 'x.npz'
    )
    assert rc == 2 and '--frames' in err and not (tmp_path / 'x.npz').exists()


# --- topic patterns and id mapping ---------------------------------------------------------------------


@pytest.fixture
def mixed_bag(tmp_path):
    """/robot_{1,2}/odom (Odometry), /robot_1/cmd_accel (AccelStamped), /vicon/cf3/pose and
    /vicon/wand/pose (PoseStamped); 3 s at 20 Hz."""
    path = tmp_path / 'mixed.mcap'
    t = np.arange(61) * 0.05
    states = flock_circles(t, n=4)
    q = (0.0, 0.0, 0.0, 1.0)
    with BagWriter(path) as bag:
        for k, s in enumerate(t):
            ns = round(s * SEC)
            for i in (1, 2):
                bag.write(f'/robot_{i}/odom', ODOMETRY, odometry_message('flock2d', states[k, i], ns, i), ns)
            bag.write(
                '/robot_1/cmd_accel',
                'geometry_msgs/msg/AccelStamped',
                {'header': {'stamp': ns_to_stamp(ns), 'frame_id': 'world'}, 'accel': {'linear': {'x': 1.0}}},
                ns,
            )
            bag.write('/vicon/cf3/pose', POSE_STAMPED, pose_stamped((*states[k, 3, :2], 0.0), q, ns), ns)
            bag.write('/vicon/wand/pose', POSE_STAMPED, pose_stamped((0.0, 0.0, 1.0), q, ns), ns)
    return path, states


def test_topic_globs_pick_robots_and_ids_come_from_the_first_integer(mixed_bag, tmp_path, capsys):
    path, states = mixed_bag
    rc, out, err = run(
        capsys,
        path,
        '--scenario',
        'flock2d',
        '--topics',
        '/robot_*/odom,/vicon/cf*/pose',
        '--rate',
        20,
        '--out',
        tmp_path / 'a.npz',
    )
    assert rc == 0, err
    f = load_trajectories(tmp_path / 'a.npz')
    assert f.meta['robot_ids'] == [1, 2, 3]
    assert f.meta['topics'] == ['/robot_1/odom', '/robot_2/odom', '/vicon/cf3/pose']
    np.testing.assert_allclose(f.states[0, :, :, :2], states[:, 1:, :2], atol=1e-12)

    # mapping: explicit names (NAME=ID and a YAML file), --topics defaults to the mapping's names
    (tmp_path / 'ids.yaml').write_text('/vicon/cf3/pose: 30\n/vicon/wand/pose: 31\n')
    rc, out, err = run(
        capsys,
        path,
        '--scenario',
        'flock2d',
        '--id-map',
        '/robot_2/odom=2',
        '--id-map',
        tmp_path / 'ids.yaml',
        '--rate',
        20,
        '--out',
        tmp_path / 'b.npz',
    )
    assert rc == 0, err
    g = load_trajectories(tmp_path / 'b.npz')
    assert g.meta['robot_ids'] == [2, 30, 31] and g.meta['id_rule'] == '--id-map'


def test_a_name_without_an_integer_needs_a_mapping(mixed_bag, tmp_path, capsys):
    path, _ = mixed_bag
    rc, out, err = run(
        capsys,
        path,
        '--scenario',
        'flock2d',
        '--topics',
        '/vicon/*/pose',
        '--rate',
        20,
        '--out',
        tmp_path / 'a.npz',
    )
    assert rc == 2 and '/vicon/wand/pose' in err and '--id-map' in err


# --- gaps -------------------------------------------------------------------------------------------


def test_a_silent_robot_splits_the_recording_and_short_segments_are_dropped(tmp_path, capsys):
    """3 robots at 50 Hz over 6 s; robot 1 silent over (2.0, 3.0) s and (5.6, 5.8) s. Cut at both
    gaps: segments [0, 2.0] (101 frames at 50 Hz), [3.0, 5.6] (131), [5.8, 6.0] (0.2 s, dropped)."""
    t = np.arange(301) * 0.02
    states = flock_circles(t)
    mask = np.ones((t.size, 3), dtype=bool)
    mask[101:150, 1] = False
    mask[281:290, 1] = False
    write_odometry_bag(tmp_path / 'gap.mcap', states, 0.02, 'flock2d', mask=mask)
    rc, out, err = run(
        capsys,
        tmp_path / 'gap.mcap',
        '--scenario',
        'flock2d',
        '--topics',
        '/robot_*/odom',
        '--rate',
        50,
        '--out',
        tmp_path / 'g.npz',
    )
    assert rc == 0, err
    f = load_trajectories(tmp_path / 'g.npz')
    gaps = f.meta['gaps']
    assert [(g['robot'], round(g['from'], 6), round(g['to'], 6)) for g in gaps] == [
        (1, 2.0, 3.0),
        (1, 5.6, 5.8),
    ]
    assert f.meta['max_gap'] == pytest.approx(0.1)
    segs = f.meta['segments']
    assert [(s['frames'], s['kept']) for s in segs] == [(101, True), (131, True), (11, False)]
    assert '0.200 s < --min-duration 1 s' in segs[2]['reason']
    # T = shortest kept segment (101); the 131-frame segment gives one window, 30 frames unused
    assert f.states.shape == (2, 101, 3, 4) and segs[1]['unused_frames'] == 30
    starts = [tm['start_time'] for tm in f.meta['trajectories']]
    np.testing.assert_allclose(starts, [0.0, 3.0], atol=1e-9)
    np.testing.assert_allclose(f.states[0, :, :, :2], states[:101, :, :2], atol=1e-12)
    np.testing.assert_allclose(f.states[1, :, :, :2], states[150:251, :, :2], atol=1e-12)
    assert 'robot 1 (/robot_1/odom) silent 1.000 s from t = 2.000 s to 3.000 s' in out
    assert 'dropped: 11 frame(s), 0.200 s < --min-duration 1 s' in out

    # --length: windows sharing their boundary frame; a larger --max-gap bridges the short gap
    rc, out, err = run(
        capsys,
        tmp_path / 'gap.mcap',
        '--scenario',
        'flock2d',
        '--topics',
        '/robot_*/odom',
        '--rate',
        50,
        '--length',
        51,
        '--max-gap',
        0.5,
        '--out',
        tmp_path / 'w.npz',
    )
    assert rc == 0, err
    w = load_trajectories(tmp_path / 'w.npz')
    assert len(w.meta['gaps']) == 1 and [s['frames'] for s in w.meta['segments']] == [101, 151]
    assert w.states.shape == (2 + 3, 51, 3, 4)
    np.testing.assert_array_equal(w.states[0, -1], w.states[1, 0])


# --- recordings that were cut short, stamps, slow robots ------------------------------------------------


def test_a_recording_without_metadata_is_read_from_its_files_and_a_truncated_file_is_named(tmp_path, capsys):
    """A killed recorder leaves no metadata.yaml: the storage files are read in name order, with a
    note. A last file cut short (no MCAP footer) is refused (exit 2) naming that file: rosbags does
    not read broken files, and guessing where a file broke would import a partial recording."""
    path = tmp_path / 'cut'
    t = np.arange(201) * 0.02
    states = flock_circles(t, n=2)
    write_odometry_bag(path, states, 0.02, 'flock2d', split_messages=250)
    (path / 'metadata.yaml').unlink()
    rc, out, err = run(
        capsys,
        path,
        '--scenario',
        'flock2d',
        '--topics',
        '/robot_*/odom',
        '--rate',
        50,
        '--out',
        tmp_path / 'cut.npz',
    )
    assert rc == 0, err
    assert 'no metadata.yaml; reading its 2 storage file(s) in name order' in out
    f = load_trajectories(tmp_path / 'cut.npz')
    assert f.meta['messages']['read'] == 402 and f.meta['bag']['files'] == ['cut_0.mcap', 'cut_1.mcap']
    np.testing.assert_allclose(f.states[0, :, :, :2], states[..., :2], atol=1e-12)

    last = path / 'cut_1.mcap'
    with open(last, 'r+b') as fh:
        fh.truncate(last.stat().st_size // 3)
    rc, out, err = run(
        capsys,
        path,
        '--scenario',
        'flock2d',
        '--topics',
        '/robot_*/odom',
        '--rate',
        50,
        '--out',
        tmp_path / 'cut2.npz',
    )
    assert rc == 2 and str(last) in err and 'not readable (truncated, corrupt' in err, err
    assert not (tmp_path / 'cut2.npz').exists()


def test_zero_header_stamps_need_log_time_and_non_finite_samples_are_dropped(tmp_path, capsys):
    path = tmp_path / 'nostamp.mcap'
    t = np.arange(61) * 0.05
    states = flock_circles(t, n=2)
    q = (0.0, 0.0, 0.0, 1.0)
    with BagWriter(path) as bag:
        for k, s in enumerate(t):
            for i in range(2):
                p = (np.nan, 0.0, 0.0) if (i, k) == (1, 30) else (*states[k, i, :2], 0.0)
                bag.write(f'/robot_{i}/pose', POSE_STAMPED, pose_stamped(p, q, 0), round(s * SEC))
    rc, out, err = run(
        capsys,
        path,
        '--scenario',
        'flock2d',
        '--topics',
        '/robot_*/pose',
        '--rate',
        20,
        '--out',
        tmp_path / 'x.npz',
    )
    assert rc == 2 and '/robot_0/pose' in err and '--stamp log' in err
    rc, out, err = run(
        capsys,
        path,
        '--scenario',
        'flock2d',
        '--topics',
        '/robot_*/pose',
        '--rate',
        20,
        '--stamp',
        'log',
        '--out',
        tmp_path / 'x.npz',
    )
    assert rc == 0, err
    f = load_trajectories(tmp_path / 'x.npz')
    assert f.meta['messages']['non_finite'] == 1 and '1 non-finite' in out
    assert f.states.shape == (1, 61, 2, 4)  # one missing sample is interpolated over (0.1 s < max gap)


def test_slow_boids_hold_their_heading_and_a_robot_that_never_moves_has_none(tmp_path, capsys):
    t = np.arange(101) * 0.02
    p = np.zeros((t.size, 2, 3))
    p[:, 0, 0] = np.minimum(t, 1.0)  # robot 0 moves along +x for 1 s, then stops
    p[:, 1, 1] = -t  # robot 1 moves along -y
    h = np.tile([1.0, 0.0, 0.0], (t.size, 2, 1))
    write_odometry_bag(tmp_path / 'slow.mcap', np.concatenate([p, h], axis=2), 0.02, 'boids3d')
    rc, out, err = run(
        capsys,
        tmp_path / 'slow.mcap',
        '--scenario',
        'boids3d',
        '--topics',
        '/robot_*/odom',
        '--rate',
        50,
        '--out',
        tmp_path / 's.npz',
    )
    assert rc == 0, err
    f = load_trajectories(tmp_path / 's.npz')
    np.testing.assert_allclose(f.states[0, :, 0, 3:], np.tile([1.0, 0.0, 0.0], (t.size, 1)), atol=1e-12)
    np.testing.assert_allclose(f.states[0, :, 1, 3:], np.tile([0.0, -1.0, 0.0], (t.size, 1)), atol=1e-12)
    assert 'slower than --min-speed take the nearest valid heading' in out

    p[:, 1] = 0.0  # robot 1 never moves
    write_odometry_bag(tmp_path / 'still.mcap', np.concatenate([p, h], axis=2), 0.02, 'boids3d')
    rc, out, err = run(
        capsys,
        tmp_path / 'still.mcap',
        '--scenario',
        'boids3d',
        '--topics',
        '/robot_*/odom',
        '--rate',
        50,
        '--out',
        tmp_path / 'x.npz',
    )
    assert rc == 2 and 'robot 1 (/robot_1/odom) never moves' in err and '--use-orientation' in err
    rc, out, err = run(
        capsys,
        tmp_path / 'still.mcap',
        '--scenario',
        'boids3d',
        '--topics',
        '/robot_*/odom',
        '--rate',
        50,
        '--use-orientation',
        '--out',
        tmp_path / 'x.npz',
    )
    assert rc == 0, err


# --- bad input ---------------------------------------------------------------------------------------


@pytest.fixture
def odom_bag(tmp_path):
    path = tmp_path / 'odom.mcap'
    write_odometry_bag(path, flock_circles(np.arange(41) * 0.05), 0.05, 'flock2d')
    return path


def test_not_a_bag(tmp_path, capsys):
    text = tmp_path / 'notes.txt'
    text.write_text('hello\n')
    empty = tmp_path / 'empty'
    empty.mkdir()
    listed = tmp_path / 'old'
    listed.mkdir()
    (listed / 'metadata.yaml').write_text(
        'rosbag2_bagfile_information:\n  storage_identifier: sqlite3\n  relative_file_paths: [old_0.db3]\n'
    )
    misnamed = tmp_path / 'run.db3'
    misnamed.write_bytes(b'\x89MCAP0\r\n' + bytes(64))
    for path, message in (
        (text, 'not a bag file'),
        (empty, 'no metadata.yaml and no .mcap, .db3 or .bag files'),
        (tmp_path / 'missing', 'no such file or directory'),
        (listed, 'old_0.db3, which is missing'),
        (misnamed, 'holds a mcap file but is named .db3'),
    ):
        rc, out, err = run(
            capsys, path, '--scenario', 'flock2d', '--topics', '*', '--rate', 10, '--out', tmp_path / 'x.npz'
        )
        assert rc == 2 and message in err and str(path) in err and 'nothing written' in err, err
    assert not (tmp_path / 'x.npz').exists()


def test_unsupported_message_type_on_a_matched_topic(mixed_bag, tmp_path, capsys):
    path, _ = mixed_bag
    rc, out, err = run(
        capsys,
        path,
        '--scenario',
        'flock2d',
        '--topics',
        '/robot_1/*',
        '--rate',
        20,
        '--out',
        tmp_path / 'x.npz',
    )
    assert rc == 2 and '/robot_1/cmd_accel' in err and 'geometry_msgs/msg/AccelStamped' in err
    assert not (tmp_path / 'x.npz').exists()


def test_a_pattern_that_matches_nothing_lists_the_topics(odom_bag, tmp_path, capsys):
    rc, out, err = run(
        capsys,
        odom_bag,
        '--scenario',
        'flock2d',
        '--topics',
        '/robot_*/pose',
        '--rate',
        20,
        '--out',
        tmp_path / 'x.npz',
    )
    assert rc == 2 and '/robot_*/pose' in err and 'matches no topic' in err and '/robot_0/odom' in err
    rc, out, err = run(
        capsys,
        odom_bag,
        '--scenario',
        'flock2d',
        '--frames',
        'cf*',
        '--rate',
        20,
        '--out',
        tmp_path / 'x.npz',
    )
    assert rc == 2 and '/tf' in err and 'matches no topic' in err
    assert not (tmp_path / 'x.npz').exists()


def test_a_mapped_robot_that_never_appears(odom_bag, tmp_path, capsys):
    rc, out, err = run(
        capsys,
        odom_bag,
        '--scenario',
        'flock2d',
        '--topics',
        '/robot_*/odom',
        '--rate',
        20,
        '--id-map',
        '/robot_0/odom=0',
        '--id-map',
        '/robot_9/odom=9',
        '--out',
        tmp_path / 'x.npz',
    )
    assert rc == 2 and 'robot 9' in err and '/robot_9/odom' in err and 'never appears' in err
    assert not (tmp_path / 'x.npz').exists()


def test_header_stamps_going_backwards(tmp_path, capsys):
    path = tmp_path / 'back.mcap'
    states = flock_circles(np.arange(30) * 0.05, n=2)
    stamps = np.round(np.arange(30) * 0.05 * SEC).astype(np.int64)
    with BagWriter(path) as bag:
        for k in range(30):
            for i in range(2):
                header_ns = stamps[k] if not (i == 1 and k == 17) else stamps[15]  # robot 1 jumps back
                bag.write(
                    f'/robot_{i}/odom',
                    ODOMETRY,
                    odometry_message('flock2d', states[k, i], header_ns, i),
                    stamps[k],
                )
    rc, out, err = run(
        capsys,
        path,
        '--scenario',
        'flock2d',
        '--topics',
        '/robot_*/odom',
        '--rate',
        20,
        '--out',
        tmp_path / 'x.npz',
    )
    assert rc == 2 and '/robot_1/odom' in err and 'go backwards at message 17' in err
    assert not (tmp_path / 'x.npz').exists()


def test_other_refusals_name_the_problem(odom_bag, mixed_bag, tmp_path, capsys):
    path, _ = mixed_bag
    cases = [
        ((path, '--topics', '/vicon/cf3/pose', '--use-twist'), '--use-twist needs nav_msgs/msg/Odometry'),
        ((odom_bag, '--topics', '/robot_*/odom', '--min-duration', 5), 'no segment is long enough'),
        ((odom_bag, '--topics', '/robot_*/odom', '--smooth', 'savgol', '--smooth-window', 4), 'odd'),
    ]
    for args, message in cases:
        rc, out, err = run(
            capsys, args[0], '--scenario', 'flock2d', '--rate', 20, '--out', tmp_path / 'x.npz', *args[1:]
        )
        assert rc == 2 and message in err, err
    assert not (tmp_path / 'x.npz').exists()


def test_the_module_exits_2_and_writes_nothing(tmp_path):
    import os
    import subprocess
    import sys

    (tmp_path / 'notes.txt').write_text('hello\n')
    proc = subprocess.run(
        [
            sys.executable,
            '-m',
            'training.import_bag',
            str(tmp_path / 'notes.txt'),
            '--scenario',
            'flock2d',
            '--topics',
            '*',
            '--rate',
            '10',
            '--out',
            str(tmp_path / 'x.npz'),
        ],
        cwd=Path(__file__).resolve().parents[1],
        capture_output=True,
        text=True,
        env=dict(os.environ),
        timeout=120,
    )
    assert proc.returncode == 2 and 'not a bag file' in proc.stderr and not (tmp_path / 'x.npz').exists()


# --- round trip: ground truth -> MCAP bag -> import -> training ----------------------------------------


def test_ground_truth_round_trip_and_training(tmp_path, capsys):
    """A flock2d ground-truth run (Tanner, the ground-truth module's RK4 at a fine 1 ms step so that
    jittered stamps have exact states) is written as a bag at ~200 Hz (5 ms +- 2 ms stamp jitter,
    per robot), robot 2 silent for 0.6 s. Imported at the training rate 1 / 0.01 it equals the
    source run sampled every 10 ms within the interpolation bounds computed from the run's own
    acceleration and jerk (1.5x margin for their finite-difference estimates), splits into two
    trajectories at the silent stretch, and trains for two epochs."""
    from knode_swarm_ros.core import groundtruth as gt
    from knode_swarm_ros.core.groundtruth import tanner

    n, fine = 5, 0.001
    rng = np.random.default_rng(7)
    swarm = gt.TannerSwarm(tanner.initial_states(rng, 1, n, 'paper'), 'paper', dt=fine)
    for _ in range(1000):  # start recording 1 s into the flight, past the initial transient
        swarm.step()
    frames = [swarm.observe()[0]]
    for _ in range(3600):  # 3.6 s
        frames.append(swarm.step()[0])
    run_fine = np.array(frames)  # [3601, n, 4] at 1 ms
    # bag stamps: every 5 ms +- 2 ms, on the 1 ms grid so that each message holds an exact state
    idx = np.clip(np.arange(0, 3601, 5)[:, None] + rng.integers(-2, 3, (721, n)), 0, 3600)
    idx = np.sort(idx, axis=0)
    keep = np.ones(idx.shape, dtype=bool)
    keep[1:] = np.diff(idx, axis=0) > 0
    silent = (idx > 1700) & (idx < 2300) & (np.arange(n) == 2)
    mask = keep & ~silent
    states = run_fine[idx, np.arange(n)]
    start_ns = 1_700_000_000 * SEC  # an epoch-like start, as in a real recording
    stamps = start_ns + idx * 1_000_000
    bag = tmp_path / 'gt_bag'
    info = write_odometry_bag(bag, states, 0.005, 'flock2d', stamps=stamps, mask=mask)
    assert info['topics']['/robot_2/odom'] < info['topics']['/robot_0/odom']

    rc, out, err = run(
        capsys,
        bag,
        '--scenario',
        'flock2d',
        '--topics',
        '/robot_*/odom',
        '--rate',
        100,
        '--out',
        tmp_path / 'gt.npz',
    )
    assert rc == 0, err
    f = load_trajectories(tmp_path / 'gt.npz', scenario='flock2d')
    assert f.dt == pytest.approx(0.01) and f.states.shape[0] == 2 and f.states.shape[2] == n
    assert (
        len(f.meta['gaps']) == 1 and f.meta['gaps'][0]['robot'] == 2 and f.meta['gaps'][0]['duration'] >= 0.6
    )

    acc = np.abs(np.diff(run_fine[..., 2:], axis=0) / fine).max()
    jerk = np.abs(np.diff(run_fine[..., 2:], 2, axis=0) / fine**2).max()
    intervals = [np.diff(stamps[mask[:, i], i]) * 1e-9 for i in range(n)]
    h = max(d[d < 0.1].max() for d in intervals)  # longest interval between messages, gap aside
    dt = 0.01
    pos_tol = 1.5 * acc * h**2 / 8
    inner_tol = 1.5 * (jerk * dt**2 / 6) + pos_tol / dt
    edge_tol = 1.5 * (jerk * dt**2 / 3) + 4 * pos_tol / dt
    assert pos_tol < 1e-4 and inner_tol < 0.02  # the bounds are tight enough to mean something
    for traj, tm in zip(f.states, f.meta['trajectories']):
        k0 = (tm['start_ns'] - start_ns) / 1e6  # index of the first frame on the 1 ms grid
        assert abs(k0 - round(k0)) < 1e-3
        ref = run_fine[int(round(k0)) :: 10][: traj.shape[0]]
        assert ref.shape == traj.shape
        assert np.abs(traj[..., :2] - ref[..., :2]).max() <= pos_tol
        err_v = np.abs(traj[..., 2:] - ref[..., 2:]).max(axis=(1, 2))
        assert err_v[1:-1].max() <= inner_tol and err_v[[0, -1]].max() <= edge_tol

    # a few training epochs on the imported file
    from training import train

    config = Path(__file__).resolve().parents[1] / 'config' / 'train_flock2d.yaml'
    rc = train.main(
        [
            '--config',
            str(config),
            '--data',
            str(tmp_path / 'gt.npz'),
            '--out',
            str(tmp_path / 'run'),
            '--set',
            'training.epochs=2',
            '--set',
            'data.val_trajectories=1',
            '--set',
            'policy.hidden=16',
            '--set',
            'selection.every=2',
            '--set',
            'selection.trajectories=1',
            '--set',
            'selection.steps=20',
            '--set',
            'training.batch_size=256',
            '--no-progress',
        ]
    )
    assert rc == 0, capsys.readouterr().err
    assert (tmp_path / 'run' / 'policy.pt').is_file()
    assert len((tmp_path / 'run' / 'metrics.jsonl').read_text().splitlines()) == 2
