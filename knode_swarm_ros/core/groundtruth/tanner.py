"""flock2d ground truth: the global flocking controller of Tanner, Jadbabaie and Pappas.

Every robot is a double integrator, state z_i = [px, py, vx, vy]. The global controller is

    u_i = - sum_{j != i} (v_i - v_j) - sum_{j != i} grad_{r_i} V(|r_ij|),   r_ij = r_i - r_j,
    V(r) = 1/r^2 + log r^2                     (minimum at r = 1),
    grad_{r_i} V(|r_ij|) = V'(|r_ij|) r_ij / |r_ij| = (2/|r_ij|^2 - 2/|r_ij|^4) r_ij,

so close pairs repel (|r_ij| < 1), distant pairs attract and velocities align. The swarm is
integrated with the classical fourth-order Runge-Kutta method (weights 1/6, 2/6, 2/6, 1/6;
not the 3/8 rule that torchdiffeq calls ``rk4``) at dt = 0.01.

Two named variants (see :data:`VARIANTS`):

* ``paper`` (default): the paper's initial conditions, no saturation;
* ``gym_flock``: gym-flock's initial conditions and its acceleration clip at +-10 per axis,
  applied inside the vector field that RK4 integrates.

Everything is numpy, float64, vectorised over any leading axes ``[...]`` (trajectories):
``states[..., n, 4]``. One swarm is ``[1, n, 4]`` or simply ``[n, 4]``.
"""

from __future__ import annotations

from typing import Callable, Dict, Optional

import numpy as np

__all__ = [
    'VARIANTS',
    'DT',
    'pair_potential',
    'tanner_acceleration',
    'local_tanner_acceleration',
    'tanner_energy',
    'rk4',
    'rk4_step',
    'initial_states',
    'variant_clip',
    'TannerSwarm',
]

#: Ground-truth integration step (seconds), as in the paper.
DT = 0.01

#: Named variants: initial-condition recipe and the per-axis acceleration clip (None = unclipped).
VARIANTS: Dict[str, Dict[str, object]] = {
    'paper': {
        'clip': None,
        'disk_radius': 'sqrt(n)',
        'speed': '|v| ~ U[0, 3], uniform direction',
        'bias': 'one per swarm, |b| ~ U[0, 3], uniform direction',
    },
    'gym_flock': {
        'clip': 10.0,
        'disk_radius': 'n**0.25',
        'speed': 'per axis U(-3, 3)',
        'bias': 'one per swarm, per axis U(-3, 3)',
    },
}

#: Largest initial speed (paper) or per-axis velocity (gym_flock), and the same for the bias.
V_MAX = 3.0
V_BIAS = 3.0


def variant_clip(variant: str) -> Optional[float]:
    """Per-axis acceleration clip of ``variant`` (None for ``paper``); unknown names raise ValueError."""
    try:
        return VARIANTS[variant]['clip']  # type: ignore[return-value]
    except KeyError:
        raise ValueError(f'unknown flock2d variant {variant!r}; known: {", ".join(VARIANTS)}') from None


def pair_potential(r: np.ndarray) -> np.ndarray:
    """V(r) = 1/r^2 + log r^2 for distances ``r [...]`` (r > 0) -> ``[...]``."""
    r2 = np.asarray(r, dtype=np.float64) ** 2
    return 1.0 / r2 + np.log(r2)


def _set_diagonal(a: np.ndarray, value: float) -> None:
    """a[..., i, i] = value in place (a C-contiguous ``[..., n, n]``)."""
    n = a.shape[-1]
    a.reshape(-1, n * n)[:, :: n + 1] = value


def _pair_offsets(states: np.ndarray):
    """dx, dy ``[..., n, n]`` with dx[..., i, j] = x_i - x_j, and r2 = dx^2 + dy^2 (fresh arrays)."""
    x = states[..., 0]
    y = states[..., 1]
    dx = x[..., :, None] - x[..., None, :]
    dy = y[..., :, None] - y[..., None, :]
    r2 = dx * dx
    r2 += dy * dy
    return dx, dy, r2


