"""The run: start the plan's processes in two stages, watch them, stop them all, clean up.

Signals only set a flag (see ``on_signal``); :meth:`.processes.Children.pump` raises it.
"""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path
from typing import Dict, List, Optional, Sequence

from knode_swarm_ros.logic.common import EXIT_AGENT_LOST, EXIT_CONFIG, EXIT_FAILURE, EXIT_INTERRUPTED, EXIT_OK
from knode_swarm_ros.logic.reporting import write_json_report

from . import hosting
from .commands import child_environment, node_commands
from .console import say as _say
from .plan import Plan, scenario_name
from .processes import Children, Interrupted, start_child
from .report import name_never_heard, summarise
from .shm import shm_cleanup, shm_snapshot
from .sweeper import Sweeper

__all__ = ['run', 'MONITOR']

MONITOR = 'monitor'  # the process that nothing waits for


def run(plan: Plan, pending: Sequence[int] = ()) -> int:
    """Start, supervise and stop the processes of ``plan``; returns the exit status. ``pending``:
    signals received before (during the checks), which stop the run at once."""
    plan.record.parent.mkdir(parents=True, exist_ok=True)  # checked by plan_run (a fresh clone has no out/)
    env = child_environment(plan.domain_id)
    commands, env = hosting.place(node_commands(plan), env, plan.netns)
    shm_before = shm_snapshot()
    # Started before any node: it sweeps in our place if we are killed (SIGKILL) before our end.
    sweeper = Sweeper.start(shm_before)
    if sweeper is not None:
        (plan.run_dir / 'sweeper.pid').write_text(f'{sweeper.pid}\n')
    record_before = _file_identity(plan.record)
    children = Children(on_add=sweeper.add if sweeper is not None else None)
    stop_reason = {'signal': None}

    def on_signal(signum, _frame):
        # Only a flag: a signal handler that raises can have its exception swallowed (an at-fork
        # hook of the logging module runs pending handlers while a child is started and ignores
        # what they raise, measured) or raised in the forked child. Children.pump raises it.
        stop_reason['signal'] = signum
        children.interrupted = True

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    for signum in list(pending)[:1]:  # (read after ours are installed: none is lost in between)
        on_signal(signum, None)
    noted_before = len(pending)  # the launcher's own handler notes signals after ours are gone
    code = EXIT_OK
    lost_agents: List[str] = []
    t0 = time.monotonic()
    try:
        try:
            _say(
                f'{plan.robots} robots, {scenario_name(plan.scenario)}, {plan.mode}, {plan.steps or "unlimited"} steps, '
                f'ROS_DOMAIN_ID={plan.domain_id}, logs in {plan.run_dir}'
            )
            if plan.ground_truth:
                _say(f'ground truth ({plan.variant or "paper"}): the simulator drives the robots, no agents')
            else:
                _say(
                    f'policy {plan.policy} (k={plan.policy_meta.get("k")}, d_cr={plan.policy_meta.get("d_cr")}, '
                    f'tau={plan.policy_meta.get("tau")}, dt={plan.policy_meta.get("dt")})'
                )
                if plan.mode == 'realtime':
                    from knode_swarm_ros.logic.agent.control_period import check_control_period

                    _say(
                        check_control_period(plan.rate, plan.dt).describe('--rate')
                        or f'control period = policy dt ({plan.dt:g} s)'
                    )
            children.pump(0.0)  # a signal already pending: start nothing
            failed = _start_in_stages(plan, commands, env, children, t0)
            pids = {name: c.pid for name, c in children.items.items()}
            write_json_report(str(plan.run_dir / 'pids.json'), pids, indent=1)
            if failed is not None:
                code = failed
            else:
                agents = [n for n in pids if hosting.is_agent_process(n)]
                _say(
                    f'started simulator (pid {pids["simulator"]}), recorder (pid {pids["recorder"]})'
                    + (
                        f', {len(agents)} agent processes for {plan.robots} robots (pids {pids[agents[0]]}..'
                        f'{pids[agents[-1]]})'
                        if agents
                        else ''
                    )
                    + ': waiting until every agent has heard every robot'
                )
                if MONITOR in pids:
                    where = f'{plan.monitor_host}:{plan.monitor_port}' if plan.monitor_port else 'a free port'
                    _say(f'monitor (pid {pids[MONITOR]}): web page on {where} (its log has the address)')
                code = _supervise(plan, children, lost_agents, t0)
        except Interrupted:
            name = signal.Signals(stop_reason['signal']).name
            _say(f'{name}: stopping every process (the recorder saves what it has)')
            code = EXIT_INTERRUPTED

        # Stop whatever still runs; the recorder first waits for nothing: SIGTERM makes it save. A
        # signal from here on is only noted: the stop goes on, and the exit status says it came.
        def on_late_signal(signum, _frame):
            stop_reason['signal'] = stop_reason['signal'] or signum

        for signum in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
            signal.signal(signum, on_late_signal)
        children.interrupted = False
        for note in children.stop():
            _say(note)
    finally:
        for s, handler in old.items():
            signal.signal(s, handler)  # the launcher's: noted in ``pending``
        for c in children.alive():  # never leave a process behind
            c.proc.kill()
            c.proc.wait()
        children.close()
        removed = shm_cleanup(shm_before)
        if removed:
            _say(f'removed {len(removed)} FastDDS shared-memory file(s) left by killed processes')
        if sweeper is not None:
            sweeper.end()
    _say(f'every process has stopped ({time.monotonic() - t0:.1f} s in all)')
    name_never_heard(plan)
    if code in (EXIT_OK, EXIT_AGENT_LOST, EXIT_INTERRUPTED):
        if _file_identity(plan.record) != record_before:
            summarise(plan)
        elif record_before is not None:
            _say(
                f'no recording was written in this run: {plan.record} is an earlier file, left as it was '
                '(not summarised)'
            )
        else:
            _say('no recording was written in this run')
    if lost_agents and code == EXIT_OK:
        code = EXIT_AGENT_LOST
    if lost_agents:
        _say(f'agent process(es) died during the run: {"; ".join(lost_agents)}')
    if code != EXIT_INTERRUPTED and (stop_reason['signal'] is not None or len(pending) > noted_before):
        # a stop signal after the supervisor's last look (or ours were gone): it ends as every
        # stopped run does
        signum = stop_reason['signal'] or pending[-1]
        _say(f'{signal.Signals(signum).name}: stopping every process (it came as the run was ending)')
        code = EXIT_INTERRUPTED
    return code


