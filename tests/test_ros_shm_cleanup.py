"""A node stopped by SIGINT or SIGTERM while messages flow, or while it is
still being built, exits 0 and leaves none of its FastDDS shared-memory files behind.

Which files are the node's own is read from /proc/locks while it runs (the lock files of its
segment and its ports, :func:`shm_held_by`), so files of a concurrent copy of the suite, or of
the traffic simulator, never count. Before the fix the lifecycle agent left its segment and
ports on almost every stop: rclpy's LifecycleNode.destroy_node keeps the state machine, which
holds the node, which keeps the DDS participant past the context's end. The tests wait only for
polled conditions (log lines) with generous deadlines; the 2 s figure is bench/bench_shutdown.py's.
"""

import signal
import time
from pathlib import Path

import pytest
import rclpy  # noqa: F401  (a broken install must fail, not skip)
from node_processes import start, stop, wait_for

from knode_swarm_ros.nodes.swarm.shm import shm_held_by, shm_left_by, shm_snapshot

pytestmark = pytest.mark.ros

ROBOTS = 2
TRAFFIC = [
    '-p',
    f'robots:={ROBOTS}',
    '-p',
    'mode:=realtime',
    '-p',
    'steps:=0',
    '-p',
    'wait_for_agents:=false',
    '-p',
    'publish_rate:=20.0',
]


def _node_argv(node, tmp_path, policy):
    """``(argv, line it logs once it has heard every robot or runs)`` of ``node``."""
    heard = f'heard all {ROBOTS} robots: ready'
    args = {
        'agent': [
            '-p',
            'id:=0',
            '-p',
            f'robots:={ROBOTS}',
            '-p',
            f'policy:={policy}',
            '-p',
            'use_sim_time:=true',
        ],
        'agents': [
            '-p',
            'ids:=[0,1]',
            '-p',
            f'robots:={ROBOTS}',
            '-p',
            f'policy:={policy}',
            '-p',
            'use_sim_time:=true',
        ],
        'simulator': TRAFFIC,
        'recorder': [
            '-p',
            f'robots:={ROBOTS}',
            '-p',
            f'output:={tmp_path / "rec.npz"}',
            '-p',
            'use_sim_time:=true',
        ],
    }[node]
    ready = {'simulator': ': running'}.get(node, heard)
    return ['-m', f'knode_swarm_ros.nodes.{node}', '--ros-args', *args], ready


def _held_while_running(proc) -> set:
    """The node's lock files, read a few times (a port may open late); at least its segment's."""
    held = set()
    for _ in range(4):
        held |= shm_held_by(proc.pid)
        time.sleep(0.1)
    assert any('port' not in name for name in held), f'no segment lock held by {proc.pid}: {held}'
    return held


def _port_mappers(held) -> dict:
    """``{port: pids}``: the processes that have each port of ``held`` mapped now (/proc/*/maps)."""
    ports = {name[:-3] for name in held if 'port' in name}
    found = {port: set() for port in ports}
    for pid_dir in Path('/proc').glob('[0-9]*'):
        try:
            maps = (pid_dir / 'maps').read_text()
        except OSError:
            continue
        for port in ports:
            if f'/dev/shm/{port}' in maps:
                found[port].add(int(pid_dir.name))
    return found


@pytest.mark.parametrize(
    'node,sig',
    [
        ('agent', signal.SIGINT),
        ('agent', signal.SIGTERM),
        ('agents', signal.SIGINT),
        ('simulator', signal.SIGTERM),
        ('recorder', signal.SIGINT),
    ],
)
def test_a_node_stopped_while_messages_flow_leaves_no_shared_memory(
    node, sig, tmp_path, untrained_policies, ros_domain_id
):
    traffic = None
    if node != 'simulator':
        traffic = start(
            ['-m', 'knode_swarm_ros.nodes.simulator', '--ros-args', *TRAFFIC],
            open(tmp_path / 'traffic.log', 'wb'),
        )
    try:
        argv, ready = _node_argv(node, tmp_path, untrained_policies['flock2d'])
        log_path = tmp_path / f'{node}.log'
        before = frozenset(shm_snapshot())  # a port a killed process left earlier is not this node's
        with open(log_path, 'wb') as log:
            proc = start(argv, log)
        wait_for(proc, log_path, ready)
        held = _held_while_running(proc)
        ours = {proc.pid} | ({traffic.pid} if traffic is not None else set())
        foreign = {port for port, pids in _port_mappers(held).items() if pids - ours}
        rc = stop(proc, sig)
        text = log_path.read_text(errors='replace')
        assert rc == 0 and 'Traceback' not in text and 'Aborted' not in text, f'rc {rc}\n{text}'
        segments = {name for name in held if 'port' not in name}
        assert shm_left_by(segments) == [], f'{node} left its segment after {sig.name}\n{text[-2000:]}'
    finally:
        if traffic is not None:
            assert stop(traffic, signal.SIGINT) == 0
    # A port the node listened on is also open in the peers that sent to it: it goes with the last.
    # A peer outside this test (a process of a concurrent suite whose domain claim ended before it
    # did) that is killed later leaves the port behind whatever the node does: not the node's.
    left = [
        name
        for name in shm_left_by(held, ros_domain_id, before)
        if not any(name in (port, f'sem.{port}_mutex', f'{port}_el') for port in foreign)
    ]
    assert left == [], (
        f'{node} left its ports after {sig.name} (mapped by other processes: {sorted(foreign)})'
    )


