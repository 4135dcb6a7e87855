"""Several robots' agents in one process, without ROS: what the ``agents`` node wires to topics.

Each hosted robot runs its own :class:`AgentLogic`, the very class a lone ``agent`` runs: its
own delay buffer, drops and counters, lockstep bookkeeping, neighbour matrix Y_i and command.
It hears exactly what its robot would hear (every state the process receives goes to every
hosted robot's logic, which files it by its own rules); nothing of one robot's state of mind
reaches another. Shared is plumbing only: the process decodes each message once, holds one
policy module, and evaluates the policy once per tick for every hosted robot whose command is
due (:func:`.policy_call.evaluate_rows`), with each robot's matrix at its swarm index in a
rollout-shaped batch when the logic asks for parity rows, so that any split of the swarm over
processes reproduces :func:`knode_swarm_ros.core.rollout` bit for bit.

Batching in lockstep: with a delay (tau >= 1) a robot's command is due as soon as its own state
arrives, so the hosted robots fall due one after the other within a step. A due request is held
until every hosted robot has one (the simulator publishes a step's states together) and then all
are evaluated in one call; a request held ``hold_s`` wall seconds (an own state lost) is
evaluated at the next poll without waiting for the rest.

Also here: :func:`parse_ids`, the ``ids`` parameter (a list or a range) of the ``agents`` node.
"""
from __future__ import annotations

import re
from dataclasses import replace
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from .agent_logic import AgentConfig, AgentLogic, Command, PolicyLike, Request
from .common import ConfigError
from .policy_call import evaluate_rows

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
                raise ConfigError(f"parameter {name!r} = {value!r}: the range ends before it starts")
            ids = list(range(a, b + 1))
        else:
            parts = [p.strip() for p in value.strip().strip('[]').split(',') if p.strip()]
            if not parts or not all(p.isdigit() for p in parts):
                raise ConfigError(f"parameter {name!r} = {value!r} is neither a list of ids nor a range "
                                  "like '0..49'")
            ids = [int(p) for p in parts]
    elif isinstance(value, (list, tuple)) and all(isinstance(v, (int, np.integer)) and not isinstance(v, bool)
                                                  for v in value):
        ids = [int(v) for v in value]
    else:
        raise ConfigError(f"parameter {name!r} = {value!r} is neither a list of ids nor a range like '0..49'")
    if not ids:
        raise ConfigError(f"parameter {name!r} holds no robot id")
    if min(ids) < 0:
        raise ConfigError(f"parameter {name!r} holds a negative id: {ids}")
    if len(set(ids)) != len(ids):
        raise ConfigError(f"parameter {name!r} holds duplicates: {ids}")
    return sorted(ids)


def format_ids(ids: Sequence[int]) -> str:
    """``'3..7'`` for a run of consecutive ids, else ``'[1, 4, 9]'``."""
    ids = sorted(int(i) for i in ids)
    if len(ids) > 1 and ids == list(range(ids[0], ids[-1] + 1)):
        return f'{ids[0]}..{ids[-1]}'
    return str(ids)


