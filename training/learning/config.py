"""The training config: its schema and defaults, validation naming the field, loading YAML with overrides.

A config has ``scenario``, ``seed``, ``name``, ``policy`` (PolicyConfig fields; defaults are the
paper's ``DEFAULTS[scenario]``) and the sections of :data:`DEFAULT_CONFIG`.
"""

from __future__ import annotations

import copy
import math
import os
from dataclasses import dataclass, fields
from typing import Any, Dict, List, Optional, Sequence, Union

from knode_swarm_ros.core import DEFAULTS, KNODEPolicy, PolicyConfig, get_scenario

# A training config is invalid; the message names the field (one class with the nodes').
from knode_swarm_ros.core.errors import ConfigError
from knode_swarm_ros.core.scenarios import Scenario, scenario_ref
from knode_swarm_ros.core.yaml_file import load_yaml

from .derive import AUTO, auto_fields
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
    'selection': {
        'every': 5,
        'trajectories': 4,
        'steps': None,
        'rollouts': 1,
        'perturb': 1.0e-3,
        'confirm': 0,
        'confirm_trajectories': 8,
    },
    'augment': {'rotate': False, 'velocity_boost': 0.0},
}
NOISE_VARIANCE = {'flock2d': 0.001, 'boids3d': 0.01}
# A scenario of your own starts from these (train_custom.yaml derives most of them from the data).
GENERIC_NOISE_VARIANCE = 0.0


def policy_defaults(spec: Scenario) -> Dict[str, Any]:
    """The policy fields' defaults: the paper's for a shipped scenario, else generic ones
    (walls only with an arena)."""
    if spec.shipped:
        return dict(DEFAULTS[spec.name])
    return dict(
        k=6,
        d_cr=5.0,
        tau=0,
        command_limit=10.0,
        collision_a=0.0,
        collision_phi=1.0,
        collision_d0=1.0,
        wall=spec.arena is not None,
        wall_a=0.0,
        wall_phi=1.0,
        wall_d0=1.0,
    )


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
    try:
        spec = get_scenario(raw['scenario'])
    except ValueError as exc:
        raise ConfigError(f"config field 'scenario' = {raw['scenario']!r}: {exc}") from None
    # the canonical reference (a shipped name, else the whole scenario): what the data files carry
    scenario = scenario_ref(spec)
    cfg: Dict[str, Any] = {
        'scenario': scenario,
        'seed': raw.get('seed', 0),
        'name': raw.get('name', spec.name),
    }
    _check(
        isinstance(cfg['seed'], int) and not isinstance(cfg['seed'], bool),
        'seed',
        cfg['seed'],
        'must be an integer',
    )

    policy = policy_defaults(spec)
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
        cfg['noise']['variance'] = NOISE_VARIANCE.get(scenario, GENERIC_NOISE_VARIANCE)

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
    _check(isinstance(a['rotate'], bool), 'augment.rotate', a['rotate'], 'must be true or false')
    _check(
        not a['rotate'] or spec.arena is None,
        'augment.rotate',
        a['rotate'],
        f"random rotations break the symmetry of the scenario's walls (scenario {spec.name}, "
        f"field 'arena' = {spec.to_dict()['arena']})",
    )
    _check(
        not a['rotate']
        or cfg['training']['objective'] != 'multi_step'
        or (spec.dimensions == 2 and spec.state == 'position_velocity'),
        'augment.rotate',
        a['rotate'],
        'the multi_step objective rotates 2D position_velocity windows only',
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
        f"Galilean boosts shift velocities, which scenario {spec.name}'s state has not "
        f"(field 'state' = {spec.state!r})",
    )
    _check(
        a['velocity_boost'] == 0 or spec.arena is None,
        'augment.velocity_boost',
        a['velocity_boost'],
        f"Galilean boosts break the symmetry of the scenario's walls (scenario {spec.name}, field 'arena')",
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
        isinstance(s['confirm'], int) and not isinstance(s['confirm'], bool) and s['confirm'] >= 0,
        'selection.confirm',
        s['confirm'],
        'must be an integer >= 0 (0 or 1 = no confirm stage)',
    )
    _check(
        s['confirm_trajectories'] is None or pos_int(s['confirm_trajectories']),
        'selection.confirm_trajectories',
        s['confirm_trajectories'],
        'must be null (all) or an integer >= 1',
    )
    _check(
        num(s['perturb']) and s['perturb'] >= 0, 'selection.perturb', s['perturb'], 'must be a number >= 0'
    )
    _check_multistep(cfg, raw, pos_int)
    return cfg


