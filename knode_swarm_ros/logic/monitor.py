"""The live monitor's logic, without ROS: robot states in, one snapshot per tick out.

:class:`SwarmWatch` keeps every robot's newest state (``z [d]``, its stamp and the wall time it
arrived), its agent's newest health level and a short trail of positions. :meth:`SwarmWatch.snapshot`
turns them into a :class:`Snapshot`: positions ``[n, p]``, directions ``[n, p]`` (velocities,
flock2d; unit headings, boids3d), each robot's health and, when asked (``figures``: they cost
O(n^2), so the node computes them at a lower rate than the positions), the neighbour links of
the robots' Y_i (the core's ranking rule, :func:`knode_swarm_ros.core.network.rank_neighbours`,
on the newest states: the delay tau is not modelled) and the swarm metrics (avd and amd of
:mod:`knode_swarm_ros.core.metrics`, the smallest nearest-neighbour distance, polarisation), all
from one matrix of position distances. Everything is vectorised over the robots: at 200 robots
the monitor's whole tick must stay a small fraction of a core.

Health of a robot: ``unheard`` (no state yet), ``lost`` (no state for ``lost_after`` wall seconds),
``stale`` (none for ``stale_after``), else its agent's diagnostics level (``ok``, ``warn``,
``error``; ``ok`` when its agent never reported).

The web page's messages (JSON, one per tick, see :func:`hello_message` and :func:`tick_message`)
carry the mapping world -> pixel explicitly: a fixed scale for the run (pixels per metre, in
the first message) and the view's centre per tick (the swarm's centroid), so that
``px = width / 2 + (x - cx) * scale`` and ``py = height / 2 - (y - cy) * scale``.
:class:`Throttle` keeps the ticks to a rate that holds at hundreds of robots.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from knode_swarm_ros.core.geometry import pair_distances
from knode_swarm_ros.core.metrics import avd
from knode_swarm_ros.core.network import rank_neighbours
from knode_swarm_ros.core.scenarios import get_scenario

__all__ = [
    'METRICS_TOPIC',
    'MONITOR_MARKERS_TOPIC',
    'HEALTH',
    'HEALTH_CODES',
    'NETWORK_DEFAULTS',
    'network_defaults',
    'Snapshot',
    'SwarmWatch',
    'Throttle',
    'swarm_figures',
    'swarm_links_and_figures',
    'view_scale',
    'hello_message',
    'tick_message',
    'decode_tick',
    'pixel_of',
]

METRICS_TOPIC = 'monitor/metrics'  # std_msgs/String, JSON: one message per tick
MONITOR_MARKERS_TOPIC = 'monitor/markers'  # visualization_msgs/MarkerArray

#: (d_cr, k) of the paper's policies per scenario, those of core.policy.DEFAULTS (a test checks
#: it): the monitor must not import torch for two numbers.
NETWORK_DEFAULTS = {'flock2d': (5.0, 6), 'boids3d': (2.0, 6)}
#: (d_cr, k) for a scenario of one's own: core.policy.PolicyConfig's defaults (set d_cr and k to
#: the policy's; the launcher does).
OTHER_NETWORK_DEFAULTS = (5.0, 6)


def network_defaults(scenario) -> Tuple[float, int]:
    """(d_cr, k) the monitor draws with when not given: the paper's for its two scenarios."""
    spec = get_scenario(scenario)
    return NETWORK_DEFAULTS[spec.name] if spec.shipped else OTHER_NETWORK_DEFAULTS


#: Health names and their one-letter codes in the tick message.
HEALTH = ('ok', 'warn', 'error', 'stale', 'lost', 'unheard')
HEALTH_CODES = {'ok': 'o', 'warn': 'w', 'error': 'e', 'stale': 's', 'lost': 'l', 'unheard': 'u'}
#: Positions and directions travel in millimetres (mm/s): integers keep the message short.
MM = 1000.0


@dataclass(frozen=True)
class Snapshot:
    """The swarm at one tick. ``n`` robots, ``p`` position entries, ``L`` links."""

    ids: List[int]
    step: Optional[int]  # newest step heard (from the stamps), None before any state
    stamp_ns: Optional[int]
    lags: np.ndarray  # [n] int: steps each robot's state is behind ``step`` (0 for unheard robots)
    positions: np.ndarray  # [n, p]; robots never heard at the origin (health 'unheard')
    directions: np.ndarray  # [n, p]
    health: List[str]  # [n], one of HEALTH
    # links [L, 2] int, (i, j): robot ids[j] is in Y_i (indices into ids); None: not computed this tick
    links: Optional[np.ndarray]
    # avd, amd, nnd (smallest nearest-neighbour distance), polarisation; None: not computed this tick
    metrics: Optional[Dict[str, Optional[float]]]
    centre: Tuple[float, float]  # view centre (x, y): centroid of the heard robots


