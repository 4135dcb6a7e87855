"""Fleet files (logic/contract/fleet.py): validation, topic resolution, a Crazyswarm2 crazyflies.yaml."""

from pathlib import Path

import pytest
import yaml

from knode_swarm_ros.core.estimator import DEFAULT_WINDOW, window_for_rate
from knode_swarm_ros.logic.common import ConfigError, command_topic, odom_topic
from knode_swarm_ros.logic.contract.fleet import default_fleet, load_fleet, parse_fleet, resolve_topic

FLEETS = Path(__file__).resolve().parent.parent / 'config' / 'fleets'

ISSUE = {
    'robots': {'cf231': {'id': 0}, 'cf5': {'id': 7, 'initial_position': [1.0, 0.0, 0.5]}},
    'state': {'topic': '/vrpn_mocap/{name}/pose', 'type': 'pose'},
    'command': {'topic': '/{name}/cmd_vel', 'type': 'twist_stamped', 'interface': 'velocity_setpoint'},
}


def _with(**changes):
    data = yaml.safe_load(yaml.safe_dump(ISSUE))
    for where, value in changes.items():
        section, key = where.split('__')
        data[section][key] = value
    return data


def test_the_issue_fleet():
    fleet = parse_fleet(ISSUE)
    assert fleet.ids == [0, 7] and fleet.names == ['cf231', 'cf5']
    assert fleet.state_topic(7) == '/vrpn_mocap/cf5/pose'
    assert fleet.command_topic(0, 'acceleration') == '/cf231/cmd_vel'
    assert fleet.command_type('acceleration') == 'twist_stamped'
    assert fleet.robot('cf5').initial_position == (1.0, 0.0, 0.5)
    assert fleet.robot(7).name == 'cf5' and fleet.status_topic(7) == 'cf5/agent_status'
    assert fleet.meta() == {'robot_ids': [0, 7], 'robot_names': ['cf231', 'cf5']}
    fleet.check_scenario('acceleration', True)
    with pytest.raises(ConfigError, match='velocity_setpoint'):
        fleet.check_scenario('velocity', False)
    with pytest.raises(ConfigError, match="robot 'cf9' is not in the fleet"):
        fleet.robot('cf9')


def test_default_fleet_is_the_simulator_layout():
    fleet = default_fleet([2, 0, 1])
    assert fleet.names == ['robot_0', 'robot_1', 'robot_2']
    for i in range(3):
        assert fleet.state_topic(i) == odom_topic(i)
        for kind in ('acceleration', 'velocity'):
            assert fleet.command_topic(i, kind) == command_topic(i, kind)
    assert fleet.command_type('acceleration') == 'accel_stamped'
    assert fleet.command_type('velocity') == 'twist_stamped'
    assert fleet.frame(1) == 'robot_1/base_link' and fleet.owns_frame('robot_1/base_footprint', 1)
    assert not fleet.owns_frame('robot_10/base_link', 1) and fleet.owns_frame('', 1)


def test_topic_resolution_absolute_and_relative():
    assert resolve_topic('/vrpn_mocap/{name}/pose', 'cf5', 7) == '/vrpn_mocap/cf5/pose'
    assert resolve_topic('odom', 'tb4_2', 2) == 'tb4_2/odom'  # the robot's namespace, still relative
    assert resolve_topic('/robot{id}/odom', 'x', 3) == '/robot3/odom'
    assert resolve_topic('mocap/{name}_{id}', 'cf5', 7) == 'cf5/mocap/cf5_7'


