"""Roll a policy file out from a trajectory's initial state (canonical ZOH semantics).

    python -m training.rollout --policy P.pt --init FILE.npz[:TRAJ] --steps T --out OUT.npz [--runtime onnxruntime]

Any valid policy file works (whoever wrote it): the policy's ``k``, ``d_cr``, ``tau`` and
``dt`` come from its ``knode.json``; the initial state is frame 0 of trajectory ``TRAJ``
(default 0) of a trajectory file of the same scenario. The output is a trajectory file
with one trajectory of ``T + 1`` frames, produced by :func:`knode_swarm_ros.core.rollout`.
``--runtime`` picks the policy backend as the agent's ``policy_runtime`` does (default
``torchscript``, the reference; ``onnxruntime`` rolls the ONNX twin out, as robots run it).
"""
from __future__ import annotations

import argparse
import os
import sys
from typing import List, Optional

import numpy as np

from knode_swarm_ros.core import (RUNTIMES, PolicyError, TrajectoryError, load_runtime, load_trajectories,
                                  parse_trajectory_ref, rollout, save_trajectories)


def rollout_file(policy_path: str, init_ref: str, steps: int, out: str, dt: Optional[float] = None,
                 runtime: str = "torchscript") -> np.ndarray:
    """Roll ``policy_path`` out from frame 0 of ``init_ref`` and write ``out``; returns ``[T + 1, n, d]``."""
    policy = load_runtime(policy_path, runtime)
    path, index = parse_trajectory_ref(init_ref)
    data = load_trajectories(path, scenario=policy.scenario)
    if not 0 <= index < data.states.shape[0]:
        raise TrajectoryError(f"{path}: trajectory index {index} out of range "
                              f"(file holds {data.states.shape[0]} trajectories)")
    if steps < 0:
        raise ValueError(f"--steps must be >= 0, got {steps}")
    step_dt = policy.dt if dt is None else float(dt)
    z0 = data.states[index, 0]
    states = rollout(policy, z0, steps, policy.scenario, policy.d_cr, policy.k, policy.tau, step_dt)
    meta = {"generator": "training.rollout", "policy": os.fspath(policy_path), "init": init_ref,
            "steps": int(steps), "runtime": policy.backend, "k": policy.k, "d_cr": policy.d_cr, "tau": policy.tau,
            "policy_meta": {k: policy.meta.get(k) for k in ("scenario", "frame", "command_limit", "hidden")}}
    save_trajectories(out, states[None], step_dt, policy.scenario, meta)
    return states


def main(argv: Optional[List[str]] = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m training.rollout", description=__doc__.split("\n\n")[0])
    parser.add_argument("--policy", required=True, help="policy file (.pt, TorchScript with knode.json)")
    parser.add_argument("--init", required=True, help="FILE.npz[:TRAJ], initial state = frame 0 of trajectory TRAJ")
    parser.add_argument("--steps", required=True, type=int, help="number of steps to roll out")
    parser.add_argument("--out", required=True, help="output trajectory file (.npz)")
    parser.add_argument("--runtime", choices=RUNTIMES, default="torchscript",
                        help="policy backend (default torchscript; auto: the ONNX twin when it exists)")
    parser.add_argument("--dt", type=float, default=None, help="step in seconds (default: the policy's dt)")
    args = parser.parse_args(argv)
    try:
        states = rollout_file(args.policy, args.init, args.steps, args.out, args.dt, args.runtime)
    except (PolicyError, TrajectoryError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {args.out}: {states.shape[0]} frames of {states.shape[1]} robots")
    return 0


if __name__ == "__main__":
    sys.exit(main())
