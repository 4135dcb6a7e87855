"""Ground-truth swarms: known answers and physics, not smoke.

Tanner flocking (flock2d): hand-computed forces, autograd of the potential, momentum, the
Lyapunov function, RK4 (hand step, order), initial-condition statistics, flocking outcome.
Lague boids (boids3d): steer clamp, flock terms on hand-placed boids, sweep test, golden
spiral, wall avoidance, speed and cube invariants over full runs. Generator: CLI round trip,
determinism, argument errors. Whole file well under 30 s on 2 cores.
"""

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from knode_swarm_ros.core.groundtruth import BoidsSwarm, parameters, presets, simulate
from knode_swarm_ros.core.groundtruth import boids as B
from knode_swarm_ros.core.groundtruth import tanner as T
from knode_swarm_ros.core.trajectory import TrajectoryError, load_trajectories

REPO = Path(__file__).resolve().parents[1]
PAPER = B.PRESETS['paper']
PUBLISHED = B.PRESETS['published']


def _state(*rows):
    return np.array(rows, dtype=np.float64)


def _pair_distances(p):
    d = np.linalg.norm(p[..., :, None, :] - p[..., None, :, :], axis=-1)
    n = p.shape[-2]
    d[..., np.arange(n), np.arange(n)] = np.inf
    return d


def _avd(v):
    n = v.shape[-2]
    return np.linalg.norm(v[..., :, None, :] - v[..., None, :, :], axis=-1).sum(axis=(-1, -2)) / (n * (n - 1))


# ----------------------------------------------------------------------------------------------
# Tanner flocking
# ----------------------------------------------------------------------------------------------


def test_unit_distance_has_no_potential_force_only_alignment():
    z = _state([0, 0, 1.0, 0.0], [1, 0, 0.0, 2.0])  # |r_01| = 1: V'(1) = 0
    u = T.tanner_acceleration(z)
    np.testing.assert_allclose(u, [[-1.0, 2.0], [1.0, -2.0]], atol=1e-15)  # -(v_i - v_j)


@pytest.mark.parametrize('r', [0.5, 2.0, 3.7])
def test_two_robot_potential_force_by_hand(r):
    # robot 1 at distance r along a diagonal; grad_{r_0} V = (2/r^2 - 2/r^4) (r_0 - r_1)
    e = np.array([0.6, 0.8])
    z = _state([0, 0, 0, 0], [r * e[0], r * e[1], 0, 0])
    u = T.tanner_acceleration(z)
    coef = 2 / r**2 - 2 / r**4
    expected0 = -coef * (-r * e)
    np.testing.assert_allclose(u[0], expected0, rtol=1e-13)
    np.testing.assert_allclose(u[1], -expected0, rtol=1e-13)
    if r < 1:  # repulsion pushes robot 0 away from robot 1
        assert np.dot(u[0], e) < 0
    else:  # attraction
        assert np.dot(u[0], e) > 0


def test_r_half_is_minus_twelve():
    # r = 0.5 on the x axis: 2/r^2 - 2/r^4 = 8 - 32 = -24, u_0 = 24 * (-0.5, 0) = (-12, 0)
    u = T.tanner_acceleration(_state([0, 0, 0, 0], [0.5, 0, 0, 0]))
    np.testing.assert_allclose(u, [[-12.0, 0.0], [12.0, 0.0]], rtol=1e-14)


def test_three_robot_configuration_by_hand():
    # robots at (0,0), (1,0), (0,2); velocities (1,0), (0,1), (-1,-1) sum to 0, so the
    # alignment term is -(3 v_i - 0) = -3 v_i.
    # pair 0-1: r = 1, no force. pair 0-2: r_02 = (0,-2), c = 2/4 - 2/16 = 3/8 -> grad (0,-3/4).
    # pair 1-2: r_12 = (1,-2), r^2 = 5, c = 2/5 - 2/25 = 8/25 -> grad_1 (8/25, -16/25).
    z = _state([0, 0, 1, 0], [1, 0, 0, 1], [0, 2, -1, -1])
    expected = np.array(
        [
            [0 - 3 * 1, 3 / 4 - 3 * 0],
            [-8 / 25 - 3 * 0, 16 / 25 - 3 * 1],
            [8 / 25 - 3 * -1, -3 / 4 - 16 / 25 - 3 * -1],
        ]
    )
    np.testing.assert_allclose(T.tanner_acceleration(z), expected, rtol=1e-14, atol=1e-15)


