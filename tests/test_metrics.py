"""Metrics on closed-form cases."""

import numpy as np
import pytest

from knode_swarm_ros.core import amd, avd, pod_energy, pod_kld


def test_avd_closed_form():
    assert avd(np.tile([1.0, 2.0], (5, 1))) == 0.0
    # Two robots with opposite unit velocities: |v_i - v_j| = 2 for both ordered pairs.
    assert avd(np.array([[1.0, 0.0], [-1.0, 0.0]])) == pytest.approx(2.0)
    # Three robots: pairs (0,1): 1, (0,2): 2, (1,2): 1 -> mean over 3 pairs = 4/3.
    v = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]])
    assert avd(v) == pytest.approx(4.0 / 3.0)
    # Batched over leading axes.
    np.testing.assert_allclose(avd(np.stack([v, 2 * v])), [4 / 3, 8 / 3])


def test_amd_closed_form():
    grid = np.array([[x, y] for x in range(3) for y in range(3)], dtype=float)
    assert amd(grid) == pytest.approx(1.0)
    line = np.array([[0.0, 0.0], [1.0, 0.0], [3.0, 0.0]])
    assert amd(line) == pytest.approx((1 + 1 + 2) / 3)
    with pytest.raises(ValueError):
        amd(np.zeros((1, 2)))


def test_pod_energy_of_known_singular_values():
    rng = np.random.default_rng(0)
    T, n, d = 40, 5, 4
    U, _ = np.linalg.qr(rng.normal(size=(n * d, 3)))
    V, _ = np.linalg.qr(rng.normal(size=(T, 3)))
    s = np.array([6.0, 3.0, 1.0])
    X = U @ np.diag(s) @ V.T  # snapshot matrix [n d, T]
    states = X.T.reshape(T, n, d)
    np.testing.assert_allclose(pod_energy(states, modes=4), [0.6, 0.3, 0.1, 0.0], atol=1e-12)
    np.testing.assert_allclose(pod_energy(states, modes=3, squared=True), s**2 / 46.0, atol=1e-12)


def test_pod_energy_with_mean_subtraction():
    # A constant trajectory is rank one: all energy in mode 1; after centring it is all zeros.
    states = np.tile(np.arange(8.0).reshape(1, 4, 2), (10, 1, 1))
    np.testing.assert_allclose(pod_energy(states, modes=3), [1.0, 0.0, 0.0], atol=1e-12)
    with pytest.raises(ValueError, match='zero'):
        pod_energy(states, center=True)


def test_pod_kld_closed_form():
    rng = np.random.default_rng(1)
    a = rng.normal(size=(30, 4, 2))
    assert pod_kld(a, a) == pytest.approx(0.0, abs=1e-12)
    assert pod_kld(a, 2 * a, 5) == pytest.approx(0.0, abs=1e-12)  # scale does not change the distribution
    b = 2 * a + rng.normal(size=a.shape)
    p, q = pod_energy(a, 5), pod_energy(b, 5)
    assert pod_kld(a, b, 5) == pytest.approx(float(np.sum(p * np.log(p / q))))
    assert pod_kld(a, b, 5) > 0
