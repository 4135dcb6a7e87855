"""The offline smoother (training.data.smoother), the importers' default derivation: known signals,
the noise level it estimates, and samples placed by their stamps (a mocap-like bag, written by
training.studies.noise_study)."""

from pathlib import Path

import numpy as np
import pytest

from knode_swarm_ros.core import load_trajectories
from training.data.smoother import _RATIOS, estimate_noise, smooth, smooth_tracks
from training.import_bag import main as import_bag_main
from training.studies.noise_study import MocapNoise, truth_at, write_mocap_bag

CONFIG = Path(__file__).resolve().parents[1] / 'config' / 'train_flock2d.yaml'


def jittered(duration, rate, jitter, drop, rng):
    t = np.arange(0.0, duration, 1.0 / rate) + rng.normal(0.0, jitter, int(np.ceil(duration * rate)))
    t = np.sort(t)
    return t[rng.random(t.size) >= drop]


def test_a_constant_acceleration_track_is_recovered_at_any_time():
    """The motion model's own motion: exact samples give back positions and velocities between the
    samples (up to the assumed noise floor); with 2 mm noise at 120 Hz the velocity error is a few mm/s,
    where central differences of the same samples err by ~0.2 m/s."""
    rng = np.random.default_rng(0)
    t = jittered(5.0, 120.0, 0.5e-3, 0.01, rng)
    p0, v0, a = np.array([1.0, -2.0]), np.array([0.5, 0.3]), np.array([-0.2, 0.4])

    def truth(times):
        return p0 + v0 * times[:, None] + 0.5 * a * times[:, None] ** 2, v0 + a * times[:, None]

    grid = np.linspace(t[0], t[-1], 333)
    fits, record = smooth_tracks([(t, truth(t)[0])], 0.05)
    p, v = fits[0].at(grid)
    assert np.abs(p - truth(grid)[0]).max() < 1e-6
    assert np.abs(v - truth(grid)[1]).max() < 1e-5
    assert np.abs(fits[0].a - a).max() < 1e-4
    assert record['noise_std'] < 1e-9

    y = truth(t)[0] + rng.normal(0.0, 0.002, (t.size, 2))
    fits, record = smooth_tracks([(t, y)], 0.05)
    p, v = fits[0].at(grid[5:-5])
    assert np.sqrt(np.mean((v - truth(grid[5:-5])[1]) ** 2)) < 0.01
    assert np.sqrt(np.mean((p - truth(grid[5:-5])[0]) ** 2)) < 0.001  # below the 2 mm noise


@pytest.mark.parametrize('samples', [2, 3])
def test_two_or_three_samples_give_their_straight_line_at_every_process_noise(samples):
    # Once a Cholesky failure ("6-th leading minor not positive definite") at ratios 1e-10, 1e-9,
    # 1e-6 and 1e-5, the 1e-9 being what the likelihood search returns without a 4-sample track.
    t = np.array([0.0, 0.5, 1.0])[:samples]
    y = np.array([[0.0, 0.0], [1.0, 2.0], [2.0, 4.0]])[:samples]
    for ratio in _RATIOS:
        track = smooth(t, y, ratio)
        np.testing.assert_allclose(track.p, y, atol=1e-6, err_msg=f'ratio {ratio:g}')
        np.testing.assert_allclose(
            track.v, np.broadcast_to([2.0, 4.0], y.shape), atol=1e-5, err_msg=f'ratio {ratio:g}'
        )


@pytest.mark.parametrize('sigma', [0.0005, 0.001, 0.002, 0.005])
def test_the_estimated_noise_level_is_within_20_percent(sigma):
    """Gaussian noise on a curving, accelerating 2D track, jittered stamps and 1 % drops at 120 Hz,
    three robots of 10 s: the estimate from the data is within 20 % of the truth."""
    rng = np.random.default_rng(int(sigma * 1e5))
    tracks = []
    for i in range(3):
        t = jittered(10.0, 120.0, 0.5e-3, 0.01, rng)
        y = np.stack([np.sin(0.8 * t + i) * (1 + 0.1 * t), np.cos(1.1 * t) + 0.2 * t], axis=1)
        tracks.append((t, y + rng.normal(0.0, sigma, y.shape)))
    estimate, count = estimate_noise(tracks, 4.5 / 120.0)
    assert count > 5000
    assert abs(estimate / sigma - 1.0) < 0.2


