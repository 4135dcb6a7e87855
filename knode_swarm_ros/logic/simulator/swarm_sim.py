"""The simulated swarm, without ROS: state, commands, integration, lockstep bookkeeping.

:class:`SwarmSim` holds robots ``0 .. n-1`` of a robot model (parameter ``robot_model``,
:mod:`.robot_models`; by default the scenario's point robots, stepped by the core's
:func:`zoh_step`, docs/DESIGN.md "Rollout semantics") and the newest command of each, and advances
one step of ``dt`` at a time under the commands held; or, in ground-truth mode, with the Tanner /
boids stepper of :mod:`knode_swarm_ros.core.groundtruth`, which ignores commands.

* lockstep: a step advances once every live robot has answered the current step (a command
  stamped with the current state's stamp). A robot still silent ``lockstep_timeout`` wall
  seconds after the step was published is declared lost: it is stopped (below) and not waited
  for, until a command for the current step comes from it again (it rejoins).
* realtime: each step uses each robot's newest command (by stamp); a robot whose newest command
  is older than ``command_timeout`` seconds of simulated time (or that never sent one) is stopped.
  With ``substeps`` k > 1 (a motion capture faster than the policy) a step of ``dt`` is taken
  as k sub-steps of ``dt / k``, each integrating exactly the command held at its start, so a
  command that arrives mid-step acts from the next sub-step on, as on a real robot; the states
  of every sub-step are published. Lockstep takes whole steps only (k = 1).

Stopping follows docs/DESIGN.md and is the robot model's: a velocity-commanded robot gets zero
velocity, an acceleration-commanded one brakes to rest at the saturated deceleration
(:func:`knode_swarm_ros.core.saturation.stop_command` with ``stop_limit``), a differential-drive
base is commanded (0, 0) and brakes within its limits; it never coasts.

It also keeps the figures the benchmark reports: state-to-command latency (wall seconds from
publishing a state to receiving the first command stamped with it) and command counters.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Dict, List, Optional, Sequence, Tuple

import numpy as np

from knode_swarm_ros.core.scenarios import Scenario, get_scenario
from knode_swarm_ros.logic.common import MODES, ConfigError, percentiles, stamp_ns, step_of

from .robot_models import DEFAULT_ROBOT_MODEL, RobotModel, make_robot_model

__all__ = [
    'setpoint_acceleration',
    'SwarmSim',
    'initial_state',
    'initial_state_from_file',
    'random_start',
    'has_ground_truth',
    'SPACING',
    'make_ground_truth',
    'ground_truth_variants',
    'COMMAND_OUTCOMES',
]

#: What :meth:`SwarmSim.offer` can answer (each has a counter).
COMMAND_OUTCOMES = (
    'accepted',
    'unknown_id',
    'bad_size',
    'non_finite',
    'stale',
    'future',
    'rejoined',
    'malformed',
)


def setpoint_acceleration(setpoint, velocity, dt: float) -> np.ndarray:
    """The acceleration ``[m]`` a simulated robot with a velocity loop applies for a velocity
    setpoint: ``(v_sp - v) / dt``, so that it reaches ``v_sp`` after one step (the ideal loop
    docs/ros.md, "Velocity setpoints", assumes), from its true velocity ``v [m]``."""
    return (np.asarray(setpoint, dtype=np.float64) - np.asarray(velocity, dtype=np.float64)) / float(dt)


def has_ground_truth(scenario) -> bool:
    """Whether ``scenario`` (any reference) has a ground-truth law here: the paper's two only
    (Tanner for flock2d, boids for boids3d)."""
    return get_scenario(scenario).shipped


def ground_truth_variants(scenario: str) -> Tuple[str, ...]:
    """Variants (flock2d) or presets (boids3d) of the ground truth, the paper's first; none for a
    scenario of one's own."""
    from knode_swarm_ros.core import groundtruth

    return tuple(groundtruth.presets(scenario)) if has_ground_truth(scenario) else ()


