"""The agent's per-robot parameters, declared once for the lone ``agent`` and the hosting ``agents``.

Both nodes run the same per-robot logic, so they take the same parameters with the same names,
defaults, ranges and descriptions (docs/ros.md, "agent"); only the robot's id differs (``id``
for one robot, ``ids`` for several). The options a hosting process cannot give each of its
robots on its own (the link model, a lifecycle, the unicycle output) are declared by their own
modules (:mod:`.agent_link`, :mod:`.agent_lifecycle`, :mod:`.agent_unicycle`) and refused by
the ``agents`` node with a message naming the parameter.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import List, Optional

from knode_swarm_ros.logic.agent.agent_logic import AgentConfig
from knode_swarm_ros.logic.agent.control_period import RATE_CHECKS
from knode_swarm_ros.logic.agent.realtime_tick import TICK_ON
from knode_swarm_ros.logic.common import MODES, robot_id_list
from knode_swarm_ros.logic.contract.fleet import Fleet, default_fleet, load_fleet
from knode_swarm_ros.nodes.common.conversions import TWIST_FRAMES
from knode_swarm_ros.nodes.common.params import SCENARIO_HELP, declare, declare_int_array, scenario_parameter

__all__ = ['AgentParams', 'declare_agent_parameters']


@dataclass(frozen=True)
class AgentParams:
    """The values of the shared parameters (see :func:`declare_agent_parameters`)."""

    robots: int
    robot_ids: List[int]
    scenario: str
    policy: str
    runtime: str
    mode: str
    control_rate: float
    state_timeout: float
    future_tolerance: float
    command_limit: float
    k: int
    d_cr: float
    tau: int
    dt: float
    rate_check: str
    parity_batch: bool
    threads: int
    status_period: float
    twist_frame: str
    tick_on: str = 'state'
    fleet_file: str = ''
    fleet: Optional[Fleet] = None  # the fleet file's, read at declaration

    @property
    def ids(self) -> List[int]:
        """The swarm's robot ids: the fleet file's, else ``robot_ids`` / ``robots``."""
        if self.fleet is not None:
            return self.fleet.ids
        return robot_id_list(self.robots, self.robot_ids)

    def swarm_fleet(self) -> Fleet:
        """The fleet: the file's, else the default ``robot_<id>`` layout of :attr:`ids`."""
        return self.fleet if self.fleet is not None else default_fleet(self.ids)

    def config(self, robot_id: int) -> AgentConfig:
        """Robot ``robot_id``'s :class:`AgentConfig`."""
        return AgentConfig(
            robot_id,
            self.ids,
            self.mode,
            self.state_timeout,
            self.future_tolerance,
            self.command_limit,
            self.parity_batch,
            control_rate=self.control_rate,
            rate_check=self.rate_check,
            tick_on=self.tick_on,
        )

    def policy_args(self):
        """The arguments of :func:`.agent.load_agent_policy` after the path."""
        return (
            self.scenario,
            self.k,
            self.d_cr,
            self.tau,
            self.dt,
            self.runtime,
            self.threads,
            self.control_rate if self.mode == 'realtime' else 0.0,
        )