def test_potential_force_matches_autograd():
    import torch

    rng = np.random.default_rng(5)
    z = T.initial_states(rng, 1, 6)[0]
    p = torch.tensor(z[:, :2], dtype=torch.float64, requires_grad=True)
    diff = p[:, None, :] - p[None, :, :]
    iu = torch.triu_indices(6, 6, offset=1)
    r2 = (diff**2).sum(-1)[iu[0], iu[1]]
    total = (1.0 / r2 + torch.log(r2)).sum()  # sum over pairs of V(|r_ij|)
    (grad,) = torch.autograd.grad(total, p)
    z_still = z.copy()
    z_still[:, 2:] = 0.0  # only the potential term
    np.testing.assert_allclose(T.tanner_acceleration(z_still), -grad.numpy(), rtol=1e-10, atol=1e-12)


def test_pair_potential_minimum_at_one():
    r = np.linspace(0.3, 3.0, 271)
    v = T.pair_potential(r)
    assert r[np.argmin(v)] == pytest.approx(1.0)
    assert T.pair_potential(np.array(1.0)) == pytest.approx(1.0)


def test_momentum_conserved_and_batch_matches_single():
    rng = np.random.default_rng(1)
    z = T.initial_states(rng, 4, 7)
    u = T.tanner_acceleration(z)
    scale = np.abs(u).max()
    np.testing.assert_allclose(u.sum(axis=-2), 0.0, atol=1e-12 * max(scale, 1.0))
    for s in range(4):  # trajectories are independent: batching changes nothing
        np.testing.assert_allclose(T.tanner_acceleration(z[s]), u[s], rtol=0, atol=0)


def test_gym_flock_clip():
    z = _state([0, 0, 0, 0], [0.3, 0, 0, 0])  # c = 2/0.09 - 2/0.0081: huge repulsion
    u = T.tanner_acceleration(z, clip=10.0)
    np.testing.assert_array_equal(u, [[-10.0, 0.0], [10.0, 0.0]])
    assert T.variant_clip('gym_flock') == 10.0 and T.variant_clip('paper') is None
    with pytest.raises(ValueError, match='unknown flock2d variant'):
        T.variant_clip('nope')


def test_rk4_linear_case_is_the_taylor_polynomial():
    A = np.array([[0.0, 1.0], [-4.0, -0.3]])  # damped oscillator
    z0 = np.array([1.0, 0.5])
    h = 0.1
    M = h * A
    taylor = np.eye(2) + M + M @ M / 2 + M @ M @ M / 6 + M @ M @ M @ M / 24
    np.testing.assert_allclose(T.rk4(lambda z: A @ z, z0, h), taylor @ z0, rtol=1e-14)


def _hand_accel_two(s):
    """Independent scalar Tanner law for 2 robots, s = [x0, y0, vx0, vy0, x1, y1, vx1, vy1]."""
    x0, y0, vx0, vy0, x1, y1, vx1, vy1 = s
    dx, dy = x0 - x1, y0 - y1
    r2 = dx * dx + dy * dy
    c = 2 / r2 - 2 / r2**2
    a0 = (-(vx0 - vx1) - c * dx, -(vy0 - vy1) - c * dy)
    return [vx0, vy0, a0[0], a0[1], vx1, vy1, -a0[0], -a0[1]]


def test_one_rk4_step_equals_hand_step_and_is_not_three_eighths():
    s = [0.0, 0.0, 0.3, -0.2, 0.8, 0.1, -0.5, 0.4]
    h = 0.1

    def add(a, b, w):
        return [ai + w * bi for ai, bi in zip(a, b)]

    k1 = _hand_accel_two(s)
    k2 = _hand_accel_two(add(s, k1, h / 2))
    k3 = _hand_accel_two(add(s, k2, h / 2))
    k4 = _hand_accel_two(add(s, k3, h))
    hand = [si + h / 6 * (a + 2 * b + 2 * c + d) for si, a, b, c, d in zip(s, k1, k2, k3, k4)]
    ours = T.rk4_step(np.array(s).reshape(2, 4), h).ravel()
    np.testing.assert_allclose(ours, hand, rtol=1e-13, atol=1e-15)

    # the 3/8 rule (torchdiffeq's "rk4") gives a visibly different step here
    q2 = _hand_accel_two(add(s, k1, h / 3))
    q3 = _hand_accel_two(add(add(s, k1, -h / 3), q2, h))
    q4 = _hand_accel_two(add(add(add(s, k1, h), q2, -h), q3, h))
    three_eighths = [si + h / 8 * (a + 3 * b + 3 * c + d) for si, a, b, c, d in zip(s, k1, q2, q3, q4)]
    assert np.abs(np.array(three_eighths) - hand).max() > 1e-6


