"""The chaos run's short version (bench/chaos.py runs 100 kills): a handful of processes of a
running swarm killed or stopped, each checked as the bench checks it.

After each kill: the launcher's report names the process and how it ended, every process of the
run has ended, the exit status is the documented one, no FastDDS shared-memory file of the run is
left, and the recording is complete and valid (an agent process's robots named in its meta
``silent``) or absent with the file that was there before intact. The kill waits for the run to
be running (a condition on the simulator's log), never for an amount of wall time.
"""

import random
import signal
import sys
from pathlib import Path

import pytest
import rclpy  # noqa: F401  (a broken install must fail, not skip)

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench.chaos import SENTINEL, Swarm, expected_status, run_round
from knode_swarm_ros.core import load_trajectories

pytestmark = pytest.mark.ros


def _swarm(kind, policy):
    if kind == 'hosted':  # lockstep, 2 processes of 3 robots; long enough to outlive the kill
        return Swarm(
            'hosted', ('--robots', 6, '--agents-per-process', 3, '--steps', 1500, '--policy', policy), 0
        )
    return Swarm('lone', ('--robots', 3, '--mode', 'realtime', '--steps', 3000, '--policy', policy), 0)


@pytest.mark.parametrize(
    'kind,target,sig',
    [
        ('hosted', 'agent', signal.SIGKILL),
        ('hosted', 'recorder', signal.SIGTERM),
        ('hosted', 'launcher', signal.SIGINT),
        ('lone', 'simulator', signal.SIGTERM),
        ('lone', 'launcher', signal.SIGKILL),
    ],
)
def test_a_killed_process_is_handled_as_documented(
    kind, target, sig, tmp_path, untrained_policies, ros_domain_id
):
    swarm = _swarm(kind, untrained_policies['flock2d'])
    r = run_round(swarm, target, sig, 0.0, random.Random(0), tmp_path, ros_domain_id, when_running=True)
    assert r.phase == 'running', r  # the target was signalled while the run ran
    assert r.problems == [], (r, (tmp_path / 'launcher.out').read_text(errors='replace'))
    assert r.rc in expected_status(r)
    record = tmp_path / 'run.npz'
    if target == 'agent':
        assert r.rc == 3 and r.recording == 'valid'
        assert load_trajectories(record).meta['incomplete_frames'] == 0
    elif target == 'recorder':  # it saved what it had, and the run stopped: not a finished run
        assert r.rc == 1 and load_trajectories(record).meta['interrupted'] is True
    elif r.recording == 'absent':
        assert record.read_bytes() == SENTINEL


def test_a_killed_launcher_s_sweeper_removes_what_a_child_killed_with_it_left(
    tmp_path, untrained_policies, ros_domain_id
):
    # The simulator killed right after the launcher (its stop cut short, as under load) always
    # leaves its segment and ports; only the launcher's sweeper, which outlives it, can remove them.
    swarm = _swarm('lone', untrained_policies['flock2d'])
    r = run_round(
        swarm,
        'launcher',
        signal.SIGKILL,
        0.0,
        random.Random(0),
        tmp_path,
        ros_domain_id,
        when_running=True,
        also='simulator',
    )
    assert r.phase == 'running' and r.rc == -signal.SIGKILL, r
    # No leftover of the run, and the sweeper has ended (run_round waits for it). Whether its line
    # ("removed N FastDDS ...") is there is not checked: a concurrent suite's living launcher
    # sweeps every new unlocked file too, ours among them.
    assert r.problems == [], (r, (tmp_path / 'launcher.out').read_text(errors='replace'))
