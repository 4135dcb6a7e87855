"""The ``swarm`` command line: its arguments and its entry point."""

from __future__ import annotations

import argparse
import shutil
import sys
from typing import List

from knode_swarm_ros.logic.common import EXIT_CONFIG, EXIT_OK, MODES, ConfigError
from knode_swarm_ros.nodes.agent.link import add_link_arguments
from knode_swarm_ros.nodes.common.startup import note_stop_signals, started_as_launcher

from . import hosting, robot_model
from .console import say as _say
from .plan import DOMAIN_RANGE, MONITOR_PORT, plan_run
from .supervise import run

__all__ = ['build_parser', 'main']


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog='swarm',
        description='Run a swarm of learnt controllers on this machine: the simulator, one agent '
        'process per robot and the recorder, on a fresh ROS domain with localhost-only discovery.',
    )
    p.add_argument(
        '--scenario',
        metavar='NAME|FILE.yaml',
        help="flock2d, boids3d or a scenario file (docs/scenarios.md); default: the policy's, else flock2d",
    )
    p.add_argument('--robots', type=int, help='number of robots (default: 10, or as many as --init has)')
    p.add_argument(
        '--steps', type=int, default=2000, help='steps of dt to simulate (0: until Ctrl-C); default 2000'
    )
    p.add_argument('--mode', choices=MODES, default='lockstep', help='default lockstep')
    p.add_argument(
        '--policy',
        help='TorchScript policy file (default: the shipped policy of the scenario; realtime: '
        'the one trained for --rate, e.g. policies/flock2d_20hz.pt, if shipped)',
    )
    p.add_argument(
        '--policy-runtime',
        choices=('auto', 'torchscript', 'onnxruntime'),
        default='auto',
        help="agents' policy_runtime (auto: the ONNX twin on onnxruntime when it exists); default auto",
    )
    p.add_argument(
        '--init',
        metavar='FILE.npz[:TRAJ]',
        help='initial state: frame 0 of a trajectory file of the scenario (e.g. training.import_tracks)',
    )
    p.add_argument(
        '--seed',
        type=int,
        default=0,
        help='seed of the initial state (without --init; a scenario of your own starts at random in a '
        'box, docs/scenarios.md); default 0',
    )
    p.add_argument('--record', metavar='OUT.npz', required=True, help='trajectory file to write')
    p.add_argument(
        '--bag',
        metavar='OUT.mcap',
        help='also write the run as a bag of /robot_<id>/odom (an .mcap '
        'file, else a rosbag2 directory), for training.import_bag',
    )
    p.add_argument(
        '--ground-truth',
        action='store_true',
        help='the simulator drives the robots with the Tanner / boids controller (flock2d, boids3d only); '
        'no agents',
    )
    p.add_argument('--variant', default='', help='ground-truth variant / preset (default: paper)')
    p.add_argument(
        '--rate',
        type=float,
        default=None,
        help="realtime: control and publishing rate in Hz (simulated time); default: the policy's own "
        '(20 for the shipped flock2d realtime policy, 60 for boids3d)',
    )
    p.add_argument(
        '--rate-check',
        choices=('warn', 'refuse'),
        default='warn',
        help="realtime: when 1 / --rate differs from the policy's dt the agents warn (default) or refuse",
    )
    p.add_argument('--real-time-factor', type=float, default=1.0, help='realtime: default 1')
    p.add_argument('--state-timeout', type=float, default=0.5, help="agents' state_timeout in s; default 0.5")
    p.add_argument(
        '--lockstep-timeout',
        type=float,
        default=5.0,
        help='lockstep: wall seconds before a silent agent is held at its last command; default 5',
    )
    p.add_argument(
        '--startup-timeout',
        type=float,
        default=180.0,
        help='wall seconds for every process to be ready; default 180',
    )
    p.add_argument(
        '--timeout', type=float, default=0.0, help='stop after this many wall seconds (0: no limit)'
    )
    p.add_argument(
        '--no-parity-batch',
        action='store_true',
        help='agents evaluate a batch of 1 (faster; no bit-for-bit parity with core.rollout)',
    )
    p.add_argument(
        '--on-agent-exit',
        choices=('continue', 'stop'),
        default='continue',
        help='when an agent process dies: go on without it (default) or stop the run',
    )
    p.add_argument(
        '--domain-id',
        type=int,
        help=f'ROS_DOMAIN_ID (default: a free one, claimed, in {DOMAIN_RANGE[0]}..{DOMAIN_RANGE[1]})',
    )
    p.add_argument('--figure', metavar='PNG', help='figure path (default: the recording with .png)')
    p.add_argument('--no-figure', action='store_true', help='do not draw a figure')
    p.add_argument(
        '--log-dir',
        help="where the processes' logs, parameter files and reports go (default: a "
        'temporary folder, removed after a successful run unless --keep-logs)',
    )
    p.add_argument('--keep-logs', action='store_true', help='keep the temporary log folder')
    p.add_argument('--quiet', action='store_true', help="do not echo the nodes' output")
    p.add_argument(
        '--monitor',
        type=int,
        nargs='?',
        const=MONITOR_PORT,
        metavar='PORT',
        help=f'also start the live monitor: RViz markers and a web page on http://localhost:PORT/ '
        f'(default port {MONITOR_PORT}; 0: any free one); never waited for, its death changes nothing',
    )
    p.add_argument(
        '--monitor-host',
        metavar='ADDRESS',
        help="the address the monitor's page binds (default 127.0.0.1, this machine only; e.g. 0.0.0.0)",
    )
    p.add_argument(
        '--fleet',
        metavar='FLEET.yaml',
        help="run the fleet file's robots (names, ids, state and command topics and types; docs/ros.md, "
        "'Your own fleet'): the simulator speaks exactly the fleet's topics, so a run rehearses the deployment",
    )
    p.add_argument(
        '--pose-noise',
        type=float,
        default=0.0,
        metavar='SIGMA',
        help='--fleet with poses: position noise per axis of the simulated motion capture, metres (seeded by '
        '--seed); default 0',
    )
    p.add_argument(
        '--pose-rate',
        type=float,
        metavar='HZ',
        help='--fleet with poses, realtime: the motion capture rate in simulated Hz: at most 1 / dt of the '
        'policy, or a whole multiple of it (e.g. 100 under a 20 Hz policy: the simulator integrates each '
        'step in that many sub-steps and publishes every one); default: the state.rate of the fleet, else --rate',
    )
    add_link_arguments(p)
    robot_model.add_arguments(p)
    p.add_argument(
        '--managed',
        action='store_true',
        help='agents as managed (lifecycle) nodes: configure every agent, then activate them together',
    )
    hosting.add_arguments(p)
    return p


def main(argv=None):
    """Entry point of the ``swarm`` executable."""
    parser = build_parser()
    args = parser.parse_args(argv)
    # A signal during the checks (or the imports, when started as the launcher) is noted and acted
    # on once run() has its own handlers: the policy's `import torch` swallows a KeyboardInterrupt
    # raised inside it (measured: 1 in 10).
    pending: List[int] = note_stop_signals(carry=started_as_launcher())
    try:
        plan = plan_run(args)
    except ConfigError as exc:
        print(f'swarm: error: {exc}', file=sys.stderr)
        sys.exit(EXIT_CONFIG)
    code = run(plan, pending)
    if plan.temporary_dir:
        if code == EXIT_OK and not plan.keep_logs:
            shutil.rmtree(plan.run_dir, ignore_errors=True)
        else:
            _say(f'logs kept in {plan.run_dir}')
    sys.exit(code)
