"""Baselines of the controller comparison: the local Tanner law and the interaction-kernel fit."""

import json

import numpy as np
import pytest

from knode_swarm_ros.core import neighbour_matrix, rollout, save_trajectories
from knode_swarm_ros.core.groundtruth.tanner import local_tanner_acceleration, tanner_acceleration
from training.assessment.kernel_baseline import KernelModel, fit_kernel


def _swarm(rng, S, n, spread=2.0):
    return np.concatenate([rng.uniform(-spread, spread, (S, n, 2)), rng.normal(0, 1, (S, n, 2))], -1)


def test_local_tanner_with_every_robot_in_range_is_the_global_law():
    z = _swarm(np.random.default_rng(0), 3, 7)
    Y, mask = neighbour_matrix(z, z, 2, 1e9, 7)
    got = local_tanner_acceleration(Y.reshape(-1, 7, 4), mask.reshape(-1, 7)).reshape(3, 7, 2)
    np.testing.assert_allclose(got, tanner_acceleration(z), rtol=0, atol=1e-12)


def test_local_tanner_sees_only_its_rows_and_clips():
    # robot 0 at the origin, robot 1 at distance 2 moving: one neighbour row, known answer
    Y = np.array([[[0.0, 0.0, 0.0, 0.0], [2.0, 0.0, 1.0, -1.0], [0.0, 0.0, 0.0, 0.0]]])
    mask = np.array([[True, True, False]])
    r = 2.0
    want = np.array([[1.0 - 2 * (1 / r**2 - 1 / r**4) * -2.0, -1.0]])  # alignment + attraction towards +x
    np.testing.assert_allclose(local_tanner_acceleration(Y, mask), want)
    np.testing.assert_allclose(local_tanner_acceleration(Y, mask, clip=0.5), np.clip(want, -0.5, 0.5))
    # a coincident neighbour adds alignment only, never a NaN
    Y[0, 1, :2] = 0.0
    np.testing.assert_allclose(local_tanner_acceleration(Y, mask), [[1.0, -1.0]])


def test_kernel_fit_recovers_a_known_kernel():
    edges = np.linspace(0, 3, 7)
    true = KernelModel(
        edges, np.array([1.0, 0.8, 0.6, 0.4, 0.2, 0.1]), np.array([-3.0, -1, 0.2, 0.5, 0.3, 0.1])
    )
    z0 = _swarm(np.random.default_rng(1), 5, 8)
    states = rollout(true, z0, 150, 'flock2d', 3.0, 5, 0, 0.01)
    fit = fit_kernel(states, 0.01, 3.0, 5, 0, bins=6)
    assert np.all(fit.samples_per_bin > 0)
    np.testing.assert_allclose(fit.phi_a, true.phi_a, atol=1e-5)
    np.testing.assert_allclose(fit.phi_p, true.phi_p, atol=1e-5)
    # stride and tau: the same law seen through a delayed network and every 3rd frame
    states = rollout(true, z0, 150, 'flock2d', 3.0, 5, 2, 0.01)
    fit = fit_kernel(states, 0.01, 3.0, 5, 2, bins=6, stride=3)
    np.testing.assert_allclose(fit.phi_a, true.phi_a, atol=1e-5)
    assert json.loads(fit.to_json())['phi_p'] == pytest.approx(true.phi_p.tolist(), abs=1e-5)


def test_kernel_fit_leaves_out_saturated_samples_and_clips():
    edges = np.linspace(0, 3, 4)
    true = KernelModel(edges, np.array([1.0, 0.5, 0.2]), np.array([-8.0, 0.5, 0.1]), command_limit=3.0)
    states = rollout(
        true, _swarm(np.random.default_rng(2), 4, 6, spread=1.5), 100, 'flock2d', 3.0, 4, 0, 0.01
    )
    implied = np.abs(states[:, 1:, :, 2:] - states[:, :-1, :, 2:]).max(-1) / 0.01
    assert 0.2 < np.mean(implied >= 3.0 - 1e-6) < 0.6  # many samples are saturated
    # fitted to every sample the kernel is biased; without the saturated ones it is exact
    biased = fit_kernel(states, 0.01, 3.0, 4, 0, bins=3)
    assert abs(biased.phi_a[0] - 1.0) > 0.1
    fit = fit_kernel(states, 0.01, 3.0, 4, 0, bins=3, command_limit=3.0)
    np.testing.assert_allclose(fit.phi_a, true.phi_a, atol=1e-5)
    np.testing.assert_allclose(fit.phi_p, true.phi_p, atol=1e-5)
    Y = np.array([[[0.0, 0, 0, 0], [0.5, 0, 0, 0]]])  # -8 * 0.5 = -4: clipped at -3
    np.testing.assert_allclose(fit(Y, np.array([[True, True]])), [[-3.0, 0.0]])


