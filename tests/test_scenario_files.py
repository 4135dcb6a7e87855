"""Scenario files: valid ones load, invalid ones are refused naming the field and the file, the
shipped two equal the paper's scenarios, and trajectory and policy files carry a custom scenario."""

import json

import numpy as np
import pytest
import yaml

from knode_swarm_ros.core.errors import ConfigError
from knode_swarm_ros.core.policy_meta import PolicyError, check_meta
from knode_swarm_ros.core.scenarios import (
    SCENARIOS,
    Scenario,
    ScenarioError,
    get_scenario,
    parse_scenario_argument,
    scenario_ref,
)
from knode_swarm_ros.core.trajectory import TrajectoryError, load_trajectories, save_trajectories

BASE = {
    'name': 'my_swarm',
    'dimensions': 2,
    'state': 'position',
    'command': 'velocity',
    'dt': 0.05,
    'arena': None,
}

# (changes to BASE, expected layout)
VALID = [
    ({}, ('px', 'py')),
    ({'dimensions': 3}, ('px', 'py', 'pz')),
    ({'state': 'position_heading'}, ('px', 'py', 'hx', 'hy')),
    ({'state': 'position_velocity', 'command': 'acceleration'}, ('px', 'py', 'vx', 'vy')),
    (
        {
            'dimensions': 3,
            'state': 'position_velocity',
            'command': 'acceleration',
            'arena': {'half_width': 6},
        },
        ('px', 'py', 'pz', 'vx', 'vy', 'vz'),
    ),
    ({'dt': 1}, ('px', 'py')),
]

# (changes to BASE (None deletes the field), the field the message must name)
INVALID = [
    ({'name': None}, 'name'),
    ({'name': ''}, 'name'),
    ({'name': 7}, 'name'),
    ({'name': 'flock2d'}, 'name'),  # a shipped name on other values
    ({'dimensions': None}, 'dimensions'),
    ({'dimensions': 1}, 'dimensions'),
    ({'dimensions': 4}, 'dimensions'),
    ({'dimensions': 2.0}, 'dimensions'),
    ({'dimensions': True}, 'dimensions'),
    ({'dimensions': '2'}, 'dimensions'),
    ({'state': None}, 'state'),
    ({'state': 'velocity'}, 'state'),
    ({'state': ['position']}, 'state'),
    ({'command': None}, 'command'),
    ({'command': 'jerk'}, 'command'),
    ({'command': 3}, 'command'),
    ({'command': 'acceleration'}, 'command'),  # position + acceleration
    ({'state': 'position_heading', 'command': 'acceleration'}, 'command'),
    ({'state': 'position_velocity'}, 'command'),  # position_velocity + velocity
    ({'dt': None}, 'dt'),
    ({'dt': 0}, 'dt'),
    ({'dt': -0.1}, 'dt'),
    ({'dt': '0.05'}, 'dt'),
    ({'dt': float('nan')}, 'dt'),
    ({'dt': True}, 'dt'),
    ({'arena': 'MISSING'}, 'arena'),
    ({'arena': 5.0}, 'arena'),
    ({'arena': {'width': 5.0}}, 'arena'),
    ({'arena': {'half_width': 5.0, 'height': 2}}, 'arena'),
    ({'arena': {'half_width': 0}}, 'arena.half_width'),
    ({'arena': {'half_width': 'big'}}, 'arena.half_width'),
    ({'colour': 'red'}, 'colour'),
]


def scenario(**changes):
    data = dict(BASE)
    for key, value in changes.items():
        if value is None or value == 'MISSING':
            del data[key]
        else:
            data[key] = value
    return data


def write(tmp_path, data, name='s.yaml'):
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data) if not isinstance(data, str) else data)
    return path


@pytest.mark.parametrize('changes,layout', VALID)
def test_valid_scenario_files_load(tmp_path, changes, layout):
    path = write(tmp_path, scenario(**changes))
    spec = get_scenario(str(path))
    assert spec.state_layout == layout and spec.state_dim == len(layout)
    assert spec.position_dim == spec.command_dim == spec.dimensions
    assert get_scenario(spec.to_dict()) == spec == get_scenario(scenario_ref(spec))
    assert parse_scenario_argument(str(path)) == scenario_ref(spec)


@pytest.mark.parametrize('changes,field', INVALID)
def test_invalid_scenario_files_are_refused_naming_field_and_file(tmp_path, changes, field):
    path = write(tmp_path, scenario(**changes))
    with pytest.raises(ScenarioError) as info:
        get_scenario(str(path))
    assert f"field '{field}'" in str(info.value) and str(path) in str(info.value)
    assert isinstance(info.value, ConfigError) and isinstance(info.value, ValueError)


@pytest.mark.parametrize(
    'text,message',
    [
        ('[1, 2]', 'must be a mapping'),
        ('name: [unclosed', 'not valid YAML'),
        ('', 'must be a mapping'),
    ],
)
def test_unreadable_scenario_files_are_refused_naming_the_file(tmp_path, text, message):
    path = write(tmp_path, text)
    with pytest.raises(ScenarioError, match=message) as info:
        get_scenario(str(path))
    assert str(path) in str(info.value)


@pytest.mark.parametrize('ref,message', [('flock5d', 'unknown scenario'), ('nowhere.yaml', 'no such file')])
def test_unknown_names_and_missing_files_are_refused(ref, message):
    with pytest.raises(ScenarioError, match=message):
        get_scenario(ref)


