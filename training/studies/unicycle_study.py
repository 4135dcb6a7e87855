"""The flock2d policy on differential-drive robots, offline: unicycles vs double integrators.

    python -m training.studies.unicycle_study --out out/unicycle          # flock2d_20hz.pt, 10 starts x 600 steps
    python -m training.studies.unicycle_study --out out/unicycle --ros    # and once through ROS (swarm, lockstep)

Exactly what ``swarm --robot-model unicycle --mode lockstep`` runs, without ROS: the simulator's
stepping (:class:`knode_swarm_ros.logic.simulator.swarm_sim.SwarmSim` with its ``unicycle`` robot
model, the bases of :class:`knode_swarm_ros.core.unicycle.UnicycleRobots`, which enforce the
limits), the REP 105 Odometry fields the simulator publishes, what the agent's policy sees of
them (``unicycle_state``: the point ahead, or the axle), the policy's saturated command
(:func:`core.rollout.policy_commands`)
and the agent's mapping to (v, omega) (:class:`~knode_swarm_ros.core.unicycle.UnicycleMapper`).
Starts: held-out Tanner draws (seed 2026); heading = direction of the initial velocity.

Cases, each against the double-integrator rollout (:func:`core.rollout`) from the same starts:
loose limits (10 m/s, 20 rad/s, no acceleration limit); binding limits (top speed ``--bind-speed``
x the start's double-integrator flocking speed, 1.8 rad/s like a TurtleBot, 1 m/s^2, 5 rad/s^2);
and the loose case with the policy fed the axle states, to show why the point is the default.
Reports final avd / amd (mean, 95 % t interval), mean speed, close passes (< 0.3 after 1 s) and
the share of commands a limit changed. Writes ``DIR/results.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from typing import Any, Dict, List, Optional

import numpy as np

from knode_swarm_ros.core import PolicyError, amd, avd, load_policy, rollout
from knode_swarm_ros.core.cli import cli
from knode_swarm_ros.core.errors import KnodeError
from knode_swarm_ros.core.geometry import min_pair_distance
from knode_swarm_ros.core.groundtruth import tanner
from knode_swarm_ros.core.rollout import policy_commands
from knode_swarm_ros.core.scenarios import get_scenario
from knode_swarm_ros.core.unicycle import UnicycleLimits, UnicycleMapper
from knode_swarm_ros.logic.contract.rep105 import fields_to_point_state, fields_to_state, yaw_of
from knode_swarm_ros.logic.simulator.swarm_sim import SwarmSim
from training.assessment.stats import interval
from training.learning.records import write_json

SHIPPED = os.path.join(
    os.path.dirname(__file__), '..', '..', 'knode_swarm_ros', 'policies', 'flock2d_20hz.pt'
)


def unicycle_rollout(
    policy,
    z0: np.ndarray,
    steps: int,
    limits,
    d_cr: float,
    k: int,
    dt: float,
    state: str = 'point',
    command_limit: Optional[float] = None,
):
    """Recorded (axle) states ``[S, steps + 1, n, 4]`` of unicycle swarms from ``z0 [S, n, 4]``
    (tau 0), and the share of commands a limit changed.

    ``limits``: one :class:`UnicycleLimits` (base and agent alike) or one per start.
    """
    S, n, _ = z0.shape
    spec = get_scenario('flock2d')
    limits = list(limits) if isinstance(limits, (list, tuple)) else [limits] * S
    sims = [
        SwarmSim('flock2d', z0[s], dt, 'lockstep', robot_model='unicycle', robot_params=vars(limits[s]))
        for s in range(S)
    ]
    mappers = [[UnicycleMapper(limits[s], 'acceleration', dt) for _ in range(n)] for s in range(S)]
    for s in range(
        S
    ):  # a base already moving: the agent starts its limits from its motion (as AgentUnicycle)
        for i in range(n):
            bases = sims[s].robots.bases
            mappers[s][i].last = (float(bases.speed[i]), float(bases.turn[i]))
    out = np.empty((S, steps + 1, n, 4))
    seen = np.empty((S, n, 4))
    for t in range(steps + 1):
        fields = [[sim.robots.odom_fields(i) for i in range(n)] for sim in sims]
        for s in range(S):
            out[s, t] = sims[s].states
            for i, (pos, quat, lin, ang) in enumerate(fields[s]):
                seen[s, i] = (
                    fields_to_point_state(pos, quat, lin, ang, limits[s].lookahead)
                    if state == 'point'
                    else fields_to_state(pos, quat, lin, spec)
                )
        if t == steps:
            break
        u = policy_commands(policy, seen, seen, spec, d_cr, k, command_limit)
        for s, sim in enumerate(sims):
            for i, (pos, quat, lin, ang) in enumerate(fields[s]):
                point_v = fields_to_point_state(pos, quat, lin, ang, limits[s].lookahead)[2:]
                v, w = mappers[s][i](u[s, i], yaw_of(quat), point_v, ang[2])
                sim.offer(i, sim.stamp_ns, [v, w])
            sim.advance()
    bound = sum(m.bound for row in mappers for m in row) / max(
        1, sum(m.periods for row in mappers for m in row)
    )
    return out, bound


def _row(
    name: str, states: np.ndarray, dt: float, di_final: np.ndarray, extra: Dict[str, Any]
) -> Dict[str, Any]:
    final = states[:, -1]
    close = min_pair_distance(states[:, int(round(1 / dt)) :, :, :2]).min(axis=1)
    return {
        'case': name,
        'avd': interval(avd(final[..., 2:])),
        'amd': interval(amd(final[..., :2])),
        'speed': interval(np.linalg.norm(final[..., 2:], axis=-1).mean(axis=-1)),
        'speed_ratio_to_double_integrator': interval(
            np.linalg.norm(final[..., 2:], axis=-1).mean(axis=-1)
            / np.linalg.norm(di_final[..., 2:], axis=-1).mean(axis=-1)
        ),
        'close_passes': int((close < 0.3).sum()),
        'min_distance': float(close.min()),
        **extra,
    }


def run(
    policy_path: str,
    out: str,
    starts: int = 10,
    robots: int = 10,
    steps: int = 600,
    seed: int = 2026,
    bind_speed: float = 0.5,
    log=print,
) -> Dict[str, Any]:
    """Every case of the module doc; writes and returns ``results.json``'s content."""
    policy = load_policy(policy_path)
    if policy.scenario != 'flock2d' or policy.tau != 0:
        raise PolicyError(
            f'{policy_path}: a flock2d policy with tau 0 is needed, got {policy.scenario} tau {policy.tau}'
        )
    dt, limit = policy.dt, policy.command_limit
    z0 = tanner.initial_states(np.random.default_rng(seed), starts, robots, 'paper')
    di = rollout(policy, z0, steps, 'flock2d', policy.d_cr, policy.k, 0, dt)
    flock_speed = np.linalg.norm(di[:, -1, :, 2:], axis=-1).mean(axis=-1)  # [S]
    loose = UnicycleLimits(0.2, 10.0, 20.0, 0.0, 0.0)
    binding = [UnicycleLimits(0.2, float(bind_speed * v), 1.8, 1.0, 5.0) for v in flock_speed]
    rows: List[Dict[str, Any]] = [_row('double_integrator', di, dt, di[:, -1], {})]
    for name, lim, state in (
        ('unicycle_loose', loose, 'point'),
        ('unicycle_binding', binding, 'point'),
        ('unicycle_loose_axle_state', loose, 'axle'),
    ):
        states, bound = unicycle_rollout(policy, z0, steps, lim, policy.d_cr, policy.k, dt, state, limit)
        lims = lim if isinstance(lim, list) else [lim]
        rows.append(
            _row(
                name,
                states,
                dt,
                di[:, -1],
                {'state': state, 'limited_share': bound, 'limits': [x.__dict__ for x in lims]},
            )
        )
    for r in rows:
        log(
            f'{r["case"]:26s} avd {r["avd"]["mean"]:.3f} [{r["avd"]["lo"]:.3f}, {r["avd"]["hi"]:.3f}]  amd '
            f'{r["amd"]["mean"]:.3f} [{r["amd"]["lo"]:.3f}, {r["amd"]["hi"]:.3f}]  speed {r["speed"]["mean"]:.2f} '
            f'(x{r["speed_ratio_to_double_integrator"]["mean"]:.2f} of DI)  close passes {r["close_passes"]}/'
            f'{starts}  limited {100 * r.get("limited_share", 0):.0f} %'
        )
    results = {
        'policy': os.path.relpath(policy_path),
        'dt': dt,
        'starts': starts,
        'robots': robots,
        'steps': steps,
        'seed': seed,
        'bind_speed': bind_speed,
        'flock_speed_double_integrator': interval(flock_speed),
        'rows': rows,
    }
    write_json(os.path.join(out, 'results.json'), results, indent=1, sort_keys=False)
    return results


