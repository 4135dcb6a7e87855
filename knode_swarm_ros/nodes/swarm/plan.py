"""The launcher's plan: every argument and input file checked once, before a process starts.

:func:`plan_run` turns the parsed arguments into a frozen :class:`Plan` (the arguments are not
changed); :mod:`.commands` turns a plan into the nodes' command lines.
"""

from __future__ import annotations

import argparse
import math
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, List, Optional

from knode_swarm_ros.logic.common import ConfigError
from knode_swarm_ros.nodes.agent.link import link_parameters

from . import hosting, robot_model

__all__ = [
    'Plan',
    'plan_run',
    'available_memory_mb',
    'DOMAIN_RANGE',
    'MAX_ROBOTS',
    'AGENT_MB',
    'NODE_MB',
    'MONITOR_PORT',
    'scenario_name',
]

DOMAIN_RANGE = (30, 101)  # valid ids with the default port mapping, away from the default 0
#: The most robots any node accepts (the 'robots' parameter range of agent, simulator, recorder).
MAX_ROBOTS = 10_000
#: --rate when not given, in lockstep and ground-truth runs (Hz); realtime agents run at the policy's rate.
DEFAULT_RATE = 20.0
#: Private memory of one process, with the CPU build of torch (docs/DESIGN.md):
#: an agent about 330 MB; the simulator and the recorder (numpy, no torch) far less.
AGENT_MB, NODE_MB = 330, 150
#: The monitor's web page port when ``--monitor`` names none.
MONITOR_PORT = 8765


@dataclass(frozen=True)
class Plan:
    """Everything decided before a process starts (built once by :func:`plan_run`)."""

    scenario: str
    robots: int
    steps: int
    mode: str
    dt: float
    d_cr: float
    policy: Optional[str]  # resolved path; None with ground_truth
    record: Path
    figure: Optional[Path]
    run_dir: Path
    temporary_dir: bool
    domain_id: int
    policy_meta: Dict = field(default_factory=dict)
    domain_claim: object = None  # held for the run (domains.DomainClaim) when the domain was drawn
    agents_per_process: int = 1
    # the flags the nodes and the watcher need, as checked
    ground_truth: bool = False
    variant: str = ''
    seed: int = 0
    init: str = ''  # 'ABSOLUTE.npz:TRAJ' or ''
    rate: float = DEFAULT_RATE
    rate_check: str = 'warn'
    real_time_factor: float = 1.0
    state_timeout: float = 0.5
    lockstep_timeout: float = 5.0
    startup_timeout: float = 180.0
    timeout: float = 0.0
    parity_batch: bool = True
    policy_runtime: str = 'auto'
    link: Dict[str, Any] = field(default_factory=dict)  # the agents' link_* parameters ({}: off)
    robot_model: Dict[str, Dict] = field(default_factory=dict)  # --robot-model: simulator / agent parameters
    managed: bool = False
    bag: str = ''  # absolute path or ''
    netns: Optional[str] = None
    quiet: bool = False
    on_agent_exit: str = 'continue'
    keep_logs: bool = False
    monitor_port: Optional[int] = None  # None: no monitor; 0: any free port
    monitor_host: str = '127.0.0.1'
    fleet: str = ''  # absolute path of the fleet file, or ''
    fleet_ids: List[int] = field(default_factory=list)  # its robots' ids (ascending), or []
    pose_noise: float = 0.0
    pose_rate: Optional[float] = None  # realtime: the state publishing rate (None: rate)


def scenario_name(scenario: str) -> str:
    """The name of a scenario reference, for messages (a custom one's reference is its JSON)."""
    from knode_swarm_ros.core.scenarios import get_scenario

    return get_scenario(scenario).name


def _check_output_folder(option: str, given: str, folder: Path) -> None:
    """``folder`` exists, or can be created (``run`` creates it once the whole plan is checked):
    its nearest existing ancestor is a writable directory."""
    if folder.is_dir():
        return
    ancestor = folder
    while not ancestor.exists() and ancestor != ancestor.parent:
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise ConfigError(f'{option} {given}: cannot create folder {folder}: {ancestor} is not a folder')
    if not os.access(ancestor, os.W_OK | os.X_OK):
        raise ConfigError(f'{option} {given}: cannot create folder {folder}: {ancestor} is not writable')


def available_memory_mb() -> Optional[float]:
    """MemAvailable of /proc/meminfo in MB (None where unknown)."""
    try:
        with open('/proc/meminfo') as fh:
            for line in fh:
                if line.startswith('MemAvailable:'):
                    return int(line.split()[1]) / 1024.0
    except (OSError, ValueError, IndexError):
        pass
    return None


