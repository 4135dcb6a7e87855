"""Realtime ticks on the arrival of the robot's own state (``realtime_tick: state``).

The offline rollout (``core.rollout``, docs/DESIGN.md "Rollout semantics") computes the command
of step s from the states of step s (its own, and its neighbours' at s - tau) and holds it over
[s, s + 1). A free-running control timer computes from whatever own state is newest when it
fires: up to one period old, and its command lands up to one period late. Ticking when the
robot's own new state arrives keeps the command with the state it answers:

* a tick opens when an own state arrives whose stamp is at or past the next tick's time on a
  grid of one period from the previous tick's, less a quarter period of jitter (the rate limit:
  ``control_rate`` ticks per second of state time on average, whatever the odometry's rate; a
  duplicate stamp or an older state opens none; after a silence the grid restarts at the
  stamp that ends it);
* it is computed once every robot heard within ``state_timeout`` (:meth:`Hearing.live_count`)
  has its state of step ``max(s - tau, s0)`` filed (s0: the first own step), as a robot that
  waits for its neighbours' broadcasts of the same instant, or ``grace`` wall seconds
  (``period / 2``) after the own state arrived with what was heard by then (counted
  ``late_ticks``): a neighbour whose state is late is taken at its newest state before, as a
  timer would have. (Half a period: a simulator applies a command from its next step on, so one
  that lands within the period loses nothing; measured with ten agent processes on two loaded
  cores, a quarter period let 5 % of the ticks go without the last-published robots' states.)
  Such a tick opens again when a state of the step it waited for arrives after all (or a
  repeated own state of its step: the simulator re-publishes the initial state until every
  agent is ready), once: it is computed again when every awaited state is in (no grace), unless
  a newer tick opens first, and sent again with the same stamp (a simulator takes the newest
  command of a step). (Re-opened ticks that computed again at a second grace cost a loaded
  100-robot run 10-18 % more commands and policy calls.)
* the rows are those a timer tick would use at that moment (``Hearing.delayed``), the command is
  stamped with the own state's stamp;
* the control timer stays, as a watchdog: when the own state is older than ``state_timeout`` it
  publishes the stop command (docs/DESIGN.md, "Saturation and stopping").

``realtime_tick: timer`` ticks on a free-running timer instead (a robot whose odometry comes
slower than its control rate, or a comparison).
"""

from __future__ import annotations

from typing import Optional, Tuple

__all__ = ['TICK_ON', 'TickOnState', 'GraceArm']

#: What drives a realtime agent's ticks (parameter ``realtime_tick``).
TICK_ON = ('state', 'timer')


class TickOnState:
    """One robot's pending realtime tick (see the module doc).

    Args:
        period_s: the control period ``1 / control_rate`` (seconds of state time).
        grace_s: wall seconds a pending tick waits for the neighbours' states.
    """

    def __init__(self, period_s: float, grace_s: float):
        self.period_ns = int(round(period_s * 1e9))
        self.jitter_ns = self.period_ns // 4
        self.grace_s = float(grace_s)
        self.next_ns: Optional[int] = None  # the next tick's time on the grid (own-state stamps)
        self.pending: Optional[Tuple[int, int]] = None  # (own step, own stamp) waiting for neighbours
        self.since = 0.0  # wall time it arrived
        self.reopened = False  # the pending tick is a re-opened one: due only when complete
        self.first_step: Optional[int] = None  # the first own step heard
        self.incomplete: Optional[Tuple[int, int, int]] = (
            None  # (step, stamp, need) of the last tick if computed late
        )

    def own_state(self, step: int, stamp_ns: int, wall: float) -> bool:
        """An own state of ``step`` stamped ``stamp_ns`` was filed (not a duplicate) at ``wall``;
        True when it opens a tick (a pending one not yet computed is superseded)."""
        if self.first_step is None or step < self.first_step:
            self.first_step = step
        if self.next_ns is not None and stamp_ns < self.next_ns - self.jitter_ns:
            return False  # within the period of the last tick, or older
        on_grid = self.next_ns is not None and stamp_ns < self.next_ns + self.period_ns
        self.next_ns = (self.next_ns if on_grid else int(stamp_ns)) + self.period_ns
        self.incomplete, self.reopened = None, False
        self.pending = (int(step), int(stamp_ns))
        self.since = wall
        return True

    def repeated(self, step: int, wall: float) -> bool:
        """A duplicate own state of ``step`` arrived: True when it opens again a tick that was
        computed with states missing."""
        if self.incomplete is None or self.incomplete[0] != step or self.pending is not None:
            return False
        return self._reopen(wall)

    def heard(self, step: int, wall: float) -> bool:
        """A neighbour's state of ``step`` was filed: True when it opens again a tick that was
        computed without some state of that step."""
        if self.incomplete is None or self.incomplete[2] != step or self.pending is not None:
            return False
        return self._reopen(wall)

    def _reopen(self, wall: float) -> bool:
        self.pending, self.since, self.reopened = self.incomplete[:2], wall, True
        self.incomplete = None  # once
        return True

    @property
    def deadline(self) -> float:
        """Wall time the pending tick stops waiting (inf: none pending, or a re-opened one)."""
        return self.since + self.grace_s if self.pending is not None and not self.reopened else float('inf')

    def due(
        self, hearing, tau: int, me: int, now_ns: Optional[int], wall: float, force: bool = False
    ) -> Optional[Tuple[int, int, bool]]:
        """``(step, stamp, late)`` of the pending tick when it is due now (then no longer
        pending), None while it waits; ``late``: computed at the deadline with states missing.
        ``force``: due now whatever is missing (a hosting process whose first grace passed)."""
        if self.pending is None:
            return None
        step, stamp = self.pending
        need = max(step - tau, self.first_step)
        missing = not hearing.complete(need, hearing.live_count(now_ns), me)
        if missing and (self.reopened or (wall < self.since + self.grace_s and not force)):
            return None
        self.pending, self.reopened = None, False
        self.incomplete = (step, stamp, need) if missing else None
        return step, stamp, missing


class GraceArm:
    """The one-shot grace of ticks that wait for neighbours' states, on a wall timer of
    ``grace_s`` (any object with ``reset()`` and ``cancel()``, e.g. an rclpy timer): armed when a
    tick starts to wait, disarmed when none waits (one definition for the lone and hosted agents)."""

    def __init__(self, timer) -> None:
        self.timer = timer
        self.armed = False
        timer.cancel()

    def set(self, waiting: bool) -> None:
        """Arm (``waiting``) or disarm the timer; nothing when already so (a reset restarts it)."""
        if waiting != self.armed:
            self.armed = waiting
            if waiting:
                self.timer.reset()
            else:
                self.timer.cancel()
