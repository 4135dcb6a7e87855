"""Shared pieces of training and evaluation: configs, samples, the one-step-ahead loss, scores.

Shapes: N trajectories, T frames, n robots, d state entries, k neighbour rows, m command
entries, M = samples (one per trajectory, frame t < T - 1 and robot).

The model is always :class:`knode_swarm_ros.core.KNODEPolicy`: the trained module is the
exported one. Neighbour matrices come from the core's batched builder
:func:`knode_swarm_ros.core.neighbour_matrices`, so training sees exactly what a robot sees.
"""
from __future__ import annotations

import copy
import json
import math
import os
import subprocess
from dataclasses import dataclass, fields
from typing import Any, Dict, Optional, Tuple

import numpy as np
import torch
from torch import Tensor, nn

from knode_swarm_ros.core import (DEFAULTS, KNODEPolicy, PolicyConfig, amd, avd, get_scenario, neighbour_matrices,
                                  pod_kld, rollout)
from knode_swarm_ros.core.scenarios import Scenario
from knode_swarm_ros.core.rollout import heading_torch, zoh_step_torch


# A training config is invalid; the message names the field (one class with the nodes').
from knode_swarm_ros.core.errors import ConfigError  # noqa: E402


# ----------------------------------------------------------------------------- configs

# Every config section with its defaults; ``None`` means "scenario dependent" (filled below).
DEFAULT_CONFIG: Dict[str, Dict[str, Any]] = {
    "data": {"train_trajectories": None, "val_trajectories": 4, "frames": None, "stride": 1,
             "drop_saturated": True, "policy_dt": None},
    "noise": {"mode": "inputs", "variance": None},
    "training": {"solver": "zoh", "ode_method": "rk4", "epochs": 60, "batch_size": 4096, "lr": 3e-3,
                 "lr_schedule": "cosine", "lr_min": 1e-4, "weight_decay": 0.0, "loss_units": "command",
                 "heading_weight": 1.0, "grad_clip": 10.0, "diverge_factor": 1000.0, "max_param": 1.0e5, "threads": 1,
                 "max_minutes": None, "objective": "one_step"},
    # the multi_step objective (training/multistep.py): curriculum of horizons, from a one-step model
    "multistep": {"init": None, "horizons": [10, 50, 200], "epochs": [2, 2, 2], "windows_per_epoch": 256,
                  "batch_windows": 16, "units": "command", "checkpoint": 0},
    "selection": {"every": 5, "trajectories": 4, "steps": None},
    "augment": {"rotate": False, "velocity_boost": 0.0},
}
NOISE_VARIANCE = {"flock2d": 0.001, "boids3d": 0.01}
SOLVERS = ("zoh", "rk4", "adjoint")
NOISE_MODES = ("inputs", "observations", "none")
SCHEDULES = ("cosine", "step", "none")
LOSS_UNITS = ("command", "state")
OBJECTIVES = ("one_step", "multi_step")
POLICY_FIELDS = {f.name for f in fields(PolicyConfig)} - {"scenario", "extra"}


def _check(cond: bool, field: str, value: Any, why: str) -> None:
    if not cond:
        raise ConfigError(f"config field {field!r} = {value!r}: {why}")


