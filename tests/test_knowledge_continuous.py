"""The continuous avoidance potentials (core.knowledge, PolicyConfig.potential = "continuous").

U(d) = (lambda / 2) (1/d - 1/d0)^2 for d < d0, summed over every heard neighbour (per face for
walls): the force is minus its gradient, vanishes continuously at d0 and does not jump when the
closest neighbour changes (the paper's form does both: the checks below measure its jumps too,
they are why the variant exists), and keeps the paper's lambda / d^3 growth at contact.
"""

import math

import pytest
import torch
from test_knowledge import float64, matrices  # noqa: F401  (float64: the autouse double-precision fixture)

from knode_swarm_ros.core.knowledge import (
    collision_avoidance,
    continuous_collision_avoidance,
    continuous_collision_potential,
    continuous_wall_avoidance,
    continuous_wall_potential,
    wall_avoidance,
)


def both(Y, mask, p, gain, d0, **kw):
    """(continuous, paper) collision forces ``[B, p]``."""
    return (
        continuous_collision_avoidance(Y, mask, p, torch.tensor(gain), d0, **kw),
        collision_avoidance(Y, mask, p, torch.tensor(gain), d0, **kw),
    )


def one_neighbour(dist, p=2, direction=0):
    """The robot at the origin, one active neighbour at ``dist`` along axis ``direction``."""
    other = [0.0] * p
    other[direction] = dist
    return matrices([0.0] * p, [other], [1, 1])


# --- force = -grad U --------------------------------------------------------------------------


@pytest.mark.parametrize('p,gain,d0,seed', [(2, 1.7, 1.0, 0), (3, 0.6, 0.8, 1), (2, 2.5, 1.3, 2)])
def test_collision_force_is_minus_grad_of_the_summed_potential(p, gain, d0, seed):
    """Random batches with several neighbours: some masked, some beyond d0, several within it."""
    torch.manual_seed(seed)
    B, k = 40, 6
    Y = torch.randn(B, k, 2 * p)
    Y[:, 1:, :p] = Y[:, :1, :p] + torch.randn(B, k - 1, p) * 0.7 * d0
    mask = (torch.rand(B, k) < 0.7).double()
    mask[:, 0] = 1
    Y[:, :, :p][mask == 0] = 0.0  # padded rows are zeros, as the neighbour matrix writes them
    dist = torch.linalg.vector_norm(Y[:, 1:, :p] - Y[:, :1, :p], dim=-1)
    heard = mask[:, 1:] > 0
    assert dist.min() > 1e-3  # no floor here: the floor is not a gradient (tested below)
    # the table really holds every kind of row: several within d0, masked ones within d0, far ones
    assert ((dist < d0) & heard).sum(-1).max() >= 3
    assert ((dist < d0) & ~heard).any() and ((dist >= d0) & heard).any()
    Yg = Y.clone().requires_grad_(True)
    U = continuous_collision_potential(Yg, mask, p, torch.tensor(gain), d0)
    (g,) = torch.autograd.grad(U.sum(), Yg)
    force = continuous_collision_avoidance(Y, mask, p, torch.tensor(gain), d0)
    torch.testing.assert_close(force, -g[:, 0, :p])
    assert force.abs().max() > 0


def test_collision_force_by_hand():
    # lambda = 2, d0 = 1. (0.5, 0): d = 0.5, magnitude 2 (2 - 1) / 0.25 = 8 along -x.
    # (0, -0.25): d = 0.25, magnitude 2 (4 - 1) / 0.0625 = 96 along +y. (0.1, 0) masked and
    # (1.5, 0) beyond d0 add nothing.
    Y, mask = matrices([0.0, 0.0], [[0.5, 0.0], [0.0, -0.25], [0.1, 0.0], [1.5, 0.0]], [1, 1, 1, 0, 1])
    force, paper = both(Y, mask, 2, 2.0, 1.0)
    torch.testing.assert_close(force, torch.tensor([[-8.0, 96.0]]))
    # the paper's form: the closest neighbour only, lambda / d^3 = 2 / 0.25^3 along +y
    torch.testing.assert_close(paper, torch.tensor([[0.0, 128.0]]))


@pytest.mark.parametrize('box,d0,gain', [(5.0, 1.0, 0.8), (0.6, 1.0, 1.3), (2.0, 0.7, 2.0)])
def test_wall_force_is_minus_grad_of_potential_inside_the_box(box, d0, gain):
    """box = 0.6 < d0: both faces of an axis push at once."""
    torch.manual_seed(3)
    p = (torch.rand(60, 3) * 2 - 1) * (box - 1e-2)
    near = (box - p.abs()) < d0
    assert near.any() and (box < d0 or (~near).any())
    pg = p.clone().requires_grad_(True)
    (g,) = torch.autograd.grad(continuous_wall_potential(pg, box, torch.tensor(gain), d0).sum(), pg)
    force = continuous_wall_avoidance(p, box, torch.tensor(gain), d0)
    torch.testing.assert_close(force, -g)
    assert force.abs().max() > 0


