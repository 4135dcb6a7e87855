"""Statistics of a boids swarm that do not depend on matching initial conditions.

Used to compare our boids with the Unity recordings. Every function takes
boids3d trajectories ``[T, n, 6]`` (position, unit heading) or ``[S, T, n, 6]`` and
returns per-frame values or a flat sample, so runs of different lengths compare.
"""

from __future__ import annotations

import numpy as np

from knode_swarm_ros.core import amd, pod_energy
from knode_swarm_ros.core.geometry import pair_distances

__all__ = ['speeds', 'flockmates', 'alignment', 'group_labels', 'subgroups', 'wall_distance', 'summary']

PERCEPTION_RADIUS = 2.5
BOX = 5.0


def _pairs(states: np.ndarray) -> np.ndarray:
    return pair_distances(states[..., :3])


def speeds(states: np.ndarray, dt: float) -> np.ndarray:
    """Speeds ``[..., T-1, n]`` from finite differences of positions (no velocity is recorded)."""
    return np.linalg.norm(np.diff(states[..., :3], axis=-3), axis=-1) / dt


def flockmates(states: np.ndarray, radius: float = PERCEPTION_RADIUS) -> np.ndarray:
    """Number of other boids within ``radius`` of each boid, ``[..., T, n]``."""
    return (_pairs(states) <= radius).sum(axis=-1)


def alignment(states: np.ndarray, radius: float = PERCEPTION_RADIUS) -> np.ndarray:
    """Mean cosine between each boid's heading and its flockmates' headings, ``[..., T, n]``
    (NaN for a boid without flockmates)."""
    near = _pairs(states) <= radius
    h = states[..., 3:]
    cos = np.einsum('...id,...jd->...ij', h, h)
    count = near.sum(axis=-1)
    total = np.where(near, cos, 0.0).sum(axis=-1)
    return np.divide(total, count, out=np.full(count.shape, np.nan), where=count > 0)


def group_labels(states: np.ndarray, radius: float = PERCEPTION_RADIUS) -> np.ndarray:
    """Connected group of each boid (boids linked when within ``radius``, transitively), ``[..., T, n]``:
    the index of the group's lowest-index member."""
    near = _pairs(states) <= radius
    n = near.shape[-1]
    reach = (near | np.eye(n, dtype=bool)).astype(np.float32)
    # Transitive closure by repeated boolean squaring: log2(n) matrix products (float32 matmul
    # uses BLAS; entries stay exact 0/1 after the threshold).
    for _ in range(int(np.ceil(np.log2(max(n, 2))))):
        reach = (np.matmul(reach, reach) > 0).astype(np.float32)
    return np.argmax(reach > 0, axis=-1)


def subgroups(states: np.ndarray, radius: float = PERCEPTION_RADIUS) -> np.ndarray:
    """Number of connected groups (boids linked when within ``radius``) per frame, ``[..., T]``."""
    labels = group_labels(states, radius)
    # Each group is counted once through its lowest-index member.
    return (labels == np.arange(labels.shape[-1])).sum(axis=-1)


def wall_distance(states: np.ndarray, box: float = BOX) -> np.ndarray:
    """Distance of each boid to the closest wall of the cube [-box, box]^3, ``[..., T, n]``."""
    return (box - np.abs(states[..., :3])).min(axis=-1)


def summary(states: np.ndarray, dt: float, modes: int = 10) -> dict:
    """Headline statistics of trajectories ``[S, T, n, 6]``: means and spreads over runs."""
    per_run = []
    for run in states:
        per_run.append(
            {
                'speed_mean': float(speeds(run, dt).mean()),
                'speed_p05': float(np.percentile(speeds(run, dt), 5)),
                'speed_p95': float(np.percentile(speeds(run, dt), 95)),
                'alignment': float(np.nanmean(alignment(run))),
                'flockmates': float(flockmates(run).mean()),
                'subgroups_final': float(subgroups(run[-50:]).mean()),
                'wall_distance': float(wall_distance(run).mean()),
                'amd': float(amd(run[..., :3]).mean()),
                'pod_energy': pod_energy(run, modes).tolist(),
            }
        )
    keys = [k for k in per_run[0] if k != 'pod_energy']
    out = {
        k: {'mean': float(np.mean([r[k] for r in per_run])), 'std': float(np.std([r[k] for r in per_run]))}
        for k in keys
    }
    out['pod_energy'] = np.mean([r['pod_energy'] for r in per_run], axis=0).tolist()
    out['runs'] = len(per_run)
    return out
