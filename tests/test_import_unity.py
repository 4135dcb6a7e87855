"""Unity boids importer on small hand-written files, and on a real recording."""

import lzma
from pathlib import Path

import numpy as np
import pytest

from knode_swarm_ros.core import load_trajectories
from training.import_unity import UNITY_DIR, main, read_recording, shipped_recordings


def line(boids):
    return ''.join(
        f'({p[0]:.7f}, {p[1]:.7f}, {p[2]:.7f})({h[0]:.7f}, {h[1]:.7f}, {h[2]:.7f})' for p, h in boids
    )


def write(tmp_path, name, frames):
    path = tmp_path / name
    path.write_text('\n'.join(frames) + '\n')
    return path


def good_frames(T=14, n=3, seed=0):
    rng = np.random.default_rng(seed)
    out, states = [], []
    for _ in range(T):
        p = rng.uniform(-4, 4, (n, 3))
        h = rng.normal(size=(n, 3))
        h /= np.linalg.norm(h, axis=1, keepdims=True)
        out.append(line(zip(p, h)))
        states.append(np.round(np.concatenate([p, h], axis=1), 7))
    return out, np.array(states)


def test_good_file_round_trips_through_the_trajectory_reader(tmp_path):
    frames, states = good_frames()
    src = write(tmp_path, 'rec.txt', frames)
    assert main([str(src), '--out', str(tmp_path / 'u.npz')]) == 0
    f = load_trajectories(tmp_path / 'u.npz', scenario='boids3d')
    assert f.states.shape == (1, 4, 3, 6) and f.dt == pytest.approx(1 / 60)
    np.testing.assert_allclose(f.states[0], states[10:], atol=2e-7)
    np.testing.assert_allclose(np.linalg.norm(f.states[..., 3:], axis=-1), 1.0, atol=1e-12)
    assert f.meta['discarded_frames'] == 10 and f.meta['frames'] == [4]


def test_recordings_of_different_lengths_are_trimmed_or_kept_separate(tmp_path):
    a = write(tmp_path, 'a.txt', good_frames(T=14)[0])
    b = write(tmp_path, 'b.txt', good_frames(T=17, seed=1)[0])
    assert main([str(a), str(b), '--out', str(tmp_path / 'ab.npz')]) == 0
    assert load_trajectories(tmp_path / 'ab.npz').states.shape == (2, 4, 3, 6)
    assert main([str(a), str(b), '--out', str(tmp_path / 'sep.npz'), '--separate']) == 0
    assert load_trajectories(tmp_path / 'sep_1.npz').states.shape == (1, 7, 3, 6)


def bad_heading(fr):
    fr[3] = line([((0.0, 0.0, 0.0), (2.0, 0.0, 0.0))] * 3)


def drop_boid(fr):
    fr[7] = fr[7][: fr[7].rfind('(', 0, fr[7].rfind('('))]


@pytest.mark.parametrize(
    'mutate,message',
    [
        (lambda fr: fr.__setitem__(5, fr[5].replace(')(', ')x(', 1)), r'rec.txt:6: unexpected text'),
        (drop_boid, r'rec.txt:8: 2 boids, expected 3'),
        (bad_heading, r'rec.txt:4: heading of boid 0 has norm 2'),
        (
            lambda fr: fr.__setitem__(2, fr[2].replace(',', ', 1.0,', 1)),
            r'rec.txt:3: group 1 holds 4 numbers',
        ),
        (lambda fr: fr.__setitem__(9, fr[9].replace(',', ';', 1)), r'rec.txt:10: group 1 holds 2 numbers'),
        (
            lambda fr: fr.__setitem__(11, '(nan, 0, 0)' + fr[11][fr[11].index(')') + 1 :]),
            r'rec.txt:12: non-finite value in group 1',
        ),
        (
            lambda fr: fr.__setitem__(1, fr[1].replace('(', '(x', 1)),
            r'rec.txt:2: group 1: a number could not be read',
        ),
    ],
)
def test_malformed_lines_are_named_by_file_and_line(tmp_path, capsys, mutate, message):
    frames, _ = good_frames()
    mutate(frames)
    src = write(tmp_path, 'rec.txt', frames)
    out = tmp_path / 'bad.npz'
    assert main([str(src), '--out', str(out)]) == 2  # bad input (was 1 before the one error model)
    assert __import__('re').search(message, capsys.readouterr().err)
    assert not out.exists()


def test_too_short_and_missing_files(tmp_path, capsys):
    src = write(tmp_path, 'short.txt', good_frames(T=5)[0])
    assert main([str(src), '--out', str(tmp_path / 'x.npz')]) == 2
    assert 'need more than the 10 discarded' in capsys.readouterr().err
    assert main([str(tmp_path / 'none.txt'), '--out', str(tmp_path / 'x.npz')]) == 2
    assert 'no such file' in capsys.readouterr().err


def test_the_six_recordings_ship_inside_the_repository():
    paths = shipped_recordings()
    assert [p.name for p in paths] == [
        f'simulation_data{i}_7decimal{"_one_group" if i == 4 else ""}.txt.xz' for i in range(6)
    ]
    assert all(
        p.parent == UNITY_DIR and UNITY_DIR.parent == Path(__file__).resolve().parents[1] / 'training'
        for p in paths
    )
    assert (UNITY_DIR / 'README.md').is_file() and 'MIT' in (UNITY_DIR / 'LICENSE').read_text()


def test_compressed_and_plain_recordings_read_the_same(tmp_path):
    frames, _ = good_frames(T=14, n=3)
    plain = write(tmp_path, 'r.txt', frames)
    packed = tmp_path / 'r.txt.xz'
    packed.write_bytes(lzma.compress(plain.read_bytes()))
    np.testing.assert_array_equal(read_recording(packed), read_recording(plain))


def test_real_recording_has_the_documented_speeds():
    states = read_recording(UNITY_DIR / 'simulation_data0_7decimal.txt.xz')
    assert states.shape == (2051, 10, 6)
    speed = np.linalg.norm(np.diff(states[:, :, :3], axis=0), axis=-1) * 60
    # README: with dt = 1/60 speeds fall between 5.0 and about 8.1 (frame-time jitter aside).
    assert 4.9 < np.percentile(speed, 1) and np.percentile(speed, 99) < 8.2
    assert np.abs(states[:, :, :3]).max() < 5.0
