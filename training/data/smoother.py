"""Offline positions and velocities from noisy, jittered, gappy samples: a Rauch-Tung-Striebel
smoother with a constant-acceleration (white-jerk) motion model, run at the samples' own stamps
(docs/import_bag.md, "Derivatives").

Three steps, each on one robot's samples ``t[m]`` (seconds, strictly increasing, any spacing) and
``y[m, c]`` (positions):

1. :func:`estimate_noise`: the position noise level from the data itself. The third divided
   difference of four consecutive samples, taken at their stamps, cancels any constant-acceleration
   motion; scaled to unit gain it is the noise alone (its robust spread is the noise's standard
   deviation), whatever the jitter or the dropped samples.
2. :func:`choose_process_noise`: the white-jerk intensity that maximises the likelihood of the
   samples given that noise level (how much the motion may bend between samples).
3. :func:`smooth` then :func:`SmoothedTrack.at`: the smoothed state (position, velocity,
   acceleration) at every sample, then at any time within, by the model's own interpolation
   (quintic Hermite, the posterior mean of a white-jerk process between two known states).

The smoother is the batch form of the RTS smoother: the least-squares problem over all states is
block-tridiagonal and solved at once with a banded Cholesky factorisation (the same estimate as the
forward Kalman filter and backward pass, faster in numpy).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import List, Sequence, Tuple

import numpy as np
from scipy.linalg import cho_solve_banded, cholesky_banded

__all__ = [
    'SmoothedTrack',
    'noise_residuals',
    'estimate_noise',
    'choose_process_noise',
    'smooth',
    'smooth_tracks',
    'NOISE_FLOOR',
]

#: Smallest position noise the smoother assumes (m): clean data still get a well-posed problem.
NOISE_FLOOR = 1e-6

_BAND = 5  # upper bandwidth of the normal equations: states of 3 values, neighbours coupled
_RATIOS = np.logspace(-10, 8, 19)  # process / measurement noise ratios searched (scaled time)


@dataclass
class SmoothedTrack:
    """The smoothed states of one robot at its sample times ``t[m]``: ``p, v, a`` each ``[m, c]``."""

    t: np.ndarray
    p: np.ndarray
    v: np.ndarray
    a: np.ndarray

    def at(self, times: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        """Positions and velocities ``[L, c]`` at ``times[L]`` within ``[t[0], t[-1]]``: quintic
        Hermite between the two samples around each time, the model's own interpolation."""
        times = np.clip(np.asarray(times, dtype=np.float64), self.t[0], self.t[-1])
        i = np.clip(np.searchsorted(self.t, times, 'right') - 1, 0, self.t.size - 2)
        h = (self.t[i + 1] - self.t[i])[:, None]
        s = (times - self.t[i])[:, None] / h
        s2, s3, s4, s5 = s * s, s**3, s**4, s**5
        b = [
            1 - 10 * s3 + 15 * s4 - 6 * s5,
            s - 6 * s3 + 8 * s4 - 3 * s5,
            (s2 - 3 * s3 + 3 * s4 - s5) / 2,
            (s3 - 2 * s4 + s5) / 2,
            -4 * s3 + 7 * s4 - 3 * s5,
            10 * s3 - 15 * s4 + 6 * s5,
        ]
        db = [
            -30 * s2 + 60 * s3 - 30 * s4,
            1 - 18 * s2 + 32 * s3 - 15 * s4,
            (2 * s - 9 * s2 + 12 * s3 - 5 * s4) / 2,
            (3 * s2 - 8 * s3 + 5 * s4) / 2,
            -12 * s2 + 28 * s3 - 15 * s4,
            30 * s2 - 60 * s3 + 30 * s4,
        ]
        ends = [
            self.p[i],
            h * self.v[i],
            h * h * self.a[i],
            h * h * self.a[i + 1],
            h * self.v[i + 1],
            self.p[i + 1],
        ]
        pos = sum(w * x for w, x in zip(b, ends))
        vel = sum(w * x for w, x in zip(db, ends)) / h
        return pos, vel


