"""Ten swarm laws of our own, unlike Tanner's flocking and boids, to show the generic recipe
(``config/train_custom.yaml``) on swarms it was not written for (docs/scenarios.md, "Show it on
swarms of your own").

* ``aggregate2d``: first order 2D (``position`` + ``velocity``): aggregation with short-range
  repulsion between robots within ``R``, plus a chiral twist about the neighbours' centroid, so
  the aggregate keeps turning instead of freezing.
* ``flock3d_arena``: 3D double integrator in a box (``position_velocity`` + ``acceleration``,
  arena half width 4 m): an Olfati-Saber-like pair potential with equilibrium spacing, velocity
  consensus, self-propulsion to a cruise speed and spring walls.
* ``mill2d``: 2D D'Orsogna milling (``position_velocity`` + ``acceleration``): self-propulsion
  (alpha - beta |v|^2) v, a Morse potential, and a weak left turn that picks one sense of rotation.
* ``couzin2d``: 2D Couzin zones at constant speed (``position_heading`` + ``velocity``): away from
  robots within ``r_repulse``, else along the headings of those within ``r_orient`` and towards
  those within ``r_attract``, turning at most ``turn_rate``. Added after the recipe was fixed, as
  a law it was never tried on (docs/scenarios.md, "A law the recipe was not tried on").
* ``starlings3d``: 3D, constant speed (``position_heading`` + ``velocity``), topological: each
  robot heeds its ``k`` nearest others whatever their distance (as starlings do), aligning with
  their headings, moving towards their centroid and away from those closer than ``r_repulse``;
  its heading relaxes towards that direction (a share ``blend`` per step, no hard turn limit).
  Added after constant-speed steering was built, as a law neither was tried on.
* ``tank2d``: fish in a tank: 2D at constant speed in an arena (``position_heading`` +
  ``velocity``, half width 3 m): zones as couzin2d's but averaged over the neighbours, and near a
  wall a turn away from it and along it, so that the school circles the tank.
* ``drones3d_arena``: drones with velocity set-points in a room (``position`` + ``velocity``, 3D,
  half width 2.5 m): summed springs to a spacing within reach, a swirl about the vertical through
  the neighbours' centroid, walls that push back, speed capped.
  Both added with the recipe fixed, as the two scenario kinds no law had covered (a heading in an
  arena; first order in 3D and in an arena).
* ``drones3d``: the same drones in open space (no walls): the swirl's preferred vertical is then
  the law's alone, which no scenario field states; added with the recipe fixed, to check that the
  recipe reads it from the data (docs/scenarios.md, "A preferred sense in open space").
* ``roundabout2d``: ground robots in a room (``position_velocity`` + ``acceleration``, 2D, half
  width 4 m): each tracks a velocity field of the room itself (anticlockwise round its centre,
  onto a ring of radius 2 m) and is pushed off robots within 1 m and off the walls: a command
  that depends on where a robot is, not only on its neighbours.
* ``fish3d_tank``: fish in a 3D tank (``position_heading`` + ``velocity``, half width 3 m, 0.8
  m/s): topological alignment with the 4 nearest, towards those of them within 2 m, away from
  any within 0.4 m, and away from walls within 1 m; at most 2.5 rad/s.
  Both added with the recipe fixed and never tuned on, as a blind check on the two scenario
  kinds no law had covered (a double integrator in a 2D arena; a heading in a 3D arena).

Each law is a function ``(states [S, n, d]) -> command [S, n, dim]``; :func:`simulate` integrates
it with the scenario's zero-order hold (:func:`knode_swarm_ros.core.rollout.zoh_step`), the same
step the learnt policy is rolled out with. Units: metres and seconds.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Callable, Dict

import numpy as np

from knode_swarm_ros.core.rollout import zoh_step
from knode_swarm_ros.core.scenarios import Scenario, scenario_from_dict

__all__ = ['Law', 'LAWS', 'RECIPE', 'simulate', 'initial_states']

#: The generic recipe these laws are learnt with.
RECIPE = os.path.normpath(os.path.join(os.path.dirname(__file__), '..', '..', 'config', 'train_custom.yaml'))


DT = 0.05  # s: every law's step (its scenario's dt; couzin2d bounds its turn per step with it)


@dataclass(frozen=True)
class Law:
    """A swarm law: its scenario, its command function and the spread of its starts."""

    name: str
    scenario: Scenario
    command: Callable[[np.ndarray], np.ndarray]
    start_radius_per_sqrt_n: float  # starts uniform in a disc/ball of radius this x sqrt(n)
    start_speed: float  # initial speeds (acceleration laws), uniform directions
    steps: int  # frames per trajectory - 1


def _offsets(p: np.ndarray):
    """``r [S, n, n, dim]`` = p_j - p_i and distances ``[S, n, n]`` (inf on the diagonal)."""
    r = p[:, None, :, :] - p[:, :, None, :]
    d = np.linalg.norm(r, axis=-1)
    n = p.shape[1]
    d[:, np.arange(n), np.arange(n)] = np.inf
    return r, d


def _clip_norm(u: np.ndarray, limit: float) -> np.ndarray:
    norm = np.linalg.norm(u, axis=-1, keepdims=True)
    return u * np.minimum(1.0, limit / np.maximum(norm, 1e-12))


def _left(v: np.ndarray) -> np.ndarray:
    """v turned by +90 degrees (2D)."""
    return np.stack([-v[..., 1], v[..., 0]], axis=-1)


def aggregate2d(
    z: np.ndarray, R: float = 2.0, r0: float = 0.8, a: float = 1.0, twist: float = 0.4
) -> np.ndarray:
    p = z[..., :2]
    r, d = _offsets(p)
    near = d < R
    g = np.where(near, a * (1.0 - (r0 / np.minimum(d, 1e6)) ** 2), 0.0)  # < 0: repulsion inside r0
    count = near.sum(axis=2, keepdims=True)
    # the mean over the neighbours: a denser swarm does not pull harder
    u = (g[..., None] * r / np.where(near, d, 1.0)[..., None]).sum(axis=2) / np.maximum(count, 1)
    centroid_offset = (r * near[..., None]).sum(axis=2) / np.maximum(count, 1)
    u = u + twist * _left(centroid_offset)
    return _clip_norm(u, 1.0)


def flock3d_arena(
    z: np.ndarray,
    w: float = 4.0,
    R: float = 2.5,
    spacing: float = 1.0,
    v0: float = 1.0,
    wall_range: float = 1.2,
) -> np.ndarray:
    p, v = z[..., :3], z[..., 3:]
    r, d = _offsets(p)
    near = d < R
    dn = np.where(near, d, 1.0)
    pair = np.where(near, 1.5 * (dn - spacing) / np.maximum(dn, 0.2) ** 2, 0.0)  # spring, stiff when close
    a = (pair[..., None] * r / dn[..., None]).sum(axis=2)
    a += (
        0.6
        * ((v[:, None, :, :] - v[:, :, None, :]) * near[..., None]).sum(axis=2)
        / np.maximum(near.sum(axis=2, keepdims=True), 1)
    )
    speed2 = (v**2).sum(-1, keepdims=True)
    a += 0.5 * (v0**2 - speed2) * v
    a += 6.0 * _walls_depth(p, w, wall_range)
    return _clip_norm(a, 6.0)


def mill2d(
    z: np.ndarray,
    alpha: float = 1.0,
    beta: float = 0.5,
    c_a: float = 1.0,
    l_a: float = 2.0,
    c_r: float = 2.0,
    l_r: float = 0.5,
    turn: float = 0.3,
) -> np.ndarray:
    p, v = z[..., :2], z[..., 2:]
    r, d = _offsets(p)
    dd = np.where(np.isfinite(d), d, 1.0)
    # -dU/dd of U = c_r exp(-d / l_r) - c_a exp(-d / l_a), along r / d (towards the neighbour)
    force = np.where(np.isfinite(d), c_a / l_a * np.exp(-dd / l_a) - c_r / l_r * np.exp(-dd / l_r), 0.0)
    a = (force[..., None] * r / dd[..., None]).sum(axis=2) / p.shape[1] * 10.0  # per 10 robots
    speed2 = (v**2).sum(-1, keepdims=True)
    a += (alpha - beta * speed2) * v + turn * _left(v)
    return _clip_norm(a, 5.0)


def couzin2d(
    z: np.ndarray,
    speed: float = 1.0,
    r_repulse: float = 0.5,
    r_orient: float = 1.2,
    r_attract: float = 2.5,
    turn_rate: float = 2.0,
    dt: float = DT,
) -> np.ndarray:
    h = z[..., 2:]
    away, along, towards, _, crowded = _zones(z[..., :2], h, r_repulse, r_orient, r_attract)
    want = np.where(crowded, away, h + along + towards)
    return speed * _turn_towards(h, want, turn_rate * dt)


def _zones(p: np.ndarray, h: np.ndarray, r_repulse: float, r_orient: float, r_attract: float):
    """Couzin's zones of each robot (``p, h [S, n, dim]``): the sums of the directions away from
    the robots within ``r_repulse``, of the headings of those from there to ``r_orient`` and of
    the directions to those from there to ``r_attract`` (each ``[S, n, dim]``), the number of
    robots in the latter two zones and whether any is in the first (``[S, n, 1]``)."""
    r, d = _offsets(p)
    rh = r / np.where(np.isfinite(d), d, 1.0)[..., None]
    zor, zoo = d < r_repulse, (d >= r_repulse) & (d < r_orient)
    zoa = (d >= r_orient) & (d < r_attract)
    away = -(rh * zor[..., None]).sum(axis=2)
    along = (h[:, None, :, :] * zoo[..., None]).sum(axis=2)
    towards = (rh * zoa[..., None]).sum(axis=2)
    return away, along, towards, (zoo | zoa).sum(axis=2, keepdims=True), zor.any(axis=2, keepdims=True)


def _turn_towards(h: np.ndarray, want: np.ndarray, most: float) -> np.ndarray:
    """2D unit headings ``h`` turned towards ``want`` by at most ``most`` radians."""
    angle = np.arctan2(h[..., 0] * want[..., 1] - h[..., 1] * want[..., 0], (h * want).sum(-1))
    angle = np.clip(angle, -most, most)[..., None]
    return np.cos(angle) * h + np.sin(angle) * _left(h)


def _walls_depth(p: np.ndarray, w: float, wall_range: float) -> np.ndarray:
    """How deep ``p`` is within ``wall_range`` of the faces of the box [-w, w]^dim, per axis,
    signed away from the wall (0 farther than that)."""
    return np.maximum(0.0, -w + wall_range - p) - np.maximum(0.0, p - (w - wall_range))


def tank2d(
    z: np.ndarray,
    speed: float = 1.0,
    w: float = 3.0,
    r_repulse: float = 0.4,
    r_orient: float = 0.7,
    r_attract: float = 3.0,
    wall_range: float = 1.2,
    turn_rate: float = 3.0,
    dt: float = DT,
) -> np.ndarray:
    p, h = z[..., :2], z[..., 2:]
    away, along, towards, count, crowded = _zones(p, h, r_repulse, r_orient, r_attract)
    # the mean over the zones (a fish heeds its neighbours' directions, not their number)
    want = np.where(crowded, away, h + (along + towards) / np.maximum(count, 1))
    unit = want / np.maximum(np.linalg.norm(want, axis=-1, keepdims=True), 1e-9)
    push = _walls_depth(p, w, wall_range) / wall_range  # 0 to 1 within wall_range
    # near a wall a robot turns away from it and along it, to its left: the school circles
    # anticlockwise
    want = unit + 6.0 * (push - _left(push))
    return speed * _turn_towards(h, want, turn_rate * dt)


def drones3d_arena(
    z: np.ndarray,
    w: float = 2.5,
    R: float = 1.6,
    spacing: float = 0.7,
    swirl: float = 0.5,
    wall_range: float = 0.5,
    v_max: float = 0.6,
) -> np.ndarray:
    p = z[..., :3]
    r, d = _offsets(p)
    near = d < R
    dn = np.where(near, d, 1.0)
    # springs to the spacing, summed (each neighbour pulls or pushes on its own)
    pair = np.where(near, 0.8 * (1.0 - (spacing / dn) ** 2), 0.0)
    u = (pair[..., None] * r / dn[..., None]).sum(axis=2)
    # a swirl about the vertical through the neighbours' centroid: the swarm turns as one
    centroid = (r * near[..., None]).sum(axis=2) / np.maximum(near.sum(axis=2, keepdims=True), 1)
    u[..., :2] += swirl * _left(centroid[..., :2])
    u += 1.5 / wall_range * _walls_depth(p, w, wall_range)
    return _clip_norm(u, v_max)


def drones3d(z: np.ndarray) -> np.ndarray:
    return drones3d_arena(z, w=np.inf)


def _nearest(d: np.ndarray, k: int) -> np.ndarray:
    """Whether robot j is one of robot i's ``k`` nearest others, whatever the distance (rank, not
    range): ``[S, n, n]`` bool from distances ``d [S, n, n]`` (inf on the diagonal)."""
    nearest = np.argsort(d, axis=2)[:, :, : min(k, d.shape[-1] - 1)]
    heeded = np.zeros(d.shape, dtype=bool)
    np.put_along_axis(heeded, nearest, True, axis=2)
    return heeded


def starlings3d(
    z: np.ndarray,
    speed: float = 1.0,
    k: int = 6,
    r_repulse: float = 0.5,
    cohesion: float = 0.4,
    blend: float = 0.1,
) -> np.ndarray:
    p, h = z[..., :3], z[..., 3:]
    r, d = _offsets(p)
    heeded = _nearest(d, k)
    count = heeded.sum(axis=2, keepdims=True)
    align = (h[:, None, :, :] * heeded[..., None]).sum(axis=2) / count
    centre = (r * heeded[..., None]).sum(axis=2) / count
    close = heeded & (d < r_repulse)
    away = -(r / np.where(close, d, 1.0)[..., None] * close[..., None]).sum(axis=2)
    want = align + cohesion * centre + 2.0 * away
    want = want / np.maximum(np.linalg.norm(want, axis=-1, keepdims=True), 1e-9)
    new = (1.0 - blend) * h + blend * want
    norm = np.linalg.norm(new, axis=-1, keepdims=True)
    return speed * np.where(norm > 1e-9, new / np.maximum(norm, 1e-9), h)


def roundabout2d(
    z: np.ndarray,
    w: float = 4.0,
    ring: float = 2.0,
    speed: float = 0.8,
    gain: float = 1.5,
    r_repulse: float = 1.0,
    wall_range: float = 0.8,
) -> np.ndarray:
    p, v = z[..., :2], z[..., 2:]
    r, d = _offsets(p)
    close = d < r_repulse
    dc = np.where(close, d, 1.0)
    push = np.where(close, r_repulse / np.maximum(dc, 0.1) - 1.0, 0.0)
    a = -(push[..., None] * r / dc[..., None]).sum(axis=2)
    # a velocity field of the room: anticlockwise round its centre, onto a ring
    rad = np.linalg.norm(p, axis=-1, keepdims=True)
    out = p / np.maximum(rad, 1e-6)
    a += gain * (speed * _left(out) + 0.8 * (ring - rad) * out - v)
    a += 4.0 * _walls_depth(p, w, wall_range)
    return _clip_norm(a, 3.0)


def _turn_towards_3d(h: np.ndarray, want: np.ndarray, most: float) -> np.ndarray:
    """3D unit headings ``h`` turned towards ``want`` by at most ``most`` radians, in the plane
    of the two (``want`` exactly behind has no such plane: the heading is kept)."""
    wu = want / np.maximum(np.linalg.norm(want, axis=-1, keepdims=True), 1e-9)
    c = np.clip((h * wu).sum(-1, keepdims=True), -1.0, 1.0)
    side = wu - c * h
    sn = np.linalg.norm(side, axis=-1, keepdims=True)
    n = side / np.maximum(sn, 1e-9) * (sn > 1e-9)
    a = np.minimum(np.arccos(c), most)
    new = np.cos(a) * h + np.sin(a) * n
    return new / np.maximum(np.linalg.norm(new, axis=-1, keepdims=True), 1e-9)


def fish3d_tank(
    z: np.ndarray,
    w: float = 3.0,
    speed: float = 0.8,
    k: int = 4,
    r_repulse: float = 0.4,
    r_attract: float = 2.0,
    wall_range: float = 1.0,
    turn_rate: float = 2.5,
    dt: float = DT,
) -> np.ndarray:
    p, h = z[..., :3], z[..., 3:]
    r, d = _offsets(p)
    heeded = _nearest(d, k)
    rh = r / np.where(np.isfinite(d), d, 1.0)[..., None]
    count = heeded.sum(axis=2, keepdims=True)
    align = (h[:, None, :, :] * heeded[..., None]).sum(axis=2) / np.maximum(count, 1)  # a lone fish
    near = heeded & (d < r_attract)
    towards = (rh * near[..., None]).sum(axis=2) / np.maximum(near.sum(axis=2, keepdims=True), 1)
    close = d < r_repulse
    away = -(rh * close[..., None]).sum(axis=2)
    want = np.where(close.any(axis=2, keepdims=True), away, h + align + towards)
    want = want / np.maximum(np.linalg.norm(want, axis=-1, keepdims=True), 1e-9)
    want = want + 4.0 * _walls_depth(p, w, wall_range) / wall_range
    return speed * _turn_towards_3d(h, want, turn_rate * dt)


def _spec(name: str, dims: int, state: str, command: str, arena=None) -> Scenario:
    return scenario_from_dict(
        dict(name=name, dimensions=dims, state=state, command=command, dt=DT, arena=arena), name
    )


LAWS: Dict[str, Law] = {
    'aggregate2d': Law(
        'aggregate2d', _spec('aggregate2d', 2, 'position', 'velocity'), aggregate2d, 0.55, 0.0, 400
    ),
    'flock3d_arena': Law(
        'flock3d_arena',
        _spec('flock3d_arena', 3, 'position_velocity', 'acceleration', {'half_width': 4.0}),
        flock3d_arena,
        0.5,
        0.8,
        400,
    ),
    'mill2d': Law('mill2d', _spec('mill2d', 2, 'position_velocity', 'acceleration'), mill2d, 0.6, 1.0, 400),
    'couzin2d': Law(
        'couzin2d', _spec('couzin2d', 2, 'position_heading', 'velocity'), couzin2d, 0.5, 1.0, 400
    ),
    'starlings3d': Law(
        'starlings3d', _spec('starlings3d', 3, 'position_heading', 'velocity'), starlings3d, 0.5, 1.0, 400
    ),
    'tank2d': Law(
        'tank2d',
        _spec('tank2d', 2, 'position_heading', 'velocity', {'half_width': 3.0}),
        tank2d,
        0.5,
        1.0,
        400,
    ),
    'drones3d_arena': Law(
        'drones3d_arena',
        _spec('drones3d_arena', 3, 'position', 'velocity', {'half_width': 2.5}),
        drones3d_arena,
        0.4,
        0.0,
        400,
    ),
    'drones3d': Law('drones3d', _spec('drones3d', 3, 'position', 'velocity'), drones3d, 0.4, 0.0, 400),
    'roundabout2d': Law(
        'roundabout2d',
        _spec('roundabout2d', 2, 'position_velocity', 'acceleration', {'half_width': 4.0}),
        roundabout2d,
        0.6,
        0.5,
        400,
    ),
    'fish3d_tank': Law(
        'fish3d_tank',
        _spec('fish3d_tank', 3, 'position_heading', 'velocity', {'half_width': 3.0}),
        fish3d_tank,
        0.5,
        1.0,
        400,
    ),
}


def initial_states(law: Law, count: int, n: int, seed: int) -> np.ndarray:
    """``[count, n, d]`` starts: positions uniform in a disc (ball) of radius
    ``start_radius_per_sqrt_n * sqrt(n)``, speeds ``start_speed`` in uniform directions."""
    spec = law.scenario
    rng = np.random.default_rng(seed)
    dim = spec.dimensions
    direction = rng.normal(size=(count, n, dim))
    direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
    radius = law.start_radius_per_sqrt_n * np.sqrt(n) * rng.random((count, n, 1)) ** (1.0 / dim)
    p = direction * radius
    if spec.arena is not None:
        p = np.clip(p, -0.8 * spec.arena, 0.8 * spec.arena)
    if spec.velocity is None and spec.heading is None:
        return p
    heading = rng.normal(size=(count, n, dim))
    heading /= np.linalg.norm(heading, axis=-1, keepdims=True)
    return np.concatenate([p, (1.0 if spec.heading is not None else law.start_speed) * heading], axis=-1)


def simulate(law: Law, z0: np.ndarray, steps: int) -> np.ndarray:
    """Trajectories ``[S, steps + 1, n, d]`` of ``law`` from ``z0 [S, n, d]``."""
    out = np.empty((z0.shape[0], steps + 1) + z0.shape[1:])
    out[:, 0] = z = np.asarray(z0, dtype=np.float64)
    for t in range(steps):
        z = zoh_step(z, law.command(z), law.scenario, law.scenario.dt)
        out[:, t + 1] = z
    return out
