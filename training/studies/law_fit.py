"""Can a policy network represent a swarm law at all? A recipe policy without its knowledge terms
(the network, steered where the recipe derives a set speed, saturated), regressed directly on
the law's own commands (no rollout, no noise), with
its error by nearest-neighbour distance (docs/scenarios.md, "Can the network represent the law").

    python -m training.studies.law_fit --law mill2d --seconds 120
    python -m training.studies.law_fit --law mill2d --seconds 90 --set policy.encoder=equivariant

The law's 10-robot trajectories (starts of ``--seed``: 10 to fit, 2 held out) give the states;
the recipe (``--config``, default ``config/train_custom.yaml``, with ``--set``) derives its
fields from the fitted ones, as a training does. Adam at the recipe's learning rate for
``--seconds`` (or ``--epochs``), one thread. A one-step training learns the same map from the
same states, so it can hardly fit better; a rollout of a policy that cannot fit its law drifts
from it.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from typing import List, Optional

import numpy as np
import torch

from knode_swarm_ros.core import neighbour_matrix
from knode_swarm_ros.core.cli import cli, parse_set
from knode_swarm_ros.core.metrics import nearest_neighbour_distance
from training.learning.config import build_policy, load_config, resolve_config

from .laws import LAWS, RECIPE, initial_states, simulate

BINS = (0.0, 0.5, 1.0, 2.0, np.inf)  # nearest-neighbour distance bins, m


def _batch(law, z: np.ndarray):
    """``Y [S, k, d]``, ``mask [S, k]`` (every robot sees every other) and the law's commands."""
    n = z.shape[-2]
    z = z.reshape(-1, n, z.shape[-1])
    Y, mask = neighbour_matrix(z, z, law.scenario.position_dim, 1e9, n)
    u = law.command(z)
    f = torch.float32
    return (
        torch.tensor(Y.reshape(-1, n, z.shape[-1]), dtype=f),
        torch.tensor(mask.reshape(-1, n), dtype=f),
        torch.tensor(u.reshape(-1, u.shape[-1]), dtype=f),
    )


@cli('python -m training.studies.law_fit')
def main(argv: Optional[List[str]] = None) -> int:
    parser = argparse.ArgumentParser(prog='training.studies.law_fit', description=__doc__.split('\n\n')[0])
    parser.add_argument('--law', choices=sorted(LAWS), required=True)
    parser.add_argument('--seconds', type=float, default=120.0, help='fitting time (Adam)')
    parser.add_argument(
        '--epochs', type=int, default=None, help='at most this many passes (default: no limit)'
    )
    parser.add_argument('--seed', type=int, default=0, help='starts of the fitted trajectories')
    parser.add_argument('--config', default=RECIPE, help='training recipe (default train_custom.yaml)')
    parser.add_argument('--set', action='append', metavar='KEY=VALUE', help='a recipe field (repeatable)')
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    torch.manual_seed(args.seed)
    law = LAWS[args.law]
    spec = law.scenario
    z = simulate(law, initial_states(law, 12, 10, args.seed), law.steps)  # [12, T, 10, d]
    ref = json.dumps(spec.to_dict(), sort_keys=True)
    cfg, _ = resolve_config(load_config(args.config, parse_set(args.set)), [z[:10]], ref, spec.dt)
    cfg['policy'].update(collision=False, wall=False)  # the network alone
    policy = build_policy(cfg)
    Y, mask, U = _batch(law, z[:10])
    Yt, maskt, Ut = _batch(law, z[10:, ::4])
    opt = torch.optim.Adam(policy.parameters(), lr=float(cfg['training']['lr']))
    t0, epochs = time.perf_counter(), 0
    while time.perf_counter() - t0 < args.seconds and (args.epochs is None or epochs < args.epochs):
        for idx in torch.randperm(len(Y)).split(int(cfg['training']['batch_size'])):
            loss = ((policy(Y[idx], mask[idx]) - U[idx]) ** 2).sum(-1).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
        epochs += 1
    with torch.no_grad():
        err = (policy(Yt, maskt) - Ut).norm(dim=-1).numpy()
    nn = nearest_neighbour_distance(z[10:, ::4, ..., spec.position]).reshape(-1)
    pol = cfg['policy']
    print(
        f'{args.law}, encoder {pol["encoder"]}, symmetric {pol["symmetric"]}, speed {pol["speed"]}, '
        f'turn limit {pol["turn_limit"]}, position scale {pol["position_scale"]:.4g}: {epochs} epochs in '
        f'{time.perf_counter() - t0:.0f} s'
    )
    print(
        f'held-out commands: RMS {float(Ut.norm(dim=-1).pow(2).mean().sqrt()):.3f}, '
        f'error RMS {float(np.sqrt(np.mean(err**2))):.3f}'
    )
    for lo, hi in zip(BINS[:-1], BINS[1:]):
        sel = (nn >= lo) & (nn < hi)
        if sel.any():
            print(
                f'  nearest neighbour in [{lo:g}, {hi:g}) m: {sel.sum()} robots, error RMS {np.sqrt(np.mean(err[sel] ** 2)):.3f}'
            )
    return 0


if __name__ == '__main__':
    sys.exit(main())
