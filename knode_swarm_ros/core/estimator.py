"""Velocities from a pose stream: one causal estimator for deployment, recordings and the offline rollout.

Motion capture gives positions only; a scenario whose state holds velocities (``flock2d``,
``boids3d``) then needs them estimated. :class:`VelocityEstimator` fits a straight line, by least
squares, to the newest ``window`` (time, position) samples of a robot and returns its slope:

    v_hat = sum_j w_j p_j,   w_j = (t_j - t_bar) / sum_k (t_k - t_bar)^2

(t_bar the mean sample time). It is causal (only samples already heard) and uses the samples'
own stamps, so an uneven stream is handled as it is.

Properties (N = ``window`` samples, spaced h seconds, position noise sigma per axis):

* exact for a constant velocity as soon as two samples are in (fewer than N: the fit uses
  what it has; one sample: velocity 0, nothing is known yet);
* lag: for any signal whose velocity changes linearly (constant acceleration) the slope is the
  velocity at the window's mean time, so the estimate lags by ``(N - 1) h / 2`` seconds; after a
  step in velocity the estimate is exact again once the N samples all lie after the step;
* noise gain: white position noise gives a velocity error of standard deviation
  ``sigma * sqrt(12 / (N (N^2 - 1))) / h`` per axis (:func:`noise_gain`).

Cost: :meth:`VelocityEstimator.push` only stores a sample; the fit is made when
:attr:`VelocityEstimator.velocity` is read (once per sample read, cached), so a stream faster
than the policy costs one fit per filed state, not one per sample.

Which sample stands for a step (:class:`StepSampler`): the newest sample at or before the step's
time ``stamp_ns(s) = round(s dt 1e9)``. A sample stamped exactly on a step is filed at once; a
sample between steps is filed (for the newest step it precedes) when the next sample shows that
no newer one at or before that step will come (one sample of extra latency; a stream on the grid,
as the simulator's, has none). The agents and the offline rollout (which observes on the grid)
both apply it, so they file the same samples.

Equality across paths: the agent estimates robot by robot (``p [d]``) and the offline rollout
all robots at once (``p [..., n, d]``); both accumulate the same weights in the same order with
elementwise operations only, so their estimates are equal bit for bit. Stamps are integer
nanoseconds (the nodes' stamps), taken relative to the newest.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Deque, Optional, Tuple

import numpy as np

__all__ = [
    'VelocityEstimator',
    'DEFAULT_WINDOW',
    'DEFAULT_LAG_S',
    'window_for_rate',
    'noise_gain',
    'lag_s',
    'fit_weights',
    'StepSampler',
    'step_at_or_before',
    'CommandAidedEstimator',
    'OWN_WINDOW_FACTOR',
]

#: The own robot's fit (:class:`CommandAidedEstimator`) spans this many times the window.
OWN_WINDOW_FACTOR = 5

#: The default lag (seconds): the 100 Hz design point's 10 samples. At 2 mm of noise per axis it
#: gives 22 mm/s of velocity noise at 100 Hz; a slower stream gets the same lag from fewer samples
#: (more noise: 28 mm/s at 20 Hz, 3 samples), a faster one less noise.
DEFAULT_LAG_S = 0.045

#: Samples per fit when the stream's rate is not stated: the 100 Hz window of DEFAULT_LAG_S.
DEFAULT_WINDOW = 10


def window_for_rate(rate_hz: float, lag: float = DEFAULT_LAG_S) -> int:
    """The window of about ``lag`` seconds of lag at ``rate_hz`` samples per second:
    ``max(2, 1 + round(2 lag rate))`` (the inverse of :func:`lag_s`; 10 at 100 Hz, 3 at 20 Hz)."""
    return max(2, 1 + int(round(2.0 * float(lag) * float(rate_hz))))


def noise_gain(window: int, period_s: float) -> float:
    """Velocity standard deviation per unit of position noise: ``sqrt(12 / (N (N^2 - 1))) / h``."""
    n = int(window)
    return math.sqrt(12.0 / (n * (n * n - 1))) / float(period_s)


def lag_s(window: int, period_s: float) -> float:
    """The estimate's lag in seconds for an evenly spaced stream: ``(N - 1) h / 2``."""
    return (int(window) - 1) * float(period_s) / 2.0