# The paper's scenarios as they were written in code before they became files.
PAPER = {
    'flock2d': (('px', 'py', 'vx', 'vy'), 2, 'acceleration', 0.01, None, slice(2, 4), None),
    'boids3d': (('px', 'py', 'pz', 'hx', 'hy', 'hz'), 3, 'velocity', 1.0 / 60.0, 5.0, None, slice(3, 6)),
}


@pytest.mark.parametrize('name', sorted(PAPER))
def test_shipped_scenarios_equal_the_papers(name):
    layout, p, command, dt, box, velocity, heading = PAPER[name]
    spec = get_scenario(name)
    assert spec is SCENARIOS[name] and spec.shipped and scenario_ref(spec) == name
    assert (spec.state_layout, spec.position_dim, spec.command, spec.dt, spec.box) == (
        layout,
        p,
        command,
        dt,
        box,
    )
    assert (spec.velocity, spec.heading, spec.translation_invariant) == (velocity, heading, box is None)
    # The shipped file, copied elsewhere, is the same scenario and is referred to by name.
    assert parse_scenario_argument(name) == name
    assert get_scenario(spec.to_dict()) == spec


def test_a_copy_of_a_shipped_file_is_the_shipped_scenario(tmp_path):
    path = write(tmp_path, get_scenario('boids3d').to_dict())
    assert parse_scenario_argument(str(path)) == 'boids3d'


def test_trajectory_files_carry_a_custom_scenario_whole(tmp_path):
    spec = Scenario('ground', 2, 'position', 'velocity', 0.05, 8.0)
    path = tmp_path / 't.npz'
    states = np.zeros((1, 3, 4, 2))
    save_trajectories(path, states, 0.05, spec)
    data = load_trajectories(path)
    assert data.spec == spec and json.loads(data.scenario) == spec.to_dict()
    assert load_trajectories(path, scenario=spec.to_dict()).spec == spec
    with pytest.raises(TrajectoryError, match="field 'scenario'"):
        load_trajectories(path, scenario='flock2d')
    with pytest.raises(TrajectoryError, match='needs d = 4'):
        save_trajectories(path, states, 0.05, 'flock2d')


def test_old_trajectory_files_with_a_name_keep_working(tmp_path):
    path = tmp_path / 'old.npz'
    np.savez(
        path,
        states=np.zeros((1, 2, 3, 4)),
        dt=np.float64(0.01),
        scenario=np.str_('flock2d'),
        meta=np.str_('{}'),
    )
    assert load_trajectories(path).scenario == 'flock2d'


@pytest.mark.parametrize('stored', ['some/file.yaml', 'flock5d', '{"name": "x"}'])
def test_trajectory_files_refuse_other_scenario_fields(tmp_path, stored):
    path = tmp_path / 'bad.npz'
    np.savez(
        path, states=np.zeros((1, 2, 3, 2)), dt=np.float64(0.01), scenario=np.str_(stored), meta=np.str_('{}')
    )
    with pytest.raises(TrajectoryError, match="field 'scenario'"):
        load_trajectories(path)


def policy_meta(spec):
    spec = get_scenario(spec)
    return {
        'format': 'knode-policy/1',
        'scenario': spec.name if spec.shipped else spec.to_dict(),
        'state_dim': spec.state_dim,
        'command_dim': spec.command_dim,
        'command': spec.command,
        'k': 4,
        'd_cr': 2.0,
        'tau': 0,
        'dt': spec.dt,
        'state_layout': list(spec.state_layout),
    }


def test_policy_files_carry_a_custom_scenario_whole():
    spec = Scenario('drones', 3, 'position_velocity', 'acceleration', 0.02, 6.0)
    meta = policy_meta(spec)
    check_meta('p.pt', meta, expect={'scenario': scenario_ref(spec)})
    check_meta('p.pt', policy_meta('flock2d'), expect={'scenario': 'flock2d'})
    with pytest.raises(PolicyError, match="'scenario'"):
        check_meta('p.pt', meta, expect={'scenario': 'boids3d'})
    with pytest.raises(PolicyError, match="'state_layout'"):
        check_meta('p.pt', dict(meta, state_layout=['px', 'py', 'pz', 'hx', 'hy', 'hz']))


@pytest.mark.parametrize(
    'value,message',
    [
        ('flock5d', 'known: boids3d, flock2d'),
        ('my.yaml', 'known: boids3d, flock2d'),  # a policy carries its scenario, it names no file
        (dict(BASE, dimensions=5), "field 'dimensions'"),
        (3, 'must be a scenario name or object'),
    ],
)
def test_policy_files_refuse_bad_scenarios(value, message):
    meta = dict(policy_meta('flock2d'), scenario=value)
    with pytest.raises(PolicyError, match=message):
        check_meta('p.pt', meta)


def test_a_custom_policy_round_trips_through_export(tmp_path):
    torch = pytest.importorskip('torch')
    from knode_swarm_ros.core.policy import KNODEPolicy, PolicyConfig
    from knode_swarm_ros.core.policy_io import export_policy, load_policy

    spec = Scenario('ground', 2, 'position', 'velocity', 0.05, None)
    policy = KNODEPolicy(PolicyConfig(scenario_ref(spec), k=3, d_cr=2.0, tau=0))
    path = tmp_path / 'p.pt'
    export_policy(policy, path, policy.metadata())
    loaded = load_policy(path)
    assert get_scenario(loaded.scenario) == spec and loaded.meta['scenario'] == spec.to_dict()
    out = loaded(np.zeros((2, 3, 2)), np.ones((2, 3)))
    assert np.asarray(out).shape == (2, 2)
    del torch
