"""Small statistics of repeated runs: the one 95% interval of a mean (normal approximation, or
Student's t for a handful of runs), and one summary dict."""

from __future__ import annotations

from typing import Dict, Sequence, Tuple

import numpy as np

__all__ = ['mean_ci', 'interval', 'describe']


def mean_ci(x: np.ndarray, axis: int = 0, t: bool = False) -> Tuple[np.ndarray, np.ndarray]:
    """Mean and 95% confidence half-width along ``axis`` (zero for one value): quantile times
    std (ddof 1) / sqrt(n), the quantile 1.96 (normal approximation) or, with ``t``, Student's
    t with n - 1 degrees of freedom (honest for a few runs)."""
    x = np.asarray(x, dtype=np.float64)
    n = x.shape[axis]
    mean = x.mean(axis=axis)
    if n <= 1:
        return mean, np.zeros_like(mean)
    if t:
        from scipy import stats  # only the t quantile needs scipy

        quantile = stats.t.ppf(0.975, n - 1)
    else:
        quantile = 1.96
    return mean, quantile * x.std(axis=axis, ddof=1) / np.sqrt(n)


def interval(values: Sequence[float]) -> Dict[str, float]:
    """Mean and 95% t interval of ``values [S]``: ``{'mean', 'lo', 'hi'}``."""
    mean, half = mean_ci(np.asarray(values, dtype=np.float64).ravel(), t=True)
    mean, half = float(mean), float(half)
    return {'mean': mean, 'lo': mean - half, 'hi': mean + half}


def describe(values: Sequence[float]) -> Dict[str, float]:
    """Summary of a sample ``[S]``: mean, std (ddof 1; 0 for one value), ci95 (normal
    approximation; 0 for one value), median, quartiles q1/q3, min, max and count."""
    v = np.asarray(values, dtype=np.float64).ravel()
    mean, half = mean_ci(v[:, None])
    q1, med, q3 = np.percentile(v, [25, 50, 75])
    return {
        'mean': float(mean[0]),
        'std': float(v.std(ddof=1)) if v.size > 1 else 0.0,
        'ci95': float(half[0]),
        'median': float(med),
        'q1': float(q1),
        'q3': float(q3),
        'min': float(v.min()),
        'max': float(v.max()),
        'count': int(v.size),
    }
