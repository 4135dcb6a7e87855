"""What ``python -m training.import_bag`` is asked to do: options, their checks, ``--id-map``."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Dict, List, Optional, Sequence

import numpy as np

from knode_swarm_ros.bag import BagError
from knode_swarm_ros.core import get_scenario

__all__ = [
    'ImportOptions',
    'ImportResult',
    'FORMAT_VERSION',
    'GAP_FACTOR',
    'parse_id_map',
    'split_patterns',
    'check_options',
]

FORMAT_VERSION = 1
#: Default gap threshold in units of the slowest robot's median message interval.
GAP_FACTOR = 5.0


@dataclass
class ImportOptions:
    """What ``python -m training.import_bag`` is asked to do (see ``--help`` and docs/import_bag.md)."""

    scenario: str
    rate: float
    topics: Optional[List[str]] = None  # globs; default '/tf' with frames, or the id map's names
    frames: Optional[List[str]] = None  # child frame globs on TF topics
    id_map: Optional[Dict[str, int]] = None  # source name (topic or frame) -> robot id
    max_gap: Optional[float] = None  # seconds; default GAP_FACTOR x slowest median interval
    min_duration: float = 1.0  # seconds; shorter segments are dropped
    length: Optional[int] = None  # frames per trajectory; default the shortest kept segment
    smooth: str = 'none'  # none | moving-average | savgol
    smooth_window: int = 5  # odd, in output samples
    smooth_order: int = 2  # savgol polynomial order
    use_twist: bool = False  # velocity (flock2d) / heading (boids3d) from Odometry twist
    twist_frame: str = 'body'  # body (REP 105: rotate twist by the pose orientation) | world
    use_orientation: bool = False  # boids3d heading from the pose orientation (+x axis)
    heading_diff: str = 'backward'  # boids3d: backward | central differences
    min_speed: float = 1e-3  # boids3d: slower samples take the nearest valid heading
    stamp: str = 'header'  # header | log
    test_trajectories: int = 0  # the last K trajectories form meta.split.test


@dataclass
class ImportResult:
    states: np.ndarray  # [trajectories, T, n, d]
    dt: float
    scenario: str
    meta: Dict[str, Any]
    summary: List[str]


# --- command-line helpers ---------------------------------------------------------------------------


def parse_id_map(items: Sequence[str]) -> Dict[str, int]:
    """``NAME=ID`` items and/or YAML files ``{NAME: ID}`` -> ``{name: id}`` (ids distinct, >= 0)."""
    mapping: Dict[str, int] = {}
    for item in items:
        if '=' not in item:
            path = Path(item)
            if not path.is_file():
                raise BagError(f'--id-map {item}: neither NAME=ID nor an existing YAML file')
            import yaml

            try:
                data = yaml.safe_load(path.read_text(encoding='utf-8'))
            except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
                raise BagError(f'--id-map {item}: not a readable YAML file ({exc})') from None
            if not isinstance(data, dict) or not data:
                raise BagError(f'--id-map {item}: expected a YAML mapping NAME: ID')
            pairs = list(data.items())
        else:
            name, _, value = item.rpartition('=')
            pairs = [(name, value)]
        for name, value in pairs:
            try:
                rid = int(value)
            except (TypeError, ValueError):
                raise BagError(f'--id-map: robot id of {name!r} is {value!r}, not an integer') from None
            if rid < 0 or not str(name):
                raise BagError(f'--id-map: {name!r} -> {value!r}: ids must be >= 0 and names non-empty')
            name = str(name)
            if name in mapping and mapping[name] != rid:
                raise BagError(f'--id-map: {name} is mapped twice ({mapping[name]} and {rid})')
            mapping[name] = rid
    ids = list(mapping.values())
    dup = sorted({i for i in ids if ids.count(i) > 1})
    if dup:
        raise BagError(f'--id-map: robot id(s) {dup} given to more than one name')
    return mapping


def split_patterns(items: Optional[Sequence[str]]) -> Optional[List[str]]:
    if not items:
        return None
    out = [p.strip() for item in items for p in item.split(',') if p.strip()]
    return out or None


def check_options(opts: ImportOptions) -> None:
    spec = get_scenario(opts.scenario)
    if not (np.isfinite(opts.rate) and opts.rate > 0):
        raise BagError(f'--rate must be a positive number of Hz, got {opts.rate}')
    if opts.use_twist and opts.use_orientation:
        raise BagError('--use-twist and --use-orientation exclude each other')
    if opts.use_orientation and spec.heading is None:
        raise BagError('--use-orientation is for boids3d headings; flock2d needs no orientation')
    if opts.smooth not in ('none', 'moving-average', 'savgol'):
        raise BagError(f'--smooth {opts.smooth}: choose none, moving-average or savgol')
    if opts.smooth != 'none' and (opts.smooth_window < 3 or opts.smooth_window % 2 == 0):
        raise BagError(f'--smooth-window must be odd and >= 3, got {opts.smooth_window}')
    if opts.smooth == 'savgol' and not (0 <= opts.smooth_order < opts.smooth_window):
        raise BagError(f'--smooth-order must be >= 0 and below --smooth-window, got {opts.smooth_order}')
    if opts.max_gap is not None and not opts.max_gap > 0:
        raise BagError(f'--max-gap must be positive, got {opts.max_gap}')
    if opts.length is not None and opts.length < 3:
        raise BagError(f'--length must be at least 3 frames, got {opts.length}')
    if opts.min_duration < 0:
        raise BagError(f'--min-duration must be >= 0, got {opts.min_duration}')
    if opts.test_trajectories < 0:
        raise BagError(f'--test-trajectories must be >= 0, got {opts.test_trajectories}')
    if opts.heading_diff not in ('backward', 'central'):
        raise BagError(f'--heading-diff {opts.heading_diff}: choose backward or central')
