"""The training config: its schema and defaults, validation naming the field, loading YAML with overrides.

A config has ``scenario``, ``seed``, ``name``, ``policy`` (PolicyConfig fields; defaults are the
paper's ``DEFAULTS[scenario]``) and the sections of :data:`DEFAULT_CONFIG`.
"""

from __future__ import annotations

import copy
import math
import os
from dataclasses import fields
from typing import Any, Dict, Optional

from knode_swarm_ros.core import DEFAULTS, KNODEPolicy, PolicyConfig, get_scenario

# A training config is invalid; the message names the field (one class with the nodes').
from knode_swarm_ros.core.errors import ConfigError

from .objectives import OBJECTIVES

# ----------------------------------------------------------------------------- configs

# Every config section with its defaults; ``None`` means "scenario dependent" (filled below).
DEFAULT_CONFIG: Dict[str, Dict[str, Any]] = {
    'data': {
        'train_trajectories': None,
        'val_trajectories': None,
        'val_fraction': 0.2,
        'frames': None,
        'stride': 1,
        'drop_saturated': True,
        'policy_dt': None,
    },
    'noise': {'mode': 'inputs', 'variance': None},
    'training': {
        'solver': 'zoh',
        'ode_method': 'rk4',
        'epochs': 60,
        'batch_size': 4096,
        'lr': 3e-3,
        'lr_schedule': 'cosine',
        'lr_min': 1e-4,
        'weight_decay': 0.0,
        'loss_units': 'command',
        'heading_weight': 1.0,
        'grad_clip': 10.0,
        'diverge_factor': 1000.0,
        'max_param': 1.0e5,
        'threads': 1,
        'max_minutes': None,
        'objective': 'one_step',
    },
    # the multi_step objective (objectives/multi_step.py): a curriculum of horizons, from a one-step model
    'multistep': {
        'init': None,
        'horizons': [10, 50, 200],
        'epochs': [2, 2, 2],
        'windows_per_epoch': 256,
        'batch_windows': 16,
        'units': 'command',
        'checkpoint': 0,
        'velocity_weight': 1.0,
        'consensus_weight': 0.0,
    },
    'selection': {'every': 5, 'trajectories': 4, 'steps': None, 'rollouts': 1, 'perturb': 1.0e-3},
    'augment': {'rotate': False, 'velocity_boost': 0.0},
}
NOISE_VARIANCE = {'flock2d': 0.001, 'boids3d': 0.01}
SOLVERS = ('zoh', 'rk4', 'adjoint')
NOISE_MODES = ('inputs', 'observations', 'none')
SCHEDULES = ('cosine', 'step', 'none')
LOSS_UNITS = ('command', 'state')
POLICY_FIELDS = {f.name for f in fields(PolicyConfig)} - {'scenario', 'extra'}


def _check(cond: bool, field: str, value: Any, why: str) -> None:
    if not cond:
        raise ConfigError(f'config field {field!r} = {value!r}: {why}')