def fit_weights(stamps_ns) -> Tuple[float, ...]:
    """Least-squares slope weights ``w_j`` (``v = sum w_j p_j``) of samples stamped ``stamps_ns``
    (oldest first); all zero for a single sample."""
    newest = int(stamps_ns[-1])
    t = [(int(s) - newest) * 1e-9 for s in stamps_ns]
    mean = sum(t) / len(t)
    spread = sum((x - mean) ** 2 for x in t)
    if spread <= 0.0:
        return tuple(0.0 for _ in t)
    return tuple((x - mean) / spread for x in t)


class VelocityEstimator:
    """Causal least-squares velocity of one pose stream (one robot, or every robot at once).

    Args:
        window: N, the number of newest samples the line is fitted to (>= 2).

    ``update(stamp_ns, p)`` takes a position ``p [..., dim]`` and returns the velocity estimate
    ``[..., dim]`` (float64). A sample not newer than the newest one is ignored (a repeated or
    late message) and the current estimate returned.
    """

    def __init__(self, window: int = DEFAULT_WINDOW):
        if int(window) < 2:
            raise ValueError(f'the velocity window must hold >= 2 samples, got {window}')
        self.window = int(window)
        self._stamps: Deque[int] = deque(maxlen=self.window)
        self._positions: Deque[np.ndarray] = deque(maxlen=self.window)
        self._velocity: Optional[np.ndarray] = None

    @property
    def newest_ns(self) -> Optional[int]:
        """Stamp of the newest sample used (None before any)."""
        return self._stamps[-1] if self._stamps else None

    def push(self, stamp_ns: int, position) -> bool:
        """Add a sample without fitting (False: not newer than the newest, ignored)."""
        stamp_ns = int(stamp_ns)
        if self._stamps and stamp_ns <= self._stamps[-1]:
            return False
        self._stamps.append(stamp_ns)
        self._positions.append(np.array(position, dtype=np.float64, copy=True))
        self._velocity = None
        return True

    @property
    def velocity(self) -> Optional[np.ndarray]:
        """The estimate at the newest sample ``[..., dim]`` (None before any sample)."""
        if self._velocity is None and self._stamps:
            weights = fit_weights(self._stamps)
            v = np.zeros_like(self._positions[-1])
            for w, p in zip(weights, self._positions):  # one fixed order: equal results across shapes
                v = v + w * p
            self._velocity = v
        return self._velocity

    def update(self, stamp_ns: int, position) -> np.ndarray:
        """Add a sample and return the velocity estimate ``[..., dim]``."""
        self.push(stamp_ns, position)
        return self.velocity


def step_at_or_before(stamp_ns: int, dt: float) -> int:
    """The newest step s whose time ``round(s dt 1e9)`` ns is at or before ``stamp_ns``."""
    step_ns = float(dt) * 1e9
    s = int(round(int(stamp_ns) / step_ns))
    return s if int(round(s * step_ns)) <= int(stamp_ns) else s - 1