def normalise_config(raw: Dict[str, Any]) -> Dict[str, Any]:
    """Fill defaults and validate a training config; raises :class:`ConfigError` naming the field.

    Layout: ``scenario``, ``seed``, ``policy`` (PolicyConfig fields; defaults are the paper's
    ``DEFAULTS[scenario]``), ``data``, ``noise``, ``training``, ``selection``.
    """
    if not isinstance(raw, dict):
        raise ConfigError(f"config must be a mapping, got {type(raw).__name__}")
    known_top = {"scenario", "seed", "policy", "name", *DEFAULT_CONFIG}
    for key in raw:
        _check(key in known_top, key, raw[key], f"unknown top-level field; known: {', '.join(sorted(known_top))}")
    _check("scenario" in raw, "scenario", None, "required (flock2d or boids3d)")
    scenario = raw["scenario"]
    try:
        get_scenario(scenario)
    except ValueError as exc:
        raise ConfigError(f"config field 'scenario' = {scenario!r}: {exc}") from None
    cfg: Dict[str, Any] = {"scenario": scenario, "seed": raw.get("seed", 0), "name": raw.get("name", scenario)}
    _check(isinstance(cfg["seed"], int) and not isinstance(cfg["seed"], bool), "seed", cfg["seed"], "must be an integer")

    policy = dict(DEFAULTS[scenario])
    given = raw.get("policy") or {}
    _check(isinstance(given, dict), "policy", given, "must be a mapping")
    for key, value in given.items():
        _check(key in POLICY_FIELDS, f"policy.{key}", value, f"unknown; known: {', '.join(sorted(POLICY_FIELDS))}")
        policy[key] = value
    try:
        PolicyConfig(scenario, **policy)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"config field 'policy': {exc}") from None
    cfg["policy"] = policy

    for section, defaults in DEFAULT_CONFIG.items():
        given = raw.get(section) or {}
        _check(isinstance(given, dict), section, given, "must be a mapping")
        merged = dict(defaults)
        for key, value in given.items():
            _check(key in defaults, f"{section}.{key}", value, f"unknown; known: {', '.join(sorted(defaults))}")
            merged[key] = value
        cfg[section] = merged
    if cfg["noise"]["variance"] is None:
        cfg["noise"]["variance"] = NOISE_VARIANCE[scenario]

    t, d, n, s = cfg["training"], cfg["data"], cfg["noise"], cfg["selection"]

    def num(v):
        return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)

    def pos_int(v):
        return isinstance(v, int) and not isinstance(v, bool) and v >= 1

    _check(t["solver"] in SOLVERS, "training.solver", t["solver"], f"must be one of {', '.join(SOLVERS)}")
    _check(t["ode_method"] in ("rk4", "euler", "midpoint", "dopri5"), "training.ode_method", t["ode_method"],
           "must be rk4, euler, midpoint or dopri5")
    _check(pos_int(t["epochs"]), "training.epochs", t["epochs"], "must be an integer >= 1")
    _check(pos_int(t["batch_size"]) or t["batch_size"] == "full", "training.batch_size", t["batch_size"],
           "must be an integer >= 1 or 'full'")
    _check(num(t["lr"]) and t["lr"] > 0, "training.lr", t["lr"], "must be a positive number")
    _check(num(t["lr_min"]) and t["lr_min"] >= 0, "training.lr_min", t["lr_min"], "must be >= 0")
    _check(t["lr_schedule"] in SCHEDULES, "training.lr_schedule", t["lr_schedule"], f"must be one of {', '.join(SCHEDULES)}")
    _check(num(t["weight_decay"]) and t["weight_decay"] >= 0, "training.weight_decay", t["weight_decay"], "must be >= 0")
    _check(t["loss_units"] in LOSS_UNITS, "training.loss_units", t["loss_units"], f"must be one of {', '.join(LOSS_UNITS)}")
    _check(num(t["heading_weight"]) and t["heading_weight"] >= 0, "training.heading_weight", t["heading_weight"], "must be >= 0")
    _check(t["grad_clip"] is None or (num(t["grad_clip"]) and t["grad_clip"] > 0), "training.grad_clip",
           t["grad_clip"], "must be null or a positive number")
    _check(num(t["diverge_factor"]) and t["diverge_factor"] > 1, "training.diverge_factor", t["diverge_factor"], "must be > 1")
    _check(num(t["max_param"]) and t["max_param"] > 0, "training.max_param", t["max_param"], "must be > 0")
    _check(pos_int(t["threads"]), "training.threads", t["threads"], "must be an integer >= 1")
    _check(t["max_minutes"] is None or (num(t["max_minutes"]) and t["max_minutes"] > 0), "training.max_minutes",
           t["max_minutes"], "must be null or a positive number")
    _check(d["train_trajectories"] is None or pos_int(d["train_trajectories"]), "data.train_trajectories",
           d["train_trajectories"], "must be null or an integer >= 1")
    _check(isinstance(d["val_trajectories"], int) and d["val_trajectories"] >= 0, "data.val_trajectories",
           d["val_trajectories"], "must be an integer >= 0")
    _check(d["frames"] is None or (pos_int(d["frames"]) and d["frames"] >= 2), "data.frames", d["frames"],
           "must be null or an integer >= 2")
    _check(pos_int(d["stride"]), "data.stride", d["stride"], "must be an integer >= 1")
    _check(isinstance(d["drop_saturated"], bool), "data.drop_saturated", d["drop_saturated"], "must be true or false")
    _check(d["policy_dt"] is None or (num(d["policy_dt"]) and d["policy_dt"] > 0), "data.policy_dt", d["policy_dt"],
           "must be null (the data's dt) or a positive multiple of the data's dt in seconds")
    _check(n["mode"] in NOISE_MODES, "noise.mode", n["mode"], f"must be one of {', '.join(NOISE_MODES)}")
    _check(num(n["variance"]) and n["variance"] >= 0, "noise.variance", n["variance"], "must be >= 0")
    a = cfg["augment"]
    spec = get_scenario(scenario)
    _check(isinstance(a["rotate"], bool), "augment.rotate", a["rotate"], "must be true or false")
    _check(not a["rotate"] or spec.name == "flock2d", "augment.rotate", a["rotate"],
           "random rotations are a symmetry of flock2d only (boids3d has walls)")
    _check(num(a["velocity_boost"]) and a["velocity_boost"] >= 0, "augment.velocity_boost", a["velocity_boost"],
           "must be a number >= 0")
    _check(a["velocity_boost"] == 0 or spec.command == "acceleration", "augment.velocity_boost",
           a["velocity_boost"], "Galilean boosts are a symmetry of flock2d only")
    _check(isinstance(s["every"], int) and s["every"] >= 0, "selection.every", s["every"], "must be an integer >= 0 (0 = off)")
    _check(pos_int(s["trajectories"]), "selection.trajectories", s["trajectories"], "must be an integer >= 1")
    _check(s["steps"] is None or pos_int(s["steps"]), "selection.steps", s["steps"], "must be null or an integer >= 1")
    _check_multistep(cfg, raw, pos_int)
    return cfg


