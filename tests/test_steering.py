"""Constant-speed steering (core.steering; ``policy.speed``, ``policy.turn_limit``).

* ``steer`` on hand-built cases with known answers (within the limit, beyond it, exactly behind,
  no heading, unbounded, free speed), and its invariants on random inputs in 2D and 3D: the set
  speed exactly, the turn below the limit, equivariance under rotations, finite gradients;
* a steered policy: commands of the set speed within the limit of the own heading; eager ==
  TorchScript bit for bit; the ONNX twin within 1e-5; knode.json records both fields; unset,
  the policy is today's (same parameters, same commands);
* the config refuses them for a scenario without headings and bad values, naming the field;
* the derivation: a constant-speed track gives its speed and 1.5 x its largest turn; varying
  speeds, turns near a half turn and states without a heading leave them unset.
"""

import json
import math
import os

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from knode_swarm_ros.core import DEFAULTS, KNODEPolicy, PolicyConfig, export_policy, load_policy, load_runtime
from knode_swarm_ros.core.errors import ConfigError
from knode_swarm_ros.core.scenarios import scenario_from_dict
from knode_swarm_ros.core.steering import FREE_SPEED, FREE_TURN, steer
from training.learning.config import load_config, normalise_config, resolve_config
from training.learning.onnx_twin import check_inputs, compare, export_onnx

torch.set_num_threads(1)
pytestmark = pytest.mark.filterwarnings('ignore:`torch.jit.script` is deprecated:DeprecationWarning')
RECIPE = os.path.join(os.path.dirname(__file__), '..', 'config', 'train_custom.yaml')


def angle(a, b):
    """Angles between the rows of ``a`` and ``b`` ``[B]``."""
    cos = (a * b).sum(-1) / (a.norm(dim=-1) * b.norm(dim=-1))
    return torch.arccos(cos.clamp(-1.0, 1.0))


def bounded(angle_, limit):
    x = angle_ / limit
    return limit * x / math.sqrt(1 + x * x)


H = [1.0, 0.0]
# (w, heading, speed, turn_limit, expected command)
CASES = {
    # speed 1 + w along h: straight on at the set speed
    'straight on': ([0.5, 0.0], H, 1.0, 0.2, [1.0, 0.0]),
    # pointing 0.05 rad to the left, limit 1: a turn of about 0.05 (x / sqrt(1 + x^2))
    'small turn': (
        [0.0, math.tan(0.05)],
        H,
        1.0,
        1.0,
        [math.cos(bounded(0.05, 1.0)), math.sin(bounded(0.05, 1.0))],
    ),
    # pointing a quarter turn to the right, limit 0.1: about the limit, never beyond it
    'beyond the limit': (
        [-2.0, -1.0],
        H,
        2.0,
        0.1,
        [2 * math.cos(bounded(math.pi / 2, 0.1)), -2 * math.sin(bounded(math.pi / 2, 0.1))],
    ),
    # pointing exactly behind: no side to turn to, the heading is kept
    'exactly behind': ([-3.0, 0.0], H, 1.0, 0.1, [1.0, 0.0]),
    # the set speed cancelled exactly: pointing nowhere, the heading is kept
    'nowhere': ([-1.0, 0.0], H, 1.0, 0.1, [1.0, 0.0]),
    # a heading that is not unit (noisy input) is normalised first
    'long heading': ([0.0, 0.0], [0.0, 3.0], 1.5, 0.1, [0.0, 1.5]),
    # no heading at all: the direction of w
    'no heading': ([0.0, 2.0], [0.0, 0.0], 1.0, 0.1, [0.0, 1.0]),
    # unbounded: the direction of speed h + w, even a half turn round
    'unbounded': ([-1.0, 1.0], H, 1.0, FREE_TURN, [0.0, 1.0]),
    # free speed: |w| along the bounded direction
    'free speed': (
        [0.0, 3.0],
        H,
        FREE_SPEED,
        0.1,
        [3 * math.cos(bounded(math.pi / 2, 0.1)), 3 * math.sin(bounded(math.pi / 2, 0.1))],
    ),
}


@pytest.mark.parametrize('case', sorted(CASES))
def test_steer_known_answers(case):
    w, h, speed, limit, expected = CASES[case]
    got = steer(torch.tensor([w], dtype=torch.float64), torch.tensor([h], dtype=torch.float64), speed, limit)
    torch.testing.assert_close(got, torch.tensor([expected], dtype=torch.float64), atol=1e-9, rtol=0)


