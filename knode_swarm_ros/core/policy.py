"""The KNODE single-robot controller as a ``torch.nn.Module``.

``u(Y, mask) = clip(u_theta(features(Y, mask)) + collision + wall, -limit, limit)``

* ``u_theta``: one hidden layer (128 tanh units by default) on features of the neighbour
  matrix; ``frame='relative'`` (default) feeds neighbour states relative to the robot plus
  the mask (translation invariant; the own position is kept only where walls make absolute
  position matter), ``frame='absolute'`` feeds the paper's raw masked Y. That is
  ``encoder='flat'`` (default): an MLP over the k rows flattened. ``encoder='set'`` is a
  permutation-invariant neighbour encoder (:mod:`.set_encoder`) whose weights do not depend on
  k, so a policy learnt with a small k runs with a larger one; ``encoder='equivariant'``
  (:mod:`.equivariant_encoder`) is one too, and exactly rotation-equivariant: pairwise terms
  along the directions the robots define; with ``axes=True`` its pair terms also see the
  coordinate axes, for laws that rotations change (a room whose vertical is special); with
  ``rank=R`` they also see each neighbour's rank by distance, up to R (topological laws).
* ``symmetric=True`` averages ``u_theta`` over the half turns about the coordinate axes
  (:func:`half_turns`): the network is then exactly equivariant under them. Training data
  rotated at random teach a network the symmetry only approximately, and a constant left over
  in a per-neighbour term grows with the neighbour count: a denser swarm than the data then
  drifts as a whole. The average of a constant over the half turns is zero. ``symmetric='z'``
  (3D; or ``'x'``, ``'y'``) averages over the identity and the half turn about that axis only:
  a law that swirls one way about the vertical keeps its sense (the half turns about x and y
  reverse it), but a constant along z survives that average. ``inversion=True`` (3D) adds the
  point inversion p -> -p (u(-Y) = -u(Y)), which keeps every sense of rotation and averages any
  constant to zero: the parity the equivariant encoder has without the axes.
* knowledge terms from :mod:`knode_swarm_ros.core.knowledge`, with trainable gains;
  ``potential='paper'`` (default: the paper's 1/d^2 potential of the closest neighbour, cut at
  d0) or ``'continuous'`` (vanishing continuously at d0, summed over neighbours).
* ``speed`` / ``turn_limit`` (heading states only): the command keeps a set speed and turns the
  own heading by at most ``turn_limit`` per step towards the network's direction
  (:mod:`.steering`: constant-speed laws such as Vicsek's or Couzin's); unset by default.
* saturation per axis at ``command_limit`` as the last operation (docs/DESIGN.md: real
  actuators saturate, and a zero-order hold of an unbounded repulsion is unstable).

The forward signature is the policy file contract: ``forward(Y [B, k, d], mask [B, k]) -> [B, m]``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any, Dict, List, Optional, Union

import torch
from torch import Tensor, nn

from .equivariant_encoder import EquivariantEncoder
from .knowledge import (
    AvoidanceGain,
    collision_avoidance,
    continuous_collision_avoidance,
    continuous_wall_avoidance,
    wall_avoidance,
)
from .scenarios import _is_number, get_scenario, scenario_ref
from .set_encoder import NeighbourSetEncoder
from .steering import FREE_SPEED, FREE_TURN, steer

__all__ = ['PolicyConfig', 'KNODEPolicy', 'DEFAULTS', 'ROW_FREE_ENCODERS', 'TURN_AXES', 'half_turns']

#: The encoders with no weight per neighbour row (permutation invariant: the rows are summed),
#: by ``policy.encoder`` name; ``flat`` (the paper's MLP over the k rows) is the other one.
ROW_FREE_ENCODERS = {'set': NeighbourSetEncoder, 'equivariant': EquivariantEncoder}


#: ``symmetric`` values that name one axis (3D): the identity and the half turn about it alone.
TURN_AXES = ('x', 'y', 'z')


def half_turns(position_dim: int, about: Optional[str] = None) -> List[List[float]]:
    """The identity and the rotations by 180 degrees about the coordinate axes, as the signs of
    their diagonal matrices ``[G][position_dim]``: a group of rotations that maps the arena
    ``[-w, w]^d`` onto itself and averages any constant vector to zero (2D: the half turn
    about the origin; 3D: the three half turns about x, y and z). ``about`` (3D, one of
    :data:`TURN_AXES`): the identity and the half turn about that axis only, the subgroup that
    keeps a sense of rotation about it (a half turn about x or y reverses a swirl about z)."""
    if position_dim == 2 and about is None:
        return [[1.0, 1.0], [-1.0, -1.0]]
    if position_dim == 3:
        if about is None:
            return [[1.0, 1.0, 1.0], [1.0, -1.0, -1.0], [-1.0, 1.0, -1.0], [-1.0, -1.0, 1.0]]
        if about in TURN_AXES:
            return [[1.0, 1.0, 1.0], [1.0 if axis == about else -1.0 for axis in TURN_AXES]]
    raise ValueError(f'half_turns: no half turns about {about!r} in {position_dim} dimensions')


@dataclass
class PolicyConfig:
    """Everything that defines a policy's architecture and its information network.

    ``collision_a``/``wall_a`` are the fixed gain offsets a, ``*_phi`` the initial phi,
    ``*_d0`` the potentials' ranges. ``wall`` is used only by scenarios with a box.
    ``position_scale``/``velocity_scale`` divide the network's input entries (positions; the
    rest of the state: velocities, headings) so that they reach the tanh units at O(1) whatever
    the swarm's units; the knowledge terms see the raw states.
    """

    scenario: str
    k: int = 6
    d_cr: float = 5.0
    tau: int = 0
    hidden: int = 128
    frame: str = 'relative'
    encoder: str = 'flat'
    symmetric: Union[bool, str] = False
    command_limit: float = 10.0
    collision: bool = True
    potential: str = 'paper'
    collision_a: float = 0.0
    collision_phi: float = 1.0
    collision_d0: float = 1.0
    wall: bool = True
    wall_a: float = 0.0
    wall_phi: float = 1.0
    wall_d0: float = 1.0
    position_scale: float = 1.0
    velocity_scale: float = 1.0
    speed: Optional[float] = None
    turn_limit: Optional[float] = None
    axes: bool = False
    inversion: bool = False
    rank: int = 0
    extra: Dict[str, Any] = field(default_factory=dict)

    def __post_init__(self):
        spec = get_scenario(self.scenario)  # raises on an unknown name
        steered = self.speed is not None or self.turn_limit is not None
        checks = {
            'k': self.k >= 1,
            'd_cr': self.d_cr > 0,
            'tau': self.tau >= 0,
            'hidden': self.hidden >= 1,
            'frame': self.frame in ('relative', 'absolute'),
            # the row-free encoders are built on offsets to the robot: they have no absolute frame
            'encoder': self.encoder == 'flat'
            or (self.encoder in ROW_FREE_ENCODERS and self.frame == 'relative'),
            'symmetric': isinstance(self.symmetric, bool)
            or (self.symmetric in TURN_AXES and spec.position_dim == 3),
            # the other encoders see the offsets' coordinates already
            'axes': self.axes is False or (self.axes is True and self.encoder == 'equivariant'),
            'rank': type(self.rank) is int
            and (self.rank == 0 or (self.rank > 0 and self.encoder == 'equivariant')),
            # in 2D the half turn about the origin is the inversion already
            'inversion': self.inversion is False or (self.inversion is True and spec.position_dim == 3),
            'potential': self.potential in ('paper', 'continuous'),
            'command_limit': self.command_limit > 0,
            'collision_d0': self.collision_d0 > 0,
            'wall_d0': self.wall_d0 > 0,
            'collision_a': self.collision_a >= 0,
            'wall_a': self.wall_a >= 0,
            'position_scale': self.position_scale > 0,
            'velocity_scale': self.velocity_scale > 0,
            'speed': self.speed is None or (_is_number(self.speed) and self.speed > 0),
            'turn_limit': self.turn_limit is None
            or (_is_number(self.turn_limit) and 0 < self.turn_limit <= FREE_TURN),
        }
        for name, ok in checks.items():
            if not ok:
                raise ValueError(f'policy config: invalid {name} = {getattr(self, name)!r}')
        if steered and spec.heading is None:
            name = 'speed' if self.speed is not None else 'turn_limit'
            raise ValueError(
                f'policy config: invalid {name} = {getattr(self, name)!r}: a set speed and turn limit '
                f'need a heading in the state (position_heading), not {spec.state}'
            )


# The paper's settings per scenario (flock2d: lambda = a + phi^2 for collisions;
# boids3d: lambda = phi^2 for collisions and walls, tau = 1, d_cr = 2). phi starts at 1,
# never 0: phi = 0 is a stationary point of phi^2, where the gain would never train.
DEFAULTS: Dict[str, Dict[str, Any]] = {
    'flock2d': dict(
        k=6,
        d_cr=5.0,
        tau=0,
        command_limit=10.0,
        collision_a=1.0,
        collision_phi=1.0,
        collision_d0=1.0,
        wall=False,
    ),
    'boids3d': dict(
        k=6,
        d_cr=2.0,
        tau=1,
        command_limit=10.0,
        collision_a=0.0,
        collision_phi=1.0,
        collision_d0=1.0,
        wall=True,
        wall_a=0.0,
        wall_phi=1.0,
        wall_d0=1.0,
    ),
}


class KNODEPolicy(nn.Module):
    """Hybrid controller: a small network plus avoidance knowledge, saturated per axis.

    Build with ``KNODEPolicy(PolicyConfig('flock2d', **DEFAULTS['flock2d']))``.
    """

    def __init__(self, config: PolicyConfig):
        super().__init__()
        spec = get_scenario(config.scenario)
        self.config = config
        self.k = config.k
        self.state_dim = spec.state_dim
        self.position_dim = spec.position_dim
        self.command_dim = spec.command_dim
        self.relative = config.frame == 'relative'
        self.keep_own_position = not spec.translation_invariant
        self.command_limit = float(config.command_limit)
        self.use_collision = bool(config.collision)
        self.collision_d0 = float(config.collision_d0)
        self.use_wall = bool(config.wall) and spec.box is not None
        self.wall_d0 = float(config.wall_d0)
        # a double integrator cannot stop at once: its walls act on the distance left after braking
        self.wall_brake = spec.command == 'acceleration' and spec.velocity is not None
        self.continuous = config.potential == 'continuous'
        self.box = float(spec.box) if spec.box is not None else 0.0
        # unit scales leave the features untouched (the shipped policies' numbers, bit for bit)
        self.scaled = config.position_scale != 1.0 or config.velocity_scale != 1.0
        # plain floats, not a buffer: the state_dict (and files' state) stays the shipped layout
        self.input_scale: List[float] = [float(config.position_scale)] * spec.position_dim + [
            float(config.velocity_scale)
        ] * (spec.state_dim - spec.position_dim)
        if config.encoder in ROW_FREE_ENCODERS:
            self.encoder = ROW_FREE_ENCODERS[config.encoder](
                spec.state_dim,
                spec.position_dim,
                spec.command_dim,
                config.hidden,
                self.keep_own_position,
                reach=config.d_cr / config.position_scale,
                **({'axes': True} if config.axes else {}),
                **({'rank': config.rank} if config.rank else {}),
            )
        else:
            n_in = config.k * spec.state_dim + ((config.k - 1) if self.relative else 0)
            self.net = nn.Sequential(
                nn.Linear(n_in, config.hidden), nn.Tanh(), nn.Linear(config.hidden, spec.command_dim)
            )
        turns = (
            half_turns(spec.position_dim, None if isinstance(config.symmetric, bool) else config.symmetric)
            if config.symmetric is not False
            else [[1.0] * spec.position_dim]
        )
        if config.inversion:  # p -> -p keeps every sense of rotation and averages any constant to zero
            turns = turns + [[-s for s in t] for t in turns]
        self.symmetric = len(turns) > 1
        # the signs of each element on every command and state entry (positions, then velocities
        # or headings), flattened row by row: ONNX export takes flat lists of constants only
        self.turn_count = len(turns)
        self.command_signs: List[float] = [s for t in turns for s in t]
        self.state_signs: List[float] = [s for t in turns for s in t * (spec.state_dim // spec.position_dim)]
        self.collision_gain = AvoidanceGain(config.collision_a, config.collision_phi)
        self.wall_gain = AvoidanceGain(config.wall_a, config.wall_phi)
        self.steered = config.speed is not None or config.turn_limit is not None
        self.speed = float(config.speed) if config.speed is not None else FREE_SPEED
        self.turn_limit = float(config.turn_limit) if config.turn_limit is not None else FREE_TURN

    def scale_inputs(self, Y: Tensor) -> Tensor:
        if self.scaled:
            return Y / torch.tensor(self.input_scale, dtype=Y.dtype, device=Y.device)
        return Y

    def features(self, Y: Tensor, mask: Tensor) -> Tensor:
        """Flat network input ``[B, F]`` from ``Y [B, k, d]`` and ``mask [B, k]``."""
        m = mask.to(Y.dtype).unsqueeze(-1)
        Y = self.scale_inputs(Y)
        if not self.relative:
            return (Y * m).flatten(1)
        own = Y[:, 0, :]
        if not self.keep_own_position:
            own = torch.cat(
                [torch.zeros_like(own[:, : self.position_dim]), own[:, self.position_dim :]], dim=1
            )
        rel = (Y[:, 1:, :] - Y[:, :1, :]) * m[:, 1:, :]
        return torch.cat([own, rel.flatten(1), mask[:, 1:].to(Y.dtype)], dim=1)

    def knowledge(self, Y: Tensor, mask: Tensor) -> Tensor:
        """Sum of the knowledge terms ``[B, m]``."""
        out = torch.zeros(Y.shape[0], self.command_dim, dtype=Y.dtype, device=Y.device)
        if self.use_collision:
            if self.continuous:
                out = out + continuous_collision_avoidance(
                    Y, mask, self.position_dim, self.collision_gain(), self.collision_d0
                )
            else:
                out = out + collision_avoidance(
                    Y, mask, self.position_dim, self.collision_gain(), self.collision_d0
                )
        if self.use_wall:
            own = Y[:, 0, : self.position_dim]
            velocity: Optional[Tensor] = None
            if self.wall_brake:
                velocity = Y[:, 0, self.position_dim : 2 * self.position_dim]
            if self.continuous:
                out = out + continuous_wall_avoidance(
                    own, self.box, self.wall_gain(), self.wall_d0, velocity=velocity, limit=self.command_limit
                )
            else:
                out = out + wall_avoidance(
                    own, self.box, self.wall_gain(), self.wall_d0, velocity=velocity, limit=self.command_limit
                )
        return out

    def raw_network(self, Y: Tensor, mask: Tensor) -> Tensor:
        """The network alone ``[B, m]``, before any symmetrisation."""
        if hasattr(self, 'encoder'):  # resolved when scripted: one branch per policy
            return self.encoder(self.scale_inputs(Y), mask)
        return self.net(self.features(Y, mask))

    def network(self, Y: Tensor, mask: Tensor) -> Tensor:
        """The learnt part ``u_theta [B, m]``: with ``symmetric``, the mean over the half turns g
        of ``g u(g Y)``."""
        if not self.symmetric:
            return self.raw_network(Y, mask)
        G, d = self.turn_count, Y.shape[2]
        state_signs = torch.tensor(self.state_signs, dtype=Y.dtype, device=Y.device).reshape(G, d)
        command_signs = torch.tensor(self.command_signs, dtype=Y.dtype, device=Y.device).reshape(G, -1)
        # one turn at a time: a batch of G x B rows falls out of the cache (a training step of the
        # set encoder in 3D takes twice as long)
        total = self.raw_network(Y, mask)  # the identity comes first
        for g in range(1, G):
            total = total + self.raw_network(Y * state_signs[g], mask) * command_signs[g]
        return total / G

    def forward(self, Y: Tensor, mask: Tensor) -> Tensor:
        """Command ``[B, m]`` for neighbour matrices ``Y [B, k, d]`` with ``mask [B, k]``."""
        u = self.network(Y, mask) + self.knowledge(Y, mask)
        if self.steered:
            u = steer(u, Y[:, 0, self.position_dim :], self.speed, self.turn_limit)
        return torch.clamp(u, -self.command_limit, self.command_limit)

    def metadata(self, dt: Optional[float] = None) -> Dict[str, Any]:
        """The ``knode.json`` object of docs/DESIGN.md for this policy."""
        spec = get_scenario(self.config.scenario)
        meta = {
            'format': 'knode-policy/1',
            'scenario': spec.name if spec.shipped else spec.to_dict(),
            'state_dim': spec.state_dim,
            'command_dim': spec.command_dim,
            'command': spec.command,
            'k': self.config.k,
            'd_cr': float(self.config.d_cr),
            'tau': int(self.config.tau),
            'dt': float(spec.dt if dt is None else dt),
            'state_layout': list(spec.state_layout),
            'command_limit': self.command_limit,
            'frame': self.config.frame,
            'encoder': self.config.encoder,
            'hidden': self.config.hidden,
            'config': {k: v for k, v in asdict(self.config).items() if k != 'extra'},
        }
        # a Scenario object would turn into its fields (arena as a float), which no loader reads
        meta['config']['scenario'] = scenario_ref(self.config.scenario)
        meta.update(self.config.extra)
        return meta