class Throttle:
    """At most ``rate`` ticks per second of a monotonic clock (0: never)."""

    def __init__(self, rate: float):
        self.period = 1.0 / rate if rate > 0 else math.inf
        self.last = -math.inf

    def due(self, now: float) -> bool:
        """Whether a tick is due at ``now`` (then the next one is a period later)."""
        if self.period == math.inf or now - self.last < self.period:
            return False
        self.last = now
        return True


_UNHEARD, _LOST, _STALE = HEALTH.index('unheard'), HEALTH.index('lost'), HEALTH.index('stale')
_NO_LEVEL = -1
_HEALTH_NAMES = np.array(HEALTH, dtype=object)


class SwarmWatch:
    """Newest state, health and trail of robots ``robot_ids`` (see the module doc)."""

    def __init__(
        self,
        scenario: str,
        robot_ids: Sequence[int],
        d_cr: float,
        k: int,
        dt: Optional[float] = None,
        stale_after: float = 1.0,
        lost_after: float = 5.0,
        trail: int = 50,
        trail_every: float = 0.2,
    ):
        self.spec = get_scenario(scenario)
        self.ids = [int(i) for i in robot_ids]
        self.index = {r: n for n, r in enumerate(self.ids)}
        ids = np.array(self.ids, dtype=np.int64)
        self._by_id = np.argsort(ids, kind='stable')  # rows of the ids in ascending order
        self._sorted_ids = ids[self._by_id]
        n, d, p = len(self.ids), self.spec.state_dim, self.spec.position_dim
        self.d_cr, self.k = float(d_cr), int(k)
        self.dt = float(dt or self.spec.dt)
        self.stale_after, self.lost_after = float(stale_after), float(lost_after)
        self.trail_every = float(trail_every)
        self.states = np.zeros((n, d))
        self.stamps = np.full(n, -1, dtype=np.int64)
        self.arrived = np.full(n, -math.inf)  # wall seconds
        self.levels = np.full(n, _NO_LEVEL, dtype=np.int64)  # diagnostics level, -1: never reported
        # trails: a ring of the last ``trail`` positions per robot, written at ``head``
        self.trail_points = np.zeros((n, max(1, int(trail)), p))
        self.trail_count = np.zeros(n, dtype=np.int64)
        self.trail_head = np.zeros(n, dtype=np.int64)
        self.trail_wall = np.full(n, -math.inf)

    def receive(self, robot: int, stamp_ns: int, z: np.ndarray, wall: float) -> bool:
        """File a state of ``robot``; older than the newest one or unknown robot: ignored (False)."""
        i = self.index.get(int(robot))
        if i is None:
            return False
        return bool(self._file(np.array([i]), np.array([stamp_ns], np.int64), np.asarray(z)[None], wall)[0])

    def receive_many(self, robots: Sequence[int], stamps_ns, states: np.ndarray, wall: float) -> np.ndarray:
        """:meth:`receive` of states ``[m, d]`` of ``robots [m]`` stamped ``stamps_ns [m]``, in
        order (a robot's later state counts after its earlier one); returns which were filed [m]."""
        rows = self._rows(robots)
        stamps = np.asarray(stamps_ns, dtype=np.int64).reshape(-1)
        states = np.asarray(states, dtype=float).reshape(len(rows), -1)
        filed = np.zeros(len(rows), dtype=bool)
        known = np.nonzero(rows >= 0)[0]
        if np.bincount(rows[known], minlength=1).max() <= 1:  # one state per robot: all at once
            filed[known] = self._file(rows[known], stamps[known], states[known], wall)
        else:  # several states of a robot (poses): in order, each against the newest filed
            for m in known:
                filed[m] = self._file(rows[m : m + 1], stamps[m : m + 1], states[m : m + 1], wall)[0]
        return filed

    def _rows(self, robots: Sequence[int]) -> np.ndarray:
        """Rows of ``robots`` (ids), -1 for an id not watched."""
        robots = np.asarray(robots, dtype=np.int64).reshape(-1)
        at = np.minimum(np.searchsorted(self._sorted_ids, robots), len(self.ids) - 1)
        return np.where(self._sorted_ids[at] == robots, self._by_id[at], -1)

    def _file(self, rows: np.ndarray, stamps: np.ndarray, states: np.ndarray, wall: float) -> np.ndarray:
        """File states of distinct ``rows``; returns which were newer and finite."""
        ok = (stamps >= self.stamps[rows]) & np.isfinite(states).all(axis=1)
        rows, states = rows[ok], states[ok]
        self.states[rows] = states
        self.stamps[rows] = stamps[ok]
        self.arrived[rows] = wall
        due = rows[wall - self.trail_wall[rows] >= self.trail_every]
        if len(due):
            self.trail_wall[due] = wall
            self.trail_points[due, self.trail_head[due]] = self.states[due, : self.spec.position_dim]
            self.trail_head[due] = (self.trail_head[due] + 1) % self.trail_points.shape[1]
            self.trail_count[due] = np.minimum(self.trail_count[due] + 1, self.trail_points.shape[1])
        return ok

    def diagnostics(self, robot: int, level: int) -> None:
        """The newest diagnostics level of ``robot``'s agent (0 OK, 1 WARN, 2 ERROR, 3 STALE)."""
        i = self.index.get(int(robot))
        if i is not None:
            self.levels[i] = int(level)

    def health_codes(self, wall: float) -> np.ndarray:
        """Health of every robot at wall time ``wall`` as indices into :data:`HEALTH` ``[n]``."""
        age = wall - self.arrived
        codes = np.where(self.levels == _NO_LEVEL, 0, np.clip(self.levels, 0, 2))  # 3 (STALE): error
        codes[age > self.stale_after] = _STALE  # each overruled by the next
        codes[age > self.lost_after] = _LOST
        codes[self.stamps < 0] = _UNHEARD
        return codes

    def health(self, wall: float) -> List[str]:
        """Health of every robot at wall time ``wall`` (see the module doc)."""
        return _HEALTH_NAMES[self.health_codes(wall)].tolist()

    def trails(self) -> List[np.ndarray]:
        """Each robot's trail ``[m_i, p]``, oldest first."""
        size = self.trail_points.shape[1]
        return [
            np.roll(points, -head, axis=0)[size - count :] if count == size else points[:count]
            for points, head, count in zip(
                self.trail_points, self.trail_head.tolist(), self.trail_count.tolist()
            )
        ]

    def snapshot(self, wall: float, figures: bool = True) -> Snapshot:
        """The swarm now (see :class:`Snapshot`); the links and the metrics only with ``figures``."""
        p = self.spec.position_dim
        heard = self.stamps >= 0
        any_heard = bool(heard.any())
        pos, direction = self.states[:, :p].copy(), self.states[:, p:].copy()
        links = metrics = None
        if figures:
            links, metrics = swarm_links_and_figures(self.states, heard, p, self.d_cr, self.k)
        stamp = int(self.stamps.max()) if any_heard else None
        steps = np.rint(self.stamps / (self.dt * 1e9)).astype(np.int64)
        lags = np.where(heard, steps.max() - steps, 0) if any_heard else np.zeros(len(self.ids), np.int64)
        centre = tuple(float(c) for c in pos[heard, :2].mean(axis=0)) if any_heard else (0.0, 0.0)
        return Snapshot(
            ids=list(self.ids),
            step=int(round(stamp / (self.dt * 1e9))) if stamp is not None else None,
            stamp_ns=stamp,
            lags=lags,
            positions=pos,
            directions=direction,
            health=self.health(wall),
            links=links,
            metrics=metrics,
            centre=centre,
        )


