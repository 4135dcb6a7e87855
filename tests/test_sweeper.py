"""The launcher's sweeper (``nodes/swarm/sweeper.py``) without ROS: fake run processes, fake
FastDDS files in a temporary folder in place of /dev/shm.

It must wait until the launcher and every process of the run have gone, then sweep only what the
launcher's own sweep would (new since the run's start, unlocked), outlive a SIGKILL of the
launcher's process group, end at once when the launcher ends normally, and end by its deadline
when a process of the run never does.
"""

import fcntl
import json
import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import pytest

from knode_swarm_ros.nodes.swarm import shm, sweeper

ROOT = Path(__file__).resolve().parents[1]
SEGMENT = ('fastrtps_0123456789abcdef', 'fastrtps_0123456789abcdef_el')
PORT = ('fastrtps_port7411', 'fastrtps_port7411_el', 'sem.fastrtps_port7411_mutex')

# A process of the run: waits for ``go`` in the folder, then leaves an unlocked segment and port
# there (as one killed mid-stop does) and exits.
_RUN_PROCESS = textwrap.dedent(
    """
    import sys, time
    from pathlib import Path
    folder = Path(sys.argv[1])
    while not (folder / 'go').exists():
        time.sleep(0.02)
    for name in sys.argv[2:]:
        (folder / name).write_bytes(b'')
    """
)


def _run_process(folder: Path, **kw) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, '-c', _RUN_PROCESS, str(folder), *SEGMENT, *PORT], **kw)


def _alive(pid: int) -> bool:
    return sweeper._start_time(pid) is not None


def _wait_gone(pid: int, limit: float = 60.0) -> None:
    end = time.monotonic() + limit  # only a hang fails
    while _alive(pid) and time.monotonic() < end:
        time.sleep(0.05)
    assert not _alive(pid), f'process {pid} still runs'


@pytest.fixture
def shm_dir(tmp_path, monkeypatch):
    folder = tmp_path / 'shm'
    folder.mkdir()
    monkeypatch.setattr(shm, 'SHM_DIR', folder)
    (folder / 'fastrtps_old').write_bytes(b'')  # before the run: never the run's to remove
    (folder / 'fastrtps_old_el').write_bytes(b'')
    return folder


def test_orders_are_read_until_end_and_junk_or_ended_pids_are_skipped():
    done = subprocess.Popen([sys.executable, '-c', 'pass'])
    done.wait()  # ended and reaped
    lines = [
        json.dumps({'before': ['fastrtps_a', 7]}),
        'not json',
        json.dumps([1, 2]),
        json.dumps({'pid': os.getpid()}),
        json.dumps({'pid': -3}),
        json.dumps({'pid': done.pid}),
        json.dumps({'end': True}),
        json.dumps({'pid': os.getppid()}),  # after end: not read
    ]
    before, procs, ended = sweeper.read_orders(lines)
    assert before == {'fastrtps_a'} and list(procs) == [os.getpid()] and ended
    assert sweeper.read_orders(lines[:2]) == ({'fastrtps_a'}, {}, False)
    assert sweeper.read_orders([lines[0][:-3], lines[3]]) == (None, {os.getpid(): procs[os.getpid()]}, False)