class StepSampler:
    """Which samples of one stream stand for the steps of ``dt``: the newest at or before each.

    ``push(stamp_ns)`` for every sample in order returns ``(previous_step, this_step)``: the
    step the previous sample stands for, now that this one is past that step's time (None: none),
    and the step this sample stands for (None unless it is stamped exactly on a step). A sample
    not newer than the previous one returns ``(None, None)`` and is forgotten. After a gap only
    the newest step passed is named (the steps before it have no newer sample either; a delay
    buffer bridges them).
    """

    def __init__(self, dt: float):
        if dt <= 0:
            raise ValueError(f'dt must be > 0, got {dt}')
        self.dt = float(dt)
        self._newest: Optional[int] = None  # stamp of the previous sample
        self._open = False  # the previous sample is between steps, not yet filed

    def push(self, stamp_ns: int) -> Tuple[Optional[int], Optional[int]]:
        stamp_ns = int(stamp_ns)
        if self._newest is not None and stamp_ns <= self._newest:
            return None, None
        s = step_at_or_before(stamp_ns, self.dt)
        on_step = int(round(s * self.dt * 1e9)) == stamp_ns
        previous = None
        if self._open:
            passed = s - 1 if on_step else s  # the newest step strictly after the previous sample
            if passed > step_at_or_before(self._newest, self.dt):
                previous = passed
        self._newest = stamp_ns
        self._open = not on_step
        return previous, (s if on_step else None)


class CommandAidedEstimator:
    """A robot's own velocity from its poses and the accelerations it commanded.

    A robot knows what it commanded: under a held acceleration u its position is
    ``p(t) = p0 + v0 t + q(t)``, q the double integral of the commands since the first sample.
    The residual ``p - q`` is then a straight line, fitted (:class:`VelocityEstimator`, ``window``
    samples) to give v0 plus the drift the commands do not explain; the estimate is that slope
    plus w(t), the integral of the commands. The commanded part has no lag and no noise, so the
    window can be long (noise ``sigma * sqrt(12 / (N (N^2 - 1))) / h`` with the larger N); only
    what the commands do not explain (a disturbance, a velocity loop's error) is seen with the
    fit's lag ``(N - 1) h / 2``. Exact for a robot that executes its commands.

    ``command(stamp_ns, u)``: the command held from ``stamp_ns`` (from the newest sample, if that
    is later: it cannot act on the past). ``push``/``velocity`` as :class:`VelocityEstimator`.
    Works on ``[..., dim]`` arrays elementwise, in one fixed order (one robot or all at once
    give equal results bit for bit).
    """

    def __init__(self, window: int):
        self.fit = VelocityEstimator(window)
        self._t: Optional[int] = None  # stamp the integrals below are at
        self._q = None  # double integral of the commands since the first sample
        self._w = None  # integral of the commands since the first sample
        self._u = None  # the command held now
        self._w_newest = None  # w at the newest sample
        self._pending: list = []  # (stamp, command) held from a stamp not reached yet

    def command(self, stamp_ns: int, u) -> None:
        u, stamp_ns = np.array(u, dtype=np.float64, copy=True), int(stamp_ns)
        if self._t is None or stamp_ns <= self._t:
            self._u = u  # from now (or from the first sample)
        else:
            self._pending.append((stamp_ns, u))  # a stop command stamped ahead of the poses

    def _advance(self, stamp_ns: int) -> None:
        while self._pending and self._pending[0][0] <= stamp_ns:
            at, u = self._pending.pop(0)
            self._integrate(at)
            self._u = u
        self._integrate(stamp_ns)

    def _integrate(self, stamp_ns: int) -> None:
        if self._u is not None and stamp_ns > self._t:
            s = (stamp_ns - self._t) * 1e-9
            self._q = self._q + self._w * s + 0.5 * self._u * s * s
            self._w = self._w + self._u * s
        self._t = max(self._t, stamp_ns)

    def push(self, stamp_ns: int, position) -> bool:
        stamp_ns = int(stamp_ns)
        p = np.array(position, dtype=np.float64, copy=True)
        if self._t is None:
            self._t, self._q, self._w = stamp_ns, np.zeros_like(p), np.zeros_like(p)
        elif stamp_ns <= self._t:
            return False
        self._advance(stamp_ns)
        if not self.fit.push(stamp_ns, p - self._q):
            return False
        self._w_newest = self._w
        return True

    @property
    def velocity(self) -> Optional[np.ndarray]:
        v = self.fit.velocity
        return None if v is None else v + self._w_newest