def noise_residuals(t: np.ndarray, y: np.ndarray, max_span: float) -> np.ndarray:
    """Third divided differences of ``y[m, c]`` over four consecutive samples at their stamps
    ``t[m]``, scaled to unit noise gain: ``[k, c]``, one row per window spanning at most
    ``max_span`` seconds (none across a gap). Zero for any constant-acceleration motion; for white
    noise of standard deviation sigma, each value has standard deviation sigma."""
    if t.size < 4:
        return np.empty((0, y.shape[1]))
    w = np.stack([t[j : t.size - 3 + j] for j in range(4)], axis=1)  # [k, 4] window stamps
    keep = (w[:, 3] - w[:, 0]) <= max_span
    w = w[keep]
    w = w - w[:, :1]
    c = np.empty_like(w)
    for j in range(4):
        others = [w[:, o] for o in range(4) if o != j]
        c[:, j] = 1.0 / ((w[:, j] - others[0]) * (w[:, j] - others[1]) * (w[:, j] - others[2]))
    c /= np.linalg.norm(c, axis=1, keepdims=True)
    idx = np.nonzero(keep)[0][:, None] + np.arange(4)
    return np.einsum('kj,kjc->kc', c, y[idx])


def estimate_noise(tracks: Sequence[Tuple[np.ndarray, np.ndarray]], max_span: float) -> Tuple[float, int]:
    """The position noise standard deviation (m) pooled over ``tracks`` ``[(t[m], y[m, c])]``, and
    the number of residuals behind it: 1.4826 x the median absolute residual of
    :func:`noise_residuals` (robust to the odd outlier or manoeuvre)."""
    res = [noise_residuals(t, y, max_span).ravel() for t, y in tracks]
    res = np.concatenate(res) if res else np.empty(0)
    if res.size == 0:
        return float('nan'), 0
    return float(1.4826 * np.median(np.abs(res))), int(res.size)


def _precision(eta: np.ndarray) -> np.ndarray:
    """``[k, 3, 3]``: inverse of the white-jerk process covariance over steps ``eta[k]`` (unit
    intensity, scaled state ``(p, v, a)``)."""
    e = eta[:, None, None]
    m = np.array([[720.0, -360.0, 60.0], [-360.0, 192.0, -36.0], [60.0, -36.0, 9.0]])
    powers = np.array([[5, 4, 3], [4, 3, 2], [3, 2, 1]])
    return m / e**powers


def _transition(eta: np.ndarray) -> np.ndarray:
    f = np.zeros((eta.size, 3, 3))
    f[:, 0, 0] = f[:, 1, 1] = f[:, 2, 2] = 1.0
    f[:, 0, 1] = f[:, 1, 2] = eta
    f[:, 0, 2] = eta * eta / 2
    return f


def _normal_equations(eta: np.ndarray, ratio: float) -> np.ndarray:
    """Upper banded form ``[6, 3m]`` of the normal matrix (in units of the measurement precision)
    for steps ``eta[m - 1]`` and process / measurement noise ``ratio``."""
    m = eta.size + 1
    W = _precision(eta) / ratio
    F = _transition(eta)
    FtW = np.einsum('kji,kjl->kil', F, W)
    blocks_kk = np.einsum('kij,kjl->kil', FtW, F)  # F^T W F on state k
    n = 3 * m
    ab = np.zeros((_BAND + 1, n))

    def add(row0: int, col0: int, blocks: np.ndarray) -> None:
        # blocks[k] goes to rows 3(k + row0).., cols 3(k + col0)..; keep the upper triangle only
        for i in range(3):
            for j in range(3):
                rows = 3 * (np.arange(blocks.shape[0]) + row0) + i
                cols = 3 * (np.arange(blocks.shape[0]) + col0) + j
                ok = rows <= cols
                np.add.at(ab, (_BAND + rows[ok] - cols[ok], cols[ok]), blocks[ok, i, j])

    add(0, 0, blocks_kk)
    add(1, 1, W)
    add(0, 1, -FtW)
    ab[_BAND, 0::3] += 1.0  # every state is measured (position, unit precision)
    ab[_BAND] += 1e-12  # a vanishing prior keeps three samples or fewer posed
    return ab


