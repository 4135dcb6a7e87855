"""Policy files: export a controller to TorchScript and load any valid policy file.

A policy file is one TorchScript archive whose ``forward(Y [B, k, d], mask [B, k]) -> [B, m]``
returns the command, with ``knode.json`` metadata in its extra files (DESIGN.md,
"Policy file contract"). The loader checks everything a robot relies on before the first
real call, so a bad file fails at start with a message naming the field, never deep
inside torch in the control loop.
"""
from __future__ import annotations

import json
import math
import os
import warnings
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any, Dict, Optional, Union

import numpy as np
import torch

from .scenarios import SCENARIOS, get_scenario
from .trajectory import atomic_write

__all__ = ["PolicyError", "LoadedPolicy", "export_policy", "load_policy", "shipped_policy_path",
           "REQUIRED_KEYS", "FORMAT", "BOUNDS"]

FORMAT = "knode-policy/1"
REQUIRED_KEYS = ("format", "scenario", "state_dim", "command_dim", "command", "k", "d_cr", "tau",
                 "dt", "state_layout")
PathLike = Union[str, os.PathLike]

#: Allowed ranges of the numeric knode.json keys (inclusive; d_cr and command_limit exclude 0).
#: Every robot builds and evaluates tensors and buffers from these numbers before checking
#: anything else, so a file must not be able to ask for absurd sizes (k = 10**9 allocates 32 GB
#: in the first forward call) or times that break the stamp arithmetic (dt = 1e-300).
BOUNDS = {"k": (1, 1024), "tau": (0, 10_000), "d_cr": (0.0, 1e6), "dt": (1e-6, 3600.0),
          "command_limit": (0.0, 1e9)}
_WHY = {"k": "rows of Y: the robot plus at most 1023 neighbours; Y [B, k, d] is built every step",
        "tau": "delay in steps: every robot buffers 4 tau + 8 states of every robot",
        "d_cr": "communication radius in metres",
        "dt": "seconds per step: stamps are integer nanoseconds, so a step spans at least 1000 ns; "
              "at most an hour",
        "command_limit": "per-axis saturation of the command"}


class PolicyError(ValueError):
    """A policy file is missing, corrupt or does not match what the caller needs."""


@dataclass
class LoadedPolicy:
    """A validated policy: the TorchScript module and its metadata.

    Call it with numpy or torch ``Y [B, k, d]`` and ``mask [B, k]``; it returns a float64
    numpy ``[B, m]`` command (evaluated in float32, as the contract fixes).
    """

    module: torch.jit.ScriptModule
    meta: Dict[str, Any]
    path: str

    @property
    def k(self) -> int:
        return int(self.meta["k"])

    @property
    def d_cr(self) -> float:
        return float(self.meta["d_cr"])

    @property
    def tau(self) -> int:
        return int(self.meta["tau"])

    @property
    def dt(self) -> float:
        return float(self.meta["dt"])

    @property
    def scenario(self) -> str:
        return str(self.meta["scenario"])

    @property
    def command_limit(self) -> Optional[float]:
        limit = self.meta.get("command_limit")
        return None if limit is None else float(limit)

    def __call__(self, Y, mask) -> np.ndarray:
        Yt = torch.as_tensor(np.asarray(Y), dtype=torch.float32)
        mt = torch.as_tensor(np.asarray(mask), dtype=torch.float32)
        with torch.no_grad():
            return self.module(Yt, mt).numpy().astype(np.float64)


def _with_jit_quiet(fn, *args, **kwargs):
    # TorchScript is deprecated upstream but remains this project's deployment format.
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        warnings.simplefilter("ignore", FutureWarning)
        return fn(*args, **kwargs)


def export_policy(policy: torch.nn.Module, path: PathLike, meta: Dict[str, Any]) -> None:
    """Script ``policy`` and write it with ``knode.json`` = ``meta`` atomically.

    ``meta`` must hold the required keys (``KNODEPolicy.metadata()`` does); the written file
    is loaded back and validated before it replaces ``path``.
    """
    _check_meta(str(path), meta)
    was_training = policy.training
    policy.eval()
    try:
        scripted = _with_jit_quiet(torch.jit.script, policy)
    finally:
        policy.train(was_training)
    extra = {"knode.json": json.dumps(meta, sort_keys=True)}

    def write(tmp):
        _with_jit_quiet(torch.jit.save, scripted, tmp, _extra_files=extra)
        load_policy(tmp)

    atomic_write(path, write)


