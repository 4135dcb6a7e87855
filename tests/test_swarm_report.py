"""The launcher's closing summary (make demo): the ground-truth swarm from the recording's start
beside the learnt one, in the summary and the figure. No ROS: a recording on disk."""

from types import SimpleNamespace

import numpy as np

from knode_swarm_ros.core import amd, avd, save_trajectories
from knode_swarm_ros.core.groundtruth import TannerSwarm, follow, simulate
from knode_swarm_ros.nodes.swarm.report import summarise


def _plan(tmp_path, record, **kw):
    fields = dict(
        record=record,
        figure=tmp_path / 'fig.png',
        run_dir=tmp_path / 'logs',
        mode='lockstep',
        ground_truth=False,
        variant='paper',
    )
    fields.update(kw)
    return SimpleNamespace(**fields)


def _recording(tmp_path, states, dt):
    path = tmp_path / 'run.npz'
    save_trajectories(path, states[None], dt, 'flock2d', {'split': {'train': [], 'test': [0]}})
    return path


def test_follow_is_the_tanner_swarm_from_that_start_at_the_given_period():
    z = simulate('flock2d', 1, 6, 11, seed=5, progress=False)[0]  # [11, 6, 4] at 0.01 s
    np.testing.assert_array_equal(follow('flock2d', z[0], 11, 0.01), z)
    np.testing.assert_array_equal(follow('flock2d', z[0], 3, 0.05), z[[0, 5, 10]])  # substeps at 0.01 s
    swarm = TannerSwarm(z[0][None], 'paper', dt=0.015)
    np.testing.assert_array_equal(follow('flock2d', z[0], 2, 0.015)[1], swarm.step()[0])
    for bad in (
        lambda: follow('boids3d', np.zeros((3, 6)), 5, 0.025),  # not a whole multiple of 1/60 s
        lambda: follow('flock2d', np.zeros((3, 3)), 5, 0.1),
        lambda: follow('flock2d', np.full((3, 4), np.nan), 5, 0.01),
    ):
        try:
            bad()
        except ValueError:
            continue
        raise AssertionError('accepted a bad argument')


def test_summary_and_figure_put_the_ground_truth_beside_the_learnt_swarm(tmp_path, capsys):
    # a "learnt" run that is not the ground truth: the Tanner swarm with its velocities damped
    truth = simulate('flock2d', 1, 8, 300, seed=7, progress=False)[0]
    run = truth.copy()
    run[:, :, 2:] *= 0.5
    run[0] = truth[0]  # the same start
    plan = _plan(tmp_path, _recording(tmp_path, run, 0.01))
    info = summarise(plan)
    gt = info['ground_truth']
    assert (
        set(gt) == {'variant', 'avd_end', 'amd_end', 'avd_last10pct', 'amd_last10pct'}
        and gt['variant'] == 'paper'
    )
    tail = truth[-30:]  # last 10 % of 300 frames
    assert np.isclose(gt['avd_last10pct'], np.mean([avd(f[:, 2:]) for f in tail]))
    assert np.isclose(gt['amd_last10pct'], np.mean([amd(f[:, :2]) for f in tail]))
    assert np.isclose(gt['avd_end'], avd(truth[-1, :, 2:]))
    assert not np.isclose(info['avd_last10pct'], gt['avd_last10pct'])  # the run's own figures stay its own
    out = capsys.readouterr().out + capsys.readouterr().err
    assert 'ground truth from the same start' in out
    import matplotlib.image as mpimg

    wide = mpimg.imread(plan.figure)
    assert wide.shape[1] == 2000  # 4 panels x 5 in x 100 dpi
    # a run that is itself the ground truth, and boids3d, get no second swarm (3 panels)
    plan2 = _plan(tmp_path, plan.record, figure=tmp_path / 'gt.png', ground_truth=True)
    assert 'ground_truth' not in summarise(plan2)
    assert mpimg.imread(plan2.figure).shape[1] == 1500


def test_follow_boids3d_is_the_boids_swarm_at_spawn_speed():
    """The boids3d figure and summary get their ground truth too (the boids from the same start)."""
    from knode_swarm_ros.core.groundtruth import BoidsSwarm

    z = simulate('boids3d', 1, 6, 8, seed=3, progress=False)[0]
    swarm = BoidsSwarm.from_observation(z[0][None])
    np.testing.assert_array_equal(follow('boids3d', z[0], 3, 1 / 60)[1], swarm.step()[0])
    assert follow('boids3d', z[0], 3, 2 / 60).shape == (3, 6, 6)