def normalise_config(raw: Dict[str, Any]) -> Dict[str, Any]:
    """Fill defaults and validate a training config; raises :class:`ConfigError` naming the field.

    Layout: ``scenario``, ``seed``, ``policy`` (PolicyConfig fields; defaults are the paper's
    ``DEFAULTS[scenario]``), ``data``, ``noise``, ``training``, ``selection``.
    """
    if not isinstance(raw, dict):
        raise ConfigError(f'config must be a mapping, got {type(raw).__name__}')
    known_top = {'scenario', 'seed', 'policy', 'name', *DEFAULT_CONFIG}
    for key in raw:
        _check(
            key in known_top, key, raw[key], f'unknown top-level field; known: {", ".join(sorted(known_top))}'
        )
    _check('scenario' in raw, 'scenario', None, 'required (flock2d or boids3d)')
    scenario = raw['scenario']
    try:
        get_scenario(scenario)
    except ValueError as exc:
        raise ConfigError(f"config field 'scenario' = {scenario!r}: {exc}") from None
    cfg: Dict[str, Any] = {
        'scenario': scenario,
        'seed': raw.get('seed', 0),
        'name': raw.get('name', scenario),
    }
    _check(
        isinstance(cfg['seed'], int) and not isinstance(cfg['seed'], bool),
        'seed',
        cfg['seed'],
        'must be an integer',
    )

    policy = dict(DEFAULTS[scenario])
    given = raw.get('policy') or {}
    _check(isinstance(given, dict), 'policy', given, 'must be a mapping')
    for key, value in given.items():
        _check(
            key in POLICY_FIELDS,
            f'policy.{key}',
            value,
            f'unknown; known: {", ".join(sorted(POLICY_FIELDS))}',
        )
        policy[key] = value
    try:
        PolicyConfig(scenario, **policy)
    except (TypeError, ValueError) as exc:
        # PolicyConfig says "invalid NAME = VALUE": name it as the user spells it (--set policy.NAME=...)
        named = [f'policy.{key}' for key in sorted(policy) if f'invalid {key} = ' in str(exc)]
        raise ConfigError(f'config field {(named or ["policy"])[0]!r}: {exc}') from None
    cfg['policy'] = policy

    for section, defaults in DEFAULT_CONFIG.items():
        given = raw.get(section) or {}
        _check(isinstance(given, dict), section, given, 'must be a mapping')
        merged = dict(defaults)
        for key, value in given.items():
            _check(
                key in defaults, f'{section}.{key}', value, f'unknown; known: {", ".join(sorted(defaults))}'
            )
            merged[key] = value
        cfg[section] = merged
    if cfg['noise']['variance'] is None:
        cfg['noise']['variance'] = NOISE_VARIANCE[scenario]

    t, d, n, s = cfg['training'], cfg['data'], cfg['noise'], cfg['selection']

    def num(v):
        return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)

    def pos_int(v):
        return isinstance(v, int) and not isinstance(v, bool) and v >= 1

    _check(t['solver'] in SOLVERS, 'training.solver', t['solver'], f'must be one of {", ".join(SOLVERS)}')
    _check(
        t['ode_method'] in ('rk4', 'euler', 'midpoint', 'dopri5'),
        'training.ode_method',
        t['ode_method'],
        'must be rk4, euler, midpoint or dopri5',
    )
    _check(pos_int(t['epochs']), 'training.epochs', t['epochs'], 'must be an integer >= 1')
    _check(
        pos_int(t['batch_size']) or t['batch_size'] == 'full',
        'training.batch_size',
        t['batch_size'],
        "must be an integer >= 1 or 'full'",
    )
    _check(num(t['lr']) and t['lr'] > 0, 'training.lr', t['lr'], 'must be a positive number')
    _check(num(t['lr_min']) and t['lr_min'] >= 0, 'training.lr_min', t['lr_min'], 'must be >= 0')
    _check(
        t['lr_schedule'] in SCHEDULES,
        'training.lr_schedule',
        t['lr_schedule'],
        f'must be one of {", ".join(SCHEDULES)}',
    )
    _check(
        num(t['weight_decay']) and t['weight_decay'] >= 0,
        'training.weight_decay',
        t['weight_decay'],
        'must be >= 0',
    )
    _check(
        t['loss_units'] in LOSS_UNITS,
        'training.loss_units',
        t['loss_units'],
        f'must be one of {", ".join(LOSS_UNITS)}',
    )
    _check(
        num(t['heading_weight']) and t['heading_weight'] >= 0,
        'training.heading_weight',
        t['heading_weight'],
        'must be >= 0',
    )
    _check(
        t['grad_clip'] is None or (num(t['grad_clip']) and t['grad_clip'] > 0),
        'training.grad_clip',
        t['grad_clip'],
        'must be null or a positive number',
    )
    _check(
        num(t['diverge_factor']) and t['diverge_factor'] > 1,
        'training.diverge_factor',
        t['diverge_factor'],
        'must be > 1',
    )
    _check(num(t['max_param']) and t['max_param'] > 0, 'training.max_param', t['max_param'], 'must be > 0')
    _check(pos_int(t['threads']), 'training.threads', t['threads'], 'must be an integer >= 1')
    _check(
        t['max_minutes'] is None or (num(t['max_minutes']) and t['max_minutes'] > 0),
        'training.max_minutes',
        t['max_minutes'],
        'must be null or a positive number',
    )
    _check(
        d['train_trajectories'] is None or pos_int(d['train_trajectories']),
        'data.train_trajectories',
        d['train_trajectories'],
        'must be null or an integer >= 1',
    )
    _check(
        d['val_trajectories'] is None
        or (isinstance(d['val_trajectories'], int) and not isinstance(d['val_trajectories'], bool))
        and d['val_trajectories'] >= 0,
        'data.val_trajectories',
        d['val_trajectories'],
        'must be null (use data.val_fraction) or an integer >= 0',
    )
    _check(
        num(d['val_fraction']) and 0 <= d['val_fraction'] < 1,
        'data.val_fraction',
        d['val_fraction'],
        'must be a number in [0, 1)',
    )
    _check(
        d['frames'] is None or (pos_int(d['frames']) and d['frames'] >= 2),
        'data.frames',
        d['frames'],
        'must be null or an integer >= 2',
    )
    _check(pos_int(d['stride']), 'data.stride', d['stride'], 'must be an integer >= 1')
    _check(
        isinstance(d['drop_saturated'], bool),
        'data.drop_saturated',
        d['drop_saturated'],
        'must be true or false',
    )
    _check(
        d['policy_dt'] is None or (num(d['policy_dt']) and d['policy_dt'] > 0),
        'data.policy_dt',
        d['policy_dt'],
        "must be null (the data's dt) or a positive multiple of the data's dt in seconds",
    )
    _check(n['mode'] in NOISE_MODES, 'noise.mode', n['mode'], f'must be one of {", ".join(NOISE_MODES)}')
    _check(num(n['variance']) and n['variance'] >= 0, 'noise.variance', n['variance'], 'must be >= 0')
    a = cfg['augment']
    spec = get_scenario(scenario)
    _check(isinstance(a['rotate'], bool), 'augment.rotate', a['rotate'], 'must be true or false')
    _check(
        not a['rotate'] or spec.name == 'flock2d',
        'augment.rotate',
        a['rotate'],
        'random rotations are a symmetry of flock2d only (boids3d has walls)',
    )
    _check(
        num(a['velocity_boost']) and a['velocity_boost'] >= 0,
        'augment.velocity_boost',
        a['velocity_boost'],
        'must be a number >= 0',
    )
    _check(
        a['velocity_boost'] == 0 or spec.command == 'acceleration',
        'augment.velocity_boost',
        a['velocity_boost'],
        'Galilean boosts are a symmetry of flock2d only',
    )
    _check(
        isinstance(s['every'], int) and s['every'] >= 0,
        'selection.every',
        s['every'],
        'must be an integer >= 0 (0 = off)',
    )
    _check(pos_int(s['trajectories']), 'selection.trajectories', s['trajectories'], 'must be an integer >= 1')
    _check(
        s['steps'] is None or pos_int(s['steps']),
        'selection.steps',
        s['steps'],
        'must be null or an integer >= 1',
    )
    _check(pos_int(s['rollouts']), 'selection.rollouts', s['rollouts'], 'must be an integer >= 1')
    _check(
        num(s['perturb']) and s['perturb'] >= 0, 'selection.perturb', s['perturb'], 'must be a number >= 0'
    )
    _check_multistep(cfg, raw, pos_int)
    return cfg


