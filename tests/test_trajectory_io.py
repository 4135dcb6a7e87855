"""Trajectory files: round trip, validation with named fields, atomic writes."""

import json

import numpy as np
import pytest

from knode_swarm_ros.core import TrajectoryError, load_trajectories, parse_trajectory_ref, save_trajectories


def states(S=2, T=5, n=3, d=4, seed=0):
    return np.random.default_rng(seed).normal(size=(S, T, n, d))


def test_round_trip(tmp_path):
    x = states()
    meta = {'generator': 'test', 'split': {'train': [0], 'test': [1]}}
    save_trajectories(tmp_path / 'a.npz', x, 0.01, 'flock2d', meta)
    f = load_trajectories(tmp_path / 'a.npz', scenario='flock2d')
    np.testing.assert_array_equal(f.states, x)
    assert f.dt == 0.01 and f.scenario == 'flock2d' and f.meta == meta
    np.testing.assert_array_equal(f.split('test'), [1])


def test_single_frame_is_valid(tmp_path):
    save_trajectories(tmp_path / 'one.npz', states(T=1), 0.01, 'flock2d')
    assert load_trajectories(tmp_path / 'one.npz').states.shape == (2, 1, 3, 4)


@pytest.mark.parametrize(
    'x,dt,scenario,message',
    [
        (states(d=6), 0.01, 'flock2d', 'd = 6'),
        (states(d=3), 0.01, 'flock2d', 'd = 3'),  # too few entries as well as too many
        (states()[0], 0.01, 'flock2d', r'\[trajectories, T, n, d\]'),
        (states(), 0.0, 'flock2d', "'dt'"),
        (states(), 0.01, 'swarm9d', "'scenario'"),
    ],
)
def test_invalid_contents_are_refused_on_write(tmp_path, x, dt, scenario, message):
    with pytest.raises(TrajectoryError, match=message):
        save_trajectories(tmp_path / 'bad.npz', x, dt, scenario)
    assert not list(tmp_path.iterdir())


def test_reader_names_what_is_wrong(tmp_path):
    x = states()
    x[1, 2, 0, 3] = np.nan
    np.savez(tmp_path / 'nan.npz', states=x, dt=0.01, scenario='flock2d', meta='{}')
    with pytest.raises(TrajectoryError, match=r'non-finite value at index \(1, 2, 0, 3\)'):
        load_trajectories(tmp_path / 'nan.npz')
    np.savez(tmp_path / 'nometa.npz', states=states(), dt=0.01, scenario='flock2d')
    with pytest.raises(TrajectoryError, match='missing field.*meta'):
        load_trajectories(tmp_path / 'nometa.npz')
    (tmp_path / 'junk.npz').write_text('hello')
    with pytest.raises(TrajectoryError, match='not a readable'):
        load_trajectories(tmp_path / 'junk.npz')
    with pytest.raises(TrajectoryError, match='no such file'):
        load_trajectories(tmp_path / 'missing.npz')
    save_trajectories(tmp_path / 'b.npz', states(d=6), 1 / 60, 'boids3d')
    with pytest.raises(TrajectoryError, match="expected 'flock2d'"):
        load_trajectories(tmp_path / 'b.npz', scenario='flock2d')


def test_failed_write_keeps_the_previous_file(tmp_path):
    path = tmp_path / 'keep.npz'
    save_trajectories(path, states(), 0.01, 'flock2d', {'v': 1})
    with pytest.raises(TypeError):
        save_trajectories(path, states(seed=1), 0.01, 'flock2d', {'v': object()})
    assert json.loads(str(np.load(path)['meta'])) == {'v': 1}
    assert [p.name for p in tmp_path.iterdir()] == ['keep.npz']


def test_parse_trajectory_ref():
    assert parse_trajectory_ref('data/x.npz:7') == ('data/x.npz', 7)
    assert parse_trajectory_ref('data/x.npz') == ('data/x.npz', 0)


@pytest.mark.parametrize('umask', [0o022, 0o077, 0o002])
def test_a_written_file_has_the_usual_permissions(tmp_path, umask):
    """0666 less the umask (not mkstemp's 0600), whatever the umask."""
    import os

    old = os.umask(umask)
    try:
        save_trajectories(tmp_path / 't.npz', states(), 0.01, 'flock2d')
    finally:
        os.umask(old)
    assert (tmp_path / 't.npz').stat().st_mode & 0o777 == 0o666 & ~umask
