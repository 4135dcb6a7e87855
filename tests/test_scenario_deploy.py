"""Deploying a scenario of one's own, without ROS running: the REP 105 mapping and the command
messages of every state and command kind, the simulator stepping a custom scenario, its random
start, and the nodes' and the launcher's scenario arguments (docs/scenarios.md)."""

from __future__ import annotations

import itertools

import nav_msgs.msg  # noqa: F401  (a broken install must fail, not skip)
import numpy as np
import pytest

from knode_swarm_ros.core.rollout import zoh_step
from knode_swarm_ros.core.scenarios import get_scenario, scenario_ref
from knode_swarm_ros.logic.common import ConfigError
from knode_swarm_ros.logic.contract.rep105 import fields_to_state, rotate, state_to_fields
from knode_swarm_ros.logic.simulator.swarm_sim import (
    SPACING,
    SwarmSim,
    initial_state,
    make_ground_truth,
    random_start,
)


def _spec(dims, state, arena=None, dt=0.05):
    command = 'acceleration' if state == 'position_velocity' else 'velocity'
    return get_scenario(
        {
            'name': f'kind_{dims}d_{state}',
            'dimensions': dims,
            'state': state,
            'command': command,
            'dt': dt,
            'arena': None if arena is None else {'half_width': arena},
        }
    )


KINDS = [
    _spec(dims, state)
    for dims, state in itertools.product((2, 3), ('position', 'position_velocity', 'position_heading'))
]


def _state(spec, rng):
    z = rng.normal(size=spec.state_dim)
    if spec.heading is not None:
        z[spec.heading] /= np.linalg.norm(z[spec.heading])
    return z


@pytest.mark.parametrize('spec', KINDS, ids=lambda s: s.name)
def test_rep105_fields_of_every_state_kind(spec):
    rng = np.random.default_rng(1)
    for _ in range(20):
        z = _state(spec, rng)
        position, q, linear = state_to_fields(z, spec)
        dims = spec.dimensions
        assert position[:dims] == tuple(z[:dims]) and (dims == 3 or position[2] == 0.0)
        back = fields_to_state(position, q, linear, spec)
        assert back.shape == (spec.state_dim,)
        if spec.state == 'position':  # the pose only: no turn, no twist
            assert q == (0.0, 0.0, 0.0, 1.0) and linear == (0.0, 0.0, 0.0)
            assert np.array_equal(back, z)
        elif spec.state == 'position_velocity':  # identity orientation, the world velocity exactly
            assert q == (0.0, 0.0, 0.0, 1.0)
            assert linear[:dims] == tuple(z[dims:]) and (dims == 3 or linear[2] == 0.0)
            assert np.array_equal(back, z)
        else:  # the heading as the rotation of +x (a yaw in 2D), up to rounding
            if dims == 2:
                assert q[0] == 0.0 and q[1] == 0.0
            assert np.allclose(back, z, rtol=0, atol=1e-15)


@pytest.mark.parametrize('dims', (2, 3))
def test_a_heading_states_twist_is_the_applied_velocity_in_the_child_frame(dims):
    spec = _spec(dims, 'position_heading')
    u = np.array([0.3, -1.2, 0.7][:dims])
    z = np.concatenate([np.ones(dims), u / np.linalg.norm(u)])
    _, q, linear = state_to_fields(z, spec, u)
    world = rotate(np.array(q), np.array(linear))
    assert np.allclose(world, np.pad(u, (0, 3 - dims)), rtol=0, atol=1e-15)
    assert np.allclose(linear, [np.linalg.norm(u), 0.0, 0.0], rtol=0, atol=1e-15)