def _check_multistep(cfg: Dict[str, Any], raw: Dict[str, Any], pos_int) -> None:
    t, m = cfg["training"], cfg["multistep"]
    _check(t["objective"] in OBJECTIVES, "training.objective", t["objective"], f"must be one of {', '.join(OBJECTIVES)}")
    _check(m["init"] is None or isinstance(m["init"], str), "multistep.init", m["init"],
           "must be null or the path of a policy file or run directory")
    for key in ("horizons", "epochs"):
        _check(isinstance(m[key], list) and len(m[key]) >= 1 and all(pos_int(v) for v in m[key]),
               f"multistep.{key}", m[key], "must be a non-empty list of integers >= 1")
    _check(len(m["horizons"]) == len(m["epochs"]), "multistep.epochs", m["epochs"],
           f"needs one entry per horizon ({len(m['horizons'])})")
    for key in ("windows_per_epoch", "batch_windows"):
        _check(pos_int(m[key]), f"multistep.{key}", m[key], "must be an integer >= 1")
    _check(m["units"] in LOSS_UNITS, "multistep.units", m["units"], f"must be one of {', '.join(LOSS_UNITS)}")
    _check(isinstance(m["checkpoint"], int) and m["checkpoint"] >= 0, "multistep.checkpoint", m["checkpoint"],
           "must be an integer >= 0 (0: no activation checkpointing)")
    if t["objective"] == "multi_step":
        # the curriculum fixes the epoch count; a different explicit training.epochs is a contradiction
        total = sum(m["epochs"])
        given = (raw.get("training") or {}).get("epochs")
        _check(given is None or given == total, "training.epochs", given,
               f"the multi_step curriculum (multistep.epochs) trains {total} epochs")
        t["epochs"] = total