def _solve(t: np.ndarray, y: np.ndarray, ratio: float):
    """Scaled smoothing of one track: ``(states [3m, c], log det of the normal matrix, the minimised
    cost x sigma^2, median interval, steps in median intervals)``."""
    h0 = float(np.median(np.diff(t)))
    eta = np.diff(t) / h0
    ab = _normal_equations(eta, ratio)
    u = cholesky_banded(ab, lower=False)
    origin = y[0]  # the model ignores a constant offset; removing it keeps the numbers small
    b = np.zeros((3 * t.size, y.shape[1]))
    b[0::3] = y - origin
    z = cho_solve_banded((u, False), b)
    logdet = 2.0 * float(np.sum(np.log(u[_BAND])))
    # the cost summed term by term (all non-negative) rather than as y'y - b'z, which cancels
    x = z.reshape(t.size, 3, -1)
    e = x[1:] - np.einsum('kij,kjc->kic', _transition(eta), x[:-1])
    cost = float(np.sum((b[0::3] - x[:, 0]) ** 2) + np.einsum('kic,kij,kjc->', e, _precision(eta), e) / ratio)
    z[0::3] += origin
    return z, logdet, cost, h0, eta


def _log_likelihood(tracks, sigma: float, ratio: float) -> float:
    """Log-likelihood (up to a constant) of the samples under the white-jerk model with process
    intensity ``ratio`` x sigma^2 (scaled time) and measurement noise sigma."""
    total = 0.0
    for t, y in tracks:
        if t.size < 4:
            continue
        _, logdet, fit, _, eta = _solve(t, y, ratio)
        c = y.shape[1]
        # det of each step's process covariance: eta^9 / 8640 x (ratio sigma^2)^3
        logdet_q = np.sum(9 * np.log(eta)) + eta.size * 3 * np.log(ratio)
        total -= 0.5 * (c * (logdet_q + logdet) + fit / sigma**2)
    return total


def choose_process_noise(tracks: Sequence[Tuple[np.ndarray, np.ndarray]], sigma: float) -> float:
    """The process / measurement noise ratio (white-jerk intensity x median interval^5 / sigma^2)
    that maximises the likelihood of ``tracks`` ``[(t[m], y[m, c])]`` given noise ``sigma``:
    a search over decades, refined by a parabola through the best three."""
    ll = np.array([_log_likelihood(tracks, sigma, r) for r in _RATIOS])
    k = int(np.clip(np.argmax(ll), 1, _RATIOS.size - 2))
    x = np.log(_RATIOS[k - 1 : k + 2])
    a, b, _ = np.polyfit(x, ll[k - 1 : k + 2], 2)
    best = -b / (2 * a) if a < 0 else x[1]
    return float(np.exp(np.clip(best, x[0], x[2])))


def smooth(t: np.ndarray, y: np.ndarray, ratio: float) -> SmoothedTrack:
    """The smoothed track of samples ``y[m, c]`` at stamps ``t[m]`` (m >= 2)."""
    if t.size <= 3:
        return _through(t, y)
    z, _, _, h0, _ = _solve(t, y, ratio)
    return SmoothedTrack(t, z[0::3], z[1::3] / h0, z[2::3] / (h0 * h0))


def _through(t: np.ndarray, y: np.ndarray) -> SmoothedTrack:
    """Two or three samples: the smoother's answer is the line or parabola through them (no jerk,
    no residual), here in closed form: at small ratios its normal equations are too ill-conditioned
    to solve (a Cholesky failure)."""
    s = t - t[0]
    coef = np.linalg.solve(np.vander(s, t.size, increasing=True), y)  # [m, c], increasing powers
    v = sum(k * coef[k] * s[:, None] ** (k - 1) for k in range(1, t.size))
    a = sum(k * (k - 1) * coef[k] * s[:, None] ** (k - 2) for k in range(2, t.size)) + np.zeros_like(y)
    return SmoothedTrack(t, y.astype(np.float64), v + np.zeros_like(y), a)


def smooth_tracks(
    tracks: Sequence[Tuple[np.ndarray, np.ndarray]], max_span: float
) -> Tuple[List[SmoothedTrack], dict]:
    """Estimate the noise, choose the process noise and smooth every track; the record of what was
    estimated (``noise_std`` in m, ``process_ratio``, ``residuals``) for the importer's meta."""
    sigma, count = estimate_noise(tracks, max_span)
    used = max(sigma, NOISE_FLOOR) if np.isfinite(sigma) else NOISE_FLOOR
    ratio = choose_process_noise(tracks, used)
    return [smooth(t, y, ratio) for t, y in tracks], {
        'noise_std': sigma,
        'noise_std_used': used,
        'residuals': count,
        'process_ratio': ratio,
    }