@pytest.mark.parametrize('spec', KINDS, ids=lambda s: s.name)
def test_odometry_messages_and_their_bytes_round_trip_for_every_state_kind(spec):
    from nav_msgs.msg import Odometry
    from rclpy import serialization

    from knode_swarm_ros.nodes.common.conversions import (
        odom_from_cdr,
        odom_to_cdr,
        odom_to_state,
        state_to_odom,
    )

    rng = np.random.default_rng(2)
    ref = scenario_ref(spec)  # what nodes pass around: the JSON object of a custom scenario
    for robot, ns in ((0, 0), (7, 50_000_000), (123, 1_234_567_890_123)):
        z = _state(spec, rng)
        v = rng.normal(size=spec.dimensions) if spec.heading is not None else None
        msg = state_to_odom(robot, ns, z, ref, v)
        ours = odom_to_cdr(robot, ns, z, ref, v)
        assert serialization.deserialize_message(ours, Odometry) == msg
        got_ns, frame, got = odom_from_cdr(ours, ref)
        assert got_ns == ns and frame == f'robot_{robot}/base_link'
        assert np.array_equal(got, odom_to_state(msg, spec))
        if spec.heading is None:
            assert np.array_equal(got, z)


@pytest.mark.parametrize('dims,command', list(itertools.product((2, 3), ('velocity', 'acceleration'))))
def test_commands_of_every_command_kind_in_2d_and_3d(dims, command):
    from geometry_msgs.msg import AccelStamped, TwistStamped
    from rclpy import serialization

    from knode_swarm_ros.logic.common import command_topic
    from knode_swarm_ros.nodes.common.conversions import (
        command_from_cdr,
        command_msg_type,
        command_to_cdr,
        command_to_msg,
        msg_to_command,
    )

    spec = _spec(dims, 'position_velocity' if command == 'acceleration' else 'position')
    assert command_msg_type(spec) is (AccelStamped if command == 'acceleration' else TwistStamped)
    assert command_topic(3, spec.command) == (
        'robot_3/cmd_accel' if command == 'acceleration' else 'robot_3/cmd_vel'
    )
    u = np.array([1.5, -2.25, 0.125][:dims])
    msg = command_to_msg(42, u, spec)
    linear = msg.accel.linear if command == 'acceleration' else msg.twist.linear
    assert (linear.x, linear.y, linear.z) == (1.5, -2.25, 0.125 if dims == 3 else 0.0)
    ours = command_to_cdr(42, u, spec)
    assert serialization.deserialize_message(ours, command_msg_type(spec)) == msg
    for ns, got in (msg_to_command(msg, spec), command_from_cdr(ours, spec)):
        assert ns == 42 and np.array_equal(got, u)


@pytest.mark.parametrize(
    'spec',
    [_spec(2, 'position'), _spec(3, 'position_velocity', arena=4.0), _spec(3, 'position_heading')],
    ids=lambda s: s.name,
)
def test_the_simulator_steps_a_custom_scenario_as_the_core_does(spec):
    rng = np.random.default_rng(3)
    z0 = random_start(spec, 6, rng)
    sim = SwarmSim(scenario_ref(spec), z0, spec.dt)
    assert sim.robots.wire.kind == spec.command and sim.robots.command_dim == spec.dimensions
    expected = z0
    for step in range(5):
        commands = rng.normal(size=(6, spec.dimensions))
        for r in range(6):
            assert sim.offer(r, sim.stamp_ns, commands[r]) == 'accepted'
        assert sim.can_advance()
        got = sim.advance()
        expected = zoh_step(expected, commands, spec, spec.dt)
        assert np.array_equal(got, expected)
    assert sim.offer(0, sim.stamp_ns, np.zeros(spec.dimensions + 1)) == 'bad_size'
    stop = sim.stop_commands()  # velocity: zero; acceleration: brake towards rest
    if spec.command == 'velocity':
        assert np.array_equal(stop, np.zeros((6, spec.dimensions)))
    else:
        assert np.all(np.sign(stop) == -np.sign(sim.states[:, spec.velocity]))


