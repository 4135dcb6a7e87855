"""Statistics of boids runs that do not depend on matching initial conditions, and group comparisons.

Shapes: T frames, n boids, rows (x, y, z, hx, hy, hz); speeds assume the nominal 1/60 s unless
frame times are given.
"""

from __future__ import annotations

from typing import Dict, Optional, Sequence

import numpy as np

from knode_swarm_ros.core.metrics import amd, kl_divergence, pod_energy
from training.assessment.boids_stats import alignment, flockmates, speeds, subgroups, wall_distance

from .frames import NOMINAL_DT

__all__ = ['STATS', 'run_statistics', 'compare_groups', 'pod_kld_pairs']

STATS = {
    # name: (description, unit)
    'speed_mean': 'mean speed from positions with dt = 1/60 (what a learner sees)',
    'speed_p95': '95th percentile of that speed',
    'speed_above_max': 'fraction of boid-frames with that speed > 8.01 (max speed 8)',
    'true_speed_mean': 'mean speed with the actual frame times',
    'true_speed_at_min': 'fraction of boid-frames at the minimum speed 5 (actual frame times)',
    'alignment': "mean cosine of heading with flockmates' headings (radius 2.5)",
    'flockmates': 'mean number of flockmates (radius 2.5)',
    'isolated': 'fraction of boid-frames without flockmates',
    'subgroups_mean': 'mean number of connected groups (radius 2.5)',
    'subgroups_final': 'mean number of groups over the last 50 frames',
    'wall_distance': 'mean distance to the nearest wall',
    'near_wall': 'fraction of boid-frames within 1 of a wall',
    'amd_mean': 'amd averaged over time',
    'amd_final': 'amd over the last 10 frames',
    'pod_mode1': "energy share of the first POD mode (10 modes, paper's S)",
}


def run_statistics(
    run: np.ndarray, frame_times: Optional[np.ndarray] = None, modes: int = 10
) -> Dict[str, float]:
    """Scalar statistics of one run ``[T, n, 6]``; ``frame_times [T - 1]`` (default 1/60) give true speeds."""
    s = speeds(run, NOMINAL_DT)
    dt = (
        np.full(run.shape[0] - 1, NOMINAL_DT)
        if frame_times is None
        else np.asarray(frame_times)[: run.shape[0] - 1]
    )
    true = s * NOMINAL_DT / dt[:, None]
    fm = flockmates(run)
    wd = wall_distance(run)
    a = amd(run[..., :3])
    groups = subgroups(run)
    al = alignment(run)
    al = al[np.isfinite(al)]
    return {
        'speed_mean': float(s.mean()),
        'speed_p95': float(np.percentile(s, 95)),
        'speed_above_max': float(np.mean(s > 8.01)),
        'true_speed_mean': float(true.mean()),
        'true_speed_at_min': float(np.mean(true < 5.001)),
        'alignment': float(al.mean()) if al.size else float('nan'),
        'flockmates': float(fm.mean()),
        'isolated': float(np.mean(fm == 0)),
        'subgroups_mean': float(groups.mean()),
        'subgroups_final': float(groups[-50:].mean()),
        'wall_distance': float(wd.mean()),
        'near_wall': float(np.mean(wd < 1.0)),
        'amd_mean': float(a.mean()),
        'amd_final': float(a[-10:].mean()),
        'pod_mode1': float(pod_energy(run, modes)[0]),
    }


def compare_groups(reference: Sequence[float], other: Sequence[float]) -> Dict[str, float]:
    """Welch's t-test of per-run values, and the difference in units of the reference's run-to-run spread."""
    from scipy import stats as sps

    r, o = np.asarray(reference, float), np.asarray(other, float)
    diff = float(o.mean() - r.mean())
    spread = float(r.std(ddof=1)) if r.size > 1 else 0.0
    if r.size > 1 and o.size > 1 and (r.std() > 0 or o.std() > 0):
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter('ignore', RuntimeWarning)  # nearly identical samples
            p = float(sps.ttest_ind(o, r, equal_var=False).pvalue)
    else:
        p = float('nan') if diff == 0 else 0.0
    return {
        'diff': diff,
        'rel_diff': diff / abs(r.mean()) if r.mean() != 0 else float('nan'),
        'diff_over_spread': diff / spread if spread > 0 else float('nan'),
        'p_welch': p,
    }


def pod_kld_pairs(truth: np.ndarray, predicted: Optional[np.ndarray] = None, modes: int = 10) -> np.ndarray:
    """KL(truth_i || predicted_j) of POD energies (as :func:`pod_kld`) over all pairs; without
    ``predicted``, truth against itself with i != j."""
    et = [pod_energy(x, modes) for x in truth]
    if predicted is None:
        return np.array(
            [kl_divergence(et[i], et[j]) for i in range(len(et)) for j in range(len(et)) if i != j]
        )
    ep = [pod_energy(x, modes) for x in predicted]
    return np.array([kl_divergence(a, b) for a in et for b in ep])
