"""A classical learning-from-observation baseline: least-squares interaction kernels (flock2d).

After Lu, Maggioni and Tang ("Nonparametric inference of interaction laws in systems of agents
from trajectory data", PNAS 2019), restricted to what a robot hears: every robot's acceleration
is a sum of pairwise terms over the neighbours in its neighbour matrix Y,

    u_i = sum_j  phi_a(r_ij) (v_j - v_i)  +  phi_p(r_ij) (p_j - p_i),     r_ij = |p_j - p_i|,

with alignment and position kernels phi_a, phi_p piecewise constant on ``bins`` equal bins of
[0, d_cr]. The model is linear in the 2 * bins kernel values, so fitting it to the implied
accelerations of the observations (the same targets as the one-step loss) is one linear
least-squares problem, accumulated in chunks as normal equations. The Tanner law lies in this
family (phi_a = 1, phi_p(r) = 2/r^2 - 2/r^4), so the baseline is strong where the data are.

Shapes: M samples, k rows, B bins.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Optional

import numpy as np

from knode_swarm_ros.core import get_scenario, neighbour_matrices

__all__ = ['KernelModel', 'kernel_features', 'fit_kernel']


def kernel_features(Y: np.ndarray, mask: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Design tensor ``[M, 2, 2B]``: the model's output per axis is ``features @ coefficients``.

    Columns 0..B-1 multiply phi_a's bin values, columns B..2B-1 phi_p's.
    """
    Y = np.asarray(Y, dtype=np.float64)
    m = np.asarray(mask, dtype=bool)[:, 1:]
    dp = Y[:, 1:, :2] - Y[:, :1, :2]  # p_j - p_i   [M, k-1, 2]
    dv = Y[:, 1:, 2:4] - Y[:, :1, 2:4]  # v_j - v_i
    r = np.sqrt(np.sum(dp * dp, axis=-1))  # [M, k-1]
    B = len(edges) - 1
    b = np.clip(np.searchsorted(edges, r, side='right') - 1, 0, B - 1)
    onehot = (b[..., None] == np.arange(B)) & m[..., None]  # [M, k-1, B]
    fa = np.einsum('mjb,mjx->mxb', onehot, dv)  # [M, 2, B]
    fp = np.einsum('mjb,mjx->mxb', onehot, dp)
    return np.concatenate([fa, fp], axis=-1)


@dataclass
class KernelModel:
    """Fitted kernels; ``__call__(Y [M, k, 4], mask [M, k]) -> [M, 2]`` is a core policy callable."""

    edges: np.ndarray  # [B + 1] bin edges of r, 0 .. d_cr
    phi_a: np.ndarray  # [B] alignment kernel values
    phi_p: np.ndarray  # [B] position kernel values
    command_limit: Optional[float] = None
    samples_per_bin: Optional[np.ndarray] = None

    def __call__(self, Y: np.ndarray, mask: np.ndarray) -> np.ndarray:
        u = kernel_features(Y, mask, self.edges) @ np.concatenate([self.phi_a, self.phi_p])
        return u if self.command_limit is None else np.clip(u, -self.command_limit, self.command_limit)

    def to_json(self) -> str:
        return json.dumps(
            {
                'edges': self.edges.tolist(),
                'phi_a': self.phi_a.tolist(),
                'phi_p': self.phi_p.tolist(),
                'command_limit': self.command_limit,
                'samples_per_bin': None if self.samples_per_bin is None else self.samples_per_bin.tolist(),
            }
        )


def fit_kernel(
    states: np.ndarray,
    dt: float,
    d_cr: float,
    k: int,
    tau: int,
    bins: int = 24,
    command_limit: Optional[float] = None,
    ridge: float = 1e-8,
    stride: int = 1,
    chunk: int = 20000,
) -> KernelModel:
    """Least-squares kernels from trajectories ``states [N, T, n, 4]`` (flock2d).

    Targets are the implied accelerations (v(t + 1) - v(t)) / dt; samples whose implied
    acceleration reaches ``command_limit`` on an axis (to a relative 1e-6: the finite difference
    of a clipped command rounds to just below the limit) are left out (they were, or may have been,
    saturated, so they say nothing about the kernel beyond the limit). ``stride`` keeps every stride-th frame as a sample (targets
    stay one step ahead). ``ridge`` (relative to the normal matrix's trace) keeps bins
    without data at zero.
    """
    spec = get_scenario('flock2d')
    states = np.asarray(states, dtype=np.float64)
    if states.ndim != 4 or states.shape[-1] != spec.state_dim or states.shape[1] < 2:
        raise ValueError(f'need flock2d trajectories [N, T >= 2, n, 4], got {states.shape}')
    edges = np.linspace(0.0, d_cr, bins + 1)
    ata = np.zeros((2 * bins, 2 * bins))
    aty = np.zeros(2 * bins)
    counts = np.zeros(bins, dtype=np.int64)
    for s in range(states.shape[0]):
        traj = states[s]
        Y, mask = neighbour_matrices(traj, spec.position_dim, d_cr, k, tau)  # [T, n, k, 4]
        Y, mask = Y[:-1:stride].reshape(-1, k, 4), mask[:-1:stride].reshape(-1, k)
        target = ((traj[1::stride, :, 2:] - traj[:-1:stride, :, 2:]) / dt).reshape(-1, 2)
        keep = (
            np.ones(len(target), bool)
            if command_limit is None
            else np.abs(target).max(1) < command_limit * (1 - 1e-6)
        )
        for lo in range(0, len(target), chunk):
            sl = slice(lo, lo + chunk)
            F = kernel_features(Y[sl][keep[sl]], mask[sl][keep[sl]], edges)  # [M, 2, 2B]
            A = F.reshape(-1, 2 * bins)
            ata += A.T @ A
            aty += A.T @ target[sl][keep[sl]].reshape(-1)
            counts += _bin_counts(Y[sl][keep[sl]], mask[sl][keep[sl]], edges)
    lam = ridge * max(np.trace(ata), 1.0) / (2 * bins)
    coef = np.linalg.solve(ata + lam * np.eye(2 * bins), aty)
    return KernelModel(edges, coef[:bins], coef[bins:], command_limit, counts)


def _bin_counts(Y: np.ndarray, mask: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Neighbour pairs per distance bin ``[B]`` (how much data each kernel value rests on)."""
    dp = Y[:, 1:, :2] - Y[:, :1, :2]
    r = np.sqrt(np.sum(dp * dp, axis=-1))[np.asarray(mask, bool)[:, 1:]]
    return np.histogram(np.clip(r, 0, edges[-1]), bins=edges)[0]
