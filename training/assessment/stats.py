"""Small statistics of repeated runs: mean with a 95% confidence half-width, and one summary dict."""

from __future__ import annotations

from typing import Dict, Sequence, Tuple

import numpy as np


def mean_ci(x: np.ndarray, axis: int = 0) -> Tuple[np.ndarray, np.ndarray]:
    """Mean and 95% confidence half-width (normal approximation) along ``axis``."""
    x = np.asarray(x, dtype=np.float64)
    n = x.shape[axis]
    mean = x.mean(axis=axis)
    half = 1.96 * x.std(axis=axis, ddof=1) / np.sqrt(n) if n > 1 else np.zeros_like(mean)
    return mean, half


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