def load_config(path: str, overrides: Optional[Dict[str, Any]] = None) -> Dict[str, Any]:
    """Read a YAML config, apply ``{"section.key": value}`` overrides, validate."""
    import yaml
    if not os.path.isfile(path):
        raise ConfigError(f"config file {path}: no such file")
    with open(path) as fh:
        try:
            raw = yaml.safe_load(fh) or {}
        except yaml.YAMLError as exc:
            raise ConfigError(f"config file {path}: not valid YAML ({exc})") from None
    raw = copy.deepcopy(raw)
    for dotted, value in (overrides or {}).items():
        node = raw
        *parents, leaf = dotted.split(".")
        for key in parents:
            node = node.setdefault(key, {})
        node[leaf] = value
    try:
        return normalise_config(raw)
    except ConfigError as exc:
        raise ConfigError(f"config file {path}: {exc}") from None


def build_policy(cfg: Dict[str, Any]) -> KNODEPolicy:
    return KNODEPolicy(PolicyConfig(cfg["scenario"], **cfg["policy"]))


def git_commit(cwd: Optional[str] = None) -> Optional[str]:
    """The current git commit (with ``-dirty`` when the tree has changes), or None."""
    try:
        sha = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, cwd=cwd,
                             timeout=5, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], capture_output=True,
                               text=True, cwd=cwd, timeout=5).stdout.strip()
        return sha + ("-dirty" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        return None


# ----------------------------------------------------------------------------- samples

@dataclass
class Samples:
    """One-step-ahead training pairs: the robot's neighbour matrix at t and its own state at t + 1.

    ``Y [M, k, d]`` float32 (row 0 = own state at t), ``mask [M, k]`` float32,
    ``target [M, d]`` float32 (own state at t + 1), ``clean_own [M, d]`` own state at t
    without observation noise (equal to ``Y[:, 0]`` unless noise mode is ``observations``).
    """

    Y: Tensor
    mask: Tensor
    target: Tensor
    clean_own: Tensor

    def __len__(self) -> int:
        return self.Y.shape[0]

    def subset(self, keep: Tensor) -> "Samples":
        return Samples(self.Y[keep], self.mask[keep], self.target[keep], self.clean_own[keep])


def implied_command(own: Tensor, target: Tensor, spec: Scenario, dt: float) -> Tensor:
    """The command ``[M, m]`` that a zero-order hold needs to go from ``own`` to ``target``
    (acceleration: velocity change / dt; velocity: displacement / dt)."""
    p = spec.position_dim
    if spec.command == "acceleration":
        return (target[:, p:] - own[:, p:]) / dt
    return (target[:, :p] - own[:, :p]) / dt


def make_samples(states: np.ndarray, spec: Scenario, d_cr: float, k: int, tau: int, stride: int = 1,
                 obs_noise_std: float = 0.0, rng: Optional[np.random.Generator] = None, ratio: int = 1) -> Samples:
    """Build samples from trajectories ``[N, T, n, d]`` (T >= ratio + 1) with the core's batched builder.

    ``obs_noise_std`` > 0 adds Gaussian noise to the observed trajectories once (the paper's
    noisy observations): inputs and targets both see it. ``stride`` keeps every stride-th
    frame as a start state. ``ratio`` (policy dt / data dt, see :mod:`training.period`): the
    target of start frame t is frame t + ratio and the delay ``tau`` (policy steps) is
    ``tau * ratio`` frames, so the pairs are observations at the policy's period taken at
    every phase of the data (``stride = ratio`` keeps one phase).
    """
    states = np.asarray(states, dtype=np.float64)
    if states.ndim != 4 or states.shape[1] < ratio + 1:
        raise ValueError(f"need trajectories [N, T >= {ratio + 1}, n, d], got {states.shape}")
    clean = states
    if obs_noise_std > 0:
        rng = rng or np.random.default_rng(0)
        states = states + rng.normal(0.0, obs_noise_std, size=states.shape)
    Y, mask = neighbour_matrices(states, spec.position_dim, d_cr, k, tau * ratio)   # [N, T, n, k, d]
    starts = np.arange(0, states.shape[1] - ratio, stride)
    d = states.shape[-1]
    Ys = Y[:, starts].reshape(-1, k, d)
    ms = mask[:, starts].reshape(-1, k)
    target = states[:, starts + ratio].reshape(-1, d)
    own = clean[:, starts].reshape(-1, d)
    f32 = lambda a: torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32))  # noqa: E731
    return Samples(f32(Ys), f32(ms), f32(target), f32(own))