def _file_identity(path: Path):
    """(inode, size, mtime) of ``path``, None when absent: the recorder replaces the file
    atomically, so any write of this run changes it."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return (st.st_ino, st.st_size, st.st_mtime_ns)


def _saved_whole(rec) -> bool:
    """Whether the recorder's log says it wrote the whole run (a signal makes it save what it has,
    marked '(interrupted)', and exit 0 too)."""
    line = rec.seen.get('wrote ', '')
    return bool(line) and '(interrupted)' not in line


def _start_in_stages(
    plan: Plan, commands: Dict[str, List[str]], env: Dict[str, str], children: Children, t0: float
) -> Optional[int]:
    """Start the simulator and the recorder, then, once both are past their checks (their logs
    say so), the agents: a refused parameter or file stops the run before hundreds of agents
    load torch. (An agent that refuses its configuration stops the run in _supervise; agents are
    not staged further: under load, one agent's start-up is tens of seconds that the simulator's
    start-up timeout would lose.) Returns an exit status when the first stage failed."""
    names = list(commands)
    agents = [n for n in names if hosting.is_agent_process(n)]
    for stage in ([n for n in names if n not in agents], agents):
        for name in stage:
            echo = 'none' if plan.quiet else 'problems' if hosting.is_agent_process(name) else 'all'
            children.add(start_child(name, commands[name], env, plan.run_dir, echo))
        if stage is agents:
            break  # supervised with the rest of the run
        waiting = [children.items[n] for n in stage if n != MONITOR]  # never waited for
        while any(not c.marked for c in waiting):
            children.pump(0.1)
            for c in waiting:
                if c.proc.poll() is not None and not c.marked:
                    c.reported = True
                    last = [line for line in c.tail if line.strip()][-3:]
                    detail = (' -- last output: ' + ' | '.join(last)) if last else ''
                    _say(
                        f'the {c.name} (pid {c.pid}) {c.how_it_ended()} while starting{detail}: nothing else '
                        'is started'
                    )
                    return EXIT_CONFIG if c.proc.returncode == EXIT_CONFIG else EXIT_FAILURE
            if time.monotonic() - t0 > plan.startup_timeout:
                late = [c.name for c in waiting if not c.marked]
                _say(
                    f'{", ".join(late)} not started after --startup-timeout {plan.startup_timeout:g} s: stopping'
                )
                return EXIT_FAILURE
    return None


def _supervise(plan: Plan, children: Children, lost_agents: List[str], t0: float) -> int:
    sim = children.items['simulator']
    rec = children.items['recorder']
    while True:
        children.pump(0.1)
        if any(not c.reported and c.proc.poll() is not None for c in children.items.values()):
            children.drain()  # its last lines (done, wrote) decide how it ended
        for c in children.items.values():
            if c.reported or c.proc.poll() is None:
                continue
            c.reported = True
            rc = c.proc.returncode
            if c is rec and rc == 0 and _saved_whole(rec):
                continue  # saved after the simulator said done
            if c.name == MONITOR:  # an observer: the run goes on as it would without it
                _say(f'the monitor (pid {c.pid}) {c.how_it_ended()}: the run goes on without it')
                continue
            if c.name == 'lifecycle_manager' and rc == 0:
                _say('every agent configured, then activated together')
                continue
            if c is sim and rc == 0 and 'done: ' in sim.seen:
                _say('the simulator has finished')
                end = time.monotonic() + 15.0
                while rec.proc.poll() is None and time.monotonic() < end:
                    children.pump(0.1)
                if rec.proc.poll() not in (0,):
                    _say(f'the recorder {rec.how_it_ended()} after the simulator finished')
                    return EXIT_FAILURE
                return EXIT_OK
            why = c.how_it_ended()
            last = [line for line in c.tail if line.strip()][-3:]
            detail = (' -- last output: ' + ' | '.join(last)) if last else ''
            if hosting.is_agent_process(c.name):
                held = hosting.robots_of(c.name)
                _say(f'{c.name} (pid {c.pid}) {why}{detail}')
                lost_agents.append(
                    f'{c.name} (pid {c.pid}) {why}'
                    + (f', hosting robots {held}' if c.name.startswith('agents_') else '')
                )
                if rc == EXIT_CONFIG:
                    _say('an agent refused its configuration: stopping the run')
                    return EXIT_CONFIG
                if ' s: running' not in sim.seen:  # else the simulator would wait --startup-timeout for it
                    _say('an agent process died before the run started: stopping the run')
                    return EXIT_FAILURE
                if plan.on_agent_exit == 'stop':
                    _say('--on-agent-exit stop: stopping the run')
                    return EXIT_FAILURE
                _say(
                    f'{c.name} is gone: the other agents go on; the simulator holds robot'
                    f'{"s" if len(held) > 1 else ""} {", ".join(map(str, held))} at '
                    f'{"their" if len(held) > 1 else "its"} last command'
                )
            else:
                early = ' before the run was over (stopped by a signal?)' if rc == 0 else ''
                _say(f'the {c.name} (pid {c.pid}) {why}{early}{detail}: stopping the run')
                return EXIT_CONFIG if rc == EXIT_CONFIG else EXIT_FAILURE
        if plan.timeout and time.monotonic() - t0 > plan.timeout:
            _say(f'--timeout {plan.timeout:g} s reached: stopping the run')
            return EXIT_FAILURE