def _check_multistep(cfg: Dict[str, Any], raw: Dict[str, Any], pos_int) -> None:
    t, m = cfg['training'], cfg['multistep']
    _check(
        isinstance(t['objective'], str) and t['objective'] in OBJECTIVES,  # a list is no key of it
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


@dataclass
class PendingConfig:
    """A config with fields the data decide: ``scenario: auto`` (the data file's scenario) or
    ``auto`` fields (:data:`training.learning.derive.DERIVED_FIELDS`). Everything else was
    validated on load; :func:`resolve_config` completes it once the data are read."""

    raw: Dict[str, Any]
    auto: List[str]
    where: str = 'config'


#: Policy fields whose valid values depend on the scenario's state or dimensions: with
#: ``scenario: auto`` they are checked once the data's scenario is known, not against a stand-in.
SCENARIO_FIELDS = ('policy.speed', 'policy.turn_limit', 'policy.symmetric', 'policy.inversion')


def _placeholders(raw: Dict[str, Any], scenario: Any, unchecked: Sequence[str] = ()) -> Dict[str, Any]:
    """``raw`` with ``scenario`` and every ``auto`` field (and those ``unchecked``) replaced by its
    default, for validation."""
    out = copy.deepcopy(raw)
    out['scenario'] = scenario
    for dotted in set(auto_fields(raw)) | set(unchecked):
        section, key = dotted.split('.')
        if isinstance(out.get(section), dict):
            out[section].pop(key, None)
    return out


def resolve_config(pending: PendingConfig, trajectories, scenario: str, dt: float):
    """The complete config of ``pending`` for data of ``scenario`` (a reference) whose train
    trajectories are ``trajectories`` (one ``[N, T, n, d]`` array per file, at the data's ``dt``).

    Returns ``(cfg, derived)``; ``derived`` maps each derived field to its value and how it was
    derived (:func:`training.learning.derive.derive`). Raises :class:`ConfigError` naming the field.
    """
    from .derive import derive
    from .period import period_ratio, policy_dt, subsample

    raw = pending.raw
    if raw.get('scenario') not in (AUTO, None):
        given = scenario_ref(get_scenario(raw['scenario']))
        if given != scenario:
            raise ConfigError(
                f"{pending.where}: field 'scenario' is {given!r} but the data's scenario is {scenario!r} "
                "(use 'scenario: auto' to take the data's)"
            )
    try:
        cfg = normalise_config(_placeholders(raw, scenario))
        ratio = period_ratio(dt, cfg['data']['policy_dt'])
        cfg, derived = derive(
            cfg,
            pending.auto,
            [subsample(t, ratio) for t in trajectories],
            get_scenario(scenario),
            policy_dt(dt, ratio),
        )
        return normalise_config(cfg), derived
    except ConfigError as exc:
        raise ConfigError(f'{pending.where}: {exc}') from None
    except ValueError as exc:
        raise ConfigError(f'{pending.where}: config field {exc}') from None


def complete_config(pending: PendingConfig, data_paths: List[str]):
    """:func:`resolve_config` from trajectory files: the first file's scenario and dt, every
    file's train split. Returns ``(cfg, derived)``."""
    from knode_swarm_ros.core import load_trajectories

    files = [load_trajectories(path) for path in data_paths]
    trajectories = [f.states[f.split('train')] for f in files]
    return resolve_config(pending, trajectories, files[0].scenario, float(files[0].dt))


def load_config(
    path: str, overrides: Optional[Dict[str, Any]] = None
) -> Union[Dict[str, Any], PendingConfig]:
    """Read a YAML config, apply ``{"section.key": value}`` overrides, validate.

    A config with ``scenario: auto`` or ``auto`` fields gives a :class:`PendingConfig` (the
    trainer completes it from the data); any other gives the normalised config."""
    import yaml

    if not os.path.isfile(path):
        raise ConfigError(f'config file {path}: no such file')
    with open(path) as fh:
        try:
            raw = load_yaml(fh) or {}
        except yaml.YAMLError as exc:
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
        auto = auto_fields(raw)
        if raw.get('scenario') == AUTO or auto:
            # validate what is given now; the scenario-dependent checks run again once resolved
            scenario = raw.get('scenario')
            if scenario == AUTO:
                normalise_config(_placeholders(raw, 'flock2d', SCENARIO_FIELDS))
            else:
                normalise_config(_placeholders(raw, scenario))
            return PendingConfig(raw, auto, f'config file {path}')
        return normalise_config(raw)
    except ConfigError as exc:
        # a field set on the command line is reported there, not as an error of the file
        blamed = [key for key in overrides or {} if f"'{key}'" in str(exc)]
        if blamed:
            raise ConfigError(f'--set {blamed[0]}={overrides[blamed[0]]}: {exc}') from None
        raise ConfigError(f'config file {path}: {exc}') from None


def build_policy(cfg: Dict[str, Any]) -> KNODEPolicy:
    return KNODEPolicy(PolicyConfig(cfg['scenario'], **cfg['policy']))
