"""The simulator's run: its phases, its timeouts and what it waits for, without ROS.

Phases: ``waiting`` (the initial state is re-published every ``republish_period`` until every
agent has heard every robot, and the recorder too when ``wait_for_recorder``), ``running``,
``done`` (after ``steps`` steps: the final state stays published until the recorder says it
has saved, then the run finishes with status 0). Startup that does not complete within
``startup_timeout`` finishes with status 1 and names who is missing; in lockstep, a robot
without a command ``lockstep_timeout`` wall seconds after its step was published is declared
lost (stopped, no longer waited for).

:class:`SimLifecycle` takes the events (a command, a status, a watchdog or physics tick) with the
wall time and acts through an :class:`Outputs` port (publish a frame or the status, log, start or
stop the physics timer, finish): a frame is published after each step, so the steps and the
publications interleave. The node (``simulator.py``) implements the port with ROS.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable, Dict, List, Optional, Protocol

from knode_swarm_ros.logic.common import EXIT_CONFIG, EXIT_FAILURE, EXIT_OK, dt_mismatch
from knode_swarm_ros.logic.reporting import Throttle

from .swarm_sim import SwarmSim

__all__ = ['LifecycleConfig', 'Outputs', 'SimLifecycle']

_LOCKSTEP_BURST = 20  # ground-truth lockstep: steps per watchdog call at most
_MAX_CATCH_UP = 10  # realtime: steps per physics tick at most; beyond, time is dropped and counted


@dataclass(frozen=True)
class LifecycleConfig:
    """The simulator parameters of the run's lifecycle (docs/ros.md, "simulator")."""

    steps: int  # 0: until stopped
    mode: str  # 'lockstep' or 'realtime'
    publish_every: int = 1  # realtime: sub-steps (steps without sub-steps) between published frames
    real_time_factor: float = 1.0
    lockstep_timeout: float = 5.0
    startup_timeout: float = 120.0
    republish_period: float = 0.5
    wait_for_agents: bool = True
    wait_for_recorder: bool = False
    recorder_max_lag: int = 50
    done_timeout: float = 30.0
    progress_period: float = 5.0
    exit_when_done: bool = True


class Outputs(Protocol):
    """What the lifecycle asks of its node."""

    def publish_frame(self) -> None: ...  # the current state of every robot, and the clock
    def publish_status(self) -> None: ...  # SimLifecycle.status_fields() as the status message
    def log(self, level: str, text: str) -> None: ...  # level: 'info', 'warn' or 'error'
    def start_physics(self, period: float) -> None: ...  # realtime: call on_physics every period wall s
    def stop_physics(self) -> None: ...
    def finish(self, code: int) -> None: ...  # the run is over: exit with this status


def _ids(ids) -> str:
    ids = list(ids)
    return str(ids) if len(ids) <= 12 else f'{ids[:12]} and {len(ids) - 12} more'