def tanner_acceleration(states: np.ndarray, clip: Optional[float] = None) -> np.ndarray:
    """Global Tanner flocking control of every robot.

    Args:
        states: ``[..., n, 4]`` rows [px, py, vx, vy]; no two robots at the same position.
        clip: if given, saturate each acceleration component to [-clip, clip] (gym-flock: 10).

    Returns:
        ``[..., n, 2]`` accelerations u_i = -sum_j (v_i - v_j) - sum_j (2/r^2 - 2/r^4) r_ij.
        Unclipped, they sum to zero over the robots (momentum is conserved).
    """
    states = np.asarray(states, dtype=np.float64)
    n = states.shape[-2]
    v = states[..., 2:4]
    # -sum_j (v_i - v_j) = sum_j v_j - n v_i
    acc = v.sum(axis=-2, keepdims=True) - n * v
    dx, dy, r2 = _pair_offsets(states)
    _set_diagonal(r2, np.inf)  # no self term: 1/inf = 0 and dx_ii = 0
    inv = np.reciprocal(r2, out=r2)  # 1/r^2
    c = inv * inv
    np.subtract(inv, c, out=c)  # grad_{r_i} V_ij = 2 c_ij r_ij, c = 1/r^2 - 1/r^4
    acc[..., 0] -= 2.0 * np.einsum('...ij,...ij->...i', c, dx)
    acc[..., 1] -= 2.0 * np.einsum('...ij,...ij->...i', c, dy)
    if clip is not None:
        np.clip(acc, -clip, clip, out=acc)
    return acc


def local_tanner_acceleration(Y: np.ndarray, mask: np.ndarray, clip: Optional[float] = None) -> np.ndarray:
    """The Tanner law restricted to what a robot hears: the hand-written decentralised baseline.

    Args:
        Y: ``[B, k, 4]`` neighbour matrices (row 0 the robot, rows 1.. its delayed neighbours).
        mask: ``[B, k]`` real rows.
        clip: per-axis saturation (the policies' ``command_limit``), or None.

    Returns:
        ``[B, 2]``: u_i = -sum_j (v_i - v_j) - sum_j (2/r^2 - 2/r^4) r_ij over the masked rows
        j >= 1 (:func:`tanner_acceleration` with the sums cut to the neighbour matrix). A
        neighbour at the robot's own position adds no potential term (its direction is undefined).
    """
    Y = np.asarray(Y, dtype=np.float64)
    m = np.asarray(mask, dtype=bool)[:, 1:, None]
    dp = Y[:, :1, :2] - Y[:, 1:, :2]  # r_ij = r_i - r_j  [B, k-1, 2]
    r2 = np.sum(dp * dp, axis=-1, keepdims=True)
    with np.errstate(divide='ignore', invalid='ignore'):
        inv = np.where(r2 > 0, 1.0 / r2, 0.0)
    c = inv - inv * inv
    acc = -np.sum(np.where(m, Y[:, :1, 2:] - Y[:, 1:, 2:], 0.0), axis=1) - 2.0 * np.sum(
        np.where(m, c * dp, 0.0), axis=1
    )
    return acc if clip is None else np.clip(acc, -clip, clip)


def tanner_energy(states: np.ndarray) -> np.ndarray:
    """Lyapunov function of the global controller, ``states [..., n, 4] -> [...]``.

    Q = 1/2 sum_i ( sum_{j != i} V(|r_ij|) + |v_i|^2 ); along the unclipped closed loop
    dQ/dt = -1/2 sum_{i,j} |v_i - v_j|^2 <= 0.
    """
    states = np.asarray(states, dtype=np.float64)
    _, _, r2 = _pair_offsets(states)
    _set_diagonal(r2, 1.0)  # V(1) = 1 on the diagonal, removed below
    n = states.shape[-2]
    pot = (1.0 / r2 + np.log(r2)).sum(axis=(-1, -2)) - n * 1.0
    kin = np.sum(states[..., 2:4] ** 2, axis=(-1, -2))
    return 0.5 * (pot + kin)


def rk4(f: Callable[[np.ndarray], np.ndarray], z: np.ndarray, dt: float) -> np.ndarray:
    """One classical RK4 step of the autonomous ODE z' = f(z) (any array shape).

    k1 = f(z), k2 = f(z + dt/2 k1), k3 = f(z + dt/2 k2), k4 = f(z + dt k3),
    z_next = z + dt/6 (k1 + 2 k2 + 2 k3 + k4).
    """
    k1 = f(z)
    k2 = f(z + (0.5 * dt) * k1)
    k3 = f(z + (0.5 * dt) * k2)
    k4 = f(z + dt * k3)
    return z + (dt / 6.0) * (k1 + 2.0 * (k2 + k3) + k4)


def _vector_field(states: np.ndarray, clip: Optional[float]) -> np.ndarray:
    out = np.empty_like(states)
    out[..., 0:2] = states[..., 2:4]
    out[..., 2:4] = tanner_acceleration(states, clip)
    return out


def rk4_step(states: np.ndarray, dt: float = DT, clip: Optional[float] = None) -> np.ndarray:
    """Advance ``states [..., n, 4]`` by one classical RK4 step of the closed loop -> ``[..., n, 4]``.

    ``clip`` saturates the acceleration inside the vector field (gym-flock variant: 10).
    The input is not modified.
    """
    states = np.asarray(states, dtype=np.float64)
    return rk4(lambda z: _vector_field(z, clip), states, dt)


