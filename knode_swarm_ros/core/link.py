"""Imperfect links between robots: loss, delay, jitter and radio range (no ROS; docs/DESIGN.md).

The model sits where a robot receives a neighbour's state. Every state robot j sends at time
s reaches robot i independently of every other message:

* not at all when i was farther than ``range`` from j at s (the radio cannot hear it;
  ``range`` 0 means unlimited; this is separate from the policy's d_cr, which selects
  neighbours among the robots heard);
* otherwise lost with probability ``loss``;
* otherwise after ``delay + U[0, jitter]`` (so messages may overtake each other).

A robot's own state never goes through a link. Everything is drawn from one seeded
``numpy.random.Generator``, so a run is reproducible; everything is counted. With all four
settings at 0 the model is off and changes nothing (tested: the offline rollout is then
bit for bit :func:`knode_swarm_ros.core.rollout`).

Two users share these semantics:

* :class:`LinkModel`, one receiving robot, streaming (the agent node: seconds, ROS clock);
* :func:`link_rollout`, a whole swarm offline (steps of dt). At step t robot i uses, for each
  j, the newest state of j sent at a step s <= max(t - tau, 0) that has arrived by t; a peer
  whose newest usable state is more than ``timeout_steps`` older than t - tau is not a
  neighbour (the agent's ``state_timeout``), and neither is one never heard.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass
from typing import Any, Dict, List, Tuple

import numpy as np

from .geometry import distances
from .network import rank_neighbours
from .rollout import PolicyFn, zoh_step
from .scenarios import get_scenario

__all__ = ['LinkConfig', 'LinkModel', 'link_rollout', 'LINK_COUNTERS']

#: What :class:`LinkModel` and :func:`link_rollout` count.
LINK_COUNTERS = ('offered', 'out_of_range', 'lost', 'delivered')


@dataclass(frozen=True)
class LinkConfig:
    """Link settings (agent parameters ``link_loss``, ``link_delay``, ``link_jitter``,
    ``link_range``, ``link_seed``). ``delay`` and ``jitter`` are in the caller's time unit
    (seconds for the agent, steps for :func:`link_rollout`)."""

    loss: float = 0.0
    delay: float = 0.0
    jitter: float = 0.0
    range: float = 0.0
    seed: int = 0

    def validate(self, prefix: str = 'link_') -> None:
        """Raise ValueError naming the first bad setting (``prefix`` + field name)."""
        if not (math.isfinite(self.loss) and 0.0 <= self.loss < 1.0):
            raise ValueError(f'{prefix}loss must be a probability in [0, 1), got {self.loss}')
        for name in ('delay', 'jitter', 'range'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f'{prefix}{name} must be finite and >= 0, got {value}')
        if int(self.seed) < 0:
            raise ValueError(f'{prefix}seed must be >= 0, got {self.seed}')

    @property
    def enabled(self) -> bool:
        """Whether the model changes anything."""
        return bool(self.loss or self.delay or self.jitter or self.range)


class LinkModel:
    """The links into one receiving robot (see the module doc), with a delivery queue.

    ``offer(now, payload, sender_pos, receiver_pos)`` decides a message's fate and queues it;
    ``due(now)`` hands back the payloads that have arrived by ``now``, in arrival order.
    """

    def __init__(self, config: LinkConfig):
        config.validate()
        self.config = config
        self.rng = np.random.default_rng(int(config.seed))
        self.counters: Dict[str, int] = {name: 0 for name in LINK_COUNTERS}
        self.delays: List[float] = []  # every delivered message's delay (for statistics)
        self._queue: List[Tuple[float, int, Any]] = []
        self._seq = 0

    def fate(self, sender_pos=None, receiver_pos=None) -> Tuple[str, float]:
        """(``out_of_range`` | ``lost`` | ``delivered``, delay) of one message; counted."""
        c = self.counters
        c['offered'] += 1
        cfg = self.config
        if cfg.range > 0.0 and sender_pos is not None and receiver_pos is not None:
            gap = np.asarray(sender_pos, dtype=np.float64) - np.asarray(receiver_pos, dtype=np.float64)
            if not float(np.sqrt(np.dot(gap, gap))) <= cfg.range:
                c['out_of_range'] += 1
                return 'out_of_range', 0.0
        if cfg.loss > 0.0 and self.rng.random() < cfg.loss:
            c['lost'] += 1
            return 'lost', 0.0
        delay = cfg.delay + (self.rng.random() * cfg.jitter if cfg.jitter > 0.0 else 0.0)
        c['delivered'] += 1
        if len(self.delays) < 100_000:
            self.delays.append(delay)
        return 'delivered', delay

    def offer(self, now: float, payload: Any, sender_pos=None, receiver_pos=None) -> str:
        """Decide the fate of ``payload`` sent at ``now``; a delivered one is queued until
        ``now + delay``. Returns the fate."""
        fate, delay = self.fate(sender_pos, receiver_pos)
        if fate == 'delivered':
            heapq.heappush(self._queue, (now + delay, self._seq, payload))
            self._seq += 1
        return fate

    def due(self, now: float) -> List[Any]:
        """Payloads that have arrived by ``now`` (removed from the queue), earliest first."""
        out = []
        while self._queue and self._queue[0][0] <= now:
            out.append(heapq.heappop(self._queue)[2])
        return out

    @property
    def pending(self) -> int:
        """Messages under way."""
        return len(self._queue)


def _gather_rows(view: np.ndarray, index: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Rows ``view[..., i, index[..., i, r], :]`` ``[..., n, k-1, d]``, zero where not valid."""
    rows = np.take_along_axis(view, index[..., None], axis=-2)
    return np.where(valid[..., None], rows, 0.0)