def test_rk4_is_fourth_order():
    z0 = _state([0, 0, 0.5, 0], [1.5, 0.2, -0.3, 0.4], [0.4, 1.3, 0, -0.6])
    horizon = 1.0

    def integrate(h):
        z = z0
        for _ in range(int(round(horizon / h))):
            z = T.rk4_step(z, h)
        return z

    ref = integrate(0.002)
    errors = [np.abs(integrate(h) - ref).max() for h in (0.1, 0.05, 0.025)]
    ratios = [errors[0] / errors[1], errors[1] / errors[2]]
    assert all(12 < r < 20 for r in ratios), (errors, ratios)


def test_tanner_swarm_stepper_matches_rk4_step():
    z = T.initial_states(np.random.default_rng(2), 1, 5, 'gym_flock')
    swarm = T.TannerSwarm(z, 'gym_flock')
    out = swarm.step()
    np.testing.assert_array_equal(out, T.rk4_step(z, T.DT, 10.0))
    assert out.shape == (1, 5, 4)


def test_paper_initial_conditions_statistics():
    S, n = 200, 2000
    z = T.initial_states(np.random.default_rng(11), S, n, 'paper')
    assert z.shape == (S, n, 4) and z.dtype == np.float64
    # positions uniform by area on the disk of radius sqrt(n): P(rho <= q R) = q^2
    rho = np.linalg.norm(z[..., :2], axis=-1) / math.sqrt(n)
    assert rho.max() <= 1.0
    for q in (0.25, 0.5, 0.75, 0.9):
        assert np.mean(rho <= q) == pytest.approx(q * q, abs=0.005)
    angle = np.arctan2(z[..., 1], z[..., 0])
    assert np.abs(np.mean(np.exp(1j * angle))) < 0.01
    # velocities: bias (estimated by the swarm mean, std ~0.03) plus |u| ~ U[0, 3], uniform direction
    bias = z[..., 2:].mean(axis=1)
    rel = np.linalg.norm(z[..., 2:] - bias[:, None, :], axis=-1) / 3.0
    assert rel.max() < 1.06
    for q in (0.1, 0.25, 0.5, 0.75, 0.9):  # uniform in magnitude, not by area
        assert np.quantile(rel, q) == pytest.approx(q, abs=0.02)
    b = np.linalg.norm(bias, axis=-1)
    assert b.max() < 3.1 and np.mean(b) == pytest.approx(1.5, abs=0.2)
    assert np.abs(np.mean(bias / b[:, None], axis=0)).max() < 0.2


def test_gym_flock_initial_conditions_statistics():
    S, n = 200, 2000
    z = T.initial_states(np.random.default_rng(12), S, n, 'gym_flock')
    rho = np.linalg.norm(z[..., :2], axis=-1) / n**0.25
    assert rho.max() <= 1.0
    assert np.mean(rho <= 0.5) == pytest.approx(0.25, abs=0.005)
    bias = z[..., 2:].mean(axis=1)
    rel = z[..., 2:] - bias[:, None, :]
    assert np.abs(rel).max() < 3.2  # the estimated bias is off by ~0.04 per axis
    np.testing.assert_allclose(rel.std(), math.sqrt(3.0), rtol=0.01)  # U(-3, 3): variance 3
    assert np.abs(bias).max() < 3.1 and bias.std() == pytest.approx(math.sqrt(3.0), rel=0.15)


def test_global_controller_flocks_energy_decreases_and_no_collision():
    """Over 2000 steps for several seeds: Q non-increasing, velocities align, no collision."""
    states = np.concatenate(
        [simulate('flock2d', 4, 10, 2000, seed, progress=False, min_separation=0.15) for seed in (0, 1, 2)]
    )
    assert states.shape == (12, 2000, 10, 4)
    # dt = 0.01 resolves the 1/r^5 repulsion when no pair starts nearer than ~0.15 (the paper's
    # unconditioned draw does not ensure that; see test_close_start_is_under_resolved)
    energy = T.tanner_energy(states)  # [S, T]
    assert np.diff(energy, axis=1).max() <= 1e-9 * np.abs(energy).max()
    avd = _avd(states[..., 2:])
    assert np.all(avd[:, -1] < 0.05 * avd[:, 0])
    assert np.all(avd[:, -1] < 0.03)
    min_dist = _pair_distances(states[..., :2]).min(axis=-1)  # [S, T, n]
    assert min_dist.min() > 0.1
    amd = min_dist.mean(axis=-1)
    assert np.all(np.abs(amd[:, -1] - 0.70) < 0.02)  # lattice spacing near the minimum of V


