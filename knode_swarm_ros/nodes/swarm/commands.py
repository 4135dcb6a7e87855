"""A :class:`~.plan.Plan` as the nodes' command lines and parameter files.

:func:`build_commands` is pure: it returns the command lines and the parameter files they name
(path -> parameters) without touching the disk; :func:`node_commands` also writes the files.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Dict, List, Tuple

from . import hosting

__all__ = ['build_commands', 'node_commands', 'child_environment', 'param_scalar', 'PACKAGE']

PACKAGE = 'knode_swarm_ros'


def param_scalar(value) -> str:
    """A value as the YAML scalar ``-p name:=value`` expects."""
    import yaml

    text = yaml.safe_dump(value, default_flow_style=True).strip()
    return text[:-3].strip() if text.endswith('...') else text


def _write_params_file(path: Path, params: Dict) -> None:
    import yaml

    path.write_text(yaml.safe_dump({'/**': {'ros__parameters': params}}, sort_keys=True))


def build_commands(plan) -> Tuple[Dict[str, List[str]], Dict[Path, Dict]]:
    """``(commands, files)``: every process's command line by name (``simulator``,
    ``recorder``, [``monitor``,] [``lifecycle_manager``,] ``agent_<i>`` or ``agents_<a>_<b>``) and the parameter
    files those command lines name (path in ``plan.run_dir`` -> parameters). Pure."""
    gt = plan.ground_truth
    sim = {
        'scenario': plan.scenario,
        'robots': plan.robots,
        'steps': plan.steps,
        'mode': plan.mode,
        'dt': float(plan.dt),
        'seed': int(plan.seed),
        'init': plan.init,
        'variant': plan.variant,
        'ground_truth': gt,
        'real_time_factor': float(plan.real_time_factor),
        'publish_rate': float(plan.rate),
        'command_timeout': max(0.5, 3.0 / plan.rate),
        'lockstep_timeout': float(plan.lockstep_timeout),
        'startup_timeout': float(plan.startup_timeout),
        'wait_for_agents': not gt,
        'wait_for_recorder': True,
        'd_cr': float(plan.d_cr),
        'report': str(plan.run_dir / 'simulator.json'),
        'stop_limit': float(plan.policy_meta.get('command_limit') or 0.0),
    }
    sim.update(plan.robot_model.get('simulator', {}))
    fleet = getattr(plan, 'fleet', '')
    if fleet:  # every node speaks the fleet's names, topics and types
        sim.update(fleet=fleet, pose_noise=float(plan.pose_noise))
        if plan.pose_rate is not None and plan.pose_rate * plan.dt > 1.0 + 1e-9:
            sim['state_rate'] = float(plan.pose_rate)  # a motion capture faster than the policy: sub-steps
        elif plan.pose_rate is not None:
            sim['publish_rate'] = float(plan.pose_rate)
    rec = {
        'scenario': plan.scenario,
        'robots': plan.robots,
        'output': str(plan.record),
        'dt': float(plan.dt),
        'bag': plan.bag,
        'use_sim_time': True,
    }
    if fleet:
        rec['fleet'] = fleet
    files = {plan.run_dir / 'simulator.yaml': sim, plan.run_dir / 'recorder.yaml': rec}
    python = [sys.executable, '-m']
    out = {
        'simulator': python
        + [f'{PACKAGE}.nodes.simulator', '--ros-args', '--params-file', str(plan.run_dir / 'simulator.yaml')],
        'recorder': python
        + [f'{PACKAGE}.nodes.recorder', '--ros-args', '--params-file', str(plan.run_dir / 'recorder.yaml')],
    }
    if plan.monitor_port is not None:  # reads what the agents read; nothing waits for it
        files[plan.run_dir / 'monitor.yaml'] = {
            'scenario': plan.scenario,
            'robots': plan.robots,
            'd_cr': float(plan.d_cr),
            'k': int(plan.policy_meta.get('k') or 0),
            'port': int(plan.monitor_port),
            'host': plan.monitor_host,
        }
        if fleet:
            files[plan.run_dir / 'monitor.yaml']['fleet'] = fleet
        out['monitor'] = python + [
            f'{PACKAGE}.nodes.monitor',
            '--ros-args',
            '--params-file',
            str(plan.run_dir / 'monitor.yaml'),
        ]
    if not gt:
        agent = {
            'scenario': plan.scenario,
            'robots': plan.robots,
            'policy': plan.policy,
            'mode': plan.mode,
            'control_rate': float(plan.rate),
            # the launcher says a rate mismatch once itself: its agents need not repeat it
            'rate_check': 'accept' if plan.rate_check == 'warn' else plan.rate_check,
            'state_timeout': float(plan.state_timeout),
            'parity_batch': plan.parity_batch,
            'use_sim_time': True,
            'policy_runtime': plan.policy_runtime,
            **plan.link,
        }
        agent['managed'] = bool(plan.managed)
        agent.update(plan.robot_model.get('agent', {}))
        if fleet:
            agent['fleet'] = fleet
        files[plan.run_dir / 'agent.yaml'] = agent
        params = str(plan.run_dir / 'agent.yaml')
        if plan.managed:  # configures every agent, then activates them together, then exits 0
            out['lifecycle_manager'] = (
                python
                + [
                    f'{PACKAGE}.nodes.lifecycle_manager',
                    '--ros-args',
                    '-p',
                    f'robots:={plan.robots}',
                    '-p',
                    f'timeout:={float(plan.startup_timeout)}',
                ]
                + (['-p', f'fleet:={param_scalar(fleet)}'] if fleet else [])
            )
        out.update(
            hosting.agent_commands(
                plan.robots,
                plan.agents_per_process,
                python,
                PACKAGE,
                params,
                plan.run_dir,
                getattr(plan, 'fleet_ids', None),
            )
        )
    return out, files


def node_commands(plan) -> Dict[str, List[str]]:
    """:func:`build_commands`, with its parameter files written; returns the commands."""
    commands, files = build_commands(plan)
    for path, params in files.items():
        _write_params_file(path, params)
    return commands


def child_environment(domain_id: int) -> Dict[str, str]:
    """The environment of every node: a copy of ours (the ROS wheels' LD_LIBRARY_PATH and
    bootstrap flag travel together), the domain, localhost-only discovery, one thread each."""
    env = dict(os.environ)
    env.update(
        {
            'ROS_DOMAIN_ID': str(domain_id),
            'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
            'PYTHONUNBUFFERED': '1',
            'RCUTILS_COLORIZED_OUTPUT': '0',
            'OMP_NUM_THREADS': '1',
            'MKL_NUM_THREADS': '1',
        }
    )
    env.pop('ROS_LOCALHOST_ONLY', None)  # deprecated; the discovery range above replaces it
    return env
