"""Order parameters on hand-built configurations with known values: a perfect mill, a perfect
flock, a random gas, groups of known count, escapes and closest approaches."""

import numpy as np
import pytest

from knode_swarm_ros.core.metrics import (
    amd,
    closest_approach,
    escaped,
    group_count,
    group_labels,
    nearest_neighbour_distance,
    polarisation,
    rotation_order,
    speed_quantiles,
    velocities,
)
from knode_swarm_ros.core.scenarios import Scenario, get_scenario


def ring(n, radius=3.0, centre=(1.0, -2.0)):
    angle = 2 * np.pi * np.arange(n) / n
    pos = np.stack([np.cos(angle), np.sin(angle)], -1) * radius + np.asarray(centre)
    tangent = np.stack([-np.sin(angle), np.cos(angle)], -1)
    return pos, tangent


def lift(x, z=0.0):
    """2D rows [n, 2] -> 3D rows [n, 3] in the plane at height z."""
    return np.concatenate([x, np.full(x.shape[:-1] + (1,), z)], -1)


@pytest.mark.parametrize('dim', [2, 3])
@pytest.mark.parametrize('direction', [1.0, -1.0])
def test_a_perfect_mill_has_rotation_1_and_polarisation_0(dim, direction):
    pos, tangent = ring(12)
    vel = direction * tangent * np.linspace(0.5, 2.0, 12)[:, None]  # any speeds
    if dim == 3:
        pos, vel = lift(pos, 4.0), lift(vel)
    assert rotation_order(pos, vel) == pytest.approx(1.0, abs=1e-12)
    assert polarisation(vel) == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize('dim', [2, 3])
def test_a_perfect_flock_has_polarisation_1_and_rotation_0(dim):
    pos, _ = ring(8)
    vel = np.tile(np.array([0.6, 0.8]), (8, 1)) * np.arange(1, 9)[:, None]
    if dim == 3:
        pos, vel = lift(pos), lift(vel)
    assert polarisation(vel) == pytest.approx(1.0, abs=1e-12)
    assert rotation_order(pos, vel) == pytest.approx(0.0, abs=1e-12)  # symmetric about the centroid


@pytest.mark.parametrize('dim', [2, 3])
def test_a_random_gas_has_small_order_parameters(dim):
    """Uniform random directions: n |mean unit vector|^2 has mean 1, so both parameters stay
    below 5 / sqrt(n) except with a probability below e^-12 (Hoeffding)."""
    rng = np.random.default_rng(11)
    n = 400
    pos = rng.uniform(-10, 10, size=(n, dim))
    vel = rng.normal(size=(n, dim))
    bound = 5 / np.sqrt(n)
    assert polarisation(vel) < bound
    assert rotation_order(pos, vel) < bound


def test_resting_robots_and_robots_at_the_centroid_add_nothing():
    pos = np.array([[0.0, 0.0], [1.0, 0.0], [-1.0, 0.0]])
    vel = np.array([[1.0, 0.0], [0.0, 0.0], [0.0, 2.0]])
    assert polarisation(vel) == pytest.approx(np.sqrt(2) / 3)
    assert rotation_order(pos, vel) == pytest.approx(1 / 3)  # only the third robot turns (clockwise)


def test_order_parameters_broadcast_over_leading_axes():
    pos, tangent = ring(6)
    pos = np.stack([pos, pos])
    vel = np.stack([tangent, np.tile([1.0, 0.0], (6, 1))])
    np.testing.assert_allclose(rotation_order(pos, vel), [1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(polarisation(vel), [0.0, 1.0], atol=1e-12)


def test_nearest_neighbour_distance_and_closest_approach():
    pos = np.array([[0.0, 0.0], [1.0, 0.0], [3.0, 0.0]])
    np.testing.assert_array_equal(nearest_neighbour_distance(pos), [1.0, 1.0, 2.0])
    assert amd(pos) == pytest.approx(4 / 3)
    trajectory = np.stack([pos, pos * 0.25, pos * 2])  # [T, n, 2]
    assert closest_approach(trajectory) == 0.25
    assert closest_approach(np.stack([trajectory, trajectory * 4])).tolist() == [0.25, 1.0]


@pytest.mark.parametrize(
    'points,distance,count',
    [
        # three far-apart clusters
        ([[0, 0], [0.5, 0], [10, 0], [10, 0.5], [10.5, 0.5], [0, 20]], 1.0, 3),
        # a chain in shuffled order: linked end to end through every link, endpoints 4 apart
        ([[4, 0], [0, 0], [2, 0], [1, 0], [3, 0]], 1.0, 1),
        # the link at exactly the distance counts; just beyond does not
        ([[0, 0], [1, 0]], 1.0, 1),
        ([[0, 0], [1.0 + 1e-9, 0]], 1.0, 2),
        # everyone alone
        ([[0, 0, 0], [5, 0, 0], [0, 5, 0], [0, 0, 5]], 1.0, 4),
    ],
)
def test_groups_of_known_count(points, distance, count):
    assert group_count(np.asarray(points, dtype=float), distance) == count


def test_group_labels_name_each_group_by_its_lowest_index():
    pos = np.array([[10.0, 0], [0, 0], [10.5, 0], [0.5, 0]])
    np.testing.assert_array_equal(group_labels(pos, 1.0), [0, 1, 0, 1])
    np.testing.assert_array_equal(group_count(np.stack([pos, pos * 0.01]), 1.0), [2, 1])


def test_speed_quantiles():
    vel = np.array([[1.0, 0], [0, 2.0], [3.0, 0], [0, -4.0], [3.0, 4.0]])
    np.testing.assert_allclose(speed_quantiles(vel, (0.0, 0.5, 1.0)), [1.0, 3.0, 5.0])
    assert speed_quantiles(np.stack([vel, 2 * vel])).shape == (2, 5)


def test_escapes_count_leaving_the_arena_not_starting_outside():
    # [T, n, 2]: robot 0 stays in; robot 1 leaves at t = 2; robot 2 starts outside and never
    # gets in; robot 3 starts outside, gets in, and leaves again
    x = np.array(
        [
            [0.0, 4.0, 6.0, 6.0],
            [1.0, 4.9, 6.0, 4.0],
            [2.0, 5.1, 7.0, 5.5],
        ]
    )
    pos = np.stack([x, np.zeros_like(x)], -1)
    np.testing.assert_array_equal(escaped(pos, 5.0), [False, True, False, True])
    assert escaped(pos, 5.0).sum() == 2


def test_velocities_follow_the_scenario():
    flock = get_scenario('flock2d')
    states = np.zeros((3, 2, 4))
    states[..., 2:] = [1.0, -1.0]
    np.testing.assert_array_equal(velocities(states, flock, 0.01), states[..., 2:])
    ground = Scenario('ground', 2, 'position', 'velocity', 0.5, None)
    track = np.array([[[0.0, 0.0]], [[1.0, 0.0]], [[1.0, 2.0]]])  # [T=3, n=1, 2]
    np.testing.assert_array_equal(velocities(track, ground, 0.5)[:, 0], [[2, 0], [2, 0], [0, 4]])
    with pytest.raises(ValueError, match='2 frames'):
        velocities(track[:1], ground, 0.5)
