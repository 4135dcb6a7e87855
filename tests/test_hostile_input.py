"""Bad files give a clear error naming the file and the field, exit
status 2, never a traceback; every policy field is bounded by what a policy can sensibly be."""

import json
import subprocess
import sys
import warnings

import numpy as np
import pytest
import torch

from knode_swarm_ros.core import (
    DEFAULTS,
    KNODEPolicy,
    PolicyConfig,
    PolicyError,
    TrajectoryError,
    export_policy,
    load_policy,
    load_trajectories,
    save_trajectories,
)


@pytest.fixture
def good(tmp_path):
    torch.manual_seed(0)
    policy = KNODEPolicy(PolicyConfig('flock2d', **DEFAULTS['flock2d']))
    path = tmp_path / 'good.pt'
    export_policy(policy, path, policy.metadata())
    return policy, path


def _with_meta(tmp_path, policy, **changes):
    meta = policy.metadata()
    meta.update(changes)
    path = tmp_path / 'bad.pt'
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        torch.jit.save(torch.jit.script(policy), str(path), _extra_files={'knode.json': json.dumps(meta)})
    return path


@pytest.mark.parametrize(
    'key,value',
    [
        ('scenario', ['flock2d']),
        ('scenario', {'name': 'flock2d'}),
        ('format', ['knode-policy/1']),
        ('command', {'a': 1}),
        # item 9: unbounded sizes and times
        ('k', 10**9),
        ('tau', 10**9),
        ('dt', 1e-300),
        ('dt', 1e9),
        ('d_cr', 1e300),
        ('command_limit', 1e300),
    ],
)
def test_policy_metadata_of_the_wrong_type_or_size_is_refused_naming_the_key(tmp_path, good, key, value):
    path = _with_meta(tmp_path, good[0], **{key: value})
    with pytest.raises(PolicyError) as err:
        load_policy(path)
    assert f"'{key}'" in str(err.value) and str(path) in str(err.value)


def test_bounds_still_accept_the_shipped_kind_of_policy(tmp_path, good):
    path = _with_meta(tmp_path, good[0], k=6, tau=100, dt=1.0 / 60.0, d_cr=50.0)
    assert load_policy(path).tau == 100


def _npz(path, **fields):
    base = dict(
        states=np.zeros((1, 3, 2, 4)), dt=np.float64(0.01), scenario=np.str_('flock2d'), meta=np.str_('{}')
    )
    base.update(fields)
    with open(path, 'wb') as fh:
        np.savez(fh, **base)
    return path


@pytest.mark.parametrize(
    'field,value',
    [
        ('dt', np.array([0.01, 0.02])),
        ('dt', np.str_('fast')),
        ('scenario', np.array(['flock2d', 'boids3d'])),
        ('scenario', np.float64(3.0)),
        ('meta', np.str_('[1, 2]')),
        ('meta', np.str_('"text"')),
        ('meta', np.array(['{}', '{}'])),
    ],
)
def test_trajectory_fields_of_the_wrong_type_are_refused_naming_the_field(tmp_path, field, value):
    path = _npz(tmp_path / 'bad.npz', **{field: value})
    with pytest.raises(TrajectoryError) as err:
        load_trajectories(path)
    assert f"'{field}'" in str(err.value) and str(path) in str(err.value)


def test_rollout_cli_refuses_an_array_dt_with_status_2_and_keeps_its_output(tmp_path, good):
    bad = _npz(tmp_path / 'bad.npz', dt=np.array([0.01, 0.02]))
    out = tmp_path / 'out.npz'
    save_trajectories(out, np.ones((1, 2, 2, 4)), 0.01, 'flock2d', {'keep': True})
    before = out.read_bytes()
    proc = subprocess.run(
        [
            sys.executable,
            '-m',
            'training.rollout',
            '--policy',
            str(good[1]),
            '--init',
            str(bad),
            '--steps',
            '3',
            '--out',
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 2, proc.stderr
    assert "'dt'" in proc.stderr and 'bad.npz' in proc.stderr and 'Traceback' not in proc.stderr
    assert out.read_bytes() == before
