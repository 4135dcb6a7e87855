"""training.import_tracks (CSV tracks, .npy arrays) and several bags with training.import_bag, both
through the shared library training.data (tracks, timeline, derive).

The tracks here move on straight lines at constant speed, so linear interpolation and central
differences are exact: the imported states must equal the known ones to float precision.
"""

from pathlib import Path

import numpy as np
import pytest

from knode_swarm_ros.bag import write_odometry_bag
from knode_swarm_ros.core import load_trajectories
from training.import_bag import main as import_bag_main
from training.import_tracks import main

FIRST_ORDER = 'name: walkers\ndimensions: 2\nstate: position\ncommand: velocity\ndt: 0.1\narena: null\n'
IDS = [2, 5, 11]  # non-contiguous robot ids
START = np.array([[0.0, 0.0], [1.0, -1.0], [-2.0, 3.0]])
SPEED = np.array([[1.0, 0.5], [-0.5, 0.0], [0.2, -0.3]])


def line(t):
    """Positions ``[len(t), 3, 2]`` of the three robots on straight lines."""
    return START[None] + t[:, None, None] * SPEED[None]


def run(capsys, *argv, command=main):
    """The known states here are those of central differences: ``--smooth none`` unless asked."""
    argv = [str(a) for a in argv]
    rc = command(argv if '--smooth' in argv else argv + ['--smooth', 'none'])
    out, err = capsys.readouterr()
    return rc, out, err


def write_csv(path, t, pos, keep=None, extra=None, columns=('t', 'id', 'x', 'y'), seed=0):
    """Long-format rows (shuffled) of robots ``IDS``; ``keep[k, i]`` False leaves a row out;
    ``extra`` ``[T, n, c]`` adds columns after x, y."""
    rows = []
    for k, tk in enumerate(t):
        for i, rid in enumerate(IDS):
            if keep is not None and not keep[k, i]:
                continue
            values = [tk, rid, *pos[k, i]] + ([] if extra is None else list(extra[k, i]))
            rows.append(','.join(repr(float(v)) if j != 1 else str(v) for j, v in enumerate(values)))
    np.random.default_rng(seed).shuffle(rows)
    Path(path).write_text(','.join(columns) + '\n' + '\n'.join(rows) + '\n')


@pytest.fixture
def walkers(tmp_path):
    path = tmp_path / 'walkers.yaml'
    path.write_text(FIRST_ORDER)
    return path


def test_shuffled_rows_non_contiguous_ids_and_a_gap_give_the_known_states(tmp_path, capsys, walkers):
    """10 Hz over 3 s; robot 5 missing in (1.0, 2.0) s: two segments of 11 frames each, the known
    positions (first order) and velocities (flock2d, central differences of a line are exact)."""
    t = np.round(np.arange(31) * 0.1, 10)
    keep = np.ones((31, 3), dtype=bool)
    keep[11:20, 1] = False
    write_csv(tmp_path / 'run.csv', t, line(t), keep)
    rc, out, err = run(
        capsys,
        tmp_path / 'run.csv',
        '--scenario',
        walkers,
        '--min-duration',
        0.5,
        '--out',
        tmp_path / 'w.npz',
    )
    assert rc == 0, err
    f = load_trajectories(tmp_path / 'w.npz')
    assert f.spec.name == 'walkers' and f.dt == pytest.approx(0.1)
    assert f.states.shape == (2, 11, 3, 2)
    np.testing.assert_allclose(f.states[0], line(t[:11]), atol=1e-12)
    np.testing.assert_allclose(f.states[1], line(t[20:]), atol=1e-12)
    assert f.meta['robot_ids'] == IDS and f.meta['episodes'] == [0, 0]
    assert [(g['robot'], round(g['from'], 6), round(g['to'], 6)) for g in f.meta['gaps']] == [(5, 1.0, 2.0)]
    assert 'robot 5 missing 1.000 s from t = 1.000 s to 2.000 s' in out

    rc, out, err = run(
        capsys,
        tmp_path / 'run.csv',
        '--scenario',
        'flock2d',
        '--min-duration',
        0.5,
        '--out',
        tmp_path / 'f.npz',
    )
    assert rc == 0, err
    g = load_trajectories(tmp_path / 'f.npz', scenario='flock2d')
    assert g.dt == pytest.approx(0.01) and g.states.shape == (2, 101, 3, 4)  # resampled at flock2d's dt
    np.testing.assert_allclose(g.states[0, :, :, :2], line(np.arange(101) * 0.01), atol=1e-12)
    np.testing.assert_allclose(g.states[..., 2:], np.broadcast_to(SPEED, (2, 101, 3, 2)), atol=1e-9)