def declare_agent_parameters(node) -> AgentParams:
    """Declare the agent's parameters (all but the id) on ``node`` and return their values.

    Raises:
        ConfigError: a value of the wrong type, out of range or not one of the choices.
    """
    d = declare
    fleet_file = d(
        node,
        'fleet',
        '',
        "fleet file (docs/ros.md, 'Your own fleet'): the robots' names and ids, state and command "
        "topics and types; overrides 'robots' and 'robot_ids' (empty: robot_<id>, Odometry)",
    )
    return AgentParams(
        robots=d(
            node,
            'robots',
            10,
            'swarm size: robot ids are 0 .. robots-1 (unless robot_ids is set)',
            int_range=(1, 10_000),
        ),
        robot_ids=declare_int_array(node, 'robot_ids', "the swarm's robot ids (overrides 'robots')"),
        scenario=scenario_parameter(
            d(
                node,
                'scenario',
                '',
                SCENARIO_HELP + " (empty: the policy's; with policy empty too: flock2d)",
            )
        ),
        policy=d(
            node,
            'policy',
            '',
            'TorchScript policy file, or its ONNX twin (empty: the shipped policy of '
            'scenario; realtime: the one trained for control_rate, if shipped)',
        ),
        runtime=d(
            node,
            'policy_runtime',
            'auto',
            'auto: onnxruntime when POLICY.onnx exists and onnxruntime is '
            'installed, else TorchScript; torchscript; onnxruntime (no torch import)',
            choices=('auto', 'torchscript', 'onnxruntime'),
        ),
        mode=d(
            node,
            'mode',
            'realtime',
            'lockstep: answer each own state once every needed neighbour state is '
            'here; realtime: at control_rate, on the own state (realtime_tick)',
            choices=MODES,
        ),
        control_rate=d(
            node,
            'control_rate',
            20.0,
            'realtime control rate in Hz (on the ROS clock)',
            float_range=(0.01, 1000.0),
        ),
        state_timeout=d(
            node,
            'state_timeout',
            0.5,
            'seconds after which a silent neighbour leaves the neighbour '
            'set and a stale own state gives a zero command',
            float_range=(1e-3, 3600.0),
        ),
        future_tolerance=d(
            node,
            'future_tolerance',
            0.5,
            'states stamped more than this many seconds ahead of the clock are dropped',
            float_range=(0.0, 3600.0),
        ),
        command_limit=d(
            node,
            'command_limit',
            0.0,
            "per-axis command saturation (0: the policy's limit); the "
            "tighter of this and the policy's limit applies",
            float_range=(0.0, 1e9),
        ),
        k=d(node, 'k', 0, "rows of Y (0: the policy's; another value must equal it)", int_range=(0, 1000)),
        d_cr=d(
            node,
            'd_cr',
            0.0,
            "communication radius (0: the policy's; another value must equal it)",
            float_range=(0.0, 1e9),
        ),
        tau=d(
            node,
            'tau',
            -1,
            "delay in steps (-1: the policy's; another value must equal it)",
            int_range=(-1, 100_000),
        ),
        dt=d(
            node,
            'dt',
            0.0,
            "seconds per step (0: the policy's; another value must equal it)",
            float_range=(0.0, 3600.0),
        ),
        rate_check=d(
            node,
            'rate_check',
            'warn',
            "realtime: when 1 / control_rate differs from the policy's dt, "
            'warn once (warn), refuse to start (refuse) or run without a word (accept: the launcher has warned)',
            choices=RATE_CHECKS,
        ),
        parity_batch=d(
            node,
            'parity_batch',
            True,
            'lockstep: evaluate the policy in a batch shaped like the '
            "offline rollout's, so lockstep runs equal core.rollout bit for bit",
        ),
        threads=d(
            node,
            'torch_threads',
            1,
            'intra-op threads of the policy runtime (torch or onnxruntime)',
            int_range=(1, 256),
        ),
        status_period=d(
            node,
            'status_period',
            0.5,
            'seconds between status messages (wall clock)',
            float_range=(0.01, 3600.0),
        ),
        twist_frame=d(
            node,
            'twist_frame',
            'body',
            "frame of the twist in the robots' Odometry: body (REP 105 "
            'child frame, rotated into the world by the pose orientation) or world (a driver that '
            'deviates from REP 105)',
            choices=TWIST_FRAMES,
        ),
        tick_on=d(
            node,
            'realtime_tick',
            'state',
            "realtime: state: tick when the robot's own state of a new "
            'control period arrives (at most control_rate Hz; the timer then only stops a stale robot); '
            'timer: tick on a free-running timer at control_rate',
            choices=TICK_ON,
        ),
        fleet_file=fleet_file,
        fleet=load_fleet(fleet_file) if fleet_file else None,
    )
