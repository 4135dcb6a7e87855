"""The simulator's robot-model registry (logic/simulator/robot_models), model by model.

Every registered model integrates one hand-computed step, stops as documented, publishes the
documented Odometry fields and refuses what it cannot run; the registry holds exactly the names
docs/ros.md documents.
"""

import math

import numpy as np
import pytest

from knode_swarm_ros.core.scenarios import get_scenario
from knode_swarm_ros.logic.common import ConfigError
from knode_swarm_ros.logic.simulator.robot_models import (
    DEFAULT_ROBOT_MODEL,
    ROBOT_MODELS,
    RobotModel,
    check_robot_model,
    make_robot_model,
)

H = math.sqrt(0.5)

# (model, scenario, z0 [1, d], command [1, m], dt, states after one step, stop command afterwards
#  with stop_limit None, wire (kind, fields))
STEPS = [
    (  # double integrator: p + v dt + a dt^2 / 2, v + a dt; a stop brakes to rest in one step (-v / dt)
        'double_integrator',
        'flock2d',
        [[1.0, 2.0, 0.5, -1.0]],
        [[2.0, 4.0]],
        0.5,
        [[1.0 + 0.25 + 0.25, 2.0 - 0.5 + 0.5, 1.5, 1.0]],
        [[-3.0, -2.0]],
        ('acceleration', (0, 1)),
    ),
    (  # boids3d point robots: p + u dt, heading u / |u|; a stop is zero velocity
        'double_integrator',
        'boids3d',
        [[0.0, 0.0, 0.0, 1.0, 0.0, 0.0]],
        [[0.0, 3.0, 3.0]],
        2.0,
        [[0.0, 6.0, 6.0, 0.0, H, H]],
        [[0.0, 0.0, 0.0]],
        ('velocity', (0, 1, 2)),
    ),
    (  # unicycle at heading 0, speed 1, commanded (v, omega) = (1, pi/2) for 1 s: a quarter circle
        # of radius 2 / pi, ending at heading pi/2 (states: axle, speed * heading); a stop is (0, 0)
        'unicycle',
        'flock2d',
        [[0.0, 0.0, 1.0, 0.0]],
        [[1.0, math.pi / 2]],
        1.0,
        [[2 / math.pi, 2 / math.pi, 0.0, 1.0]],
        [[0.0, 0.0]],
        ('velocity', (0, 5)),
    ),
]


def test_the_registry_lists_exactly_the_documented_models():
    assert list(ROBOT_MODELS) == ['double_integrator', 'unicycle']
    assert DEFAULT_ROBOT_MODEL == 'double_integrator'
    assert all(issubclass(cls, RobotModel) for cls in ROBOT_MODELS.values())
    assert {row[0] for row in STEPS} == set(ROBOT_MODELS)  # every model is tested below


@pytest.mark.parametrize('name,scenario,z0,u,dt,after,stop,wire', STEPS)
def test_every_model_integrates_a_known_step(name, scenario, z0, u, dt, after, stop, wire):
    spec = get_scenario(scenario)
    robots = make_robot_model(name, spec, np.array(z0))
    assert np.allclose(robots.states(), z0, atol=1e-15)
    assert (robots.wire.kind, robots.wire.fields) == wire and robots.command_dim == len(wire[1])
    robots.step(np.array(u), dt)
    assert np.allclose(robots.states(), after, atol=1e-12)
    assert robots.states().shape == (1, spec.state_dim)
    assert np.allclose(robots.stop_commands(None, dt), stop, atol=1e-12)


def test_the_double_integrator_brakes_at_the_stop_limit():
    robots = make_robot_model('double_integrator', get_scenario('flock2d'), np.array([[0.0, 0.0, 3.0, -0.1]]))
    assert np.array_equal(robots.stop_commands(2.0, 0.5), [[-2.0, 0.2]])  # saturated per axis


