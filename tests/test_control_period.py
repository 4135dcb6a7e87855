"""Deploying at the rate a policy was trained for.

* the agent's control-period check: equal (silent), a whole multiple and a mismatch (one
  warning naming both periods, or a refusal with ``rate_check: refuse``), the ratio in status;
* training for a longer control period: the samples built with ``ratio`` against a hand-built
  example, the ratio check, a tiny training whose policy carries the longer dt;
* the shipped 20 Hz flock2d policy: its metadata, its offline rollout at dt 0.05 from held-out
  starts, and the realtime defaults (configs, ``swarm --mode realtime``) picking it.
"""

import math
import os

import numpy as np
import pytest
import yaml
from test_training import linear_teacher, spy_on_selection_rollouts

from knode_swarm_ros.core.scenarios import get_scenario
from knode_swarm_ros.logic.agent.agent_logic import AgentConfig, AgentLogic
from knode_swarm_ros.logic.agent.control_period import check_control_period
from knode_swarm_ros.logic.common import ConfigError

FLOCK = get_scenario('flock2d')
SEC = 1_000_000_000


class ZeroPolicy:
    """A stand-in for a policy file with a given dt: always a zero command."""

    def __init__(self, dt):
        self.scenario, self.k, self.d_cr, self.tau, self.dt, self.command_limit = (
            'flock2d',
            3,
            5.0,
            0,
            dt,
            10.0,
        )

    def __call__(self, Y, mask):
        return np.zeros((Y.shape[0], 2))


def _logic(rate, dt, mode='realtime', **kw):
    return AgentLogic(AgentConfig(0, [0, 1], mode=mode, control_rate=rate, **kw), ZeroPolicy(dt))


# --- the agent's period check -----------------------------------------------------------
def test_equal_period_is_silent_and_status_reports_ratio_one():
    logic = _logic(20.0, 0.05)
    assert logic.drain_events() == []
    status = logic.status()
    assert status['period_ratio'] == pytest.approx(1.0)
    assert status['control_period'] == pytest.approx(0.05) and status['policy_dt'] == 0.05
    assert _logic(100.0, 0.01).drain_events() == []  # 1 / 100.0 is not exactly 0.01 in binary
    assert _logic(20.0, 0.05, rate_check='refuse').period.equal


