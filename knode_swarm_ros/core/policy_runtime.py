"""One small interface for evaluating a policy, with two backends.

* ``torchscript``: :class:`knode_swarm_ros.core.policy_io.LoadedPolicy` (the contract and the
  training artefact; imports torch).
* ``onnxruntime``: :class:`OnnxPolicy`, the ONNX twin ``POLICY.onnx`` beside ``POLICY.pt``
  (docs/DESIGN.md, "ONNX twin"). Nothing on this path imports torch: the knowledge terms and the
  policy's own saturation are in the exported graph, the metadata checks are
  :mod:`.policy_meta`'s and the inputs are numpy.

Both are called the same way, for one robot (B = 1) or many hosted robots at once:
``policy(Y [B, k, d], mask [B, k]) -> [B, m]`` float64 numpy (evaluated in float32), and both
carry ``meta`` (knode.json), ``path``, ``backend`` and the ``k``, ``d_cr``, ``tau``, ``dt``,
``scenario`` and ``command_limit`` properties. :func:`load_runtime` picks one:
``auto`` is onnxruntime when the twin exists and onnxruntime is installed, else TorchScript.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path
from typing import Any, Dict, Optional, Union

import numpy as np

from .errors import first_line
from .policy_meta import PolicyError, check_meta, parse_meta, read_pt_meta
from .scenarios import scenario_ref

__all__ = [
    'RUNTIMES',
    'OnnxPolicy',
    'PolicyView',
    'load_onnx_policy',
    'load_runtime',
    'onnx_twin_path',
    'file_sha256',
    'META_KEY',
    'SOURCE_KEY',
]

RUNTIMES = ('auto', 'torchscript', 'onnxruntime')
#: ONNX model metadata keys: the knode.json text, and the SHA-256 of the .pt it was exported from.
META_KEY = 'knode.json'
SOURCE_KEY = 'knode.source_sha256'
PathLike = Union[str, os.PathLike]
_INSTALL = 'pip install -r requirements-robot.txt (onnxruntime==1.32.0)'


class PolicyView:
    """The knode.json values a caller needs, as properties of a ``meta`` dict attribute."""

    meta: Dict[str, Any]

    @property
    def k(self) -> int:
        return int(self.meta['k'])

    @property
    def d_cr(self) -> float:
        return float(self.meta['d_cr'])

    @property
    def tau(self) -> int:
        return int(self.meta['tau'])

    @property
    def dt(self) -> float:
        return float(self.meta['dt'])

    @property
    def scenario(self) -> str:
        """The scenario's reference (:func:`~.scenarios.scenario_ref`): its name if shipped."""
        return scenario_ref(self.meta['scenario'])

    @property
    def command_limit(self) -> Optional[float]:
        limit = self.meta.get('command_limit')
        return None if limit is None else float(limit)


class OnnxPolicy(PolicyView):
    """A validated ONNX twin on an onnxruntime session (see the module doc)."""

    backend = 'onnxruntime'

    def __init__(self, session, meta: Dict[str, Any], path: str):
        self.session = session
        self.meta = meta
        self.path = path
        self._output = session.get_outputs()[0].name

    def __call__(self, Y, mask) -> np.ndarray:
        """Commands ``[B, m]`` float64 for ``Y [B, k, d]`` and ``mask [B, k]`` (any real dtype)."""
        feed = {
            'Y': np.ascontiguousarray(Y, dtype=np.float32),
            'mask': np.ascontiguousarray(mask, dtype=np.float32),
        }
        return self.session.run([self._output], feed)[0].astype(np.float64)


def onnx_twin_path(path: PathLike) -> Path:
    """``POLICY.onnx`` for ``POLICY.pt`` (the twin lies beside the TorchScript file)."""
    return Path(path).with_suffix('.onnx')


def file_sha256(path: PathLike) -> str:
    with open(path, 'rb') as fh:
        return hashlib.sha256(fh.read()).hexdigest()


def _import_onnxruntime():
    try:
        import onnxruntime
    except ImportError:
        return None
    return onnxruntime


def _check_signature(where: str, session, meta: Dict[str, Any]) -> None:
    k, d, m = int(meta['k']), int(meta['state_dim']), int(meta['command_dim'])
    inputs = {i.name: i.shape for i in session.get_inputs()}
    want = {'Y': [None, k, d], 'mask': [None, k]}
    if sorted(inputs) != sorted(want):
        raise PolicyError(f"{where}: inputs are {sorted(inputs)}, expected ['Y', 'mask']")
    for name, shape in want.items():
        got = inputs[name]
        # Dimensions are ints when fixed, strings (or None) when dynamic; the batch must be dynamic.
        fixed = [None if not isinstance(s, int) else s for s in got]
        if (
            len(got) != len(shape)
            or fixed[0] is not None
            or any(g is not None and g != s for g, s in zip(fixed[1:], shape[1:]))
        ):
            raise PolicyError(
                f'{where}: input {name} has shape {got}, knode.json needs [batch, '
                f'{", ".join(str(s) for s in shape[1:])}] (k = {k}, state_dim = {d})'
            )
    outputs = session.get_outputs()
    if len(outputs) != 1:
        raise PolicyError(f'{where}: {len(outputs)} outputs, expected one [batch, {m}] command')
    # The probe (same dummy batch as the TorchScript loader's) checks shape, dtype, finiteness.
    Y = np.zeros((2, k, d), np.float32)
    Y[1, 0, 0] = 1.0
    mask = np.zeros((2, k), np.float32)
    mask[:, 0] = 1.0
    try:
        out = session.run(None, {'Y': Y, 'mask': mask})[0]
    except Exception as exc:  # onnxruntime raises its own exception types
        raise PolicyError(
            f'{where}: running Y[2, {k}, {d}], mask[2, {k}] failed: {first_line(exc)}'
        ) from None
    if out.shape != (2, m) or out.dtype != np.float32:
        raise PolicyError(f'{where}: returned {out.dtype} {out.shape}, expected float32 (2, {m})')
    if not np.all(np.isfinite(out)):
        raise PolicyError(f'{where}: returned non-finite commands on a dummy batch')