# The node is built with a step that never ends by itself (it waits in Python, where a signal is
# handled): the policy load, or the last part of rclpy's Node constructor (its type description
# service), after which rclpy's destroy_node works and before which it stops short of the handle.
# The signal must end the start-up, not wait for it to finish, and free the half-built node;
# inside torch's code (where an exception must not unwind) the node is freed where it stands.
_BLOCKED = """
import sys, time
import rclpy.node
from knode_swarm_ros.nodes.agent import node as agent
from knode_swarm_ros.nodes.{module} import node as {module}
def never_ending(*args, **kwargs):
    print('blocked in construction', flush=True)
    time.sleep(3600)
if '{step}' == 'torch':  # blocked inside torch's own code (as during `import torch`)
    space = {{}}
    exec(compile('import time\\ndef never_ending(*args, **kwargs):\\n    print("blocked in construction", flush=True)\\n'
                 '    time.sleep(3600)\\n', '/site-packages/torch/_blocked.py', 'exec'), space)
    agent.load_agent_policy = {module}.load_agent_policy = space['never_ending']
elif '{step}' == 'policy':
    agent.load_agent_policy = {module}.load_agent_policy = never_ending
else:
    rclpy.node.TypeDescriptionService = never_ending
sys.argv = ['{module}', '--ros-args', *sys.argv[1:]]
{module}.main()
"""


@pytest.mark.parametrize(
    'node,step,sig',
    [
        ('agent', 'policy', signal.SIGINT),
        ('agent', 'policy', signal.SIGTERM),
        ('agents', 'policy', signal.SIGINT),
        ('agent', 'rclpy', signal.SIGTERM),
        ('simulator', 'rclpy', signal.SIGINT),
        ('agent', 'torch', signal.SIGTERM),
        ('agent', 'torch', signal.SIGINT),
    ],
)
def test_a_signal_while_the_node_is_built_ends_the_start_up_cleanly(
    node, step, sig, tmp_path, untrained_policies, ros_domain_id
):
    argv, _ = _node_argv(node, tmp_path, untrained_policies['flock2d'])
    log_path = tmp_path / f'{node}.log'
    with open(log_path, 'wb') as log:
        proc = start(['-c', _BLOCKED.format(module=node, step=step), *argv[3:]], log)
    wait_for(proc, log_path, 'blocked in construction')
    held = _held_while_running(proc)  # the half-built node already has its DDS participant
    rc = stop(proc, sig)
    text = log_path.read_text(errors='replace')
    assert rc == 0 and 'Traceback' not in text and 'KeyboardInterrupt' not in text, f'rc {rc}\n{text}'
    assert '(k=' not in text and ': running' not in text, text  # what a built node logs: it never got there
    # Its own segment must go. Its ports are judged only where no other participant could share
    # them: a concurrent copy of the suite once left this domain's port file (CI, 1 run in 5 cases)
    segments = {name for name in held if 'port' not in name}
    assert shm_left_by(segments) == [], f'{node} left its shared memory segment\n{text[-2000:]}'


@pytest.mark.parametrize('node', ['recorder', 'agent'])
def test_a_node_whose_launcher_died_stops_cleanly_on_its_broken_pipe(
    node, tmp_path, untrained_policies, ros_domain_id
):
    """The launcher SIGKILLed: its children get SIGTERM (PR_SET_PDEATHSIG) with their stdout and
    stderr a pipe nobody reads any more. That must not cut their clean-up short (the recorder
    saves, then the node and its DDS files go)."""
    import subprocess
    import sys

    from node_processes import WAIT_S

    from knode_swarm_ros.nodes.common.startup import block_stop_signals

    traffic = start(
        ['-m', 'knode_swarm_ros.nodes.simulator', '--ros-args', *TRAFFIC],
        open(tmp_path / 'traffic.log', 'wb'),
    )
    try:
        argv, ready = _node_argv(node, tmp_path, untrained_policies['flock2d'])
        env = dict(__import__('os').environ, PYTHONUNBUFFERED='1', OMP_NUM_THREADS='1')
        proc = subprocess.Popen(
            [sys.executable, *argv],
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            start_new_session=True,
            preexec_fn=block_stop_signals,
        )
        seen = b''
        deadline = time.monotonic() + WAIT_S
        while ready.encode() not in seen and time.monotonic() < deadline and proc.poll() is None:
            seen += proc.stdout.read1(4096)
        assert ready.encode() in seen, seen.decode(errors='replace')
        held = _held_while_running(proc)
        proc.stdout.close()  # the reader is gone, as with a killed launcher
        rc = stop(proc, signal.SIGTERM)
        assert rc == 0, f'{node} exited {rc} on a broken pipe'
        segments = {name for name in held if 'port' not in name}
        assert shm_left_by(segments) == [], f'{node} left its segment after its pipe broke'
        if node == 'recorder':
            assert (tmp_path / 'rec.npz').is_file()  # saved all the same
    finally:
        assert stop(traffic, signal.SIGINT) == 0