def _check_meta(where: str, meta: Any, expect: Optional[Dict[str, Any]] = None) -> None:
    if not isinstance(meta, dict):
        raise PolicyError(f"{where}: knode.json must be a JSON object, got {type(meta).__name__}")
    missing = [key for key in REQUIRED_KEYS if key not in meta]
    if missing:
        raise PolicyError(f"{where}: knode.json lacks required key(s) {', '.join(missing)}")
    for key in ("format", "scenario", "command"):
        if not isinstance(meta[key], str):
            raise PolicyError(f"{where}: knode.json key {key!r} must be a string, got {meta[key]!r}")
    if meta["format"] != FORMAT:
        raise PolicyError(f"{where}: knode.json key 'format' is {meta['format']!r}, expected {FORMAT!r}")
    if meta["scenario"] not in SCENARIOS:
        raise PolicyError(f"{where}: knode.json key 'scenario' is {meta['scenario']!r}; "
                          f"known: {', '.join(sorted(SCENARIOS))}")
    spec = get_scenario(meta["scenario"])
    wanted = {"state_dim": spec.state_dim, "command_dim": spec.command_dim, "command": spec.command,
              "state_layout": list(spec.state_layout)}
    for key, value in wanted.items():
        got = list(meta[key]) if key == "state_layout" and isinstance(meta[key], (list, tuple)) else meta[key]
        if got != value:
            raise PolicyError(f"{where}: knode.json key {key!r} is {meta[key]!r}, "
                              f"scenario {spec.name} needs {value!r}")

    def is_int(v):
        return isinstance(v, int) and not isinstance(v, bool)

    def is_num(v):
        return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)

    numeric = {"k": is_int(meta["k"]) and BOUNDS["k"][0] <= meta["k"] <= BOUNDS["k"][1],
               "tau": is_int(meta["tau"]) and BOUNDS["tau"][0] <= meta["tau"] <= BOUNDS["tau"][1],
               "d_cr": is_num(meta["d_cr"]) and BOUNDS["d_cr"][0] < meta["d_cr"] <= BOUNDS["d_cr"][1],
               "dt": is_num(meta["dt"]) and BOUNDS["dt"][0] <= meta["dt"] <= BOUNDS["dt"][1]}
    if "command_limit" in meta and meta["command_limit"] is not None:
        numeric["command_limit"] = is_num(meta["command_limit"]) and \
            BOUNDS["command_limit"][0] < meta["command_limit"] <= BOUNDS["command_limit"][1]
    for key, ok in numeric.items():
        if not ok:
            low, high = BOUNDS[key]
            raise PolicyError(f"{where}: knode.json key {key!r} has invalid value {meta[key]!r} "
                              f"(allowed: {low:g} .. {high:g}; {_WHY[key]})")
    for key, value in (expect or {}).items():
        if value is None:
            continue
        got = meta.get(key)
        same = math.isclose(float(got), float(value), rel_tol=1e-9) if is_num(got) and is_num(value) else got == value
        if not same:
            raise PolicyError(f"{where}: knode.json key {key!r} is {got!r} but {value!r} was required")


def _probe(where: str, module, meta: Dict[str, Any]) -> None:
    """One forward call on a dummy batch: catches wrong signatures and output shapes."""
    k, d, m = int(meta["k"]), int(meta["state_dim"]), int(meta["command_dim"])
    Y = torch.zeros(2, k, d)
    Y[1, 0, 0] = 1.0
    mask = torch.zeros(2, k)
    mask[:, 0] = 1.0
    try:
        with torch.no_grad():
            out = module(Y, mask)
    except Exception as exc:  # TorchScript raises many types; report them all the same way
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise PolicyError(f"{where}: forward(Y[2, {k}, {d}], mask[2, {k}]) failed: {first}") from None
    if not isinstance(out, torch.Tensor) or tuple(out.shape) != (2, m):
        shape = tuple(out.shape) if isinstance(out, torch.Tensor) else type(out).__name__
        raise PolicyError(f"{where}: forward returned {shape}, expected a tensor of shape (2, {m})")
    if out.dtype != torch.float32:
        raise PolicyError(f"{where}: forward returned dtype {out.dtype}, expected torch.float32")
    if not torch.all(torch.isfinite(out)):
        raise PolicyError(f"{where}: forward returned non-finite commands on a dummy batch")


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
    where = f"policy file {os.fspath(path)}"
    if not os.path.isfile(path):
        raise PolicyError(f"{where}: no such file")
    extra = {"knode.json": ""}
    try:
        module = _with_jit_quiet(torch.jit.load, os.fspath(path), map_location="cpu", _extra_files=extra)
    except Exception as exc:  # torch reports corrupt archives with RuntimeError and friends
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise PolicyError(f"{where}: not a readable TorchScript archive ({first})") from None
    text = extra["knode.json"]
    if isinstance(text, bytes):
        text = text.decode("utf-8", errors="replace")
    if not text:
        raise PolicyError(f"{where}: no knode.json metadata in the archive's extra files")
    try:
        meta = json.loads(text)
    except json.JSONDecodeError as exc:
        raise PolicyError(f"{where}: knode.json is not valid JSON ({exc})") from None
    _check_meta(where, meta, expect)
    module.eval()
    _probe(where, module, meta)
    return LoadedPolicy(module, meta, os.fspath(path))


def shipped_policy_path(name: str) -> Path:
    """Path of a policy shipped inside the package (``policies/<name>.pt``)."""
    ref = resources.files("knode_swarm_ros") / "policies" / f"{name}.pt"
    if not ref.is_file():
        raise PolicyError(f"no shipped policy named {name!r} (looked for {ref})")
    return Path(str(ref))
