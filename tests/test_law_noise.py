"""A law recorded as motion capture records it (training/studies/law_noise.py): the law between its
steps, the import against the law, the paired comparison, and custom_laws over several noise
levels, rates and training seeds, resumed without redoing a step."""

import json
import os

import numpy as np
import pytest

from training.studies.law_noise import import_against_law, law_at, paired_difference
from training.studies.laws import LAWS, Law, initial_states, simulate

ROOT = os.path.join(os.path.dirname(__file__), '..')


def short(law_name='mill2d', steps=40):
    """The law, ``steps`` steps long (its name kept: custom_laws names folders by it)."""
    base = LAWS[law_name]
    return Law(base.name, base.scenario, base.command, base.start_radius_per_sqrt_n, base.start_speed, steps)


def test_the_law_between_its_steps_is_its_steps_and_moves_at_its_velocity():
    law = short(steps=10)
    truth = simulate(law, initial_states(law, 1, 4, 2), law.steps)[0]
    dt = law.scenario.dt
    pos, vel = law_at(law, truth, np.arange(law.steps) * dt)
    assert np.allclose(pos, truth[:-1, :, :2], atol=1e-12)
    assert np.allclose(vel, truth[:-1, :, 2:], atol=1e-12)
    # the velocity is the derivative of the position, also between the steps
    t = np.linspace(0.013, 0.4, 50)
    h = 1e-6
    numeric = (law_at(law, truth, t + h)[0] - law_at(law, truth, t - h)[0]) / (2 * h)
    assert np.allclose(law_at(law, truth, t)[1], numeric, atol=1e-5)


def test_a_first_order_law_between_its_steps_moves_in_straight_lines():
    """couzin2d (velocity commands, headings): at the steps the positions are the law's; between
    them the straight line at the step's constant velocity, which points along the heading the
    step ends with (the direction of the last command)."""
    law = short('couzin2d', steps=10)
    truth = simulate(law, initial_states(law, 1, 4, 2), law.steps)[0]
    dt = law.scenario.dt
    pos, vel = law_at(law, truth, np.arange(law.steps) * dt)
    assert np.allclose(pos, truth[:-1, :, :2], atol=1e-12)
    assert np.allclose(vel, truth[1:, :, 2:], atol=1e-12)  # 1 m/s along the next heading
    t = np.array([0.3 * dt, 4.6 * dt])
    mid = law_at(law, truth, t)[0]
    assert np.allclose(mid[0], 0.7 * truth[0, :, :2] + 0.3 * truth[1, :, :2], atol=1e-12)
    assert np.allclose(mid[1], 0.4 * truth[4, :, :2] + 0.6 * truth[5, :, :2], atol=1e-12)


def test_paired_difference_is_the_mean_and_standard_error_of_the_differences():
    mean, se = paired_difference([1.0, 2.0, 4.0], [0.0, 1.0, 1.0])
    assert mean == pytest.approx(5 / 3)
    assert se == pytest.approx(np.std([1.0, 1.0, 3.0], ddof=1) / np.sqrt(3))


def test_the_exact_tracks_of_a_law_import_as_the_law(tmp_path):
    from training.import_tracks import main as import_main
    from training.studies.custom_laws import write_tracks

    law = short()
    csvs = write_tracks(law, str(tmp_path / 'csv'), 2, 5, seed=4)
    scen = tmp_path / 'law.yaml'
    scen.write_text(
        'name: short\ndimensions: 2\nstate: position_velocity\ncommand: acceleration\ndt: 0.05\narena: null\n'
    )
    data = tmp_path / 'law.npz'
    assert import_main([*csvs, '--scenario', str(scen), '--out', str(data), '--smooth', 'none']) == 0
    exact = import_against_law(law, str(data), 2, 5, 4)
    assert exact['position_rms'] < 1e-7 and exact['velocity_rms'] < 1e-7
    assert np.isnan(exact['noise_estimate'])  # no smoother, no estimate
    wrong = import_against_law(law, str(data), 2, 5, 5)  # another law's swarms: far off
    assert wrong['position_rms'] > 0.1


def test_a_heading_law_recorded_as_positions_imports_near_the_law(tmp_path):
    """couzin2d as motion capture records it (positions only, 120 Hz): without noise the importer
    derives headings within a hundredth of a radian of the law's (the steps of the smoothed
    positions, which round the law's kinks a little); with 3 mm of noise it estimates the noise and
    the headings stay within a few hundredths; another law's swarms are far off."""
    from training.import_tracks import main as import_main
    from training.studies.custom_laws import write_noisy_tracks

    law = short('couzin2d', steps=60)
    scen = tmp_path / 'law.yaml'
    scen.write_text(
        'name: c\ndimensions: 2\nstate: position_heading\ncommand: velocity\ndt: 0.05\narena: null\n'
    )
    result = {}
    for noise in (0.0, 0.003):
        csvs = write_noisy_tracks(law, str(tmp_path / f'csv{noise}'), 2, 6, 4, noise, 120.0)
        data = tmp_path / f'{noise}.npz'
        assert import_main([*csvs, '--scenario', str(scen), '--out', str(data)]) == 0
        result[noise] = import_against_law(law, str(data), 2, 6, 4)
        assert np.isnan(result[noise]['velocity_rms'])  # no velocity in the state
    assert result[0.0]['position_rms'] < 0.002 and result[0.0]['heading_rms'] < 0.015
    assert 0.002 < result[0.003]['noise_estimate'] < 0.004
    assert result[0.003]['position_rms'] < 0.003 and result[0.003]['heading_rms'] < 0.04
    wrong = import_against_law(law, str(tmp_path / '0.0.npz'), 2, 6, 5)
    assert wrong['position_rms'] > 0.1 and wrong['heading_rms'] > 0.5


