"""Whole swarms through the real processes: the ``swarm`` launcher, simulator, agents, recorder.

* lockstep parity: flock2d (10 robots, 300 steps, tau 0) equals core.rollout from the recorded
  initial state bit for bit, boids3d (tau 1) to 1e-14 (headings travel as quaternions);
* an agent killed mid-run: the others go on, the simulator holds the robot, the launcher
  reports it (exit status 3) and leaves neither processes nor shared-memory files behind;
* realtime mode records, and Ctrl-C on the launcher stops everything with the file saved;
* ground-truth mode records exactly what the ground truth computes.

Each run has its own ROS domain (the launcher draws one) and localhost-only discovery.
Waiting is always for a condition (a line of output, a file) with a deadline.
"""

import json
import os
import re
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
import rclpy  # noqa: F401  (a broken install must fail, not skip)

from knode_swarm_ros.core import load_policy, load_trajectories, save_trajectories
from knode_swarm_ros.core.rollout import rollout

pytestmark = pytest.mark.ros

RUN_TIMEOUT = 240


def _env():
    env = dict(os.environ)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env['PYTHONUNBUFFERED'] = '1'
    return env


@pytest.fixture(autouse=True)
def _own_domain(ros_domain_id):
    """Every run gets a domain claimed for this test (conftest), passed as --domain-id."""
    return ros_domain_id