def test_compare_command_writes_the_table_for_every_controller(tmp_path, untrained_policies):
    from knode_swarm_ros.core.groundtruth import simulate
    from training.studies.compare_controllers import main

    states = simulate('flock2d', 3, 5, 30, 0, progress=False)
    data = tmp_path / 'd.npz'
    save_trajectories(data, states, 0.01, 'flock2d', {'split': {'train': [0, 1], 'test': [2]}})
    out = tmp_path / 'cmp'
    docs = tmp_path / 'docs'
    rc = main(
        [
            '--data',
            str(data),
            '--out',
            str(out),
            '--policy',
            f'a={untrained_policies["flock2d"]}',
            '--sizes',
            '4',
            '6',
            '--ics',
            '2',
            '--steps',
            '20',
            '--docs',
            str(docs),
        ]
    )
    assert rc == 0
    assert (docs / 'compare_controllers_flock2d.md').read_text() == (out / 'table.md').read_text()
    assert (docs / 'figures' / 'compare_controllers_flock2d.png').read_bytes() == (
        out / 'compare.png'
    ).read_bytes()
    r = json.loads((out / 'results.json').read_text())
    names = {(row['robots'], row['controller']) for row in r['rows']}
    assert names == {(n, c) for n in (4, 6) for c in ('ground_truth', 'a', 'local_tanner', 'kernel')}
    assert (out / 'compare.png').stat().st_size > 0
    table = (out / 'table.md').read_text()
    assert table.count('| 6 |') == 4
    assert main(['--data', str(data), '--out', str(out), '--policy', 'nonsense']) == 2


# ----------------------------------------------------------------------------- training.studies.gains (why scaling fails)


def test_row_gains_of_the_local_tanner_law_are_its_known_gains():
    """Velocity gains -(k - 1), 1, ..., 1; position gains d/dr of the pair force at each row (one
    neighbour at distance 2 on the x axis: the x row derivative of -2 (1/r^2 - 1/r^4) r_ij)."""
    from training.studies.gains import row_gains

    rng = np.random.default_rng(0)
    Y = np.concatenate([rng.uniform(-2, 2, (7, 5, 2)), rng.normal(size=(7, 5, 2)) * 0.1], -1)
    mask = np.ones((7, 5), bool)
    g = row_gains(lambda Y, m: local_tanner_acceleration(Y, m), Y, mask)
    np.testing.assert_allclose(g['velocity'], [-4.0, 1, 1, 1, 1], atol=1e-6)
    np.testing.assert_allclose(g['position'].sum(), 0.0, atol=1e-5)  # translation invariance
    one = np.array([[[0.0, 0, 0, 0], [2.0, 0, 0, 0]]])
    g1 = row_gains(lambda Y, m: local_tanner_acceleration(Y, m), one, np.ones((1, 2), bool), eps=1e-5)
    # with (x, y) = p_0 - p_1 = (-2, 0): u_x = -2 (1/r^2 - 1/r^4) x and d u_y / d y = -2 (1/r^2 - 1/r^4);
    # moving p_1 moves (x, y) the other way, so the gain is -(d u_x / d x + d u_y / d y) / 2
    ux = lambda x: -2 * (1 / x**2 - 1 / x**4) * x  # noqa: E731
    uy_dy = -2 * (1 / 4 - 1 / 16)  # d u_y / d(y_0 - y_1) at y = 0
    want = (-(ux(-2 + 1e-6) - ux(-2 - 1e-6)) / 2e-6 - uy_dy) / 2
    np.testing.assert_allclose(g1['position'][1], want, rtol=1e-6)


def test_velocity_field_recovers_a_known_rotation_and_expansion():
    from training.studies.gains import velocity_field

    rng = np.random.default_rng(1)
    r = rng.normal(size=(40, 2)) * 3
    A = np.array([[0.05, -0.2], [0.2, 0.05]])  # div 0.05, omega 0.2
    z = np.concatenate([r + 7.0, r @ A.T + np.array([1.0, -2.0])], 1)  # any offset, any common velocity
    f = velocity_field(z)
    assert abs(f['div'] - 0.05) < 1e-9 and abs(f['omega'] - 0.2) < 1e-9 and abs(f['r2'] - 1) < 1e-9
    np.testing.assert_allclose(f['avd'], np.linalg.norm((r - r.mean(0)) @ A.T, axis=1).mean())