def _check_variant(scenario: str, variant: str) -> str:
    names = ground_truth_variants(scenario)
    if not names:
        if variant:
            raise ConfigError(
                f"parameter 'variant' = {variant!r}: scenario {get_scenario(scenario).name} has no "
                'ground-truth law (only flock2d and boids3d have)'
            )
        return ''
    variant = variant or names[0]
    if variant not in names:
        raise ConfigError(
            f"parameter 'variant' = {variant!r} is not a {scenario} ground-truth variant; "
            f'known: {", ".join(names)}'
        )
    return variant


#: Default spacing (m) of a random start without an arena: about one robot per SPACING^dimensions.
SPACING = 1.0


def random_start(spec: Scenario, robots: int, rng: np.random.Generator) -> np.ndarray:
    """A random initial state ``[robots, d]`` of a scenario of one's own (no ground truth to
    draw it from): positions uniform in the box ``[-a, a]^dimensions``, with ``a`` half the
    arena's half width (the middle of the arena, clear of the walls), or without an arena
    ``a = SPACING * robots^(1/dimensions) / 2`` (about one robot per ``SPACING^dimensions``);
    velocities zero (at rest); headings uniform on the unit circle or sphere."""
    dims = spec.dimensions
    half = 0.5 * spec.arena if spec.arena is not None else 0.5 * SPACING * robots ** (1.0 / dims)
    z = np.zeros((robots, spec.state_dim))
    z[:, spec.position] = rng.uniform(-half, half, size=(robots, dims))
    if spec.heading is not None:
        h = rng.standard_normal((robots, dims))
        z[:, spec.heading] = h / np.linalg.norm(h, axis=1, keepdims=True)
    return z


def initial_state(scenario: str, robots: int, seed: int, variant: str = ''):
    """The training density's initial condition for any number of robots.

    Returns (``z0 [robots, d]``, the ground-truth swarm in that state, or None). For the paper's
    scenarios it equals frame 0 of ``core.groundtruth.simulate(scenario, 1, robots, 1, seed,
    variant)``: flock2d draws Tanner initial states; boids3d spawns boids and discards the first
    frames as the dataset generator does. Any other scenario has no ground truth: a
    :func:`random_start` drawn from ``seed``.
    """
    from knode_swarm_ros.core.groundtruth import (
        BOIDS_PRESETS,
        DISCARD_FRAMES,
        BoidsSwarm,
        TannerSwarm,
        tanner,
    )

    variant = _check_variant(scenario, variant)
    if robots < 1:
        raise ConfigError(f"parameter 'robots' must be >= 1, got {robots}")
    rng = np.random.default_rng(seed)
    spec = get_scenario(scenario)
    if not has_ground_truth(spec):
        return random_start(spec, robots, rng), None
    if spec.name == 'flock2d':
        swarm = TannerSwarm(tanner.initial_states(rng, 1, robots, variant), variant)
    else:
        swarm = BoidsSwarm.spawn(rng, 1, robots, BOIDS_PRESETS[variant])
        for _ in range(DISCARD_FRAMES):
            swarm.step()
    return swarm.observe()[0], swarm


def initial_state_from_file(ref: str, scenario: str, robots: int = 0) -> Tuple[np.ndarray, str, int]:
    """Frame 0 of trajectory ``TRAJ`` of ``FILE.npz[:TRAJ]`` -> (``z0 [n, d]``, path, traj).

    Raises:
        ConfigError: unreadable file, wrong scenario, no such trajectory, or ``robots`` > 0 and
            different from the file's n.
    """
    from knode_swarm_ros.core.trajectory import TrajectoryError, load_trajectories, parse_trajectory_ref

    path, traj = parse_trajectory_ref(ref)
    try:
        data = load_trajectories(path, scenario)
    except TrajectoryError as exc:
        raise ConfigError(f"parameter 'init': {exc}") from None
    count = data.states.shape[0]
    if not 0 <= traj < count:
        raise ConfigError(
            f"parameter 'init' = {ref!r}: trajectory {traj} does not exist ({path} holds "
            f'{count}, indices 0..{count - 1})'
        )
    z0 = np.array(data.states[traj, 0], dtype=np.float64)
    if robots and robots != z0.shape[0]:
        raise ConfigError(
            f"parameter 'robots' = {robots} but trajectory {traj} of {path} has {z0.shape[0]} robots"
        )
    return z0, path, traj