def _cmd(tmp_path, *args):
    return [
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


def _run(tmp_path, *args):
    proc = subprocess.run(
        _cmd(tmp_path, *args), env=_env(), capture_output=True, text=True, timeout=RUN_TIMEOUT
    )
    return proc.returncode, proc.stdout + proc.stderr


_STEP_LINE = re.compile(r'\bstep (\d+)(?:/\d+)? \(t = .* steps/s')


class Launcher:
    """The launcher as a background process whose output lines are collected as they come."""

    def __init__(self, tmp_path, *args):
        self.lines = []
        self.proc = subprocess.Popen(
            _cmd(tmp_path, *args),
            env=_env(),
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            start_new_session=True,
        )
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()

    def _read(self):
        for line in self.proc.stdout:
            self.lines.append(line.rstrip('\n'))

    @property
    def output(self):
        return '\n'.join(self.lines)

    def wait_for(self, text, timeout=RUN_TIMEOUT):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if any(text in line for line in self.lines):
                return True
            if self.proc.poll() is not None:
                self.reader.join(timeout=5)
                return any(text in line for line in self.lines)
            time.sleep(0.05)  # polling the collected output for a condition
        return False

    def wait_for_step(self, step, timeout=RUN_TIMEOUT):
        """Wait for a simulator progress line ``step N...`` with N >= ``step``."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and self.proc.poll() is None:
            if any(int(m.group(1)) >= step for m in map(_STEP_LINE.search, list(self.lines)) if m):
                return True
            time.sleep(0.05)  # polling the collected output for a condition
        return False

    def finish(self, timeout=RUN_TIMEOUT):
        try:
            rc = self.proc.wait(timeout=timeout)
        finally:
            if self.proc.poll() is None:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait()
        self.reader.join(timeout=10)
        return rc


def _pids(tmp_path):
    return json.loads((tmp_path / 'logs' / 'pids.json').read_text())


def _assert_no_strays(tmp_path):
    alive = []
    sweeper = int((tmp_path / 'logs' / 'sweeper.pid').read_text())  # ends with the launcher
    for name, pid in {**_pids(tmp_path), 'sweeper': sweeper}.items():
        try:
            os.kill(pid, 0)
            alive.append(f'{name} ({pid})')
        except ProcessLookupError:
            pass
    assert not alive, f'processes left running: {alive}'


def _parity(record, policy_path, steps):
    data = load_trajectories(record)
    states = data.states[0]
    assert states.shape[0] == steps + 1
    assert data.meta['incomplete_frames'] == 0 and data.meta['filled_entries'] == 0
    import torch

    # One intra-op thread, as every agent (torch_threads: 1): a matrix product's rounding depends on
    # the thread count, so the comparison must not depend on what earlier tests left set.
    torch.set_num_threads(1)
    policy = load_policy(policy_path)
    ref = rollout(policy, states[0], steps, data.scenario, policy.d_cr, policy.k, policy.tau, policy.dt)
    return float(np.abs(ref - states).max())


def test_lockstep_flock2d_ten_robots_equals_the_offline_rollout(tmp_path, untrained_policies):
    record = tmp_path / 'flock.npz'
    rc, out = _run(
        tmp_path,
        '--policy',
        untrained_policies['flock2d'],
        '--robots',
        10,
        '--steps',
        300,
        '--seed',
        3,
        '--record',
        record,
    )
    assert rc == 0, out
    diff = _parity(record, untrained_policies['flock2d'], 300)
    assert diff == 0.0, f'max state difference {diff}'  # bit for bit
    assert 'avd (velocity difference)' in out and 'every process has stopped' in out
    report = json.loads((tmp_path / 'logs' / 'simulator.json').read_text())
    # What lockstep guarantees: every robot answered each of the 300 steps (a rejoin counts
    # apart); the commands for the final state may race the simulator's exit.
    counters = report['counters']
    assert (
        report['steps_run'] == 300
        and report['lost'] == []
        and counters['accepted'] + counters['rejoined'] >= 3000
    )
    _assert_no_strays(tmp_path)


def test_lockstep_boids3d_with_delay_equals_the_offline_rollout(tmp_path, untrained_policies):
    from knode_swarm_ros.logic.simulator.swarm_sim import initial_state

    z0, _ = initial_state('boids3d', 10, seed=4)
    init = tmp_path / 'init.npz'
    save_trajectories(init, np.stack([z0 + 1.0, z0])[:, None], 1 / 60, 'boids3d')
    assert load_policy(untrained_policies['boids3d']).tau == 1
    record = tmp_path / 'boids.npz'
    rc, out = _run(
        tmp_path,
        '--policy',
        untrained_policies['boids3d'],
        '--init',
        f'{init}:1',
        '--steps',
        300,
        '--record',
        record,
    )
    assert rc == 0, out
    assert np.allclose(
        load_trajectories(record).states[0, 0], z0, rtol=0, atol=1e-15
    )  # heading via quaternion
    diff = _parity(record, untrained_policies['boids3d'], 300)
    # Headings reach the recorder as quaternions: a few ulps (measured 5.6e-16), nothing more.
    assert diff <= 1e-14, f'max state difference {diff}'
    _assert_no_strays(tmp_path)


def test_a_killed_agent_is_reported_and_the_others_go_on(tmp_path, untrained_policies):
    from knode_swarm_ros.nodes import swarm

    shm_before = swarm.shm_snapshot()
    record = tmp_path / 'kill.npz'
    steps = 600
    # The simulator holds a robot after --lockstep-timeout wall seconds without its command. A
    # live agent slowed down past it by a loaded machine is held too, but rejoins with its next
    # command, so only robot 2 is lost at the end whatever the load; 3 s (not 1 s) keeps such
    # false alarms rare without making the run long.
    run = Launcher(
        tmp_path,
        '--policy',
        untrained_policies['flock2d'],
        '--robots',
        5,
        '--steps',
        steps,
        '--seed',
        1,
        '--lockstep-timeout',
        3.0,
        '--record',
        record,
    )
    assert run.wait_for('ready after'), run.output
    victim = _pids(tmp_path)['agent_2']
    os.kill(victim, signal.SIGKILL)
    rc = run.finish()
    out = run.output
    assert rc == 3, out
    assert f'agent_2 (pid {victim}) killed by SIGKILL' in out
    assert 'the other agents go on' in out and 'agent process(es) died during the run' in out
    sim_log = (tmp_path / 'logs' / 'simulator.log').read_text()
    assert 'robot(s) [2]: no command for step' in sim_log and 'stopping them (brake' in sim_log
    report = json.loads((tmp_path / 'logs' / 'simulator.json').read_text())
    assert report['lost'] == [2] and report['steps_run'] == steps
    # The other agents answered to the end and stopped cleanly (their reports are written at exit).
    for i in (0, 1, 3, 4):
        agent = json.loads((tmp_path / 'logs' / f'agent_{i}.json').read_text())
        assert agent['answered'] == steps and agent['counters']['commands'] >= steps
    assert not (tmp_path / 'logs' / 'agent_2.json').exists()
    # The recording is complete, and robot 2 was braked to rest (docs/DESIGN.md: a lost acceleration-
    # commanded robot does not coast, nor keep its last acceleration): at rest, in place, at the end.
    data = load_trajectories(record)
    states = data.states[0]
    assert states.shape[0] == steps + 1 and data.meta['incomplete_frames'] == 0
    np.testing.assert_allclose(states[-50:, 2, 2:], 0.0, atol=1e-9)
    np.testing.assert_allclose(states[-50:, 2, :2], np.broadcast_to(states[-1, 2, :2], (50, 2)), atol=1e-9)
    _assert_no_strays(tmp_path)
    # No shared-memory file of this run is left: no unlocked lock file, no port of its domain.
    domain = int(re.search(r'ROS_DOMAIN_ID=(\d+)', out).group(1))
    ours = range(7400 + 250 * domain, 7400 + 250 * (domain + 1))
    left = []
    for name in swarm.shm_snapshot() - shm_before:
        port = re.match(r'(?:sem\.)?fastrtps_port(\d+)', name)
        if port and int(port.group(1)) in ours:
            left.append(name)
        elif name.endswith(('_el', '_sl')) and not swarm.lock_held(swarm.SHM_DIR / name):
            left.append(name)
    assert not left, f'stale shared-memory files left: {left}'


def test_realtime_records_and_ctrl_c_stops_everything_with_the_file_saved(tmp_path, untrained_policies):
    record = tmp_path / 'rt.npz'
    run = Launcher(
        tmp_path,
        '--policy',
        untrained_policies['flock2d'],
        '--robots',
        4,
        '--mode',
        'realtime',
        '--steps',
        0,
        '--rate',
        20,
        '--record',
        record,
    )
    # Ctrl-C once the simulator reports step 250 (50 published frames at 5 steps a frame), a
    # condition on the run's own progress rather than on how much wall time has passed.
    assert run.wait_for_step(250), run.output
    os.killpg(run.proc.pid, signal.SIGINT)  # Ctrl-C in the launcher's terminal
    rc = run.finish()
    out = run.output
    assert rc == 130, out
    assert 'SIGINT: stopping every process' in out and 'every process has stopped' in out
    data = load_trajectories(record)
    assert data.meta['interrupted'] is True and data.dt == pytest.approx(0.05)
    states = data.states[0]
    assert states.shape[0] >= 40
    # Frames are 5 simulation steps apart and the robots were driven by the agents.
    report = json.loads((tmp_path / 'logs' / 'simulator.json').read_text())
    assert report['mode'] == 'realtime' and report['publish_every'] == 5
    assert report['counters']['accepted'] >= 4 * 30 and report['latency_ms']['count'] >= 4 * 30
    _assert_no_strays(tmp_path)


def test_ground_truth_mode_records_the_ground_truth(tmp_path):
    from knode_swarm_ros.core.groundtruth import simulate

    record = tmp_path / 'gt.npz'
    bag = tmp_path / 'gt.mcap'
    rc, out = _run(
        tmp_path,
        '--ground-truth',
        '--scenario',
        'flock2d',
        '--robots',
        6,
        '--steps',
        200,
        '--seed',
        5,
        '--record',
        record,
        '--bag',
        bag,
    )
    assert rc == 0, out
    assert 'no agents' in out
    got = load_trajectories(record)
    ref = simulate('flock2d', 1, 6, 201, seed=5, progress=False)
    assert got.states.shape == ref.shape and np.array_equal(got.states, ref)
    assert got.meta['source']['ground_truth'] is True
    # Observe, learn, deploy: the run's bag imports back into the same trajectory (without the
    # default smoother, positions are stored exactly; velocities come from central differences).
    from training.import_bag import ImportOptions, import_bag

    options = ImportOptions(scenario='flock2d', rate=100.0, topics=['/robot_*/odom'], smooth='none')
    imported = import_bag(bag, options).states
    assert imported.shape == (1, 201, 6, 4)
    np.testing.assert_allclose(imported[0, :, :, :2], ref[0, :, :, :2], atol=1e-9)
    central = (ref[0, 2:, :, :2] - ref[0, :-2, :, :2]) / 0.02
    np.testing.assert_allclose(imported[0, 1:-1, :, 2:], central, atol=1e-6)
    # ... which is the true velocity up to the central-difference error jerk dt^2 / 6 (< 1e-2 here).
    np.testing.assert_allclose(imported[0, 1:-1, :, 2:], ref[0, 1:-1, :, 2:], atol=1e-2)
    _assert_no_strays(tmp_path)
