"""ONNX twins and the torch-free robot runtime.

* the twin equals the TorchScript module within 1e-5 on a table of inputs (random rows, empty
  neighbourhoods, full rows, coincident robots, walls in 3D, real swarms), for untrained and
  shipped policies, batched and one row at a time;
* a foreign policy file (not built by this project) exports and runs;
* a corrupt, stale or mismatched twin is refused naming the file; a failed parity check writes
  nothing; ``policy_runtime: onnxruntime`` without onnxruntime gives a clear error;
* offline rollouts on onnxruntime stay within 1e-4 of TorchScript's over 300 steps;
* the robot path (policy loading, the agent logic, the agent node module) never imports torch.
"""

import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import onnx
import onnxruntime
import pytest
import torch

from knode_swarm_ros.core import (
    DEFAULTS,
    KNODEPolicy,
    PolicyConfig,
    PolicyError,
    export_policy,
    load_policy,
    load_runtime,
    rollout,
    shipped_policy_path,
)
from training.export_onnx import main as export_main
from training.learning.onnx_twin import check_inputs, compare, export_onnx

torch.set_num_threads(1)
REPO = Path(__file__).resolve().parents[1]
SHIPPED = ('flock2d', 'boids3d', 'boids3d_unity')


def _policy(tmp_path, scenario, seed=3, name=None, **overrides):
    torch.manual_seed(seed)
    policy = KNODEPolicy(PolicyConfig(scenario, **{**DEFAULTS[scenario], **overrides}))
    path = tmp_path / (name or f'{scenario}_{seed}.pt')
    export_policy(policy, path, policy.metadata())
    return path


@pytest.fixture(scope='module')
def twins(tmp_path_factory):
    """Untrained policies of both scenarios with their twins, ``{scenario: pt path}``."""
    root = tmp_path_factory.mktemp('twins')
    out = {}
    for scenario in ('flock2d', 'boids3d'):
        out[scenario] = _policy(root, scenario)
        export_onnx(out[scenario])
    return out


