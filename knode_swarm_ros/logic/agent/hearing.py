"""What an agent process hears, filed once: the states, why some were dropped, and snapshots.

A lone agent has one :class:`Hearing`. A process hosting several robots (:mod:`.hosted`)
has one for all of them: its robots subscribe to the same topics and check every state by the
same rules on the same clock, so each robot's own buffer would hold exactly the same states
(the same drops, the same duplicates); the process files each state once and every hosted
robot reads it as its own. A robot whose hearing differs from its process-mates' (a link model
with its own losses) cannot share one, and the ``agents`` node refuses such options.

Snapshots (:class:`Rows`) are what the neighbour-matrix builder needs, gathered once per step and
shared by every robot that asks for the same step: :meth:`Hearing.exact` (lockstep: each robot's
state filed at exactly step s) and :meth:`Hearing.delayed` (realtime: the state at or before
s - tau of every robot heard within ``state_timeout``).
"""

from __future__ import annotations

from collections.abc import MutableMapping
from typing import Any, Dict, List, Optional, Sequence, Tuple

import numpy as np

from knode_swarm_ros.core.delay_buffer import DelayBuffer

__all__ = ['Hearing', 'Rows', 'Counters', 'DROP_REASONS', 'RECEIPT']

#: Reasons a state is dropped for (each has a counter).
DROP_REASONS = ('malformed', 'unknown_id', 'bad_size', 'non_finite', 'too_old', 'too_future')
#: The receipt counters (the same for every robot of a process).
RECEIPT = ('received', 'accepted', 'duplicate', *DROP_REASONS)


class Rows:
    """States of several robots at one step: ``ids`` (ascending), ``Z [r, d]``, ``index`` id -> row."""

    __slots__ = ('ids', 'Z', 'index')

    def __init__(self, ids: Sequence[int], states: List[np.ndarray], d: int):
        self.ids = tuple(ids)
        self.Z = np.stack(states) if states else np.zeros((0, d))
        self.index = {rid: n for n, rid in enumerate(self.ids)}

    def with_row(self, robot: int, z: np.ndarray) -> 'Rows':
        """A copy with ``robot``'s row added (ids stay ascending)."""
        pairs = sorted([*zip(self.ids, self.Z), (robot, z)], key=lambda p: p[0])
        return Rows([p[0] for p in pairs], [p[1] for p in pairs], self.Z.shape[1])

    def __len__(self) -> int:
        return len(self.ids)


