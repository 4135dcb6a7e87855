"""Policy files: export a controller to TorchScript and load any valid policy file.

A policy file is one TorchScript archive whose ``forward(Y [B, k, d], mask [B, k]) -> [B, m]``
returns the command, with ``knode.json`` metadata in its extra files (docs/DESIGN.md,
"Policy file contract"). The loader checks everything a robot relies on before the first
real call, so a bad file fails at start with a message naming the field, never deep
inside torch in the control loop.
"""

from __future__ import annotations

import json
import os
import warnings
from dataclasses import dataclass
from typing import Any, Dict, Optional, Union

import numpy as np
import torch

from .policy_meta import (
    BOUNDS,
    FORMAT,
    REQUIRED_KEYS,
    PolicyError,
    check_meta,
    parse_meta,
    shipped_policy_path,
)
from .policy_runtime import PolicyView
from .trajectory import atomic_write

__all__ = [
    'PolicyError',
    'LoadedPolicy',
    'export_policy',
    'load_policy',
    'shipped_policy_path',
    'REQUIRED_KEYS',
    'FORMAT',
    'BOUNDS',
]

PathLike = Union[str, os.PathLike]
# One definition of the metadata contract (torch-free, shared with the onnxruntime path).
_check_meta = check_meta


@dataclass
class LoadedPolicy(PolicyView):
    """A validated policy: the TorchScript module and its metadata.

    Call it with numpy or torch ``Y [B, k, d]`` and ``mask [B, k]``; it returns a float64
    numpy ``[B, m]`` command (evaluated in float32, as the contract fixes).
    """

    module: torch.jit.ScriptModule
    meta: Dict[str, Any]
    path: str

    backend = 'torchscript'

    def __call__(self, Y, mask) -> np.ndarray:
        Yt = torch.as_tensor(np.asarray(Y), dtype=torch.float32)
        mt = torch.as_tensor(np.asarray(mask), dtype=torch.float32)
        with torch.no_grad():
            return self.module(Yt, mt).numpy().astype(np.float64)


def _with_jit_quiet(fn, *args, **kwargs):
    # TorchScript is deprecated upstream but remains this project's deployment format.
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', DeprecationWarning)
        warnings.simplefilter('ignore', FutureWarning)
        return fn(*args, **kwargs)


def export_policy(policy: torch.nn.Module, path: PathLike, meta: Dict[str, Any]) -> None:
    """Script ``policy`` and write it with ``knode.json`` = ``meta`` atomically.

    ``meta`` must hold the required keys (``KNODEPolicy.metadata()`` does); the written file
    is loaded back and validated before it replaces ``path``, and the scripted module must compute
    what ``policy`` does (:func:`_check_same_code`).
    """
    _check_meta(str(path), meta)
    was_training = policy.training
    policy.eval()
    try:
        scripted = _with_jit_quiet(torch.jit.script, policy)
        _check_same_code(f'policy file {os.fspath(path)}', policy, scripted, meta)
    finally:
        policy.train(was_training)
    extra = {'knode.json': json.dumps(meta, sort_keys=True)}

    def write(tmp):
        _with_jit_quiet(torch.jit.save, scripted, tmp, _extra_files=extra)
        load_policy(tmp)

    atomic_write(path, write)


def _check_same_code(where: str, policy: torch.nn.Module, scripted, meta: Dict[str, Any]) -> None:
    """The scripted module computes what ``policy`` does, on a random batch. ``torch.jit.script``
    compiles the classes' source as it is on disk when called, not as it was when ``policy`` was
    built: a file edited or upgraded during a long training would otherwise export other code
    than the one that trained, silently."""
    k, d = int(meta['k']), int(meta['state_dim'])
    g = torch.Generator().manual_seed(0)
    Y = torch.randn(8, k, d, generator=g)
    mask = (torch.rand(8, k, generator=g) < 0.7).to(torch.float32)
    mask[:, 0] = 1.0
    with torch.no_grad():
        want, got = policy(Y, mask), scripted(Y, mask)
    if not torch.allclose(got, want, rtol=1e-4, atol=1e-5, equal_nan=True):
        gap = float((got - want).abs().max())
        raise PolicyError(
            f'{where}: the scripted module differs from the module it was made from (by up to {gap:.3g} '
            'on a random batch): has its source changed on disk since it was built? Nothing was written'
        )


def _probe(where: str, module, meta: Dict[str, Any]) -> None:
    """One forward call on a dummy batch: catches wrong signatures and output shapes."""
    k, d, m = int(meta['k']), int(meta['state_dim']), int(meta['command_dim'])
    Y = torch.zeros(2, k, d)
    Y[1, 0, 0] = 1.0
    mask = torch.zeros(2, k)
    mask[:, 0] = 1.0
    try:
        with torch.no_grad():
            out = module(Y, mask)
    except Exception as exc:  # TorchScript raises many types; report them all the same way
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise PolicyError(f'{where}: forward(Y[2, {k}, {d}], mask[2, {k}]) failed: {first}') from None
    if not isinstance(out, torch.Tensor) or tuple(out.shape) != (2, m):
        shape = tuple(out.shape) if isinstance(out, torch.Tensor) else type(out).__name__
        raise PolicyError(f'{where}: forward returned {shape}, expected a tensor of shape (2, {m})')
    if out.dtype != torch.float32:
        raise PolicyError(f'{where}: forward returned dtype {out.dtype}, expected torch.float32')
    if not torch.all(torch.isfinite(out)):
        raise PolicyError(f'{where}: forward returned non-finite commands on a dummy batch')


def load_policy(path: PathLike, expect: Optional[Dict[str, Any]] = None) -> LoadedPolicy:
    """Load and validate a policy file.

    Args:
        path: the TorchScript file.
        expect: optional required metadata values, e.g. ``{"scenario": "flock2d", "k": 6}``;
            a mismatch raises :class:`PolicyError` naming the key and both values.

    Raises:
        PolicyError: missing file, not a TorchScript archive, missing or invalid ``knode.json``,
            a forward that fails or returns the wrong shape.
    """
    where = f'policy file {os.fspath(path)}'
    if not os.path.isfile(path):
        raise PolicyError(f'{where}: no such file')
    extra = {'knode.json': ''}
    try:
        module = _with_jit_quiet(torch.jit.load, os.fspath(path), map_location='cpu', _extra_files=extra)
    except Exception as exc:  # torch reports corrupt archives with RuntimeError and friends
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise PolicyError(f'{where}: not a readable TorchScript archive ({first})') from None
    if not extra['knode.json']:
        raise PolicyError(f"{where}: no knode.json metadata in the archive's extra files")
    meta = parse_meta(where, extra['knode.json'])
    _check_meta(where, meta, expect)
    module.eval()
    _probe(where, module, meta)
    return LoadedPolicy(module, meta, os.fspath(path))