def flock_truth(T=1200, dt=0.01, n=3):
    """flock2d states ``[T, n, 4]``: robots on circles of radius 1.5 m at 1 rad/s."""
    t = np.arange(T) * dt
    states = np.empty((T, n, 4))
    for i in range(n):
        a = t + 2 * np.pi * i / n
        states[:, i, :2] = np.stack([3 * i + 1.5 * np.cos(a), 1.5 * np.sin(a)], axis=1)
        states[:, i, 2:] = 1.5 * np.stack([-np.sin(a), np.cos(a)], axis=1)
    return states


def import_mocap(tmp_path, capsys, mocap, name='m', extra=()):
    states, dt = flock_truth(), 0.01
    truth = write_mocap_bag(tmp_path / f'{name}.mcap', states, dt, mocap, np.random.default_rng(1))
    rc = import_bag_main(
        [str(tmp_path / f'{name}.mcap'), '--scenario', 'flock2d', '--topics', '/mocap/robot_*/pose']
        + ['--rate', '50', '--out', str(tmp_path / f'{name}.npz'), *extra]
    )
    out, err = capsys.readouterr()
    assert rc == 0, err
    return load_trajectories(tmp_path / f'{name}.npz'), states, dt, truth, out


def test_jittered_late_stamps_are_placed_by_stamp(tmp_path, capsys):
    """Noise-free PoseStamped at 120 Hz with 0.5 ms stamp jitter, and receive delays that put some
    messages in the bag after a later one: each sample counts at its header stamp, so the imported
    positions and velocities are the truth's at the grid times (to ~1e-5), which they could not be
    if the samples were placed by arrival order or on a uniform grid (0.5 ms at 1.5 m/s is 0.75 mm)."""
    mocap = MocapNoise(noise=0.0, drop=0.0, latency=20e-3)
    f, states, dt, truth, out = import_mocap(tmp_path, capsys, mocap)
    assert truth['late'] > 10
    assert f.meta['messages']['reordered'] == truth['late'] and 'placed by stamp' in out
    t0 = f.meta['t0_ns'] * 1e-9 + f.meta['grid']['anchor']
    for s, tm in enumerate(f.meta['trajectories']):
        times = t0 + tm['grid_index'] * f.dt + np.arange(f.states.shape[1]) * f.dt
        pos, vel = truth_at(states, dt, times, 2)
        assert np.abs(f.states[s, :, :, :2] - pos).max() < 2e-5
        assert np.abs(f.states[s, 2:-2, :, 2:] - vel[2:-2]).max() < 2e-3


def test_the_importer_reports_the_noise_it_estimated(tmp_path, capsys):
    """2 mm at 120 Hz with drops and an occlusion: the meta and the log give the estimate (within
    20 %), and the smoothed velocities beat central differences of the same bag."""
    mocap = MocapNoise(noise=0.002, occlusion=(1, 5.0, 0.4))
    f, states, dt, _, out = import_mocap(tmp_path, capsys, mocap)
    assert abs(f.meta['noise']['noise_std'] / 0.002 - 1) < 0.2
    assert 'noise: position noise estimated at' in out
    assert f.meta['derivation']['smoothing']['method'] == 'rts'
    assert len(f.meta['gaps']) == 1
    g, *_ = import_mocap(tmp_path, capsys, mocap, name='fd', extra=['--smooth', 'none'])

    def velocity_error(file):
        t0 = file.meta['t0_ns'] * 1e-9 + file.meta['grid']['anchor']
        errs = []
        for s, tm in enumerate(file.meta['trajectories']):
            times = t0 + tm['grid_index'] * file.dt + np.arange(file.states.shape[1]) * file.dt
            errs.append(file.states[s, :, :, 2:] - truth_at(states, dt, times, 2)[1])
        return float(np.sqrt(np.mean(np.concatenate(errs) ** 2)))

    assert velocity_error(f) < 0.01 and 5 * velocity_error(f) < velocity_error(g)


def test_validation_holds_out_whole_episodes():
    """Trajectories of several recordings (meta.episodes): validation takes whole episodes, the
    last ones, by fraction or count; no episode has windows on both sides."""
    from knode_swarm_ros.core.trajectory import TrajectoryFile
    from training.learning.config import load_config
    from training.learning.trainer import split_data

    episodes = [0, 0, 0, 1, 2, 2, 3, 3, 3, 4]
    S = len(episodes)
    data = TrajectoryFile(
        np.zeros((S, 5, 3, 4)), 0.01, 'flock2d', {'episodes': episodes, 'split': {'train': list(range(S))}}
    )
    for overrides, held in (({}, {4}), ({'val_fraction': 0.6}, {2, 3, 4}), ({'val_trajectories': 2}, {3, 4})):
        cfg = load_config(str(CONFIG), {f'data.{k}': v for k, v in overrides.items()})
        lines = []
        split = split_data(cfg, data, log=lines.append)
        val = {episodes[i] for i in split['val_idx']}
        train = {episodes[i] for i in split['train_idx']}
        assert val == held and not (val & train) and len(split['val_idx']) + len(split['train_idx']) == S
        assert 'episodes held out whole' in lines[-1]


