"""The launcher's first run, its plan checks and its Ctrl-C.

The first tests need no ROS process: the plan is checked before anything starts. The ROS ones
start the launcher and assert what must hold whatever the timing of the processes: nothing is
started after a refused stage, and a summary is printed exactly when this run wrote the file.
"""

import json
import os
import signal
import subprocess
import sys
import time
from types import SimpleNamespace

import numpy as np
import pytest

from knode_swarm_ros.core import save_trajectories
from knode_swarm_ros.logic.common import ConfigError
from knode_swarm_ros.nodes import swarm


def _plan(*argv):
    return swarm.plan_run(swarm.build_parser().parse_args([str(a) for a in argv]))


def _main(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        swarm.main([str(a) for a in argv])
    return exc.value.code, capsys.readouterr()


def test_record_folder_that_does_not_exist_yet_is_accepted_and_created_by_run(tmp_path, untrained_policies):
    """make demo on a fresh clone: --record out/demo/swarm_flock2d.npz without out/."""
    record = tmp_path / 'out' / 'demo' / 'swarm.npz'
    plan = _plan(
        '--policy',
        untrained_policies['flock2d'],
        '--record',
        record,
        '--figure',
        tmp_path / 'figs' / 'a.png',
        '--log-dir',
        tmp_path / 'logs',
    )
    assert plan.record == record and not record.parent.exists()  # nothing created by checking
    (tmp_path / 'afile').write_text('x')
    with pytest.raises(ConfigError, match='is not a folder'):
        _plan('--policy', untrained_policies['flock2d'], '--record', tmp_path / 'afile' / 'x.npz')


def test_the_makefile_demo_target_passes_the_plan_check(tmp_path, monkeypatch):
    """The README's `make demo` arguments, from a checkout without out/ (shipped policy)."""
    import re
    from pathlib import Path

    makefile = (Path(__file__).resolve().parents[1] / 'Makefile').read_text()
    recipe = re.search(r'^demo:.*\n((?:\t.*\n)+)', makefile, re.M).group(1)
    argv = recipe.split('bin/swarm', 1)[1].replace('\\\n', ' ').split()
    monkeypatch.chdir(tmp_path)
    plan = _plan(*argv, '--log-dir', tmp_path / 'logs')
    assert plan.record == tmp_path / 'out' / 'demo' / 'swarm_flock2d.npz'


def test_too_many_robots_for_the_nodes_or_the_memory_are_refused_before_anything_starts(
    tmp_path, capsys, monkeypatch
):
    out = tmp_path / 'run.npz'
    code, cap = _main(['--robots', 13000, '--record', out, '--log-dir', tmp_path / 'logs'], capsys)
    assert code == 2 and '--robots must be in 1..10000' in cap.err and '13000' in cap.err
    monkeypatch.setattr(swarm.plan, 'available_memory_mb', lambda: 4096.0)  # the module that calls it
    code, cap = _main(
        ['--robots', 405, '--agents-per-process', 1, '--record', out, '--log-dir', tmp_path / 'logs'], capsys
    )
    assert (
        code == 2 and '405 agent processes need about 130.8 GB' in cap.err and '4.0 GB available' in cap.err
    )
    assert not out.exists() and not (tmp_path / 'logs' / 'pids.json').exists()


# --- with ROS processes ----------------------------------------------------------------------
def _env():
    return dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONUNBUFFERED='1')


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


@pytest.mark.ros
def test_a_refused_simulator_stops_the_run_before_any_agent_starts(
    tmp_path, untrained_policies, ros_domain_id
):
    # The plan accepts --lockstep-timeout 1e-9 (> 0); the simulator's parameter range refuses it.
    proc = subprocess.run(
        _cmd(
            tmp_path,
            '--policy',
            untrained_policies['flock2d'],
            '--robots',
            6,
            '--lockstep-timeout',
            1e-9,
            '--record',
            tmp_path / 'r.npz',
        ),
        env=_env(),
        capture_output=True,
        text=True,
        timeout=600,
    )
    out = proc.stdout + proc.stderr
    assert proc.returncode == 2, out
    assert "'lockstep_timeout'" in out and 'nothing else is started' in out and 'Traceback' not in out
    pids = json.loads((tmp_path / 'logs' / 'pids.json').read_text())
    assert sorted(pids) == ['recorder', 'simulator']