def test_close_start_is_under_resolved_and_min_separation_prevents_it():
    # seed 0 of the paper's dataset: trajectory 25 starts with a pair 0.02 apart
    z = T.initial_states(np.random.default_rng(0), 50, 10)
    closest = T._min_pair_distance(z[..., :2])
    assert np.argmin(closest) == 25 and closest[25] < 0.03
    one = z[25]
    for _ in range(3):
        one = T.rk4_step(one, 0.01)
    assert np.linalg.norm(one[:, 2:], axis=-1).max() > 1000  # a spurious kick (exact ODE: ~50)
    kept = T.initial_states(np.random.default_rng(0), 50, 10, min_separation=0.15)
    assert T._min_pair_distance(kept[..., :2]).min() >= 0.15
    np.testing.assert_array_equal(
        kept, T.initial_states(np.random.default_rng(0), 50, 10, min_separation=0.15)
    )
    with pytest.raises(ValueError, match='min_separation'):
        T.initial_states(np.random.default_rng(0), 1, 10, min_separation=5.0, max_redraws=20)
    with pytest.raises(ValueError, match='flock2d only'):
        simulate('boids3d', 1, 3, 2, 0, progress=False, min_separation=0.1)


def test_unknown_variant_and_bad_sizes():
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match='variant'):
        T.initial_states(rng, 1, 3, 'nope')
    with pytest.raises(ValueError):
        T.initial_states(rng, 0, 3)
    with pytest.raises(ValueError, match='preset'):
        simulate('boids3d', 1, 3, 2, 0, preset='gym_flock', progress=False)
    with pytest.raises(ValueError, match='steps'):
        simulate('flock2d', 1, 3, 0, 0, progress=False)


# ----------------------------------------------------------------------------------------------
# Boids
# ----------------------------------------------------------------------------------------------


def test_presets():
    assert (PAPER.min_speed, PAPER.max_speed, PAPER.max_steer_force) == (2, 5, 3)
    assert (
        PAPER.align_weight,
        PAPER.cohesion_weight,
        PAPER.separate_weight,
        PAPER.avoid_collision_weight,
    ) == (1, 1, 1, 10)
    assert (PUBLISHED.min_speed, PUBLISHED.max_speed, PUBLISHED.max_steer_force) == (5, 8, 8)
    assert (
        PUBLISHED.align_weight,
        PUBLISHED.cohesion_weight,
        PUBLISHED.separate_weight,
        PUBLISHED.avoid_collision_weight,
    ) == (2, 1, 2.5, 20)
    for p in (PAPER, PUBLISHED):
        assert (p.perception_radius, p.avoidance_radius, p.bounds_radius, p.collision_avoid_dst) == (
            2.5,
            1.0,
            0.27,
            5.0,
        )
        assert (p.num_directions, p.box, p.dt) == (300, 5.0, 1 / 60)
    assert presets('boids3d') == ('paper', 'published') and presets('flock2d') == ('paper', 'gym_flock')


def test_steer_towards_by_hand():
    st = lambda w, v: B.steer_towards(np.array(w, float), np.array(v, float), 5.0, 3.0)  # noqa: E731
    np.testing.assert_allclose(st([2, 0, 0], [0, 0, 0]), [3, 0, 0])  # 5 clamped to 3
    np.testing.assert_allclose(st([0, 2, 0], [0, 4, 0]), [0, 1, 0])  # under the clamp
    np.testing.assert_allclose(st([0, 0, 0], [1, 0, 0]), [-1, 0, 0])  # normalise(0) = 0
    np.testing.assert_allclose(st([0, 0, 0], [0, 0, 7]), [0, 0, -3])  # ... then clamped
    np.testing.assert_allclose(st([1, 0, 0], [0, 5, 0]), [3 / math.sqrt(2), -3 / math.sqrt(2), 0])
    np.testing.assert_allclose(st([3e-6, 0, 0], [1, 0, 0]), [-1, 0, 0])  # Unity: |w| <= 1e-5 -> 0


def _hand_boids():
    p = np.array([[0, 0, 0], [0.5, 0, 0], [0, 2, 0], [4, -4, 4]], float)
    h = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [0, -1, 0]], float)
    return p, h


def test_flock_terms_by_hand():
    # 0-1 at 0.5 (inside avoidance), 0-2 at 2 and 1-2 at sqrt(4.25) ~ 2.06 (perceived only),
    # boid 3 far from all (> 2.5)
    p, h = _hand_boids()
    count, align, coh, sep = B.flock_terms(p, h, PAPER)
    np.testing.assert_array_equal(count, [2, 2, 2, 0])
    np.testing.assert_allclose(align, [[0, 1, 1], [1, 0, 1], [1, 1, 0], [0, 0, 0]])
    np.testing.assert_allclose(coh, [[0.25, 1, 0], [-0.5, 1, 0], [0.25, -2, 0], [0, 0, 0]])
    # separation: -offset/|offset|^2 with offset = p_j - p_i = (0.5,0,0) for boid 0 -> (-2,0,0)
    np.testing.assert_allclose(sep, [[-2, 0, 0], [2, 0, 0], [0, 0, 0], [0, 0, 0]])