def test_several_noise_levels_rates_and_seeds_in_one_call_resume_and_compare(tmp_path, monkeypatch):
    """custom_laws --noise-mm 0 5 --rate 30 --train-seeds 0 1: one folder per case, one run per seed,
    the import against the law, a table paired against 0 mm; the same call again redoes nothing, and
    --report only gathers what has run."""
    import yaml

    from training.studies import custom_laws

    monkeypatch.setitem(custom_laws.LAWS, 'mill2d', short())
    with open(os.path.join(ROOT, 'config', 'train_custom.yaml')) as fh:
        recipe = yaml.safe_load(fh)
    recipe['training']['epochs'] = 1
    recipe['policy']['hidden'] = 8
    recipe['selection']['every'] = 1
    config = tmp_path / 'tiny.yaml'
    config.write_text(yaml.safe_dump(recipe))
    out = tmp_path / 'out'
    argv = ['--laws', 'mill2d', '--out', str(out), '--config', str(config), '--trajectories', '3']
    argv += ['--noise-mm', '0', '5', '--rate', '30', '--train-seeds', '0', '1', '--eval-robots', '4']
    # the law is simulated and evaluated in this process; the subprocesses only import and train
    assert custom_laws.main(argv) == 0
    results = json.loads((out / 'results.json').read_text())
    assert sorted(results) == ['mill2d_0mm_30hz', 'mill2d_5mm_30hz']
    for case in results:
        folder = out / case
        for name in (
            'run/policy.pt',
            'run_seed1/policy.pt',
            'eval_n4/results.json',
            'eval_n4_seed1/results.json',
        ):
            assert (folder / name).is_file(), (case, name)
        assert [s['seed'] for s in results[case]['seeds']] == [0, 1]
    clean, noisy = results['mill2d_0mm_30hz']['import'], results['mill2d_5mm_30hz']['import']
    assert 0.004 < noisy['noise_estimate'] < 0.006  # the importer's estimate of 5 mm
    assert clean['position_rms'] < 0.001 < noisy['position_rms'] < 0.005  # smoothed below the noise
    assert clean['velocity_rms'] < noisy['velocity_rms']
    table = (out / 'mill2d_noise.md').read_text().splitlines()
    assert len(table) == 2 + 1 + 4 and table[2].startswith('| law |')
    zero, five = [row.split(' | ') for row in table[3:5]]  # 30 Hz, seed 0: 0 mm then 5 mm
    assert zero[:3] == ['| 0', '30', '0'] and five[:3] == ['| 5', '30', '0']
    first = 6 + 2 * 3  # the columns vs 0 mm
    assert zero[first] == '' and ' ± ' in five[first]
    assert (out / 'mill2d_noise.png').stat().st_size > 0
    before = {p: p.stat().st_mtime_ns for p in out.rglob('*') if p.suffix in ('.pt', '.npz', '.csv')}
    assert custom_laws.main(argv) == 0
    after = {p: p.stat().st_mtime_ns for p in out.rglob('*') if p.suffix in ('.pt', '.npz', '.csv')}
    assert after == before
    assert json.loads((out / 'results.json').read_text()) == results
    # --report trains nothing: the seeds and noise levels not run are left out
    report = argv[:-10] + [
        '--noise-mm',
        '0',
        '5',
        '10',
        '--rate',
        '30',
        '60',
        '--train-seeds',
        '0',
        '2',
        '--report',
    ]
    assert custom_laws.main(report + ['--eval-robots', '4']) == 0
    assert sorted(p.name for p in out.iterdir() if p.is_dir()) == ['mill2d_0mm_30hz', 'mill2d_5mm_30hz']
    assert not (out / 'mill2d_0mm_30hz' / 'run_seed2').exists()
    assert len((out / 'mill2d_noise.md').read_text().splitlines()) == 2 + 1 + 2  # seed 0 only
    # a recording of another tracked swarm size: its own folder, key and table; the others stay
    table = (out / 'mill2d_noise.md').read_text()
    sized = argv[:8] + ['--noise-mm', '0', '--rate', '30', '--eval-robots', '4', '--track-robots', '4']
    assert custom_laws.main(sized) == 0
    results = json.loads((out / 'results.json').read_text())
    assert sorted(results) == ['mill2d_0mm_30hz', 'mill2d_0mm_30hz_tracks4', 'mill2d_5mm_30hz']
    assert results['mill2d_0mm_30hz_tracks4']['track_robots'] == [4]
    assert (out / 'mill2d_0mm_30hz_tracks4' / 'tracks_n4.npz').is_file()
    assert (out / 'mill2d_noise.md').read_text() == table
    assert len((out / 'mill2d_tracks4_noise.md').read_text().splitlines()) == 2 + 1 + 1
