"""Training throughput and peak memory: adjoint vs direct gradients, and growth with robots.

    python bench/bench_training.py [--robots 10 20 40] [--batches 8] [--batch-size 4096]

For each gradient method (``zoh``: exact zero-order hold, direct backprop; ``rk4``: direct
backprop through torchdiffeq's fixed-step rk4 of the held-neighbour field; ``adjoint``:
``odeint_adjoint`` of the same field, the paper's choice) and each swarm size, one child
process builds flock2d samples (2 trajectories x 200 frames of Tanner data), runs forward +
backward + Adam on ``--batches`` mini-batches and reports samples per second and its peak
resident memory. Also reports how close the three gradients are on one batch. Ratios are
relative to ``zoh`` at the same size. One thread (the fastest setting on this machine).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def child(method: str, robots: int, batches: int, batch_size: int) -> dict:
    import torch

    torch.set_num_threads(1)
    sys.path.insert(0, ROOT)
    from knode_swarm_ros.core import get_scenario
    from knode_swarm_ros.core.groundtruth import simulate
    from training.learning.config import build_policy, load_config
    from training.learning.objectives.one_step import loss_scales, one_step_loss, predict_next
    from training.learning.samples import make_samples

    cfg = load_config(os.path.join(ROOT, 'config', 'train_flock2d.yaml'))
    spec = get_scenario('flock2d')
    states = simulate('flock2d', 2, robots, 200, seed=0, progress=False)
    s = make_samples(states, spec, cfg['policy']['d_cr'], cfg['policy']['k'], 0)
    torch.manual_seed(0)
    policy = build_policy(cfg)
    opt = torch.optim.Adam(policy.parameters(), lr=1e-3)
    scales = loss_scales(spec, 0.01, 'command')
    g = torch.Generator().manual_seed(0)
    idx = [torch.randint(len(s), (batch_size,), generator=g) for _ in range(batches + 1)]

    def step(i):
        loss = one_step_loss(
            predict_next(policy, spec, 0.01, s.Y[i], s.mask[i], s.clean_own[i], method), s.target[i], scales
        )
        opt.zero_grad()
        loss.backward()
        opt.step()

    step(idx[0])  # warm-up
    t0 = time.perf_counter()
    for i in idx[1:]:
        step(i)
    dt = time.perf_counter() - t0
    return {
        'method': method,
        'robots': robots,
        'samples_per_s': batches * batch_size / dt,
        'peak_rss_mb': resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }


def gradient_agreement() -> dict:
    import torch

    torch.set_num_threads(1)
    sys.path.insert(0, ROOT)
    from knode_swarm_ros.core import get_scenario
    from knode_swarm_ros.core.groundtruth import simulate
    from training.learning.config import build_policy, load_config
    from training.learning.objectives.one_step import loss_scales, one_step_loss, predict_next
    from training.learning.samples import make_samples

    cfg = load_config(os.path.join(ROOT, 'config', 'train_flock2d.yaml'))
    spec = get_scenario('flock2d')
    s = make_samples(simulate('flock2d', 1, 10, 100, seed=1, progress=False), spec, 5.0, 6, 0)
    torch.manual_seed(0)
    policy = build_policy(cfg)
    grads = {}
    for m in ('zoh', 'rk4', 'adjoint'):
        policy.zero_grad()
        one_step_loss(
            predict_next(policy, spec, 0.01, s.Y, s.mask, s.clean_own, m),
            s.target,
            loss_scales(spec, 0.01, 'command'),
        ).backward()
        grads[m] = torch.cat(
            [(p.grad if p.grad is not None else torch.zeros_like(p)).flatten() for p in policy.parameters()]
        )
    rel = lambda a, b: float((grads[a] - grads[b]).norm() / grads[b].norm())  # noqa: E731
    return {'rk4_vs_adjoint_rel': rel('rk4', 'adjoint'), 'zoh_vs_rk4_rel': rel('zoh', 'rk4')}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--robots', type=int, nargs='+', default=[10, 20, 40])
    parser.add_argument('--batches', type=int, default=8)
    parser.add_argument('--batch-size', type=int, default=4096)
    parser.add_argument('--child', nargs=2, metavar=('METHOD', 'ROBOTS'), help=argparse.SUPPRESS)
    parser.add_argument('--agreement', action='store_true', help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(child(args.child[0], int(args.child[1]), args.batches, args.batch_size)))
        return 0
    if args.agreement:
        print(json.dumps(gradient_agreement()))
        return 0
    rows = []
    for n in args.robots:
        for m in ('zoh', 'rk4', 'adjoint'):
            out = subprocess.run(
                [
                    sys.executable,
                    __file__,
                    '--child',
                    m,
                    str(n),
                    '--batches',
                    str(args.batches),
                    '--batch-size',
                    str(args.batch_size),
                ],
                capture_output=True,
                text=True,
                check=True,
            )
            rows.append(json.loads(out.stdout.strip().splitlines()[-1]))
    agree = json.loads(
        subprocess.run([sys.executable, __file__, '--agreement'], capture_output=True, text=True, check=True)
        .stdout.strip()
        .splitlines()[-1]
    )
    print(f'{"robots":>6} {"method":>8} {"samples/s":>10} {"x zoh":>6} {"peak MB":>8} {"x zoh":>6}')
    base = {r['robots']: r for r in rows if r['method'] == 'zoh'}
    for r in rows:
        b = base[r['robots']]
        print(
            f'{r["robots"]:>6} {r["method"]:>8} {r["samples_per_s"]:>10.0f} {r["samples_per_s"] / b["samples_per_s"]:>6.2f} '
            f'{r["peak_rss_mb"]:>8.0f} {r["peak_rss_mb"] / b["peak_rss_mb"]:>6.2f}'
        )
    print(
        f'gradient agreement on one batch: |rk4 - adjoint| / |adjoint| = {agree["rk4_vs_adjoint_rel"]:.2e}, '
        f'|zoh - rk4| / |rk4| = {agree["zoh_vs_rk4_rel"]:.2e}'
    )
    return 0


if __name__ == '__main__':
    sys.exit(main())