def test_gains_command_reports_every_controller_and_refuses_bad_frames(untrained_policies, capsys):
    from training.studies.gains import main

    path = str(untrained_policies['flock2d'])
    assert (
        main(
            ['--policy', path, '--sizes', '7', '--starts', '2', '--steps', '20', '--frames', '5', '10', '20']
        )
        == 0
    )
    out = capsys.readouterr().out
    assert out.count('n=7 ground_truth: rollout') == 3 and out.count('n=7 ground_truth: final avd') == 1
    for name in ('local_tanner', path):
        assert out.count(f'n=7 {name}: truth frame') == 2 and out.count(f'n=7 {name}: rollout') == 3
        assert out.count(f'n=7 {name}: final avd') == 1
    # an added term changes the policy's rollout, never the local Tanner baseline's
    assert (
        main(
            [
                '--policy',
                path,
                '--sizes',
                '7',
                '--starts',
                '2',
                '--steps',
                '20',
                '--frames',
                '5',
                '10',
                '20',
                '--add-alignment',
                '1',
            ]
        )
        == 0
    )
    added = capsys.readouterr().out
    line = lambda text, name: next(x for x in text.splitlines() if x.startswith(f'n=7 {name}: final avd'))  # noqa: E731
    assert line(added, 'local_tanner') == line(out, 'local_tanner') and line(added, path) != line(out, path)
    assert main(['--policy', path, '--steps', '20', '--frames', '30']) == 2
    assert main(['--policy', str(untrained_policies['boids3d']), '--steps', '20', '--frames', '5', '10']) == 2


def test_added_tanner_terms_make_a_zero_controller_the_local_tanner_law_where_pairs_attract():
    """zero + attraction + alignment (gain 1) equals local Tanner on rows that are all farther than 1
    (where the pair term attracts), and the attraction term is 0 for rows closer than 1."""
    from training.studies.gains import tanner_attraction, with_terms

    rng = np.random.default_rng(2)
    ang = rng.uniform(0, 2 * np.pi, (6, 4))
    dist = rng.uniform(1.2, 3.0, (6, 4))
    Y = np.zeros((6, 5, 4))
    Y[:, 1:, 0], Y[:, 1:, 1] = dist * np.cos(ang), dist * np.sin(ang)
    Y[..., 2:] = rng.normal(size=(6, 5, 2))
    mask = np.ones((6, 5), bool)
    zero = lambda Y, m: np.zeros((len(Y), 2))  # noqa: E731
    np.testing.assert_allclose(
        with_terms(zero, 1.0, 1.0, None)(Y, mask), local_tanner_acceleration(Y, mask), atol=1e-12
    )
    np.testing.assert_allclose(
        with_terms(zero, 1.0, 1.0, 0.5)(Y, mask), local_tanner_acceleration(Y, mask, 0.5), atol=1e-12
    )
    Y[:, 1:, :2] *= 0.5 / dist[..., None]  # every neighbour 0.5 away
    np.testing.assert_array_equal(tanner_attraction(Y, mask), np.zeros((6, 2)))
    assert with_terms(zero, 0.0, 0.0, None) is zero


def test_closed_groups_counts_groups_that_hear_no_one_else():
    """Two far clusters of 3 (k = 3: two nearest each) are two closed groups; a chain that listens
    towards one end is one; a robot out of every radius is a group of its own."""
    from training.studies.gains import closed_groups

    z = np.zeros((6, 4))
    z[:3, 0] = [0.0, 1.0, 2.0]
    z[3:, 0] = [50.0, 51.0, 52.0]
    assert closed_groups(z, 5.0, 3) == 2
    assert closed_groups(z, 100.0, 6) == 1  # everyone hears everyone
    chain = np.zeros((5, 4))
    chain[:, 0] = [0.0, 1.0, 3.0, 6.0, 10.0]  # each hears its single nearest (k = 2)
    assert closed_groups(chain, 5.0, 2) == 1  # 0 <-> 1 is the one closed pair; 2 -> 1, 3 -> 2, 4 -> 3
    z[5, 0] = 200.0
    assert closed_groups(z, 5.0, 3) == 3  # robot 5 hears no one; 3 and 4 hear only each other
