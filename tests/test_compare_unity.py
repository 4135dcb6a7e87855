"""training.studies.compare_unity and the training.data.unity libraries: frame-time recovery, tie margins, pair
statistics and the CLI end to end."""

import dataclasses
import json

import numpy as np
import pytest

from knode_swarm_ros.core.groundtruth import boids as gt_boids
from knode_swarm_ros.core.groundtruth import simulate
from knode_swarm_ros.core.metrics import pod_kld
from training.data.unity import frames as uf
from training.data.unity import statistics as us
from training.studies import compare_unity as cu

PUBLISHED = gt_boids.get_preset('published')


def unity_like_run(seed, n, frames, rng_dt):
    """One run of our boids from spawn (frame 0 = spawn, as Unity's first line) with Unity-like
    frame times: mostly 1/60, some longer frames; returns states [frames, n, 6] and dt [frames - 1]."""
    rng = np.random.default_rng(seed)
    p, v = gt_boids.initial_boids(rng, 1, n, PUBLISHED)
    dt = np.where(rng_dt.random(frames - 1) < 0.3, rng_dt.uniform(1.0, 2.7, frames - 1), 1.0) / 60
    out = [gt_boids.observe(p, v)[0]]
    for t in range(frames - 1):
        p, v = gt_boids.boids_step(p, v, dataclasses.replace(PUBLISHED, dt=float(dt[t])))
        out.append(gt_boids.observe(p, v)[0])
    return np.stack(out), dt


def test_frame_times_are_recovered_and_the_model_reproduces_its_own_runs():
    states, dt = unity_like_run(3, 6, 120, np.random.default_rng(0))
    est, res = uf.estimate_frame_times(states[10:])
    true = dt[10:]
    # Without the spawn, dt(0) is only bounded from above; after a few frames the fit is exact.
    assert np.isnan(res[0]).all()
    np.testing.assert_allclose(est[5:], true[5:], rtol=1e-6)
    assert np.max(res[5:]) < 1e-6
    # From the spawn (every speed (5 + 8) / 2), every frame time is fitted.
    est, res = uf.estimate_frame_times(states, initial_speed=6.5)
    np.testing.assert_allclose(est, dt, rtol=1e-6)
    assert np.max(res) < 1e-6
    # The frame times matter: a fixed 1/60 is far off on the long frames.
    assert np.max(np.abs(true - 1 / 60)) > 0.5 / 60


def test_replay_at_nominal_frame_times_is_simulate():
    frames = 30
    ours = simulate('boids3d', 4, 5, frames, seed=7, preset='published', progress=False)
    replay = uf.simulate_with_frame_times(
        4, 5, frames, 7, [np.full(frames - 1, 1 / 60), np.full(frames, 1 / 60)]
    )
    np.testing.assert_array_equal(replay, ours)
    with pytest.raises(ValueError, match='frame_times'):
        uf.simulate_with_frame_times(2, 5, frames, 7, [np.full(3, 1 / 60)])


def test_decision_margins_find_ties_at_the_radii():
    params = dataclasses.replace(PUBLISHED, box=20.0)  # walls far away: only the radii decide
    frame = np.array([[-1.0, 0, 0, 0, 1, 0], [1.0, 0, 0, 0, 1, 0]])
    np.testing.assert_allclose(uf.decision_margins(frame, params), [0.5, 0.5])  # |2 - 2.5|, |2 - 1| = 1
    frame[1, 0] = -1.0 + 2.5 + 1e-7  # at the perception radius
    assert np.all(uf.decision_margins(frame, params) < uf.TIE_MARGIN)
    frame[1, 0] = -1.0 + 1.0 - 1e-7  # at the avoidance radius
    assert np.all(uf.decision_margins(frame, params) < uf.TIE_MARGIN)
    # Heading straight at a near wall: neither the sweep test nor the candidates up to the first clear one tie.
    wall = np.array([[4.0, 0, 0, 1, 0, 0], [-4.0, 0, 0, -1, 0, 0]])
    assert np.all(uf.decision_margins(wall, PUBLISHED) > uf.TIE_MARGIN)