def ros_confirm(
    policy_path: str, out: str, steps: int, seed: int, bind_speed: float, log=print
) -> Dict[str, Any]:
    """The binding case once through ROS: ``swarm --robot-model unicycle --mode lockstep`` with 10
    robots from the simulator's seeded start (TorchScript, as offline), against the offline loop
    and the double integrators from the same start. Writes ``DIR/ros.npz`` (logs in
    ``DIR/ros_logs``) and returns the figures (``results.json['ros']``)."""
    import subprocess

    from knode_swarm_ros.core import load_trajectories
    from knode_swarm_ros.logic.simulator.swarm_sim import initial_state

    policy = load_policy(policy_path)
    z0 = initial_state('flock2d', 10, seed)[0][None]
    di = rollout(policy, z0, steps, 'flock2d', policy.d_cr, policy.k, 0, policy.dt)
    lim = UnicycleLimits(
        0.2, round(float(bind_speed * np.linalg.norm(di[0, -1, :, 2:], axis=-1).mean()), 3), 1.8, 1.0, 5.0
    )
    record = os.path.join(out, 'ros.npz')
    cmd = [
        sys.executable,
        '-m',
        'knode_swarm_ros.nodes.swarm',
        '--policy',
        policy_path,
        '--robots',
        '10',
        '--steps',
        str(steps),
        '--seed',
        str(seed),
        '--mode',
        'lockstep',
        '--record',
        record,
        '--no-figure',
        '--lockstep-timeout',
        '120',
        '--log-dir',
        os.path.join(out, 'ros_logs'),  # a loaded machine loses no robot
        '--quiet',
        '--policy-runtime',
        'torchscript',
        '--robot-model',
        'unicycle',
        '--max-linear-speed',
        repr(lim.max_linear_speed),
        '--max-angular-speed',
        '1.8',
        '--max-linear-accel',
        '1.0',
        '--max-angular-accel',
        '5.0',
    ]
    log('$ ' + ' '.join(cmd))
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise KnodeError(
            f'the ROS run failed (exit {proc.returncode}):\n{proc.stdout[-2000:]}{proc.stderr[-2000:]}'
        )
    ros = load_trajectories(record).states[:1]
    with open(os.path.join(out, 'ros_logs', 'simulator.json')) as fh:
        report = json.load(fh)
    offline, _ = unicycle_rollout(
        policy, z0, steps, lim, policy.d_cr, policy.k, policy.dt, 'point', policy.command_limit
    )
    result = {
        'command': ' '.join(cmd[1:]),
        'limits': lim.__dict__,
        'lost': report.get('lost'),
        'simulator_counters': report.get('counters'),
        'max_difference_to_offline': float(np.abs(ros - offline).max()),
    }
    for name, states in (('ros_unicycle', ros), ('double_integrator', di)):
        final = states[0, -1]
        result[name] = {
            'avd': float(avd(final[:, 2:])),
            'amd': float(amd(final[:, :2])),
            'speed': float(np.linalg.norm(final[:, 2:], axis=-1).mean()),
        }
    log(
        f'ROS lockstep, 10 unicycles, binding limits: avd {result["ros_unicycle"]["avd"]:.3f} amd '
        f'{result["ros_unicycle"]["amd"]:.3f} speed {result["ros_unicycle"]["speed"]:.2f}; double integrator avd '
        f'{result["double_integrator"]["avd"]:.3f} amd {result["double_integrator"]["amd"]:.3f} speed '
        f'{result["double_integrator"]["speed"]:.2f}; max |ROS - offline| {result["max_difference_to_offline"]:.1e}'
    )
    return result


