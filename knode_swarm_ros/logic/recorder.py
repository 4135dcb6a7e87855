"""What the recorder does, without ROS: collect states into frames and build a trajectory.

:class:`FrameCollector` files robot states by step (``round(stamp / dt)``), knows which frames
are complete (every robot present) and builds the ``[T, n, d]`` array of a trajectory file on
a regular grid of steps (``frame_every``: 1 in lockstep, the publishing period in real time).
A robot missing from a frame (a lost message) is filled with its state in the previous frame
(the next one for the first frame) and counted, so a file always has a single dt.

:meth:`FrameCollector.receive` applies the agents' checks to every stamped state before it is
filed, so that one bad message can neither invent frames nor make the file unwritable: a stamp
before the run (negative), older than ``max_age`` or more than ``future_tolerance`` ahead of the
node's clock, or off the step grid (more than 1 % of dt away from a multiple of dt) is dropped
and counted, as are non-finite states. The frame grid is anchored at the steps most states
arrived on, so a stray frame off it cannot shift the grid away from the real ones.
"""

from __future__ import annotations

import math
from collections import Counter
from typing import Any, Dict, List, Optional, Tuple

import numpy as np

from knode_swarm_ros.core.metrics import amd, avd
from knode_swarm_ros.core.scenarios import get_scenario

__all__ = ['FrameCollector', 'swarm_metrics']


def swarm_metrics(frame: np.ndarray, scenario: str) -> Tuple[float, float]:
    """(avd, amd) of one frame ``[n, d]``: avd over the velocities (``position_velocity``) or
    unit headings (``position_heading``, heading alignment), NaN for a ``position`` state (it
    holds no velocity); amd over the positions. NaN for fewer than 2 robots."""
    spec = get_scenario(scenario)
    if frame.shape[0] < 2:
        return math.nan, math.nan
    p = spec.position_dim
    spread = float(avd(frame[:, p:])) if spec.state_dim > p else math.nan
    return spread, float(amd(frame[:, :p]))


