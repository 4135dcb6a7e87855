"""The executables stop cleanly on SIGINT / SIGTERM at
any moment, start-up included, and refuse an unparsable params file with exit status 2.

Whatever the moment the signal lands (importing, inside rclpy.init, building the node,
spinning), the outcome must be the same: exit status 0 and no traceback (or, for a signal
that lands before the interpreter has run a line, the signal's default action). So the tests send the
signal at moments they do not control and assert that invariant; they wait only for polled
conditions with generous deadlines. Timing figures (2 s, 50 of 50) are bench/bench_shutdown.py's.
"""

import signal
import subprocess
import sys
import time

import pytest
import rclpy  # noqa: F401  (a broken install must fail, not skip)
from node_processes import WAIT_S, start, stop, wait_for

from knode_swarm_ros.nodes.swarm.processes import catches_signal

pytestmark = pytest.mark.ros


def _command(node, tmp_path, untrained_policies):
    if node == 'agent':
        return [
            '-p',
            'id:=0',
            '-p',
            'robots:=2',
            '-p',
            f'policy:={untrained_policies["flock2d"]}',
        ], 'publishing'
    if node == 'agents':  # the hosted agents: several robots in one process
        return [
            '-p',
            'ids:=[0,1]',
            '-p',
            'robots:=2',
            '-p',
            f'policy:={untrained_policies["flock2d"]}',
        ], '(2 hosted)'
    if node == 'simulator':
        return [
            '-p',
            'robots:=2',
            '-p',
            'mode:=realtime',
            '-p',
            'steps:=0',
            '-p',
            'wait_for_agents:=false',
            '-p',
            'real_time_factor:=1.0',
        ], ': running'
    return ['-p', 'robots:=2', '-p', f'output:={tmp_path / "rec.npz"}'], 'recording 2 robots'


def _start(node, args, log):
    return start(['-m', f'knode_swarm_ros.nodes.{node}', '--ros-args', *args], log)


def _stop(proc, sig, log_path):
    return stop(proc, sig), log_path.read_text(errors='replace')


@pytest.mark.parametrize('node', ['agent', 'agents', 'simulator', 'recorder'])
def test_a_signal_at_any_moment_gives_a_clean_exit(node, tmp_path, untrained_policies, ros_domain_id):
    args, running = _command(node, tmp_path, untrained_policies)
    # 1) SIGTERM at once: wherever start-up has got to. Before the package's handler exists,
    #    SIGTERM's default action ends the process silently (-SIGTERM: nothing was created yet).
    log_path = tmp_path / f'{node}_at_once.log'
    with open(log_path, 'wb') as log:
        proc = _start(node, args, log)
    rc, text = _stop(proc, signal.SIGTERM, log_path)
    assert rc in (0, -signal.SIGTERM) and 'Traceback' not in text, f'rc {rc}\n{text}'
    # 2) SIGINT as soon as the process handles signals itself (a polled condition), wherever it is
    #    then: importing rclpy and torch, inside rclpy.init, building the node or spinning.
    log_path = tmp_path / f'{node}_starting.log'
    with open(log_path, 'wb') as log:
        proc = _start(node, args, log)
    deadline = time.monotonic() + WAIT_S
    while time.monotonic() < deadline and proc.poll() is None and not catches_signal(proc.pid):
        time.sleep(0.001)
    rc, text = _stop(proc, signal.SIGINT, log_path)
    assert rc == 0 and 'Traceback' not in text, f'rc {rc}\n{text}'
    # 3) once it runs (a polled condition: its log line).
    for sig in (signal.SIGINT, signal.SIGTERM):
        log_path = tmp_path / f'{node}_running_{sig}.log'
        with open(log_path, 'wb') as log:
            proc = _start(node, args, log)
        wait_for(proc, log_path, running)
        rc, text = _stop(proc, sig, log_path)
        assert rc == 0 and 'Traceback' not in text and 'Aborted' not in text, f'rc {rc}\n{text}'


@pytest.mark.parametrize('node', ['agent', 'simulator', 'recorder'])
def test_an_unparsable_params_file_is_refused_with_status_2(node, tmp_path, ros_domain_id):
    bad = tmp_path / 'params.yaml'
    bad.write_text('/**:\n  ros__parameters:\n    robots: [1\n  oops: : :\n')
    proc = subprocess.run(
        [
            sys.executable,
            '-m',
            f'knode_swarm_ros.nodes.{node}',
            '--ros-args',
            '-p',
            'id:=0',
            '--params-file',
            str(bad),
        ],
        capture_output=True,
        text=True,
        timeout=WAIT_S,
    )
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert 'Traceback' not in proc.stderr and 'params.yaml' in proc.stderr and 'error:' in proc.stderr
