"""What one robot's controller does, without ROS: the agent node only wires it to topics.

(Over 400 lines on purpose: receiving, lockstep waiting, realtime ticks, stopping and the
command are one robot's state machine; split apart they would share most of their fields.)

:class:`AgentLogic` files every state it hears in the core's :class:`DelayBuffer`, drops and
counts what a real network delivers badly, and turns what it heard into one command with the
core's neighbour-matrix builder and the policy file's controller:

* ``receive(robot, stamp_ns, z, now_ns, wall)`` files a state or says why it was dropped:
  ``malformed`` (undecodable bytes: :meth:`malformed`), ``unknown_id`` (not one of the
  swarm's robots), ``bad_size``, ``non_finite``, ``too_old`` (older than ``state_timeout``
  on the node's clock), ``too_future`` (more than ``future_tolerance`` ahead of it),
  ``duplicate`` (a step already filed: the first copy wins).
* ``lockstep``: the arrival of the robot's own state for a new step s opens a command; it is
  computed (``lockstep_poll``) once every live peer's state of step ``max(s - tau, s0)`` is
  filed (s0: the robot's first step), so a command is never built on stale neighbours, whatever
  order the messages arrive in. A peer still missing ``state_timeout`` wall seconds after the
  own state arrived is left out and counted as gone until it is heard again. A repeated own
  state of the step already answered re-sends the same command (the simulator's retransmission
  after a lost message).
* ``realtime``: with ``tick_on`` ``state`` (the default) the arrival of the own state of a new
  control period opens a tick, computed (``realtime_poll``) once the live peers' states of
  ``own step - tau`` are here or a grace has passed (:mod:`.realtime_tick`); the control timer is
  then a watchdog (``watchdog``: stop commands only). With ``tick_on`` ``timer``,
  ``tick(now_ns)`` (the control timer) computes. Either uses the own state and, for every
  peer heard within ``state_timeout``, its newest state at or before ``own step - tau``; an own
  state older than ``state_timeout`` gives a stop command, stamped ``now``: zero velocity, or
  for an acceleration-commanded robot a saturated brake to rest from the velocity it is
  estimated to have (its last state carried forward under the commands sent since:
  :func:`knode_swarm_ros.core.saturation.stop_command`), so it does not coast.
  Its control period ``1 / control_rate`` is compared with the policy's dt
  (:mod:`.control_period`): equal is silent, different warns once (an event) or, with
  ``rate_check`` ``refuse``, raises :class:`ConfigError`; :meth:`status` reports the ratio.

Y_i comes from :func:`knode_swarm_ros.core.neighbour_matrix_rows` with the rows ordered by
robot id (ties go to the lower id, as in the offline rollout). What the robot hears (delay
buffer, newest stamps, receipt counters) is its :class:`.hearing.Hearing`, shared by the robots
of a hosting process (they hear the same). With ``parity_batch`` the policy
is evaluated in a batch shaped like the offline rollout's (one row per robot, this robot's
matrix at its own index): float32 matrix products round differently for different batch
shapes, and this makes a lockstep run equal :func:`knode_swarm_ros.core.rollout` bit for bit
(lockstep only: in real time there is no rollout to match, and a batch of 1 is cheaper).
Commands are saturated per axis by :func:`knode_swarm_ros.core.saturation.saturate` at the
policy's ``command_limit``, lowered (never raised) by the ``command_limit`` parameter.

A process that hosts several robots (``agents``, :mod:`.hosted`) runs one AgentLogic per
robot and evaluates their policies together: ``lockstep_next`` / ``tick_next`` stop short of the
policy call and hand back a :class:`Request` (own state and the rows heard), :func:`build_matrices`
builds Y_i and the mask of many requests at once, and ``finish(request, u)`` applies the command
exactly as ``lockstep_poll`` / ``tick`` do, which are those steps for one request with the
policy called in between (:func:`.batch.evaluate_batch`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Dict, List, Optional, Protocol, Sequence, Tuple

import numpy as np

from knode_swarm_ros.core.saturation import effective_limit, stop_command
from knode_swarm_ros.core.scenarios import get_scenario
from knode_swarm_ros.logic.common import MODES, ConfigError

from .batch import Request, build_matrices, clean_commands, evaluate_batch
from .control_period import RATE_CHECKS, check_control_period
from .hearing import DROP_REASONS, Counters, Hearing, Rows
from .realtime_tick import TICK_ON, TickOnState

__all__ = [
    'AgentConfig',
    'AgentLogic',
    'Command',
    'Request',
    'PolicyLike',
    'DROP_REASONS',
    'build_matrices',
    'clean_commands',
]


class PolicyLike(Protocol):
    """What the logic needs of a policy (:class:`knode_swarm_ros.core.LoadedPolicy` has it)."""

    k: int
    d_cr: float
    tau: int
    dt: float
    scenario: str
    command_limit: Optional[float]

    def __call__(self, Y: np.ndarray, mask: np.ndarray) -> np.ndarray: ...


@dataclass
class AgentConfig:
    """The agent's settings (parameters of the same names; see docs/ros.md)."""

    robot_id: int
    robot_ids: Sequence[int]
    mode: str = 'realtime'
    state_timeout: float = 0.5
    future_tolerance: float = 0.5
    command_limit: float = 0.0
    parity_batch: bool = True
    control_rate: float = 0.0  # Hz (realtime); 0: not known, no period check
    rate_check: str = (
        'warn'  # control period != policy dt: 'warn' once, 'refuse' or 'accept' (control_period.py)
    )
    tick_on: str = 'state'  # realtime: tick on the own state's arrival, or on the timer (realtime_tick.py)

    def validate(self) -> None:
        """Raise :class:`ConfigError` naming the first bad parameter."""
        ids = list(self.robot_ids)
        if len(set(ids)) != len(ids) or not ids:
            raise ConfigError(f"parameter 'robot_ids' must be distinct ids, got {ids}")
        if self.robot_id not in ids:
            raise ConfigError(
                f"parameter 'id' = {self.robot_id} is not one of the swarm's robot ids "
                f"{_short(ids)} (set 'robots' or 'robot_ids')"
            )
        if self.mode not in MODES:
            raise ConfigError(f"parameter 'mode' = {self.mode!r} is not one of {', '.join(MODES)}")
        if not (np.isfinite(self.state_timeout) and self.state_timeout > 0):
            raise ConfigError(f"parameter 'state_timeout' must be > 0 seconds, got {self.state_timeout}")
        if not (np.isfinite(self.future_tolerance) and self.future_tolerance >= 0):
            raise ConfigError(
                f"parameter 'future_tolerance' must be >= 0 seconds, got {self.future_tolerance}"
            )
        if not (np.isfinite(self.command_limit) and self.command_limit >= 0):
            raise ConfigError(
                f"parameter 'command_limit' must be >= 0 (0: the policy's), got {self.command_limit}"
            )
        if not (np.isfinite(self.control_rate) and self.control_rate >= 0):
            raise ConfigError(f"parameter 'control_rate' must be > 0 Hz, got {self.control_rate}")
        if self.tick_on not in TICK_ON:
            raise ConfigError(
                f"parameter 'realtime_tick' = {self.tick_on!r} is not one of {', '.join(TICK_ON)}"
            )
        if self.rate_check not in RATE_CHECKS:
            raise ConfigError(
                f"parameter 'rate_check' = {self.rate_check!r} is not one of {', '.join(RATE_CHECKS)}"
            )


