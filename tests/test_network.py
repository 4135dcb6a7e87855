"""The information network against hand-built configurations (docs/DESIGN.md, Method A and B)."""

import numpy as np
import pytest

from knode_swarm_ros.core import (
    neighbour_matrices,
    neighbour_matrix,
    neighbour_matrix_rows,
    neighbour_matrix_single,
)


def flock(*rows):
    """flock2d states [n, 4] from (px, py, vx, vy) rows."""
    return np.array(rows, dtype=np.float64)


def test_radius_is_inclusive_and_rows_sorted_by_distance():
    z = flock((0, 0, 1, 1), (3, 4, 0, 0), (1, 0, 2, 2), (0, 2, 3, 3), (3, 4.0001, 9, 9))
    Y, mask = neighbour_matrix(z, z, 2, 5.0, 6)
    # Robot 0: distance 1 (robot 2), 2 (robot 3), exactly 5 (robot 1, kept); 5.0001 (robot 4) is out.
    expected = np.array([z[0], z[2], z[3], z[1], np.zeros(4), np.zeros(4)])
    np.testing.assert_array_equal(Y[0], expected)
    np.testing.assert_array_equal(mask[0], [1, 1, 1, 1, 0, 0])


def test_fewer_robots_than_rows_pads_with_zeros():
    z = flock((0, 0, 1, 0), (1, 0, 0, 1))
    Y, mask = neighbour_matrix(z, z, 2, 5.0, 6)
    assert Y.shape == (2, 6, 4) and mask.shape == (2, 6)
    np.testing.assert_array_equal(Y[1, :2], [z[1], z[0]])
    np.testing.assert_array_equal(Y[1, 2:], 0.0)
    np.testing.assert_array_equal(mask[1], [1, 1, 0, 0, 0, 0])


def test_only_k_minus_1_closest_are_kept():
    z = flock((0, 0, 0, 0), (4, 0, 1, 0), (1, 0, 2, 0), (3, 0, 3, 0), (2, 0, 4, 0))
    Y, mask = neighbour_matrix(z, z, 2, 5.0, 3)
    np.testing.assert_array_equal(Y[0], [z[0], z[2], z[4]])
    assert mask[0].all()


def test_ties_are_broken_by_lower_id():
    z = flock((0, 0, 0, 0), (0, 2, 1, 0), (2, 0, 2, 0), (-2, 0, 3, 0), (0, -2, 4, 0))
    Y, mask = neighbour_matrix(z, z, 2, 5.0, 4)
    np.testing.assert_array_equal(Y[0, 1:, 2], [1, 2, 3])  # robots 1, 2, 3 in id order


def test_many_equidistant_robots_keep_id_order():
    # 16 robots exactly 5 from robot 0 (integer points of the circle of radius 5, shuffled
    # ids): an unstable sort keeps id order for 4 ties but not for this many.
    pts = [
        (5, 0),
        (-5, 0),
        (0, 5),
        (0, -5),
        (3, 4),
        (-3, 4),
        (3, -4),
        (-3, -4),
        (4, 3),
        (-4, 3),
        (4, -3),
        (-4, -3),
    ]
    pts = pts + pts[:4]  # a few robots on the same spot: still distance 5, still id order
    order = np.random.default_rng(0).permutation(len(pts))
    z = flock((0, 0, 0, 0), *[(px, py, i + 1, 0) for i, (px, py) in enumerate(pts[j] for j in order)])
    for k in (6, 13, 17):
        Y, mask = neighbour_matrix(z, z, 2, 5.0, k)
        np.testing.assert_array_equal(Y[0, 1:, 2], np.arange(1, k))  # robots 1..k-1 in id order
        np.testing.assert_array_equal(neighbour_matrix_single(0, z[0], z, 2, 5.0, k)[0], Y[0])


def test_k_equal_one_is_the_robot_alone():
    z = flock((0, 0, 5, 6), (0.5, 0, 0, 0))
    Y, mask = neighbour_matrix(z, z, 2, 5.0, 1)
    np.testing.assert_array_equal(Y[:, 0], z)
    assert Y.shape == (2, 1, 4) and mask.all()