def random_rotation(dims, seed):
    q, r = np.linalg.qr(np.random.default_rng(seed).normal(size=(dims, dims)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return torch.tensor(q)


@settings(max_examples=40, deadline=None)
@given(
    dims=st.sampled_from([2, 3]),
    seed=st.integers(0, 10_000),
    speed=st.floats(0.1, 5.0),
    limit=st.floats(0.01, 3.0),
    scale=st.floats(0.01, 10.0),
)
def test_steer_invariants(dims, seed, speed, limit, scale):
    g = torch.Generator().manual_seed(seed)
    w = scale * torch.randn(64, dims, generator=g, dtype=torch.float64)
    h = torch.randn(64, dims, generator=g, dtype=torch.float64)
    u = steer(w, h, speed, limit)
    torch.testing.assert_close(u.norm(dim=-1), torch.full((64,), speed, dtype=torch.float64))
    assert (angle(u, h) <= limit + 1e-9).all()
    # it turns towards where the robot points: never farther from it than the heading was
    target = w + speed * h / h.norm(dim=-1, keepdim=True)
    assert (angle(u, target) <= angle(h, target) + 1e-9).all()
    R = random_rotation(dims, seed)
    torch.testing.assert_close(steer(w @ R.T, h @ R.T, speed, limit), u @ R.T)


@pytest.mark.parametrize('dims', [2, 3])
def test_steer_gradients_are_finite_everywhere(dims):
    h = torch.zeros(4, dims)
    h[:, 0] = 1.0
    h[3] = 0.0  # no heading
    w = torch.zeros(4, dims)
    w[1, 0] = -1.0  # cancels the set speed: pointing nowhere
    w[2, 0] = -5.0  # exactly behind
    w.requires_grad_(True)
    steer(w, h, 1.0, 0.2).sum().backward()
    assert torch.isfinite(w.grad).all()
    w2 = torch.tensor([[0.0, 1.0] + [0.0] * (dims - 2)], requires_grad=True)
    steer(w2, h[:1], 1.0, 0.1)[0, 1].backward()  # far beyond the limit: still a slope
    assert w2.grad.abs().sum() > 0


# --- the policy ------------------------------------------------------------------------------------


def steered_policy(encoder='flat', seed=0, **fields):
    torch.manual_seed(seed)
    base = {**DEFAULTS['boids3d'], 'encoder': encoder, 'speed': 1.2, 'turn_limit': 0.2, **fields}
    return KNODEPolicy(PolicyConfig('boids3d', **base)).eval()


def heading_batch(B=64, seed=0):
    g = torch.Generator().manual_seed(seed)
    Y = torch.randn(B, 6, 6, generator=g)
    Y[..., 3:] = Y[..., 3:] / Y[..., 3:].norm(dim=-1, keepdim=True)
    return Y, torch.ones(B, 6)


@pytest.mark.parametrize('encoder', ['flat', 'equivariant'])
def test_a_steered_policy_keeps_the_speed_and_the_turn_limit(encoder):
    policy = steered_policy(encoder)
    Y, mask = heading_batch()
    with torch.no_grad():
        u = policy(Y, mask)
        torch.testing.assert_close(u.norm(dim=-1), torch.full((64,), 1.2), atol=1e-5, rtol=0)
        assert (angle(u.double(), Y[:, 0, 3:].double()) <= 0.2 + 1e-5).all()
        assert torch.equal(torch.jit.script(policy)(Y, mask), u)


def test_an_unsteered_policy_is_unchanged_by_the_fields():
    torch.manual_seed(0)
    plain = KNODEPolicy(PolicyConfig('boids3d', **DEFAULTS['boids3d'])).eval()
    steered = steered_policy(speed=None, turn_limit=None)
    assert plain.state_dict().keys() == steered.state_dict().keys()
    steered.load_state_dict(plain.state_dict())
    Y, mask = heading_batch(seed=1)
    with torch.no_grad():
        assert torch.equal(steered(Y, mask), plain(Y, mask))
    assert 'speed' not in DEFAULTS['boids3d'] and plain.config.speed is None


@pytest.mark.parametrize('encoder', ['flat', 'equivariant'])
def test_steered_files_record_the_fields_and_the_onnx_twin_agrees(tmp_path, encoder):
    policy = steered_policy(encoder, seed=2)
    pt = tmp_path / 'steered.pt'
    export_policy(policy, pt, policy.metadata())
    loaded = load_policy(pt)
    assert loaded.meta['config']['speed'] == 1.2 and loaded.meta['config']['turn_limit'] == 0.2
    Y, mask = heading_batch(seed=3)
    with torch.no_grad():
        assert torch.equal(loaded.module(Y, mask), policy(Y, mask))
    export_onnx(pt)
    ts, ox = load_runtime(pt, 'torchscript'), load_runtime(pt, 'onnxruntime')
    table = check_inputs(ts.meta, seed=5)
    table['unit headings'] = (Y.numpy(), mask.numpy())
    errors = compare(ts, ox, table)
    assert max(errors.values()) <= 1e-5, errors


@pytest.mark.parametrize(
    'scenario, fields, named',
    [
        ('flock2d', {'speed': 1.0}, 'policy.speed'),
        ('flock2d', {'turn_limit': 0.1}, 'policy.turn_limit'),
        ('boids3d', {'speed': -1.0}, 'policy.speed'),
        ('boids3d', {'speed': True}, 'policy.speed'),
        ('boids3d', {'speed': float('inf')}, 'policy.speed'),
        ('boids3d', {'turn_limit': 0.0}, 'policy.turn_limit'),
        ('boids3d', {'turn_limit': 4.0}, 'policy.turn_limit'),
        ('boids3d', {'turn_limit': 'fast'}, 'policy.turn_limit'),
    ],
)
def test_the_config_refuses_bad_steering_naming_the_field(scenario, fields, named):
    with pytest.raises(ConfigError, match=named.replace('.', r'\.')):
        normalise_config({'scenario': scenario, 'policy': fields})


# --- the derivation --------------------------------------------------------------------------------


def heading_scenario():
    return scenario_from_dict(
        dict(name='circle', dimensions=2, state='position_heading', command='velocity', dt=0.1, arena=None)
    )


def circling(speeds, turn):
    """``[1, T, 3, 4]``: three robots 2 m apart moving at ``speeds[t]`` (m/s), turning their
    heading by ``turn`` rad every step of 0.1 s; the heading is the last step's direction."""
    T = len(speeds) + 1
    heading_angle = turn * np.arange(T)
    z = np.zeros((1, T, 3, 4))
    for t in range(1, T):
        step = 0.1 * speeds[t - 1] * np.array([np.cos(heading_angle[t - 1]), np.sin(heading_angle[t - 1])])
        z[0, t, :, :2] = z[0, t - 1, :, :2] + step
    z[0, :, :, 0] += 2.0 * np.arange(3)
    # the heading at t is the direction of the step that led to it (the step before the first: turn back)
    z[0, :, :, 2] = np.cos(heading_angle - turn)[:, None]
    z[0, :, :, 3] = np.sin(heading_angle - turn)[:, None]
    return z


def resolve(tracks):
    ref = json.dumps(heading_scenario().to_dict(), sort_keys=True)
    return resolve_config(load_config(RECIPE), [tracks], ref, 0.1)


def test_constant_speed_headings_derive_the_speed_and_the_turn_limit():
    cfg, derived = resolve(circling([0.8] * 40, 0.05))
    assert cfg['policy']['speed'] == pytest.approx(0.8)
    assert cfg['policy']['turn_limit'] == pytest.approx(1.5 * 0.05, rel=1e-5)
    assert 'constant speed' in derived['policy.speed']['how']
    assert 'largest turn' in derived['policy.turn_limit']['how']


@pytest.mark.parametrize(
    'speeds, turn, why',
    [
        (list(np.linspace(0.5, 1.5, 40)), 0.05, 'speeds vary'),  # boids-like: the speed is free
        ([1.0] * 40, 2.5, 'unbounded'),  # 1.5 x the largest turn reaches pi
    ],
)
def test_what_the_data_do_not_show_stays_unset(speeds, turn, why):
    cfg, derived = resolve(circling(speeds, turn))
    if why == 'unbounded':
        assert cfg['policy']['speed'] == pytest.approx(1.0) and cfg['policy']['turn_limit'] is None
        assert 'unbounded' in derived['policy.turn_limit']['how']
    else:
        assert cfg['policy']['speed'] is None and cfg['policy']['turn_limit'] is None
        assert why in derived['policy.speed']['how']


def test_states_without_a_heading_leave_steering_unset():
    spec = scenario_from_dict(
        dict(name='p', dimensions=2, state='position', command='velocity', dt=0.1, arena=None)
    )
    tracks = circling([1.0] * 20, 0.05)[..., :2]
    cfg, derived = resolve_config(
        load_config(RECIPE), [tracks], json.dumps(spec.to_dict(), sort_keys=True), 0.1
    )
    assert cfg['policy']['speed'] is None and cfg['policy']['turn_limit'] is None
    assert 'no heading' in derived['policy.speed']['how']


def test_an_explicit_turn_limit_with_the_datas_scenario_is_checked_against_that_scenario():
    """With ``scenario: auto`` (the recipe's) an explicit speed or turn limit is valid or not
    only once the data's scenario is known: accepted for heading data (used as given, the other
    still derived), refused for data without a heading, naming the field."""
    pending = load_config(RECIPE, {'policy.turn_limit': 0.15})
    ref = json.dumps(heading_scenario().to_dict(), sort_keys=True)
    cfg, derived = resolve_config(pending, [circling([0.8] * 40, 0.05)], ref, 0.1)
    assert cfg['policy']['turn_limit'] == 0.15 and 'policy.turn_limit' not in derived
    assert cfg['policy']['speed'] == pytest.approx(0.8)
    spec = scenario_from_dict(
        dict(name='p', dimensions=2, state='position', command='velocity', dt=0.1, arena=None)
    )
    with pytest.raises(ConfigError, match=r'turn_limit'):
        resolve_config(
            load_config(RECIPE, {'policy.turn_limit': 0.15}),
            [circling([1.0] * 20, 0.05)[..., :2]],
            json.dumps(spec.to_dict(), sort_keys=True),
            0.1,
        )
    with pytest.raises(ConfigError, match=r'speed'):  # what no scenario accepts: before any training
        resolve_config(load_config(RECIPE, {'policy.speed': 'fast'}), [circling([0.8] * 40, 0.05)], ref, 0.1)
