"""The causal velocity estimator (core/estimator.py) on known signals, and the pose-observed rollout."""

import math

import numpy as np
import pytest

from knode_swarm_ros.core.estimator import (
    CommandAidedEstimator,
    StepSampler,
    VelocityEstimator,
    fit_weights,
    lag_s,
    noise_gain,
    step_at_or_before,
)
from knode_swarm_ros.core.rollout import PoseObserver, rollout
from knode_swarm_ros.core.saturation import velocity_setpoint
from knode_swarm_ros.core.scenarios import get_scenario

H_NS = 10_000_000  # 100 Hz


def test_one_sample_knows_no_velocity_then_constant_velocity_is_exact():
    est = VelocityEstimator(5)
    v = np.array([0.3, -1.2])
    p0 = np.array([1.0, 2.0])
    np.testing.assert_array_equal(est.update(0, p0), [0.0, 0.0])
    for j in range(1, 12):
        got = est.update(j * H_NS, p0 + v * j * 0.01)
        np.testing.assert_allclose(got, v, rtol=0, atol=1e-12)  # from the second sample on


def test_uneven_stamps_still_exact_for_constant_velocity():
    est = VelocityEstimator(4)
    v = np.array([0.7, 0.1, -0.4])
    for ns in (0, 7_000_000, 19_000_000, 23_000_000, 41_000_000, 50_000_000):
        got = est.update(ns, v * ns * 1e-9)
    np.testing.assert_allclose(got, v, atol=1e-12)


def test_repeated_or_late_samples_are_ignored():
    est = VelocityEstimator(3)
    est.update(0, [0.0])
    first = est.update(H_NS, [0.01]).copy()
    np.testing.assert_array_equal(est.update(H_NS, [5.0]), first)  # the retransmission of a step
    np.testing.assert_array_equal(est.update(0, [9.0]), first)  # late
    assert est.newest_ns == H_NS


def test_constant_acceleration_lags_by_the_formula():
    n, h, a = 8, 0.01, 2.0
    est = VelocityEstimator(n)
    for j in range(30):
        t = j * h
        got = est.update(j * H_NS, np.array([0.5 * a * t * t]))
    assert math.isclose(got[0], a * (29 * h - lag_s(n, h)), abs_tol=1e-9)


def test_velocity_step_settles_after_the_window():
    n = 6
    est = VelocityEstimator(n)
    got = []
    for j in range(20):  # at rest until sample 10, then 1 m/s
        got.append(est.update(j * H_NS, np.array([max(0, j - 10) * 0.01]))[0])
    assert got[10] == 0.0 and 0 < got[11] < 1  # the kink starts to show one sample later
    assert all(0 <= g <= 1 + 1e-12 for g in got)  # no overshoot
    np.testing.assert_allclose(got[10 + n - 1 :], 1.0, atol=1e-12)  # all N samples on the new line
    assert got[10 + n - 2] < 1 - 1e-6


def test_noise_gain_matches_its_formula():
    n, h, sigma = 10, 0.01, 0.002
    rng = np.random.default_rng(3)
    est = VelocityEstimator(n)
    noise = rng.normal(0, sigma, (4000, 2000))  # 2000 independent streams at once
    errors = [est.update(j * H_NS, noise[j]) for j in range(noise.shape[0])][n:]
    std = np.std(np.stack(errors)[::n])  # every N-th estimate: independent windows
    want = sigma * noise_gain(n, h)
    assert math.isclose(want, sigma * math.sqrt(12 / (n * (n * n - 1))) / h)
    assert abs(std / want - 1) < 0.02


def test_weights_of_a_single_sample_are_zero_and_window_is_checked():
    assert fit_weights([5]) == (0.0,)
    with pytest.raises(ValueError, match='window'):
        VelocityEstimator(1)


def test_batched_estimates_equal_one_robot_at_a_time():
    rng = np.random.default_rng(1)
    p = rng.normal(size=(12, 3, 5, 2))  # [T, S, n, 2]
    batched = VelocityEstimator(4)
    alone = {(s, i): VelocityEstimator(4) for s in range(3) for i in range(5)}
    for t in range(p.shape[0]):
        all_at_once = batched.update(t * 50_000_000, p[t])
        for (s, i), est in alone.items():
            np.testing.assert_array_equal(est.update(t * 50_000_000, p[t, s, i]), all_at_once[s, i])


