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

An ``--out`` that already holds a run (``policy.pt`` or ``checkpoint.pt``) is refused unless
``--resume`` (continue it; ``--set training.epochs=N`` may extend a finished run) or
``--overwrite`` (replace it) is given. The progress bar is drawn only on a terminal; redirected
to a file the log has one line per epoch (and one a minute within a long epoch).

Exit status: 0 done, 2 bad config or data (message names the field or file), 3 divergence
(NaN or exploding loss; the last good checkpoint is kept), 130 interrupted (Ctrl-C; the last
checkpoint is kept and ``--resume`` continues from it).
"""

from __future__ import annotations

import argparse
import os
import sys
from typing import List, Optional

from knode_swarm_ros.core.cli import cli, parse_set
from knode_swarm_ros.core.errors import EXIT_INTERRUPTED, ConfigError
from training.learning.config import load_config
from training.learning.trainer import Trainer

#: The files that say a directory holds a run (training.train refuses to train over them by accident).
RUN_FILES = ('policy.pt', 'checkpoint.pt')


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
    parser.add_argument(
        '--resume',
        action='store_true',
        help='continue from OUT/checkpoint.pt (same config; --set training.epochs=N may extend the run)',
    )
    parser.add_argument(
        '--overwrite', action='store_true', help='replace the run already in --out (default: refuse)'
    )
    parser.add_argument('--set', action='append', metavar='SECTION.KEY=VALUE', help='override a config field')
    parser.add_argument(
        '--no-progress',
        action='store_true',
        help='no progress bar and no progress lines within an epoch (the bar is drawn only on a terminal)',
    )
    args = parser.parse_args(argv)
    cfg = load_config(args.config, parse_set(args.set))
    if args.resume and args.overwrite:
        parser.error('--resume and --overwrite exclude each other')
    earlier = [name for name in RUN_FILES if os.path.exists(os.path.join(args.out, name))]
    if earlier and not (args.resume or args.overwrite):
        raise ConfigError(
            f'--out {args.out} already holds a run ({", ".join(earlier)}): add --resume to continue it, '
            '--overwrite to replace it, or choose another --out'
        )
    trainer = Trainer(
        cfg,
        args.data[0] if len(args.data) == 1 else args.data,
        args.out,
        resume=args.resume,
        progress=not args.no_progress,
    )
    try:
        summary = trainer.run()  # DivergenceError: exit 3
    except KeyboardInterrupt:
        print(f'python -m training.train: interrupted: {trainer.resume_hint()}', file=sys.stderr)
        return EXIT_INTERRUPTED
    print(f'wrote {summary["policy"]} ({summary["selected"]}, {summary["train_seconds"]} s)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
