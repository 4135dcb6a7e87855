"""Export a TorchScript policy file to its ONNX twin and check the twin against it (the library
behind ``python -m training.export_onnx`` and the export at the end of training).

The TorchScript module is exported with the TorchScript-based exporter (``torch.onnx.export(...,
dynamo=False)``), inputs ``Y [batch, k, d]`` and ``mask [batch, k]`` with a dynamic batch, output
``u [batch, m]``; the model's metadata carries the same ``knode.json`` text and the SHA-256 of the
``.pt``. The twin is run on onnxruntime against the TorchScript module on :func:`check_inputs`
before anything is written; a command further than ``tol`` from TorchScript's writes nothing.
"""

from __future__ import annotations

import io
import json
import os
import warnings
from pathlib import Path
from typing import Dict, Optional, Tuple

import numpy as np
import torch

from knode_swarm_ros.core import PolicyError, get_scenario, load_policy, neighbour_matrices
from knode_swarm_ros.core.policy_runtime import (
    META_KEY,
    SOURCE_KEY,
    file_sha256,
    load_onnx_policy,
    onnx_twin_path,
)
from knode_swarm_ros.core.trajectory import atomic_write

__all__ = ['export_onnx', 'check_inputs', 'compare', 'OPSET', 'TOLERANCE']

OPSET = 17
TOLERANCE = 1e-5


def check_inputs(meta: Dict, seed: int = 0) -> Dict[str, Tuple[np.ndarray, np.ndarray]]:
    """Named batches ``(Y [B, k, d] float32, mask [B, k] float32)`` the twin must match on."""
    spec = get_scenario(meta['scenario'])
    k, d, p = int(meta['k']), spec.state_dim, spec.position_dim
    rng = np.random.default_rng(seed)

    def finish(Y, mask):
        Y = np.asarray(Y, np.float64)
        if spec.heading is not None:  # headings are unit vectors
            h = Y[..., spec.heading]
            Y[..., spec.heading] = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-9)
        mask = np.asarray(mask, np.float32)
        return (Y * mask[..., None]).astype(np.float32), mask

    B = 64
    scale = 2.0 * float(meta['d_cr'])
    out = {}
    mask = (rng.random((B, k)) < 0.6).astype(np.float32)
    mask[:, 0] = 1
    out['random'] = finish(rng.normal(0, scale, (B, k, d)), mask)
    empty = np.zeros((B, k), np.float32)
    empty[:, 0] = 1
    out['empty neighbourhoods'] = finish(rng.normal(0, scale, (B, k, d)), empty)
    near = rng.normal(0, 0.3 * float(meta['d_cr']), (B, k, d))
    out['full rows'] = finish(near, np.ones((B, k), np.float32))
    coincident = rng.normal(0, 1, (B, k, d))
    coincident[:, 1:, :p] = coincident[:, :1, :p]  # every neighbour on top of the robot
    coincident[B // 2 :, 1:, :p] += rng.normal(0, 1e-4, (B - B // 2, k - 1, p))
    out['coincident robots'] = finish(coincident, np.ones((B, k), np.float32))
    if spec.box is not None:
        walls = rng.normal(0, 1, (B, k, d))
        faces = rng.uniform(spec.box - 1.5, spec.box + 0.5, (B, p)) * rng.choice([-1, 1], (B, p))
        walls[:, 0, :p] = faces  # near, on and beyond the walls
        out['walls'] = finish(walls, (rng.random((B, k)) < 0.5) | (np.arange(k) == 0))
    if spec.shipped:
        from knode_swarm_ros.core.groundtruth import simulate

        states = simulate(spec.name, 2, 12, 40, seed, progress=False)
    else:  # no ground truth law: random swarms at the policy's neighbour range
        states = rng.normal(0, 0.5 * float(meta['d_cr']), (2, 40, 12, d))
        if spec.heading is not None:
            h = states[..., spec.heading]
            states[..., spec.heading] = h / np.linalg.norm(h, axis=-1, keepdims=True)
    Y, mask = neighbour_matrices(states, p, float(meta['d_cr']), k, int(meta['tau']))
    out['real swarms'] = (Y.reshape(-1, k, d).astype(np.float32), mask.reshape(-1, k).astype(np.float32))
    return out


def compare(reference, twin, inputs: Dict[str, Tuple[np.ndarray, np.ndarray]]) -> Dict[str, float]:
    """Largest relative-above-1 difference ``|a - b| / max(1, |a|)`` per named batch."""
    errors = {}
    for name, (Y, mask) in inputs.items():
        a, b = reference(Y, mask), twin(Y, mask)
        errors[name] = float(np.max(np.abs(a - b) / np.maximum(1.0, np.abs(a)), initial=0.0))
    return errors


def export_onnx(
    pt_path, out: Optional[os.PathLike] = None, tol: float = TOLERANCE, seed: int = 0
) -> Tuple[Path, Dict[str, float]]:
    """Write the ONNX twin of the policy file ``pt_path``; returns (path, errors per batch).

    Raises:
        PolicyError: the policy file is invalid, the export fails, or the twin differs from
            the TorchScript module by more than ``tol`` (then nothing is written).
    """
    import onnx  # export only: a robot reads metadata through onnxruntime

    policy = load_policy(pt_path)
    out = Path(out) if out is not None else onnx_twin_path(pt_path)
    where = f'policy file {os.fspath(pt_path)}'
    k, d = policy.k, int(policy.meta['state_dim'])
    example = (torch.zeros(2, k, d), torch.ones(2, k))
    buffer = io.BytesIO()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')  # TorchScript/exporter deprecation notices
            torch.onnx.export(
                policy.module,
                example,
                buffer,
                input_names=['Y', 'mask'],
                output_names=['u'],
                dynamic_axes={'Y': {0: 'batch'}, 'mask': {0: 'batch'}, 'u': {0: 'batch'}},
                opset_version=OPSET,
                dynamo=False,
            )
    except Exception as exc:  # the exporter raises many types for unsupported graphs
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise PolicyError(f'{where}: ONNX export failed: {first}') from None
    model = onnx.load_from_string(buffer.getvalue())
    del model.metadata_props[:]
    for key, value in (
        (META_KEY, json.dumps(policy.meta, sort_keys=True)),
        (SOURCE_KEY, file_sha256(pt_path)),
    ):
        entry = model.metadata_props.add()
        entry.key, entry.value = key, value
    model.producer_name = 'knode_swarm_ros training.export_onnx'
    onnx.checker.check_model(model)
    errors: Dict[str, float] = {}

    def write(tmp):
        onnx.save(model, tmp)
        twin = load_onnx_policy(tmp, pt_path=pt_path)
        errors.update(compare(policy, twin, check_inputs(policy.meta, seed)))
        worst = max(errors, key=errors.get)
        if errors[worst] > tol:
            raise PolicyError(
                f'{where}: the ONNX export differs from the TorchScript module by {errors[worst]:.3g} '
                f'> {tol:g} on {worst!r} inputs; {out} not written'
            )

    atomic_write(out, write)
    return out, errors
