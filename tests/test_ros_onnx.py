"""A whole swarm on onnxruntime with torch impossible to import.

The launcher, the simulator, ten lockstep agents and the recorder run with a
``sitecustomize`` on PYTHONPATH that makes ``import torch`` fail in every process; the
recording stays within 1e-4 of the TorchScript offline rollout over 300 steps and equals
the offline rollout on onnxruntime (same batch shapes: parity_batch).
"""

import os
import subprocess
import sys
import textwrap

import numpy as np
import onnx  # noqa: F401  (a broken install must fail, not skip)
import onnxruntime  # noqa: F401  (a broken install must fail, not skip)
import pytest
import rclpy  # noqa: F401  (a broken install must fail, not skip)

from knode_swarm_ros.core import load_runtime, load_trajectories, rollout

pytestmark = pytest.mark.ros

BLOCKER = textwrap.dedent("""
    # Test only: a robot without torch. Any import of torch fails in this process.
    import sys
    class _NoTorch:
        def find_spec(self, name, path=None, target=None):
            if name == 'torch' or name.startswith('torch.'):
                raise ImportError('torch is blocked in this process (robot without torch)')
    sys.meta_path.insert(0, _NoTorch())
""")


def test_lockstep_swarm_on_onnxruntime_without_torch(tmp_path, untrained_policies):
    from training.learning.onnx_twin import export_onnx

    pt = tmp_path / 'flock2d.pt'
    pt.write_bytes(untrained_policies['flock2d'].read_bytes())
    export_onnx(pt)
    site = tmp_path / 'no_torch'
    site.mkdir()
    (site / 'sitecustomize.py').write_text(BLOCKER)
    env = dict(os.environ)
    env['PYTHONPATH'] = os.pathsep.join(
        [str(site)] + [p for p in env.get('PYTHONPATH', '').split(os.pathsep) if p]
    )
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    check = subprocess.run(
        [sys.executable, '-c', 'import torch'], env=env, capture_output=True, text=True, timeout=60
    )
    assert check.returncode != 0 and 'torch is blocked' in check.stderr
    record = tmp_path / 'onnx.npz'
    proc = subprocess.run(
        [
            sys.executable,
            '-m',
            'knode_swarm_ros.nodes.swarm',
            '--log-dir',
            str(tmp_path / 'logs'),
            '--no-figure',
            '--policy',
            str(pt),
            '--policy-runtime',
            'onnxruntime',
            '--robots',
            '10',
            '--steps',
            '300',
            '--seed',
            '3',
            '--state-timeout',
            '120',
            '--lockstep-timeout',
            '120',
            '--record',
            str(record),
        ],
        env=env,
        capture_output=True,
        text=True,
        timeout=240,
    )
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out
    logs = [(tmp_path / 'logs' / f'agent_{i}.log').read_text() for i in range(10)]
    assert all('flock2d.onnx on onnxruntime' in log and 'torch is blocked' not in log for log in logs)
    states = load_trajectories(record).states[0]
    assert states.shape[0] == 301
    ts, ox = load_runtime(pt, 'torchscript'), load_runtime(pt, 'onnxruntime')
    args = (states[0], 300, 'flock2d', ts.d_cr, ts.k, ts.tau, ts.dt)
    assert np.abs(rollout(ts, *args) - states).max() <= 1e-4
    assert np.abs(rollout(ox, *args) - states).max() <= 1e-9