# --- parity ---------------------------------------------------------------------------
@pytest.mark.parametrize('scenario', ['flock2d', 'boids3d'])
def test_twin_equals_torchscript_on_the_input_table(twins, scenario):
    pt = twins[scenario]
    ts, ox = load_runtime(pt, 'torchscript'), load_runtime(pt, 'onnxruntime')
    assert (ts.backend, ox.backend) == ('torchscript', 'onnxruntime') and ox.meta == ts.meta
    table = check_inputs(ts.meta, seed=11)
    expected = {'random', 'empty neighbourhoods', 'full rows', 'coincident robots', 'real swarms'}
    assert expected | ({'walls'} if scenario == 'boids3d' else set()) == set(table)
    errors = compare(ts, ox, table)
    assert max(errors.values()) <= 1e-5, errors
    # the table really exercises the knowledge terms: saturation, wall pushes, repulsion
    Y, mask = table['coincident robots']  # first half exactly on top (r = 0: no push), then 1e-4 apart
    u = ox(Y, mask)
    assert np.all(np.isfinite(u)) and np.all(np.abs(u[len(u) // 2 :]).max(axis=1) == ts.command_limit)
    if scenario == 'boids3d':
        assert np.abs(ts(*table['walls'])).max() == ts.command_limit


@pytest.mark.parametrize('name', SHIPPED)
def test_shipped_policies_ship_a_valid_twin(name):
    pt = shipped_policy_path(name)
    ox = load_runtime(pt)  # auto: the twin, checked against the .pt (knode.json and SHA-256)
    ts = load_policy(pt)
    assert ox.backend == 'onnxruntime' and ox.path == str(pt.with_suffix('.onnx')) and ox.meta == ts.meta
    errors = compare(ts, ox, check_inputs(ts.meta, seed=5))
    assert max(errors.values()) <= 1e-5, errors


def test_batched_call_equals_one_row_at_a_time(twins):
    ox = load_runtime(twins['boids3d'], 'onnxruntime')
    Y, mask = check_inputs(ox.meta, seed=2)['random']
    batch = ox(Y, mask)
    assert batch.shape == (len(Y), 3) and batch.dtype == np.float64
    rows = np.concatenate([ox(Y[i : i + 1], mask[i : i + 1].astype(bool)) for i in range(len(Y))])
    np.testing.assert_allclose(rows, batch, rtol=0, atol=1e-5)


@pytest.mark.parametrize('scenario,robots', [('flock2d', 10), ('boids3d', 10)])
def test_onnx_rollout_stays_within_1e_4_of_torchscript_over_300_steps(twins, scenario, robots):
    from knode_swarm_ros.logic.simulator.swarm_sim import initial_state

    ts, ox = load_runtime(twins[scenario], 'torchscript'), load_runtime(twins[scenario], 'onnxruntime')
    z0, _ = initial_state(scenario, robots, seed=4)
    args = (300, scenario, ts.d_cr, ts.k, ts.tau, ts.dt)
    ref, got = rollout(ts, z0, *args), rollout(ox, z0, *args)
    assert np.all(np.isfinite(got)) and np.abs(ref - z0).max() > 0.1  # the swarm moved
    assert np.abs(ref - got).max() <= 1e-4


# --- foreign files and bad twins --------------------------------------------------------
class _Foreign(torch.nn.Module):
    """Not a KNODEPolicy: a plain linear map of the masked neighbour matrix, clipped."""

    def __init__(self):
        super().__init__()
        self.lin = torch.nn.Linear(5 * 4, 2)

    def forward(self, Y: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        return torch.clamp(self.lin((Y * mask.unsqueeze(-1)).flatten(1)), -3.0, 3.0)


@pytest.mark.filterwarnings('ignore::DeprecationWarning')  # torch.jit: how others still write policies
def test_a_foreign_policy_file_exports_and_runs(tmp_path, capsys):
    torch.manual_seed(0)
    meta = {
        'format': 'knode-policy/1',
        'scenario': 'flock2d',
        'state_dim': 4,
        'command_dim': 2,
        'command': 'acceleration',
        'k': 5,
        'd_cr': 2.5,
        'tau': 2,
        'dt': 0.02,
        'state_layout': ['px', 'py', 'vx', 'vy'],
        'author': 'someone else',
    }
    pt = tmp_path / 'theirs.pt'
    torch.jit.save(torch.jit.script(_Foreign()), str(pt), _extra_files={'knode.json': json.dumps(meta)})
    assert export_main([str(pt)]) == 0
    assert 'wrote' in capsys.readouterr().out
    ts, ox = load_runtime(pt, 'torchscript'), load_runtime(pt)
    assert ox.backend == 'onnxruntime' and ox.meta == meta and (ox.k, ox.tau, ox.dt) == (5, 2, 0.02)
    Y, mask = check_inputs(meta, seed=1)['random']
    np.testing.assert_allclose(ox(Y, mask), ts(Y, mask), rtol=0, atol=1e-5)


def test_a_corrupt_twin_is_refused_naming_the_file(tmp_path):
    pt = _policy(tmp_path, 'flock2d')
    twin = pt.with_suffix('.onnx')
    twin.write_bytes(b'\x08\x07 not an onnx model at all')
    for runtime in ('auto', 'onnxruntime'):
        with pytest.raises(PolicyError, match=f'{twin}.*not a readable ONNX model'):
            load_runtime(pt, runtime)
    assert load_runtime(pt, 'torchscript').backend == 'torchscript'


def test_stale_and_mismatched_twins_are_refused(tmp_path, twins):
    # same knode.json, other weights: the recorded SHA-256 of the .pt differs
    stale = _policy(tmp_path, 'flock2d', seed=4)
    shutil.copy(twins['flock2d'].with_suffix('.onnx'), stale.with_suffix('.onnx'))
    with pytest.raises(PolicyError, match=f'{stale.with_suffix(".onnx")}.*another version of {stale}'):
        load_runtime(stale)
    # another knode.json (d_cr): refused naming the key
    other = _policy(tmp_path, 'flock2d', seed=3, name='other.pt', d_cr=4.0)
    shutil.copy(twins['flock2d'].with_suffix('.onnx'), other.with_suffix('.onnx'))
    with pytest.raises(PolicyError, match=r'other\.onnx.*differs from that of its TorchScript policy.*d_cr'):
        load_runtime(other, 'onnxruntime')
    # a required value the caller expects
    with pytest.raises(PolicyError, match="onnx.*'k' is 6 but 5 was required"):
        load_runtime(twins['flock2d'], 'onnxruntime', expect={'k': 5})


def test_a_twin_without_metadata_is_refused(tmp_path, twins):
    model = onnx.load(str(twins['boids3d'].with_suffix('.onnx')))
    del model.metadata_props[:]
    bare = tmp_path / 'bare.onnx'
    onnx.save(model, str(bare))
    with pytest.raises(PolicyError, match=r'bare\.onnx: no knode\.json'):
        load_runtime(bare)
    with pytest.raises(PolicyError, match='torchscript needs the TorchScript .pt'):
        load_runtime(bare, 'torchscript')


def test_a_failed_parity_check_writes_nothing_and_keeps_the_old_twin(tmp_path):
    pt = _policy(tmp_path, 'boids3d')
    twin = pt.with_suffix('.onnx')
    twin.write_bytes(b'previous twin')
    with pytest.raises(PolicyError, match=r'differs from the TorchScript module by .* > 1e-15.*not written'):
        export_onnx(pt, tol=1e-15)
    assert twin.read_bytes() == b'previous twin'
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([pt.name, twin.name])  # no temporary left


def test_export_cli_bad_file_exits_2(tmp_path, capsys):
    bad = tmp_path / 'bad.pt'
    bad.write_bytes(b'nope')
    assert export_main([str(bad)]) == 2
    assert f'policy file {bad}: not a readable TorchScript archive' in capsys.readouterr().err
    assert not bad.with_suffix('.onnx').exists()


def test_onnxruntime_missing_gives_a_clear_error(monkeypatch, twins):
    from knode_swarm_ros.logic.common import ConfigError
    from knode_swarm_ros.nodes.agent.plumbing import load_agent_policy

    monkeypatch.setitem(sys.modules, 'onnxruntime', None)  # import onnxruntime now raises ImportError
    with pytest.raises(PolicyError, match='needs the onnxruntime package, which is not installed'):
        load_runtime(twins['flock2d'], 'onnxruntime')
    assert load_runtime(twins['flock2d'], 'auto').backend == 'torchscript'  # auto falls back
    with pytest.raises(
        ConfigError, match=r"parameter 'policy' \(policy_runtime onnxruntime\).*onnxruntime package"
    ):
        load_agent_policy(str(twins['flock2d']), '', 0, 0.0, -1, 0.0, 'onnxruntime')
    with pytest.raises(
        PolicyError, match="policy_runtime 'tensorrt' is not one of auto, torchscript, onnxruntime"
    ):
        load_runtime(twins['flock2d'], 'tensorrt')


def test_onnxruntime_without_a_twin_names_the_missing_file(tmp_path):
    pt = _policy(tmp_path, 'flock2d')
    with pytest.raises(PolicyError, match=f'needs its ONNX twin {pt.with_suffix(".onnx")}.*export_onnx'):
        load_runtime(pt, 'onnxruntime')
    assert load_runtime(pt).backend == 'torchscript'  # auto without a twin


# --- the robot path never imports torch ---------------------------------------------------------
# Run in a fresh interpreter whose import of torch fails, as on a robot without it.
_NO_TORCH = textwrap.dedent("""
    import sys
    class _NoTorch:
        def find_spec(self, name, path=None, target=None):
            if name == 'torch' or name.startswith('torch.'):
                raise ImportError('torch is blocked in this process (robot without torch)')
    sys.meta_path.insert(0, _NoTorch())
""")


def _run_without_torch(code, *args, timeout=120):
    env = dict(os.environ)
    env['PYTHONPATH'] = os.pathsep.join(
        [str(REPO)] + [p for p in env.get('PYTHONPATH', '').split(os.pathsep) if p]
    )
    return subprocess.run(
        [sys.executable, '-c', _NO_TORCH + textwrap.dedent(code), *map(str, args)],
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
        cwd=REPO,
    )


def test_the_robot_path_never_imports_torch(twins):
    code = """
        import json, sys
        import numpy as np
        try:
            import torch
        except ImportError:
            pass
        else:
            raise SystemExit('the torch blocker does not work')
        from knode_swarm_ros.nodes.agent import node as agent  # the node module: rclpy, messages, logic
        from knode_swarm_ros.logic.agent.agent_logic import AgentConfig, AgentLogic
        policy = agent.load_agent_policy(sys.argv[1], '', 0, 0.0, -1, 0.0, 'auto')
        logic = AgentLogic(AgentConfig(1, [0, 1, 2], 'lockstep'), policy)
        states = json.loads(sys.argv[2])
        for rid, z in enumerate(states):
            logic.receive(rid, 0, z)
        cmd = logic.lockstep_poll(0.0)
        print(json.dumps({'backend': policy.backend, 'u': cmd.value.tolist(), 'neighbours': cmd.neighbours,
                          'torch': [m for m in sys.modules if m == 'torch' or m.startswith('torch.')]}))
    """
    states = [[0.0, 0.0, 0.1, 0.0], [0.5, 0.2, 0.0, 0.3], [1.5, -1.0, -0.2, 0.1]]
    proc = _run_without_torch(code, twins['flock2d'], json.dumps(states))
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out['backend'] == 'onnxruntime' and out['torch'] == [] and out['neighbours'] == 2
    # the same command as the TorchScript policy's (row 1 of the parity batch)
    from knode_swarm_ros.core import neighbour_matrix

    ts = load_policy(twins['flock2d'])
    Y, mask = neighbour_matrix(np.array(states), np.array(states), 2, ts.d_cr, ts.k)
    np.testing.assert_allclose(out['u'], ts(Y, mask)[1], rtol=0, atol=1e-5)


def test_the_torchscript_runtime_without_torch_says_what_to_do(twins):
    proc = _run_without_torch(
        """
        import sys
        from knode_swarm_ros.core import PolicyError, load_runtime
        try:
            load_runtime(sys.argv[1], 'torchscript')
        except PolicyError as exc:
            print(exc)
    """,
        twins['flock2d'],
    )
    assert proc.returncode == 0, proc.stderr
    assert (
        'the TorchScript runtime needs torch' in proc.stdout and 'policy_runtime onnxruntime' in proc.stdout
    )


# --- offline rollout option and packaging ----------------------------------------------
def test_rollout_cli_runs_the_twin_on_request(tmp_path, twins):
    from knode_swarm_ros.core import load_trajectories, save_trajectories
    from knode_swarm_ros.logic.simulator.swarm_sim import initial_state
    from training.rollout import main as rollout_main

    z0, _ = initial_state('boids3d', 6, seed=1)
    init = tmp_path / 'init.npz'
    save_trajectories(init, z0[None, None], 1 / 60, 'boids3d')
    out = {}
    for runtime in ('torchscript', 'onnxruntime'):
        path = tmp_path / f'{runtime}.npz'
        assert (
            rollout_main(
                [
                    '--policy',
                    str(twins['boids3d']),
                    '--init',
                    str(init),
                    '--steps',
                    '50',
                    '--out',
                    str(path),
                    '--runtime',
                    runtime,
                ]
            )
            == 0
        )
        data = load_trajectories(path)
        assert data.meta['runtime'] == runtime
        out[runtime] = data.states
    assert 0 < np.abs(out['torchscript'] - out['onnxruntime']).max() <= 1e-4  # two backends, float32 rounding


def _pins(path):
    lines = [line.split('#')[0].strip() for line in (REPO / path).read_text().splitlines()]
    return dict(line.split('==') for line in lines if '==' in line)


def test_the_robot_requirements_need_no_torch():
    robot, full = _pins('requirements-robot.txt'), _pins('requirements.txt')
    assert 'torch' not in robot and {'numpy', 'PyYAML', 'onnxruntime', 'ros-jazzy-rclpy'} <= set(robot)
    assert set(full) == {'torch'} and '-r requirements-robot.txt' in (REPO / 'requirements.txt').read_text()
    setup = (REPO / 'setup.py').read_text()
    assert f"'robot': ['onnxruntime=={robot['onnxruntime']}']" in setup and "'policies/*.onnx'" in setup
    assert onnxruntime.__version__ == robot['onnxruntime']
