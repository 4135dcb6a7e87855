"""Walls of a double integrator act on the distance left after braking at the command limit
(core/knowledge.py, ``stopping_reach``): a robot that could no longer stop inside the box is
pushed back with more than any learnt command, and nothing changes for a robot at rest."""

import json

import pytest
import torch

from knode_swarm_ros.core.knowledge import continuous_wall_avoidance, stopping_reach, wall_avoidance
from knode_swarm_ros.core.policy import KNODEPolicy, PolicyConfig
from knode_swarm_ros.core.scenarios import scenario_from_dict

BOX, D0, LIMIT = 4.0, 0.8, 4.0
GAIN = torch.tensor(LIMIT * D0**3 / 8)  # the push at d0 / 2 is half the limit


def test_stopping_reach_is_v_squared_over_twice_the_limit_along_the_motion():
    up, down = stopping_reach(torch.tensor([[2.0, -1.0, 0.0]]), LIMIT)
    assert up.tolist() == [[0.5, 0.0, 0.0]] and down.tolist() == [[0.0, 0.125, 0.0]]


@pytest.mark.parametrize('term', [continuous_wall_avoidance, wall_avoidance])
def test_the_push_is_the_resting_push_at_the_distance_left_after_braking(term):
    p = torch.tensor([[3.5, -3.6, 0.0]], dtype=torch.float64)  # 0.5 m from +x, 0.4 m from -y
    v = torch.tensor([[1.0, -1.0, 0.0]], dtype=torch.float64)  # reaches 0.125 m further on both axes
    moving = term(p, BOX, GAIN, D0, velocity=v, limit=LIMIT)
    resting = term(p + torch.tensor([[0.125, -0.125, 0.0]], dtype=torch.float64), BOX, GAIN, D0)
    torch.testing.assert_close(moving, resting)
    assert moving[0, 0] < 0 and moving[0, 1] > 0  # inwards, on both faces
    # at rest, and moving inwards, the term is the distance-only one
    torch.testing.assert_close(
        term(p, BOX, GAIN, D0, velocity=torch.zeros_like(v), limit=LIMIT), term(p, BOX, GAIN, D0)
    )
    torch.testing.assert_close(term(p, BOX, GAIN, D0, velocity=-v, limit=LIMIT), term(p, BOX, GAIN, D0))


def _policy(scenario):
    cfg = PolicyConfig(
        json.dumps(scenario.to_dict()),
        k=2,
        d_cr=1.0,
        hidden=4,
        command_limit=LIMIT,
        collision=False,
        potential='continuous',
        wall=True,
        wall_phi=float(GAIN.sqrt()),
        wall_d0=D0,
    )
    policy = KNODEPolicy(cfg).double()
    with torch.no_grad():  # a learnt part that pushes outwards (+x) at the limit everywhere
        for param in policy.net.parameters():
            param.zero_()
        policy.net[-1].bias[0] = LIMIT
    return policy


def _rollout(policy, speed, steps=200, dt=0.05):
    """One robot from the middle of the box at ``speed`` towards +x; its largest x."""
    z = torch.tensor([[0.0, 0.0, 0.0, speed, 0.0, 0.0]], dtype=torch.float64)
    largest = 0.0
    for _ in range(steps):
        Y = torch.cat([z[:, None, :], torch.zeros_like(z)[:, None, :]], dim=1)
        u = policy(Y, torch.tensor([[1.0, 0.0]], dtype=torch.float64))
        z = torch.cat([z[:, :3] + z[:, 3:] * dt + 0.5 * u * dt * dt, z[:, 3:] + u * dt], dim=1)
        largest = max(largest, float(z[0, 0].detach()))
    return largest


@pytest.mark.parametrize('speed', [1.0, 3.0, 5.0])
def test_a_double_integrator_pushed_outwards_at_the_limit_stays_in_the_box(speed):
    arena = dict(name='box3d', dimensions=3, state='position_velocity', command='acceleration', dt=0.05)
    policy = _policy(scenario_from_dict(dict(arena, arena={'half_width': BOX}), 'box3d'))
    assert _rollout(policy, speed) < BOX
    scripted = torch.jit.script(policy)  # the exported policy brakes the same way
    assert _rollout(scripted, speed) == pytest.approx(_rollout(policy, speed))


def test_without_braking_the_same_robot_leaves_the_box():
    """The contrast: the distance-only wall term lets a fast robot through."""
    arena = dict(name='box3d', dimensions=3, state='position_velocity', command='acceleration', dt=0.05)
    policy = _policy(scenario_from_dict(dict(arena, arena={'half_width': BOX}), 'box3d'))
    policy.wall_brake = False
    assert _rollout(policy, 5.0) > BOX
