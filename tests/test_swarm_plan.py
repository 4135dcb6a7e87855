"""The launcher's plan -> commands step, without starting a process (pure logic)."""

import dataclasses
import sys
from pathlib import Path

import numpy as np
import pytest

from knode_swarm_ros.nodes import swarm
from knode_swarm_ros.nodes.swarm import Plan, build_commands


def _plan(tmp_path, **kw):
    base = dict(
        scenario='flock2d',
        robots=3,
        steps=50,
        mode='lockstep',
        dt=0.01,
        d_cr=1.0,
        policy='/p/policy.pt',
        record=tmp_path / 'r.npz',
        figure=None,
        run_dir=tmp_path / 'logs',
        temporary_dir=False,
        domain_id=42,
    )
    base.update(kw)
    return Plan(**base)


def test_build_commands_is_pure_and_names_its_parameter_files(tmp_path):
    plan = _plan(tmp_path)
    commands, files = build_commands(plan)
    assert not (tmp_path / 'logs').exists()  # nothing written
    assert list(commands) == ['simulator', 'recorder', 'agent_0', 'agent_1', 'agent_2']
    assert set(files) == {tmp_path / 'logs' / n for n in ('simulator.yaml', 'recorder.yaml', 'agent.yaml')}
    for name, cmd in commands.items():
        assert cmd[:2] == [sys.executable, '-m'] and '--ros-args' in cmd
        assert Path(cmd[cmd.index('--params-file') + 1]) in files  # every named file is one returned
    assert 'id:=1' in commands['agent_1']
    sim = files[tmp_path / 'logs' / 'simulator.yaml']
    assert sim['robots'] == 3 and sim['steps'] == 50 and sim['wait_for_agents'] and sim['init'] == ''
    assert sim['command_timeout'] == pytest.approx(max(0.5, 3.0 / plan.rate))
    agent = files[tmp_path / 'logs' / 'agent.yaml']
    assert agent['policy'] == '/p/policy.pt' and agent['parity_batch'] and not agent['managed']
    assert not any(k.startswith('link_') for k in agent)
    assert build_commands(plan) == (commands, files)  # deterministic


def test_build_commands_follows_the_plan(tmp_path):
    gt = build_commands(_plan(tmp_path, ground_truth=True, policy=None, variant='paper'))
    assert list(gt[0]) == ['simulator', 'recorder'] and len(gt[1]) == 2
    sim = gt[1][tmp_path / 'logs' / 'simulator.yaml']
    assert sim['ground_truth'] and not sim['wait_for_agents'] and sim['variant'] == 'paper'
    hosted, _ = build_commands(_plan(tmp_path, robots=5, agents_per_process=2))
    assert [n for n in hosted if n.startswith('agent')] == ['agents_0_1', 'agents_2_3', 'agents_4_4']
    assert 'ids:=2..3' in hosted['agents_2_3'] and hosted['agents_2_3'][2] == 'knode_swarm_ros.nodes.agents'
    managed, files = build_commands(_plan(tmp_path, managed=True, startup_timeout=7.0))
    assert managed['lifecycle_manager'][-3:] == ['robots:=3', '-p', 'timeout:=7.0']
    assert files[tmp_path / 'logs' / 'agent.yaml']['managed']
    _, files = build_commands(
        _plan(
            tmp_path,
            mode='realtime',
            rate=50.0,
            link={'link_loss': 0.1},
            bag='/b.mcap',
            parity_batch=False,
            policy_meta={'command_limit': 2.5},
        )
    )
    agent = files[tmp_path / 'logs' / 'agent.yaml']
    assert agent['link_loss'] == 0.1 and agent['control_rate'] == 50.0 and not agent['parity_batch']
    assert files[tmp_path / 'logs' / 'recorder.yaml']['bag'] == '/b.mcap'
    assert files[tmp_path / 'logs' / 'simulator.yaml']['stop_limit'] == 2.5


def test_the_plan_is_frozen_and_planning_leaves_the_arguments_alone(tmp_path, monkeypatch):
    from knode_swarm_ros.core import save_trajectories

    save_trajectories(tmp_path / 'init.npz', np.zeros((1, 1, 3, 4)) + np.arange(3)[:, None], 0.01, 'flock2d')
    monkeypatch.chdir(tmp_path)
    argv = [
        '--ground-truth',
        '--init',
        'init.npz',
        '--record',
        'out.npz',
        '--log-dir',
        'logs',
        '--domain-id',
        '40',
    ]
    args = swarm.build_parser().parse_args(argv)
    before = vars(args).copy()
    plan = swarm.plan_run(args)
    assert vars(args) == before
    assert plan.init == f'{tmp_path / "init.npz"}:0' and plan.robots == 3 and plan.domain_id == 40
    with pytest.raises(dataclasses.FrozenInstanceError):
        plan.robots = 4
