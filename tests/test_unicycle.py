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
    lim = UnicycleLimits(
        lookahead=0.2,
        max_linear_speed=0.22,
        max_angular_speed=1.8,
        max_linear_accel=0.5,
        max_angular_accel=3.0,
    )
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
    limits = UnicycleLimits(
        lookahead=0.2,
        max_linear_speed=1.0,
        max_angular_speed=1.8,
        max_linear_accel=2.0,
        max_angular_accel=6.0,
    )
    pose, (v, w) = _drive(u, theta0, limits)
    heading = math.atan2(u[1], u[0])
    assert abs(math.remainder(pose[2] - heading, 2 * math.pi)) < 1e-3  # faces the motion
    assert v == pytest.approx(np.linalg.norm(u), abs=1e-3) and abs(w) < 1e-3
    # A binding speed limit: it drives the right way at the top speed.
    pose, (v, w) = _drive(
        u, theta0, UnicycleLimits(lookahead=0.2, max_linear_speed=0.1, max_angular_speed=1.8)
    )
    assert abs(math.remainder(pose[2] - heading, 2 * math.pi)) < 1e-2 and v == pytest.approx(0.1)


def test_unicycle_step_is_exact_on_arcs():
    pose = np.array([1.0, 2.0, 0.3])
    fine = pose.copy()
    for _ in range(10_000):
        fine = unicycle_step(fine, 0.7, 1.1, 1e-4)
    assert np.allclose(unicycle_step(pose, 0.7, 1.1, 1.0), fine, atol=1e-9)
    assert np.allclose(
        unicycle_step(pose, 0.7, 0.0, 2.0), [1.0 + 1.4 * math.cos(0.3), 2.0 + 1.4 * math.sin(0.3), 0.3]
    )


def test_brake_command_stops_a_double_integrator_within_the_limit():
    import rclpy.lifecycle  # noqa: F401  (a broken install must fail, not skip)

    from knode_swarm_ros.nodes.agent.managed import brake_command

    z = np.array([1.0, 2.0, 0.03, -0.5])
    u = brake_command('acceleration', z, 0.01, 10.0)
    assert np.allclose(u, [-3.0, 10.0])  # -v/dt, saturated per axis
    assert np.allclose(brake_command('acceleration', z, 0.01, None), [-3.0, 50.0])
    assert np.array_equal(brake_command('velocity', np.zeros(6), 0.01, 1.0, command_dim=3), np.zeros(3))
    v = z[2:].copy()  # braking to rest, step by step
    for _ in range(10):
        v = v + brake_command('acceleration', np.r_[0.0, 0.0, v], 0.01, 10.0) * 0.01
    assert np.allclose(v, 0.0, atol=1e-12)


def test_unicycle_swarm_without_commands_drives_straight_like_the_double_integrator():
    """The offline study's loop (simulator stepping, Odometry fields, the agent's mapping): a zero
    policy leaves unicycles on the straight lines of the point masses; a braking one slows them."""
    from knode_swarm_ros.core import rollout
    from training.studies.unicycle_study import unicycle_rollout

    rng = np.random.default_rng(5)
    z0 = np.concatenate([rng.uniform(-3, 3, (2, 4, 2)), rng.normal(size=(2, 4, 2))], axis=-1)

    def zero(Y, mask):
        return np.zeros((Y.shape[0], 2))

    di = rollout(zero, z0, 50, 'flock2d', 5.0, 4, 0, 0.01)
    for state in ('point', 'axle'):
        uni, bound = unicycle_rollout(zero, z0, 50, UnicycleLimits(lookahead=0.2), 5.0, 4, 0.01, state)
        assert np.allclose(uni, di, atol=1e-9) and bound == 0
    # A policy that brakes (u = -v / 0.5) slows the unicycles down as it slows the point masses.
    brake = lambda Y, mask: -Y[:, 0, 2:] / 0.5  # noqa: E731
    uni, _ = unicycle_rollout(brake, z0, 100, UnicycleLimits(lookahead=0.2), 5.0, 4, 0.01)
    speed = np.linalg.norm(uni[:, :, :, 2:], axis=-1)
    assert np.all(speed[:, -1] < 0.2 * speed[:, 0] + 1e-9)


