"""How the ``swarm`` launcher spreads the robots' agents over processes (no rclpy here).

``--agents-per-process K``: K = 1 starts one ``agent`` process per robot (today's layout, the
one real robots use); K > 1 starts ``agents`` processes hosting K consecutive robots each
(the last one the rest), named ``agents_<first>_<last>``. The default (0) picks K so that large
swarms fit this machine: one process per robot up to :data:`LONE_UP_TO` robots, beyond that
the robots split evenly over ``min(cores, MAX_PROCESSES)`` processes (at least 2). An agent
process holds about 330 MB (torch), so 100 robots need 2 to 8 processes, not 100.

``--netns NS0,NS1,...`` (tests and benchmarks of several hosts on one machine, see
:mod:`.netns`): the simulator and the recorder run in NS0, the agent processes round-robin in
all of them, with DDS discovery over the subnet and the UDP transport only (no shared memory
across "hosts"), instead of localhost-only discovery.
"""

from __future__ import annotations

import argparse
import math
import os
import re
from typing import Dict, List, Optional, Sequence

from knode_swarm_ros.logic.common import ConfigError

__all__ = [
    'add_arguments',
    'check_netns',
    'place',
    'resolve_agents_per_process',
    'split',
    'agent_commands',
    'robots_of',
    'is_agent_process',
    'LONE_UP_TO',
    'MAX_PROCESSES',
]

LONE_UP_TO = 10
MAX_PROCESSES = 8
_HOSTED_RE = re.compile(r'^agents_(\d+)_(\d+)$')


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--agents-per-process``."""
    parser.add_argument(
        '--agents-per-process',
        type=int,
        default=0,
        metavar='K',
        help=f'robots whose agents share one process (1: one agent process per robot; 0, the '
        f'default: 1 up to {LONE_UP_TO} robots, else the robots split over min(cores, '
        f'{MAX_PROCESSES}) processes)',
    )
    parser.add_argument(
        '--netns',
        metavar='NS0,NS1,..',
        help='run the nodes in these network namespaces (as '
        'root; the simulator and the recorder in the first, the agent processes round-robin), with '
        'subnet discovery over UDP: a multi-host swarm on one machine (docs/ros.md)',
    )


def resolve_agents_per_process(requested: int, robots: int, cores: Optional[int] = None) -> int:
    """K for ``robots`` robots: ``requested`` when > 0 (at most ``robots``), else the default.

    Raises:
        ConfigError: ``requested`` < 0.
    """
    if requested < 0:
        raise ConfigError(f'--agents-per-process must be >= 0 (0: chosen for this machine), got {requested}')
    if requested > 0:
        return min(requested, robots)
    if robots <= LONE_UP_TO:
        return 1
    processes = max(2, min(cores or os.cpu_count() or 2, MAX_PROCESSES))
    return math.ceil(robots / processes)


def split(ids: Sequence[int], per_process: int) -> List[List[int]]:
    """Consecutive groups of ``per_process`` ids (the last one the rest)."""
    ids = list(ids)
    return [ids[i : i + per_process] for i in range(0, len(ids), per_process)]


def agent_commands(
    robots: int, per_process: int, python: List[str], package: str, params: str, run_dir, robot_ids=None
) -> Dict[str, List[str]]:
    """The agents' command lines by process name: ``agent_<i>`` (K = 1) or ``agents_<a>_<b>``;
    ``robot_ids`` (a fleet's, ascending) instead of ``0 .. robots - 1``."""
    from .commands import param_scalar  # the YAML scalar the ``-p`` flag expects

    out: Dict[str, List[str]] = {}
    for group in split(list(robot_ids) if robot_ids else range(robots), per_process):
        if per_process == 1:
            name, node, ids = f'agent_{group[0]}', 'agent', f'id:={group[0]}'
        else:
            name, node = f'agents_{group[0]}_{group[-1]}', 'agents'
            contiguous = list(group) == list(range(group[0], group[-1] + 1))
            ids = f'ids:={group[0]}..{group[-1]}' if contiguous else f'ids:={param_scalar(list(group))}'
        out[name] = python + [
            f'{package}.nodes.{node}',
            '--ros-args',
            '--params-file',
            params,
            '-p',
            ids,
            '-p',
            f'report:={param_scalar(str(run_dir / f"{name}.json"))}',
        ]
    return out


def is_agent_process(name: str) -> bool:
    """``agent_<i>`` or ``agents_<a>_<b>``."""
    return name.startswith('agent_') or bool(_HOSTED_RE.match(name))


def robots_of(name: str) -> List[int]:
    """The robot ids an agent process hosts, from its name."""
    m = _HOSTED_RE.match(name)
    if m:
        return list(range(int(m.group(1)), int(m.group(2)) + 1))
    return [int(name.split('_')[1])]


def check_netns(netns: Optional[str]) -> None:
    """Raise :class:`ConfigError` unless every namespace of ``--netns`` exists (``ip netns add``)."""
    if netns is None:
        return
    spaces = [n.strip() for n in netns.split(',') if n.strip()]
    if not spaces:
        raise ConfigError('--netns: no namespace given (NS0,NS1,...)')
    missing = [n for n in spaces if not os.path.exists(f'/run/netns/{n}')]
    if missing:
        raise ConfigError(f'--netns: no network namespace {", ".join(missing)} (see `ip netns list`)')


def place(commands: Dict[str, List[str]], env: Dict[str, str], netns: Optional[str]):
    """``(commands, env)`` with the processes spread over the namespaces of ``--netns`` (as is
    when None): discovery over the subnet, UDP only (the namespaces share /dev/shm, and a
    shared-memory transport would bypass the network under test)."""
    if not netns:
        return commands, env
    from .netns import wrap

    spaces = [n.strip() for n in netns.split(',') if n.strip()]
    out, agents = {}, 0
    for name, cmd in commands.items():
        if is_agent_process(name):
            out[name] = wrap(spaces[agents % len(spaces)], cmd)
            agents += 1
        else:
            out[name] = wrap(spaces[0], cmd)
    env = dict(env, ROS_AUTOMATIC_DISCOVERY_RANGE='SUBNET', FASTDDS_BUILTIN_TRANSPORTS='UDPv4')
    return out, env
