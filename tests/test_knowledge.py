"""Knowledge terms: forces equal minus the autograd gradient of their potentials."""

import pytest
import torch

from knode_swarm_ros.core import AvoidanceGain, collision_avoidance, wall_avoidance
from knode_swarm_ros.core.knowledge import collision_potential, wall_potential


@pytest.fixture(autouse=True)
def float64():
    """These checks compare against autograd in double precision; restore the default after."""
    old = torch.get_default_dtype()
    torch.set_default_dtype(torch.float64)
    yield
    torch.set_default_dtype(old)


def matrices(own, neighbours, mask_rows, d=None):
    """Y [1, k, d] with the positions given (d = 2 p: zero velocities), mask [1, k] from mask_rows."""
    rows = [own] + neighbours
    Y = torch.zeros(1, len(rows), d or 2 * len(own))
    Y[0, :, : len(own)] = torch.tensor(rows, dtype=torch.float64)
    return Y, torch.tensor([mask_rows], dtype=torch.float64)


def grad_of_potential(Y, mask, gain, d0):
    Y = Y.clone().requires_grad_(True)
    U = collision_potential(Y, mask, 2, gain, d0).sum()
    (g,) = torch.autograd.grad(U, Y)
    return g[:, 0, :2]  # gradient w.r.t. the robot's own position


def test_collision_force_is_minus_grad_of_potential():
    gain = torch.tensor(1.7)
    torch.manual_seed(0)
    for _ in range(20):
        Y = torch.zeros(1, 4, 4)
        Y[0, 1:, :2] = torch.randn(3, 2) * 0.5
        mask = torch.tensor([[1.0, 1.0, 1.0, 0.0]])
        force = collision_avoidance(Y, mask, 2, gain, d0=1.0)
        torch.testing.assert_close(force, -grad_of_potential(Y, mask, gain, 1.0))


def test_collision_force_by_hand():
    # Neighbour at (0.5, 0): r = (-0.5, 0), d = 0.5: force = lambda r / d^4 = 2 * (-0.5, 0) / 0.0625.
    Y, mask = matrices([0.0, 0.0], [[0.5, 0.0]], [1, 1])
    force = collision_avoidance(Y, mask, 2, torch.tensor(2.0), d0=1.0)
    torch.testing.assert_close(force, torch.tensor([[-16.0, 0.0]]))


def test_only_the_closest_active_neighbour_counts():
    Y, mask = matrices([0.0, 0.0], [[0.0, 0.3], [0.6, 0.0], [0.0, -0.5]], [1, 0, 1, 1])
    # Row 1 is closest but inactive: the closest active one is row 3 at distance 0.5.
    force = collision_avoidance(Y, mask, 2, torch.tensor(1.0), d0=1.0)
    torch.testing.assert_close(force, torch.tensor([[0.0, 0.5 / 0.5**4]]))


def test_no_force_beyond_d0_or_without_neighbours():
    Y, mask = matrices([0.0, 0.0], [[1.5, 0.0]], [1, 1])
    assert torch.count_nonzero(collision_avoidance(Y, mask, 2, torch.tensor(1.0), d0=1.0)) == 0
    Y, mask = matrices([0.0, 0.0], [[0.1, 0.0]], [1, 0])
    assert torch.count_nonzero(collision_avoidance(Y, mask, 2, torch.tensor(1.0), d0=1.0)) == 0


def test_coincident_robots_get_the_floored_push_along_plus_x():
    # r = 0 has no direction: the documented choice is +x with the floored magnitude
    # lambda / min_distance^3 (not zero).
    Y, mask = matrices([1.0, 1.0], [[1.0, 1.0]], [1, 1])
    force = collision_avoidance(Y, mask, 2, torch.tensor(2.0), d0=1.0, min_distance=0.01)
    torch.testing.assert_close(force, torch.tensor([[2.0 / 0.01**3, 0.0]]))