def test_given_velocities_are_used_and_a_missing_column_is_refused(tmp_path, capsys):
    t = np.round(np.arange(21) * 0.05, 10)
    given = np.broadcast_to(2 * SPEED, (21, 3, 2))  # not the motion's: proves they are taken as given
    write_csv(tmp_path / 'v.csv', t, line(t), extra=given, columns=('t', 'id', 'x', 'y', 'vx', 'vy'))
    rc, out, err = run(capsys, tmp_path / 'v.csv', '--scenario', 'flock2d', '--out', tmp_path / 'v.npz')
    assert rc == 0, err
    f = load_trajectories(tmp_path / 'v.npz')
    assert f.states.shape == (1, 101, 3, 4)
    np.testing.assert_allclose(f.states[0, :, :, 2:], np.broadcast_to(2 * SPEED, (101, 3, 2)), atol=1e-12)
    assert 'given vx' in f.meta['derivation']['velocity']

    write_csv(tmp_path / 'no_y.csv', t, line(t)[..., :1], columns=('t', 'id', 'x'))
    rc, out, err = run(capsys, tmp_path / 'no_y.csv', '--scenario', 'flock2d', '--out', tmp_path / 'x.npz')
    assert rc == 2 and "no_y.csv: no column 'y'" in err and 'nothing written' in err
    write_csv(tmp_path / 'vx.csv', t, line(t), extra=given[..., :1], columns=('t', 'id', 'x', 'y', 'vx'))
    rc, out, err = run(capsys, tmp_path / 'vx.csv', '--scenario', 'flock2d', '--out', tmp_path / 'x.npz')
    assert rc == 2 and "vx.csv: column 'vy' is missing" in err
    assert not (tmp_path / 'x.npz').exists()


def test_npy_with_fps_and_a_lost_robot(tmp_path, capsys, walkers):
    """A tracker's array [T, n, 2] at 20 fps resampled to dt 0.1; NaN (a lost robot) is a gap."""
    t = np.arange(61) / 20
    arr = line(t)
    arr[20:41, 0] = np.nan  # robot 0 lost after 0.95 s until 2.05 s; the grid is k * 0.1 s
    np.save(tmp_path / 'fish.npy', arr)
    rc, out, err = run(
        capsys,
        tmp_path / 'fish.npy',
        '--fps',
        20,
        '--scenario',
        walkers,
        '--min-duration',
        0.5,
        '--out',
        tmp_path / 'n.npz',
    )
    assert rc == 0, err
    f = load_trajectories(tmp_path / 'n.npz')
    assert f.states.shape == (2, 10, 3, 2) and f.meta['robot_ids'] == [0, 1, 2]
    np.testing.assert_allclose(f.states[0], line(np.arange(10) * 0.1), atol=1e-12)
    np.testing.assert_allclose(f.states[1], line(2.1 + np.arange(10) * 0.1), atol=1e-12)
    assert f.meta['samples']['0']['non_finite'] == 21

    rc, out, err = run(capsys, tmp_path / 'fish.npy', '--scenario', walkers, '--out', tmp_path / 'x.npz')
    assert rc == 2 and 'fish.npy' in err and '--fps' in err


def test_several_files_make_one_dataset_with_episode_ids(tmp_path, capsys, walkers):
    t1, t2 = np.round(np.arange(21) * 0.1, 10), np.round(np.arange(31) * 0.1, 10)
    write_csv(tmp_path / 'a.csv', t1, line(t1))
    write_csv(tmp_path / 'b.csv', t2, line(t2) + 10.0, seed=1)
    rc, out, err = run(
        capsys, tmp_path / 'a.csv', tmp_path / 'b.csv', '--scenario', walkers, '--out', tmp_path / 'e.npz'
    )
    assert rc == 0, err
    f = load_trajectories(tmp_path / 'e.npz')
    # T = the shortest kept segment of all files (21); b's 31 frames give one window
    assert f.states.shape == (2, 21, 3, 2) and f.meta['episodes'] == [0, 1]
    assert f.meta['episode_files'] == [str(tmp_path / 'a.csv'), str(tmp_path / 'b.csv')]
    assert len(f.meta['sources']) == 2 and f.meta['sources'][1]['segments'][0]['unused_frames'] == 10
    np.testing.assert_allclose(f.states[1], line(t1) + 10.0, atol=1e-12)

    rc, out, err = run(
        capsys,
        tmp_path / 'a.csv',
        tmp_path / 'b.csv',
        '--scenario',
        walkers,
        '--length',
        11,
        '--out',
        tmp_path / 'l.npz',
    )
    assert rc == 0, err
    g = load_trajectories(tmp_path / 'l.npz')
    assert g.states.shape == (5, 11, 3, 2) and g.meta['episodes'] == [0, 0, 1, 1, 1]
    assert [tm['episode'] for tm in g.meta['trajectories']] == [0, 0, 1, 1, 1]