def _check_multistep(cfg: Dict[str, Any], raw: Dict[str, Any], pos_int) -> None:
    t, m = cfg['training'], cfg['multistep']
    _check(
        t['objective'] in OBJECTIVES,
        'training.objective',
        t['objective'],
        f'must be one of {", ".join(OBJECTIVES)}',
    )
    _check(
        m['init'] is None or isinstance(m['init'], str),
        'multistep.init',
        m['init'],
        'must be null or the path of a policy file or run directory',
    )
    for key in ('horizons', 'epochs'):
        _check(
            isinstance(m[key], list) and len(m[key]) >= 1 and all(pos_int(v) for v in m[key]),
            f'multistep.{key}',
            m[key],
            'must be a non-empty list of integers >= 1',
        )
    _check(
        len(m['horizons']) == len(m['epochs']),
        'multistep.epochs',
        m['epochs'],
        f'needs one entry per horizon ({len(m["horizons"])})',
    )
    for key in ('windows_per_epoch', 'batch_windows'):
        _check(pos_int(m[key]), f'multistep.{key}', m[key], 'must be an integer >= 1')
    _check(m['units'] in LOSS_UNITS, 'multistep.units', m['units'], f'must be one of {", ".join(LOSS_UNITS)}')
    vw = m['velocity_weight']
    _check(
        isinstance(vw, (int, float)) and not isinstance(vw, bool) and math.isfinite(vw) and vw > 0,
        'multistep.velocity_weight',
        vw,
        'must be a number > 0 (1: position and velocity weigh alike)',
    )
    cw = m['consensus_weight']
    _check(
        isinstance(cw, (int, float)) and not isinstance(cw, bool) and math.isfinite(cw) and cw >= 0,
        'multistep.consensus_weight',
        cw,
        'must be a number >= 0 (0: off)',
    )
    _check(
        cw == 0 or get_scenario(cfg['scenario']).command == 'acceleration',
        'multistep.consensus_weight',
        cw,
        "weighs velocities relative to the swarm's mean: acceleration scenarios (flock2d) only",
    )
    _check(
        isinstance(m['checkpoint'], int) and m['checkpoint'] >= 0,
        'multistep.checkpoint',
        m['checkpoint'],
        'must be an integer >= 0 (0: no activation checkpointing)',
    )
    if t['objective'] == 'multi_step':
        # the curriculum fixes the epoch count; a different explicit training.epochs is a contradiction
        total = sum(m['epochs'])
        given = (raw.get('training') or {}).get('epochs')
        _check(
            given is None or given == total,
            'training.epochs',
            given,
            f'the multi_step curriculum (multistep.epochs) trains {total} epochs',
        )
        t['epochs'] = total