def test_without_the_snapshot_it_sweeps_nothing(shm_dir):
    # The launcher killed before the snapshot was written (or while writing it): every file
    # would look new, other runs' leftovers too.
    (shm_dir / 'fastrtps_port7411').write_bytes(b'')
    cut = json.dumps({'before': sorted(os.listdir(shm_dir))})[:-5]
    out = subprocess.run(
        [sys.executable, str(Path(sweeper.__file__)), '--shm-dir', str(shm_dir)],
        input=cut,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 0 and out.stdout == '' and out.stderr == ''
    assert sorted(os.listdir(shm_dir)) == ['fastrtps_old', 'fastrtps_old_el', 'fastrtps_port7411']


def test_it_waits_for_the_run_s_processes_then_sweeps_only_new_unlocked_files(shm_dir):
    before = shm.shm_snapshot()
    late = _run_process(shm_dir)
    # A concurrent run's live participant, new since the snapshot: locked, so never swept.
    (shm_dir / 'fastrtps_1111111111111111').write_bytes(b'')
    other = open(shm_dir / 'fastrtps_1111111111111111_el', 'ab')
    fcntl.flock(other, fcntl.LOCK_EX)
    _, procs, _ = sweeper.read_orders([json.dumps({'pid': late.pid})])
    said, removed = [], []
    worker = threading.Thread(
        target=lambda: removed.extend(sweeper.sweep_after(before, procs, 60.0, said.append))
    )
    try:
        worker.start()
        worker.join(timeout=0.5)
        assert worker.is_alive()  # the run's process still runs: nothing swept yet
        (shm_dir / 'go').write_bytes(b'')  # it leaves its files and exits
        assert late.wait(timeout=60) == 0
        worker.join(timeout=60)
    finally:
        late.kill()
        other.close()
    assert not worker.is_alive()
    assert sorted(removed) == sorted(SEGMENT + PORT)  # written after the sweeper started waiting
    assert sorted(os.listdir(shm_dir)) == [
        'fastrtps_1111111111111111',
        'fastrtps_1111111111111111_el',
        'fastrtps_old',
        'fastrtps_old_el',
        'go',
    ]
    assert len(said) == 1 and 'removed 5 FastDDS' in said[0]


def test_a_process_that_never_ends_does_not_keep_it_past_its_deadline(shm_dir):
    before = shm.shm_snapshot()
    stuck = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(600)'])
    try:
        (shm_dir / 'fastrtps_port7411').write_bytes(b'')  # unlocked, new: swept anyway
        said = []
        removed = sweeper.sweep_after(before, {stuck.pid: sweeper._start_time(stuck.pid)}, 0.3, said.append)
        assert stuck.poll() is None
    finally:
        stuck.kill()
        stuck.wait()
    assert removed == ['fastrtps_port7411']
    assert f'1 of its processes still ran after 0.3 s (pids [{stuck.pid}])' in said[0]


def test_a_normal_end_of_the_launcher_ends_it_at_once_without_sweeping(shm_dir):
    s = sweeper.Sweeper.start(shm.shm_snapshot())
    assert s is not None
    (shm_dir / 'fastrtps_port7411').write_bytes(b'')  # the launcher's sweep's business, not its
    s.end()
    assert s.proc.returncode == 0
    assert 'fastrtps_port7411' in os.listdir(shm_dir)


# A launcher: starts the sweeper, then a process of the run (in its own session, as the nodes
# are), tells the sweeper, prints both pids, and waits to be killed.
_LAUNCHER = textwrap.dedent(
    """
    import subprocess, sys, time
    from pathlib import Path
    from knode_swarm_ros.nodes.swarm import shm, sweeper
    shm.SHM_DIR = Path(sys.argv[1])
    s = sweeper.Sweeper.start(shm.shm_snapshot())
    run = subprocess.Popen([sys.executable, '-c', sys.argv[2], *sys.argv[1:2], *sys.argv[3:]],
                           start_new_session=True)
    s.add(run.pid)
    print(s.pid, run.pid, flush=True)
    time.sleep(600)
    """
)


def test_it_outlives_a_sigkill_of_the_launcher_s_group_and_sweeps_after_the_run(shm_dir):
    launcher = subprocess.Popen(
        [sys.executable, '-c', _LAUNCHER, str(shm_dir), _RUN_PROCESS, *SEGMENT, *PORT],
        stdout=subprocess.PIPE,
        text=True,
        start_new_session=True,
        env=dict(os.environ, PYTHONPATH=str(ROOT)),
    )
    sweeper_pid, run_pid = map(int, launcher.stdout.readline().split())
    try:
        os.killpg(launcher.pid, signal.SIGKILL)
        launcher.wait()
        assert _alive(sweeper_pid) and _alive(run_pid)
        (shm_dir / 'go').write_bytes(b'')
        _wait_gone(run_pid)
        _wait_gone(sweeper_pid)
        said = launcher.stdout.read()  # the sweeper had the launcher's output
    finally:
        for pid in (sweeper_pid, run_pid):
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)
    assert sorted(os.listdir(shm_dir)) == ['fastrtps_old', 'fastrtps_old_el', 'go']
    assert 'removed 5 FastDDS shared-memory file(s)' in said


def test_it_imports_nothing_heavy():
    out = subprocess.run(
        [sys.executable, '-X', 'importtime', str(Path(sweeper.__file__))],
        input=json.dumps({'end': True}) + '\n',
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 0, out.stderr
    imported = {line.split('|')[-1].strip().split('.')[0] for line in out.stderr.splitlines() if '|' in line}
    assert 'shm' in imported and not imported & {'numpy', 'torch', 'rclpy', 'knode_swarm_ros'}
