"""Deployed at its rate, does a policy do what its offline rollout does?

    python -m training.studies.rate_study --data data/flock2d.npz --out out/rate_study \
        --case 20=knode_swarm_ros/policies/flock2d_20hz.pt --starts 10 --seconds 20 --realtime

For every ``--case RATE=POLICY``: the offline rollout (:func:`knode_swarm_ros.core.rollout`
at the policy's dt) and, with ``--realtime``, the ROS swarm (``swarm --mode realtime --rate
RATE``, one process per robot, simulator stepping at the policy's dt) from frame 0 of the
first ``--starts`` held-out test trajectories (``meta.split.test``), for ``--seconds`` of
simulated time each. Final avd / amd = mean over the last 10 frames of the policy's dt (the
realtime recording holds one frame per step of the policy's dt). Writes ``results.json`` and
``summary.md`` (mean, sd, min, max per case; realtime / offline per start) under ``--out``;
the realtime recordings and logs stay in ``--out/<rate>hz_<start>/``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from typing import Any, Dict, List, Optional

import numpy as np

from knode_swarm_ros.core import amd, avd, get_scenario, load_policy, load_trajectories, rollout
from knode_swarm_ros.core.cli import cli
from knode_swarm_ros.core.errors import KnodeError
from training.assessment.stats import describe
from training.learning.records import write_json

LAST = 10  # frames averaged for the final metrics (as training.evaluate)


def final_avd_amd(states: np.ndarray, scenario: str) -> Dict[str, float]:
    """Mean avd and amd over the last ``LAST`` frames of one run ``[T, n, d]``."""
    spec = get_scenario(scenario)
    tail = states[-LAST:]
    out = {'amd': float(amd(tail[:, :, spec.position]).mean())}
    if spec.velocity is not None:
        out['avd'] = float(avd(tail[:, :, spec.velocity]).mean())
    return out


#: A realtime recording "tracks" the offline rollout while no state differs by more than this (m, m/s):
#: float32 batch shapes round differently (about 1e-7), a command applied one step late moves a
#: robot by about 1e-2.
TRACK_TOL = 1e-4


def tracked_steps(states: np.ndarray, pred: np.ndarray) -> int:
    """Frames from the start in which the recording ``states [T, n, d]`` equals the offline
    rollout ``pred [T', n, d]`` within :data:`TRACK_TOL` (all compared frames when it never departs)."""
    T = min(len(states), len(pred))
    off = np.nonzero(np.abs(states[:T] - pred[:T]).max(axis=(1, 2)) > TRACK_TOL)[0]
    return int(off[0]) if len(off) else T


def realtime_run(
    policy: str, rate: float, init: str, steps: int, out_dir: str, rtf: float, timeout: float
) -> Dict[str, Any]:
    """One ``swarm --mode realtime`` run; returns its final metrics, the simulator report and the exit code."""
    os.makedirs(out_dir, exist_ok=True)
    record = os.path.join(out_dir, 'run.npz')
    cmd = [
        sys.executable,
        '-m',
        'knode_swarm_ros.nodes.swarm',
        '--mode',
        'realtime',
        '--rate',
        f'{rate:g}',
        '--policy',
        policy,
        '--init',
        init,
        '--steps',
        str(steps),
        '--record',
        record,
        '--no-figure',
        '--quiet',
        '--real-time-factor',
        f'{rtf:g}',
        '--log-dir',
        os.path.join(out_dir, 'logs'),
        '--timeout',
        f'{timeout:g}',
    ]
    t0 = time.monotonic()
    with open(os.path.join(out_dir, 'swarm.log'), 'w') as log:
        rc = subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT).returncode
    result: Dict[str, Any] = {
        'exit_code': rc,
        'wall_s': round(time.monotonic() - t0, 1),
        'command': ' '.join(cmd),
    }
    if os.path.isfile(record):
        data = load_trajectories(record)
        states = data.states[0]
        result.update(
            final_avd_amd(states, data.scenario),
            frames=int(states.shape[0]),
            dt=float(data.dt),
            incomplete_frames=data.meta.get('incomplete_frames'),
        )
    report = os.path.join(out_dir, 'logs', 'simulator.json')
    if os.path.isfile(report):
        with open(report) as fh:
            sim = json.load(fh)
        result['simulator'] = {k: sim.get(k) for k in ('overruns', 'latency_ms', 'counters', 'steps_per_s')}
    return result