def test_pod_kld_pairs_agree_with_the_metric():
    rng = np.random.default_rng(1)
    a, b = rng.normal(size=(3, 20, 4, 6)), rng.normal(size=(2, 20, 4, 6))
    pairs = us.pod_kld_pairs(a, b)
    assert pairs.shape == (6,)
    np.testing.assert_allclose(pairs, [pod_kld(x, y) for x in a for y in b], rtol=1e-12)
    own = us.pod_kld_pairs(np.stack([a[0], a[0]]))
    np.testing.assert_allclose(own, [0.0, 0.0], atol=1e-15)


def test_compare_groups():
    rng = np.random.default_rng(2)
    ref = rng.normal(0.0, 1.0, 6)
    same = us.compare_groups(ref, ref)
    assert same['diff'] == 0 and same['p_welch'] == pytest.approx(1.0)
    shifted = us.compare_groups(ref, rng.normal(5.0, 1.0, 30))
    assert shifted['p_welch'] < 0.01 and shifted['diff_over_spread'] > 2


def test_run_statistics_of_a_known_run():
    # Two boids 2 apart moving along +x at speed 6 (so 0.1 per 1/60 frame), 1.5 from the nearest wall.
    T = 12
    x = np.arange(T)[:, None] * 0.1
    run = np.zeros((T, 2, 6))
    run[:, 0, 0], run[:, 1, 0] = x[:, 0] - 2.0, x[:, 0] - 2.0
    run[:, 0, 1], run[:, 1, 1] = -1.0, 1.0
    run[:, 0, 2] = run[:, 1, 2] = 3.5
    run[..., 3] = 1.0
    s = us.run_statistics(run)
    assert s['speed_mean'] == pytest.approx(6.0) and s['speed_above_max'] == 0.0
    assert s['alignment'] == pytest.approx(1.0) and s['flockmates'] == 1.0 and s['isolated'] == 0.0
    assert s['subgroups_mean'] == 1.0 and s['amd_mean'] == pytest.approx(2.0)
    assert s['wall_distance'] == pytest.approx(1.5) and s['near_wall'] == 0.0
    slow = us.run_statistics(run, frame_times=np.full(T - 1, 2 / 60))  # the same path in twice the time
    assert slow['true_speed_mean'] == pytest.approx(3.0)


def write_unity(path, states):
    with open(path, 'w') as fh:
        for frame in states:
            fh.write(
                ''.join(
                    f'({b[0]:.7f}, {b[1]:.7f}, {b[2]:.7f})({b[3]:.7f}, {b[4]:.7f}, {b[5]:.7f})' for b in frame
                )
                + '\n'
            )


def test_cli_end_to_end(tmp_path):
    rng_dt = np.random.default_rng(5)
    files, dts = [], []
    for k, frames in enumerate((52, 56, 60)):
        states, dt = unity_like_run(100 + k, 5, frames, rng_dt)
        path = tmp_path / f'simulation_data{k}.txt'
        write_unity(path, states)
        files.append(str(path))
        dts.append(dt)
    out = tmp_path / 'cmp'
    assert cu.main(['--unity', *files, '--out', str(out), '--runs', '3', '--seed', '1']) == 0
    r = json.loads((out / 'results.json').read_text())
    assert r['frames'] == 42 and r['robots'] == 5 and r['runs'] == 3
    assert set(r['statistics']) == {'unity', 'ours', 'ours_unity_dt'}
    for check, dt in zip(r['unity']['model_check'], dts):
        assert check['mismatches'] == 0  # our own boids, 7 decimals: exact
        assert check['residual_percentiles']['max'] < 1e-3
        assert check['duration_s'] == pytest.approx(dt[10:].sum(), rel=1e-3)
    assert r['pod_kld']['unity || unity']['count'] == 6
    assert r['pod_kld']['unity || ours']['count'] == 9
    summary = (out / 'summary.md').read_text()
    assert '| speed_mean |' in summary and 'Model check' in summary
    for name in ('frame_times', 'speed', 'alignment_flockmates', 'amd', 'subgroups_walls', 'pod'):
        assert (out / f'unity_{name}.png').stat().st_size > 1000
    # Only our fixed-dt runs and no figures
    out2 = tmp_path / 'cmp2'
    assert (
        cu.main(
            ['--unity', *files, '--out', str(out2), '--runs', '2', '--frame-times', 'fixed', '--figures', '']
        )
        == 0
    )
    r2 = json.loads((out2 / 'results.json').read_text())
    assert set(r2['statistics']) == {'unity', 'ours'} and 'figures' not in r2
    assert not list(out2.glob('*.png'))