def test_a_custom_scenario_starts_at_random_in_a_documented_box():
    free = _spec(2, 'position')
    z0, truth = initial_state(scenario_ref(free), 16, seed=4)
    assert truth is None and z0.shape == (16, 2)
    assert np.all(np.abs(z0) <= 0.5 * SPACING * 16**0.5)
    again, _ = initial_state(scenario_ref(free), 16, seed=4)
    assert np.array_equal(z0, again)  # seeded
    room = _spec(3, 'position_velocity', arena=6.0)
    z0, _ = initial_state(room, 9, seed=1)
    assert np.all(np.abs(z0[:, :3]) <= 3.0) and np.array_equal(z0[:, 3:], np.zeros((9, 3)))  # at rest
    heading = _spec(3, 'position_heading')
    z0, _ = initial_state(heading, 9, seed=1)
    assert np.allclose(np.linalg.norm(z0[:, 3:], axis=1), 1.0)


def test_a_custom_scenario_has_no_ground_truth_nor_variants():
    spec = _spec(2, 'position')
    with pytest.raises(ConfigError, match="'ground_truth'.*no ground-truth law"):
        make_ground_truth(scenario_ref(spec), np.zeros((3, 2)))
    with pytest.raises(ConfigError, match="'variant'.*no ground-truth law"):
        initial_state(spec, 3, 0, 'paper')
    # The paper's two keep theirs.
    assert initial_state('flock2d', 3, 0)[1] is not None


def test_markers_of_a_position_state_have_no_arrows():
    from knode_swarm_ros.nodes.common.markers import swarm_markers

    out = swarm_markers(np.array([[0.0, 0.0], [1.0, 0.0]]), _spec(2, 'position'), 1.5, 0)
    assert {m.ns for m in out.markers} == {'robots', 'links'}


def test_node_scenario_parameters_take_a_file_and_name_the_parameter(tmp_path):
    import yaml

    from knode_swarm_ros.nodes.common.params import scenario_parameter

    fields = {
        'name': 'mine',
        'dimensions': 2,
        'state': 'position',
        'command': 'velocity',
        'dt': 0.1,
        'arena': None,
    }
    path = tmp_path / 'mine.yaml'
    path.write_text(yaml.safe_dump(fields))
    ref = scenario_parameter(str(path))
    assert get_scenario(ref) == get_scenario(fields) and scenario_parameter(ref) == ref
    assert scenario_parameter('boids3d') == 'boids3d' and scenario_parameter('') == ''
    with pytest.raises(ConfigError, match=r"parameter 'scenario' = 'nope\.yaml'.*no such file"):
        scenario_parameter('nope.yaml')


def test_swarm_takes_a_scenario_file_and_refuses_what_a_custom_scenario_cannot_do(tmp_path):
    import yaml

    from knode_swarm_ros.nodes.swarm.cli import build_parser
    from knode_swarm_ros.nodes.swarm.plan import plan_run

    fields = {
        'name': 'mine',
        'dimensions': 2,
        'state': 'position',
        'command': 'velocity',
        'dt': 0.1,
        'arena': None,
    }
    path = tmp_path / 'mine.yaml'
    path.write_text(yaml.safe_dump(fields))
    record = str(tmp_path / 'r.npz')

    def plan(*args):
        return plan_run(build_parser().parse_args(['--record', record, *args]))

    with pytest.raises(ConfigError, match='--ground-truth: scenario mine has no ground-truth law'):
        plan('--scenario', str(path), '--ground-truth')
    with pytest.raises(ConfigError, match='no policy is shipped for a scenario of your own'):
        plan('--scenario', str(path))
    with pytest.raises(ConfigError, match='--scenario broken.yaml: scenario file broken.yaml: no such file'):
        plan('--scenario', 'broken.yaml')
    with pytest.raises(ConfigError, match='--scenario .*mine.yaml but the policy .* is for flock2d'):
        plan('--scenario', str(path), '--policy', _shipped_flock2d())


def _shipped_flock2d():
    from knode_swarm_ros.core.policy_meta import shipped_policy_path

    return str(shipped_policy_path('flock2d'))