def _check_memory(robots: int, per_process: int = 1) -> None:
    """Refuse a swarm whose agent processes cannot fit in this machine's available memory."""
    processes = math.ceil(robots / per_process)
    need = processes * AGENT_MB + 2 * NODE_MB
    have = available_memory_mb()
    if have is not None and need > have:
        raise ConfigError(
            f'--robots {robots}: {processes} agent processes need about {need / 1024:.1f} GB '
            f'({AGENT_MB} MB each, measured with the CPU build of torch) but this machine has '
            f'{have / 1024:.1f} GB available; run fewer robots'
        )


def _check_numbers(args: argparse.Namespace) -> None:
    if args.steps < 0:
        raise ConfigError(f'--steps must be >= 0, got {args.steps}')
    if args.robots is not None and not 1 <= args.robots <= MAX_ROBOTS:
        raise ConfigError(f"--robots must be in 1..{MAX_ROBOTS} (the nodes' limit), got {args.robots}")
    if args.rate is not None and not args.rate > 0:
        raise ConfigError(f'--rate must be > 0, got {args.rate}')
    for name in ('real_time_factor', 'state_timeout', 'lockstep_timeout', 'startup_timeout'):
        value = getattr(args, name)
        if not value > 0:
            raise ConfigError(f'--{name.replace("_", "-")} must be > 0, got {value}')
    if args.timeout < 0:
        raise ConfigError(f'--timeout must be >= 0, got {args.timeout}')
    monitor = getattr(args, 'monitor', None)
    if monitor is not None and not 0 <= monitor <= 65535:
        raise ConfigError(f'--monitor PORT must be in 0..65535, got {monitor}')
    if getattr(args, 'monitor_host', None) and monitor is None:
        raise ConfigError('--monitor-host needs --monitor')


def _scenario_argument(args: argparse.Namespace) -> str:
    """``--scenario`` as a canonical reference ('' when not given)."""
    from knode_swarm_ros.core.scenarios import ScenarioError, parse_scenario_argument

    if not args.scenario:
        return ''
    try:
        return parse_scenario_argument(args.scenario)
    except ScenarioError as exc:
        raise ConfigError(f'--scenario {args.scenario}: {exc}') from None


def _policy(args: argparse.Namespace):
    """``(scenario, dt, d_cr, policy path or None, metadata)`` of the run; ``scenario`` is the
    canonical reference (a shipped name, else the JSON object: the policy's own)."""
    from knode_swarm_ros.core.scenarios import get_scenario

    scenario = _scenario_argument(args)
    if args.ground_truth:
        if args.policy:
            raise ConfigError(
                '--policy and --ground-truth exclude each other (no agents run with --ground-truth)'
            )
        scenario = scenario or 'flock2d'
        spec = get_scenario(scenario)
        if not spec.shipped:  # the ground truths are the paper's two laws
            raise ConfigError(
                f'--ground-truth: scenario {spec.name} has no ground-truth law (only flock2d and '
                'boids3d have); run a policy with --policy'
            )
        from knode_swarm_ros.core.policy import DEFAULTS

        return scenario, spec.dt, float(DEFAULTS[spec.name]['d_cr']), None, {}
    from knode_swarm_ros.core.policy_meta import PolicyError, shipped_policy_path
    from knode_swarm_ros.core.policy_runtime import (
        load_runtime,  # the agents' backend: checks an ONNX twin up front
    )

    try:
        if args.policy:
            policy_path = args.policy
        elif scenario and not get_scenario(scenario).shipped:
            raise ConfigError(
                f'--scenario {args.scenario}: no policy is shipped for a scenario of your own; '
                'pass --policy RUN/policy.pt (its knode.json carries the scenario)'
            )
        elif args.mode == 'realtime':  # the shipped policy trained for --rate, if there is one
            from knode_swarm_ros.logic.agent.control_period import shipped_policy_for_rate

            policy_path = str(shipped_policy_for_rate(scenario or 'flock2d', args.rate or DEFAULT_RATE)[0])
        else:
            policy_path = str(shipped_policy_path(scenario or 'flock2d'))
        policy = load_runtime(policy_path, args.policy_runtime)
    except PolicyError as exc:
        hint = '' if args.policy else ' (pass --policy FILE.pt)'
        raise ConfigError(f'--policy (--policy-runtime {args.policy_runtime}): {exc}{hint}') from None
    if scenario and get_scenario(policy.scenario) != get_scenario(scenario):
        raise ConfigError(
            f'--scenario {args.scenario} but the policy {policy_path} is for '
            f'{get_scenario(policy.scenario).name} ({policy.scenario})'
        )
    return policy.scenario, policy.dt, policy.d_cr, str(Path(policy_path).resolve()), dict(policy.meta)


