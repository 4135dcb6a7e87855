"""A sweep's table: per cell of the axes other than ``seed``, the mean and 95 % interval over seeds
of each selection metric (:mod:`.stats`), as JSON and markdown, and heat maps when two axes remain.
"""

from __future__ import annotations

import itertools
import os
from typing import Any, Dict, List, Sequence, Tuple

import numpy as np

from .stats import describe

SEED = 'seed'
#: Selection metrics tabulated (those a cell's record holds): the score, flock2d's and boids3d's terms.
TABLE_METRICS = ('score', 'avd_final', 'amd_final', 'amd_median', 'pod_kld', 'stays_inside')


def sweep_table(records: List[Dict[str, Any]], axes: Sequence[Tuple[str, List[Any]]]) -> Dict[str, Any]:
    """``{'axes': [keys but seed], 'rows': [{'values', 'seeds', 'failed', 'metrics': {name: describe}}]}``,
    one row per point of the other axes (the first axis slowest), over its ``done`` cells."""
    keys = [k for k, _ in axes if k != SEED]
    rows = []
    for combo in itertools.product(*(v for k, v in axes if k != SEED)):
        values = dict(zip(keys, combo))
        mine = [r for r in records if all(r['values'].get(k) == v for k, v in values.items())]
        done = [r for r in mine if r['status'] == 'done' and r.get('metrics')]
        metrics = {}
        for name in TABLE_METRICS:
            sample = [r['metrics'][name] for r in done if name in r['metrics']]
            if sample and len(sample) == len(done):
                metrics[name] = describe(sample)
        rows.append(
            {
                'values': values,
                'seeds': len(done),
                'failed': sum(r['status'] == 'failed' for r in mine),
                'metrics': metrics,
            }
        )
    return {'axes': keys, 'rows': rows}


def table_markdown(table: Dict[str, Any], title: str = 'Sweep') -> str:
    """One markdown table: a row per cell, ``mean ± ci95`` of each metric over its seeds."""
    names = [m for m in TABLE_METRICS if any(m in r['metrics'] for r in table['rows'])]
    head = table['axes'] + ['seeds', 'failed'] + [f'{m} (mean ± 95 %)' for m in names]
    lines = [f'# {title}', '', '| ' + ' | '.join(head) + ' |', '|' + ' --- |' * len(head)]
    for row in table['rows']:
        cells = [str(row['values'][k]) for k in table['axes']] + [str(row['seeds']), str(row['failed'])]
        for m in names:
            d = row['metrics'].get(m)
            cells.append('-' if d is None else f'{d["mean"]:.3g} ± {d["ci95"]:.2g}')
        lines.append('| ' + ' | '.join(cells) + ' |')
    return '\n'.join(lines) + '\n'


def heatmaps(table: Dict[str, Any], axes: Sequence[Tuple[str, List[Any]]], out: str) -> List[str]:
    """``OUT/heatmap_<metric>.png``: the mean over seeds per cell, when exactly two axes besides
    ``seed`` remain (rows the first, columns the second); returns the paths written."""
    if len(table['axes']) != 2:
        return []
    from . import figures

    (row_key, row_values), (col_key, col_values) = [(k, v) for k, v in axes if k != SEED]
    paths = []
    for name in TABLE_METRICS:
        grid = np.full((len(row_values), len(col_values)), np.nan)
        for row in table['rows']:
            d = row['metrics'].get(name)
            if d is not None:
                i = row_values.index(row['values'][row_key])
                j = col_values.index(row['values'][col_key])
                grid[i, j] = d['mean']
        if np.isfinite(grid).any():
            path = os.path.join(out, f'heatmap_{name}.png')
            figures.heatmap(path, grid, row_values, col_values, f'mean {name} over seeds', row_key, col_key)
            paths.append(path)
    return paths