class HostedAgents:
    """One :class:`AgentLogic` per hosted robot and one policy call per tick for all of them.

    Args:
        hosted: the ids of the robots this process hosts (a subset of ``config.robot_ids``).
        config: the settings every hosted robot shares; ``robot_id`` is replaced per robot.
        policy: the one policy module, ``(Y [B, k, d], mask [B, k]) -> [B, m]``.
    """

    def __init__(self, hosted: Sequence[int], config: AgentConfig, policy: PolicyLike, hold_s: float = 0.05):
        hosted = parse_ids(list(hosted))
        missing = [i for i in hosted if i not in set(int(r) for r in config.robot_ids)]
        if missing:
            raise ConfigError(f"parameter 'ids': robot(s) {missing} are not among the swarm's robot ids "
                              f"{format_ids(config.robot_ids)} (set 'robots' or 'robot_ids')")
        self.policy = policy
        self.hosted: List[int] = hosted
        self.logics: Dict[int, AgentLogic] = {rid: AgentLogic(replace(config, robot_id=rid), policy)
                                              for rid in hosted}
        first = self._first = self.logics[hosted[0]]
        self.spec, self.ids, self.index = first.spec, first.ids, first.index
        self.hold_s = float(hold_s)
        self._held: Dict[int, Request] = {}  # lockstep requests waiting for the rest of the step
        self._held_since = 0.0
        self.calls = 0      # batched policy calls
        self.evaluated = 0  # matrices evaluated in them

    # --- input: every state to every hosted robot ------------------------------------------
    def receive(self, robot: Optional[int], stamp_ns: int, z, now_ns: Optional[int] = None,
                wall: float = 0.0) -> str:
        """Give the state to every hosted robot's logic (see :meth:`AgentLogic.receive`);
        returns the first hosted robot's outcome (they apply the same rules to the same input)."""
        verdict = self._first.check(robot, stamp_ns, z, now_ns)  # the same rules for all: check once
        if verdict is None:
            z = np.asarray(z, dtype=np.float64)
        outcomes = [logic.receive(robot, stamp_ns, z, now_ns, wall, verdict) for logic in self.logics.values()]
        return outcomes[0]

    def malformed(self) -> str:
        """Count an undecodable message at every hosted robot."""
        for logic in self.logics.values():
            logic.malformed()
        return 'malformed'

    @property
    def ready(self) -> bool:
        """Every hosted robot has heard every robot."""
        return all(logic.ready for logic in self.logics.values())

    # --- commands --------------------------------------------------------------------------
    def lockstep_poll(self, wall: float) -> List[Tuple[int, Command]]:
        """``(robot, command)`` of every hosted robot whose lockstep command is due now (see the
        module doc on batching); call after every ``receive`` and now and then (a timer)."""
        out: List[Tuple[int, Command]] = []
        for rid, logic in self.logics.items():
            if rid in self._held:
                continue
            item = logic.lockstep_next(wall)
            if isinstance(item, Request):
                if not self._held:
                    self._held_since = wall
                self._held[rid] = item
            elif item is not None:
                out.append((rid, item))  # a re-sent command
        if self._held and (len(self._held) == len(self.logics) or wall - self._held_since >= self.hold_s):
            held, self._held = self._held, {}
            out += self._run(held)
        return sorted(out, key=lambda item: item[0])

    def tick(self, now_ns: Optional[int]) -> List[Tuple[int, Command]]:
        """``(robot, command)`` of every hosted robot at a control tick (none before its own state)."""
        return self._run({rid: logic.tick_next(now_ns) for rid, logic in self.logics.items()})

    def _run(self, items: Dict[int, object]) -> List[Tuple[int, Command]]:
        out: List[Tuple[int, Command]] = []
        requests: List[Tuple[int, Request]] = []
        for rid, item in items.items():
            if isinstance(item, Request):
                requests.append((rid, item))
            elif item is not None:
                out.append((rid, item))
        if requests:
            for (rid, request), u in zip(requests, self.evaluate([r for _, r in requests], [rid for rid, _ in requests])):
                out.append((rid, self.logics[rid].finish(request, u)))
            out.sort(key=lambda item: item[0])
        return out

    def evaluate(self, requests: Sequence[Request], robots: Sequence[int]) -> np.ndarray:
        """One policy call for the requests of ``robots``: commands ``[len(requests), m]``."""
        Y = np.stack([r.Y for r in requests])
        mask = np.stack([r.mask for r in requests])
        self.calls += 1
        self.evaluated += len(requests)
        if self.logics[robots[0]].parity_rows:
            return evaluate_rows(self.policy, Y, mask, [self.index[rid] for rid in robots], len(self.ids))
        return evaluate_rows(self.policy, Y, mask)

    # --- reporting -------------------------------------------------------------------------
    def drain_events(self) -> List[str]:
        """Every hosted robot's notes since the last call, prefixed with its id."""
        return [f'robot {rid}: {text}' for rid, logic in self.logics.items() for text in logic.drain_events()]

    def status(self) -> Dict:
        """JSON-able: each hosted robot's status (as a lone agent reports it) and the batching figures."""
        return {'hosted': self.hosted, 'policy_calls': self.calls, 'evaluated': self.evaluated,
                'robots': {str(rid): logic.status() for rid, logic in self.logics.items()}}
