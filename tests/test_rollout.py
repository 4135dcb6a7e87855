"""The canonical rollout: exact zero-order-hold integration and the delay rule."""

import re

import numpy as np
import pytest

from knode_swarm_ros.core import get_scenario, neighbour_matrix_single, rollout, zoh_step


def zero_policy(m):
    return lambda Y, mask: np.zeros((Y.shape[0], m))


def test_zero_policy_is_exact_free_motion_flock2d():
    rng = np.random.default_rng(0)
    z0 = rng.normal(size=(3, 7, 4))
    out = rollout(zero_policy(2), z0, 50, 'flock2d', 5.0, 6, 0, 0.01)
    t = np.arange(51)[None, :, None, None] * 0.01
    np.testing.assert_allclose(out[..., :2], z0[:, None, :, :2] + z0[:, None, :, 2:] * t, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(out[..., 2:], np.broadcast_to(z0[:, None, :, 2:], out[..., 2:].shape))


def test_zero_velocity_command_keeps_boids_in_place_and_heading():
    rng = np.random.default_rng(1)
    z0 = rng.normal(size=(5, 6))
    z0[:, 3:] /= np.linalg.norm(z0[:, 3:], axis=1, keepdims=True)
    out = rollout(zero_policy(3), z0, 10, 'boids3d', 2.0, 6, 1, 1 / 60)
    assert out.shape == (11, 5, 6)
    np.testing.assert_array_equal(out, np.broadcast_to(z0, out.shape))


def test_constant_acceleration_is_integrated_exactly():
    a = np.array([0.5, -2.0])
    z0 = np.array([[1.0, 2.0, 3.0, -1.0]])
    out = rollout(lambda Y, m: np.tile(a, (Y.shape[0], 1)), z0, 100, 'flock2d', 5.0, 6, 0, 0.01)
    t = 1.0
    np.testing.assert_allclose(out[-1, 0, :2], z0[0, :2] + z0[0, 2:] * t + 0.5 * a * t * t, atol=1e-11)
    np.testing.assert_allclose(out[-1, 0, 2:], z0[0, 2:] + a * t, atol=1e-11)


def test_velocity_command_moves_and_sets_heading():
    c = np.array([3.0, 0.0, 4.0])
    z0 = np.array([[0.0, 0.0, 0.0, 1.0, 0.0, 0.0]])
    out = rollout(lambda Y, m: np.tile(c, (Y.shape[0], 1)), z0, 60, 'boids3d', 2.0, 6, 1, 1 / 60)
    np.testing.assert_allclose(out[-1, 0, :3], c * 1.0, atol=1e-12)
    np.testing.assert_allclose(out[1:, 0, 3:], np.tile([0.6, 0.0, 0.8], (60, 1)), atol=1e-15)


def test_zoh_step_by_hand():
    spec = get_scenario('flock2d')
    z = np.array([[1.0, 1.0, 2.0, 0.0]])
    new = zoh_step(z, np.array([[4.0, 2.0]]), spec, 0.5)
    # p += v dt + c dt^2 / 2 = (1 + 1 + 0.5, 1 + 0 + 0.25); v += c dt = (4, 1)
    np.testing.assert_array_equal(new, [[2.5, 1.25, 4.0, 1.0]])


def reference_rollout(policy, z0, steps, spec, d_cr, k, tau, dt):
    """Per-robot loop with the single-robot builder: the agent nodes' view of a rollout."""
    frames = [np.array(z0)]
    for t in range(steps):
        z, zd = frames[t], frames[max(t - tau, 0)]
        command = np.zeros((z.shape[0], spec.command_dim))
        for i in range(z.shape[0]):
            Y, mask = neighbour_matrix_single(i, z[i], zd, spec.position_dim, d_cr, k)
            command[i] = policy(Y[None], mask[None])[0]
        frames.append(zoh_step(z, command, spec, dt))
    return np.stack(frames)


def cohesion_policy(Y, mask):
    """Steer towards the mean of the rows (depends on delayed neighbours)."""
    m = mask[..., None].astype(float)
    centre = (Y[:, :, :2] * m).sum(1) / m.sum(1)
    return (centre - Y[:, 0, :2]) - 0.5 * Y[:, 0, 2:4]


@pytest.mark.parametrize('tau', [0, 3])
def test_batched_rollout_equals_per_robot_loop_with_delay(tau):
    rng = np.random.default_rng(3)
    z0 = rng.normal(scale=2.0, size=(2, 6, 4))
    spec = get_scenario('flock2d')
    out = rollout(cohesion_policy, z0, 30, 'flock2d', 3.0, 4, tau, 0.05)
    for s in range(2):
        ref = reference_rollout(cohesion_policy, z0[s], 30, spec, 3.0, 4, tau, 0.05)
        np.testing.assert_allclose(out[s], ref, rtol=0, atol=1e-12)


def test_delay_uses_the_frame_tau_steps_back_by_hand():
    # Two robots 1 apart, cohesion towards the midpoint of own position and the other's
    # position tau = 5 steps back (the initial frame before that), written out by hand.
    z0 = np.array([[0.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.5]])
    tau, dt, steps = 5, 0.05, 12
    out = rollout(cohesion_policy, z0, steps, 'flock2d', 3.0, 4, tau, dt)
    frames = [z0]
    for t in range(steps):
        z, zd = frames[t], frames[max(t - tau, 0)]
        c = np.stack([(z[i, :2] + zd[1 - i, :2]) / 2 - z[i, :2] - 0.5 * z[i, 2:] for i in (0, 1)])
        frames.append(
            np.concatenate([z[:, :2] + z[:, 2:] * dt + 0.5 * c * dt * dt, z[:, 2:] + c * dt], axis=1)
        )
    np.testing.assert_allclose(out, np.stack(frames), rtol=0, atol=1e-14)
    # Without the delay the first two frames agree and the third does not (step 1 sees frame 1).
    undelayed = rollout(cohesion_policy, z0, steps, 'flock2d', 3.0, 4, 0, dt)
    np.testing.assert_array_equal(undelayed[:2], out[:2])
    assert np.abs(undelayed[2] - out[2]).max() > 1e-6


def test_any_swarm_size_and_bad_shapes():
    for n in (1, 2, 37):
        assert rollout(zero_policy(2), np.zeros((n, 4)), 2, 'flock2d', 5.0, 6, 0, 0.01).shape == (3, n, 4)
    with pytest.raises(ValueError, match='z0'):
        rollout(zero_policy(2), np.zeros((3, 6)), 2, 'flock2d', 5.0, 6, 0, 0.01)
    for shape in ((4,), (1, 2, 3, 4)):  # the message gives the shape as passed in
        with pytest.raises(ValueError, match=re.escape(f'got {shape}')):
            rollout(zero_policy(2), np.zeros(shape), 2, 'flock2d', 5.0, 6, 0, 0.01)


@pytest.mark.parametrize('scenario', ['flock2d', 'boids3d'])
def test_torch_zoh_step_equals_the_numpy_one(scenario):
    import torch

    from knode_swarm_ros.core.rollout import zoh_step_torch

    spec = get_scenario(scenario)
    rng = np.random.default_rng(5)
    z = rng.normal(size=(7, spec.state_dim))
    c = rng.normal(size=(7, spec.command_dim))
    c[3] = 0.0  # zero velocity command keeps the heading
    got = zoh_step_torch(torch.tensor(z), torch.tensor(c), spec, 0.02).numpy()
    np.testing.assert_allclose(got, zoh_step(z, c, spec, 0.02), rtol=0, atol=1e-15)


def test_package_attribute_rollout_is_the_function_even_after_importing_the_submodule():
    import importlib

    importlib.import_module('knode_swarm_ros.core.rollout')
    from knode_swarm_ros.core import rollout as exported

    assert callable(exported) and exported.__name__ == 'rollout'