def test_odometry_fields_follow_rep105():
    flock = make_robot_model('double_integrator', get_scenario('flock2d'), np.array([[1.0, 2.0, 0.5, -1.0]]))
    assert flock.odom_fields(0) == ((1.0, 2.0, 0.0), (0.0, 0.0, 0.0, 1.0), (0.5, -1.0, 0.0), (0.0, 0.0, 0.0))
    uni = make_robot_model('unicycle', get_scenario('flock2d'), np.array([[1.0, 2.0, 0.0, -0.5]]))
    position, quaternion, linear, angular = uni.odom_fields(0)  # heading -pi/2, speed 0.5
    assert position == (1.0, 2.0, 0.0) and linear == (0.5, 0.0, 0.0) and angular == (0.0, 0.0, 0.0)
    assert np.allclose(quaternion, [0.0, 0.0, -H, H])
    boids = make_robot_model(
        'double_integrator', get_scenario('boids3d'), np.array([[0.0, 0.0, 0.0, 1.0, 0.0, 0.0]])
    )
    boids.step(np.array([[2.0, 0.0, 0.0]]), 0.1)
    assert np.allclose(boids.odom_fields(0)[2], [2.0, 0.0, 0.0])  # the applied velocity, body frame


@pytest.mark.parametrize(
    'name,scenario,ground_truth,params,words',
    [
        ('nope', 'flock2d', False, {}, "'robot_model' = 'nope' is not one of double_integrator, unicycle"),
        ('unicycle', 'boids3d', False, {}, "'robot_model' = 'unicycle' needs scenario flock2d, not boids3d"),
        ('unicycle', 'flock2d', True, {}, "'robot_model' = 'unicycle' cannot be driven by the ground truth"),
        ('unicycle', 'flock2d', False, {'max_linear_speed': -1.0}, 'parameter max_linear_speed must be'),
    ],
)
def test_models_refuse_what_they_cannot_run(name, scenario, ground_truth, params, words):
    spec = get_scenario(scenario)
    z0 = np.zeros((2, spec.state_dim))
    with pytest.raises(ConfigError, match='parameter') as err:
        make_robot_model(name, spec, z0, ground_truth, params)
    assert words in str(err.value)


def test_what_each_model_can_run():
    for scenario in ('flock2d', 'boids3d'):
        for gt in (False, True):
            assert check_robot_model('double_integrator', scenario, gt) is ROBOT_MODELS['double_integrator']
    assert check_robot_model('unicycle', 'flock2d', False) is ROBOT_MODELS['unicycle']
    with pytest.raises(ConfigError, match='^--robot-model unicycle needs scenario flock2d'):
        check_robot_model('unicycle', 'boids3d', False, label='--robot-model unicycle')


def test_a_model_reads_only_its_own_parameters():
    spec = get_scenario('flock2d')
    z0 = np.array([[0.0, 0.0, 3.0, 0.0]])
    limits = {'max_linear_speed': 0.5, 'max_angular_speed': 0.0}
    assert np.array_equal(make_robot_model('double_integrator', spec, z0, parameters=limits).states(), z0)
    assert make_robot_model('unicycle', spec, z0, parameters=limits).states()[0, 2] == 0.5  # saturated


def test_unicycle_commands_are_read_from_a_twist_stamped():
    """The simulator reads each model's command from the serialized message by its wire's fields:
    the unicycle's (linear.x, angular.z) of a TwistStamped."""
    from geometry_msgs.msg import TwistStamped
    from rclpy import serialization

    from knode_swarm_ros.nodes.common.conversions import command_fields_from_cdr, time_msg

    msg = TwistStamped()
    msg.header.stamp = time_msg(1_500_000_000)
    msg.twist.linear.x, msg.twist.linear.y, msg.twist.angular.z = 0.7, 9.0, -1.3
    ns, u = command_fields_from_cdr(
        serialization.serialize_message(msg), ROBOT_MODELS['unicycle'].wire.fields
    )
    assert ns == 1_500_000_000 and np.array_equal(u, [0.7, -1.3]) and u.dtype == np.float64