def link_rollout(
    policy: PolicyFn,
    z0: np.ndarray,
    steps: int,
    scenario: str,
    d_cr: float,
    k: int,
    tau: int,
    dt: float,
    link: LinkConfig = LinkConfig(),
    timeout_steps: int = 50,
) -> Tuple[np.ndarray, Dict[str, Any]]:
    """:func:`knode_swarm_ros.core.rollout` with every neighbour state through a link.

    Args:
        policy, z0, steps, scenario, d_cr, k, tau, dt: as for ``rollout``; z0 ``[S, n, d]`` or ``[n, d]``.
        link: loss probability, delay and jitter in whole steps (jitter: U{0..jitter}),
            range in position units, seed.
        timeout_steps: a peer whose newest usable state is older than this (beyond t - tau)
            is not a neighbour (the agent's ``state_timeout / dt``; default 0.5 s at dt 0.01).

    Returns:
        states ``[S, steps + 1, n, d]`` (``[steps + 1, n, d]`` for ``[n, d]``) and a dict of
        the counters (:data:`LINK_COUNTERS`) and ``delays`` (a histogram {steps: count}).
    """
    link.validate()
    if link.delay != int(link.delay) or link.jitter != int(link.jitter):
        raise ValueError(f'offline link delay and jitter are whole steps, got {link.delay}, {link.jitter}')
    spec = get_scenario(scenario)
    z0 = np.asarray(z0, dtype=np.float64)
    single = z0.ndim == 2
    if single:
        z0 = z0[None]
    S, n, d = z0.shape
    p = spec.position_dim
    delay, jitter = int(link.delay), int(link.jitter)
    W = delay + jitter + tau + 1  # a message is usable at most W - 1 steps after it is sent
    rng = np.random.default_rng(int(link.seed))
    out = np.empty((S, steps + 1, n, d))
    out[:, 0] = z0
    never = np.iinfo(np.int64).max
    arrival = np.full((W, S, n, n), never, dtype=np.int64)  # ring buffer by send step: [s % W, S, recv, send]
    held = np.full((S, n, n), -1, dtype=np.int64)  # newest usable send step, -1: none yet
    eye = np.eye(n, dtype=bool)
    counters = {name: 0 for name in LINK_COUNTERS}
    hist = np.zeros(delay + jitter + 1, dtype=np.int64)
    s_idx = np.arange(S)[:, None, None]
    j_idx = np.arange(n)[None, None, :]
    for t in range(steps + 1):
        # Robot j's state of step t goes out to every i != j.
        pos = out[:, t, :, :p]
        ok = ~eye[None].repeat(S, 0)
        counters['offered'] += int(ok.sum())
        if link.range > 0.0:
            far = ~(distances(pos, pos) <= link.range) & ok
            counters['out_of_range'] += int(far.sum())
            ok &= ~far
        if link.loss > 0.0:
            lost = (rng.random((S, n, n)) < link.loss) & ok
            counters['lost'] += int(lost.sum())
            ok &= ~lost
        lag = delay + (rng.integers(0, jitter + 1, size=(S, n, n)) if jitter else 0)
        counters['delivered'] += int(ok.sum())
        hist += np.bincount(np.broadcast_to(lag, ok.shape)[ok], minlength=hist.size)[: hist.size]
        arrival[t % W] = np.where(ok, t + lag, never)
        if t == steps:
            break
        # What each robot holds at step t: the newest state sent at s <= max(t - tau, 0) that has arrived.
        newest = max(t - tau, 0)
        # Only messages that arrive now, and the one that tau has just made old enough, are new.
        fresh = set(range(max(t - delay - jitter, 0), min(t - delay, newest) + 1)) | {newest}
        for s in sorted(fresh):
            usable = arrival[s % W] <= t
            held = np.where(usable & (s > held), s, held)
        alive = (held >= 0) & (newest - held <= timeout_steps)
        view = out[s_idx, np.maximum(held, 0), j_idx]  # [S, recv, send, d]
        own_delayed = out[:, newest]  # a robot's own row needs no link
        view[:, eye] = own_delayed
        dist = np.sqrt(np.sum((view[..., :p] - own_delayed[:, :, None, :p]) ** 2, axis=-1))
        dist = np.where(alive & ~eye, dist, np.inf)
        index, valid = rank_neighbours(dist, d_cr, k)
        rows = _gather_rows(view, index, valid)
        Y = np.concatenate([out[:, t, :, None, :], rows], axis=-2)
        mask = np.concatenate([np.ones((S, n, 1), dtype=bool), valid], axis=-1)
        command = np.asarray(policy(Y.reshape(S * n, k, d), mask.reshape(S * n, k)), dtype=np.float64)
        out[:, t + 1] = zoh_step(out[:, t], command.reshape(S, n, -1), spec, dt)
    stats: Dict[str, Any] = dict(counters)
    stats['delays'] = {int(lag): int(c) for lag, c in enumerate(hist) if c}
    return (out[0] if single else out), stats