def test_smoothed_headings_are_the_direction_of_the_last_step_across_a_turn(tmp_path, capsys):
    """A constant-speed swarm turning by 0.6 rad at t = 1 s, recorded at 120 Hz: with the smoother
    (the default) every heading is the direction of the step that ended at its frame, as the
    first-order rollout defines it, at the turn too (the smoothed velocity there points half way)."""
    (tmp_path / 'fish.yaml').write_text(
        'name: fish\ndimensions: 2\nstate: position_heading\ncommand: velocity\ndt: 0.05\narena: null\n'
    )
    angle0, turn = np.array([0.3, 2.0, -1.2]), 0.6

    def unit(a):
        return np.stack([np.cos(a), np.sin(a)], axis=-1)

    def path(t):
        before, after = np.minimum(t, 1.0), np.maximum(t - 1.0, 0.0)
        return (
            START[None]
            + before[:, None, None] * unit(angle0)[None]
            + after[:, None, None] * unit(angle0 + turn)[None]
        )

    t = np.arange(241) / 120.0
    write_csv(tmp_path / 'fish.csv', t, path(t))
    rc, out, err = run(
        capsys,
        tmp_path / 'fish.csv',
        '--scenario',
        tmp_path / 'fish.yaml',
        '--out',
        tmp_path / 'f.npz',
        '--smooth',
        'rts',
    )
    assert rc == 0, err
    states = load_trajectories(tmp_path / 'f.npz').states[0]  # [41, 3, 4], frame k at k dt
    frames = np.arange(states.shape[0])
    want = unit(angle0[None] + np.where(frames[:, None] > 20, turn, 0.0))  # frame 20 ends at t = 1 s
    np.testing.assert_allclose(states[..., :2], path(frames * 0.05), atol=1e-6)  # float32 file
    np.testing.assert_allclose(states[..., 2:], want, atol=1e-4)


def test_single_frames_are_initial_conditions(tmp_path, capsys):
    pos = START[None]
    write_csv(tmp_path / 'i0.csv', [0.0], pos, extra=SPEED[None], columns=('t', 'id', 'x', 'y', 'vx', 'vy'))
    write_csv(
        tmp_path / 'i1.csv', [0.0], pos + 1, extra=-SPEED[None], columns=('t', 'id', 'x', 'y', 'vx', 'vy')
    )
    rc, out, err = run(
        capsys, tmp_path / 'i0.csv', tmp_path / 'i1.csv', '--scenario', 'flock2d', '--out', tmp_path / 'i.npz'
    )
    assert rc == 0, err
    f = load_trajectories(tmp_path / 'i.npz')
    assert f.states.shape == (2, 1, 3, 4) and f.meta['episodes'] == [0, 1]
    np.testing.assert_allclose(f.states[1, 0], np.concatenate([START + 1, -SPEED], axis=1))

    write_csv(tmp_path / 'p.csv', [0.5], pos)
    rc, out, err = run(capsys, tmp_path / 'p.csv', '--scenario', 'flock2d', '--out', tmp_path / 'x.npz')
    assert rc == 2 and 'p.csv: a single frame (t = 0.500 s) gives no vx, vy for robot 2' in err
    assert not (tmp_path / 'x.npz').exists()


def test_ids_beyond_a_float_s_precision_stay_apart_and_a_byte_order_mark_is_read(tmp_path, capsys, walkers):
    # Through a float, 2**53 and 2**53 + 1 were one robot (a duplicate stamp, one dropped).
    path = tmp_path / 'big.csv'
    path.write_text('\ufefft,id,x,y\n0,9007199254740993,1,2\n0,9007199254740992,3,4\n')
    rc, out, err = run(capsys, path, '--scenario', walkers, '--out', tmp_path / 'b.npz')
    assert rc == 0, err
    f = load_trajectories(tmp_path / 'b.npz')
    assert f.meta['robot_ids'] == [9007199254740992, 9007199254740993]
    np.testing.assert_array_equal(f.states, [[[[3.0, 4.0], [1.0, 2.0]]]])


@pytest.mark.parametrize(
    'cell,message',
    [
        ('id=1e30', "line 3: id = '1e30' is not an integer"),
        ('id=9223372036854775808', "line 3: id = '9223372036854775808' is not an integer"),
        ('t=1e300', "line 3: t = '1e300' is not a time in seconds within +-4.6e+09"),
        ('t=-5e9', "line 3: t = '-5e9' is not a time"),
        ('t=nan', "line 3: t = 'nan' is not a time"),
    ],
)
def test_ids_and_times_beyond_int64_are_refused(tmp_path, capsys, walkers, cell, message):
    column, value = cell.split('=')
    row = {'t': '0.1', 'id': '1', 'x': '0', 'y': '0', column: value}
    path = tmp_path / 'bad.csv'
    path.write_text('t,id,x,y\n0,1,0,0\n' + ','.join(row[c] for c in ('t', 'id', 'x', 'y')) + '\n')
    rc, out, err = run(capsys, path, '--scenario', walkers, '--out', tmp_path / 'x.npz')
    assert rc == 2 and f'bad.csv: {message}' in err and not (tmp_path / 'x.npz').exists()


