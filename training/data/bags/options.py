"""What ``python -m training.import_bag`` is asked to do: options, their checks, ``--id-map``."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Dict, List, Optional, Sequence

import numpy as np

from knode_swarm_ros.bag import BagError
from knode_swarm_ros.core.yaml_file import load_yaml

from ..tracks import GAP_FACTOR, ResampleOptions, check_resample_options

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


@dataclass
class ImportOptions(ResampleOptions):
    """What ``python -m training.import_bag`` is asked to do (see ``--help`` and docs/import_bag.md):
    the shared :class:`~training.data.tracks.ResampleOptions` and which robots a bag holds."""

    topics: Optional[List[str]] = None  # globs; default '/tf' with frames, or the id map's names
    frames: Optional[List[str]] = None  # child frame globs on TF topics
    id_map: Optional[Dict[str, int]] = None  # source name (topic or frame) -> robot id
    stamp: str = 'header'  # header | log


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
                data = load_yaml(path.read_text(encoding='utf-8'))
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
    check_resample_options(opts, BagError)