def _min_pair_distance(xy: np.ndarray) -> np.ndarray:
    """Smallest pairwise distance per swarm, ``xy [S, n, 2] -> [S]`` (inf for n = 1)."""
    d = xy[:, :, None, :] - xy[:, None, :, :]
    r2 = np.einsum('...k,...k->...', d, d)
    _set_diagonal(r2, np.inf)
    return np.sqrt(r2.min(axis=(-1, -2)))


def initial_states(
    rng: np.random.Generator,
    trajectories: int,
    n: int,
    variant: str = 'paper',
    min_separation: Optional[float] = None,
    max_redraws: int = 10000,
) -> np.ndarray:
    """Random initial swarms ``[trajectories, n, 4]`` (float64).

    ``paper``: positions uniform by area on the disk of radius sqrt(n) (radius sqrt(n) * sqrt(U),
    angle U[0, 2 pi)); velocities of magnitude U[0, 3] in a uniform direction, plus one bias
    velocity per swarm of magnitude U[0, 3] in a uniform direction.

    ``gym_flock``: positions uniform by area on the disk of radius n**0.25; velocities per axis
    U(-3, 3) plus one per-axis U(-3, 3) bias per swarm.

    ``min_separation`` (default None: the paper's unconditioned draw): redraw the positions of
    every swarm whose closest pair is nearer than this, until none is (gym-flock's ``reset``
    rejects configurations closer than 0.1). Uniform positions put a pair within 0.06 in about
    2% of 10-robot swarms, where dt = 0.01 does not resolve the 1/r^5 repulsion.

    Draw order (fixed, so a seed gives the same swarms everywhere): position radius [S, n],
    position angle [S, n] (then, with ``min_separation``, radius [k, n] and angle [k, n] for
    the k offending swarms, repeatedly), then for ``paper`` speed [S, n], direction [S, n],
    bias magnitude [S], bias direction [S]; for ``gym_flock`` velocity [S, n, 2], bias [S, 2].
    """
    variant_clip(variant)
    if trajectories < 1 or n < 1:
        raise ValueError(f'need trajectories >= 1 and n >= 1, got {trajectories} and {n}')
    S = int(trajectories)
    radius = np.sqrt(n) if variant == 'paper' else n**0.25

    def disk(k):
        rho = radius * np.sqrt(rng.random((k, n)))
        theta = 2.0 * np.pi * rng.random((k, n))
        return np.stack([rho * np.cos(theta), rho * np.sin(theta)], axis=-1)

    out = np.empty((S, n, 4))
    out[..., 0:2] = disk(S)
    if min_separation is not None and n > 1:
        for _ in range(max_redraws):
            bad = np.flatnonzero(_min_pair_distance(out[..., 0:2]) < min_separation)
            if bad.size == 0:
                break
            out[bad, :, 0:2] = disk(bad.size)
        else:
            raise ValueError(
                f'min_separation {min_separation} not reached for {n} robots on a disk of radius '
                f'{radius:.3g} after {max_redraws} redraws'
            )
    if variant == 'paper':
        speed = V_MAX * rng.random((S, n))
        phi = 2.0 * np.pi * rng.random((S, n))
        bias_speed = V_BIAS * rng.random(S)
        bias_phi = 2.0 * np.pi * rng.random(S)
        out[..., 2] = speed * np.cos(phi) + (bias_speed * np.cos(bias_phi))[:, None]
        out[..., 3] = speed * np.sin(phi) + (bias_speed * np.sin(bias_phi))[:, None]
    else:
        vel = rng.uniform(-V_MAX, V_MAX, size=(S, n, 2))
        bias = rng.uniform(-V_BIAS, V_BIAS, size=(S, 2))
        out[..., 2:4] = vel + bias[:, None, :]
    return out


class TannerSwarm:
    """Stateful stepper for the simulator's ground-truth mode.

    Holds ``states [..., n, 4]`` (one swarm ``[1, n, 4]`` or S swarms ``[S, n, 4]``);
    :meth:`step` advances it by one RK4 step and :meth:`observe` returns z (a copy).
    """

    def __init__(self, states: np.ndarray, variant: str = 'paper', dt: float = DT):
        self.states = np.array(states, dtype=np.float64)
        if self.states.ndim < 2 or self.states.shape[-1] != 4:
            raise ValueError(f'states must be [..., n, 4], got shape {self.states.shape}')
        self.variant = variant
        self.clip = variant_clip(variant)
        self.dt = float(dt)

    def step(self) -> np.ndarray:
        """Advance one step of ``dt``; returns the new z ``[..., n, 4]`` (a copy)."""
        self.states = rk4_step(self.states, self.dt, self.clip)
        return self.observe()

    def observe(self) -> np.ndarray:
        """z = [px, py, vx, vy] ``[..., n, 4]`` (a copy)."""
        return self.states.copy()