def _hand_steer(w, v, max_speed, max_force):
    m = math.sqrt(sum(x * x for x in w))
    unit = [x / m for x in w] if m > 1e-5 else [0.0, 0.0, 0.0]
    s = [u * max_speed - vi for u, vi in zip(unit, v)]
    ms = math.sqrt(sum(x * x for x in s))
    return [x * max_force / ms for x in s] if ms > max_force else s


def test_flocking_acceleration_by_hand_for_three_boids():
    p, h = _hand_boids()
    v = 3.5 * h  # spawn speed (2 + 5) / 2
    acc = B.flocking_acceleration(p, v, PUBLISHED)  # unequal weights 2 / 1 / 2.5
    terms = {
        0: ([0, 1, 1], [0.25, 1, 0], [-2, 0, 0]),
        1: ([1, 0, 1], [-0.5, 1, 0], [2, 0, 0]),
        2: ([1, 1, 0], [0.25, -2, 0], [0, 0, 0]),
    }
    for i, (a, c, s) in terms.items():
        expected = np.zeros(3)
        for w, weight in ((a, 2.0), (c, 1.0), (s, 2.5)):
            expected += weight * np.array(_hand_steer(w, list(v[i]), 8.0, 8.0))
        np.testing.assert_allclose(acc[i], expected, rtol=1e-13)
    # boid 2: the zero separation heading brakes: steer(0) = -v = (0, 0, -3.5), under the clamp 8
    assert _hand_steer([0, 0, 0], list(v[2]), 8.0, 8.0) == [0.0, 0.0, -3.5]
    np.testing.assert_array_equal(acc[3], 0.0)  # no flockmates: no flocking force


def test_golden_spiral():
    d = B.golden_spiral_directions(300)
    assert d.shape == (300, 3)
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0, rtol=1e-14)
    np.testing.assert_allclose(d[0], [0, 0, 1], atol=1e-15)  # first is forward (+z)
    assert np.all(np.diff(d[:, 2]) < 0)  # forward to backward
    assert d[-1, 2] < -0.99
    np.testing.assert_allclose(d.mean(axis=0), [0, 0, 1 / 300], atol=0.01)
    # Lague: inclination acos(1 - 2 i/300), azimuth 2 pi phi i; check i = 1 by hand
    inc, az = math.acos(1 - 2 / 300), 2 * math.pi * (1 + math.sqrt(5)) / 2
    np.testing.assert_allclose(
        d[1], [math.sin(inc) * math.cos(az), math.sin(inc) * math.sin(az), math.cos(inc)]
    )