def study(
    data_path: str,
    cases: Dict[float, str],
    out: str,
    starts: int,
    seconds: float,
    realtime: bool,
    rtf: float = 1.0,
    timeout: float = 600.0,
    log=print,
) -> Dict[str, Any]:
    data = load_trajectories(data_path)
    test = [int(i) for i in data.split('test')[:starts]]
    os.makedirs(out, exist_ok=True)
    results: Dict[str, Any] = {
        'data': os.path.abspath(data_path),
        'test_trajectories': test,
        'seconds': seconds,
        'realtime': realtime,
        'real_time_factor': rtf,
        'cases': {},
    }
    for rate, policy_path in cases.items():
        policy = load_policy(policy_path)
        steps = int(round(seconds / policy.dt))
        z0 = data.states[test, 0]
        with np.errstate(all='ignore'):
            pred = rollout(policy, z0, steps, policy.scenario, policy.d_cr, policy.k, policy.tau, policy.dt)
        offline = [final_avd_amd(p, policy.scenario) for p in pred]
        case: Dict[str, Any] = {
            'policy': os.path.abspath(policy_path),
            'policy_dt': policy.dt,
            'rate': rate,
            'steps': steps,
            'offline': offline,
            'offline_avd': describe([o['avd'] for o in offline]),
        }
        log(
            f'{rate:g} Hz, policy dt {policy.dt:g} s: offline final avd {case["offline_avd"]["mean"]:.4f} '
            f'(sd {case["offline_avd"]["std"]:.4f})'
        )
        if realtime:
            runs = []
            for j, traj in enumerate(test):
                r = realtime_run(
                    os.path.abspath(policy_path),
                    rate,
                    f'{os.path.abspath(data_path)}:{traj}',
                    steps,
                    os.path.join(out, f'{rate:g}hz_{traj}'),
                    rtf,
                    timeout,
                )
                r['trajectory'] = traj
                if 'avd' in r:
                    r['ratio_to_offline'] = r['avd'] / offline[j]['avd']
                    recorded = load_trajectories(os.path.join(out, f'{rate:g}hz_{traj}', 'run.npz')).states[0]
                    r['tracked_steps'] = tracked_steps(recorded, pred[j])
                runs.append(r)
                log(
                    f'  realtime start {traj}: exit {r["exit_code"]}, final avd {r.get("avd", float("nan")):.4f} '
                    f'(offline {offline[j]["avd"]:.4f}), tracks the offline rollout for '
                    f'{r.get("tracked_steps", "-")} of {steps + 1} frames, {r["wall_s"]} s'
                )
                write_json(os.path.join(out, 'results.json'), results | {'partial': True})
            case['realtime'] = runs
            done = [r for r in runs if 'avd' in r and r['exit_code'] == 0]
            if done:
                case['realtime_avd'] = describe([r['avd'] for r in done])
                case['realtime_over_offline'] = describe([r['ratio_to_offline'] for r in done])
                case['mean_ratio'] = case['realtime_avd']['mean'] / case['offline_avd']['mean']
                case['tracked_steps'] = describe([r['tracked_steps'] for r in done])
        results['cases'][f'{rate:g}'] = case
        write_json(os.path.join(out, 'results.json'), results)
    write_summary(os.path.join(out, 'summary.md'), results)
    return results


def write_summary(path: str, results: Dict[str, Any]) -> None:
    lines = [
        f'# Rate study: {len(results["test_trajectories"])} held-out starts, {results["seconds"]:g} s each',
        '',
        '| rate | policy dt | offline final avd (mean ± sd) | realtime final avd (mean ± sd, runs) | '
        'realtime / offline (mean of means) | per-start ratio min..max | frames tracking the offline rollout '
        f'(within {TRACK_TOL:g}; median, min..max) |',
        '| --- | --- | --- | --- | --- | --- | --- |',
    ]
    for case in results['cases'].values():
        off = case['offline_avd']
        rt = case.get('realtime_avd')
        rts = f'{rt["mean"]:.4f} ± {rt["std"]:.4f} ({rt["count"]})' if rt else 'not run'
        ratio = f'{case["mean_ratio"]:.2f}' if rt else ''
        spread = (
            f'{case["realtime_over_offline"]["min"]:.2f}..{case["realtime_over_offline"]["max"]:.2f}'
            if rt
            else ''
        )
        tr = case.get('tracked_steps')
        tracked = f'{tr["median"]:g}, {tr["min"]:g}..{tr["max"]:g} of {case["steps"] + 1}' if tr else ''
        lines.append(
            f'| {case["rate"]:g} Hz | {case["policy_dt"]:g} s | {off["mean"]:.4f} ± {off["std"]:.4f} | '
            f'{rts} | {ratio} | {spread} | {tracked} |'
        )
    with open(path, 'w') as fh:
        fh.write('\n'.join(lines) + '\n')


@cli('python -m training.studies.rate_study')
def main(argv: Optional[List[str]] = None) -> int:
    parser = argparse.ArgumentParser(
        prog='python -m training.studies.rate_study', description=__doc__.split('\n\n')[0]
    )
    parser.add_argument(
        '--data', required=True, help='trajectory file with a test split (the held-out starts)'
    )
    parser.add_argument(
        '--case',
        action='append',
        required=True,
        metavar='RATE=POLICY',
        help='control rate in Hz and the policy file deployed at it (repeatable)',
    )
    parser.add_argument('--out', required=True, help='output folder')
    parser.add_argument('--starts', type=int, default=10, help='held-out starts (default 10)')
    parser.add_argument('--seconds', type=float, default=20.0, help='simulated seconds per run (default 20)')
    parser.add_argument('--realtime', action='store_true', help='also run the ROS swarm in realtime mode')
    parser.add_argument(
        '--real-time-factor', type=float, default=1.0, help='realtime: simulated s per wall s'
    )
    parser.add_argument('--timeout', type=float, default=600.0, help='wall seconds per realtime run')
    args = parser.parse_args(argv)
    cases = {}
    for item in args.case:
        rate, sep, path = item.partition('=')
        try:
            cases[float(rate)] = path
            assert sep and float(rate) > 0 and os.path.isfile(path)
        except (ValueError, AssertionError):
            raise KnodeError(
                f'--case {item!r}: expected RATE=POLICY with RATE > 0 Hz and an existing policy file'
            ) from None
    if args.starts < 1 or args.seconds <= 0:
        raise KnodeError('--starts must be >= 1 and --seconds > 0')
    study(
        args.data,
        cases,
        args.out,
        args.starts,
        args.seconds,
        args.realtime,
        args.real_time_factor,
        args.timeout,
    )
    print(open(os.path.join(args.out, 'summary.md')).read())
    return 0


if __name__ == '__main__':
    sys.exit(main())
