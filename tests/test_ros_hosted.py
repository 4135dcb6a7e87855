"""Hosted agents through the real processes: ``swarm --agents-per-process K``.

* lockstep with 11 robots over 3 ``agents`` processes (4 + 4 + 3) equals core.rollout from the
  recorded initial state bit for bit, with one batched policy call per step and process;
* a hosting process killed mid-run is reported by the launcher with the ids of the robots it
  held (exit status 3); the simulator holds those robots and the other processes go on to the end.
"""

import json
import os
import signal

import pytest
import rclpy  # noqa: F401  (a broken install must fail, not skip)
from test_ros_swarm import Launcher, _assert_no_strays, _parity, _pids, _run

from knode_swarm_ros.core import load_trajectories

pytestmark = pytest.mark.ros


def test_lockstep_over_three_hosting_processes_equals_the_offline_rollout(
    tmp_path, untrained_policies, ros_domain_id
):
    record = tmp_path / 'hosted.npz'
    steps = 200
    # A loaded machine may leave a hosting process behind its queue for longer than the default
    # 0.5 s state_timeout; parity is what is tested here, so the agents and the simulator wait.
    rc, out = _run(
        tmp_path,
        '--policy',
        untrained_policies['flock2d'],
        '--robots',
        11,
        '--agents-per-process',
        4,
        '--steps',
        steps,
        '--seed',
        5,
        '--state-timeout',
        120,
        '--lockstep-timeout',
        120,
        '--record',
        record,
    )
    assert rc == 0, out
    assert '3 agent processes for 11 robots' in out
    assert load_trajectories(record).states[0].shape == (steps + 1, 11, 4)
    assert _parity(record, untrained_policies['flock2d'], steps) == 0  # bit for bit
    for name, hosted in (('agents_0_3', 4), ('agents_4_7', 4), ('agents_8_10', 3)):
        report = json.loads((tmp_path / 'logs' / f'{name}.json').read_text())
        assert len(report['robots']) == hosted
        assert all(r['answered'] == steps for r in report['robots'].values())
        # one batched call per step (the initial state, published until all are ready, may add some)
        assert report['evaluated'] == hosted * report['policy_calls']
    _assert_no_strays(tmp_path)


def test_a_killed_hosting_process_is_reported_with_its_robots_and_the_others_go_on(
    tmp_path, untrained_policies, ros_domain_id
):
    record = tmp_path / 'kill.npz'
    steps = 400
    run = Launcher(
        tmp_path,
        '--policy',
        untrained_policies['flock2d'],
        '--robots',
        9,
        '--agents-per-process',
        3,
        '--steps',
        steps,
        '--seed',
        1,
        '--lockstep-timeout',
        1.0,
        '--record',
        record,
    )
    assert run.wait_for('ready after'), run.output
    victim = _pids(tmp_path)['agents_3_5']
    os.kill(victim, signal.SIGKILL)
    rc = run.finish()
    out = run.output
    assert rc == 3, out
    assert f'agents_3_5 (pid {victim}) killed by SIGKILL' in out
    assert 'the simulator holds robots 3, 4, 5 at their last command' in out
    assert f'agents_3_5 (pid {victim}) killed by SIGKILL, hosting robots [3, 4, 5]' in out
    report = json.loads((tmp_path / 'logs' / 'simulator.json').read_text())
    assert report['lost'] == [3, 4, 5] and report['steps_run'] == steps
    for name in ('agents_0_2', 'agents_6_8'):
        hosted = json.loads((tmp_path / 'logs' / f'{name}.json').read_text())
        assert all(r['answered'] == steps for r in hosted['robots'].values())
    assert not (tmp_path / 'logs' / 'agents_3_5.json').exists()
    data = load_trajectories(record)
    assert data.states.shape[1] == steps + 1 and data.meta['incomplete_frames'] == 0
    _assert_no_strays(tmp_path)


def _agents(tmp_path, *params):
    import subprocess
    import sys

    cmd = [sys.executable, '-m', 'knode_swarm_ros.nodes.agents', '--ros-args']
    for p in params:
        cmd += ['-p', p]
    return subprocess.Popen(
        cmd, env=dict(os.environ), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )


@pytest.mark.parametrize(
    'ids, words',
    [
        ('ids:=5..2', "'ids' = '5..2': the range ends before it starts"),
        ('ids:=[1,30]', "robot(s) [30] are not among the swarm's robot ids 0..9"),
        ('robots:=10', "parameter 'ids' is required"),
    ],
)
def test_the_agents_executable_refuses_bad_ids(tmp_path, ros_domain_id, ids, words):
    proc = _agents(tmp_path, ids, 'robots:=10')
    out = proc.communicate(timeout=120)[0]
    assert proc.returncode == 2 and words in out, out


@pytest.mark.parametrize(
    'params, words',
    [
        (
            ['mode:=realtime', 'link_loss:=0.1'],
            "parameters 'link_*' (the link model) are not offered by the agents node",
        ),
        (['managed:=true'], "parameter 'managed' = true: the agents node is not a lifecycle node"),
        (
            ['mode:=realtime', 'command_interface:=unicycle'],
            "'command_interface' = 'unicycle' is not offered",
        ),
        (['state_timout:=3'], "unknown parameter 'state_timout': did you mean 'state_timeout'?"),
        (
            ['policy_runtime:=tensorflow'],
            "parameter 'policy_runtime' = 'tensorflow' is not one of auto, torchscript",
        ),
    ],
)
def test_the_agents_executable_refuses_the_options_it_does_not_offer(
    tmp_path, ros_domain_id, untrained_policies, params, words
):
    # the lone agent's parameters, declared by the same code; the per-robot options a hosting
    # process cannot give each robot are refused by name (exit status 2)
    proc = _agents(tmp_path, 'ids:=0..2', 'robots:=4', f'policy:={untrained_policies["flock2d"]}', *params)
    out = proc.communicate(timeout=120)[0]
    assert proc.returncode == 2 and words in out, out


def test_the_agents_executable_stops_on_sigint(tmp_path, ros_domain_id, untrained_policies):
    # (its report at exit is checked by the launcher tests above, which stop it with SIGINT)
    import time

    proc = _agents(
        tmp_path,
        'ids:=[2, 5]',
        'robots:=6',
        f'policy:={untrained_policies["flock2d"]}',
        'mode:=lockstep',
        'policy_runtime:=torchscript',
        'twist_frame:=world',
    )
    lines = []
    deadline = time.monotonic() + 120
    for line in proc.stdout:  # until the node is up (its last line at construction)
        lines.append(line)
        if 'robots [2, 5] (2 hosted) of 6' in line or time.monotonic() > deadline:
            break
    assert any('robots [2, 5] (2 hosted) of 6' in line for line in lines), ''.join(lines)
    assert '[agents_2_5]' in lines[-1] and 'on torchscript' in lines[-1]
    proc.send_signal(signal.SIGINT)
    rest = proc.communicate(timeout=30)[0]
    assert proc.returncode == 0, ''.join(lines) + rest