# --- the simulator's robot model (core.unicycle.UnicycleRobots, SwarmSim robot_model='unicycle') ---
def _bases(z0, **limits):
    from knode_swarm_ros.core.unicycle import UnicycleRobots

    return UnicycleRobots(np.asarray(z0, dtype=np.float64), UnicycleLimits(**limits))


def test_base_drives_a_straight_line_at_its_speed():
    b = _bases([[1.0, -2.0, 0.6, 0.8]])  # heading atan2(0.8, 0.6), speed 1
    for _ in range(250):
        b.step([[1.0, 0.0]], 0.01)
    assert np.allclose(b.pose[0, :2], [1.0 + 2.5 * 0.6, -2.0 + 2.5 * 0.8], atol=1e-12)
    assert np.allclose(b.states(), [[1.0 + 1.5, -2.0 + 2.0, 0.6, 0.8]], atol=1e-12)


@pytest.mark.parametrize('theta0', [0.4, 2.0, -2.5, -0.7])
def test_base_drives_a_circle_of_radius_v_over_omega(theta0):
    v, w, dt = 0.8, 1.6, 0.01
    b = _bases([[0.0, 0.0, np.cos(theta0), np.sin(theta0)]])
    centre = np.array([-v / w * np.sin(theta0), v / w * np.cos(theta0)])  # to the left of the heading
    steps = int(round(2 * np.pi / w / dt))  # one lap (2 pi / w = 3.93 s)
    radii = []
    for _ in range(steps):
        b.step([[v, w]], dt)
        radii.append(np.linalg.norm(b.pose[0, :2] - centre))
    assert np.allclose(radii, v / w, atol=1e-12)
    lap = steps * dt * w  # the angle turned, about 2 pi
    assert math.remainder(b.pose[0, 2] - theta0 - lap, 2 * math.pi) == pytest.approx(0.0, abs=1e-9)
    assert np.allclose(b.states()[0, 2:], v * np.array([np.cos(b.pose[0, 2]), np.sin(b.pose[0, 2])]))


def test_base_enforces_its_limits_like_a_real_one():
    """Speed and turn rate ramp at the acceleration limits to the speed limits and stay there;
    the initial speed is saturated; a stop brakes at the same rate."""
    b = _bases(
        [[0.0, 0.0, 0.0, 3.0]],
        max_linear_speed=0.5,
        max_angular_speed=1.8,
        max_linear_accel=1.0,
        max_angular_accel=4.0,
    )
    assert b.speed[0] == 0.5 and b.pose[0, 2] == pytest.approx(np.pi / 2)
    b.speed[0] = 0.0
    speeds, turns = [], []
    for _ in range(100):
        b.step([[5.0, -9.0]], 0.01)
        speeds.append(b.speed[0])
        turns.append(b.turn[0])
    assert np.allclose(speeds[:50], 0.01 * np.arange(1, 51)) and np.allclose(speeds[50:], 0.5)
    assert np.allclose(turns[:45], -0.04 * np.arange(1, 46)) and np.allclose(turns[45:], -1.8)
    for _ in range(10):
        before = b.speed[0]
        b.step([[0.0, 0.0]], 0.01)
        assert before - b.speed[0] == pytest.approx(0.01)
    # The agent's mapping clamps with the same function: same limits, same numbers.
    from knode_swarm_ros.core.unicycle import limit_twist

    lim = UnicycleLimits(
        max_linear_speed=0.5, max_angular_speed=1.8, max_linear_accel=1.0, max_angular_accel=4.0
    )
    assert limit_twist(5.0, -9.0, 0.2, -1.0, lim, 0.01) == pytest.approx((0.21, -1.04))
    assert np.allclose(
        limit_twist(
            np.array([5.0, 0.3]),
            np.array([-9.0, 1.0]),
            np.array([0.2, 0.3]),
            np.array([-1.0, 1.0]),
            lim,
            0.01,
        ),
        [[0.21, 0.3], [-1.04, 1.0]],
    )