def load_config(path: str, overrides: Optional[Dict[str, Any]] = None) -> Dict[str, Any]:
    """Read a YAML config, apply ``{"section.key": value}`` overrides, validate."""
    import yaml

    if not os.path.isfile(path):
        raise ConfigError(f'config file {path}: no such file')
    with open(path) as fh:
        try:
            raw = yaml.safe_load(fh) or {}
        except (yaml.YAMLError, ValueError, RecursionError) as exc:  # integers of > 4300 digits, deep nesting
            raise ConfigError(f'config file {path}: not valid YAML ({exc})') from None
    if not isinstance(raw, dict):
        raise ConfigError(f'config file {path}: must be a mapping of sections, got {type(raw).__name__}')
    raw = copy.deepcopy(raw)
    for dotted, value in (overrides or {}).items():
        node = raw
        *parents, leaf = dotted.split('.')
        for depth, key in enumerate(parents):
            node = node.setdefault(key, {})
            if not isinstance(node, dict):
                where = '.'.join(parents[: depth + 1])
                raise ConfigError(f'--set {dotted}: {where} is {node!r}, not a section')
        node[leaf] = value
    try:
        return normalise_config(raw)
    except ConfigError as exc:
        # a field set on the command line is reported there, not as an error of the file
        blamed = [key for key in overrides or {} if f"'{key}'" in str(exc)]
        if blamed:
            raise ConfigError(f'--set {blamed[0]}={overrides[blamed[0]]}: {exc}') from None
        raise ConfigError(f'config file {path}: {exc}') from None


def build_policy(cfg: Dict[str, Any]) -> KNODEPolicy:
    return KNODEPolicy(PolicyConfig(cfg['scenario'], **cfg['policy']))