def _robots_and_init(args: argparse.Namespace, scenario: str):
    """``(robots, init)``: the swarm size and the resolved ``--init`` reference ('' without)."""
    robots, init = args.robots, ''
    if args.init:
        from knode_swarm_ros.core.trajectory import TrajectoryError, load_trajectories, parse_trajectory_ref

        path, traj = parse_trajectory_ref(args.init)
        try:
            data = load_trajectories(path, scenario)
        except TrajectoryError as exc:
            raise ConfigError(f'--init: {exc}') from None
        if not 0 <= traj < data.states.shape[0]:
            raise ConfigError(
                f'--init {args.init}: trajectory {traj} does not exist ({data.states.shape[0]} in the file)'
            )
        n = data.states.shape[2]
        if robots is not None and robots != n:
            raise ConfigError(f'--robots {robots} but --init {args.init} has {n} robots')
        robots = n
        init = f'{Path(path).resolve()}:{traj}'
    robots = robots or 10
    if robots > MAX_ROBOTS:
        raise ConfigError(f'--init {init} has {robots} robots; the nodes take at most {MAX_ROBOTS}')
    return robots, init


def _rate(args: argparse.Namespace, dt: float) -> float:
    """``--rate``, or without it: realtime the policy's own rate (no held commands, no warning),
    lockstep :data:`DEFAULT_RATE` (there it only paces publishing)."""
    if args.rate is not None:
        return float(args.rate)
    return 1.0 / dt if args.mode == 'realtime' and not args.ground_truth else DEFAULT_RATE


def _fleet(args: argparse.Namespace, scenario: str, dt: float):
    """``(path, ids, pose rate)`` of ``--fleet`` (``('', [], None)`` without), checked against the
    run's scenario and the pose flags. The pose rate is ``--pose-rate``, else the fleet's
    ``state.rate`` in realtime (the simulated motion capture runs at the rate the fleet's
    estimator window was chosen for), else None (the control rate)."""
    from knode_swarm_ros.core.scenarios import get_scenario
    from knode_swarm_ros.logic.contract.fleet import load_fleet

    noise, rate = getattr(args, 'pose_noise', 0.0) or 0.0, getattr(args, 'pose_rate', None)
    if not getattr(args, 'fleet', None):
        if noise or rate is not None:
            raise ConfigError('--pose-noise and --pose-rate need --fleet (a fleet whose state type is pose)')
        return '', [], None
    path = os.path.abspath(args.fleet)
    fleet = load_fleet(path)
    spec = get_scenario(scenario)
    fleet.check_scenario(spec.command, spec.velocity is not None)
    if (noise or rate is not None) and fleet.state.type != 'pose':
        raise ConfigError(
            f'--pose-noise / --pose-rate: the fleet {args.fleet} gives {fleet.state.type}, not poses'
        )
    if not (noise >= 0 and math.isfinite(noise)):
        raise ConfigError(f'--pose-noise must be >= 0 metres, got {noise}')
    stated = fleet.state.rate if fleet.state.type == 'pose' else None
    if rate is not None and stated is not None and not math.isclose(rate, stated, rel_tol=1e-9):
        raise ConfigError(
            f'--pose-rate {rate:g}: the fleet {args.fleet} states rate {stated:g} Hz (its estimator window '
            'is chosen for it); drop --pose-rate or change the fleet'
        )
    if rate is None and stated is not None and args.mode == 'realtime':
        if not _publishable(stated, dt):
            raise ConfigError(
                f'the fleet {args.fleet} states rate {stated:g} Hz: the simulator publishes at most '
                f'1 / dt = {1.0 / dt:g} Hz or a whole multiple of it; give --pose-rate'
            )
        rate = stated
    if rate is not None and not (rate > 0 and args.mode == 'realtime' and _publishable(rate, dt)):
        raise ConfigError(
            f'--pose-rate {rate:g}: realtime only, and at most 1 / dt = {1.0 / dt:g} Hz or a whole multiple '
            'of it (the simulator then takes that many sub-steps of each policy step)'
        )
    if args.robots is not None and args.robots != len(fleet.robots):
        raise ConfigError(f'--robots {args.robots} but the fleet {args.fleet} has {len(fleet.robots)} robots')
    return path, fleet.ids, rate


def _publishable(rate: float, dt: float) -> bool:
    """Whether the simulator can publish states at ``rate`` Hz with steps of ``dt``: every k-th
    step (rate <= 1 / dt) or k sub-steps per step (a whole multiple of 1 / dt)."""
    k = rate * dt
    return k <= 1.0 + 1e-9 or abs(k - round(k)) <= 1e-6