def test_whole_multiple_warns_once_with_both_numbers():
    logic = _logic(20.0, 0.01)  # the shipped 100 Hz policy at 20 Hz
    events = logic.drain_events()
    assert len(events) == 1
    text = events[0]
    assert '0.05 s' in text and '20 Hz' in text and '0.01 s' in text and '100 Hz' in text
    assert 'held 5 policy steps' in text and 'data.policy_dt=0.05' in text
    assert logic.status()['period_ratio'] == pytest.approx(5.0)
    # once: ticking and receiving do not repeat it
    logic.receive(0, SEC, np.zeros(4), SEC)
    logic.receive(1, SEC, np.ones(4), SEC)
    for step in range(3):
        assert logic.tick(SEC + step * SEC // 20) is not None
    assert logic.drain_events() == []


def test_mismatch_warns_and_says_not_whole():
    logic = _logic(30.0, 0.01)
    (text,) = logic.drain_events()
    assert '0.0333333 s' in text and '30 Hz' in text and '0.01 s' in text and 'not a whole number' in text
    assert logic.status()['period_ratio'] == pytest.approx(10 / 3)
    (faster,) = _logic(50.0, 0.05).drain_events()  # control faster than trained
    assert 'of a policy step' in faster and '0.02 s' in faster
    assert check_control_period(50.0, 0.05).ratio == pytest.approx(0.4)


@pytest.mark.parametrize('rate,dt', [(20.0, 0.01), (30.0, 0.01), (50.0, 0.05)])
def test_refuse_raises_naming_the_parameter(rate, dt):
    with pytest.raises(ConfigError, match=r"parameter 'control_rate' \(rate_check refuse\).*differs"):
        _logic(rate, dt, rate_check='refuse')


def test_lockstep_and_bad_values():
    logic = _logic(20.0, 0.01, mode='lockstep')  # lockstep holds one simulator step: no check
    assert logic.drain_events() == [] and logic.status()['period_ratio'] is None
    with pytest.raises(ConfigError, match="'rate_check'"):
        _logic(20.0, 0.05, rate_check='ignore')
    with pytest.raises(ConfigError, match="'control_rate'"):
        _logic(-1.0, 0.05)
    with pytest.raises(ValueError):
        check_control_period(0.0, 0.05)


# --- training for a longer control period -------------------------------------------------
def _line_swarm(T=6):
    """One trajectory [1, T, 3, 4]: robots at x = 0, 1, 3 drifting +0.1 per frame, vy = t + 10 r
    (every row identifiable)."""
    states = np.zeros((1, T, 3, 4))
    for t in range(T):
        for r, x in enumerate((0.0, 1.0, 3.0)):
            states[0, t, r] = [x + 0.1 * t, 0.0, 0.1, t + 10.0 * r]
    return states


def test_period_samples_against_a_hand_built_example():
    import torch  # noqa: F401  (a broken install must fail, not skip)

    from training.learning.samples import make_samples

    states = _line_swarm()
    # ratio 2 (policy dt = 2 frames), tau 1 policy step = 2 frames of delay, every start frame
    s = make_samples(states, FLOCK, d_cr=10.0, k=3, tau=1, stride=1, ratio=2)
    order = {0: (1, 2), 1: (0, 2), 2: (1, 0)}  # neighbours closest first, from each robot
    Y, mask, target = s.Y.numpy(), s.mask.numpy(), s.target.numpy()
    assert Y.shape == (4 * 3, 3, 4)  # starts t = 0 .. 3 (t + 2 <= 5), 3 robots each
    for t in range(4):
        for i in range(3):
            m = t * 3 + i
            delayed = max(t - 2, 0)
            want = np.stack([states[0, t, i]] + [states[0, delayed, j] for j in order[i]])
            np.testing.assert_allclose(Y[m], want, rtol=0, atol=1e-6)
            np.testing.assert_allclose(target[m], states[0, t + 2, i], rtol=0, atol=1e-6)
            np.testing.assert_array_equal(mask[m], [1, 1, 1])
    # stride = ratio keeps one phase: starts 0 and 2 only
    one_phase = make_samples(states, FLOCK, 10.0, 3, 1, stride=2, ratio=2)
    np.testing.assert_array_equal(one_phase.target.numpy(), s.target.numpy()[[0, 1, 2, 6, 7, 8]])
    # ratio 1 is the plain one-step builder: target = next frame, delay tau frames
    plain = make_samples(states, FLOCK, 10.0, 3, 1, ratio=1)
    np.testing.assert_allclose(plain.target.numpy()[3:6], states[0, 2], atol=1e-6)
    np.testing.assert_allclose(
        plain.Y.numpy()[3 * 3 + 0, 1], states[0, 2, 1], atol=1e-6
    )  # t 3, delay 1 frame
    with pytest.raises(ValueError, match='T >= 7'):
        make_samples(states, FLOCK, 10.0, 3, 0, ratio=6)


def test_period_ratio():
    from training.learning.period import period_ratio, policy_dt, subsample

    assert period_ratio(0.01, None) == 1
    assert period_ratio(0.01, 0.05) == 5 and period_ratio(0.01, 0.1) == 10 and period_ratio(0.01, 0.01) == 1
    assert period_ratio(1 / 60, 1 / 20) == 3
    assert policy_dt(0.01, 5) == 0.05 and policy_dt(0.01, 3) == 0.03
    assert policy_dt(1 / 60, 1) == 1 / 60 and policy_dt(1 / 60, 2) == 2 / 60  # never rounded off the grid
    for bad in (0.035, 0.005, 0.0, -0.05, math.inf):
        with pytest.raises(ValueError, match='data.policy_dt'):
            period_ratio(0.01, bad)
    states = _line_swarm(T=7)
    np.testing.assert_array_equal(subsample(states, 3), states[:, [0, 3, 6]])


def _held_teacher_data(tmp_path, hold=5, steps=40, trajectories=5, n=6, seed=0):
    """100 Hz recordings of a linear controller that holds each command ``hold`` frames
    (a 20 Hz controller for hold 5): the ground truth of a policy with dt = hold * 0.01."""
    from knode_swarm_ros.core import save_trajectories, zoh_step
    from knode_swarm_ros.core.rollout import policy_commands

    linear = linear_teacher
    rng = np.random.default_rng(seed)
    z = np.concatenate([rng.uniform(-2, 2, (trajectories, n, 2)), rng.normal(0, 1, (trajectories, n, 2))], -1)
    frames = [z]
    for _ in range(steps):
        c = policy_commands(linear, z, z, FLOCK, 3.0, 4)
        for _ in range(hold):
            z = zoh_step(z, c, FLOCK, 0.01)
            frames.append(z)
    states = np.stack(frames, axis=1)
    path = tmp_path / 'held.npz'
    save_trajectories(
        path,
        states,
        0.01,
        'flock2d',
        {'split': {'train': list(range(trajectories - 1)), 'test': [trajectories - 1]}},
    )
    return str(path), linear


def test_training_for_20hz_from_100hz_data_recovers_the_held_controller(tmp_path):
    import torch

    from knode_swarm_ros.core import load_policy
    from training.learning.config import normalise_config
    from training.learning.trainer import Trainer

    torch.set_num_threads(1)
    data, linear = _held_teacher_data(tmp_path)
    raw = {
        'scenario': 'flock2d',
        'seed': 3,
        'policy': {'hidden': 32, 'd_cr': 3.0, 'k': 4, 'collision': False},
        'data': {'val_trajectories': 1, 'policy_dt': 0.05, 'stride': 5},
        'noise': {'mode': 'none'},
        'training': {'epochs': 60, 'batch_size': 128, 'lr': 0.01, 'lr_min': 0.001, 'threads': 1},
        'selection': {'every': 0},
    }
    trainer = Trainer(normalise_config(raw), data, str(tmp_path / 'run'), progress=False, log=lambda *a: None)
    assert trainer.ratio == 5 and trainer.dt == 0.05
    trainer.run()
    policy = load_policy(tmp_path / 'run' / 'policy.pt')
    assert policy.dt == 0.05
    prov = policy.meta['provenance']
    assert prov['data_dt'] == 0.01 and prov['dt_ratio'] == 5 and prov['config']['data']['policy_dt'] == 0.05
    s = trainer.train  # phase 0 only (stride 5): exact 0.05 s holds
    want = linear(s.Y.double().numpy(), s.mask.double().numpy())
    got = policy(s.Y.numpy(), s.mask.numpy())
    rms = np.sqrt(np.mean((got - want) ** 2)) / np.sqrt(np.mean(want**2))
    assert rms < 0.1, rms


def test_trainer_selection_rolls_out_at_the_policy_dt_and_bad_policy_dt_exits_2(tmp_path, capsys):
    import torch  # noqa: F401  (a broken install must fail, not skip)

    from training.learning.config import normalise_config
    from training.learning.trainer import Trainer
    from training.train import main as train_main

    data, _ = _held_teacher_data(tmp_path, steps=8)  # 41 frames at 0.01 s
    raw = {
        'scenario': 'flock2d',
        'seed': 3,
        'policy': {'hidden': 8, 'd_cr': 3.0, 'k': 4},
        'data': {'val_trajectories': 1, 'policy_dt': 0.05},
        'training': {'epochs': 1, 'threads': 1},
        'selection': {'every': 1, 'trajectories': 1},
    }
    trainer = Trainer(normalise_config(raw), data, str(tmp_path / 'run'), progress=False, log=lambda *a: None)
    seen = {}
    with spy_on_selection_rollouts(lambda z0, steps, dt: seen.update(steps=steps, dt=dt)):
        trainer.run()
    assert seen == {'steps': 8, 'dt': 0.05}  # 41 frames at 0.01 s = 9 frames at 0.05 s
    cfg = tmp_path / 'cfg.yaml'
    raw['data']['policy_dt'] = 0.025
    cfg.write_text(yaml.safe_dump(raw))
    assert (
        train_main(['--config', str(cfg), '--data', data, '--out', str(tmp_path / 'r2'), '--no-progress'])
        == 2
    )
    err = capsys.readouterr().err
    assert 'data.policy_dt' in err and '0.025' in err and 'whole multiple' in err
    raw['data']['policy_dt'] = 'fast'
    cfg.write_text(yaml.safe_dump(raw))
    assert (
        train_main(['--config', str(cfg), '--data', data, '--out', str(tmp_path / 'r3'), '--no-progress'])
        == 2
    )
    assert 'data.policy_dt' in capsys.readouterr().err


# --- the shipped 20 Hz policy and the realtime defaults ----------------------------------
def test_shipped_20hz_policy_rolls_out_at_dt_005_from_held_out_starts():
    import torch  # noqa: F401  (a broken install must fail, not skip)

    from knode_swarm_ros.core import amd, avd, load_policy, rollout, shipped_policy_path
    from knode_swarm_ros.core.geometry import min_pair_distance
    from knode_swarm_ros.core.groundtruth.tanner import initial_states

    policy = load_policy(shipped_policy_path('flock2d_20hz'), expect={'scenario': 'flock2d', 'dt': 0.05})
    prov = policy.meta['provenance']
    assert prov['data_dt'] == 0.01 and prov['dt_ratio'] == 5 and prov['config']['data']['policy_dt'] == 0.05
    # starts drawn like the data (paper disk, 10 robots) from a seed the data never used
    z0 = initial_states(np.random.default_rng(20261130), 4, 10, min_separation=0.3)
    states = rollout(policy, z0, 400, 'flock2d', policy.d_cr, policy.k, policy.tau, policy.dt)  # 20 s
    assert states.shape == (4, 401, 10, 4) and np.all(np.isfinite(states))
    # each step is an exact zero-order hold of 0.05 s: x1 - x0 = v0 dt + (v1 - v0) dt / 2
    dx, dv = states[:, 1:, :, :2] - states[:, :-1, :, :2], states[:, 1:, :, 2:] - states[:, :-1, :, 2:]
    np.testing.assert_allclose(dx, states[:, :-1, :, 2:] * 0.05 + dv * 0.025, atol=1e-12)
    start = avd(states[:, 0, :, 2:])
    final = avd(states[:, -10:, :, 2:]).mean(axis=1)
    assert np.all(final < 0.25) and np.all(final < start / 5), (start, final)  # flocked (measured ~0.12)
    assert np.all(min_pair_distance(states[:, 20:, :, :2]) > 0.3)  # no collision after 1 s
    assert np.all(np.abs(amd(states[:, -10:, :, :2]).mean(axis=1) - 0.73) < 0.15)


def test_realtime_defaults_pick_the_policy_of_the_rate(tmp_path):
    import torch  # noqa: F401  (a broken install must fail, not skip)

    from knode_swarm_ros.core import shipped_policy_path
    from knode_swarm_ros.logic.agent.control_period import shipped_policy_for_rate
    from knode_swarm_ros.nodes import swarm

    assert shipped_policy_for_rate('flock2d', 20.0) == (shipped_policy_path('flock2d_20hz'), True)
    assert shipped_policy_for_rate('flock2d', 100.0) == (shipped_policy_path('flock2d'), True)
    assert shipped_policy_for_rate('flock2d', 10.0) == (
        shipped_policy_path('flock2d'),
        False,
    )  # none shipped: warns
    config = yaml.safe_load(
        open(os.path.join(os.path.dirname(__file__), '..', 'config', 'agent_flock2d.yaml'))
    )['/**']['ros__parameters']
    assert config['mode'] == 'realtime' and config['policy'] == '' and config['control_rate'] == 20.0
    from knode_swarm_ros.nodes.agent.plumbing import load_agent_policy

    assert (
        load_agent_policy('', config['scenario'], 0, 0.0, -1, 0.0, control_rate=config['control_rate']).dt
        == 0.05
    )
    assert load_agent_policy('', 'flock2d', 0, 0.0, -1, 0.0).dt == 0.01  # lockstep
    record = str(tmp_path / 'r.npz')
    plans = {
        mode: swarm.plan_run(
            swarm.build_parser().parse_args(
                ['--mode', mode, '--record', record, '--log-dir', str(tmp_path / mode)]
            )
        )
        for mode in ('realtime', 'lockstep')
    }
    assert plans['realtime'].policy == str(shipped_policy_path('flock2d_20hz').resolve())
    assert plans['realtime'].dt == 0.05  # the simulator steps at the policy's dt
    assert (
        plans['lockstep'].policy == str(shipped_policy_path('flock2d').resolve())
        and plans['lockstep'].dt == 0.01
    )
    args = swarm.build_parser().parse_args(
        [
            '--mode',
            'realtime',
            '--rate',
            '50',
            '--rate-check',
            'refuse',
            '--record',
            record,
            '--log-dir',
            str(tmp_path / 'r50'),
        ]
    )
    plan = swarm.plan_run(args)
    assert plan.policy == str(shipped_policy_path('flock2d').resolve())
    agent = swarm.node_commands(plan)['agent_0']
    params = yaml.safe_load(open(agent[agent.index('--params-file') + 1]))['/**']['ros__parameters']
    assert params['control_rate'] == 50.0 and params['rate_check'] == 'refuse'


def test_phases_and_multi_step_windows_step_at_the_policy_dt(tmp_path):
    from training.learning.config import normalise_config
    from training.learning.period import phases
    from training.learning.trainer import Trainer

    states = np.arange(2 * 7, dtype=float).reshape(2, 7, 1, 1)
    np.testing.assert_array_equal(
        phases(states, 3)[..., 0, 0], [[0, 3], [7, 10], [1, 4], [8, 11], [2, 5], [9, 12]]
    )
    assert phases(states, 1) is states
    data, _ = _held_teacher_data(tmp_path, steps=8)  # 41 frames at 0.01 s, 4 train trajectories
    raw = {
        'scenario': 'flock2d',
        'seed': 3,
        'policy': {'hidden': 8, 'd_cr': 3.0, 'k': 4},
        'data': {'val_trajectories': 1, 'policy_dt': 0.05},
        'training': {'objective': 'multi_step', 'threads': 1},
        'multistep': {'horizons': [3], 'epochs': [1], 'windows_per_epoch': 4, 'batch_windows': 2},
        'selection': {'every': 0},
    }
    trainer = Trainer(normalise_config(raw), data, str(tmp_path / 'run'), progress=False, log=lambda *a: None)
    assert trainer.objective.dt == 0.05
    np.testing.assert_array_equal(
        trainer.objective.windows.states.numpy(), phases(trainer.split['train'], 5).astype(np.float32)
    )
    assert trainer.objective.windows.states.shape[:2] == (3 * 5, 8)
    trainer.run()
    from knode_swarm_ros.core import load_policy

    assert load_policy(tmp_path / 'run' / 'policy.pt').dt == 0.05


def test_choosing_the_shipped_policy_for_a_rate_imports_no_torch():
    """An onnxruntime robot picks its realtime policy from knode.json alone (torch blocked)."""
    import subprocess
    import sys

    code = (
        "import sys; sys.modules['torch'] = None\n"
        'from knode_swarm_ros.logic.agent.control_period import shipped_policy_for_rate\n'
        "path, matched = shipped_policy_for_rate('flock2d', 20.0)\n"
        'print(path.name, matched)'
    )
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ['flock2d_20hz.pt', 'True']