def make_ground_truth(scenario: str, z0: np.ndarray, variant: str = '', dt: Optional[float] = None):
    """A ground-truth stepper (``step() -> [1, n, d]``) starting from ``z0 [n, d]``.

    boids3d states carry no speed: the boids start at the spawn speed (see BoidsSwarm).

    Raises:
        ConfigError: a scenario without a ground-truth law (:func:`has_ground_truth`), a bad
            variant, or ``dt`` other than the law's.
    """
    from knode_swarm_ros.core.groundtruth import BOIDS_PRESETS, BoidsSwarm, TannerSwarm

    spec = get_scenario(scenario)
    if not has_ground_truth(spec):
        raise ConfigError(
            f"parameter 'ground_truth': scenario {spec.name} has no ground-truth law (only flock2d "
            'and boids3d have); drive it with agents running a policy'
        )
    variant = _check_variant(scenario, variant)
    if dt is not None and not np.isclose(dt, spec.dt, rtol=1e-9, atol=0):
        raise ConfigError(f"parameter 'dt' = {dt:g}: the {scenario} ground truth steps at dt = {spec.dt:g}")
    if spec.name == 'flock2d':
        return TannerSwarm(np.asarray(z0)[None], variant)
    return BoidsSwarm.from_observation(np.asarray(z0)[None], BOIDS_PRESETS[variant])


@dataclass
class _Counters:
    accepted: int = 0
    unknown_id: int = 0
    bad_size: int = 0
    non_finite: int = 0
    stale: int = 0
    future: int = 0
    rejoined: int = 0
    malformed: int = 0  # undecodable command messages (:meth:`SwarmSim.malformed`)
    commanded: int = 0  # distinct (robot, step) commands received (a re-send counts once; recent 64 steps)
    zeroed: int = 0  # robot-steps stopped (lost in lockstep, command too old in realtime)
    lost_events: int = 0