def plan_run(args: argparse.Namespace) -> Plan:
    """Check the arguments and the input files; raise :class:`ConfigError` naming the problem.

    ``args`` is read, never changed. Creates ``--log-dir`` (or a temporary folder) and claims a
    free ROS domain when none is given: the only effects, both after every check has passed
    but the domain's and the figure's.
    """
    _check_numbers(args)
    link = link_parameters(args, args.mode)  # checks the --link-* flags
    record = Path(args.record).expanduser().resolve()
    if record.suffix != '.npz':
        raise ConfigError(f'--record {args.record}: the trajectory file must end with .npz')
    _check_output_folder('--record', args.record, record.parent)
    scenario, dt, d_cr, policy_path, meta = _policy(args)
    fleet_path, fleet_ids, pose_rate = _fleet(args, scenario, dt)
    if fleet_ids and args.robots is None and not args.init:
        args = argparse.Namespace(**{**vars(args), 'robots': len(fleet_ids)})
    robots, init = _robots_and_init(args, scenario)
    if fleet_ids and robots != len(fleet_ids):
        raise ConfigError(f'--init has {robots} robots but the fleet {args.fleet} has {len(fleet_ids)}')
    per_process = hosting.resolve_agents_per_process(args.agents_per_process, robots)
    if args.managed and not args.ground_truth:
        if args.agents_per_process > 1:
            raise ConfigError(
                '--managed runs one lifecycle agent process per robot; it cannot be combined with '
                f'--agents-per-process {args.agents_per_process}'
            )
        per_process = 1
    # each agent hears through its own link: no hosting (nodes/agents/node.py)
    if link and not args.ground_truth:
        if args.agents_per_process > 1:
            raise ConfigError(
                '--link-* (the link model) runs one agent process per robot; it cannot be combined '
                f'with --agents-per-process {args.agents_per_process}'
            )
        per_process = 1
    robot_params = robot_model.robot_model_parameters(args, scenario_name(scenario), per_process)
    hosting.check_netns(args.netns)
    if not args.ground_truth:
        _check_memory(robots, per_process)
    if args.variant:
        from knode_swarm_ros.logic.simulator.swarm_sim import ground_truth_variants

        known = ground_truth_variants(scenario)
        if args.variant not in known:
            raise ConfigError(
                f'--variant {args.variant!r}: '
                + (
                    f'known {scenario} variants are {", ".join(known)}'
                    if known
                    else f'scenario {scenario_name(scenario)} has no ground-truth law, so no variants'
                )
            )
    claim = None
    if args.domain_id is None:  # a free one: another swarm on this machine may hold one
        from .domains import claim_domain

        try:
            claim = claim_domain(range(DOMAIN_RANGE[0], DOMAIN_RANGE[1] + 1))
        except RuntimeError as exc:
            raise ConfigError(f'{exc}; pass --domain-id') from None
    domain = args.domain_id if claim is None else claim.domain_id
    if not 0 <= domain <= 232:
        raise ConfigError(f'--domain-id must be in 0..232, got {domain}')
    figure = (
        None if args.no_figure else Path(args.figure).resolve() if args.figure else record.with_suffix('.png')
    )
    if figure is not None:
        _check_output_folder('--figure', str(args.figure or figure), figure.parent)
    if args.log_dir:
        run_dir, temporary = Path(args.log_dir).resolve(), False
        run_dir.mkdir(parents=True, exist_ok=True)
    else:
        run_dir, temporary = Path(tempfile.mkdtemp(prefix='knode_swarm_')), True
    return Plan(
        scenario=scenario,
        robots=robots,
        steps=args.steps,
        mode=args.mode,
        dt=dt,
        d_cr=d_cr,
        policy=policy_path,
        record=record,
        figure=figure,
        run_dir=run_dir,
        temporary_dir=temporary,
        domain_id=domain,
        policy_meta=meta,
        domain_claim=claim,
        agents_per_process=per_process,
        ground_truth=bool(args.ground_truth),
        variant=args.variant,
        seed=int(args.seed),
        init=init,
        rate=_rate(args, dt),
        rate_check=args.rate_check,
        real_time_factor=float(args.real_time_factor),
        state_timeout=float(args.state_timeout),
        lockstep_timeout=float(args.lockstep_timeout),
        startup_timeout=float(args.startup_timeout),
        timeout=float(args.timeout),
        parity_batch=not args.no_parity_batch,
        policy_runtime=args.policy_runtime,
        link=link,
        robot_model=robot_params,
        managed=bool(args.managed),
        bag=os.path.abspath(args.bag) if args.bag else '',
        netns=args.netns,
        quiet=bool(args.quiet),
        on_agent_exit=args.on_agent_exit,
        keep_logs=bool(args.keep_logs),
        monitor_port=getattr(args, 'monitor', None),
        monitor_host=getattr(args, 'monitor_host', None) or '127.0.0.1',
        fleet=fleet_path,
        fleet_ids=fleet_ids,
        pose_noise=float(getattr(args, 'pose_noise', 0.0) or 0.0),
        pose_rate=pose_rate,
    )