def test_cli_reports_bad_input(tmp_path, capsys):
    good, _ = unity_like_run(1, 3, 20, np.random.default_rng(0))
    path = tmp_path / 'bad.txt'
    write_unity(path, good)
    lines = path.read_text().splitlines()
    lines[4] = lines[4].replace('(', '[', 1)
    path.write_text('\n'.join(lines) + '\n')
    assert cu.main(['--unity', str(path), '--out', str(tmp_path / 'o')]) == 2
    assert f'{path}:5' in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        cu.main(['--unity', str(path), '--out', str(tmp_path / 'o'), '--runs', '1'])
    assert exc.value.code == 2


def test_save_runs_writes_a_unity_equivalent_test_set(tmp_path):
    from knode_swarm_ros.core import load_trajectories

    files = []
    for k in range(2):
        states, _ = unity_like_run(200 + k, 4, 40, np.random.default_rng(k))
        write_unity(tmp_path / f'u{k}.txt', states)
        files.append(str(tmp_path / f'u{k}.txt'))
    target = tmp_path / 'equiv.npz'
    assert (
        cu.main(
            [
                '--unity',
                *files,
                '--out',
                str(tmp_path / 'o'),
                '--runs',
                '3',
                '--frame-times',
                'unity',
                '--figures',
                '',
                '--save-runs',
                str(target),
            ]
        )
        == 0
    )
    data = load_trajectories(target, scenario='boids3d')
    assert data.states.shape == (3, 30, 4, 6) and list(data.split('test')) == [0, 1, 2]
    r = json.loads((tmp_path / 'o' / 'results.json').read_text())
    assert set(r['statistics']) == {'unity', 'ours_unity_dt'}


def test_unity_policies_cli(tmp_path):
    import torch

    from knode_swarm_ros.core import DEFAULTS, KNODEPolicy, PolicyConfig, export_policy, save_trajectories
    from training.studies import unity_policies

    torch.manual_seed(0)
    policy = KNODEPolicy(PolicyConfig('boids3d', **{**DEFAULTS['boids3d'], 'hidden': 8}))
    pol = tmp_path / 'p.pt'
    export_policy(policy, pol, policy.metadata())
    states = simulate('boids3d', 3, 5, 25, seed=1, preset='published', progress=False)
    data = tmp_path / 'd.npz'
    save_trajectories(data, states, 1 / 60, 'boids3d', {'split': {'train': [0], 'test': [1, 2]}})
    out = tmp_path / 'pol'
    assert (
        unity_policies.main(
            [
                '--policy',
                f'a={pol}',
                '--policy',
                f'b={pol}',
                '--data',
                f't={data}',
                '--out',
                str(out),
                '--steps',
                '15',
                '--oracle',
            ]
        )
        == 0
    )
    r = json.loads((out / 'results.json').read_text())
    assert r['data']['t']['trajectories'] == 2 and r['data']['t']['frames'] == 16
    assert r['sets']['t']['a']['pod_kld'] == r['sets']['t']['b']['pod_kld']
    assert len(r['sets']['t']['a']['pod_kld_runs']) == 2
    # The oracle is our ground truth restarted from frame 0 (speed from the first displacement): on our own
    # data it stays close, far closer than an untrained policy.
    assert r['sets']['t']['oracle']['pod_kld']['max'] < 1e-3 < r['sets']['t']['a']['pod_kld']['mean']
    assert (out / 'unity_policies_amd.png').stat().st_size > 1000 and '| truth |' in (
        out / 'summary.md'
    ).read_text()
    assert unity_policies.main(['--policy', 'nonsense', '--data', f't={data}', '--out', str(out)]) == 2
    # --rollouts 3: 3 runs per test trajectory; copy 0 of each is the single-rollout run, the
    # others start 1e-3 away (so they differ) and are compared with the same trajectory.
    out3 = tmp_path / 'pol3'
    assert (
        unity_policies.main(
            [
                '--policy',
                f'a={pol}',
                '--data',
                f't={data}',
                '--out',
                str(out3),
                '--steps',
                '15',
                '--figures',
                '',
                '--rollouts',
                '3',
            ]
        )
        == 0
    )
    r3 = json.loads((out3 / 'results.json').read_text())
    kl3 = r3['sets']['t']['a']['pod_kld_runs']
    assert r3['data']['t']['rollouts'] == 3 and len(kl3) == 6
    np.testing.assert_allclose(kl3[0::3], r['sets']['t']['a']['pod_kld_runs'], rtol=1e-5)  # float32 batches
    assert kl3[1] != kl3[0] and kl3[4] != kl3[3]
    assert '2 runs x 3 rollouts' in (out3 / 'summary.md').read_text()
    with pytest.raises(SystemExit) as exc:  # argparse's usage error: status 2
        unity_policies.main(
            ['--policy', f'a={pol}', '--data', f't={data}', '--out', str(out3), '--rollouts', '0']
        )
    assert exc.value.code == 2


