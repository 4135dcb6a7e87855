"""A SIGINT at any moment of a node's first 2 s, as the launcher starts it, ends it with status 0
and no traceback: during Python's own start (site, the ros wheels' re-exec), the import of the
package, the slow imports and the build of the node.

Before the launcher started its children with SIGINT and SIGTERM blocked (until the node's quiet
handler is in), a SIGINT in the first 0.1-0.3 s printed a KeyboardInterrupt traceback or a "Fatal
Python error: init_import_site". The moments are sampled at fixed delays from the start (a slow
machine only shifts which start-up step each lands in); `make fuzz`-sized sampling (every 20 ms,
100 points) is in docs/testing.md.
"""

import os
import signal
import sys
import time

import pytest
import rclpy  # noqa: F401  (a broken install must fail, not skip)
from node_processes import WAIT_S

from knode_swarm_ros.nodes.swarm.processes import start_child

pytestmark = pytest.mark.ros

DELAYS_S = (0.0, 0.02, 0.05, 0.08, 0.12, 0.16, 0.2, 0.25, 0.3, 0.5, 1.0, 2.0)


def _output(child) -> str:
    data = b''
    while True:
        chunk = child.proc.stdout.read()
        if not chunk:
            return data.decode(errors='replace')
        data += chunk


@pytest.mark.parametrize('delay', DELAYS_S)
def test_a_sigint_early_in_an_agents_life_exits_0_without_a_traceback(
    delay, tmp_path, untrained_policies, ros_domain_id
):
    argv = [sys.executable, '-m', 'knode_swarm_ros.nodes.agent', '--ros-args', '-p', 'id:=0']
    argv += ['-p', 'robots:=2', '-p', f'policy:={untrained_policies["flock2d"]}']
    env = dict(os.environ, PYTHONUNBUFFERED='1', OMP_NUM_THREADS='1')
    env.pop('_ROS_WHEELS_BOOTSTRAP_COMPLETE', None)  # the wheels' re-exec is part of the start
    child = start_child('agent_0', argv, env, tmp_path, 'none')
    try:
        time.sleep(delay)
        child.proc.send_signal(signal.SIGINT)
        rc = child.proc.wait(timeout=WAIT_S)
    finally:
        if child.proc.poll() is None:
            child.proc.kill()
            child.proc.wait()
    text = _output(child)
    child.log.close()
    assert rc in (0, 130) and 'Traceback' not in text and 'KeyboardInterrupt' not in text, f'rc {rc}\n{text}'