def swarm_links_and_figures(
    states: np.ndarray, heard: np.ndarray, p: int, d_cr: float, k: int
) -> Tuple[np.ndarray, Dict[str, Optional[float]]]:
    """The links ``[L, 2]`` (indices into ``states``) of the heard robots' Y_i (the core's
    :func:`~knode_swarm_ros.core.network.rank_neighbours` on their pair distances) and
    :func:`swarm_figures` of the heard robots, the two from one matrix of position distances."""
    rows = np.nonzero(heard)[0]
    frame = states[rows]
    links = np.zeros((0, 2), dtype=np.int64)
    if len(rows) < 2:
        return links, swarm_figures(frame, p)
    gaps = pair_distances(frame[:, :p])  # inf diagonal: a robot is not its own neighbour
    if k > 1:
        index, valid = rank_neighbours(gaps, d_cr, k)
        i = np.repeat(np.arange(len(rows)), index.shape[1])[valid.ravel()]
        links = np.stack([rows[i], rows[index.ravel()[valid.ravel()]]], axis=1)
    return links, swarm_figures(frame, p, gaps)


def swarm_figures(frame: np.ndarray, p: int, gaps: Optional[np.ndarray] = None) -> Dict[str, Optional[float]]:
    """avd, amd, nnd (smallest nearest-neighbour distance) and polarisation (norm of the mean
    unit direction: 1 when every robot heads the same way) of ``frame [n, d]``; None below 2 robots.
    ``gaps``: the robots' :func:`~knode_swarm_ros.core.geometry.pair_distances` when already
    computed (amd is then the core's :func:`~knode_swarm_ros.core.metrics.amd` bit for bit)."""
    if frame.shape[0] < 2:
        return {'avd': None, 'amd': None, 'nnd': None, 'polarisation': None}
    pos, direction = frame[:, :p], frame[:, p:]
    if gaps is None:
        gaps = pair_distances(pos)
    nearest = gaps.min(axis=-1)
    norms = np.linalg.norm(direction, axis=-1, keepdims=True)
    units = np.divide(direction, norms, out=np.zeros_like(direction), where=norms > 0)
    return {
        'avd': float(avd(direction)) if direction.shape[1] else None,  # a position state has no direction
        'amd': float(nearest.mean(axis=-1)),
        'nnd': float(nearest.min()),
        'polarisation': float(np.linalg.norm(units.mean(axis=0))),
    }


