"""Train a KNODE swarm policy from observed trajectories (one-step-ahead or trajectory loss).

    python -m training.train --config config/train_flock2d.yaml --data data/flock2d.npz --out runs/flock2d
    python -m training.train ... --resume          # continue an interrupted run from its checkpoint
    python -m training.train ... --set training.epochs=10 --set training.solver=adjoint
    python -m training.train --config config/train_flock2d_multistep.yaml --data data/flock2d.npz --out runs/ms
    python -m training.train ... --data data/flock2d.npz data/flock2d_n30.npz   # mixed swarm sizes (one_step)

``training.objective``: ``one_step`` (default; one zero-order-hold step from every observed
state) or ``multi_step`` (rollouts over a curriculum of horizons), the names of the registry
``training.learning.objectives.OBJECTIVES``. The validation loss in metrics.jsonl is the one-step
loss for all, so runs compare.

The run directory receives ``config.yaml`` (the normalised config), ``metrics.jsonl`` (one
line per epoch), ``checkpoint.pt`` (after every good epoch), ``policy.pt`` (the exported
policy: the epoch with the best validation rollout score, or the last epoch when selection
is off) and ``summary.json``.

Exit status: 0 done, 2 bad config or data (message names the field or file), 3 divergence
(NaN or exploding loss; the last good checkpoint is kept).
"""

from __future__ import annotations

import argparse
import sys
from typing import List, Optional

from knode_swarm_ros.core.cli import cli, parse_set
from training.learning.config import load_config
from training.learning.trainer import Trainer


@cli('python -m training.train')
def main(argv: Optional[List[str]] = None) -> int:
    parser = argparse.ArgumentParser(prog='python -m training.train', description=__doc__.split('\n\n')[0])
    parser.add_argument('--config', required=True, help='YAML training config (config/train_*.yaml)')
    parser.add_argument(
        '--data',
        required=True,
        nargs='+',
        action='extend',
        metavar='FILE',
        help='trajectory file(s) (.npz) with a train split in meta; several files may hold '
        'swarms of different sizes (one policy learns from all)',
    )
    parser.add_argument('--out', required=True, help='run directory')
    parser.add_argument('--resume', action='store_true', help='continue from OUT/checkpoint.pt')
    parser.add_argument('--set', action='append', metavar='SECTION.KEY=VALUE', help='override a config field')
    parser.add_argument('--no-progress', action='store_true', help='no progress bar')
    args = parser.parse_args(argv)
    cfg = load_config(args.config, parse_set(args.set))
    trainer = Trainer(
        cfg,
        args.data[0] if len(args.data) == 1 else args.data,
        args.out,
        resume=args.resume,
        progress=not args.no_progress,
    )
    summary = trainer.run()  # DivergenceError: exit 3
    print(f'wrote {summary["policy"]} ({summary["selected"]}, {summary["train_seconds"]} s)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