@pytest.mark.parametrize(
    'data, message',
    [
        ({**ISSUE, 'extra': 1}, r'top level: unknown key\(s\) extra'),
        (_with(state__frequency=100), r'state: unknown key\(s\) frequency'),
        ({**ISSUE, 'robots': {'cf1': {'id': 0, 'colour': 'red'}}}, r'robots: cf1: unknown key\(s\) colour'),
        ({**ISSUE, 'robots': {'cf1': {'id': 3}, 'cf2': {'id': 3}}}, "robots: cf2: id 3 is also robot cf1's"),
        ({**ISSUE, 'robots': {'cf1': {}}}, 'robots: cf1: no id'),
        ({**ISSUE, 'robots': {'cf1': {'id': -1}}}, 'robots: cf1: id must be an integer >= 0'),
        ({**ISSUE, 'robots': {'cf-1': {'id': 1}}}, 'robots: cf-1: a robot name'),
        (
            _with(state__topic='/mocap/{robot}/pose'),
            r"state: topic '/mocap/{robot}/pose' has unknown field\(s\) {robot}",
        ),
        (_with(command__topic='/{name}/{cf}'), 'command: topic .* unknown field'),
        (_with(state__topic='/{name}/odom'), "state: type 'pose' does not match topic '/{name}/odom'"),
        (_with(command__topic='/{name}/cmd_accel'), "command: type 'twist_stamped' does not match"),
        (
            _with(command__type='accel_stamped', command__topic='/{name}/acc'),
            'interface velocity_setpoint sends',
        ),
        (_with(state__type='twist'), "state: type 'twist' is not one of odometry, pose"),
        (_with(command__interface='fly'), "command: interface 'fly' is not one of"),
        (_with(state__velocity_window=1), 'velocity_window must be an integer >= 2'),
        (_with(command__speed_limit=0), 'speed_limit must be a number > 0'),
        (_with(state__rate=0), 'state: rate must be a number > 0'),
        (_with(state__rate='fast'), 'state: rate must be a number > 0'),
        ({'state': ISSUE['state']}, 'no robots: section'),
        ([1, 2], 'must be a YAML mapping'),
    ],
)
def test_refused_naming_the_entry(data, message):
    with pytest.raises(ConfigError, match=message):
        parse_fleet(data, 'f.yaml')


def test_the_velocity_window_defaults_to_the_lag_of_the_100_hz_design_at_the_stated_rate():
    assert [window_for_rate(r) for r in (100, 120, 20, 10, 1)] == [10, 12, 3, 2, 2]
    assert parse_fleet(ISSUE).state.velocity_window == DEFAULT_WINDOW == 10  # no rate stated
    assert parse_fleet(_with(state__rate=20)).state.velocity_window == 3
    assert parse_fleet(_with(state__rate=20)).state.rate == 20.0
    assert parse_fleet(_with(state__rate=20, state__velocity_window=7)).state.velocity_window == 7
    assert load_fleet(FLEETS / 'crazyswarm2.yaml').state.velocity_window == 10


def test_a_crazyswarm2_crazyflies_yaml_is_a_robot_list():
    fleet = load_fleet(FLEETS / 'crazyflies.yaml')
    assert fleet.names == ['cf5', 'cf231'] and fleet.ids == [5, 231]  # cf7 is disabled
    assert fleet.state.type == 'odometry' and fleet.command.interface == 'policy'
    assert fleet.robot('cf5').initial_position == (1.0, 0.0, 0.0)


def test_the_worked_examples_load():
    cf = load_fleet(FLEETS / 'crazyswarm2.yaml')
    assert cf.names == ['cf5', 'cf231'] and cf.state_topic(231) == '/vrpn_mocap/cf231/pose'
    assert cf.command_topic(5, 'acceleration') == '/cf5/cmd_velocity_world' and cf.command.speed_limit == 1.0
    tb = load_fleet(FLEETS / 'turtlebot4.yaml')
    assert tb.state_topic(2) == 'tb4_2/odom' and tb.command_topic(2, 'velocity') == 'tb4_2/cmd_vel'
    assert tb.command.interface == 'unicycle'


def test_unreadable_files_are_named(tmp_path):
    with pytest.raises(ConfigError, match='fleet file .*none.yaml: cannot be read'):
        load_fleet(tmp_path / 'none.yaml')
    bad = tmp_path / 'bad.yaml'
    bad.write_text('robots: [\n')
    with pytest.raises(ConfigError, match='bad.yaml: not valid YAML'):
        load_fleet(bad)