def augment_batch(Y: Tensor, mask: Tensor, own: Tensor, target: Tensor, spec: Scenario, dt: float,
                  rotate: bool, boost_std: float, g: Optional[torch.Generator]):
    """Apply symmetries of the flock2d ground truth to a batch of samples.

    ``rotate``: one random planar rotation per sample of every position and velocity (Tanner's
    law is rotation invariant); ``boost_std``: one Gaussian velocity offset per sample added to
    every velocity (Galilean invariance: only velocity differences enter), with the target
    position shifted by offset * dt. The implied command rotates with the sample and is
    unchanged by the boost, so the augmented pairs are exact observations of the same law.
    """
    B, p = Y.shape[0], spec.position_dim
    if rotate:
        theta = torch.rand(B, generator=g) * (2 * math.pi)
        c, s = torch.cos(theta), torch.sin(theta)
        R = torch.stack([torch.stack([c, -s], -1), torch.stack([s, c], -1)], -2)      # [B, 2, 2]

        def rot(z):  # z [B, ..., d] with 2D position and velocity blocks
            shape = z.shape
            blocks = z.reshape(B, -1, 2, 2)                                             # [B, rows, block, xy]
            return torch.einsum("bij,brkj->brki", R, blocks).reshape(shape)
        Y, own, target = rot(Y), rot(own), rot(target)
    if boost_std > 0:
        b = torch.randn(B, p, generator=g) * boost_std
        Y = torch.cat([Y[..., :p], Y[..., p:] + b[:, None, :] * mask.unsqueeze(-1)], dim=-1)
        own = torch.cat([own[:, :p], own[:, p:] + b], dim=1)
        target = torch.cat([target[:, :p] + b * dt, target[:, p:] + b], dim=1)
    return Y, own, target


# ----------------------------------------------------------------------------- one-step prediction

class HeldNeighbourField(nn.Module):
    """Hybrid vector field of one robot over one step, neighbours held at their observed rows.

    ``forward(t, z [B, d]) -> dz/dt``: the own row of Y follows z (plus its input noise),
    the neighbour rows stay fixed. Double integrator: (v, u); first order: (u, 0) (the
    heading is set from the displacement after the step).
    """

    def __init__(self, policy: KNODEPolicy, spec: Scenario, Y: Tensor, mask: Tensor, own_noise: Optional[Tensor]):
        super().__init__()
        self.policy = policy
        self.spec = spec
        self.Y_rest = Y[:, 1:]
        self.mask = mask
        self.own_noise = own_noise
        self.nfe = 0

    def forward(self, t: Tensor, z: Tensor) -> Tensor:
        self.nfe += 1
        own = z if self.own_noise is None else z + self.own_noise
        u = self.policy(torch.cat([own.unsqueeze(1), self.Y_rest], dim=1), self.mask)
        p = self.spec.position_dim
        if self.spec.command == "acceleration":
            return torch.cat([z[:, p:], u], dim=1)
        return torch.cat([u, torch.zeros_like(z[:, p:])], dim=1)