def test_isolated_robot_has_only_its_own_row():
    z = flock((0, 0, 1, 2), (10, 0, 0, 0), (20, 0, 0, 0))
    Y, mask = neighbour_matrix(z, z, 2, 5.0, 4)
    np.testing.assert_array_equal(mask, [[1, 0, 0, 0]] * 3)
    np.testing.assert_array_equal(Y[:, 1:], 0.0)


def test_delay_uses_own_state_now_and_neighbours_at_t_minus_tau():
    # Robot 1 moves away from robot 0: at t = 0, 1 it is within d_cr, at t = 2, 3 outside.
    T = 4
    states = np.zeros((T, 2, 4))
    states[:, 0] = [[0, 0, 0, 0], [0.1, 0, 1, 0], [0.2, 0, 2, 0], [0.3, 0, 3, 0]]
    states[:, 1] = [[1, 0, 10, 0], [3, 0, 11, 0], [6, 0, 12, 0], [9, 0, 13, 0]]
    Y, mask = neighbour_matrices(states, 2, 5.0, 3, tau=2)
    # Own row is always the state at t.
    np.testing.assert_array_equal(Y[:, 0, 0], states[:, 0])
    # t = 0, 1: before t - tau exists, the first frame is used: neighbour state at t = 0.
    np.testing.assert_array_equal(Y[0, 0, 1], states[0, 1])
    np.testing.assert_array_equal(Y[1, 0, 1], states[0, 1])
    # t = 2: state of t = 0 (distance 1 at t - tau, inside), t = 3: state of t = 1 (distance 2.9).
    np.testing.assert_array_equal(Y[2, 0, 1], states[0, 1])
    np.testing.assert_array_equal(Y[3, 0, 1], states[1, 1])
    assert mask[:, 0, 1].all()
    # Without delay, the neighbour at t = 2 (distance 5.8) is out of range.
    Y0, mask0 = neighbour_matrices(states, 2, 5.0, 3, tau=0)
    np.testing.assert_array_equal(mask0[:, 0, 1], [1, 1, 0, 0])


def test_neighbour_set_is_decided_at_t_minus_tau_positions():
    # At t robot 1 is far, but at t - tau it was close: it is a neighbour (delayed rule).
    states = np.zeros((2, 2, 4))
    states[0, 1, :2] = [1, 0]
    states[1, 1, :2] = [100, 0]
    Y, mask = neighbour_matrices(states, 2, 5.0, 2, tau=1)
    assert mask[1, 0, 1] and mask[1, 1, 1]
    np.testing.assert_array_equal(Y[1, 0, 1], states[0, 1])


def test_single_robot_builder_equals_batched_builder_bit_for_bit():
    rng = np.random.default_rng(1)
    z_now = rng.normal(scale=3.0, size=(12, 6))
    z_delayed = z_now + rng.normal(scale=0.5, size=z_now.shape)
    z_delayed[5, :3] = z_delayed[4, :3] + [2.0, 0, 0]  # an exact boundary case at d_cr = 2
    Y, mask = neighbour_matrix(z_now, z_delayed, 3, 2.0, 6)
    for i in range(12):
        Yi, mi = neighbour_matrix_single(i, z_now[i], z_delayed, 3, 2.0, 6)
        np.testing.assert_array_equal(Yi, Y[i])
        np.testing.assert_array_equal(mi, mask[i])


def test_builders_agree_with_fewer_robots_than_rows_and_k_one():
    # 3 robots, k = 6: every builder pads. Batched over 4 frames the leading axes differ from
    # the robot count, and the single-robot builder has one query row (mutation survivors).
    rng = np.random.default_rng(6)
    states = rng.normal(scale=1.0, size=(4, 3, 4))
    Y, mask = neighbour_matrices(states, 2, 50.0, 6, tau=0)
    assert Y.shape == (4, 3, 6, 4)
    np.testing.assert_array_equal(mask, np.broadcast_to([1, 1, 1, 0, 0, 0], (4, 3, 6)))
    for t in range(4):
        for i in range(3):
            Yi, mi = neighbour_matrix_single(i, states[t, i], states[t], 2, 50.0, 6)
            np.testing.assert_array_equal(Yi, Y[t, i])
            np.testing.assert_array_equal(mi, mask[t, i])
    Y1, m1 = neighbour_matrix_single(1, states[0, 1], states[0], 2, 50.0, 1)
    np.testing.assert_array_equal(Y1, states[0, 1:2])
    np.testing.assert_array_equal(m1, [True])


