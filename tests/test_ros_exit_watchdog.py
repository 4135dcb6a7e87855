"""A node whose native clean-up hangs after everything is saved still exits, with status 0, and
its file is whole (nodes/common/exit_watchdog.py, armed once in executor.run_node).

The flake it answers: in a suite run beside a second one, the recorder wrote its file and then
hung while exiting (rclpy / DDS teardown), ignored SIGTERM and was SIGKILLed; the launcher failed
the run. Here the recorder runs the real ``run_node`` in a child process whose clean-up step is
replaced by a ``pause()`` (or, where the test signals it, a loop of short ``usleep()`` calls)
through ``ctypes.PyDLL``: native code that keeps the GIL, as rclpy's calls do, so neither a
Python signal handler nor a Python thread can end it while it waits. The tests wait only
for polled conditions (log lines, exit) with generous deadlines; no timing is asserted.
"""

import signal

import numpy as np
import pytest
import rclpy  # noqa: F401  (a broken install must fail, not skip)
from node_processes import start, stop, wait_for

from knode_swarm_ros.core import load_trajectories
from knode_swarm_ros.nodes.swarm.shm import shm_cleanup, shm_snapshot

pytestmark = pytest.mark.ros

ROBOTS = 3
STEPS = 30
SEED = 5

_HUNG_RECORDER = """
import ctypes, sys
from knode_swarm_ros.nodes.common import executor, exit_watchdog
from knode_swarm_ros.nodes.recorder import node as recorder
libc = ctypes.PyDLL(None)  # its calls block in C with the GIL held
def hung_clean_up(*args, **kwargs):
    print('clean-up hangs', flush=True)
    while True:  # a signal interrupts the call; its Python handler runs between two calls
        {hang}
executor.{step} = hung_clean_up
exit_watchdog.TEARDOWN_S = {deadline}
sys.argv = ['recorder', '--ros-args', *sys.argv[1:]]
recorder.main()
"""


# pause() waits for a signal forever; a signal that lands between the print and the call is
# taken by the handler only after the call returns, so a test that signals the hang waits in
# bounded calls instead (usleep: also in C with the GIL held)
PAUSE, SHORT_WAITS = 'libc.pause()', 'libc.usleep(100000)'


def _recorder(tmp_path, step, deadline, *params, hang=PAUSE):
    log_path = tmp_path / 'recorder.log'
    with open(log_path, 'wb') as log:
        proc = start(
            [
                '-c',
                _HUNG_RECORDER.format(step=step, deadline=deadline, hang=hang),
                '-p',
                f'robots:={ROBOTS}',
                '-p',
                f'output:={tmp_path / "rec.npz"}',
                '-p',
                'use_sim_time:=true',
                *params,
            ],
            log,
        )
    return proc, log_path


def _simulator(tmp_path, *params):
    with open(tmp_path / 'simulator.log', 'wb') as log:
        return start(
            [
                '-m',
                'knode_swarm_ros.nodes.simulator',
                '--ros-args',
                '-p',
                f'robots:={ROBOTS}',
                '-p',
                'wait_for_agents:=false',
                *params,
            ],
            log,
        )


def test_a_hung_clean_up_after_the_save_ends_with_status_0_and_the_whole_file(tmp_path, ros_domain_id):
    """The flake's course: the simulator says done, the recorder saves, then its context
    shutdown never returns. Nothing signals it: the watchdog alone ends it."""
    from knode_swarm_ros.core.groundtruth import simulate

    before = shm_snapshot()
    # the deadline must outlast the real teardown before the hung step: under two suites' load
    # destroy_node alone once took longer than 1 s, and the watchdog ended the process first
    rec, rec_log = _recorder(tmp_path, '_end_context', 5.0)
    sim = _simulator(
        tmp_path,
        '-p',
        f'steps:={STEPS}',
        '-p',
        'mode:=lockstep',
        '-p',
        'ground_truth:=true',
        '-p',
        'wait_for_recorder:=true',
        '-p',
        f'seed:={SEED}',
    )
    try:
        rc = stop(rec)
        text = rec_log.read_text(errors='replace')
        assert 'clean-up hangs' in text, text  # the hang was reached: the exit is the watchdog's
        assert rc == 0 and 'Traceback' not in text, f'rc {rc}\n{text}'
        assert 'hung_clean_up' in text, text  # faulthandler's dump names where it hung
        assert stop(sim) == 0, (tmp_path / 'simulator.log').read_text(errors='replace')
    finally:
        for proc in (rec, sim):
            if proc.poll() is None:
                stop(proc, signal.SIGKILL)
        shm_cleanup(before)  # the recorder's participant was never destroyed
    got = load_trajectories(tmp_path / 'rec.npz')
    assert got.meta['interrupted'] is False
    assert np.array_equal(got.states, simulate('flock2d', 1, ROBOTS, STEPS + 1, seed=SEED, progress=False))


def test_a_second_signal_during_a_hung_clean_up_ends_it_after_the_save(tmp_path, ros_domain_id):
    """SIGTERM while recording: the recorder saves what it has before anything is torn down
    (the executor's teardown is what hangs here); a second SIGTERM then ends the process with
    status 0 (the watchdog's deadline is pushed out of reach, so only the signal can)."""
    before = shm_snapshot()
    sim = _simulator(tmp_path, '-p', 'steps:=0', '-p', 'mode:=realtime', '-p', 'publish_rate:=20.0')
    rec, rec_log = _recorder(tmp_path, '_teardown', 3600.0, hang=SHORT_WAITS)
    try:
        wait_for(rec, rec_log, f'heard all {ROBOTS} robots: ready')
        rec.send_signal(signal.SIGTERM)
        wait_for(rec, rec_log, 'clean-up hangs')
        rec.send_signal(signal.SIGTERM)
        rc = stop(rec)
        text = rec_log.read_text(errors='replace')
        assert rc == 0 and 'Traceback' not in text, f'rc {rc}\n{text}'
    finally:
        for proc in (rec, sim):
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
                stop(proc)
        shm_cleanup(before)
    got = load_trajectories(tmp_path / 'rec.npz')
    assert got.meta['interrupted'] is True
    assert got.states.shape[:1] == (1,) and got.states.shape[1] >= 1 and got.states.shape[2:] == (ROBOTS, 4)
    assert np.isfinite(got.states).all()