def test_velocity_setpoint_by_hand():
    np.testing.assert_allclose(velocity_setpoint([0.2, -0.1], [1.0, 2.0], 0.05), [0.25, 0.0])
    np.testing.assert_allclose(velocity_setpoint([0.9, -0.9], [4.0, -4.0], 0.05, 1.0), [1.0, -1.0])
    np.testing.assert_allclose(
        velocity_setpoint([[0, 0], [1, 1]], [[1, -1], [0, 0]], 0.1, 0.5), [[0.1, -0.1], [0.5, 0.5]]
    )


def _spring(Y, mask):
    """A policy: pull towards the mean relative position, damp the own velocity."""
    rel = Y[:, :, :2] * mask[..., None]
    return rel.sum(1) / np.maximum(mask.sum(1, keepdims=True), 1) - 0.5 * Y[:, 0, 2:]


def test_pose_observed_rollout_hears_estimates_exact_states_are_written():
    rng = np.random.default_rng(0)
    z0 = np.concatenate([rng.uniform(-2, 2, (6, 2)), rng.normal(0, 0.5, (6, 2))], axis=1)
    exact = rollout(_spring, z0, 30, 'flock2d', 3.0, 4, 1, 0.05, command_limit=None)
    posed = rollout(_spring, z0, 30, 'flock2d', 3.0, 4, 1, 0.05, command_limit=None, observe='pose')
    np.testing.assert_array_equal(posed[0], exact[0])
    assert not np.array_equal(posed[1:], exact[1:])  # frame 0 is heard at rest: the runs part
    observer = PoseObserver(get_scenario('flock2d'), 10)
    heard = observer.observe(0, z0)
    np.testing.assert_array_equal(heard[:, :2], z0[:, :2])
    np.testing.assert_array_equal(heard[:, 2:], 0.0)
    with pytest.raises(ValueError, match='observe'):
        rollout(_spring, z0, 3, 'flock2d', 3.0, 4, 1, 0.05, observe='odometry')


def test_pose_observation_of_a_heading_scenario_is_the_state():
    z = np.array([[0.0, 1.0, 2.0, 1.0, 0.0, 0.0]])
    np.testing.assert_array_equal(PoseObserver(get_scenario('boids3d')).observe(0, z), z)


def test_import_option_gives_the_agents_estimates_on_the_grid():
    from training.data.derive import causal_velocities
    from training.data.tracks import ResampleOptions, TrackError, check_resample_options

    p = np.cumsum(np.random.default_rng(2).normal(size=(20, 3, 2)), axis=0)
    est = VelocityEstimator(5)
    want = [est.update(int(round(k * 0.05 * 1e9)), p[k]) for k in range(20)]
    np.testing.assert_array_equal(causal_velocities(p, 0.05, 5), np.stack(want))
    check_resample_options(ResampleOptions('flock2d', 20.0, velocity_estimator=5))
    for bad in (
        ResampleOptions('flock2d', 20.0, velocity_estimator=1),
        ResampleOptions('boids3d', 20.0, velocity_estimator=5),
        ResampleOptions('flock2d', 20.0, velocity_estimator=5, use_twist=True),
    ):
        with pytest.raises(TrackError, match='--velocity-estimator'):
            check_resample_options(bad)


# --- which sample stands for a step (StepSampler) ------------------------------------------------
def test_step_at_or_before_on_and_between_steps():
    dt = 0.05
    assert [step_at_or_before(ns, dt) for ns in (0, 1, 49_999_999, 50_000_000, 50_000_001)] == [0, 0, 0, 1, 1]
    assert step_at_or_before(-1, dt) == -1
    # a dt whose steps are not whole nanoseconds: the grid is round(s dt 1e9), as the nodes stamp
    dt = 1 / 30
    for s in range(200):
        ns = int(round(s * dt * 1e9))
        assert step_at_or_before(ns, dt) == s and step_at_or_before(ns - 1, dt) == s - 1