def test_resample_uniform_known_answers():
    from training.studies.unity_retime import resample_uniform

    rng = np.random.default_rng(4)
    states = rng.normal(size=(20, 3, 6))
    # Uniform frame times: the frames themselves from `start` on.
    np.testing.assert_allclose(resample_uniform(states, np.full(19, 1 / 60), start=5), states[5:], atol=1e-12)
    # Straight motion at speed 6 along +x with frame times 1, 2, 1, 3 (x 1/60): samples every 1/60 s lie on the line.
    dt = np.array([1.0, 2.0, 1.0, 3.0]) / 60
    t = np.concatenate([[0], np.cumsum(dt)])
    run = np.zeros((5, 1, 6))
    run[:, 0, 0] = 6 * t
    run[:, 0, 3] = 1.0
    run[2:, 0, 3:] = [0.0, 1.0, 0.0]  # heading label changes at frame 2
    out = resample_uniform(run, dt)
    np.testing.assert_allclose(out[:, 0, 0], 6 * np.arange(8) / 60, atol=1e-12)
    # at 2/60 s (inside the second step, which ends at frame 2) the heading is frame 2's; at 3/60 s (= frame 2) too
    np.testing.assert_allclose(out[1, 0, 3:], [1, 0, 0])
    np.testing.assert_allclose(out[2, 0, 3:], [0, 1, 0])
    with pytest.raises(ValueError):
        resample_uniform(run, dt[:3])


def test_unity_retime_cli(tmp_path):
    from knode_swarm_ros.core import load_trajectories
    from training.studies import unity_retime

    files, dts = [], []
    for k in range(2):
        states, dt = unity_like_run(300 + k, 4, 50, np.random.default_rng(10 + k))
        write_unity(tmp_path / f'u{k}.txt', states)
        files.append(str(tmp_path / f'u{k}.txt'))
        dts.append(dt)
    out = tmp_path / 'retimed.npz'
    assert unity_retime.main([*files, '--out', str(out)]) == 0
    data = load_trajectories(out, scenario='boids3d')
    T = min(int(np.floor(dt[10:].sum() * 60 + 1e-9)) + 1 for dt in dts)
    assert data.states.shape == (2, T, 4, 6) and data.dt == pytest.approx(1 / 60)
    # Speeds from the retimed positions are the boids' true speeds (within [5, 8] up to chords at frame boundaries).
    s = np.linalg.norm(np.diff(data.states[..., :3], axis=1), axis=-1) * 60
    assert s.max() <= 8.0 + 1e-3 and np.percentile(s, 5) > 4.9
    assert unity_retime.main([str(tmp_path / 'missing.txt'), '--out', str(out)]) == 2