def _check_twin(where: str, meta: Dict[str, Any], source: Optional[str], pt_path: Path) -> None:
    """The twin must carry its .pt's knode.json and come from that very file (no stale twin)."""
    pt_meta = read_pt_meta(pt_path)
    if pt_meta != meta:
        keys = sorted(k for k in set(pt_meta) | set(meta) if pt_meta.get(k) != meta.get(k))
        raise PolicyError(
            f'{where}: knode.json differs from that of its TorchScript policy {pt_path} '
            f'(key(s) {", ".join(keys)}): re-export it with python -m training.export_onnx {pt_path}'
        )
    if source is not None and source != file_sha256(pt_path):
        raise PolicyError(
            f'{where}: was exported from another version of {pt_path} (SHA-256 differs): '
            f're-export it with python -m training.export_onnx {pt_path}'
        )


def load_onnx_policy(
    path: PathLike,
    expect: Optional[Dict[str, Any]] = None,
    threads: int = 1,
    pt_path: Optional[PathLike] = None,
) -> OnnxPolicy:
    """Load and validate an ONNX policy (twin) without torch.

    Args:
        path: the ``.onnx`` file.
        expect: required knode.json values, as for :func:`load_policy`.
        threads: onnxruntime intra-op threads.
        pt_path: its TorchScript policy, when present: the twin must match it (knode.json and
            the recorded SHA-256 of the ``.pt``).

    Raises:
        PolicyError: onnxruntime missing, file missing or corrupt, knode.json missing, invalid
            or unlike the ``.pt``'s, wrong inputs or outputs; the message names the file.
    """
    where = f'ONNX policy file {os.fspath(path)}'
    ort = _import_onnxruntime()
    if ort is None:
        raise PolicyError(
            f'{where}: policy_runtime onnxruntime needs the onnxruntime package, which is not '
            f'installed ({_INSTALL}); or use policy_runtime torchscript'
        )
    if not os.path.isfile(path):
        raise PolicyError(f'{where}: no such file')
    options = ort.SessionOptions()
    options.intra_op_num_threads = int(threads)
    options.inter_op_num_threads = 1
    options.log_severity_level = 3  # errors only: the loader reports problems itself
    try:
        session = ort.InferenceSession(os.fspath(path), options, providers=['CPUExecutionProvider'])
    except Exception as exc:  # onnxruntime reports corrupt models with several exception types
        raise PolicyError(f'{where}: not a readable ONNX model ({first_line(exc)})') from None
    custom = session.get_modelmeta().custom_metadata_map
    if META_KEY not in custom:
        raise PolicyError(
            f"{where}: no {META_KEY} in the model's metadata (export it with "
            f'python -m training.export_onnx POLICY.pt)'
        )
    meta = parse_meta(where, custom[META_KEY])
    check_meta(where, meta, expect)
    if pt_path is not None:
        _check_twin(where, meta, custom.get(SOURCE_KEY), Path(pt_path))
    _check_signature(where, session, meta)
    return OnnxPolicy(session, meta, os.fspath(path))


def load_runtime(
    path: PathLike,
    runtime: str = 'auto',
    expect: Optional[Dict[str, Any]] = None,
    threads: Optional[int] = None,
):
    """Load the policy ``path`` (``.pt`` or ``.onnx``) on the backend ``runtime`` names.

    Args:
        path: ``POLICY.pt`` (its twin ``POLICY.onnx`` is found beside it) or ``POLICY.onnx``.
        runtime: ``auto`` (onnxruntime when the twin exists and onnxruntime is installed, else
            TorchScript), ``torchscript`` or ``onnxruntime``.
        expect: required knode.json values.
        threads: intra-op threads of the backend (None: leave torch's setting alone; 1 for onnxruntime).

    Returns:
        an :class:`OnnxPolicy` or a :class:`knode_swarm_ros.core.LoadedPolicy`.
    """
    if runtime not in RUNTIMES:
        raise PolicyError(f'policy_runtime {runtime!r} is not one of {", ".join(RUNTIMES)}')
    path = Path(path)
    if path.suffix == '.onnx':
        if runtime == 'torchscript':
            raise PolicyError(
                f'policy file {path}: policy_runtime torchscript needs the TorchScript .pt '
                f'file, not its ONNX twin'
            )
        pt = path.with_suffix('.pt')
        return load_onnx_policy(path, expect, threads or 1, pt if pt.is_file() else None)
    twin = onnx_twin_path(path)
    pt = path if path.is_file() else None
    if runtime == 'onnxruntime':
        if not twin.is_file():
            raise PolicyError(
                f'policy file {path}: policy_runtime onnxruntime needs its ONNX twin {twin}, '
                f'which does not exist (python -m training.export_onnx {path})'
            )
        return load_onnx_policy(twin, expect, threads or 1, pt)
    if runtime == 'auto' and twin.is_file() and (pt is None or _import_onnxruntime() is not None):
        return load_onnx_policy(twin, expect, threads or 1, pt)
    try:
        import torch

        from .policy_io import load_policy
    except ImportError as exc:
        raise PolicyError(
            f'policy file {path}: the TorchScript runtime needs torch ({exc}); install it '
            f'or run the ONNX twin (python -m training.export_onnx {path}, then '
            f'policy_runtime onnxruntime)'
        ) from None
    if threads is not None:
        torch.set_num_threads(int(threads))
    return load_policy(path, expect)