def _short(ids: Sequence[int]) -> str:
    ids = list(ids)
    if len(ids) > 1 and ids == list(range(ids[0], ids[-1] + 1)):
        return f'{ids[0]}..{ids[-1]}'
    return str(ids)


@dataclass
class Command:
    """A command to publish: ``value [m]`` stamped ``stamp_ns``.

    ``step`` is the own state's step (None for a stop command), ``neighbours`` the number of
    real neighbour rows in Y, ``stop`` marks a zero command for a stale own state and
    ``resend`` a repeated lockstep command.
    """

    stamp_ns: int
    step: Optional[int]
    value: np.ndarray
    stop: bool = False
    resend: bool = False
    neighbours: int = 0


@dataclass
class _Lockstep:
    first_step: Optional[int] = None
    pending: Optional[int] = None
    pending_since: float = 0.0
    answered: Optional[int] = None
    resend: bool = False
    gone: set = field(default_factory=set)


class AgentLogic:
    """Buffering, staleness, Y_i and the command of robot ``config.robot_id`` (see module doc)."""

    def __init__(self, config: AgentConfig, policy: PolicyLike, hearing: Optional[Hearing] = None):
        config.validate()
        self.config = config
        self.policy = policy
        self.spec = get_scenario(policy.scenario)
        self.me = int(config.robot_id)
        self.ids: List[int] = sorted(int(i) for i in config.robot_ids)
        self.index = {rid: n for n, rid in enumerate(self.ids)}
        self.dt = float(policy.dt)
        self.tau = int(policy.tau)
        self.k = int(policy.k)
        self.d_cr = float(policy.d_cr)
        self.limit: Optional[float] = effective_limit(policy.command_limit, config.command_limit)
        self.timeout_ns = int(round(config.state_timeout * 1e9))
        self.future_ns = int(round(config.future_tolerance * 1e9))
        # What this robot hears (buffer, newest stamps, receipt counters): its own, or the one its
        # hosting process files for all its robots, which hear the same (logic/agent/hearing.py).
        own_hearing = Hearing(
            self.spec.state_dim, self.ids, self.dt, self.tau, self.timeout_ns, self.future_ns
        )
        if hearing is not None and hearing.key() != own_hearing.key():
            raise ValueError(f'robot {self.me}: a shared hearing must have the same settings')
        self.hearing = hearing if hearing is not None else own_hearing
        self.stamps: Dict[Tuple[int, int], int] = {}  # (robot, step) -> exact stamp (own robot only)
        self._own_rows: Dict[int, np.ndarray] = {}  # step -> own row of Y, when not the filed state
        self.counters = Counters(
            self.hearing.counters,
            {
                name: 0
                for name in (
                    'commands',
                    'stop_commands',
                    'resent',
                    'gave_up',
                    'non_finite_command',
                    'clipped',
                    'late_ticks',
                )
            },
        )
        self.last_command: Optional[Command] = None
        self.events: List[str] = []  # human-readable notes for the node to log, drained by it
        self._lock = _Lockstep()
        self._last_tick_ns: Optional[int] = None
        self._stop_v: Optional[np.ndarray] = None  # estimated velocity while stopping (acceleration)
        # Realtime: each command is held one control period; the policy was trained for one dt.
        self.period = (
            check_control_period(config.control_rate, self.dt)
            if config.mode == 'realtime' and config.control_rate > 0
            else None
        )
        if self.period is not None and not self.period.equal:
            if config.rate_check == 'refuse':
                raise ConfigError(f"parameter 'control_rate' (rate_check refuse): {self.period.describe()}")
            if config.rate_check == 'warn':
                self.events.append(self.period.describe())
        # Realtime ticks on the own state's arrival (None: on the control timer).
        period_s = 1.0 / config.control_rate if config.control_rate > 0 else self.dt
        self.ticks = (
            TickOnState(period_s, period_s / 2)
            if config.mode == 'realtime' and config.tick_on == 'state'
            else None
        )

    # --- input ---------------------------------------------------------------------
    @property
    def buffer(self):
        """The :class:`DelayBuffer` of what this robot heard."""
        return self.hearing.buffer

    @property
    def newest_ns(self) -> Dict[int, int]:
        """Newest stamp heard per robot."""
        return self.hearing.newest_ns

    @property
    def last_drop(self) -> Optional[Tuple[str, int, int]]:
        """(reason, robot, stamp_ns) of the latest dropped state."""
        return self.hearing.last_drop

    def receive(
        self,
        robot: Optional[int],
        stamp_ns: int,
        z,
        now_ns: Optional[int] = None,
        wall: float = 0.0,
        verdict: Any = '',
        step: Optional[int] = None,
    ) -> str:
        """File robot ``robot``'s state ``z [d]`` stamped ``stamp_ns``; returns ``accepted``,
        ``duplicate`` or the drop reason (see :data:`DROP_REASONS`).

        ``now_ns`` is the node's clock (None or <= 0 while it is unknown: no age checks);
        ``wall`` a monotonic time in seconds (lockstep waiting). ``verdict``: the result of
        :meth:`check` on these arguments when the caller has it already; ``step``: the step the
        state stands for, when the caller chose it (default: the stamp's nearest).
        """
        outcome, step = self.hearing.file(robot, stamp_ns, z, now_ns, verdict, step)
        if step is not None:
            self.react(int(robot), int(stamp_ns), step, outcome == 'accepted', wall)
        return outcome

    def react(self, robot: int, stamp_ns: int, step: int, accepted: bool, wall: float) -> None:
        """What robot ``robot``'s state of ``step`` (just filed: ``accepted``, or a duplicate)
        changes for this robot: its own state opens a command (or asks for a re-send); a
        robot left out is waited for again. A hosting process files a state once and calls
        this only for the robots it concerns (its owner, and those that left it out)."""
        if not accepted:
            lock = self._lock
            if robot == self.me and lock.answered == step and self.last_command is not None:
                lock.resend = True
            if robot == self.me and self.ticks is not None:
                self.ticks.repeated(step, wall)
            return
        if robot == self.me:
            self.stamps[(robot, step)] = int(stamp_ns)
            self._forget_stamps(step)
            self._own_state(step, wall)
            if self.ticks is not None:
                self.ticks.own_state(step, stamp_ns, wall)
            return
        if self.ticks is not None:
            self.ticks.heard(step, wall)  # a late neighbour's state may re-open a tick computed without it
        if robot in self._lock.gone and step >= self._current_step() - self.tau:
            self._lock.gone.discard(robot)
            self.events.append(f'robot {robot} is heard again (step {step}): waiting for it again')

    def malformed(self) -> str:
        """Count a message that could not be decoded at all; returns ``malformed``."""
        return self.hearing.malformed()

    def _current_step(self) -> int:
        lock = self._lock
        current = lock.pending if lock.pending is not None else lock.answered
        return -1 if current is None else current

    def check(self, robot, stamp_ns, z, now_ns) -> Optional[str]:
        """The drop reason of a state (None: acceptable), before the duplicate check."""
        return self.hearing.check(robot, stamp_ns, z, now_ns)

    def _forget_stamps(self, step: int) -> None:
        if len(self.stamps) > 4 * self.buffer.horizon:
            cut = step - self.buffer.horizon
            for key in [key for key in self.stamps if key[1] < cut]:
                del self.stamps[key]

    def _own_state(self, step: int, wall: float) -> None:
        lock = self._lock
        if lock.first_step is None or step < lock.first_step:
            lock.first_step = step
        newest = lock.pending if lock.pending is not None else lock.answered
        if newest is None or step > newest:  # a new step (a late, older one is only filed)
            lock.pending = step
            lock.pending_since = wall

    @property
    def left_out(self) -> set:
        """Lockstep: the robots given up on (no state within ``state_timeout``) until heard again."""
        return self._lock.gone

    @property
    def waiting_since(self) -> Optional[float]:
        """Lockstep: the wall time the pending own step arrived (None: nothing pending or re-sent)."""
        lock = self._lock
        return lock.pending_since if lock.pending is not None or lock.resend else None

    # --- readiness -----------------------------------------------------------------
    def heard(self) -> List[int]:
        """Robots heard from at least once (ids, ascending)."""
        newest = self.hearing.newest_ns
        return [rid for rid in self.ids if rid in newest]

    def missing(self) -> List[int]:
        """Robots never heard from."""
        newest = self.hearing.newest_ns
        return [rid for rid in self.ids if rid not in newest]

    @property
    def ready(self) -> bool:
        """Every robot of the swarm (this one included) heard at least once."""
        return len(self.newest_ns) == len(self.ids)

    # --- lockstep ------------------------------------------------------------------
    def lockstep_poll(self, wall: float) -> Optional[Command]:
        """The command for the pending own step once every live peer's needed state is here
        (or a re-send of the last one); None while waiting. Call after every ``receive`` and
        now and then (a timer) so that silent peers time out."""
        return self._now(self.lockstep_next(wall))

    def lockstep_next(self, wall: float):
        """:meth:`lockstep_poll` short of the policy call: None, a re-sent :class:`Command`, or
        the :class:`Request` of the pending step (then marked answered: call :meth:`finish`)."""
        lock = self._lock
        if lock.resend:
            lock.resend = False
            self.counters['resent'] += 1
            last = self.last_command
            return Command(
                last.stamp_ns, last.step, last.value.copy(), resend=True, neighbours=last.neighbours
            )
        if lock.pending is None:
            return None
        s = lock.pending
        need = max(s - self.tau, lock.first_step)
        timed_out = wall - lock.pending_since >= self.config.state_timeout
        # Fewer states of step `need` filed than the robots waited for (the peers not left out, and
        # this one when its own is among them): one is missing, no need to look which.
        if not timed_out and not self.hearing.complete(need, len(self.ids) - len(lock.gone), self.me):
            return None
        rows = self.hearing.exact(need)  # the snapshot every robot of the process asking for `need` shares
        missing = (
            []
            if len(rows) == len(self.ids)
            else [
                rid for rid in self.ids if rid not in rows.index and rid != self.me and rid not in lock.gone
            ]
        )
        if missing:
            # A robot never heard is still being discovered, not silent: the simulator starts the
            # clock only once every agent heard every robot, so giving up on it would only break
            # the first steps (seen under load while discovery was still running).
            if not timed_out or any(rid not in self.hearing.newest_ns for rid in missing):
                return None
            for rid in missing:
                lock.gone.add(rid)
                self.counters['gave_up'] += 1
            self.events.append(
                f'step {s}: no state of step {need} from robot(s) {missing} within '
                f'{self.config.state_timeout:g} s: left out until heard again'
            )
        if self.me not in rows.index:
            z = self.buffer.at(self.me, need)  # own delayed state lost: the closest one before
            rows = rows.with_row(self.me, z)
        own = self.buffer.get(self.me, s)
        request = self._request(s, self.stamps.get((self.me, s), int(round(s * self.dt * 1e9))), own, rows)
        lock.answered = s
        lock.pending = None
        return request

    # --- realtime ------------------------------------------------------------------
    def tick(self, now_ns: Optional[int]) -> Optional[Command]:
        """The command of a control tick at ``now_ns`` (None before the own state is heard)."""
        return self._now(self.tick_next(now_ns))

    def tick_next(self, now_ns: Optional[int], stop_only: bool = False):
        """:meth:`tick` short of the policy call: None, a stop :class:`Command` or a :class:`Request`
        (``stop_only``: :meth:`watchdog`'s, a fresh own state gives None)."""
        latest = self.buffer.latest(self.me)
        if latest is None:
            return None
        s, own = latest
        own_ns = self.newest_ns[self.me]
        clock_known = now_ns is not None and now_ns > 0
        period_ns = None if self._last_tick_ns is None or not clock_known else now_ns - self._last_tick_ns
        if clock_known:
            self._last_tick_ns = int(now_ns)
        if clock_known and now_ns - own_ns > self.timeout_ns:
            return self._stop(int(now_ns), own, own_ns, period_ns)
        if stop_only:
            return None
        self._stop_v = None
        # every robot heard within the timeout (this one too: its own state is not stale), at s - tau
        return self._request(s, own_ns, own, self.hearing.delayed(s, now_ns))

    def watchdog(self, now_ns: Optional[int]) -> Optional[Command]:
        """The control timer when ticks come with the own state: the stop command of an own state
        older than ``state_timeout`` (as :meth:`tick`), else None."""
        return self.tick_next(now_ns, stop_only=True)

    def realtime_poll(self, now_ns: Optional[int], wall: float) -> Optional[Command]:
        """The command of the pending own-state tick once it is due (:mod:`.realtime_tick`), else
        None. Call after every ``receive`` and now and then (a timer) so that the grace passes."""
        return self._now(self.realtime_next(now_ns, wall))

    def realtime_next(self, now_ns: Optional[int], wall: float, force: bool = False) -> Optional[Request]:
        """:meth:`realtime_poll` short of the policy call: None or the due tick's :class:`Request`
        (``force``: due now, see :meth:`.realtime_tick.TickOnState.due`)."""
        got = (
            None
            if self.ticks is None
            else self.ticks.due(self.hearing, self.tau, self.me, now_ns, wall, force)
        )
        if got is None:
            return None
        s, stamp, late = got
        own = self.buffer.get(self.me, s)
        if own is None:  # fell out of the buffer's horizon while waiting (never in practice): skip it
            return None
        rows = self.hearing.delayed(s, now_ns)
        if self.me not in rows.index:
            # The own state went stale while the tick waited (a process fallen behind its
            # messages): no command from it; the watchdog stops the robot.
            return None
        if late:
            self.counters['late_ticks'] += 1
        self._stop_v = None
        return self._request(s, stamp, own, rows)

    def _stop(self, now_ns: int, own: np.ndarray, own_ns: int, period_ns: Optional[int]) -> Command:
        """The stop command of a stale own state (see the module doc)."""
        self.counters['stop_commands'] += 1
        kind = self.spec.command
        hold = period_ns * 1e-9 if period_ns and period_ns > 0 else self.dt  # time since the last tick
        v = np.zeros(self.spec.command_dim)
        if kind == 'acceleration':
            last = self.last_command
            if self._stop_v is None:  # stopping starts: the last state carried forward under the held command
                held = last.value if last is not None and not last.stop else 0.0
                v = own[self.spec.velocity] + held * ((now_ns - own_ns) * 1e-9)
            else:  # the previous brake was held for one tick; braking never reverses an axis
                prev = self._stop_v
                v = prev + last.value * hold
                v[(np.sign(v) * np.sign(prev) < 0) | (np.abs(v) < 1e-9)] = 0.0  # at rest (no float dust)
            self._stop_v = v
        cmd = Command(int(now_ns), None, stop_command(kind, v, self.limit, hold), stop=True)
        self.last_command = cmd
        return cmd

    # --- the command ---------------------------------------------------------------
    def neighbour_matrix(self, own: np.ndarray, rows: Dict[int, np.ndarray]) -> Tuple[np.ndarray, np.ndarray]:
        """Y ``[k, d]`` and mask ``[k]`` from the own state ``own [d]`` and each robot's delayed
        state ``rows {id: [d]}`` (this robot's included: it centres the radius), rows in id order."""
        ids = sorted(rows)
        request = Request(0, 0, self.me, np.asarray(own), Rows(ids, [rows[rid] for rid in ids], len(own)))
        self.build([request])
        return request.Y, request.mask

    def build(self, requests: Sequence[Request]) -> None:
        """Fill Y and mask of ``requests`` (this robot's, or its process-mates': same settings)."""
        build_matrices(requests, self.spec.position_dim, self.d_cr, self.k)

    @property
    def parity_index(self) -> Optional[Dict[int, int]]:
        """``{robot: swarm index}`` when the policy is evaluated in a batch shaped like the
        offline rollout's (lockstep with ``parity_batch`` and more than one robot), else None."""
        parity = self.config.parity_batch and self.config.mode == 'lockstep' and len(self.ids) > 1
        return self.index if parity else None

    def evaluate(self, Y: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """The policy's command ``[m]`` for one ``Y [k, d]``, ``mask [k]`` (before the agent's clip)."""
        return evaluate_batch(self.policy, Y[None], mask[None], [self.me], self.parity_index)[0]

    def own_row(self, step: int, z) -> None:
        """The own row of Y for ``step`` when it is not the state filed for the others (a pose
        fleet's command-aided own velocity, :class:`knode_swarm_ros.logic.contract.pose.PoseStates`)."""
        step = int(step)
        self._own_rows[step] = np.asarray(z, dtype=np.float64)
        if len(self._own_rows) > 4 * self.buffer.horizon:
            for s in [s for s in self._own_rows if s < step - self.buffer.horizon]:
                del self._own_rows[s]

    def _request(self, step: int, stamp: int, own: np.ndarray, rows: Rows) -> Request:
        return Request(int(step), int(stamp), self.me, self._own_rows.get(int(step), own), rows)

    def _now(self, item):
        """A :class:`Request` built, evaluated alone and finished; anything else as it is."""
        if isinstance(item, Request):
            self.build([item])
            return self.finish(item, self.evaluate(item.Y, item.mask))
        return item

    def finish(self, request: Request, u: np.ndarray) -> Command:
        """The command of ``request`` from the policy's output ``u [m]``: a non-finite output
        becomes zero, then the per-axis clip; counted and remembered as the last command."""
        value, non_finite, clipped = clean_commands(np.asarray(u, dtype=np.float64)[None], self.limit)
        return self.commit(request, value[0], bool(non_finite[0]), bool(clipped[0]), u)

    def commit(self, request: Request, value: np.ndarray, non_finite: bool, clipped: bool, raw) -> Command:
        """:meth:`finish` after :func:`clean_commands` (a hosting process cleans its batch at once)."""
        step = request.step
        if non_finite:
            self.counters['non_finite_command'] += 1
            self.events.append(
                f'step {step}: the policy returned {np.asarray(raw).tolist()}: publishing zero'
            )
        if clipped:
            self.counters['clipped'] += 1
        self.counters['commands'] += 1
        cmd = Command(int(request.stamp_ns), int(step), value, neighbours=int(request.mask.sum()) - 1)
        self.last_command = cmd
        return cmd

    # --- reporting -----------------------------------------------------------------
    def drain_events(self) -> List[str]:
        """Notes since the last call (the node logs them)."""
        events, self.events = self.events, []
        return events

    def status(self) -> Dict[str, Any]:
        """JSON-able summary: readiness, counters, lockstep bookkeeping."""
        lock = self._lock
        return {
            'id': self.me,
            'ready': self.ready,
            'dt': self.dt,
            'heard': len(self.heard()),
            'robots': len(self.ids),
            'missing': self.missing()[:20],
            'mode': self.config.mode,
            'answered': lock.answered,
            'pending': lock.pending,
            'gone': sorted(lock.gone),
            'counters': dict(self.counters),
            'policy_dt': self.dt,
            'control_period': None if self.period is None else self.period.control_period,
            'realtime_tick': None if self.config.mode != 'realtime' else self.config.tick_on,
            'period_ratio': None if self.period is None else self.period.ratio,
        }