class SwarmSim:
    """n robots, their states and commands (see the module doc).

    Args:
        scenario: any scenario reference (a shipped name, a YAML file, the JSON object).
        z0: ``[n, d]`` initial states of robots 0 .. n-1.
        dt: seconds per step.
        mode: ``lockstep`` or ``realtime``.
        command_timeout: realtime: commands older than this (simulated seconds) count as zero.
        ground_truth: optional stepper (``step() -> [1, n, d]``) that replaces the commands.
        stop_limit: per-axis deceleration limit of a braking stop (None or 0: rest in one step).
        robot_model: a name of :data:`.robot_models.ROBOT_MODELS`; the robots are built from ``z0``
            (their states are the model's ``states()``, commands ``[m]`` the model's).
        robot_params: the model's parameters (e.g. the unicycle's limits; others are ignored).
        substeps: realtime: sub-steps per step (states published every ``dt / substeps``).
    """

    robots: RobotModel

    def __init__(
        self,
        scenario: str,
        z0,
        dt: float,
        mode: str = 'lockstep',
        command_timeout: float = 0.5,
        ground_truth=None,
        stop_limit: Optional[float] = None,
        robot_model: str = DEFAULT_ROBOT_MODEL,
        robot_params: Optional[Dict[str, float]] = None,
        substeps: int = 1,
    ):
        self.spec: Scenario = get_scenario(scenario)
        z0 = np.array(z0, dtype=np.float64)
        if z0.ndim != 2 or z0.shape[1] != self.spec.state_dim or z0.shape[0] < 1:
            raise ConfigError(f'initial state must be [n, {self.spec.state_dim}], got {z0.shape}')
        if not np.all(np.isfinite(z0)):
            raise ConfigError('initial state holds non-finite values')
        if mode not in MODES:
            raise ConfigError(f"parameter 'mode' = {mode!r} is not one of {', '.join(MODES)}")
        if not dt > 0:
            raise ConfigError(f"parameter 'dt' must be > 0, got {dt}")
        if int(substeps) != substeps or substeps < 1:
            raise ConfigError(f'substeps must be an integer >= 1, got {substeps}')
        if substeps != 1 and (mode == 'lockstep' or ground_truth is not None):
            raise ConfigError('sub-steps (a state rate above 1 / dt) are for realtime runs of agents only')
        self.n = z0.shape[0]
        self.dt = float(dt)
        self.mode = mode
        self.substeps = int(substeps)
        self.h = self.dt / self.substeps  # seconds per sub-step (dt itself when substeps is 1)
        self.sub = 0  # sub-steps taken within the current step
        self.command_timeout_ticks = float(command_timeout) / self.h
        self.ground_truth = ground_truth
        if stop_limit is not None and not (np.isfinite(stop_limit) and stop_limit >= 0):
            raise ConfigError(f"parameter 'command_limit' must be >= 0, got {stop_limit}")
        self.stop_limit = float(stop_limit) if stop_limit else None
        self.robots = make_robot_model(robot_model, self.spec, z0, ground_truth is not None, robot_params)
        self.step = 0
        self.states = self.robots.states()
        m = self.robots.command_dim
        self.commands = np.zeros((self.n, m))  # newest command of each robot
        self.command_tick = np.full(self.n, -1, dtype=np.int64)  # its stamp's sub-step (-1: none yet)
        self.applied = np.zeros((self.n, m))  # what the last step applied
        self.answered = set()  # lockstep: robots that answered self.step
        self.lost = set()  # lockstep: not waited for
        self.silent_since: Dict[int, int] = {}  # robot -> step since which it is stopped for silence
        self._settled = 0  # lockstep: robots answered or lost (|answered | lost|)
        self.counters = _Counters()
        self.latency: List[float] = []  # wall seconds, state published -> first command
        self._published: Dict[int, float] = {}  # tick -> wall time it was published
        self._latency_seen = set()  # (robot, step)
        self._commanded: Dict[int, set] = {}  # step -> robots whose command for it arrived (recent steps)
        self.step_wall = 0.0  # wall time self.step was first published

    # --- time ----------------------------------------------------------------------
    @property
    def tick(self) -> int:
        """Sub-steps since the start (the step itself when ``substeps`` is 1)."""
        return self.step * self.substeps + self.sub

    @property
    def stamp_ns(self) -> int:
        """Stamp of the current state."""
        return stamp_ns(self.step, self.dt) + stamp_ns(self.sub, self.h)

    def note_published(self, wall: float) -> None:
        """The current state has been published at ``wall`` (first time only counts)."""
        if self.tick not in self._published:
            self._published[self.tick] = wall
            self.step_wall = wall
            if len(self._published) > 512:
                for s in sorted(self._published)[:256]:
                    del self._published[s]

    # --- commands ------------------------------------------------------------------
    def offer(self, robot: int, ns: int, u, wall: float = 0.0) -> str:
        """A command from ``robot`` stamped ``ns``; returns one of :data:`COMMAND_OUTCOMES`."""
        c = self.counters
        if not 0 <= robot < self.n:
            c.unknown_id += 1
            return 'unknown_id'
        u = np.asarray(u, dtype=np.float64)
        if u.shape != (self.robots.command_dim,):
            c.bad_size += 1
            return 'bad_size'
        if not np.all(np.isfinite(u)):
            c.non_finite += 1
            return 'non_finite'
        s = step_of(ns, self.h)  # a sub-step (the step when substeps is 1)
        if s > self.tick:
            c.future += 1
            return 'future'
        seen = self._commanded.setdefault(s, set())
        if robot not in seen:
            seen.add(robot)
            c.commanded += 1
            if len(self._commanded) > 64:
                del self._commanded[min(self._commanded)]
        if (robot, s) not in self._latency_seen and s in self._published:
            self._latency_seen.add((robot, s))
            self.latency.append(wall - self._published[s])
            if len(self._latency_seen) > 100_000:
                self._latency_seen.clear()
        if self.mode == 'lockstep':
            if s < self.step or robot in self.answered:
                c.stale += 1
                return 'stale'
            self.commands[robot] = u
            self.command_tick[robot] = s
            self.answered.add(robot)
            if robot in self.lost:  # (settled already, as lost)
                self.lost.discard(robot)
                self.silent_since.pop(robot, None)
                c.rejoined += 1
                return 'rejoined'
            self._settled += 1
            c.accepted += 1
            return 'accepted'
        if s < self.command_tick[robot]:  # an older command overtaken by a newer one
            c.stale += 1
            return 'stale'
        self.commands[robot] = u
        self.command_tick[robot] = s
        c.accepted += 1
        return 'accepted'

    def malformed(self) -> str:
        """Count a command message that could not be decoded; returns ``malformed``."""
        self.counters.malformed += 1
        return 'malformed'

    # --- lockstep ------------------------------------------------------------------
    def waiting(self) -> List[int]:
        """Live robots that have not answered the current step."""
        return [r for r in range(self.n) if r not in self.answered and r not in self.lost]

    def can_advance(self) -> bool:
        """Lockstep: every live robot answered (always true in ground-truth mode). Counted, not
        scanned: this runs after every command."""
        return self.ground_truth is not None or self._settled >= self.n

    def overdue(self, wall: float, timeout: float) -> List[int]:
        """Robots still waited for ``timeout`` wall seconds after the step was published."""
        if self.ground_truth is not None or wall - self.step_wall < timeout:
            return []
        return self.waiting()

    def declare_lost(self, robots: Sequence[int]) -> None:
        """Stop ``robots`` (brake or zero velocity) and stop waiting for them."""
        for r in robots:
            if r not in self.lost:
                self.lost.add(r)
                self.silent_since.setdefault(r, self.step)
                self.counters.lost_events += 1
                self._settled += r not in self.answered

    # --- stepping ------------------------------------------------------------------
    def advance(self) -> np.ndarray:
        """One sub-step of ``dt / substeps`` (a step of ``dt`` when ``substeps`` is 1); returns the
        new states ``[n, d]``."""
        if self.ground_truth is not None:
            self.states = np.array(self.ground_truth.step()[0], dtype=np.float64)
            self.robots.place(self.states)
        else:
            command = self.commands.copy()
            if self.mode == 'realtime':
                old = (self.command_tick < 0) | (self.tick - self.command_tick > self.command_timeout_ticks)
                self._note_silent(old & (self.command_tick >= 0))
            else:
                old = np.zeros(self.n, dtype=bool)
                old[sorted(self.lost)] = True
            if old.any():
                self.counters.zeroed += int(np.count_nonzero(old))
                command[old] = self.stop_commands()[old]
            self.applied = command
            self.robots.step(command, self.h)
            self.states = self.robots.states()
        self.sub += 1
        if self.sub < self.substeps:
            return self.states
        self.sub = 0
        self.step += 1
        self.answered = set()
        self._settled = len(self.lost)
        return self.states

    def _note_silent(self, silent: np.ndarray) -> None:
        """Realtime: file robots whose commands stopped (``silent [n]``; a robot that never sent
        one is still starting, not silent) from this step, forget those that command again."""
        for r in np.flatnonzero(silent):
            self.silent_since.setdefault(int(r), self.step)
        for r in [r for r in self.silent_since if not silent[r]]:
            del self.silent_since[r]

    def stop_commands(self) -> np.ndarray:
        """``[n, m]``: the command that stops each robot from its current state (see module doc)."""
        return self.robots.stop_commands(self.stop_limit, self.h)

    # --- reporting -----------------------------------------------------------------
    def report(self) -> Dict[str, Any]:
        """JSON-able figures: steps, counters, latency percentiles (milliseconds), and the true
        states ``[n, d]`` now (``states``: what a noisy motion capture hides)."""
        lat = percentiles([x * 1e3 for x in self.latency])
        return {
            'step': self.step,
            'robots': self.n,
            'lost': sorted(self.lost),
            'silent_since': {str(r): s for r, s in sorted(self.silent_since.items())},
            'counters': dict(self.counters.__dict__),
            'latency_ms': {k: v for k, v in lat.items()},
            'states': self.states.tolist(),
        }
