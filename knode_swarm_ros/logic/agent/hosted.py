"""Several robots' agents in one process, without ROS: what the ``agents`` node wires to topics.

Each hosted robot runs its own :class:`AgentLogic`, the very class a lone ``agent`` runs: its
own lockstep bookkeeping (pending step, peers given up on, re-sends), counters of commands,
neighbour matrix Y_i and command. What it hears is the process's :class:`.hearing.Hearing`:
the hosted robots subscribe to the same topics and check each state by the same rules on the
same clock, so each one's buffer would be the same; the process files each state once (one
delay buffer, receipt counters, newest stamps) and every hosted robot reads it as its own.
Nothing of one robot's state of mind reaches another. A state concerns only its owner (if hosted
here) and the robots that gave up on its sender: only they react to it, and a lockstep poll
looks only at them, or, when a step's states may be complete or a timeout may have passed, at
every robot with a pending step (polling any other would return nothing).

Shared is plumbing only: one policy module, the Y_i of all due robots built by one core call per
snapshot of rows (:func:`.agent_logic.build_matrices`), one policy call per tick
(:func:`.batch.evaluate_batch`), with each robot's matrix at its swarm index in a
rollout-shaped batch when the logic asks for parity rows, so that any split of the swarm over
processes reproduces :func:`knode_swarm_ros.core.rollout` bit for bit, and the commands cleaned
as one batch (:func:`.agent_logic.clean_commands`).

Batching in lockstep: with a delay (tau >= 1) a robot's command is due as soon as its own state
arrives, so the hosted robots fall due one after the other within a step. A due request is held
until every hosted robot has one (the simulator publishes a step's states together) and then all
are evaluated in one call; a request held ``hold_s`` wall seconds (an own state lost) is
evaluated at the next poll without waiting for the rest.

Batching in realtime (ticks on the own state, :mod:`.realtime_tick`): a hosted robot's pending
tick is looked at when some step's states are all in (a step's count reaching the live robots)
or a grace has passed, so the robots of a step that the simulator published together fall due
together and go in one call; when the first of them passes its grace, every waiting one is
computed with it (they wait for the same states: one call, not one per arrival time).

Also here: :func:`parse_ids`, the ``ids`` parameter (a list or a range) of the ``agents`` node.
"""

from __future__ import annotations

import re
from dataclasses import replace
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from knode_swarm_ros.logic.common import ConfigError

from .agent_logic import AgentConfig, AgentLogic, Command, PolicyLike, Request, clean_commands
from .batch import evaluate_batch

__all__ = ['HostedAgents', 'parse_ids', 'format_ids']

_RANGE = re.compile(r'^\s*(\d+)\s*(?:\.\.|-|:)\s*(\d+)\s*$')


def parse_ids(value, name: str = 'ids') -> List[int]:
    """Robot ids from a list of integers, ``"a..b"`` / ``"a-b"`` / ``"a:b"`` (inclusive), a
    comma-separated string or one integer; sorted.

    Raises:
        ConfigError: anything else, duplicates, negative ids or no id; names ``name``.
    """
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        ids = [int(value)]
    elif isinstance(value, str):
        m = _RANGE.match(value)
        if m:
            a, b = int(m.group(1)), int(m.group(2))
            if b < a:
                raise ConfigError(f'parameter {name!r} = {value!r}: the range ends before it starts')
            ids = list(range(a, b + 1))
        else:
            parts = [p.strip() for p in value.strip().strip('[]').split(',') if p.strip()]
            if not parts or not all(p.isdigit() for p in parts):
                raise ConfigError(
                    f"parameter {name!r} = {value!r} is neither a list of ids nor a range like '0..49'"
                )
            ids = [int(p) for p in parts]
    elif isinstance(value, (list, tuple)) and all(
        isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in value
    ):
        ids = [int(v) for v in value]
    else:
        raise ConfigError(f"parameter {name!r} = {value!r} is neither a list of ids nor a range like '0..49'")
    if not ids:
        raise ConfigError(f'parameter {name!r} holds no robot id')
    if min(ids) < 0:
        raise ConfigError(f'parameter {name!r} holds a negative id: {ids}')
    if len(set(ids)) != len(ids):
        raise ConfigError(f'parameter {name!r} holds duplicates: {ids}')
    return sorted(ids)


