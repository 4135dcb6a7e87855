"""boids3d ground truth: Reynolds boids after Sebastian Lague's Unity implementation.

One frame (``Boid.UpdateBoid`` after ``BoidCompute.compute``), for every boid i at once and
from a snapshot of all positions p and velocities v (heading h = v / |v|):

* flockmates of i: every j != i with |p_j - p_i|^2 < perception_radius^2;
* alignment heading   A_i = sum_{flockmates j} h_j                (unweighted, not averaged);
* cohesion offset     C_i = mean_{flockmates j} p_j - p_i;
* separation heading  D_i = - sum_{flockmates j, |p_j - p_i| < avoidance_radius} (p_j - p_i) / |p_j - p_i|^2;
* steer_towards(w) = clamp_magnitude(normalise(w) * max_speed - v_i, max_steer_force), with
  normalise(w) = 0 when |w| <= 1e-5 (Unity's ``Vector3.normalized``), so a zero separation
  heading still brakes: steer_towards(0) = clamp_magnitude(-v_i, max_steer_force);
* a_i = w_align steer(A_i) + w_cohesion steer(C_i) + w_separate steer(D_i) if i has any
  flockmate (else 0);
* walls: if a sphere of radius ``bounds_radius`` swept ``collision_avoid_dst`` ahead along h_i
  would hit a wall of the cube [-box, box]^3, a_i += w_avoid steer(first clear direction), where
  the candidates are the golden-spiral directions rotated into the boid's frame (Unity's
  ``Transform.TransformDirection`` with ``transform.forward = h``: the spiral's +z goes to h);
  if no candidate is clear the boid keeps steering towards h;
* v_i += a_i dt; |v_i| clamped to [min_speed, max_speed]; p_i += v_i dt; h_i = v_i / |v_i|.

Sweep test against a wall x = +box (likewise for all six): the sphere touches it once its
centre has moved g = box - bounds_radius - p_x along x; it hits within the sweep iff the
direction moves towards the wall (d_x > 0) and collision_avoid_dst * d_x >= g. A boid already
within ``bounds_radius`` of a wall thus counts as heading for collision only while it moves
towards that wall (Unity's sphere cast ignores colliders the sphere starts inside).

Unity's frame basis: ``Quaternion.LookRotation(h, up = +y)`` gives the columns
right = normalise(up x h), up' = h x right, forward = h; we map Unity's (x, y, z) to ours
unchanged. When h is parallel to +-y we take right = +x.

Differences from Unity: float64 instead of float32, a fixed dt = 1/60 instead of the frame
time, and no division by zero (coincident boids add no separation; a zero velocity after the
acceleration keeps the previous heading). Arrays are ``[..., n, 3]`` with any leading axes.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Dict, Optional, Tuple

import numpy as np

__all__ = [
    'BoidsParams',
    'PRESETS',
    'get_preset',
    'DISCARD_FRAMES',
    'golden_spiral_directions',
    'normalise',
    'steer_towards',
    'flock_terms',
    'flocking_acceleration',
    'sweep_hits_wall',
    'look_rotation',
    'avoidance_directions',
    'boids_acceleration',
    'boids_step',
    'initial_boids',
    'observe',
    'BoidsSwarm',
]

#: Frames discarded after spawning, as the paper does (its 1700 recorded steps start after them).
DISCARD_FRAMES = 10

#: Unity's ``Vector3.kEpsilon``: vectors shorter than this normalise to zero.
NORMALISE_EPS = 1e-5


@dataclass(frozen=True)
class BoidsParams:
    """Boid settings (Lague's ``BoidSettings``) plus the arena; defaults are the paper's.

    Attributes:
        min_speed, max_speed: speed clamp after each frame.
        max_steer_force: magnitude clamp of every steer_towards term.
        align_weight, cohesion_weight, separate_weight: flocking weights.
        avoid_collision_weight: weight of the wall-avoidance steer.
        perception_radius: flockmates are within this distance (strict <).
        avoidance_radius: separation acts within this distance (strict <).
        bounds_radius: radius of the swept sphere for wall tests.
        collision_avoid_dst: how far ahead the sphere is swept.
        num_directions: golden-spiral candidate directions.
        box: the walls are the faces of [-box, box]^3.
        dt: frame time.
        spawn_radius: boids spawn uniformly inside this ball around the origin.
    """

    min_speed: float = 2.0
    max_speed: float = 5.0
    max_steer_force: float = 3.0
    align_weight: float = 1.0
    cohesion_weight: float = 1.0
    separate_weight: float = 1.0
    avoid_collision_weight: float = 10.0
    perception_radius: float = 2.5
    avoidance_radius: float = 1.0
    bounds_radius: float = 0.27
    collision_avoid_dst: float = 5.0
    num_directions: int = 300
    box: float = 5.0
    dt: float = 1.0 / 60.0
    spawn_radius: float = 5.0

    def __post_init__(self):
        if not 0 < self.min_speed <= self.max_speed:
            raise ValueError(f'need 0 < min_speed <= max_speed, got {self.min_speed}, {self.max_speed}')
        if self.num_directions < 1:
            raise ValueError(f'num_directions must be >= 1, got {self.num_directions}')
        if not self.box > self.bounds_radius:
            raise ValueError(f'box ({self.box}) must exceed bounds_radius ({self.bounds_radius})')

    def as_dict(self) -> Dict[str, float]:
        return asdict(self)


#: ``paper``: the paper's (and Lague's default) settings; ``published``: those of the paper's
#: published data set.
PRESETS: Dict[str, BoidsParams] = {
    'paper': BoidsParams(),
    'published': BoidsParams(
        min_speed=5.0,
        max_speed=8.0,
        max_steer_force=8.0,
        align_weight=2.0,
        cohesion_weight=1.0,
        separate_weight=2.5,
        avoid_collision_weight=20.0,
    ),
}


def get_preset(name: str) -> BoidsParams:
    """The preset called ``name``; unknown names raise ValueError listing the known ones."""
    try:
        return PRESETS[name]
    except KeyError:
        raise ValueError(f'unknown boids3d preset {name!r}; known: {", ".join(PRESETS)}') from None


_SPIRAL_CACHE: Dict[int, np.ndarray] = {}


def golden_spiral_directions(num: int = 300) -> np.ndarray:
    """Lague's ``BoidHelper.directions``: ``[num, 3]`` unit vectors, the first +z (forward).

    t = i / num, inclination = acos(1 - 2 t), azimuth = 2 pi phi i (phi the golden ratio),
    d_i = (sin inc cos az, sin inc sin az, cos inc). Ordered from forward to backward.
    """
    if num not in _SPIRAL_CACHE:
        i = np.arange(num, dtype=np.float64)
        golden = (1.0 + np.sqrt(5.0)) / 2.0
        inc = np.arccos(1.0 - 2.0 * i / num)
        az = 2.0 * np.pi * golden * i
        d = np.stack([np.sin(inc) * np.cos(az), np.sin(inc) * np.sin(az), np.cos(inc)], axis=-1)
        d.setflags(write=False)
        _SPIRAL_CACHE[num] = d
    return _SPIRAL_CACHE[num]


def _norm(x: np.ndarray) -> np.ndarray:
    return np.sqrt(np.einsum('...k,...k->...', x, x))


def normalise(w: np.ndarray) -> np.ndarray:
    """Unit vectors ``[..., 3]``; vectors with |w| <= 1e-5 give 0 (Unity's ``normalized``)."""
    w = np.asarray(w, dtype=np.float64)
    m = _norm(w)[..., None]
    return np.where(m > NORMALISE_EPS, w / np.where(m > NORMALISE_EPS, m, 1.0), 0.0)


def steer_towards(
    w: np.ndarray, velocity: np.ndarray, max_speed: float, max_steer_force: float
) -> np.ndarray:
    """clamp_magnitude(normalise(w) * max_speed - velocity, max_steer_force), ``[..., 3]``."""
    s = normalise(w) * max_speed - velocity
    m = _norm(s)[..., None]
    return s * np.where(m > max_steer_force, max_steer_force / np.where(m > 0, m, 1.0), 1.0)


def flock_terms(
    positions: np.ndarray, headings: np.ndarray, params: BoidsParams
) -> Tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """What each boid perceives of its flockmates (Lague's compute shader).

    Args:
        positions, headings: ``[..., n, 3]`` snapshot (headings unit).

    Returns:
        count ``[..., n]`` (number of flockmates), alignment ``[..., n, 3]`` (sum of their headings),
        cohesion ``[..., n, 3]`` (their mean position minus own position; 0 without flockmates),
        separation ``[..., n, 3]`` (-sum of offset / |offset|^2 within the avoidance radius).
    """
    p = np.asarray(positions, dtype=np.float64)
    h = np.asarray(headings, dtype=np.float64)
    n = p.shape[-2]
    off = p[..., None, :, :] - p[..., :, None, :]  # off[..., i, j] = p_j - p_i
    sq = np.einsum('...k,...k->...', off, off)  # [..., n, n]
    flock = sq < params.perception_radius**2
    flock.reshape(-1, n * n)[:, :: n + 1] = False
    near = flock & (sq < params.avoidance_radius**2) & (sq > 0.0)
    fl = flock.astype(np.float64)
    count = fl.sum(axis=-1)
    alignment = np.einsum('...ij,...jk->...ik', fl, h)
    centre = np.einsum('...ij,...jk->...ik', fl, p)
    cohesion = np.where(count[..., None] > 0, centre / np.maximum(count, 1.0)[..., None] - p, 0.0)
    inv = np.where(near, 1.0 / np.where(near, sq, 1.0), 0.0)
    separation = -np.einsum('...ij,...ijk->...ik', inv, off)
    return count, alignment, cohesion, separation


def flocking_acceleration(positions: np.ndarray, velocities: np.ndarray, params: BoidsParams) -> np.ndarray:
    """Alignment + cohesion + separation steer, ``[..., n, 3]`` (0 for boids without flockmates)."""
    v = np.asarray(velocities, dtype=np.float64)
    count, align, coh, sep = flock_terms(positions, normalise(v), params)
    ms, mf = params.max_speed, params.max_steer_force
    acc = (
        params.align_weight * steer_towards(align, v, ms, mf)
        + params.cohesion_weight * steer_towards(coh, v, ms, mf)
        + params.separate_weight * steer_towards(sep, v, ms, mf)
    )
    return np.where(count[..., None] > 0, acc, 0.0)


def _sweep_limits(positions: np.ndarray, params: BoidsParams) -> Tuple[np.ndarray, np.ndarray]:
    """(lo, hi) ``[..., 3]``: a sweep along unit d is clear of all walls iff lo < d < hi on every axis.

    hi_a = max(box - r - p_a, tiny) / L: moving towards +box by L d_a reaches contact iff d_a >= hi_a;
    a wall the sphere already touches or overlaps (gap <= 0) blocks every d_a > 0, not d_a <= 0.
    """
    p = np.asarray(positions, dtype=np.float64)
    reach = params.box - params.bounds_radius
    tiny = np.finfo(np.float64).tiny
    L = params.collision_avoid_dst
    return -np.maximum(reach + p, tiny) / L, np.maximum(reach - p, tiny) / L


def sweep_hits_wall(positions: np.ndarray, directions: np.ndarray, params: BoidsParams) -> np.ndarray:
    """Whether a sphere of radius ``bounds_radius`` swept ``collision_avoid_dst`` from each position
    along each unit direction hits a wall of the cube (see the module docstring).

    Args:
        positions, directions: broadcastable ``[..., 3]``.

    Returns:
        bool ``[...]`` (the broadcast shape without the last axis).
    """
    lo, hi = _sweep_limits(positions, params)
    d = np.asarray(directions, dtype=np.float64)
    return np.any((d >= hi) | (d <= lo), axis=-1)


def look_rotation(forward: np.ndarray) -> np.ndarray:
    """Unity's ``Quaternion.LookRotation(forward, +y)`` as matrices ``[..., 3, 3]`` whose rows are
    right, up', forward (so ``local @ R`` maps local directions to world ones)."""
    f = np.asarray(forward, dtype=np.float64)
    right = np.stack([f[..., 2], np.zeros_like(f[..., 0]), -f[..., 0]], axis=-1)  # +y x f
    m = _norm(right)[..., None]
    degenerate = m <= 1e-9
    right = np.where(degenerate, np.array([1.0, 0.0, 0.0]), right / np.where(degenerate, 1.0, m))
    up = np.cross(f, right)
    return np.stack([right, up, f], axis=-2)


def avoidance_directions(positions: np.ndarray, headings: np.ndarray, params: BoidsParams) -> np.ndarray:
    """Lague's ``ObstacleRays``: for boids ``[m, 3]`` the first golden-spiral direction (in each
    boid's frame) whose sweep is clear, or the heading if none is -> ``[m, 3]``."""
    p = np.asarray(positions, dtype=np.float64)
    h = np.asarray(headings, dtype=np.float64)
    m = p.shape[0]
    spiral = golden_spiral_directions(params.num_directions)  # [K, 3]
    frames = look_rotation(h)  # [m, 3 (local), 3 (world)]
    # world components of every candidate, component-major: dirs[a, i, k] = (spiral[k] @ frames[i])[a]
    dirs = (frames.transpose(2, 0, 1).reshape(3 * m, 3) @ spiral.T).reshape(3, m, -1)
    lo, hi = _sweep_limits(p, params)
    lo = lo.T[:, :, None]  # [3, m, 1]
    hi = hi.T[:, :, None]
    ok = (dirs[0] < hi[0]) & (dirs[0] > lo[0])
    ok &= (dirs[1] < hi[1]) & (dirs[1] > lo[1])
    ok &= (dirs[2] < hi[2]) & (dirs[2] > lo[2])
    first = np.argmax(ok, axis=1)
    rows = np.arange(m)
    chosen = dirs[:, rows, first].T
    return np.where(ok[rows, first][:, None], chosen, h)


def boids_acceleration(positions: np.ndarray, velocities: np.ndarray, params: BoidsParams) -> np.ndarray:
    """Total steering acceleration of one frame (flocking plus wall avoidance), ``[..., n, 3]``."""
    p = np.asarray(positions, dtype=np.float64)
    v = np.asarray(velocities, dtype=np.float64)
    acc = flocking_acceleration(p, v, params)
    h = normalise(v)
    heading_for_collision = sweep_hits_wall(p, h, params)  # [..., n]
    if np.any(heading_for_collision):
        sel = heading_for_collision
        target = avoidance_directions(p[sel], h[sel], params)
        acc[sel] += params.avoid_collision_weight * steer_towards(
            target, v[sel], params.max_speed, params.max_steer_force
        )
    return acc


def boids_step(
    positions: np.ndarray, velocities: np.ndarray, params: BoidsParams
) -> Tuple[np.ndarray, np.ndarray]:
    """Advance one frame: ``(positions, velocities) [..., n, 3]`` -> new ``(positions, velocities)``.

    v += a dt; |v| clamped to [min_speed, max_speed] (direction kept); p += v dt.
    The inputs are not modified.
    """
    p = np.asarray(positions, dtype=np.float64)
    v = np.asarray(velocities, dtype=np.float64)
    v_new = v + boids_acceleration(p, v, params) * params.dt
    speed = _norm(v_new)[..., None]
    ok = speed > 0
    direction = np.where(ok, v_new / np.where(ok, speed, 1.0), normalise(v))
    v_new = direction * np.clip(speed, params.min_speed, params.max_speed)
    return p + v_new * params.dt, v_new


def initial_boids(
    rng: np.random.Generator, trajectories: int, n: int, params: BoidsParams
) -> Tuple[np.ndarray, np.ndarray]:
    """Spawn ``trajectories`` swarms of ``n`` boids -> ``(positions, velocities) [S, n, 3]``.

    Positions uniform inside the ball of radius ``spawn_radius`` (direction from a normalised
    Gaussian [S, n, 3], radius spawn_radius * U^(1/3) [S, n]); headings uniform on the sphere
    (normalised Gaussian [S, n, 3]); speed (min_speed + max_speed) / 2. Draws in that order.
    """
    if trajectories < 1 or n < 1:
        raise ValueError(f'need trajectories >= 1 and n >= 1, got {trajectories} and {n}')
    S = int(trajectories)

    def unit(shape):
        while True:
            g = rng.standard_normal(shape)
            m = _norm(g)
            if np.all(m > 1e-12):  # a zero draw has probability 0; redraw rather than divide by 0
                return g / m[..., None]

    direction = unit((S, n, 3))
    radius = params.spawn_radius * np.cbrt(rng.random((S, n)))
    heading = unit((S, n, 3))
    return direction * radius[..., None], heading * (0.5 * (params.min_speed + params.max_speed))


def observe(positions: np.ndarray, velocities: np.ndarray) -> np.ndarray:
    """The paper's observation z = [p, v / |v|] -> ``[..., n, 6]``."""
    p = np.asarray(positions, dtype=np.float64)
    return np.concatenate([p, normalise(velocities)], axis=-1)


class BoidsSwarm:
    """Stateful stepper holding ``positions`` and ``velocities [..., n, 3]`` (one swarm ``[1, n, 3]``
    or S swarms ``[S, n, 3]``), for the dataset generator and the simulator's ground-truth mode."""

    def __init__(self, positions: np.ndarray, velocities: np.ndarray, params: Optional[BoidsParams] = None):
        self.positions = np.array(positions, dtype=np.float64)
        self.velocities = np.array(velocities, dtype=np.float64)
        if self.positions.shape != self.velocities.shape or self.positions.shape[-1:] != (3,):
            raise ValueError(
                f'positions and velocities must both be [..., n, 3], got '
                f'{self.positions.shape} and {self.velocities.shape}'
            )
        self.params = params if params is not None else PRESETS['paper']

    @classmethod
    def spawn(
        cls, rng: np.random.Generator, trajectories: int, n: int, params: Optional[BoidsParams] = None
    ) -> 'BoidsSwarm':
        """New swarms spawned by :func:`initial_boids`."""
        params = params if params is not None else PRESETS['paper']
        return cls(*initial_boids(rng, trajectories, n, params), params)

    @classmethod
    def from_observation(
        cls, z: np.ndarray, params: Optional[BoidsParams] = None, speed: Optional[float] = None
    ) -> 'BoidsSwarm':
        """Swarms from observations ``z [..., n, 6]`` = [p, h]; the speed, which z does not carry,
        defaults to the spawn speed (min_speed + max_speed) / 2."""
        params = params if params is not None else PRESETS['paper']
        z = np.asarray(z, dtype=np.float64)
        if z.shape[-1:] != (6,):
            raise ValueError(f'z must be [..., n, 6], got shape {z.shape}')
        s = 0.5 * (params.min_speed + params.max_speed) if speed is None else float(speed)
        return cls(z[..., :3], normalise(z[..., 3:]) * s, params)

    def step(self) -> np.ndarray:
        """Advance one frame; returns the new observation ``[..., n, 6]``."""
        self.positions, self.velocities = boids_step(self.positions, self.velocities, self.params)
        return self.observe()

    def observe(self) -> np.ndarray:
        """z = [p, v / |v|] ``[..., n, 6]``."""
        return observe(self.positions, self.velocities)