def _reference_matrix(i, z_now_i, z_delayed, p, d_cr, k):
    """Y_i by the definition, one robot, plain Python: neighbours within d_cr (inclusive) of robot
    i's delayed position, sorted by (distance, id), k - 1 of them, zero rows masked."""
    d = z_delayed.shape[1]
    others = [
        (float(np.sqrt(np.sum((z_delayed[j, :p] - z_delayed[i, :p]) ** 2))), j)
        for j in range(len(z_delayed))
        if j != i
    ]
    chosen = sorted((dist, j) for dist, j in others if dist <= d_cr)[: k - 1]
    Y, mask = np.zeros((k, d)), np.zeros(k, dtype=bool)
    Y[0], mask[0] = z_now_i, True
    for row, (_, j) in enumerate(chosen, start=1):
        Y[row], mask[row] = z_delayed[j], True
    return Y, mask


@pytest.mark.parametrize('seed', range(6))
def test_matrices_of_hosted_rows_equal_the_per_robot_definition(seed):
    # What a hosting process builds for its robots at once (rows in any order, repeated, any
    # subset of the robots heard) against the definition one robot at a time: positions on an
    # integer grid make many distances equal (ties, and neighbours exactly at d_cr), a small
    # radius leaves robots without neighbours, and k runs from 1 to more than the robots.
    rng = np.random.default_rng(seed)
    n, p = int(rng.integers(1, 15)), int(rng.choice([2, 3]))
    d = 2 * p
    z_delayed = np.concatenate([rng.integers(-3, 4, size=(n, p)), rng.normal(size=(n, p))], axis=1).astype(
        float
    )
    z_now = z_delayed + rng.normal(size=z_delayed.shape)
    for k in (1, 2, 4, 6, n + 2):
        for d_cr in (0.5, 1.0, 2.0, 50.0):
            rows = rng.integers(0, n, size=int(rng.integers(1, 2 * n + 1)))
            Y, mask = neighbour_matrix_rows(rows, z_now[rows], z_delayed, p, d_cr, k)
            assert Y.shape == (len(rows), k, d) and mask.shape == (len(rows), k)
            full_Y, full_mask = neighbour_matrix(z_now, z_delayed, p, d_cr, k)
            for q, i in enumerate(rows):
                ref_Y, ref_mask = _reference_matrix(i, z_now[i], z_delayed, p, d_cr, k)
                np.testing.assert_array_equal(Y[q], ref_Y)
                np.testing.assert_array_equal(mask[q], ref_mask)
                np.testing.assert_array_equal(Y[q], full_Y[i])  # = the batched builder of training
                np.testing.assert_array_equal(mask[q], full_mask[i])


def test_batched_over_time_and_trajectories_equals_per_snapshot():
    rng = np.random.default_rng(2)
    states = rng.normal(scale=4.0, size=(3, 7, 9, 4))
    Y, mask = neighbour_matrices(states, 2, 5.0, 6, tau=2)
    assert Y.shape == (3, 7, 9, 6, 4) and mask.shape == (3, 7, 9, 6)
    for s in range(3):
        for t in range(7):
            Yr, mr = neighbour_matrix(states[s, t], states[s, max(t - 2, 0)], 2, 5.0, 6)
            np.testing.assert_array_equal(Y[s, t], Yr)
            np.testing.assert_array_equal(mask[s, t], mr)


@pytest.mark.parametrize('bad', [dict(k=0), dict(tau=-1)])
def test_invalid_arguments_are_refused(bad):
    states = np.zeros((2, 2, 4))
    with pytest.raises(ValueError):
        neighbour_matrices(states, 2, 5.0, bad.get('k', 3), bad.get('tau', 0))