class SimLifecycle:
    """The simulator's phases around a :class:`SwarmSim` (see the module doc)."""

    def __init__(
        self,
        sim: SwarmSim,
        config: LifecycleConfig,
        out: Outputs,
        meta: Dict,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.sim, self.config, self.out, self.meta, self.clock = sim, config, out, meta, clock
        self.wait_for_agents = config.wait_for_agents
        self.phase = 'waiting'
        self.exit_code: Optional[int] = None
        self.agent_ready: Dict[int, bool] = {}
        self.agent_missing: Dict[int, List[str]] = {}  # robot -> names its agent never heard (newest status)
        self.recorder_ready = False
        self.recorder_saved = False
        self.recorder_progress = -1
        self.held_warned = set()
        self.wall0 = clock()
        self.run_wall0: Optional[float] = None
        self.run_step0 = 0
        self.run_tick0 = 0
        self.done_wall: Optional[float] = None
        self.last_publish = -1e9
        self.overruns = 0
        self.frames = 0
        self.last_progress = (self.wall0, 0)
        self.throttle = Throttle(clock=clock)

    # --- outputs -------------------------------------------------------------------
    def publish(self) -> None:
        """Publish the current state (and count it as a frame of the run once running)."""
        self.out.publish_frame()
        self.last_publish = self.clock()
        if self.phase == 'running':
            self.sim.note_published(self.last_publish)
            self.frames += 1

    def _finish(self, code: int) -> None:
        if self.exit_code is None:
            self.exit_code = code
            self.out.finish(code)

    def _throttled(self, key: str, text: str, level: str = 'info') -> None:
        if self.throttle.ready(key):
            self.out.log(level, text)

    def final_frame(self) -> int:
        return (self.sim.step // self.config.publish_every) * self.config.publish_every

    def status_fields(self) -> Dict:
        """The status message's fields (JSON)."""
        fields = dict(self.meta, phase=self.phase, step=self.sim.step, lost=sorted(self.sim.lost))
        # JSON object keys are strings: robot id -> the step since which the simulator stops it
        fields['silent_since'] = {str(r): s for r, s in sorted(self.sim.silent_since.items())}
        if self.phase == 'waiting':
            fields['agents_ready'] = sum(1 for v in self.agent_ready.values() if v)
        if self.phase == 'done':
            fields['final_step'] = self.final_frame()
        return fields

    def never_heard(self) -> List[str]:
        """Names of the robots some agent has never heard, by the agents' newest statuses (sorted)."""
        return sorted({name for names in self.agent_missing.values() for name in names})

    # --- events --------------------------------------------------------------------
    def on_command(self, robot: int, ns: int, u, now: float) -> str:
        """A robot's command stamped ``ns``; returns the :meth:`SwarmSim.offer` outcome."""
        outcome = self.sim.offer(robot, ns, u, now)
        if outcome in ('unknown_id', 'bad_size', 'non_finite', 'future'):
            self._throttled(
                f'cmd_{outcome}',
                f'dropped a command from robot {robot} ({outcome}, stamp '
                f'{ns * 1e-9:.3f} s, current step {self.sim.step}); '
                f'{getattr(self.sim.counters, outcome)} in all',
                'warn',
            )
        elif outcome == 'rejoined':
            self.held_warned.discard(robot)
            self.out.log(
                'info', f'robot {robot} answered again at step {self.sim.step}: waiting for it again'
            )
        if self.config.mode == 'lockstep' and self.phase == 'running':
            self._lockstep_advance()
        return outcome

    def on_malformed_command(self, robot: int, why: str) -> str:
        """Bytes on robot ``robot``'s command topic that are not a command: dropped and counted."""
        outcome = self.sim.malformed()
        self._throttled(
            'cmd_malformed',
            f"dropped a command message on robot {robot}'s topic that could not "
            f'be decoded ({why}); {self.sim.counters.malformed} in all',
            'warn',
        )
        return outcome

    def on_agent_status(self, robot: int, status: Optional[Dict]) -> None:
        """An agent's parsed status (None: unreadable, ignored)."""
        if status is None:
            return
        self.agent_ready[robot] = bool(status.get('ready'))
        names = status.get('missing_names')
        self.agent_missing[robot] = [str(n) for n in names] if isinstance(names, list) else []
        problem = dt_mismatch(status.get('dt'), self.sim.dt)
        if problem and self.exit_code is None:
            # Each step would be integrated over a different time than the policy assumes: refuse.
            self.out.log('error', f"parameter 'dt': agent {robot} {problem}: stopping")
            self._finish(EXIT_CONFIG)

    def on_recorder_status(self, status: Optional[Dict]) -> None:
        status = status or {}
        self.recorder_ready = bool(status.get('ready'))
        self.recorder_saved = status.get('phase') == 'saved'

    def on_recorder_progress(self, step: int) -> None:
        if step > self.recorder_progress:
            self.recorder_progress = int(step)
            if self.config.mode == 'lockstep' and self.phase == 'running':
                self._lockstep_advance()

    def on_watchdog(self, now: float) -> None:
        """The periodic check (every few wall milliseconds): startup, progress, lost robots, done."""
        c = self.config
        if self.phase == 'waiting':
            self._check_startup(now)
        elif (
            self.phase == 'running' and c.progress_period and now - self.last_progress[0] >= c.progress_period
        ):
            wall0, step0 = self.last_progress
            self.last_progress = (now, self.sim.step)
            rate = (self.sim.step - step0) / max(now - wall0, 1e-9)
            self.out.log(
                'info',
                f'step {self.sim.step}{"/" + str(c.steps) if c.steps else ""} '
                f'(t = {self.sim.step * self.sim.dt:.2f} s), {rate:.1f} steps/s'
                f'{", held: " + str(sorted(self.sim.lost)) if self.sim.lost else ""}',
            )
        if self.phase == 'running' and c.mode == 'lockstep':
            if self.sim.ground_truth is None:
                lost = [r for r in self.sim.overdue(now, c.lockstep_timeout) if r not in self.held_warned]
                if lost:
                    self.held_warned.update(lost)
                    self.sim.declare_lost(lost)
                    self.out.log(
                        'warn',
                        f'robot(s) {lost}: no command for step {self.sim.step} within '
                        f'{c.lockstep_timeout:g} s: stopping them (brake or zero velocity) and '
                        'no longer waiting for them',
                    )
            self._lockstep_advance()
            if self.phase == 'running' and now - self.last_publish >= c.republish_period:
                self.publish()  # answers or frames went missing: send the current state again
        elif self.phase == 'done':
            if not c.exit_when_done:
                if now - self.last_publish >= c.republish_period:
                    self.publish()
            elif not c.wait_for_recorder or self.recorder_saved:
                self._finish(EXIT_OK)
            elif now - self.done_wall > c.done_timeout:
                self.out.log(
                    'error',
                    f'the recorder did not report "saved" within {c.done_timeout:g} s after the last step',
                )
                self._finish(EXIT_FAILURE)
            elif now - self.last_publish >= c.republish_period:
                self.publish()

    def on_physics(self, now: float) -> None:
        """Realtime: the steps due by ``now`` (simulated time runs real_time_factor times the wall's)."""
        if self.phase != 'running':
            return
        c = self.config
        rtf, h = c.real_time_factor, self.sim.h  # h: one sub-step (dt without sub-steps)
        due = int((now - self.run_wall0) * rtf / h) - (self.sim.tick - self.run_tick0)
        catch_up = _MAX_CATCH_UP * self.sim.substeps
        if due > catch_up:  # too far behind (the machine is overloaded): drop time, count it
            self.overruns += due - catch_up
            self.run_wall0 += (due - catch_up) * h / rtf
            due = catch_up
        for _ in range(max(due, 0)):
            if c.steps and self.sim.step >= c.steps:
                break
            self.sim.advance()
            if self.sim.tick % c.publish_every == 0:
                self.publish()
        if c.steps and self.sim.step >= c.steps:
            self._done()

    # --- phases --------------------------------------------------------------------
    def _check_startup(self, now: float) -> None:
        c = self.config
        n = self.sim.n
        agents = [r for r in range(n) if not self.agent_ready.get(r)] if self.wait_for_agents else []
        recorder = c.wait_for_recorder and not self.recorder_ready
        if not agents and not recorder:
            took = now - self.wall0
            self.out.log(
                'info',
                f'{"all " + str(n) + " agents " if self.wait_for_agents else ""}'
                f'{"and " if self.wait_for_agents and c.wait_for_recorder else ""}'
                f'{"the recorder " if c.wait_for_recorder else ""}ready after {took:.1f} s: '
                f'running',
            )
            self._start(now)
            return
        if now - self.wall0 > c.startup_timeout:
            who = ([f'agents {_ids(agents)}'] if agents else []) + (['the recorder'] if recorder else [])
            silent = self.never_heard()
            self.out.log(
                'error',
                f'not ready after {c.startup_timeout:g} s: {" and ".join(who)} '
                '(an agent is ready once it has heard every robot)'
                + (f'; never heard by the agents: {", ".join(silent)}' if silent else ''),
            )
            self._finish(EXIT_FAILURE)
            return
        if now - self.last_publish >= c.republish_period:
            self.publish()
            who = ([f'{len(agents)} agent(s) {_ids(agents)}'] if agents else []) + (
                ['the recorder'] if recorder else []
            )
            self._throttled('waiting', f'waiting for {" and ".join(who)}')

    def _start(self, now: float) -> None:
        self.phase = 'running'
        self.run_wall0 = now
        self.run_step0 = self.sim.step
        self.run_tick0 = self.sim.tick
        self.last_progress = (now, self.sim.step)
        self.out.publish_status()
        self.sim.note_published(now)
        self.last_publish = now
        if self.config.mode == 'realtime':
            self.out.start_physics(self.sim.h / self.config.real_time_factor)
        else:
            self._lockstep_advance()

    def _recorder_allows(self) -> bool:
        c = self.config
        return not c.wait_for_recorder or self.sim.step - self.recorder_progress < c.recorder_max_lag

    def _lockstep_advance(self) -> None:
        steps = self.config.steps
        burst = 0
        while self.phase == 'running' and self.sim.can_advance() and self._recorder_allows():
            if steps and self.sim.step >= steps:
                self._done()
                return
            self.sim.advance()
            self.publish()
            burst += 1
            if self.sim.ground_truth is not None and burst >= _LOCKSTEP_BURST:
                return
        if self.phase == 'running' and steps and self.sim.step >= steps:
            self._done()

    def _done(self) -> None:
        if self.phase == 'done':
            return
        self.phase = 'done'
        self.done_wall = self.clock()
        self.out.stop_physics()
        ran = self.done_wall - self.run_wall0
        steps = self.sim.step - self.run_step0
        self.out.log('info', f'done: {steps} steps in {ran:.2f} s ({steps / max(ran, 1e-9):.1f} steps/s)')
        self.out.publish_status()

    # --- report --------------------------------------------------------------------
    def report(self) -> Dict:
        """Timings, counters and latency of the run so far."""
        out = dict(
            self.meta,
            phase=self.phase,
            exit_code=EXIT_OK if self.exit_code is None else self.exit_code,
            frames_published=self.frames,
            overruns=self.overruns,
            never_heard=self.never_heard(),
            **self.sim.report(),
        )
        if self.run_wall0 is not None:
            end = self.done_wall or self.clock()
            out['startup_s'] = self.run_wall0 - self.wall0
            out['run_s'] = end - self.run_wall0
            out['steps_run'] = self.sim.step - self.run_step0
            out['steps_per_s'] = out['steps_run'] / max(out['run_s'], 1e-9)
        return out