def predict_next(policy: KNODEPolicy, spec: Scenario, dt: float, Y: Tensor, mask: Tensor, own: Tensor,
                 solver: str = "zoh", ode_method: str = "rk4", input_noise: Optional[Tensor] = None) -> Tensor:
    """Predicted own state at t + dt ``[B, d]`` from neighbour matrices ``Y [B, k, d]``.

    Args:
        own: ``[B, d]`` the state the prediction starts from (the observed own state).
        solver: ``zoh`` (exact zero-order hold of the command at t: what deployment does),
            ``rk4`` (direct backprop through ``torchdiffeq.odeint`` of the held-neighbour field),
            ``adjoint`` (``torchdiffeq.odeint_adjoint`` of the same field, the paper's gradient).
        input_noise: optional ``[B, k, d]`` noise added to the policy's input only.
    """
    Yin = Y if input_noise is None else Y + input_noise * mask.unsqueeze(-1)
    if solver == "zoh":
        return zoh_step_torch(own, policy(Yin, mask), spec, dt)
    import torchdiffeq
    own_noise = None if input_noise is None else input_noise[:, 0]
    field = HeldNeighbourField(policy, spec, Yin, mask, own_noise)
    t = torch.tensor([0.0, dt], dtype=Y.dtype)
    options = {"step_size": dt} if ode_method != "dopri5" else {}
    kwargs = dict(method=ode_method, options=options)
    if ode_method == "dopri5":
        kwargs.update(rtol=1e-6, atol=1e-8)
    if solver == "adjoint":
        z1 = torchdiffeq.odeint_adjoint(field, own, t, adjoint_params=tuple(policy.parameters()), **kwargs)[-1]
    else:
        z1 = torchdiffeq.odeint(field, own, t, **kwargs)[-1]
    if spec.command == "velocity":
        p = spec.position_dim
        z1 = torch.cat([z1[:, :p], heading_torch(z1[:, :p] - own[:, :p], own[:, p:])], dim=1)
    return z1


def loss_scales(spec: Scenario, dt: float, units: str, heading_weight: float = 1.0) -> Tensor:
    """Per-entry divisors ``[d]`` of the one-step error.

    ``state``: the paper's plain state MSE (all ones). ``command``: the error expressed in
    command units (acceleration: position / (dt^2 / 2), velocity / dt; velocity command:
    position / dt, heading scaled by 1 / sqrt(heading_weight)), which makes the loss read
    as the squared error of the implied command and keeps numbers O(1) in float32.
    """
    p, d = spec.position_dim, spec.state_dim
    if units == "state":
        return torch.ones(d)
    if spec.command == "acceleration":
        return torch.tensor([0.5 * dt * dt] * p + [dt] * (d - p))
    hw = 1.0 / math.sqrt(heading_weight) if heading_weight > 0 else float("inf")
    return torch.tensor([dt] * p + [hw] * (d - p))


def one_step_loss(pred: Tensor, target: Tensor, scales: Tensor) -> Tensor:
    """Mean over samples and entries of ((pred - target) / scales)^2."""
    return (((pred - target) / scales) ** 2).mean()


# ----------------------------------------------------------------------------- rollout scores

