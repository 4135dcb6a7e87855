"""The unicycle mapping (knode_swarm_ros/core/unicycle.py): exact tracking of the point ahead,
its limits, and convergence of a simulated differential-drive robot to a desired velocity."""
import math

import numpy as np
import pytest

from knode_swarm_ros.core.unicycle import UnicycleLimits, UnicycleMapper, point_ahead, unicycle_step


@pytest.mark.parametrize('theta', [0.0, 0.7, 2.0, math.pi, -2.4, -0.9])
def test_point_ahead_gets_exactly_the_desired_velocity_without_limits(theta):
    m = UnicycleMapper(UnicycleLimits(lookahead=0.3), 'velocity', 0.05)
    for u in ([1.0, 0.0], [0.0, -2.0], [-0.5, 0.4], [0.0, 0.0]):
        v, w = m(u, theta)
        _, vel = point_ahead(0.0, 0.0, theta, v, w, 0.3)
        assert np.allclose(vel, u, atol=1e-12)
    assert m.bound == 0


def test_acceleration_policy_asks_for_the_velocity_after_one_held_period():
    m = UnicycleMapper(UnicycleLimits(lookahead=0.2), 'acceleration', 0.05)
    assert np.allclose(m.desired_velocity([2.0, -4.0], [1.0, 1.0]), [1.1, 0.8])
    v, w = m([2.0, -4.0], 0.0, [1.0, 1.0])
    assert (v, w) == pytest.approx((1.1, 0.8 / 0.2))


def test_limits_hold_every_period_and_are_counted():
    lim = UnicycleLimits(lookahead=0.2, max_linear_speed=0.22, max_angular_speed=1.8, max_linear_accel=0.5,
                         max_angular_accel=3.0)
    m = UnicycleMapper(lim, 'velocity', 0.1)
    rng = np.random.default_rng(0)
    last = (0.0, 0.0)
    for _ in range(500):
        v, w = m(rng.normal(size=2) * 2, rng.uniform(-math.pi, math.pi))
        assert abs(v) <= 0.22 + 1e-15 and abs(w) <= 1.8 + 1e-15
        assert abs(v - last[0]) <= 0.05 + 1e-12 and abs(w - last[1]) <= 0.3 + 1e-12
        last = (v, w)
    assert m.bound > 400 and m.periods == 500
    # Braking to rest respects the same acceleration limits and ends at zero.
    steps = 0
    while m.last != (0.0, 0.0):
        v0, w0 = m.last
        v, w = m.stop()
        assert abs(v - v0) <= 0.05 + 1e-12 and abs(w - w0) <= 0.3 + 1e-12
        steps += 1
    assert steps <= 7
    with pytest.raises(ValueError, match='lookahead'):
        UnicycleLimits(lookahead=0.0).validate()
    with pytest.raises(ValueError, match='max_angular_speed'):
        UnicycleLimits(max_angular_speed=-1.0).validate()


def _drive(u, theta0, limits, steps=400, dt=0.02):
    m = UnicycleMapper(limits, 'velocity', dt)
    pose = np.array([0.0, 0.0, theta0])
    for _ in range(steps):
        v, w = m(u, pose[2])
        pose = unicycle_step(pose, v, w, dt)
    return pose, m.last


@pytest.mark.parametrize('theta0', [0.0, 1.5, math.pi - 0.1, -2.0])
def test_robot_converges_to_the_desired_velocity_from_any_heading(theta0):
    u = np.array([0.3, 0.15])
    limits = UnicycleLimits(lookahead=0.2, max_linear_speed=1.0, max_angular_speed=1.8, max_linear_accel=2.0,
                            max_angular_accel=6.0)
    pose, (v, w) = _drive(u, theta0, limits)
    heading = math.atan2(u[1], u[0])
    assert abs(math.remainder(pose[2] - heading, 2 * math.pi)) < 1e-3     # faces the motion
    assert v == pytest.approx(np.linalg.norm(u), abs=1e-3) and abs(w) < 1e-3
    # A binding speed limit: it drives the right way at the top speed.
    pose, (v, w) = _drive(u, theta0, UnicycleLimits(lookahead=0.2, max_linear_speed=0.1, max_angular_speed=1.8))
    assert abs(math.remainder(pose[2] - heading, 2 * math.pi)) < 1e-2 and v == pytest.approx(0.1)


def test_unicycle_step_is_exact_on_arcs():
    pose = np.array([1.0, 2.0, 0.3])
    fine = pose.copy()
    for _ in range(10_000):
        fine = unicycle_step(fine, 0.7, 1.1, 1e-4)
    assert np.allclose(unicycle_step(pose, 0.7, 1.1, 1.0), fine, atol=1e-9)
    assert np.allclose(unicycle_step(pose, 0.7, 0.0, 2.0), [1.0 + 1.4 * math.cos(0.3), 2.0 + 1.4 * math.sin(0.3), 0.3])


def test_brake_command_stops_a_double_integrator_within_the_limit():
    import rclpy.lifecycle  # noqa: F401,E402  (a broken install must fail, not skip)
    from knode_swarm_ros.nodes.agent_lifecycle import brake_command
    z = np.array([1.0, 2.0, 0.03, -0.5])
    u = brake_command('acceleration', z, 0.01, 10.0)
    assert np.allclose(u, [-3.0, 10.0])                               # -v/dt, saturated per axis
    assert np.allclose(brake_command('acceleration', z, 0.01, None), [-3.0, 50.0])
    assert np.array_equal(brake_command('velocity', np.zeros(6), 0.01, 1.0, command_dim=3), np.zeros(3))
    v = z[2:].copy()                                                  # braking to rest, step by step
    for _ in range(10):
        v = v + brake_command('acceleration', np.r_[0.0, 0.0, v], 0.01, 10.0) * 0.01
    assert np.allclose(v, 0.0, atol=1e-12)


def test_unicycle_swarm_without_commands_drives_straight_like_the_double_integrator():
    from knode_swarm_ros.core import rollout
    from training.unicycle_study import unicycle_rollout
    rng = np.random.default_rng(5)
    z0 = np.concatenate([rng.uniform(-3, 3, (2, 4, 2)), rng.normal(size=(2, 4, 2))], axis=-1)

    def zero(Y, mask):
        return np.zeros((Y.shape[0], 2))
    uni = unicycle_rollout(zero, z0, 50, UnicycleLimits(lookahead=0.2), 5.0, 4, 0.01)
    di = rollout(zero, z0, 50, 'flock2d', 5.0, 4, 0, 0.01)
    assert np.allclose(uni, di, atol=1e-9)
    # A policy that brakes (u = -v / 0.5) slows the unicycles down as it slows the point masses.
    brake = lambda Y, mask: -Y[:, 0, 2:] / 0.5  # noqa: E731
    uni = unicycle_rollout(brake, z0, 100, UnicycleLimits(lookahead=0.2), 5.0, 4, 0.01)
    speed = np.linalg.norm(uni[:, :, :, 2:], axis=-1)
    assert np.all(speed[:, -1] < 0.2 * speed[:, 0] + 1e-9)