def test_noisy_recordings_import_and_train_in_seconds(tmp_path, capsys):
    """End to end on what mocap records: three short noisy episodes (2 mm, jitter, drops, an
    occlusion) imported together with the defaults, then two epochs of training that validate on
    one whole episode."""
    from training import train

    bags = []
    for e in range(3):
        mocap = MocapNoise(noise=0.002, occlusion=(0, 3.0, 0.4) if e == 1 else None)
        write_mocap_bag(tmp_path / f'ep{e}.mcap', flock_truth(T=600), 0.01, mocap, np.random.default_rng(e))
        bags.append(str(tmp_path / f'ep{e}.mcap'))
    rc = import_bag_main(
        bags
        + ['--scenario', 'flock2d', '--topics', '/mocap/robot_*/pose', '--rate', '100']
        + ['--length', '100', '--out', str(tmp_path / 'ep.npz')]
    )
    out, err = capsys.readouterr()
    assert rc == 0, err
    f = load_trajectories(tmp_path / 'ep.npz')
    assert sorted(set(f.meta['episodes'])) == [0, 1, 2]
    assert all(abs(src['noise']['noise_std'] / 0.002 - 1) < 0.2 for src in f.meta['sources'])
    config = CONFIG
    sets = ['training.epochs=2', 'policy.hidden=16', 'selection.every=2', 'selection.trajectories=1']
    sets += ['selection.steps=20', 'training.batch_size=256']
    rc = train.main(
        ['--config', str(config), '--data', str(tmp_path / 'ep.npz'), '--out', str(tmp_path / 'run')]
        + [a for s in sets for a in ('--set', s)]
        + ['--no-progress']
    )
    out, err = capsys.readouterr()
    assert rc == 0, err
    assert 'episodes held out whole' in out + err
    assert (tmp_path / 'run' / 'policy.pt').is_file()


@pytest.mark.parametrize('sigma', [0.002, 0.01])
def test_model_selection_ranks_the_same_on_noisy_validation_data(sigma):
    """Selection compares rollouts with the validation data only through their final amd (positions,
    averaged over pairs and the last frames), never their noisy velocities: the score of two
    candidates moves by far less than their difference when the validation data carry mocap noise."""
    from knode_swarm_ros.core import get_scenario
    from training.assessment.scores import final_metrics, selection_score

    spec = get_scenario('flock2d')
    truth = np.stack([flock_truth(T=300, n=5)] * 4)  # [S, T, n, 4]
    rng = np.random.default_rng(0)
    noisy = truth + np.concatenate(
        [rng.normal(0.0, sigma, truth.shape[:-1] + (2,)), rng.normal(0.0, 0.05, truth.shape[:-1] + (2,))], -1
    )
    good, bad = truth.copy(), truth.copy()
    bad[..., :2] *= 1.1  # 10 % too far apart
    for cand in (good, bad):
        clean_score = selection_score(spec, final_metrics(spec, cand, truth))
        noisy_score = selection_score(spec, final_metrics(spec, cand, noisy))
        assert abs(noisy_score - clean_score) < 0.01
    scores = [selection_score(spec, final_metrics(spec, c, noisy)) for c in (good, bad)]
    assert scores[0] < scores[1] - 0.05


def test_the_noise_study_tabulates_and_plots_its_rows(tmp_path):
    from training.studies.noise_study import case_name, figure, summary

    def stat(mean):
        return {'mean': mean, 'std': 0.001}

    final = {'avd_final': stat(0.01), 'amd_final': stat(0.77), 'truth_amd_final': stat(0.7)}
    final['truth_avd_final'] = stat(0.006)
    row = {'case': case_name(2, 120), 'noise_mm': 2.0, 'rate_hz': 120.0, 'objective': 'one_step'}
    row.update({'noise_estimate_mm': 2.01, 'final': final, 'train_minutes': 1.5, 'load': [3.0, 2.5]})
    assert row['case'] == 'n2mm_120hz'
    table = summary([row])
    assert (
        '| 2 | 120 | one_step | 2.01 | 0.0100 ± 0.0010 | 0.770 | 0.700 | +10.0 % | 1.5 | 3.0-2.5 |' in table
    )
    figure([row], tmp_path / 'f.png')
    assert (tmp_path / 'f.png').stat().st_size > 0