def test_a_stream_on_the_grid_files_each_step_sample_at_once():
    sampler = StepSampler(0.05)
    got = [sampler.push(j * H_NS) for j in range(16)]  # 100 Hz under a 20 Hz policy
    assert got == [(None, j // 5) if j % 5 == 0 else (None, None) for j in range(16)]


def test_a_stream_off_the_grid_files_the_newest_sample_before_each_step_when_the_next_one_comes():
    sampler = StepSampler(0.05)
    stamps = [3_000_000 + j * H_NS for j in range(12)]  # 3 ms after the grid of 10 ms
    got = [sampler.push(ns) for ns in stamps]
    # 43 ms is the newest at or before 50 ms: known at 53 ms; 93 ms for 100 ms, at 103 ms
    assert got[5] == (1, None) and got[10] == (2, None)
    assert all(g == (None, None) for j, g in enumerate(got) if j not in (5, 10))


def test_a_gap_names_only_the_newest_step_passed_and_late_samples_are_forgotten():
    sampler = StepSampler(0.05)
    assert sampler.push(43_000_000) == (None, None)
    assert sampler.push(200_000_000) == (3, 4)  # 43 ms stands for steps 1..3 (3 named), 200 ms is step 4
    assert sampler.push(150_000_000) == (None, None)  # older: forgotten
    assert sampler.push(200_000_000) == (None, None)  # repeated
    assert sampler.push(249_000_000) == (None, None)
    assert sampler.push(250_000_000) == (None, 5)  # on the step: the sample before stands for none


def test_pose_observed_rollout_observes_on_the_grid_so_every_observation_stands_for_its_step():
    # core.rollout observes at round(t dt 1e9): the rule picks every observation at once, so the
    # offline rollout and the agents (which apply it) file the same samples.
    sampler = StepSampler(0.05)
    assert [sampler.push(int(round(t * 0.05 * 1e9))) for t in range(50)] == [(None, t) for t in range(50)]


def test_the_fit_is_made_when_read_and_equals_a_fit_at_every_sample():
    rng = np.random.default_rng(5)
    p = rng.normal(size=(30, 3, 2))
    lazy, eager = VelocityEstimator(6), VelocityEstimator(6)
    for j in range(30):
        v = eager.update(j * H_NS, p[j])
        lazy.push(j * H_NS, p[j])
        if j % 5 == 0:
            assert np.array_equal(lazy.velocity, v)
    assert np.array_equal(lazy.velocity, v)


# --- a robot's own velocity: its poses and its commands ------------------------------------------
def _double_integrator(commands, switch_every, v0, h=0.01):
    """Positions at every h of a robot executing ``commands[j // switch_every]`` (held)."""
    p, v, out = np.zeros(2), np.array(v0, dtype=float), []
    for j in range(len(commands) * switch_every):
        out.append((p.copy(), v.copy()))
        u = commands[j // switch_every]
        p, v = p + v * h + 0.5 * u * h * h, v + u * h
    return out


def test_command_aided_velocity_is_exact_for_a_robot_executing_its_commands():
    rng = np.random.default_rng(7)
    commands = rng.normal(0, 2.0, (40, 2))
    est, plain = CommandAidedEstimator(50), VelocityEstimator(10)
    for j, (p, v) in enumerate(_double_integrator(commands, 5, [0.3, -0.1])):
        if j % 5 == 0:
            est.command(j * H_NS, commands[j // 5])
        est.push(j * H_NS, p)
        plain.push(j * H_NS, p)
        if j >= 1:
            np.testing.assert_allclose(est.velocity, v, atol=1e-9)  # no lag, whatever the commands
    assert np.max(np.abs(plain.velocity - v)) > 1e-3  # the plain fit lags behind them


def test_command_aided_noise_is_the_long_windows_and_a_command_ahead_waits_for_its_stamp():
    n, sigma = 50, 0.002
    rng = np.random.default_rng(8)
    est = CommandAidedEstimator(n)
    est.command(0, np.zeros(2000))
    noise = rng.normal(0, sigma, (400, 2000))
    errors = []
    for j in range(400):
        est.push(j * H_NS, noise[j])
        if j >= n:
            errors.append(est.velocity.copy())
    std = np.std(np.stack(errors)[::n])
    assert abs(std / (sigma * noise_gain(n, 0.01)) - 1) < 0.05
    # a stop command stamped ahead of the newest pose acts from its stamp, not before
    ahead = CommandAidedEstimator(5)
    ahead.command(0, [0.0])
    ahead.push(0, [0.0])
    ahead.command(2 * H_NS, [1.0])
    ahead.push(H_NS, [0.0])
    assert ahead.velocity[0] == 0.0
    ahead.push(3 * H_NS, [0.5 * 0.01**2])  # one period under u = 1 since 20 ms
    assert ahead.velocity[0] == pytest.approx(0.01, abs=1e-9)


def test_command_aided_estimates_of_all_robots_at_once_equal_one_at_a_time():
    rng = np.random.default_rng(9)
    p, u = rng.normal(size=(20, 4, 2)), rng.normal(size=(20, 4, 2))
    batched = CommandAidedEstimator(6)
    alone = [CommandAidedEstimator(6) for _ in range(4)]
    for t in range(20):
        batched.push(t * 50_000_000, p[t])
        for i, est in enumerate(alone):
            est.push(t * 50_000_000, p[t, i])
            assert np.array_equal(est.velocity, batched.velocity[i])
            est.command(t * 50_000_000, u[t, i])
        batched.command(t * 50_000_000, u[t])