def view_scale(positions: np.ndarray, width: int, height: int, d_cr: float) -> float:
    """Pixels per metre of a run's view: the first snapshot's swarm (x, y extent, at least
    ``4 d_cr`` or 10 m across) fills a third of the smaller side of the canvas, leaving room
    for the swarm to spread. Fixed for the run."""
    pos = np.asarray(positions)[:, :2]
    extent = float(np.ptp(pos, axis=0).max()) if len(pos) else 0.0
    span = max(extent, 4.0 * d_cr, 10.0) * 3.0
    return min(width, height) / span


def pixel_of(x: float, y: float, centre: Sequence[float], scale: float, width: int, height: int):
    """Canvas pixel (column, row) of world point (x, y) (see the module doc)."""
    return width / 2.0 + (x - centre[0]) * scale, height / 2.0 - (y - centre[1]) * scale


def hello_message(scenario: str, ids: Sequence[int], d_cr: float, k: int, scale: float, size) -> str:
    """The first message of a WebSocket: the run and the view (pixels per metre, canvas size)."""
    return json.dumps(
        {
            'type': 'hello',
            'scenario': scenario,
            'ids': list(map(int, ids)),
            'd_cr': float(d_cr),
            'k': int(k),
            'position_dim': get_scenario(scenario).position_dim,
            'scale': float(scale),
            'width': int(size[0]),
            'height': int(size[1]),
            'health': {code: name for name, code in HEALTH_CODES.items()},
        },
        separators=(',', ':'),
    )


def _mm(values: np.ndarray) -> List[int]:
    return np.rint(np.asarray(values, dtype=float).ravel() * MM).astype(np.int64).tolist()


def tick_message(snap: Snapshot) -> str:
    """One tick as compact JSON: ``step``, ``a`` (steps each robot's state is behind ``step``),
    ``c`` (view centre, m), ``p`` / ``v`` (positions in mm and directions in mm/s, flattened
    ``[n * p]``), ``h`` (health, one letter per robot) and, on ticks that computed them, ``l``
    (links, flattened index pairs) and ``m`` (metrics; null below 2 robots): the page keeps the
    last ones until new ones come. Trails are the page's own (it keeps the positions it received)."""
    msg = {
        'type': 'tick',
        'step': snap.step,
        'a': snap.lags.tolist(),
        'c': [round(snap.centre[0], 3), round(snap.centre[1], 3)],
        'p': _mm(snap.positions),
        'v': _mm(snap.directions),
        'h': ''.join(map(HEALTH_CODES.__getitem__, snap.health)),
    }
    if snap.links is not None:
        msg['l'] = snap.links.ravel().tolist()
    if snap.metrics is not None:
        msg['m'] = {k: (round(v, 4) if v is not None else None) for k, v in snap.metrics.items()}
    return json.dumps(msg, separators=(',', ':'))


def decode_tick(text: str, position_dim: int) -> Dict:
    """A tick message back as arrays: ``positions [n, p]`` and ``directions [n, p]`` in metres,
    ``health`` names, ``centre``, ``step``, ``lags [n]``, ``links [L, 2]`` and ``metrics``
    (None on a tick without them)."""
    msg = json.loads(text)
    names = {code: name for name, code in HEALTH_CODES.items()}
    return {
        'step': msg['step'],
        'lags': np.asarray(msg['a'], dtype=np.int64),
        'centre': tuple(msg['c']),
        'positions': np.asarray(msg['p'], dtype=float).reshape(-1, position_dim) / MM,
        'directions': np.asarray(msg['v'], dtype=float).reshape(-1, position_dim) / MM,
        'health': [names[c] for c in msg['h']],
        'links': np.asarray(msg['l'], dtype=np.int64).reshape(-1, 2) if 'l' in msg else None,
        'metrics': msg.get('m'),
    }