class Hearing:
    """The delay buffer, newest stamps, receipt counters and snapshots of one process.

    Args:
        state_dim: d; ids: the swarm's robot ids; dt, tau: the policy's; timeout_ns,
        future_ns: ``state_timeout`` and ``future_tolerance`` in nanoseconds.
    """

    def __init__(
        self, state_dim: int, ids: Sequence[int], dt: float, tau: int, timeout_ns: int, future_ns: int
    ):
        self.d = int(state_dim)
        self.ids: List[int] = sorted(int(i) for i in ids)
        self.known = frozenset(self.ids)
        self.dt, self.tau = float(dt), int(tau)
        self.timeout_ns, self.future_ns = int(timeout_ns), int(future_ns)
        self.buffer = DelayBuffer(self.dt, self.tau, horizon=max(64, 4 * self.tau + 8))
        self.newest_ns: Dict[int, int] = {}  # newest stamp heard per robot
        self.counters: Dict[str, int] = {name: 0 for name in RECEIPT}
        self.last_drop: Optional[Tuple[str, int, int]] = None  # (reason, robot, stamp_ns)
        self._count: Dict[int, int] = {}  # step -> states filed at exactly that step
        self._exact: Dict[int, Rows] = {}  # step -> snapshot (dropped when that step gets a state)
        self._delayed: Dict[
            Tuple[int, Optional[int]], Rows
        ] = {}  # (step, now) -> snapshot (any filing clears)
        self._live = (None, 0)  # (now_ns, robots heard within the timeout at now): live_count

    def key(self) -> Tuple:
        """What must agree for robots to share this hearing."""
        return (tuple(self.ids), self.d, self.dt, self.tau, self.timeout_ns, self.future_ns)

    # --- filing ---------------------------------------------------------------------
    def check(self, robot, stamp_ns, z, now_ns) -> Optional[str]:
        """The drop reason of a state (None: acceptable), before the duplicate check."""
        if robot is None or robot not in self.known:
            return 'unknown_id'
        z = np.asarray(z)
        if z.shape != (self.d,):
            return 'bad_size'
        if not np.isfinite(z).all():  # (the array method: no numpy dispatch, once per message)
            return 'non_finite'
        if now_ns is not None and now_ns > 0:
            if stamp_ns < now_ns - self.timeout_ns:
                return 'too_old'
            if stamp_ns > now_ns + self.future_ns:
                return 'too_future'
        return None

    def file(
        self,
        robot,
        stamp_ns: int,
        z,
        now_ns: Optional[int] = None,
        verdict: Any = '',
        step: Optional[int] = None,
    ) -> Tuple[str, Optional[int]]:
        """File robot ``robot``'s state ``z [d]``: ``(outcome, step)``, outcome ``accepted``,
        ``duplicate`` (a step already filed: the first copy wins) or a drop reason (step None).
        ``verdict``: :meth:`check`'s result when the caller has it already; ``step``: the step
        it stands for when the caller chose it (a pose stream's :class:`StepSampler`), else the
        stamp's nearest."""
        c = self.counters
        c['received'] += 1
        reason = self.check(robot, stamp_ns, z, now_ns) if verdict == '' else verdict
        if reason is not None:
            c[reason] += 1
            self.last_drop = (reason, -1 if robot is None else int(robot), int(stamp_ns))
            return reason, None
        robot = int(robot)
        step = self.buffer.step_of(stamp_ns * 1e-9) if step is None else int(step)
        if not self.buffer.add(robot, stamp_ns * 1e-9, np.asarray(z, dtype=np.float64), step):
            c['duplicate'] += 1
            return 'duplicate', step
        c['accepted'] += 1
        before = self.newest_ns.get(robot, -1)
        if stamp_ns > before:
            self.newest_ns[robot] = int(stamp_ns)
            now_live, live = self._live
            if now_live is not None and before < now_live - self.timeout_ns <= stamp_ns:
                self._live = (now_live, live + 1)  # heard again (or first): live at that clock now
        self._count[step] = self._count.get(step, 0) + 1
        self._exact.pop(step, None)
        if self._delayed:
            self._delayed.clear()
        if len(self._count) > 4 * self.buffer.horizon:
            cut = step - 2 * self.buffer.horizon
            for s in [s for s in self._count if s < cut]:
                del self._count[s]
        return 'accepted', step

    def malformed(self) -> str:
        """Count a message that could not be decoded at all."""
        self.counters['received'] += 1
        self.counters['malformed'] += 1
        self.last_drop = ('malformed', -1, -1)
        return 'malformed'

    # --- lookups ----------------------------------------------------------------------
    def count_at(self, step: int) -> int:
        """States filed at exactly ``step`` (never fewer than the buffer holds there)."""
        return self._count.get(step, 0)

    def complete(self, step: int, expected: int, me: Optional[int] = None) -> bool:
        """The states of ``step`` are all in for robot ``me``, which awaits ``expected`` robots
        (itself included): filed by at least ``expected``, one fewer when ``me``'s own state of
        ``step`` is lost (it is not awaited). ``me`` None: all in for some robot whose own state
        there may be lost (the hint to look at every waiting robot of a process)."""
        own_lost = True if me is None else self.buffer.get(me, step) is None
        return self.count_at(step) + own_lost >= expected

    def live_count(self, now_ns: Optional[int]) -> int:
        """Robots heard within ``state_timeout`` at ``now_ns`` (every robot of the swarm while the
        clock is unknown: before it runs nobody can be judged silent): those a realtime tick waits
        for (:mod:`.realtime_tick`). Counted once per clock value, then kept up to date as states
        are filed."""
        if now_ns is None or now_ns <= 0:
            return len(self.ids)
        if self._live[0] != now_ns:
            cut = now_ns - self.timeout_ns
            self._live = (now_ns, sum(1 for ns in self.newest_ns.values() if ns >= cut))
        return self._live[1]

    def exact(self, step: int) -> Rows:
        """Each robot's state filed at exactly ``step`` (robots without one left out)."""
        rows = self._exact.get(step)
        if rows is None:
            ids, states = [], []
            for rid in self.ids:
                z = self.buffer.get(rid, step)
                if z is not None:
                    ids.append(rid)
                    states.append(z)
            rows = self._exact[step] = Rows(ids, states, self.d)
            if len(self._exact) > 8:
                del self._exact[min(self._exact)]
        return rows

    def delayed(self, step: int, now_ns: Optional[int]) -> Rows:
        """Realtime: for every robot heard (and, with the clock known, within the timeout at
        ``now_ns``), its newest state at or before ``step - tau``."""
        key = (step, now_ns)
        rows = self._delayed.get(key)
        if rows is None:
            clock_known = now_ns is not None and now_ns > 0
            ids, states = [], []
            for rid in self.ids:
                newest = self.newest_ns.get(rid)
                if newest is None or (clock_known and now_ns - newest > self.timeout_ns):
                    continue  # never heard, or silent longer than the timeout: not a neighbour
                ids.append(rid)
                states.append(self.buffer.delayed(rid, step))
            rows = self._delayed[key] = Rows(ids, states, self.d)
        return rows


class Counters(MutableMapping):
    """One robot's counters: the receipt counters of its :class:`Hearing` (shared by the robots
    of a process) followed by its own (``commands``, ``resent``, ...); reads like one dict."""

    def __init__(self, receipt: Dict[str, int], own: Dict[str, int]):
        self._receipt, self._own = receipt, own

    def _where(self, key: str) -> Dict[str, int]:
        return self._own if key in self._own else self._receipt

    def __getitem__(self, key: str) -> int:
        return self._where(key)[key]

    def __setitem__(self, key: str, value: int) -> None:
        if key not in self._own and key not in self._receipt:
            raise KeyError(key)
        self._where(key)[key] = value

    def __delitem__(self, key: str) -> None:
        raise TypeError('counters cannot be removed')

    def __iter__(self):
        yield from self._receipt
        yield from self._own

    def __len__(self) -> int:
        return len(self._receipt) + len(self._own)

    def __repr__(self) -> str:
        return repr(dict(self))
