"""What a robot has heard: states of every robot by time step, for tau-delayed lookups.

Messages arrive with stamps, late, out of order or not at all. The buffer files each
state under its step index ``round(stamp / dt)`` and answers "the state of robot j at
step s" with the newest state at or before s (a gap is bridged by the last state heard;
before the first state heard, the earliest one is used, as docs/DESIGN.md fixes for t < tau).
"""

from __future__ import annotations

import bisect
from typing import Dict, List, Optional, Tuple

import numpy as np

__all__ = ['DelayBuffer']


class DelayBuffer:
    """Per-robot state history keyed by integer step.

    Args:
        dt: seconds per step.
        tau: delay in steps used by :meth:`delayed`.
        horizon: steps of history kept behind each robot's newest state (>= tau).
    """

    def __init__(self, dt: float, tau: int = 0, horizon: int = 64):
        if dt <= 0:
            raise ValueError(f'dt must be > 0, got {dt}')
        if tau < 0:
            raise ValueError(f'tau must be >= 0, got {tau}')
        self.dt = float(dt)
        self.tau = int(tau)
        self.horizon = max(int(horizon), self.tau + 1)
        self._steps: Dict[int, List[int]] = {}
        self._states: Dict[int, Dict[int, np.ndarray]] = {}

    def step_of(self, stamp: float) -> int:
        """Step index of a stamp in seconds."""
        return int(round(stamp / self.dt))

    def add(self, robot: int, stamp: float, state, step: Optional[int] = None) -> bool:
        """File ``state [d]`` of ``robot`` at ``stamp`` under ``step`` (default: the stamp's
        nearest, :meth:`step_of`); a repeated step keeps the first (returns False)."""
        step = self.step_of(stamp) if step is None else int(step)
        steps = self._steps.setdefault(robot, [])
        states = self._states.setdefault(robot, {})
        if step in states:
            return False
        bisect.insort(steps, step)
        states[step] = np.array(state, dtype=np.float64)
        self._prune(robot)
        return True

    def _prune(self, robot: int) -> None:
        steps = self._steps[robot]
        cut = steps[-1] - self.horizon
        # Keep the newest entry at or before the cut so lookups inside the horizon still work.
        drop = bisect.bisect_right(steps, cut) - 1
        if drop > 0:
            for s in steps[:drop]:
                del self._states[robot][s]
            del steps[:drop]

    def robots(self) -> List[int]:
        """Ids heard from, ascending."""
        return sorted(r for r, s in self._steps.items() if s)

    def latest(self, robot: int) -> Optional[Tuple[int, np.ndarray]]:
        """(step, state) of the newest state of ``robot``, or None if never heard."""
        steps = self._steps.get(robot)
        if not steps:
            return None
        return steps[-1], self._states[robot][steps[-1]]

    def get(self, robot: int, step: int) -> Optional[np.ndarray]:
        """The state filed at exactly ``step``, or None."""
        return self._states.get(robot, {}).get(step)

    def at(self, robot: int, step: int) -> Optional[np.ndarray]:
        """Newest state at or before ``step``; the earliest state if all are later; None if never heard."""
        steps = self._steps.get(robot)
        if not steps:
            return None
        i = bisect.bisect_right(steps, step) - 1
        return self._states[robot][steps[max(i, 0)]]

    def delayed(self, robot: int, step: int) -> Optional[np.ndarray]:
        """State of ``robot`` at ``step - tau`` (see :meth:`at`)."""
        return self.at(robot, step - self.tau)

    def forget(self, robot: int) -> None:
        """Drop everything heard from ``robot``."""
        self._steps.pop(robot, None)
        self._states.pop(robot, None)