def test_swarm_sim_with_unicycles_records_the_world_velocity_and_brakes_a_silent_robot():
    from knode_swarm_ros.logic.simulator.swarm_sim import SwarmSim

    z0 = np.array([[0.0, 0.0, 1.0, 0.0], [3.0, 0.0, 0.0, -0.5]])
    sim = SwarmSim(
        'flock2d',
        z0,
        0.05,
        'realtime',
        command_timeout=0.1,
        robot_model='unicycle',
        robot_params={'max_linear_accel': 2.0},
    )
    assert np.allclose(sim.states, z0, atol=1e-15)
    assert sim.offer(0, sim.stamp_ns, [1.0, 0.0]) == 'accepted'
    for _ in range(5):
        sim.offer(0, sim.stamp_ns, [1.0, 0.0])
        sim.advance()
    assert np.allclose(sim.states[0], [0.25, 0.0, 1.0, 0.0])
    assert np.allclose(sim.states[1, 3], 0.0) and sim.states[1, 1] == pytest.approx(
        -0.05
    )  # 0.05 s x (0.4 + 0.3 + 0.2 + 0.1)
    assert sim.counters.zeroed == 5  # robot 1 never commanded: braked
    assert np.array_equal(sim.stop_commands(), np.zeros((2, 2)))  # a base's stop: (v, omega) = 0 each
    from knode_swarm_ros.logic.common import ConfigError

    with pytest.raises(ConfigError, match='robot_model'):
        SwarmSim('flock2d', z0, 0.05, ground_truth=object(), robot_model='unicycle')


@pytest.mark.parametrize('theta', [0.3, 1.9, -2.6, -1.2, np.pi])
def test_unicycle_odometry_round_trip_in_the_body_frame(theta):
    """What the simulator publishes for a base (REP 105: yaw, twist (v, 0, 0) / (0, 0, omega) in
    robot_i/base_link) reads back as the world velocity v (cos, sin) of the heading in every
    quadrant, and as the point ahead of core.unicycle.point_state."""
    from knode_swarm_ros.core.unicycle import point_state
    from knode_swarm_ros.logic.contract.rep105 import fields_to_point_state, unicycle_fields, yaw_of
    from knode_swarm_ros.nodes.common.conversions import fields_to_cdr, odom_fields_from_cdr, odom_from_cdr

    pose, v, w = np.array([1.5, -0.5, theta]), 0.7, -1.3
    data = fields_to_cdr(4, 123_000_000, *unicycle_fields(pose, v, w))
    ns, child, z = odom_from_cdr(data, 'flock2d')
    assert ns == 123_000_000 and child == 'robot_4/base_link'
    assert np.allclose(z, [1.5, -0.5, v * np.cos(theta), v * np.sin(theta)], atol=1e-15)
    _, _, p, lin, ang = odom_fields_from_cdr(data)
    assert lin == (v, 0.0, 0.0) and ang == (0.0, 0.0, w)  # body frame: forward speed, yaw rate
    assert math.remainder(yaw_of(p[3:]) - theta, 2 * math.pi) == pytest.approx(0.0, abs=1e-15)
    assert np.allclose(
        fields_to_point_state(p[:3], p[3:], lin, ang, 0.2), point_state(pose, v, w, 0.2), atol=1e-15
    )
    world = odom_from_cdr(data, 'flock2d', 'world')[2]  # read as if not REP 105: wrong
    assert np.allclose(world[2:], [v, 0.0])


def test_mid_period_heading_keeps_the_point_ahead_on_its_velocity():
    """Held over a period the body turns by omega T; mapping at the mid-period heading makes the
    point's mean velocity over the period the one asked for (to second order in omega T)."""
    lim, T = UnicycleLimits(lookahead=0.2), 0.05
    m = UnicycleMapper(lim, 'velocity', T)
    theta, w_now, u = 0.4, 3.0, np.array([0.5, 0.9])
    v, w = m(u, theta, omega_now=w_now)
    pose = unicycle_step(np.array([0.0, 0.0, theta]), v, w, T)
    start = lim.lookahead * np.array([np.cos(theta), np.sin(theta)])
    end = pose[:2] + lim.lookahead * np.array([np.cos(pose[2]), np.sin(pose[2])])
    mean = (end - start) / T
    naive = UnicycleMapper(lim, 'velocity', T)(u, theta)
    pose = unicycle_step(np.array([0.0, 0.0, theta]), *naive, T)
    mean_naive = (pose[:2] + lim.lookahead * np.array([np.cos(pose[2]), np.sin(pose[2])]) - start) / T
    assert np.linalg.norm(mean - u) < 0.3 * np.linalg.norm(mean_naive - u)
