"""Baselines of the controller comparison: the local Tanner law and the interaction-kernel fit."""
import json

import numpy as np
import pytest

from knode_swarm_ros.core import neighbour_matrix, rollout, save_trajectories
from knode_swarm_ros.core.groundtruth.tanner import local_tanner_acceleration, tanner_acceleration
from training.kernel_baseline import KernelModel, fit_kernel


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
    want = np.array([[1.0 - 2 * (1 / r**2 - 1 / r**4) * -2.0, -1.0]])   # alignment + attraction towards +x
    np.testing.assert_allclose(local_tanner_acceleration(Y, mask), want)
    np.testing.assert_allclose(local_tanner_acceleration(Y, mask, clip=0.5), np.clip(want, -0.5, 0.5))
    # a coincident neighbour adds alignment only, never a NaN
    Y[0, 1, :2] = 0.0
    np.testing.assert_allclose(local_tanner_acceleration(Y, mask), [[1.0, -1.0]])


def test_kernel_fit_recovers_a_known_kernel():
    edges = np.linspace(0, 3, 7)
    true = KernelModel(edges, np.array([1.0, 0.8, 0.6, 0.4, 0.2, 0.1]), np.array([-3.0, -1, 0.2, 0.5, 0.3, 0.1]))
    z0 = _swarm(np.random.default_rng(1), 5, 8)
    states = rollout(true, z0, 150, "flock2d", 3.0, 5, 0, 0.01)
    fit = fit_kernel(states, 0.01, 3.0, 5, 0, bins=6)
    assert np.all(fit.samples_per_bin > 0)
    np.testing.assert_allclose(fit.phi_a, true.phi_a, atol=1e-5)
    np.testing.assert_allclose(fit.phi_p, true.phi_p, atol=1e-5)
    # stride and tau: the same law seen through a delayed network and every 3rd frame
    states = rollout(true, z0, 150, "flock2d", 3.0, 5, 2, 0.01)
    fit = fit_kernel(states, 0.01, 3.0, 5, 2, bins=6, stride=3)
    np.testing.assert_allclose(fit.phi_a, true.phi_a, atol=1e-5)
    assert json.loads(fit.to_json())["phi_p"] == pytest.approx(true.phi_p.tolist(), abs=1e-5)


def test_kernel_fit_leaves_out_saturated_samples_and_clips():
    edges = np.linspace(0, 3, 4)
    true = KernelModel(edges, np.array([1.0, 0.5, 0.2]), np.array([-8.0, 0.5, 0.1]), command_limit=3.0)
    states = rollout(true, _swarm(np.random.default_rng(2), 4, 6, spread=1.5), 100, "flock2d", 3.0, 4, 0, 0.01)
    implied = np.abs(states[:, 1:, :, 2:] - states[:, :-1, :, 2:]).max(-1) / 0.01
    assert 0.2 < np.mean(implied >= 3.0 - 1e-6) < 0.6          # many samples are saturated
    # fitted to every sample the kernel is biased; without the saturated ones it is exact
    biased = fit_kernel(states, 0.01, 3.0, 4, 0, bins=3)
    assert abs(biased.phi_a[0] - 1.0) > 0.1
    fit = fit_kernel(states, 0.01, 3.0, 4, 0, bins=3, command_limit=3.0)
    np.testing.assert_allclose(fit.phi_a, true.phi_a, atol=1e-5)
    np.testing.assert_allclose(fit.phi_p, true.phi_p, atol=1e-5)
    Y = np.array([[[0.0, 0, 0, 0], [0.5, 0, 0, 0]]])                  # -8 * 0.5 = -4: clipped at -3
    np.testing.assert_allclose(fit(Y, np.array([[True, True]])), [[-3.0, 0.0]])


def test_compare_command_writes_the_table_for_every_controller(tmp_path, untrained_policies):
    from training.compare_controllers import main
    from knode_swarm_ros.core.groundtruth import simulate
    states = simulate("flock2d", 3, 5, 30, 0, progress=False)
    data = tmp_path / "d.npz"
    save_trajectories(data, states, 0.01, "flock2d", {"split": {"train": [0, 1], "test": [2]}})
    out = tmp_path / "cmp"
    rc = main(["--data", str(data), "--out", str(out), "--policy", f"a={untrained_policies['flock2d']}",
               "--sizes", "4", "6", "--ics", "2", "--steps", "20"])
    assert rc == 0
    r = json.loads((out / "results.json").read_text())
    names = {(row["robots"], row["controller"]) for row in r["rows"]}
    assert names == {(n, c) for n in (4, 6) for c in ("ground_truth", "a", "local_tanner", "kernel")}
    assert (out / "compare.png").stat().st_size > 0
    table = (out / "table.md").read_text()
    assert table.count("| 6 |") == 4
    assert main(["--data", str(data), "--out", str(out), "--policy", "nonsense"]) == 2