def test_closer_than_the_floor_keeps_the_direction_and_the_floored_magnitude():
    # d = 0.005 < min_distance = 0.01, neighbour straight below: push straight up with
    # lambda / min_distance^3, not the shrinking lambda * r / min_distance^4.
    Y, mask = matrices([0.0, 0.0], [[0.0, -0.005]], [1, 1])
    force = collision_avoidance(Y, mask, 2, torch.tensor(1.0), d0=1.0, min_distance=0.01)
    torch.testing.assert_close(force, torch.tensor([[0.0, 1.0 / 0.01**3]]))
    # Continuous at the floor: exactly at min_distance both formulas agree.
    Y, mask = matrices([0.0, 0.0], [[0.0, -0.01]], [1, 1])
    force = collision_avoidance(Y, mask, 2, torch.tensor(1.0), d0=1.0, min_distance=0.01)
    torch.testing.assert_close(force, torch.tensor([[0.0, 1.0 / 0.01**3]]))


def test_coincident_robots_have_finite_gradients():
    Y, mask = matrices([1.0, 1.0], [[1.0, 1.0], [1.5, 1.0]], [1, 1, 1])
    Y.requires_grad_(True)
    phi = torch.tensor(1.3, requires_grad=True)
    collision_avoidance(Y, mask, 2, phi * phi, d0=1.0).sum().backward()
    assert torch.isfinite(Y.grad).all() and torch.isfinite(phi.grad).all()
    torch.testing.assert_close(phi.grad, torch.tensor(2 * 1.3 / 1e-3**3))


def test_collision_range_includes_d0_exactly():
    # Neighbour at exactly d0 = 1: U is defined for d <= d0, so the push is lambda r / d^4 = -x.
    Y, mask = matrices([0.0, 0.0], [[1.0, 0.0]], [1, 1])
    force = collision_avoidance(Y, mask, 2, torch.tensor(1.0), d0=1.0)
    torch.testing.assert_close(force, torch.tensor([[-1.0, 0.0]]))


def test_wall_range_includes_d0_exactly():
    # Exactly d0 = 1 from the +x face and from the -y face: lambda / d0^3 = 1 inwards.
    f = wall_avoidance(torch.tensor([[4.0, -4.0, 0.0]]), 5.0, torch.tensor(1.0), 1.0)
    torch.testing.assert_close(f, torch.tensor([[-1.0, 1.0, 0.0]]))


def test_wall_force_is_minus_grad_of_potential_inside_the_box():
    gain = torch.tensor(0.8)
    torch.manual_seed(1)
    p = (torch.rand(50, 3) * 2 - 1) * 4.9
    p.requires_grad_(True)
    (g,) = torch.autograd.grad(wall_potential(p, 5.0, gain, 1.0).sum(), p)
    torch.testing.assert_close(wall_avoidance(p.detach(), 5.0, gain, 1.0), -g)


def test_wall_force_by_hand():
    p = torch.tensor([[4.5, 0.0, -4.75], [0.0, 0.0, 0.0]])
    f = wall_avoidance(p, 5.0, torch.tensor(1.0), 1.0)
    # x: 0.5 from the +x face -> -1/0.5^3 = -8; z: 0.25 from the -z face -> +1/0.25^3 = 64.
    torch.testing.assert_close(f, torch.tensor([[-8.0, 0.0, 64.0], [0.0, 0.0, 0.0]]))


def test_outside_the_box_is_pushed_back_in():
    f = wall_avoidance(torch.tensor([[6.0, -7.0, 0.0]]), 5.0, torch.tensor(1.0), 1.0)
    assert f[0, 0] < 0 and f[0, 1] > 0 and torch.isfinite(f).all()


def test_gain_is_a_plus_phi_squared_and_trains_phi():
    g = AvoidanceGain(a=0.5, phi=-1.5)
    value = g()
    torch.testing.assert_close(value, torch.tensor(0.5 + 2.25, dtype=value.dtype))
    value.backward()
    torch.testing.assert_close(g.phi.grad, torch.tensor(-3.0, dtype=value.dtype))
    assert not g.a.requires_grad
    with pytest.raises(ValueError):
        AvoidanceGain(a=-1.0)