def test_look_rotation_maps_forward_and_is_a_rotation():
    np.testing.assert_allclose(B.look_rotation(np.array([0, 0, 1.0])), np.eye(3), atol=1e-15)
    h = B.normalise(np.random.default_rng(3).standard_normal((50, 3)))
    h[0] = [0, 1, 0]  # degenerate with up
    h[1] = [0, -1, 0]
    R = B.look_rotation(h)
    np.testing.assert_allclose(R @ R.transpose(0, 2, 1), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    np.testing.assert_allclose(B.golden_spiral_directions()[0] @ R, h, atol=1e-12)  # spiral's +z -> h
    assert np.all(np.abs(R[2:, 0, 1]) < 1e-15)  # right = up x h is horizontal


def test_sweep_hits_wall_by_hand():
    hit = lambda p, d: bool(B.sweep_hits_wall(np.array(p, float), B.normalise(np.array(d, float)), PAPER))  # noqa
    # contact needs the centre to travel box - r - p = 5 - 0.27 - p along the wall normal, within 5
    assert hit([0, 0, 0], [1, 0, 0])  # 4.73 <= 5
    assert not hit([-0.5, 0, 0], [1, 0, 0])  # 5.23 > 5
    assert hit([-0.2, 0, 0], [1, 0, 0])  # 4.93
    assert not hit([0, 0, 0], [0.9, math.sqrt(1 - 0.81), 0])  # travels 4.5 < 4.73 in x, 2.18 in y
    assert hit([0, 3, 0], [0.9, math.sqrt(1 - 0.81), 0])  # but y reaches 3 + 2.18 >= 4.73
    assert hit([0, 0, 0], [0, 0, -1])  # every wall, both signs
    # a boid already within bounds_radius of a wall: only moving further in counts
    assert not hit([4.9, 0, 0], [-1, 0, 0])
    assert not hit([4.9, -3, 0], [0, 1, 0])  # parallel to it (y reaches 2 < 4.73)
    assert hit([4.9, -3, 0], [1e-3, 1, 0])  # slightly into it


def test_avoidance_direction_is_first_clear_spiral_direction():
    rng = np.random.default_rng(4)
    p = rng.uniform(-4.5, 4.5, (40, 3))
    h = B.normalise(rng.standard_normal((40, 3)))
    got = B.avoidance_directions(p, h, PAPER)
    spiral = B.golden_spiral_directions()
    for i in range(40):  # Lague's loop, one direction at a time
        R = B.look_rotation(h[i])
        expected = h[i]
        for k in range(300):
            d = spiral[k] @ R
            if not B.sweep_hits_wall(p[i], d, PAPER):
                expected = d
                break
        np.testing.assert_allclose(got[i], expected, atol=1e-12)
        if not B.sweep_hits_wall(p[i], h[i], PAPER):
            np.testing.assert_allclose(got[i], h[i], atol=1e-12)  # forward itself is clear


def test_boid_flying_at_a_wall_turns_away():
    swarm = BoidsSwarm([[[3.0, 0.2, -0.1]]], [[[5.0, 0.0, 0.0]]], PAPER)  # one boid, no flockmates
    xs, hx = [], []
    for _ in range(180):
        z = swarm.step()
        xs.append(z[0, 0, 0])
        hx.append(z[0, 0, 3])
    assert max(xs) < 5.0 - PAPER.bounds_radius
    assert hx[-1] < 0.0  # now heading away from the +x wall
    assert np.all(np.abs(swarm.positions) < 5.0)


@pytest.mark.parametrize('preset', ['paper', 'published'])
def test_full_run_invariants(preset):
    """Speeds stay in [min, max], headings unit, no boid leaves the cube (1709 frames)."""
    params = B.PRESETS[preset]
    trajectories = 4 if preset == 'paper' else 2
    swarm = BoidsSwarm.spawn(np.random.default_rng(7), trajectories, 10, params)
    assert np.linalg.norm(swarm.positions, axis=-1).max() <= params.spawn_radius
    np.testing.assert_allclose(
        np.linalg.norm(swarm.velocities, axis=-1), 0.5 * (params.min_speed + params.max_speed)
    )
    lo, hi, pmax, hdev = np.inf, 0.0, 0.0, 0.0
    for _ in range(B.DISCARD_FRAMES + 1700 - 1):
        z = swarm.step()
        s = np.linalg.norm(swarm.velocities, axis=-1)
        lo, hi = min(lo, s.min()), max(hi, s.max())
        pmax = max(pmax, np.abs(z[..., :3]).max())
        hdev = max(hdev, np.abs(np.linalg.norm(z[..., 3:], axis=-1) - 1).max())
    assert params.min_speed - 1e-12 <= lo and hi <= params.max_speed + 1e-12
    assert pmax < params.box
    assert hdev < 1e-12


def test_boids_step_matches_single_swarm_and_spawn_is_deterministic():
    a = BoidsSwarm.spawn(np.random.default_rng(9), 3, 6)
    b = BoidsSwarm.spawn(np.random.default_rng(9), 3, 6)
    np.testing.assert_array_equal(a.positions, b.positions)
    one = BoidsSwarm(a.positions[1:2], a.velocities[1:2])
    for _ in range(30):
        za = a.step()
        z1 = one.step()
    np.testing.assert_allclose(z1[0], za[1], rtol=0, atol=1e-12)
    again = BoidsSwarm.from_observation(z1, PAPER)
    np.testing.assert_allclose(again.observe(), z1, atol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(again.velocities, axis=-1), 3.5)


# ----------------------------------------------------------------------------------------------
# simulate and the generator
# ----------------------------------------------------------------------------------------------


def test_simulate_shapes_discard_and_determinism():
    a = simulate('boids3d', 2, 5, 20, seed=3, progress=False)
    b = simulate('boids3d', 2, 5, 20, seed=3, progress=False)
    c = simulate('boids3d', 2, 5, 20, seed=4, progress=False)
    assert a.shape == (2, 20, 5, 6) and a.dtype == np.float64
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    # frame 0 of the recording is frame 10 after the spawn
    swarm = BoidsSwarm.spawn(np.random.default_rng(3), 2, 5, PAPER)
    for _ in range(B.DISCARD_FRAMES):
        swarm.step()
    np.testing.assert_array_equal(a[:, 0], swarm.observe())
    f = simulate('flock2d', 2, 4, 3, seed=3, preset='gym_flock', progress=False)
    z0 = T.initial_states(np.random.default_rng(3), 2, 4, 'gym_flock')
    np.testing.assert_array_equal(f[:, 0], z0)
    np.testing.assert_array_equal(f[:, 2], T.rk4_step(T.rk4_step(z0, 0.01, 10.0), 0.01, 10.0))


def _generate(*args):
    from training.generate import main

    return main(list(args) + ['--no-progress'])


def test_generator_round_trip_and_determinism(tmp_path):
    out1, out2 = tmp_path / 'a.npz', tmp_path / 'sub' / 'b.npz'
    common = [
        '--scenario',
        'boids3d',
        '--trajectories',
        '4',
        '--robots',
        '5',
        '--steps',
        '12',
        '--seed',
        '8',
        '--preset',
        'published',
    ]
    assert _generate(*common, '--out', str(out1)) == 0
    assert _generate(*common, '--out', str(out2)) == 0
    f1, f2 = load_trajectories(out1, 'boids3d'), load_trajectories(out2)
    assert f1.states.shape == (4, 12, 5, 6) and f1.dt == pytest.approx(1 / 60)
    np.testing.assert_array_equal(f1.states, f2.states)
    assert f1.meta == f2.meta
    assert f1.meta['split'] == {'train': [0], 'test': [1, 2, 3]}  # round(4/11) -> at least 1
    assert f1.meta['seed'] == 8 and f1.meta['generator'] == 'training.generate'
    assert f1.meta['parameters'] == json.loads(json.dumps(parameters('boids3d', 'published')))
    assert f1.meta['parameters']['max_speed'] == 8.0
    np.testing.assert_array_equal(f1.states, simulate('boids3d', 4, 5, 12, 8, 'published', progress=False))
    np.testing.assert_array_equal(f1.split('test'), [1, 2, 3])

    out3 = tmp_path / 'f.npz'
    assert (
        _generate(
            '--scenario',
            'flock2d',
            '--trajectories',
            '5',
            '--robots',
            '3',
            '--steps',
            '4',
            '--variant',
            'gym_flock',
            '--train',
            '2',
            '--out',
            str(out3),
        )
        == 0
    )
    f3 = load_trajectories(out3, 'flock2d')
    assert f3.states.shape == (5, 4, 3, 4) and f3.dt == 0.01
    assert f3.meta['split'] == {'train': [0, 1], 'test': [2, 3, 4]}
    assert f3.meta['parameters']['accel_clip'] == 10.0
    assert f3.meta['parameters']['min_separation'] is None
    assert len(f3.meta['diagnostics']['initial_min_distance']) == 5

    out4 = tmp_path / 'g.npz'
    assert (
        _generate(
            '--scenario',
            'flock2d',
            '--trajectories',
            '3',
            '--robots',
            '4',
            '--steps',
            '2',
            '--min-separation',
            '0.5',
            '--out',
            str(out4),
        )
        == 0
    )
    f4 = load_trajectories(out4)
    assert f4.meta['parameters']['min_separation'] == 0.5
    assert min(f4.meta['diagnostics']['initial_min_distance']) >= 0.5
    np.testing.assert_array_equal(
        f4.states, simulate('flock2d', 3, 4, 2, 0, progress=False, min_separation=0.5)
    )
    with pytest.raises(SystemExit):
        _generate('--scenario', 'boids3d', '--min-separation', '0.5', '--out', str(out4))


def test_default_splits():
    from training.generate import default_train

    assert default_train('flock2d', 50) == 30 and default_train('boids3d', 22) == 2  # the paper's
    assert default_train('flock2d', 10) == 6 and default_train('boids3d', 44) == 4
    assert default_train('flock2d', 1) == 1 and default_train('boids3d', 2) == 1
    assert default_train('flock2d', 2) == 1  # keeps a test one


@pytest.mark.parametrize(
    'args, flag',
    [
        (['--trajectories', '0'], '--trajectories'),
        (['--robots', '-3'], '--robots'),
        (['--steps', 'many'], '--steps'),
        (['--seed', '-1'], '--seed'),
        (['--preset', 'published'], '--preset'),  # flock2d takes --variant
        (['--variant', 'fancy'], '--variant'),
        (['--trajectories', '3', '--train', '4'], '--train'),
        (['--min-separation', '0'], '--min-separation'),
    ],
)
def test_generator_bad_arguments(args, flag, tmp_path, capsys):
    out = tmp_path / 'x.npz'
    with pytest.raises(SystemExit) as exc:
        _generate('--scenario', 'flock2d', '--out', str(out), *args)
    assert exc.value.code != 0
    assert flag in capsys.readouterr().err
    assert not out.exists()


def test_generator_module_entry_point(tmp_path):
    # one real process (importing knode_swarm_ros.core loads torch: a few seconds)
    run = subprocess.run(
        [
            sys.executable,
            '-m',
            'training.generate',
            '--scenario',
            'flock2d',
            '--trajectories',
            '2',
            '--robots',
            '3',
            '--steps',
            '2',
            '--out',
            str(tmp_path / 'y.npz'),
        ],
        cwd=REPO,
        capture_output=True,
        text=True,
        env={**os.environ, 'PYTHONPATH': str(REPO)},
    )
    assert run.returncode == 0, run.stderr
    assert '1 train / 1 test' in run.stderr
    assert load_trajectories(tmp_path / 'y.npz').states.shape == (2, 2, 3, 4)


def test_reader_rejects_broken_files(tmp_path):
    good = simulate('flock2d', 1, 3, 2, 0, progress=False)

    def write(name, states, scenario='flock2d'):
        path = tmp_path / name
        np.savez(path, states=states, dt=np.float64(0.01), scenario=np.str_(scenario), meta=np.str_('{}'))
        return path

    bad = good.copy()
    bad[0, 1, 2, 3] = np.nan
    with pytest.raises(TrajectoryError, match='non-finite'):
        load_trajectories(write('nan.npz', bad))
    with pytest.raises(TrajectoryError, match='d = 6'):
        load_trajectories(write('shape.npz', good[..., :3].repeat(2, axis=-1)))
    with pytest.raises(TrajectoryError, match='states'):
        load_trajectories(write('dims.npz', good[0]))
    with pytest.raises(TrajectoryError, match='scenario'):
        load_trajectories(write('scen.npz', good, 'flock4d'))


def test_min_separation_is_any_positive_finite_distance():
    """0.5 (below 1) is accepted; 0, negatives and non-finite values are refused by name."""
    a = simulate('flock2d', 1, 3, 2, 0, progress=False, min_separation=0.05)
    assert a.shape == (1, 2, 3, 4) and parameters('flock2d', min_separation=0.5)['min_separation'] == 0.5
    for bad in (0.0, -0.5, float('nan'), float('inf')):
        with pytest.raises(ValueError, match='min_separation must be a positive number'):
            parameters('flock2d', min_separation=bad)


@pytest.mark.parametrize('scenario', ['flock2d', 'boids3d'])
def test_the_progress_bar_total_is_the_number_of_steps_it_counts(monkeypatch, scenario):
    import knode_swarm_ros.core.groundtruth as G

    bars = []

    class Bar:
        def __init__(self, enabled, total, desc):
            self.total, self.n = total, 0
            bars.append(self)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

        def update(self):
            self.n += 1

    monkeypatch.setattr(G, '_progress_bar', Bar)
    simulate(scenario, 1, 3, 4, 0, progress=True)
    assert len(bars) == 1 and bars[0].n == bars[0].total


def test_boids_parameters_are_checked_at_their_edges():
    assert B.BoidsParams(num_directions=1).num_directions == 1  # one ray (straight ahead) is enough
    assert B.BoidsParams(min_speed=3.0, max_speed=3.0).max_speed == 3.0
    with pytest.raises(ValueError, match='num_directions must be >= 1'):
        B.BoidsParams(num_directions=0)
    with pytest.raises(ValueError, match='min_speed <= max_speed'):
        B.BoidsParams(min_speed=0.0)
    with pytest.raises(ValueError, match='must exceed bounds_radius'):
        B.BoidsParams(box=0.27, bounds_radius=0.27)


def test_tanner_energy_by_hand_for_any_leading_shape():
    """Q = 1/2 (sum_{i != j} V(|r_ij|) + sum |v_i|^2), V(r) = 1/r^2 + ln r^2: V(1) = 1. An equilateral
    triangle of side 1 (6 ordered pairs) with speeds 1, 2, 0: Q = (6 + 5) / 2, whatever the
    leading dimensions (a frame [n, 4], a batch [S, n, 4], a run [S, T, n, 4])."""
    tri = np.array([[0.0, 0.0, 1.0, 0.0], [1.0, 0.0, 0.0, 2.0], [0.5, math.sqrt(3) / 2, 0.0, 0.0]])
    assert T.tanner_energy(tri) == pytest.approx(5.5, rel=1e-12)
    np.testing.assert_allclose(T.tanner_energy(tri[None]), [5.5], rtol=1e-12)
    np.testing.assert_allclose(T.tanner_energy(np.stack([tri, tri])[None]), [[5.5, 5.5]], rtol=1e-12)