def format_ids(ids: Sequence[int]) -> str:
    """``'3..7'`` for a run of consecutive ids, else ``'[1, 4, 9]'``."""
    ids = sorted(int(i) for i in ids)
    if len(ids) > 1 and ids == list(range(ids[0], ids[-1] + 1)):
        return f'{ids[0]}..{ids[-1]}'
    return str(ids)


class HostedAgents:
    """One :class:`AgentLogic` per hosted robot, one :class:`Hearing` and one policy call per tick.

    Args:
        hosted: the ids of the robots this process hosts (a subset of ``config.robot_ids``).
        config: the settings every hosted robot shares; ``robot_id`` is replaced per robot.
        policy: the one policy module, ``(Y [B, k, d], mask [B, k]) -> [B, m]``.
        hold_s: lockstep: wall seconds a due request waits for the other hosted robots' ones.
    """

    def __init__(self, hosted: Sequence[int], config: AgentConfig, policy: PolicyLike, hold_s: float = 0.05):
        hosted = parse_ids(list(hosted))
        missing = [i for i in hosted if i not in set(int(r) for r in config.robot_ids)]
        if missing:
            raise ConfigError(
                f"parameter 'ids': robot(s) {missing} are not among the swarm's robot ids "
                f"{format_ids(config.robot_ids)} (set 'robots' or 'robot_ids')"
            )
        self.policy = policy
        self.hosted: List[int] = hosted
        first = self._first = AgentLogic(replace(config, robot_id=hosted[0]), policy)
        self.hearing = first.hearing  # what every hosted robot hears, filed once (logic/agent/hearing.py)
        self.logics: Dict[int, AgentLogic] = {hosted[0]: first}
        for rid in hosted[1:]:
            self.logics[rid] = AgentLogic(replace(config, robot_id=rid), policy, hearing=self.hearing)
        self.spec, self.ids, self.index = first.spec, first.ids, first.index
        self.state_timeout = float(config.state_timeout)
        self.hold_s = float(hold_s)
        self._held: Dict[int, Request] = {}  # lockstep requests waiting for the rest of the step
        self._held_since = 0.0
        # Lockstep polling touches only the robots a message concerns (see _poll_set).
        self._active: set = set()  # robots with a pending step or a re-send
        self._touched: set = set()  # robots a message concerned since the last poll
        self._poll_all = False  # a step may have become complete for everyone waiting
        self._deadline = float('inf')  # wall time of the next timeout (a peer or a held request), or earlier
        self._full = False
        self._most_left_out = 0  # the largest number of robots any hosted robot left out
        self._rt_active: set = set()  # realtime: robots with a pending own-state tick
        self._rt_poll = False  # realtime: a step's states may be complete
        self._rt_deadline = float('inf')  # realtime: the earliest grace deadline of a pending tick
        self._rt_incomplete: set = set()  # realtime: robots whose last tick was computed with states missing
        self.calls = 0  # batched policy calls
        self.evaluated = 0  # matrices evaluated in them

    # --- input: every state, filed once, to the hosted robots it concerns -------------------
    def receive(
        self,
        robot: Optional[int],
        stamp_ns: int,
        z,
        now_ns: Optional[int] = None,
        wall: float = 0.0,
        step: Optional[int] = None,
    ) -> str:
        """File the state once for every hosted robot (see :meth:`AgentLogic.receive`); its
        owner (if hosted here) and the robots that left its sender out react to it."""
        outcome, step = self.hearing.file(robot, stamp_ns, z, now_ns, step=step)
        if step is None:
            return outcome
        robot, accepted = int(robot), outcome == 'accepted'
        owner = self.logics.get(robot)
        if owner is not None:
            owner.react(robot, int(stamp_ns), step, accepted, wall)
            self._touched.add(robot)
            if owner.ticks is not None and owner.ticks.pending is not None:
                self._rt_active.add(robot)
                self._rt_deadline = min(self._rt_deadline, owner.ticks.deadline)
                self._rt_poll |= not accepted  # opened again by a repeated own state: may be due now
            if owner.waiting_since is not None:
                self._active.add(robot)
                self._deadline = min(self._deadline, owner.waiting_since + self.state_timeout)
        if accepted and self._most_left_out:
            for rid, logic in self.logics.items():
                if logic is not owner and robot in logic.left_out:
                    logic.react(robot, int(stamp_ns), step, True, wall)
                    self._touched.add(rid)
            self._most_left_out = max(len(logic.left_out) for logic in self.logics.values())
        if accepted and self.hearing.complete(step, len(self.ids) - self._most_left_out):
            self._poll_all = True
        if accepted and self._rt_incomplete:  # a late state: the ticks computed without it open again
            for rid in list(self._rt_incomplete):
                ticks = self.logics[rid].ticks
                if rid != robot and ticks.heard(step, wall):
                    self._rt_active.add(rid)
                    self._rt_deadline = min(self._rt_deadline, ticks.deadline)
                if ticks.incomplete is None or ticks.pending is not None:
                    self._rt_incomplete.discard(rid)
        if accepted and self._rt_active and self.hearing.complete(step, self.hearing.live_count(now_ns)):
            self._rt_poll = True
        return outcome

    def malformed(self) -> str:
        """Count an undecodable message (once: the hosted robots share what they hear)."""
        return self.hearing.malformed()

    @property
    def ready(self) -> bool:
        """Every hosted robot has heard every robot (they hear the same)."""
        return self._first.ready

    # --- commands --------------------------------------------------------------------------
    def _poll_set(self, wall: float) -> List[int]:
        """The robots whose lockstep command may have become due since the last poll: those a
        message concerned, or, when a step's states may be complete or a timeout may have
        passed, every robot with a pending step. (Polling the others would return None.)"""
        if self._poll_all or wall >= self._deadline:
            self._poll_all, self._full = False, True
            chosen = self._active
        else:
            chosen = self._touched & self._active
        self._touched = set()
        return sorted(chosen)

    def lockstep_poll(self, wall: float) -> List[Tuple[int, Command]]:
        """``(robot, command)`` of every hosted robot whose lockstep command is due now (see the
        module doc on batching); call after every ``receive`` and now and then (a timer)."""
        out: List[Tuple[int, Command]] = []
        again = []
        self._full = False
        for rid in self._poll_set(wall):
            if rid in self._held:
                continue
            logic = self.logics[rid]
            item = logic.lockstep_next(wall)
            if isinstance(item, Request):
                if not self._held:
                    self._held_since = wall
                    self._deadline = min(self._deadline, wall + self.hold_s)
                self._held[rid] = item
                self._most_left_out = max(
                    self._most_left_out, len(logic.left_out)
                )  # it may have given up on some
            elif item is not None:
                out.append((rid, item))  # a re-sent command; a pending step may follow
                again.append(rid)
            if logic.waiting_since is None:
                self._active.discard(rid)
        self._touched.update(again)
        if self._held and (len(self._held) == len(self.logics) or wall - self._held_since >= self.hold_s):
            held, self._held = self._held, {}
            out += self._run(held)
        if self._full:  # the next timeout, exactly (in between, an earlier one only polls everyone once more)
            since = [self.logics[rid].waiting_since for rid in self._active]
            self._deadline = min(
                [t + self.state_timeout for t in since if t is not None]
                + ([self._held_since + self.hold_s] if self._held else []),
                default=float('inf'),
            )
        return sorted(out, key=lambda item: item[0])

    def tick(self, now_ns: Optional[int]) -> List[Tuple[int, Command]]:
        """``(robot, command)`` of every hosted robot at a control tick (none before its own state)."""
        return self._run({rid: logic.tick_next(now_ns) for rid, logic in self.logics.items()})

    def realtime_poll(self, now_ns: Optional[int], wall: float) -> List[Tuple[int, Command]]:
        """``(robot, command)`` of every hosted robot whose own-state tick is due now, evaluated in
        one call (see the module doc); call after every ``receive`` and now and then (a timer)."""
        expired = wall >= self._rt_deadline
        if not self._rt_active or not (self._rt_poll or expired):
            return []
        self._rt_poll = False
        due = {}
        for rid in sorted(self._rt_active):  # the first grace to pass is every waiting robot's: one call
            item = self.logics[rid].realtime_next(now_ns, wall, force=expired)
            if item is not None:
                due[rid] = item
        self._rt_incomplete.update(rid for rid in due if self.logics[rid].ticks.incomplete is not None)
        self._rt_active = {rid for rid in self._rt_active if self.logics[rid].ticks.pending is not None}
        self._rt_deadline = min(
            (self.logics[rid].ticks.deadline for rid in self._rt_active), default=float('inf')
        )
        return self._run(due)

    @property
    def waiting_ticks(self) -> set:
        """Realtime: the hosted robots whose own-state tick waits for states."""
        return self._rt_active

    def watchdog(self, now_ns: Optional[int]) -> List[Tuple[int, Command]]:
        """The control timer with ticks on the own state: the stop command of every hosted robot
        whose own state is stale (:meth:`AgentLogic.watchdog`)."""
        out = [(rid, logic.watchdog(now_ns)) for rid, logic in self.logics.items()]
        return [(rid, cmd) for rid, cmd in out if cmd is not None]

    def _run(self, items: Dict[int, object]) -> List[Tuple[int, Command]]:
        out: List[Tuple[int, Command]] = []
        requests: List[Tuple[int, Request]] = []
        for rid, item in items.items():
            if isinstance(item, Request):
                requests.append((rid, item))
            elif item is not None:
                out.append((rid, item))
        if requests:
            U = self.evaluate([r for _, r in requests], [rid for rid, _ in requests])
            values, non_finite, clipped = clean_commands(
                U, self._first.limit
            )  # the hosted robots share the limit
            for n, (rid, request) in enumerate(requests):
                out.append(
                    (
                        rid,
                        self.logics[rid].commit(
                            request, values[n], bool(non_finite[n]), bool(clipped[n]), U[n]
                        ),
                    )
                )
            out.sort(key=lambda item: item[0])
        return out

    def evaluate(self, requests: Sequence[Request], robots: Sequence[int]) -> np.ndarray:
        """Y_i of every request (one builder call per shared snapshot) and one policy call for
        all: commands ``[len(requests), m]``."""
        self._first.build(requests)
        Y = np.stack([r.Y for r in requests])
        mask = np.stack([r.mask for r in requests])
        self.calls += 1
        self.evaluated += len(requests)
        return evaluate_batch(self.policy, Y, mask, robots, self._first.parity_index)

    # --- reporting -------------------------------------------------------------------------
    def drain_events(self) -> List[str]:
        """Every hosted robot's notes since the last call, prefixed with its id."""
        return [f'robot {rid}: {text}' for rid, logic in self.logics.items() for text in logic.drain_events()]

    def status(self) -> Dict:
        """JSON-able: each hosted robot's status (as a lone agent reports it) and the batching figures."""
        return {
            'hosted': self.hosted,
            'policy_calls': self.calls,
            'evaluated': self.evaluated,
            'robots': {str(rid): logic.status() for rid, logic in self.logics.items()},
        }
