"""A fleet file through ROS (docs/ros.md, "Your own fleet"): named robots with odd ids, poses
only (PoseStamped on the fleet's topics), velocities estimated by the agents and the recorder;
a lockstep run equals ``training.rollout --observe pose`` bit for bit."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest
import rclpy  # noqa: F401  (a broken install must fail, not skip)
import yaml

from knode_swarm_ros.core import load_policy, load_trajectories
from knode_swarm_ros.core.policy_meta import shipped_policy_path
from knode_swarm_ros.core.rollout import PoseObserver, rollout
from knode_swarm_ros.core.scenarios import get_scenario

pytestmark = pytest.mark.ros

RUN_TIMEOUT = 240
NAMES = {'cf2': 2, 'cf3': 3, 'cf5': 5, 'cf8': 8, 'cf13': 13, 'cf21': 21}


@pytest.fixture(autouse=True)
def _own_domain(ros_domain_id):
    return ros_domain_id


def _fleet(tmp_path, window=6):
    path = tmp_path / 'fleet.yaml'
    path.write_text(
        yaml.safe_dump(
            {
                'robots': {name: {'id': rid} for name, rid in NAMES.items()},
                'state': {'topic': '/mocap/{name}/pose', 'type': 'pose', 'velocity_window': window},
                'command': {'topic': '/{name}/cmd_accel', 'type': 'accel_stamped'},
            }
        )
    )
    return path


def _run(tmp_path, *args):
    cmd = [
        sys.executable,
        '-m',
        'knode_swarm_ros.nodes.swarm',
        '--log-dir',
        str(tmp_path / 'logs'),
        '--no-figure',
        '--domain-id',
        os.environ['ROS_DOMAIN_ID'],
        *map(str, args),
    ]
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONUNBUFFERED='1')
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=RUN_TIMEOUT)
    return proc.returncode, proc.stdout + proc.stderr


def test_pose_only_lockstep_run_equals_the_offline_rollout_observing_poses(tmp_path):
    import torch

    record = tmp_path / 'fleet.npz'
    steps, window = 60, 6
    rc, out = _run(
        tmp_path, '--fleet', _fleet(tmp_path, window), '--steps', steps, '--seed', 3, '--record', record,
        '--agents-per-process', 3, '--policy-runtime', 'torchscript',
    )  # fmt: skip
    assert rc == 0, out
    data = load_trajectories(record)
    states = data.states[0]
    assert states.shape[:2] == (steps + 1, len(NAMES))
    assert data.meta['robot_ids'] == sorted(NAMES.values())
    assert data.meta['robot_names'] == sorted(NAMES, key=NAMES.get)
    spec = get_scenario('flock2d')
    # One intra-op thread, as every agent: a matrix product's rounding depends on the thread count.
    torch.set_num_threads(1)
    policy = load_policy(shipped_policy_path('flock2d'))
    # The recording's first frame holds an estimated velocity (0: one pose heard); the true start
    # is the simulator's seeded one, which the offline run starts from.
    from knode_swarm_ros.logic.simulator.swarm_sim import initial_state

    z0, _ = initial_state('flock2d', len(NAMES), 3)
    ref = rollout(
        policy, z0, steps, 'flock2d', policy.d_cr, policy.k, policy.tau, policy.dt,
        observe='pose', velocity_window=window,
    )  # fmt: skip
    p = spec.position
    assert np.array_equal(states[:, :, p], ref[:, :, p])  # positions bit for bit
    observer = PoseObserver(spec, window)  # the recorder's velocities: the agents' estimates
    heard = np.stack([observer.observe(int(round(t * policy.dt * 1e9)), ref[t]) for t in range(steps + 1)])
    assert np.array_equal(states, heard)
    assert float(np.abs(ref[-1] - ref[0]).max()) > 0  # the swarm moved


def test_lone_agents_of_a_realtime_motion_capture_file_one_pose_per_step(tmp_path):
    # Poses at 100 Hz under a 20 Hz policy, lone agents (neighbours' poses through the inbox):
    # each agent files one state per robot and step (the newest pose at or before it), not one per
    # pose, and the run ends cleanly with commands from every agent.
    fleet = tmp_path / 'fleet.yaml'
    fleet.write_text(
        yaml.safe_dump(
            {
                'robots': {'cf2': {'id': 2}, 'cf5': {'id': 5}, 'cf8': {'id': 8}},
                'state': {'topic': '/mocap/{name}/pose', 'type': 'pose', 'rate': 100},
            }
        )
    )
    steps = 40
    code, out = _run(
        tmp_path, '--fleet', fleet, '--mode', 'realtime', '--rate', 20, '--robots', 3, '--steps', steps,
        '--seed', 4, '--pose-noise', 0.002, '--agents-per-process', 1, '--quiet', '--record', tmp_path / 'r.npz',
    )  # fmt: skip
    assert code == 0, out
    for rid in (2, 5, 8):
        report = yaml.safe_load((tmp_path / 'logs' / f'agent_{rid}.json').read_text())
        assert report['counters']['commands'] > 0
        # 3 robots x 5 poses per step would be 600 filings; the start's re-sent state adds a few
        assert report['counters']['received'] < 2 * 3 * (steps + 1), report['counters']