class FrameCollector:
    """States of robots ``0 .. robots-1`` by step (see the module doc)."""

    def __init__(
        self,
        scenario: str,
        robots: int,
        dt: Optional[float] = None,
        max_age: float = 5.0,
        future_tolerance: float = 0.5,
    ):
        self.spec = get_scenario(scenario)
        self.dt = float(dt or self.spec.dt)
        self.max_age_ns = int(round(max_age * 1e9))
        self.future_ns = int(round(future_tolerance * 1e9))
        self.scenario = scenario
        self.n = int(robots)
        self.frames: Dict[int, np.ndarray] = {}  # step -> [n, d], NaN where missing
        self.count: Dict[int, int] = {}  # step -> robots present
        self.heard = set()
        self.counters = {
            'accepted': 0,
            'duplicate': 0,
            'malformed': 0,
            'unknown_id': 0,
            'bad_size': 0,
            'non_finite': 0,
            'too_old': 0,
            'too_future': 0,
            'off_grid': 0,
        }
        self._newest_ns: Optional[int] = None
        self.progress = -1  # newest step with every grid frame up to it complete
        self._every = 1

    @property
    def ready(self) -> bool:
        """Every robot heard at least once."""
        return len(self.heard) == self.n

    def set_every(self, every: int) -> None:
        """Grid spacing of complete frames for :attr:`progress`."""
        self._every = max(1, int(every))

    def receive(self, robot: int, stamp_ns: int, z, now_ns: Optional[int] = None) -> str:
        """Check the stamp of ``robot``'s state ``z [d]`` against the step grid and the node's
        clock ``now_ns`` (None or <= 0 while unknown or not the simulation's: the newest stamp
        filed is the reference instead, with ``max_age`` both ways), then :meth:`add` it.
        Returns ``accepted``, ``duplicate`` or the reason it was dropped."""
        stamp_ns = int(stamp_ns)
        dt_ns = self.dt * 1e9
        step = int(round(stamp_ns / dt_ns))
        clock = now_ns is not None and now_ns > 0
        ref = now_ns if clock else self._newest_ns  # without a clock: the newest state filed
        ahead = self.future_ns if clock else self.max_age_ns
        reason = None
        if stamp_ns < 0 or (ref is not None and stamp_ns < ref - self.max_age_ns):
            reason = 'too_old'
        elif ref is not None and stamp_ns > ref + ahead:
            reason = 'too_future'
        elif abs(stamp_ns - step * dt_ns) > 0.01 * dt_ns:
            reason = 'off_grid'
        if reason is not None:
            self.counters[reason] += 1
            return reason
        outcome = self.add(robot, step, z)
        if outcome == 'accepted' and (self._newest_ns is None or stamp_ns > self._newest_ns):
            self._newest_ns = stamp_ns
        return outcome

    def add(self, robot: int, step: int, z) -> str:
        """File ``z [d]`` of ``robot`` at ``step``; returns ``accepted``, ``duplicate`` or a drop reason."""
        if not 0 <= robot < self.n:
            self.counters['unknown_id'] += 1
            return 'unknown_id'
        z = np.asarray(z, dtype=np.float64)
        if z.shape != (self.spec.state_dim,):
            self.counters['bad_size'] += 1
            return 'bad_size'
        if not np.all(np.isfinite(z)):
            self.counters['non_finite'] += 1
            return 'non_finite'
        frame = self.frames.get(step)
        if frame is None:
            frame = self.frames[step] = np.full((self.n, self.spec.state_dim), np.nan)
            self.count[step] = 0
        if not np.isnan(frame[robot, 0]):
            self.counters['duplicate'] += 1
            return 'duplicate'
        frame[robot] = z
        self.count[step] += 1
        self.heard.add(robot)
        self.counters['accepted'] += 1
        self._advance_progress()
        return 'accepted'

    def complete(self, step: int) -> bool:
        """Whether every robot's state at ``step`` is here."""
        return self.count.get(step, 0) == self.n

    def _advance_progress(self) -> None:
        if not self.frames:
            return
        nxt = self._first(self._every) if self.progress < 0 else self.progress + self._every
        while self.complete(nxt):
            self.progress = nxt
            nxt += self._every

    def steps(self) -> List[int]:
        """Steps that have at least one state, ascending."""
        return sorted(self.frames)

    def infer_every(self) -> int:
        """The grid spacing implied by the steps seen (gcd of their differences; 1 if unclear)."""
        steps = self.steps()
        if len(steps) < 2:
            return 1
        return max(1, int(np.gcd.reduce(np.diff(steps))))

    def _first(self, every: int) -> int:
        """First step of the frame grid: the earliest step on the residue (mod ``every``) that
        most states arrived on."""
        if every <= 1:
            return min(self.frames)
        votes = Counter()
        for step, count in self.count.items():
            votes[step % every] += count
        residue = max(votes, key=lambda r: (votes[r], -r))
        return min(s for s in self.frames if s % every == residue)

    def build(
        self, every: Optional[int] = None, last: Optional[int] = None
    ) -> Tuple[np.ndarray, Dict[str, Any]]:
        """``states [T, n, d]`` on the grid first, first + every, ... <= last (default: the newest
        step), and facts about it: first_step, frame_every, filled entries, incomplete frames."""
        if not self.frames:
            raise ValueError('no state recorded')
        every = max(1, int(every or self.infer_every()))
        first = self._first(every)
        last = max(self.frames) if last is None else int(last)
        grid = list(range(first, max(last, first) + 1, every))
        out = np.full((len(grid), self.n, self.spec.state_dim), np.nan)
        for t, step in enumerate(grid):
            frame = self.frames.get(step)
            if frame is not None:
                out[t] = frame
        missing = np.isnan(out[..., 0])
        incomplete = int(np.count_nonzero(missing.any(axis=1)))
        filled = int(np.count_nonzero(missing))
        never = [r for r in range(self.n) if missing[:, r].all()]
        if never:
            raise ValueError(f'robot(s) {never} were never recorded on the frame grid')
        for t in range(1, len(grid)):  # forward fill
            gap = missing[t]
            out[t, gap] = out[t - 1, gap]
        for t in range(len(grid) - 2, -1, -1):  # backward fill what precedes a robot's first state
            gap = np.isnan(out[t, :, 0])
            out[t, gap] = out[t + 1, gap]
        info = {
            'first_step': first,
            'last_step': grid[-1],
            'frame_every': every,
            'frames': len(grid),
            'filled_entries': filled,
            'incomplete_frames': incomplete,
        }
        return out, info