def test_wall_force_by_hand():
    # lambda = 1, d0 = 1, box 5: x 0.5 from +x: -(2 - 1) / 0.25 = -4; z 0.25 from -z: (4 - 1) / 0.0625 = 48.
    # box 0.6, x = 0.1: 0.5 from +x (-4) and 0.7 from -x (+(1/0.7 - 1) / 0.49).
    f = continuous_wall_avoidance(
        torch.tensor([[4.5, 0.0, -4.75], [0.0, 0.0, 0.0]]), 5.0, torch.tensor(1.0), 1.0
    )
    torch.testing.assert_close(f, torch.tensor([[-4.0, 0.0, 48.0], [0.0, 0.0, 0.0]]))
    f = continuous_wall_avoidance(torch.tensor([[0.1, 0.0]]), 0.6, torch.tensor(1.0), 1.0)
    torch.testing.assert_close(f, torch.tensor([[-4.0 + (1 / 0.7 - 1) / 0.49, 0.0]]))


# --- continuity ----------------------------------------------------------------------------


@pytest.mark.parametrize('gain,d0', [(1.0, 1.0), (1.7, 0.8)])
def test_collision_force_vanishes_continuously_at_d0_where_the_paper_jumps(gain, d0):
    for eps in (1e-2, 1e-4, 1e-6):
        inside, paper_inside = both(*one_neighbour(d0 - eps), 2, gain, d0)
        # lambda (1/(d0 - eps) - 1/d0) / (d0 - eps)^2 = lambda eps / d0^4 (1 + O(eps))
        ratio = inside.norm() / (gain * eps / d0**4)
        assert abs(ratio - 1) <= 4 * eps / d0, (eps, ratio)
        at_d0, paper_at_d0 = both(*one_neighbour(d0), 2, gain, d0)
        beyond, paper_beyond = both(*one_neighbour(d0 + eps), 2, gain, d0)
        assert torch.count_nonzero(at_d0) == 0 and torch.count_nonzero(beyond) == 0
        # the paper's force is lambda / d0^3 at d0 (its range includes d0) and 0 just beyond
        torch.testing.assert_close(paper_at_d0.norm() - paper_beyond.norm(), torch.tensor(gain / d0**3))
        assert paper_inside.norm() >= gain / d0**3


@pytest.mark.parametrize('gain,d0', [(1.0, 1.0), (0.6, 0.75)])  # box - d0 exact in binary
def test_wall_force_vanishes_continuously_at_d0_where_the_paper_jumps(gain, d0):
    box = 5.0
    for eps in (1e-2, 1e-4, 1e-6):
        inside = continuous_wall_avoidance(
            torch.tensor([[box - d0 + eps, 0.0, 0.0]]), box, torch.tensor(gain), d0
        )
        assert inside[0, 0] < 0 and abs(inside[0, 0].item() / (-gain * eps / d0**4) - 1) <= 4 * eps / d0
        for x in (box - d0, box - d0 - eps):
            position = torch.tensor([[x, 0.0, -x]])
            assert torch.count_nonzero(continuous_wall_avoidance(position, box, torch.tensor(gain), d0)) == 0
        jump = wall_avoidance(
            torch.tensor([[box - d0, 0.0, 0.0]]), box, torch.tensor(gain), d0
        ) - wall_avoidance(torch.tensor([[box - d0 - eps, 0.0, 0.0]]), box, torch.tensor(gain), d0)
        torch.testing.assert_close(jump, torch.tensor([[-gain / d0**3, 0.0, 0.0]]))


@pytest.mark.parametrize('p', [2, 3])
def test_no_jump_when_two_neighbours_swap_rank(p):
    """A at 0.5 + s along +x, B at 0.5 - s along +y: the closest one changes at s = 0. The
    continuous sum moves by O(eps) (Lipschitz bound 2 |f'(0.5)| sqrt(2) eps < 100 lambda eps),
    the paper's force turns by 90 degrees: a jump of sqrt(2) lambda / 0.5^3."""
    gain, d0 = 1.3, 1.0

    def at(s):
        a, b = [0.0] * p, [0.0] * p
        a[0], b[1] = 0.5 + s, 0.5 - s
        return both(*matrices([0.0] * p, [a, b], [1, 1, 1]), p, gain, d0)

    for eps in (1e-3, 1e-5, 1e-7):
        (c_before, p_before), (c_after, p_after) = at(-eps), at(eps)
        assert (c_after - c_before).norm() <= 100 * gain * eps
        torch.testing.assert_close(
            (p_after - p_before).norm(),
            torch.tensor(math.sqrt(2) * gain / 0.5**3),
            rtol=1e-4 + 10 * eps,
            atol=0,
        )


# --- a sum over neighbours -------------------------------------------------------------------