@pytest.mark.ros
def test_ctrl_c_summarises_only_a_file_this_run_wrote(tmp_path, untrained_policies, ros_domain_id):
    record = tmp_path / 'old.npz'
    save_trajectories(record, np.zeros((1, 2, 10, 4)) + 7.0, 0.01, 'flock2d', {'generator': 'an earlier run'})
    before = record.read_bytes()
    proc = subprocess.Popen(
        _cmd(
            tmp_path,
            '--policy',
            untrained_policies['flock2d'],
            '--robots',
            3,
            '--steps',
            100000,
            '--record',
            record,
        ),
        env=_env(),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
    )
    try:
        first = proc.stdout.readline()  # the launcher is up: Ctrl-C now, whatever its children are doing
        assert 'ROS_DOMAIN_ID' in first, first
        os.killpg(proc.pid, signal.SIGINT)
        out = first + proc.stdout.read()
        assert proc.wait(timeout=600) == 130, out
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert 'SIGINT: stopping every process' in out and 'Traceback' not in out, out
    assert 'KeyboardInterrupt' not in out and 'Exception in' not in out, out
    if record.read_bytes() == before:  # the recorder had nothing yet: the old file is not this run's
        assert 'earlier file, left as it was' in out and 'avd (' not in out, out
    else:  # it had frames: it saved them, and that file is summarised
        assert 'avd (' in out and '(interrupted)' in out, out


def test_a_signal_during_the_checks_is_not_lost_when_an_import_swallows_it(monkeypatch):
    """``import torch`` (the policy's check) swallows a KeyboardInterrupt raised inside it: the
    launcher notes the signal instead, and run() stops at once."""
    from knode_swarm_ros.nodes.swarm import cli

    def checks_that_swallow(args):
        try:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.05)  # the handler runs here
        except KeyboardInterrupt:  # what the import does
            pass
        return SimpleNamespace(temporary_dir=False)

    seen = {}

    def fake_run(plan, pending=()):
        seen['pending'] = list(pending)
        return 130 if pending else 0

    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    monkeypatch.setattr(cli, 'plan_run', checks_that_swallow)
    monkeypatch.setattr(cli, 'run', fake_run)
    try:
        with pytest.raises(SystemExit) as exc:
            cli.main(['--record', 'x.npz'])
    finally:
        for s, h in handlers.items():
            signal.signal(s, h)
    assert exc.value.code == 130 and seen['pending'] == [signal.SIGINT]


@pytest.mark.parametrize('when', ['after the last check', 'while stopping', 'while summarising'])
def test_a_stop_signal_as_the_run_ends_is_reported_and_exits_130(
    tmp_path, untrained_policies, monkeypatch, capsys, when
):
    """A SIGINT that lands as the run ends (after the supervisor's last look, while the processes
    are stopped, or while the run is summarised) still ends the launcher as a stopped run does:
    the report names it and the status is 130, not 0."""
    from knode_swarm_ros.nodes.swarm import cli, supervise

    args = [
        '--robots',
        '2',
        '--policy',
        str(untrained_policies['flock2d']),
        '--record',
        str(tmp_path / 'r.npz'),
    ]
    plan = swarm.plan_run(swarm.build_parser().parse_args(args + ['--log-dir', str(tmp_path / 'logs')]))
    stop = lambda *a, **k: os.kill(os.getpid(), signal.SIGINT)  # noqa: E731  (its handler runs at once)

    # a simulator and a recorder that only wait (children start with stop signals blocked)
    wait = 'import signal, time; signal.pthread_sigmask(signal.SIG_UNBLOCK, {2, 15}); time.sleep(60)'

    def start_stand_ins(plan, commands, env, children, t0):
        for name in ('simulator', 'recorder'):
            children.add(supervise.start_child(name, [sys.executable, '-c', wait], env, plan.run_dir, 'none'))

    monkeypatch.setattr(supervise, '_start_in_stages', start_stand_ins)
    monkeypatch.setattr(supervise, '_supervise', lambda *a: (when == 'after the last check' and stop()) or 0)
    if when == 'while stopping':
        monkeypatch.setattr(supervise.Children, 'stop', lambda self: stop() or [])
    if when == 'while summarising':
        monkeypatch.setattr(supervise, 'name_never_heard', lambda plan: stop() or [])
    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    try:
        pending = cli.note_stop_signals()  # the launcher's own handler, as main installs it
        code = supervise.run(plan, pending)
    finally:
        for s, h in handlers.items():
            signal.signal(s, h)
    out = capsys.readouterr().out
    assert code == 130 and 'SIGINT: stopping every process' in out, out
    assert 'every process has stopped' in out
