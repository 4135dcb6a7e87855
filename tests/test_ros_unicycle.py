"""``swarm --robot-model unicycle``: differential-drive robots end to end.

* the plan sets the simulator's ``robot_model`` and every agent's ``command_interface`` with the
  same limits, and refuses what cannot run (boids3d, ground truth, hosted agents; exit 2);
* a short lockstep run of 3 unicycles: the recording is finite, moves, keeps the base's limits,
  and equals the ROS-free study loop (training.studies.unicycle_study.unicycle_rollout) from the
  simulator's seeded start, so the offline experiment is what the ROS swarm does.
"""

import subprocess
import sys

import numpy as np
import pytest
import rclpy  # noqa: F401  (a broken install must fail, not skip)
from test_ros_swarm import _assert_no_strays, _cmd, _env, _run

from knode_swarm_ros.core import load_policy, load_trajectories
from knode_swarm_ros.core.unicycle import UnicycleLimits
from knode_swarm_ros.logic.simulator.swarm_sim import initial_state
from knode_swarm_ros.nodes import swarm

LIMITS = dict(max_linear_speed=0.6, max_angular_speed=1.8, max_linear_accel=2.0, max_angular_accel=8.0)


@pytest.fixture(autouse=True)
def _own_domain(ros_domain_id):
    """Every run gets a domain claimed for this test (conftest), passed as --domain-id."""
    return ros_domain_id


FLAGS = [
    '--robot-model',
    'unicycle',
    '--max-linear-speed',
    '0.6',
    '--max-angular-speed',
    '1.8',
    '--max-linear-accel',
    '2',
    '--max-angular-accel',
    '8',
]


def test_plan_sets_both_sides_and_refuses_what_cannot_run(tmp_path, untrained_policies):
    args = swarm.build_parser().parse_args(
        [
            '--policy',
            str(untrained_policies['flock2d']),
            '--robots',
            '3',
            '--record',
            str(tmp_path / 'r.npz'),
            '--domain-id',
            '40',
            '--log-dir',
            str(tmp_path / 'logs'),
            *FLAGS,
        ]
    )
    plan = swarm.plan_run(args)
    _, files = swarm.build_commands(plan)
    sim, agent = files[plan.run_dir / 'simulator.yaml'], files[plan.run_dir / 'agent.yaml']
    assert sim['robot_model'] == 'unicycle' and agent['command_interface'] == 'unicycle'
    assert (
        agent['unicycle_stamped']
        and agent['unicycle_state'] == 'point'
        and agent['unicycle_lookahead'] == 0.2
    )
    for name, value in LIMITS.items():
        assert sim[name] == agent[name] == value
    plain = swarm.build_commands(
        swarm.plan_run(
            swarm.build_parser().parse_args(
                [
                    '--policy',
                    str(untrained_policies['flock2d']),
                    '--robots',
                    '3',
                    '--record',
                    str(tmp_path / 'r.npz'),
                    '--domain-id',
                    '40',
                    '--log-dir',
                    str(tmp_path / 'logs'),
                ]
            )
        )
    )[1]
    assert not any('unicycle' in str(v) for params in plain.values() for v in params.values())
    for extra, words in (
        (['--agents-per-process', '2'], 'one agent process per robot'),
        (['--policy', str(untrained_policies['boids3d'])], 'flock2d'),
        (['--max-angular-speed', '-1'], '--max-angular-speed'),
    ):
        proc = subprocess.run(
            _cmd(
                tmp_path,
                '--policy',
                untrained_policies['flock2d'],
                '--robots',
                3,
                '--record',
                tmp_path / 'x.npz',
                *FLAGS,
                *extra,
            ),
            env=_env(),
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert proc.returncode == 2 and words in proc.stderr, proc.stderr
    assert not (tmp_path / 'x.npz').exists()


@pytest.mark.ros
def test_lockstep_unicycles_move_within_their_limits_and_equal_the_offline_study(
    tmp_path, untrained_policies
):
    from training.studies.unicycle_study import unicycle_rollout

    record, steps = tmp_path / 'uni.npz', 40
    rc, out = _run(
        tmp_path,
        '--policy',
        untrained_policies['flock2d'],
        '--robots',
        3,
        '--steps',
        steps,
        '--seed',
        4,
        '--record',
        record,
        *FLAGS,
    )
    assert rc == 0, out
    states = load_trajectories(record).states[0]  # [steps + 1, 3, 4]: axle, world velocity
    assert states.shape == (steps + 1, 3, 4) and np.all(np.isfinite(states))
    speed = np.linalg.norm(states[..., 2:], axis=-1)
    assert speed.max() <= 0.6 + 1e-12  # the base's top speed
    assert np.abs(np.diff(speed, axis=0)).max() <= 2.0 * 0.01 + 1e-9  # and its acceleration (dt 0.01)
    moved = np.linalg.norm(states[-1, :, :2] - states[0, :, :2], axis=-1)
    assert np.all(moved > 0.01)
    step = np.linalg.norm(
        np.diff(states[..., :2], axis=0), axis=-1
    )  # a base moves along its heading at its speed
    assert np.allclose(step, speed[1:] * 0.01, rtol=1e-3, atol=1e-9)
    policy = load_policy(untrained_policies['flock2d'])
    z0, _ = initial_state('flock2d', 3, 4)
    ref, _ = unicycle_rollout(
        policy,
        z0[None],
        steps,
        UnicycleLimits(0.2, **LIMITS),
        policy.d_cr,
        policy.k,
        policy.dt,
        'point',
        policy.command_limit,
    )
    assert np.abs(ref[0] - states).max() < 1e-9
    _assert_no_strays(tmp_path)


if __name__ == '__main__':
    sys.exit(pytest.main([__file__, '-q']))