def test_times_far_sparser_than_the_output_step_are_refused_not_resampled(tmp_path, capsys, walkers):
    # 10 Hz stamps in nanoseconds read as seconds: 1e8 frames of dt 0.1 s between two samples.
    path = tmp_path / 'ns.csv'
    t = np.arange(12) * 1e8
    write_csv(path, t, line(np.arange(12) * 0.1))
    rc, out, err = run(capsys, path, '--scenario', walkers, '--out', tmp_path / 'x.npz')
    assert rc == 2 and not (tmp_path / 'x.npz').exists()
    assert 'no segment is long enough to keep' in err
    assert '11000000001 frames from 12 samples of a robot: more than 1000 frames of 0.1 s a sample' in err
    # The same samples 1 s apart make 111 frames: resampled.
    write_csv(path, np.arange(12.0), line(np.arange(12) * 0.1))
    rc, out, err = run(capsys, path, '--scenario', walkers, '--out', tmp_path / 'x.npz')
    assert rc == 0, err
    assert load_trajectories(tmp_path / 'x.npz').states.shape == (1, 111, 3, 2)


def test_npy_files_that_are_not_a_positions_array_are_refused_before_reading_them(tmp_path, capsys, walkers):
    header = tmp_path / 'huge.npy'  # 14.6 TiB declared in 10 header bytes: never allocated
    with open(header, 'wb') as fh:
        np.lib.format.write_array_header_1_0(
            fh, {'descr': '<f8', 'fortran_order': False, 'shape': (10**6, 10**6, 2)}
        )
        fh.write(bytes(64))
    np.savez(tmp_path / 'archive.npz', trajectories=np.zeros((3, 2, 2)))
    (tmp_path / 'archive.npz').rename(tmp_path / 'archive.npy')
    (tmp_path / 'empty.npy').write_bytes(b'')
    np.save(tmp_path / 'none.npy', np.zeros((5, 0, 2)))
    np.save(tmp_path / 'ok.npy', np.zeros((5, 2, 2)))
    cases = [
        (
            'huge.npy',
            30,
            'huge.npy: its header declares float64 [1000000, 1000000, 2] (16000000000000 bytes)',
        ),
        ('archive.npy', 30, 'archive.npy: not a plain numeric .npy array'),
        ('empty.npy', 30, 'empty.npy: not a plain numeric .npy array'),
        (
            'none.npy',
            30,
            'none.npy: expected positions [T, n, 2] (a 2D scenario, n >= 1 robots), got float64 [5, 0, 2]',
        ),
        ('ok.npy', 1e-300, 'ok.npy: 5 frames at --fps 1e-300 last beyond the 4.6e+09 s'),
    ]
    for name, fps, message in cases:
        rc, out, err = run(
            capsys, tmp_path / name, '--fps', fps, '--scenario', walkers, '--out', tmp_path / 'x.npz'
        )
        assert rc == 2 and message in err and not (tmp_path / 'x.npz').exists(), (name, err)


def flock_lines(t):
    """flock2d states [len(t), 3, 4] on the lines above."""
    return np.concatenate([line(t), np.broadcast_to(SPEED, (t.size, 3, 2))], axis=2)


def test_several_bags_make_one_dataset_with_episode_ids(tmp_path, capsys):
    write_odometry_bag(tmp_path / 'ep00.mcap', flock_lines(np.arange(41) * 0.05), 0.05, 'flock2d')
    write_odometry_bag(tmp_path / 'ep01.mcap', flock_lines(np.arange(61) * 0.05), 0.05, 'flock2d')
    rc, out, err = run(
        capsys,
        tmp_path / 'ep00.mcap',
        tmp_path / 'ep01.mcap',
        '--scenario',
        'flock2d',
        '--topics',
        '/robot_*/odom',
        '--rate',
        20,
        '--length',
        21,
        '--out',
        tmp_path / 'b.npz',
        command=import_bag_main,
    )
    assert rc == 0, err
    f = load_trajectories(tmp_path / 'b.npz')
    assert f.states.shape == (5, 21, 3, 4) and f.meta['episodes'] == [0, 0, 1, 1, 1]
    assert [Path(p).name for p in f.meta['episode_files']] == ['ep00.mcap', 'ep01.mcap']
    assert [s['robot_ids'] for s in f.meta['sources']] == [[0, 1, 2], [0, 1, 2]]
    np.testing.assert_allclose(f.states[2], flock_lines(np.arange(21) * 0.05), atol=1e-9)
    assert 'dataset: 5 trajectories from 2 bags' in out
