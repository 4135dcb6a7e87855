"""Sweep a training config over axes of config keys (seeds included), cells run in parallel on Ray.

    python -m training.sweep --config config/train_flock2d.yaml --data data/flock2d.npz --out sweeps/k \\
        --axis policy.k=6,10 --axis seed=0,1,2 [--set training.epochs=3] [--workers 2]
    python -m training.sweep ... --workers 16 --address ray://head:10001     # a Ray cluster

Every point of the axes' product (``--axis KEY=V1,V2,...``, any ``--set`` key; ``seed`` is the
config's seed) is one ordinary training run (``training.train``) in its own run directory
``OUT/<key=value,...>/`` (its ``summary.json``, ``policy.pt``, ``train.log`` and ``cell.json``).
``--workers 1`` (the default) runs the cells one after another in this process; more workers, or
``--address``, run them as Ray tasks (``pip install ray==2.60.0``, the ``sweep`` extra): a local
Ray of that many CPUs, or the cluster at the address (its nodes read ``--data`` and write ``--out``
at the same absolute paths: a shared filesystem).

Run the same command again to resume: finished cells are not run again, a cell cut short resumes
from its checkpoint. A cell that fails (an exception, a killed worker) is tried once more; failing
twice it is reported ``failed`` and the others go on. Progress lines (cells done, running,
failed, time left) go to stdout and ``OUT/sweep.log``. At the end: ``OUT/sweep.json`` (every cell:
axis values, status ``done``/``failed``/``skipped``, run directory, selection metrics; and the
table), ``OUT/table.md`` (mean and 95 % interval over seeds of the selection metrics per cell) and,
with two axes besides ``seed``, ``OUT/heatmap_<metric>.png``.

Exit status: 0 every cell done, 1 a cell failed, 2 bad arguments or config (or Ray missing).
"""

from __future__ import annotations

import argparse
import functools
import os
import sys
from typing import List, Optional

from knode_swarm_ros.core.cli import cli, parse_set
from knode_swarm_ros.core.errors import EXIT_RUN_FAILED
from training.assessment.sweep_table import heatmaps, sweep_table, table_markdown
from training.learning.config import load_config
from training.learning.records import write_json
from training.learning.sweep import (
    Cell,
    axis_product,
    cell_name,
    check_files,
    finished_cell,
    parse_axis,
    run_cells,
    train_cell,
)


@cli('python -m training.sweep')
def main(argv: Optional[List[str]] = None) -> int:
    parser = argparse.ArgumentParser(prog='python -m training.sweep', description=__doc__.split('\n\n')[0])
    parser.add_argument('--config', required=True, help='YAML training config (config/train_*.yaml)')
    parser.add_argument('--data', required=True, nargs='+', metavar='FILE', help='trajectory file(s) (.npz)')
    parser.add_argument('--out', required=True, help='sweep directory (one run directory per cell)')
    parser.add_argument(
        '--axis',
        action='append',
        default=[],
        metavar='KEY=V1,V2,...',
        help='an axis of the sweep: a config key (as --set) and its values; repeat for more axes',
    )
    parser.add_argument('--set', action='append', metavar='SECTION.KEY=VALUE', help='override a config field')
    parser.add_argument(
        '--workers', type=int, default=1, help='cells at a time (default 1: in this process; more: Ray)'
    )
    parser.add_argument(
        '--address', default=None, help='a Ray cluster (ray://host:10001) instead of a local Ray'
    )
    args = parser.parse_args(argv)
    axes = [parse_axis(a) for a in args.axis]
    base = parse_set(args.set)
    check_files('--data', args.data)
    # cluster workers do not share this directory: every path absolute
    data = [os.path.abspath(p) for p in args.data]
    data = data[0] if len(data) == 1 else data
    out = os.path.abspath(args.out)
    cells = []
    for values in axis_product(axes):
        cfg = load_config(args.config, {**base, **values})  # every cell's config checked before any runs
        run_dir = os.path.join(out, cell_name(values))
        cells.append(
            Cell(
                cell_name(values),
                values,
                run_dir,
                functools.partial(train_cell, cfg, data, run_dir),
                previous=finished_cell(run_dir, cfg, data),
            )
        )
    if len({c.name for c in cells}) != len(cells):
        raise ValueError('--axis: two values of an axis give the same directory name; spell them apart')
    header = {'config': os.path.abspath(args.config), 'data': data, 'set': base, 'axes': dict(axes)}
    records = run_cells(cells, out, args.workers, args.address, header=header)
    table = sweep_table(records, axes)
    write_json(os.path.join(out, 'sweep.json'), {**header, 'cells': records, 'table': table})
    with open(os.path.join(out, 'table.md'), 'w') as fh:
        fh.write(table_markdown(table, f'Sweep of {os.path.basename(args.config)}'))
    maps = heatmaps(table, axes, out)
    failed = [r['name'] for r in records if r['status'] != 'done']
    print(
        f'{len(records) - len(failed)} of {len(records)} cells done; wrote {out}/sweep.json, table.md'
        + (f' and {len(maps)} heat maps' if maps else '')
    )
    if failed:
        print(f'not done: {", ".join(failed)} (see {out}/sweep.json)', file=sys.stderr)
        return EXIT_RUN_FAILED
    return 0


if __name__ == '__main__':
    sys.exit(main())