def module_policy_fn(module: nn.Module):
    """Wrap a torch module as the numpy policy callable that :func:`core.rollout` expects."""
    def fn(Y: np.ndarray, mask: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            out = module(torch.as_tensor(Y, dtype=torch.float32), torch.as_tensor(mask, dtype=torch.float32))
        return out.numpy().astype(np.float64)
    return fn


def min_pair_distance(positions: np.ndarray) -> np.ndarray:
    """Smallest pairwise distance ``[...]`` of ``positions [..., n, p]``."""
    diff = positions[..., :, None, :] - positions[..., None, :, :]
    dist = np.sqrt((diff ** 2).sum(-1))
    n = positions.shape[-2]
    dist[..., np.arange(n), np.arange(n)] = np.inf
    return dist.min(axis=(-1, -2))


def final_metrics(spec: Scenario, pred: np.ndarray, truth: Optional[np.ndarray] = None, last: int = 10,
                  settle_s: float = 1.0, dt: Optional[float] = None) -> Dict[str, Any]:
    """Headline metrics of rollouts ``pred [S, T, n, d]`` (and ground truth of the same shape).

    flock2d: final avd and amd (mean over the last ``last`` frames), min pair distance after
    ``settle_s``; boids3d: final amd, POD-KLD per trajectory (needs ``truth``), fraction of
    frames inside the cube, whether each trajectory stays inside.
    """
    dt = spec.dt if dt is None else dt
    p = spec.position
    out: Dict[str, Any] = {}
    amd_pred = amd(pred[:, -last:, :, p]).mean(axis=1)
    out["amd_final"] = amd_pred.tolist()
    settle = min(int(round(settle_s / dt)), pred.shape[1] - 1)
    out["min_distance"] = min_pair_distance(pred[:, settle:, :, p]).min(axis=1).tolist()
    if spec.velocity is not None:
        out["avd_final"] = avd(pred[:, -last:, :, spec.velocity]).mean(axis=1).tolist()
    if spec.box is not None:
        inside = np.all(np.abs(pred[..., p]) <= spec.box + 1e-9, axis=(-1, -2))     # [S, T]
        out["stays_inside"] = inside.all(axis=1).tolist()
    if truth is not None:
        out["truth_amd_final"] = amd(truth[:, -last:, :, p]).mean(axis=1).tolist()
        out["truth_min_distance"] = min_pair_distance(truth[:, settle:, :, p]).min(axis=1).tolist()
        if spec.velocity is not None:
            out["truth_avd_final"] = avd(truth[:, -last:, :, spec.velocity]).mean(axis=1).tolist()
        if spec.name == "boids3d":
            out["pod_kld"] = [pod_kld(truth[s], pred[s]) for s in range(pred.shape[0])]
    return out


def selection_score(spec: Scenario, m: Dict[str, Any]) -> float:
    """Scalar for model selection by rollouts (lower is better).

    flock2d: mean final avd + relative amd error + 1 per rollout with a collision (< 0.3);
    boids3d: relative amd error + mean POD-KLD + fraction of rollouts leaving the cube.
    Non-finite metrics give +inf.
    """
    amd_rel = abs(np.mean(m["amd_final"]) - np.mean(m["truth_amd_final"])) / max(np.mean(m["truth_amd_final"]), 1e-9)
    if spec.name == "flock2d":
        score = np.mean(m["avd_final"]) + amd_rel + float(np.sum(np.array(m["min_distance"]) < 0.3))
    else:
        score = amd_rel + np.mean(m["pod_kld"]) + 1.0 - np.mean(m["stays_inside"])
    return float(score) if np.isfinite(score) else float("inf")


def rollout_module(module: nn.Module, spec: Scenario, z0: np.ndarray, steps: int, cfg_policy: Dict[str, Any],
                   dt: float) -> np.ndarray:
    """Roll a (not yet exported) policy module out with the canonical :func:`core.rollout`."""
    with np.errstate(all="ignore"):
        return rollout(module_policy_fn(module), z0, steps, spec.name, cfg_policy["d_cr"], cfg_policy["k"],
                       cfg_policy["tau"], dt)


def write_json(path: str, obj: Any) -> None:
    from knode_swarm_ros.core.trajectory import atomic_write

    def write(tmp):
        with open(tmp, "w") as fh:
            json.dump(obj, fh, indent=2, sort_keys=True, default=_json_default)
            fh.write("\n")
    atomic_write(path, write)


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def mean_ci(x: np.ndarray, axis: int = 0) -> Tuple[np.ndarray, np.ndarray]:
    """Mean and 95% confidence half-width (normal approximation) along ``axis``."""
    x = np.asarray(x, dtype=np.float64)
    n = x.shape[axis]
    mean = x.mean(axis=axis)
    half = 1.96 * x.std(axis=axis, ddof=1) / np.sqrt(n) if n > 1 else np.zeros_like(mean)
    return mean, half
