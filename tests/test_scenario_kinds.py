"""The core maths follow the scenario object, not its name: a first-order 2D scenario and a 3D
double integrator in an arena roll out as computed by hand; the shipped two step as they always did."""

import numpy as np
import pytest

from knode_swarm_ros.core.rollout import rollout, zoh_step
from knode_swarm_ros.core.scenarios import Scenario, get_scenario, scenario_ref

GROUND = Scenario('ground', 2, 'position', 'velocity', 0.25, None)
DRONES = Scenario('drones', 3, 'position_velocity', 'acceleration', 0.5, 6.0)


def towards_neighbours(Y, mask):
    """u = sum of the offsets to the heard neighbours (first order: robots meet)."""
    return ((Y[:, 1:, :2] - Y[:, :1, :2]) * mask[:, 1:, None]).sum(axis=1)


def spring(Y, mask):
    """u = -p (each robot pulled to the origin)."""
    return -Y[:, 0, :3]


def test_first_order_2d_rolls_out_as_computed_by_hand():
    z0 = np.array([[0.0, 0.0], [1.0, 0.0]])
    out = rollout(towards_neighbours, z0, 2, GROUND, d_cr=5.0, k=2, tau=0, dt=0.25, command_limit=None)
    # step 1: u = +-1, p += u / 4; step 2: offset 0.5, u = +-0.5
    expected = [[[0, 0], [1, 0]], [[0.25, 0], [0.75, 0]], [[0.375, 0], [0.625, 0]]]
    np.testing.assert_array_equal(out, expected)
    # the same through a reference: the scenario file's mapping or its canonical text
    np.testing.assert_array_equal(
        rollout(towards_neighbours, z0, 2, scenario_ref(GROUND), 5.0, 2, 0, 0.25, command_limit=None), out
    )


def test_3d_double_integrator_rolls_out_as_computed_by_hand():
    z0 = np.array([[1.0, 0, 0, 0, 0, 0]])
    out = rollout(spring, z0, 2, DRONES.to_dict(), d_cr=1.0, k=1, tau=0, dt=0.5, command_limit=None)
    # a = -p; p += v dt + a dt^2 / 2; v += a dt
    np.testing.assert_allclose(out[1, 0], [0.875, 0, 0, -0.5, 0, 0], rtol=0, atol=1e-15)
    np.testing.assert_allclose(out[2, 0], [0.515625, 0, 0, -0.9375, 0, 0], rtol=0, atol=1e-15)


def old_zoh_step(states, command, name, dt):
    """The shipped scenarios' step as written before scenarios were data (name-based)."""
    new = np.array(states, dtype=np.float64, copy=True)
    c = np.asarray(command, dtype=np.float64)
    if name == 'flock2d':
        v = new[..., 2:4]
        new[..., :2] = new[..., :2] + v * dt + 0.5 * c * dt * dt
        new[..., 2:4] = v + c * dt
        return new
    new[..., :3] = new[..., :3] + c * dt
    speed = np.linalg.norm(c, axis=-1, keepdims=True)
    heading = np.divide(c, speed, out=np.zeros_like(c), where=speed > 0)
    new[..., 3:6] = np.where(speed > 0, heading, new[..., 3:6])
    return new


@pytest.mark.parametrize('name', ['flock2d', 'boids3d'])
def test_shipped_scenarios_step_bit_identically_to_before(name):
    spec = get_scenario(name)
    rng = np.random.default_rng(3)
    z = rng.normal(size=(4, 7, spec.state_dim))
    c = rng.normal(size=(4, 7, spec.command_dim))
    c[0, 0] = 0.0  # a robot that stops keeps its heading
    np.testing.assert_array_equal(zoh_step(z, c, spec, spec.dt), old_zoh_step(z, c, name, spec.dt))


@pytest.mark.parametrize(
    'spec',
    [GROUND, DRONES, Scenario('fish', 3, 'position_heading', 'velocity', 0.1, None)],
    ids=lambda s: s.name,
)
def test_torch_step_equals_numpy_step_for_every_kind(spec):
    torch = pytest.importorskip('torch')
    from knode_swarm_ros.core.rollout import zoh_step_torch

    rng = np.random.default_rng(5)
    z = rng.normal(size=(3, 5, spec.state_dim))
    c = rng.normal(size=(3, 5, spec.command_dim))
    got = zoh_step_torch(torch.from_numpy(z), torch.from_numpy(c), spec, spec.dt).numpy()
    np.testing.assert_allclose(got, zoh_step(z, c, spec, spec.dt), rtol=0, atol=1e-12)


@pytest.mark.parametrize(
    'spec,position,wall',
    [
        (GROUND, [7.5, 0.0], [0.0, 0.0]),  # no arena: no walls, wherever the robot is
        (Scenario('pen', 2, 'position', 'velocity', 0.1, 8.0), [7.5, 0.0], [-8.0, 0.0]),  # 1 / 0.5^3
        (DRONES, [0.0, 0.0, -5.5], [0.0, 0.0, 8.0]),  # the arena's half width, not the paper's cube
    ],
    ids=['no-arena', 'arena-2d', 'arena-3d'],
)
def test_knowledge_terms_follow_the_arena(spec, position, wall):
    torch = pytest.importorskip('torch')
    from knode_swarm_ros.core.policy import KNODEPolicy, PolicyConfig

    policy = KNODEPolicy(PolicyConfig(scenario_ref(spec), k=2, d_cr=3.0, tau=0, wall=True, wall_a=0.0))
    Y = torch.zeros(2, 2, spec.state_dim, dtype=torch.float64)
    Y[:, 0, : spec.dimensions] = torch.tensor(position, dtype=torch.float64)
    Y[1, 1, : spec.dimensions] = Y[1, 0, : spec.dimensions]
    Y[1, 1, 0] += 0.5  # a neighbour 0.5 away along +x: the collision term is always there
    mask = torch.tensor([[1.0, 0.0], [1.0, 1.0]], dtype=torch.float64)
    policy = policy.double()
    out = policy.knowledge(Y, mask).detach().numpy()
    np.testing.assert_allclose(out[0], wall, rtol=1e-12)
    gain = float(policy.collision_gain().detach())
    push = np.zeros(spec.dimensions)
    push[0] = -gain / 0.5**3  # lambda r / d^4, r = -0.5 x
    np.testing.assert_allclose(out[1], np.asarray(wall) + push, rtol=1e-12)