def test_symmetric_neighbours_cancel_and_the_paper_does_not():
    Y, mask = matrices([0.0, 0.0], [[0.4, 0.0], [-0.4, 0.0]], [1, 1, 1])
    force, paper = both(Y, mask, 2, 1.0, 1.0)
    assert torch.count_nonzero(force) == 0 and paper.norm() > 1.0
    # three at 120 degrees, equal distance: the sum cancels to rounding
    ring = [
        [0.3 * math.cos(a), 0.3 * math.sin(a)] for a in (0.1, 0.1 + 2 * math.pi / 3, 0.1 + 4 * math.pi / 3)
    ]
    Y, mask = matrices([0.0, 0.0], ring, [1, 1, 1, 1])
    force, _ = both(Y, mask, 2, 1.0, 1.0)
    single, _ = both(*matrices([0.0, 0.0], ring[:1], [1, 1]), 2, 1.0, 1.0)
    assert force.norm() <= 1e-12 * single.norm()


def test_masked_rows_contribute_nothing():
    """A masked row (a close one, and a zero padding row on top of a robot at the origin) leaves
    the force of the other rows exactly as without it."""
    own, heard = [0.0, 0.0], [[0.3, 0.2], [-0.5, 0.1]]
    without, _ = both(*matrices(own, heard, [1, 1, 1]), 2, 1.2, 1.0)
    for extra in ([0.05, 0.0], [0.0, 0.0]):
        Y, mask = matrices(own, heard + [extra], [1, 1, 1, 0])
        with_masked, _ = both(Y, mask, 2, 1.2, 1.0)
        assert torch.equal(with_masked, without)
    # all masked, or k = 1 (the own row only): zeros of shape [B, p]
    Y, mask = matrices(own, heard, [1, 0, 0])
    assert torch.count_nonzero(both(Y, mask, 2, 1.2, 1.0)[0]) == 0
    for p in (2, 3):
        Y = torch.randn(5, 1, 2 * p)
        force = continuous_collision_avoidance(Y, torch.ones(5, 1), p, torch.tensor(1.0), 1.0)
        assert force.shape == (5, p) and torch.count_nonzero(force) == 0


# --- the floor and contact ------------------------------------------------------------------


def floored(gain, min_distance, d0):
    return gain * (1 / min_distance - 1 / d0) / min_distance**2


@pytest.mark.parametrize(
    'dist,direction,expected_axis,sign',
    [
        (0.005, 1, 1, -1.0),  # closer than the floor, neighbour along +y: push along -y
        (0.01, 0, 0, -1.0),  # exactly at the floor: the formula and the floor agree
        (0.0, 0, 0, 1.0),  # on top of each other: +x, the first position axis
    ],
)
def test_closer_than_the_floor_pushes_with_the_magnitude_at_the_floor(dist, direction, expected_axis, sign):
    gain, d0, md = 1.5, 1.0, 0.01
    force, _ = both(*one_neighbour(dist, direction=direction), 2, gain, d0, min_distance=md)
    expected = torch.zeros(1, 2)
    expected[0, expected_axis] = sign * floored(gain, md, d0)
    torch.testing.assert_close(force, expected)


def test_coincident_robots_have_finite_gradients():
    Y, mask = matrices([1.0, 1.0], [[1.0, 1.0], [1.5, 1.0]], [1, 1, 1])
    Y.requires_grad_(True)
    phi = torch.tensor(1.3, requires_grad=True)
    continuous_collision_avoidance(Y, mask, 2, phi * phi, d0=1.0).sum().backward()
    assert torch.isfinite(Y.grad).all() and torch.isfinite(phi.grad).all()
    # d(sum of the force)/d(phi): 2 phi (the floored +x push - the push (1/0.5 - 1)/0.25 along -x)
    torch.testing.assert_close(phi.grad, torch.tensor(2 * 1.3 * (floored(1.0, 1e-3, 1.0) - 4.0)))


def test_outside_the_box_is_pushed_back_in_with_the_floored_magnitude():
    f = continuous_wall_avoidance(torch.tensor([[6.0, -7.0, 0.0]]), 5.0, torch.tensor(1.0), 1.0)
    torch.testing.assert_close(f, torch.tensor([[-1.0, 1.0, 0.0]]) * floored(1.0, 1e-3, 1.0))


@pytest.mark.parametrize('d0', [1.0, 0.5])
def test_contact_growth_is_the_papers_lambda_over_d_cubed(d0):
    """magnitude d^3 / lambda = 1 - d / d0 -> 1 as d -> 0, for neighbours and walls alike."""
    gain, box = 2.0, 5.0
    for d in (1e-1, 1e-2, 1e-3, 1e-5):
        force, paper = both(*one_neighbour(d, p=3, direction=2), 3, gain, d0, min_distance=1e-9)
        ratio = force.norm().item() * d**3 / gain
        assert abs(ratio - 1) <= d / d0 * (1 + 1e-9), (d, ratio)
        torch.testing.assert_close(paper.norm(), torch.tensor(gain / d**3))
        wall = continuous_wall_avoidance(
            torch.tensor([[0.0, box - d, 0.0]]), box, torch.tensor(gain), d0, min_distance=1e-9
        )
        # (box - d is rounded: the distance the wall sees is d to a relative 1e-12 or so)
        assert abs(-wall[0, 1].item() * d**3 / gain - 1) <= d / d0 * (1 + 1e-6)