@cli('python -m training.studies.unicycle_study')
def main(argv: Optional[List[str]] = None) -> int:
    p = argparse.ArgumentParser(
        prog='python -m training.studies.unicycle_study', description=__doc__.split('\n\n')[0]
    )
    p.add_argument(
        '--policy',
        default=os.path.normpath(SHIPPED),
        help="flock2d policy (default: the shipped flock2d_20hz.pt, 20 Hz like a ground robot's cmd_vel)",
    )
    p.add_argument('--out', required=True)
    p.add_argument('--starts', type=int, default=10)
    p.add_argument('--steps', type=int, default=600)
    p.add_argument('--seed', type=int, default=2026)
    p.add_argument(
        '--bind-speed',
        type=float,
        default=0.5,
        help="binding top speed as a share of the start's double-integrator flocking speed; default 0.5",
    )
    p.add_argument(
        '--ros',
        action='store_true',
        help='also run the binding case once through ROS (swarm '
        '--robot-model unicycle, lockstep, 10 robots, seed --seed): results.json["ros"]',
    )
    a = p.parse_args(argv)
    if a.starts < 2 or a.steps < 1 or not 0 < a.bind_speed:
        raise KnodeError('--starts must be >= 2, --steps >= 1 and --bind-speed > 0')
    import torch

    torch.set_num_threads(1)
    results = run(a.policy, a.out, a.starts, 10, a.steps, a.seed, a.bind_speed)
    if a.ros:
        results['ros'] = ros_confirm(os.path.abspath(a.policy), a.out, a.steps, a.seed, a.bind_speed)
        write_json(os.path.join(a.out, 'results.json'), results, indent=1, sort_keys=False)
    return 0


if __name__ == '__main__':
    sys.exit(main())
