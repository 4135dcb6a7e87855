"""The training loop behind ``python -m training.train`` and ``training.grid``: data split, epochs,
checkpoints, model selection by rollouts, export of the policy and its ONNX twin.

One :class:`Trainer` per run directory; see :mod:`training.train` for the files it writes and
:mod:`training.learning.config` for the config it takes. Shapes as in :mod:`training.learning.samples`.
"""

from __future__ import annotations

import copy
import json
import math
import os
import sys
import time
from typing import Any, Dict, List, Optional, Tuple

import numpy as np
import torch
import yaml

from knode_swarm_ros.core import PolicyError, export_policy, get_scenario, load_trajectories
from knode_swarm_ros.core.errors import KnodeError, RunError
from knode_swarm_ros.core.policy import ROW_FREE_ENCODERS
from knode_swarm_ros.core.trajectory import atomic_write

from .config import ConfigError, PendingConfig, build_policy, complete_config
from .derive import size_caveat
from .objectives import TrainingData, make_objective
from .objectives.one_step import OneStepObjective
from .period import period_ratio, policy_dt
from .records import code_provenance, data_reference, write_json
from .samples import concat_samples, implied_command, make_samples
from .selection import Candidates, confirm_truths, rollout_metrics, selection_truths

#: Seconds between progress lines within an epoch when the output is not a terminal.
PROGRESS_EVERY_S = 60.0


class DivergenceError(RunError, RuntimeError):
    """Training diverged (NaN or exploding loss); ``training.train`` exits 3 (documented there)."""

    exit_status = 3

    def __str__(self) -> str:
        return f'training diverged: {super().__str__()}'


class DataError(KnodeError, ValueError):
    """The data file does not fit the config."""


def held_out_count(cfg: Dict[str, Any], available: int) -> int:
    """How many of ``available`` train-split trajectories validation holds out (whole trajectories).

    ``data.val_trajectories`` (a count) when set and below ``available``, else
    ``round(data.val_fraction * available)`` with a floor of one, always leaving one to train on.
    With a single trajectory this is 0: :func:`split_data` splits that one in time instead.
    """
    dcfg = cfg['data']
    count = dcfg['val_trajectories']
    if count is not None and (count < available or count == 0):
        return count
    if dcfg['val_fraction'] == 0 or available < 2:
        return 0
    return min(max(1, round(dcfg['val_fraction'] * available)), available - 1)


def episodes_of(data, idx: np.ndarray) -> Optional[np.ndarray]:
    """The episode (recording) of each trajectory ``idx`` from ``meta.episodes`` (an import of several
    recordings), or None when the meta has none or ``idx`` holds a single episode."""
    episodes = (data.meta or {}).get('episodes')
    if not isinstance(episodes, list) or len(episodes) != data.states.shape[0]:
        return None
    of = np.asarray(episodes)[idx]
    return of if np.unique(of).size > 1 else None


def split_by_episode(
    cfg: Dict[str, Any], idx: np.ndarray, episodes: np.ndarray, log
) -> Tuple[np.ndarray, np.ndarray]:
    """``(train, validation)`` trajectory indices holding out whole episodes: the last
    :func:`held_out_count` of the episodes (``data.val_trajectories`` then counts episodes), so no
    recording has windows on both sides."""
    order = list(dict.fromkeys(episodes.tolist()))  # episodes in the order of their trajectories
    n_val = held_out_count(cfg, len(order))
    held = set(order[len(order) - n_val :])
    val = np.array([e in held for e in episodes.tolist()], dtype=bool)
    log(
        f'validation: {n_val} of {len(order)} episodes held out whole ({int(val.sum())} of {idx.size} '
        f'trajectories; data.val_fraction = {cfg["data"]["val_fraction"]:g}, data.val_trajectories '
        f'counts episodes)'
    )
    return idx[~val], idx[val]


def split_data(cfg: Dict[str, Any], data, log=print) -> Dict[str, np.ndarray]:
    """Train and validation trajectories ``[N, T, n, d]`` from the file's ``train`` split.

    Whole trajectories are held out (:func:`held_out_count`). A split of one trajectory (one
    recorded bag) is cut in time instead: train on the first ``1 - data.val_fraction`` of its
    frames, validate on the rest; no sample window crosses the cut (each part is its own array).
    ``val_from_frame`` is that cut (None for a split by trajectories).
    """
    dcfg = cfg['data']
    idx = data.split('train')
    if dcfg['train_trajectories'] is not None:
        idx = idx[: dcfg['train_trajectories']]
    if len(idx) == 0:
        raise DataError(
            "the data's train split is empty (meta.split.train); regenerate or re-import it with train "
            'trajectories (training.generate --train N, training.import_bag --test-trajectories 0)'
        )
    frames = data.states.shape[1] if dcfg['frames'] is None else min(dcfg['frames'], data.states.shape[1])
    if frames < 2:
        raise DataError(f'trajectories hold {data.states.shape[1]} frame(s); training needs at least 2')
    states = data.states[:, :frames]
    n_val = held_out_count(cfg, len(idx))
    asked = dcfg['val_trajectories']
    if asked is not None and asked != n_val and len(idx) > 1:
        log(
            f"data.val_trajectories = {asked} but the data's train split holds only {len(idx)} "
            f'trajectories: holding out {n_val} (data.val_fraction = {dcfg["val_fraction"]:g}, at least one)'
        )
    if len(idx) == 1 and dcfg['val_fraction'] > 0 and asked != 0:
        cut = int(round((1 - dcfg['val_fraction']) * frames))
        if cut < 2 or frames - cut < 2:
            raise DataError(
                f'one trajectory of {frames} frames is too short to split in time for validation '
                f'(data.val_fraction = {dcfg["val_fraction"]:g}); record longer or --set data.val_fraction=0'
            )
        log(
            f'one trajectory in the train split: training on its frames 0-{cut - 1}, validating on '
            f'frames {cut}-{frames - 1} (the last {dcfg["val_fraction"]:.0%}, data.val_fraction)'
        )
        one = states[idx[0]]
        return {
            'train': one[None, :cut],
            'val': one[None, cut:],
            'train_idx': idx,
            'val_idx': idx,
            'val_from_frame': cut,
        }
    episodes = episodes_of(data, idx)
    if episodes is not None:
        train_idx, val_idx = split_by_episode(cfg, idx, episodes, log)
    else:
        train_idx, val_idx = idx[: len(idx) - n_val], idx[len(idx) - n_val :]
    return {
        'train': states[train_idx],
        'val': states[val_idx],
        'train_idx': train_idx,
        'val_idx': val_idx,
        'val_from_frame': None,
    }


def config_differences(old: Dict[str, Any], new: Dict[str, Any], prefix: str = '') -> List[str]:
    """Dotted names of the fields whose values differ between two normalised configs, sorted."""
    out: List[str] = []
    for key in sorted(set(old) | set(new), key=str):
        a, b = old.get(key), new.get(key)
        if isinstance(a, dict) and isinstance(b, dict):
            out += config_differences(a, b, f'{prefix}{key}.')
        elif a != b or key not in old or key not in new:
            out.append(f'{prefix}{key}')
    return out


def _lookup(cfg: Dict[str, Any], dotted: str) -> Any:
    for key in dotted.split('.'):
        cfg = cfg.get(key) if isinstance(cfg, dict) else None
    return cfg


def _epoch_generator(seed: int, epoch: int) -> torch.Generator:
    g = torch.Generator()
    g.manual_seed(int(seed) * 100003 + int(epoch))
    return g


def _lr_lambda(cfg: Dict[str, Any]):
    t = cfg['training']
    epochs, lr, lr_min = t['epochs'], t['lr'], t['lr_min']
    floor = min(lr_min / lr, 1.0)

    def fn(epoch: int) -> float:
        if t['lr_schedule'] == 'cosine':
            return floor + (1 - floor) * 0.5 * (1 + math.cos(math.pi * min(epoch, epochs) / epochs))
        if t['lr_schedule'] == 'step':
            return max(0.1 ** (epoch // max(epochs // 3, 1)), floor)
        return 1.0

    return fn


def _selection_text(sel: Dict[str, Any]) -> str:
    """The log's form of a selection record: ``select score=... rollouts=...``."""
    return 'select ' + ' '.join(f'{k}={v:.3g}' for k, v in sel.items())


class Trainer:
    """All training state; :meth:`run` trains to the configured epoch count.

    ``data_path``: one trajectory file, or a list of files (swarms of different sizes, same
    scenario and dt) whose samples are pooled; selection rolls out each file's validation swarms.
    """

    def __init__(
        self,
        cfg: Dict[str, Any],
        data_path,
        out_dir: str,
        resume: bool = False,
        progress: bool = True,
        log=print,
    ):
        self.data_path = data_path
        self.out = out_dir
        self.progress = progress
        self.log = log
        paths = [data_path] if isinstance(data_path, (str, os.PathLike)) else list(data_path)
        if not paths:
            raise DataError('no data file given')
        # fields the data decide (scenario: auto, policy.k: auto, ...): training.learning.derive
        self.derived: Dict[str, Any] = {}
        if isinstance(cfg, PendingConfig):
            cfg, self.derived = complete_config(cfg, paths)
            for name, entry in self.derived.items():
                self.log(f'derived {name} = {entry["value"]}: {entry["how"]}')
        self.cfg = cfg
        self.spec = get_scenario(cfg['scenario'])
        torch.set_num_threads(cfg['training']['threads'])
        self.data_paths = paths
        # the code that trains is the code at the start (a tree edited during a run must not
        # change what the policy says it came from)
        self.code = code_provenance()
        # Several files may hold swarms of different sizes: the neighbour matrix has
        # k rows whatever n is, so their samples train one size-agnostic policy (training.datasets).
        pc, nc = cfg['policy'], cfg['noise']
        std = math.sqrt(nc['variance'])
        obs_std = std if nc['mode'] == 'observations' else 0.0
        rng = np.random.default_rng(cfg['seed'])
        t0 = time.perf_counter()
        self.splits, train_parts, val_parts = [], [], []
        datas = [self._load(path) for path in paths]
        rows = pc['k']
        if pc.get('encoder', 'flat') in ROW_FREE_ENCODERS:
            # no weight per row: rows beyond the largest swarm are always masked
            rows = min(rows, max(int(np.asarray(d.states).shape[-2]) for d in datas))
        for path, data in zip(paths, datas):
            split = split_data(cfg, data, log)
            if split['train'].shape[1] <= self.ratio:
                raise DataError(
                    f'{path}: trajectories of {split["train"].shape[1]} frames are too short for '
                    f'a policy step of {self.ratio} frames (data.policy_dt = {self.dt:g} s)'
                )
            self.splits.append(split)
            train_parts.append(
                make_samples(
                    split['train'],
                    self.spec,
                    pc['d_cr'],
                    rows,
                    pc['tau'],
                    cfg['data']['stride'],
                    obs_std,
                    rng,
                    ratio=self.ratio,
                )
            )
            if len(split['val']):
                val_parts.append(
                    make_samples(split['val'], self.spec, pc['d_cr'], rows, pc['tau'], 1, ratio=self.ratio)
                )
        self.split = self.splits[0]
        caveat = size_caveat([sp['train'] for sp in self.splits], self.spec, float(pc['d_cr']))
        self.caveats: List[str] = [] if caveat is None else [caveat]
        for line in self.caveats:
            self.log(f'caveat: {line}')
        self.train = concat_samples(train_parts)
        self.val = concat_samples(val_parts) if val_parts else None
        self.dropped = 0
        if cfg['data']['drop_saturated']:
            # Samples whose implied command exceeds the policy's saturation cannot be reproduced
            # by any saturated policy; a few close pairs at t = 0 would otherwise dominate the MSE.
            keep = (
                implied_command(self.train.clean_own, self.train.target, self.spec, self.dt).abs().amax(1)
                <= pc['command_limit']
            )
            self.dropped = int((~keep).sum())
            self.train = self.train.subset(keep)
            if self.val is not None:
                keep = (
                    implied_command(self.val.clean_own, self.val.target, self.spec, self.dt).abs().amax(1)
                    <= pc['command_limit']
                )
                self.val = self.val.subset(keep)
        if len(self.train) == 0:
            raise DataError(f'{", ".join(paths)}: no training samples left (data.drop_saturated removed all)')
        self.prep_s = time.perf_counter() - t0
        torch.manual_seed(cfg['seed'])
        self.policy = build_policy(cfg)
        # training.objective (training.learning.objectives) draws the batches and computes the loss
        data = TrainingData(self.train, [sp['train'] for sp in self.splits], self.ratio)
        self.objective = make_objective(cfg, self.spec, self.dt, data)
        self.objective.load_init(self.policy)
        # the validation loss is the one-step loss whatever the objective, so runs compare on it
        self.val_objective = None if self.val is None else OneStepObjective(cfg, self.spec, self.dt, self.val)
        tc = cfg['training']
        self.opt = torch.optim.Adam(self.policy.parameters(), lr=tc['lr'], weight_decay=tc['weight_decay'])
        self.sched = torch.optim.lr_scheduler.LambdaLR(self.opt, _lr_lambda(cfg))
        self.epoch = 0  # epochs completed
        # the selection's best epoch (and, with selection.confirm, its runners-up: the candidates)
        self.best: Optional[Dict[str, Any]] = None
        self.candidates = Candidates(cfg['selection']['confirm'])
        # every selection's seconds: the time cap plans with their median, which one selection
        # slowed by a passing load does not move
        self.select_times: List[float] = []
        self.confirm_s: Optional[float] = None
        self.confirmed: Optional[List[Dict[str, Any]]] = None
        # the confirm stage's rollout steps over one selection's, per candidate
        sc = cfg['selection']
        selection_size = sum(t.shape[0] * t.shape[1] for t in selection_truths(self.splits, sc, self.ratio))
        confirm_size = sum(t.shape[0] * t.shape[1] for t in confirm_truths(self.splits, sc, self.ratio))
        self.confirm_cost = confirm_size / max(selection_size, 1)
        self.start_selection: Optional[Dict[str, Any]] = None  # the starting model's score (fine-tuning)
        self.ref_loss: Optional[float] = None
        self.elapsed = 0.0
        os.makedirs(out_dir, exist_ok=True)
        self.ckpt_path = os.path.join(out_dir, 'checkpoint.pt')
        self.metrics_path = os.path.join(out_dir, 'metrics.jsonl')
        # A fresh run leaves an earlier run's files in out_dir alone until its own first epoch is
        # done (_claim_out): a run that fails before that must not damage them.
        self._claimed = resume
        if resume:
            self._resume()
            self._write_config()

    def _load(self, path: str):
        """One data file, checked against the config and the files before it (scenario, dt)."""
        data = load_trajectories(path)
        if data.scenario != self.cfg['scenario']:
            raise DataError(
                f"{path}: field 'scenario' is {data.scenario!r} but the config trains "
                f'{self.cfg["scenario"]!r}'
            )
        if data.states.shape[2] < 2:
            raise DataError(f"{path}: field 'states' holds {data.states.shape[2]} robot(s); need >= 2")
        if hasattr(self, 'data_dt'):
            if abs(float(data.dt) - self.data_dt) > 1e-9 * self.data_dt:
                raise DataError(
                    f"{path}: field 'dt' is {float(data.dt):g} s but {self.data_paths[0]} has "
                    f'{self.data_dt:g} s; every --data file must share one dt'
                )
            return data
        # The policy's dt: the data's, or a whole multiple of it (data.policy_dt, training.learning.period).
        self.data_dt = float(data.dt)
        try:
            self.ratio = period_ratio(self.data_dt, self.cfg['data']['policy_dt'])
        except ValueError as exc:
            raise DataError(f'{path}: config field {exc}') from None
        self.dt = policy_dt(self.data_dt, self.ratio)
        return data

    def _claim_out(self) -> None:
        if self._claimed:
            return
        for name in ('metrics.jsonl', 'summary.json'):
            if os.path.exists(os.path.join(self.out, name)):
                os.unlink(os.path.join(self.out, name))
        self._write_config()
        self._claimed = True

    def resume_hint(self) -> str:
        """What a stopped run leaves and how to continue it (the Ctrl-C message of training.train)."""
        if not self._claimed or self.epoch == 0:
            return f'no epoch completed; nothing to resume in {self.out}'
        return (
            f'checkpoint after epoch {self.epoch} kept at {self.ckpt_path}; continue with the same '
            'command plus --resume'
        )

    def _last_good(self) -> str:
        if not self._claimed:
            return f'no epoch of this run completed; the files already in {self.out} were left as they were'
        return f'last good checkpoint (epoch {self.epoch}) kept at {self.ckpt_path}'

    # -- persistence
    def _write_config(self) -> None:
        text = yaml.safe_dump(self.cfg, sort_keys=False)
        atomic_write(os.path.join(self.out, 'config.yaml'), lambda tmp: open(tmp, 'w').write(text))

    def _resume(self) -> None:
        if not os.path.isfile(self.ckpt_path):
            raise DataError(f'--resume: no checkpoint at {self.ckpt_path}')
        ck = torch.load(self.ckpt_path, map_location='cpu', weights_only=False)
        changed = config_differences(ck['config'], self.cfg)
        if changed and (changed != ['training.epochs'] or self.cfg['training']['epochs'] < ck['epoch']):
            shown = '; '.join(
                f'{key}: {_lookup(ck["config"], key)!r} in the checkpoint, {_lookup(self.cfg, key)!r} now'
                for key in changed
            )
            raise ConfigError(
                f'--resume: the config differs from the one in {self.ckpt_path} ({shown}); resume with '
                'the same config and --set values (only training.epochs may grow), or train into a new --out'
            )
        if changed:
            self.log(
                f'--resume: training.epochs {ck["config"]["training"]["epochs"]} -> '
                f'{self.cfg["training"]["epochs"]} (the learning-rate schedule stretches to the new count)'
            )
        self.policy.load_state_dict(ck['model'])
        self.opt.load_state_dict(ck['optimizer'])
        self.sched.load_state_dict(ck['scheduler'])
        self.epoch, self.best, self.ref_loss = ck['epoch'], ck['best'], ck['ref_loss']
        self.candidates = Candidates(self.cfg['selection']['confirm'], ck.get('candidates'))
        old = ck.get('select_s')  # checkpoints written before the times were kept: the last one
        self.select_times = list(ck.get('select_times') or ([] if old is None else [old]))
        self.start_selection = ck.get('start_selection')
        self.elapsed = ck.get('elapsed', 0.0)
        # keep the metrics log consistent with the checkpoint (drop epochs after it)
        if os.path.exists(self.metrics_path):
            with open(self.metrics_path) as fh:
                lines = [ln for ln in fh if ln.strip() and json.loads(ln)['epoch'] <= self.epoch]
            atomic_write(self.metrics_path, lambda tmp: open(tmp, 'w').writelines(lines))
        self.log(f'resumed from {self.ckpt_path} after epoch {self.epoch}')

    def _save_checkpoint(self) -> None:
        ck = {
            'config': self.cfg,
            'model': self.policy.state_dict(),
            'optimizer': self.opt.state_dict(),
            'scheduler': self.sched.state_dict(),
            'epoch': self.epoch,
            'best': self.best,
            'candidates': self.candidates.kept,
            'select_times': self.select_times,
            'ref_loss': self.ref_loss,
            'elapsed': self.elapsed,
            'start_selection': self.start_selection,
        }
        atomic_write(self.ckpt_path, lambda tmp: torch.save(ck, tmp))

    # -- one epoch
    def val_loss(self) -> Optional[float]:
        if self.val_objective is None:
            return None
        total, M = 0.0, len(self.val)
        with torch.no_grad():
            for idx in torch.split(torch.arange(M), 65536):
                total += float(self.val_objective.loss(self.policy, idx, None)) * len(idx)
        return total / M

    def select_metrics(self) -> Optional[Dict[str, Any]]:
        """Roll the current module out from the validation trajectories' first frames."""
        sc = self.cfg['selection']
        truths = selection_truths(self.splits, sc, self.ratio)
        if sc['every'] == 0 or not truths:
            return None
        t0 = time.perf_counter()
        out = rollout_metrics(self.policy, self.spec, truths, sc, self.cfg['policy'], self.dt)
        self.select_times.append(time.perf_counter() - t0)
        return out

    def _offer(self, epoch: int, sel: Dict[str, Any]) -> None:
        """A selection's score: the epoch joins the candidates if among the best so far."""
        if self.candidates.offer(epoch, sel, self.policy):
            self.best = self.candidates.best
        elif self.best is None:
            # nothing finite yet: remember the (infinite) score, the export keeps the last epoch
            self.best = {'epoch': epoch, 'score': sel['score'], 'metrics': sel, 'state': None}

    @property
    def select_s(self) -> Optional[float]:
        """One selection's seconds: the median of those so far (None before the first)."""
        return float(np.median(self.select_times)) if self.select_times else None

    def confirm_reserve(self) -> float:
        """Seconds the confirm stage will take, from a selection's time (:attr:`select_s`): the
        run's time cap (``training.max_minutes``) holds training and confirm stage together."""
        sc = self.cfg['selection']
        if sc['confirm'] < 2 or self.select_s is None:
            return 0.0
        return sc['confirm'] * self.select_s * self.confirm_cost

    def confirm(self) -> None:
        """Score the candidates again on more starts (``selection.confirm``); the best there is the
        run's choice. Each candidate's two scores are logged and kept in ``self.confirmed``."""
        sc, kept = self.cfg['selection'], self.candidates.kept
        if sc['confirm'] < 2 or len(kept) < 2:
            return
        t0 = time.perf_counter()
        truths = confirm_truths(self.splits, sc, self.ratio)
        current = copy.deepcopy(self.policy.state_dict())
        scored = []
        for c in kept:
            self.policy.load_state_dict(c['state'])
            m = rollout_metrics(self.policy, self.spec, truths, sc, self.cfg['policy'], self.dt)
            scored.append(m)
            self.log(
                f'confirm: epoch {c["epoch"]} selection score {c["score"]:.4g}, '
                f'confirm score {m["score"]:.4g} on {m.get("rollouts", 0)} rollouts'
            )
        self.policy.load_state_dict(current)
        self.confirmed = [
            {'epoch': c['epoch'], 'score': c['score'], 'confirm_score': m['score']}
            for c, m in zip(kept, scored)
        ]
        won = min(range(len(kept)), key=lambda i: (scored[i]['score'], i))
        if math.isfinite(scored[won]['score']):
            self.best = {**kept[won], 'confirm': scored[won]}
        self.confirm_s = time.perf_counter() - t0
        self.log(
            f'confirm: epoch {self.best["epoch"]} chosen of the {len(kept)} best by the selection '
            f'score ({self.confirm_s:.1f}s)'
        )

    def run(self, stop_after: Optional[int] = None) -> Optional[Dict[str, Any]]:
        """Train to ``training.epochs`` (or only up to epoch ``stop_after``, leaving a checkpoint
        to resume from and returning None) and export the policy."""
        tc, sc = self.cfg['training'], self.cfg['selection']
        epochs = tc['epochs']
        from tqdm import tqdm

        start = time.perf_counter() - self.elapsed
        # A bar only on a terminal: redirected to a file its redraws are one line of carriage returns;
        # there the epoch lines (and a line every PROGRESS_EVERY_S within a long epoch) report instead.
        show_bar = self.progress and sys.stderr.isatty()
        heartbeat = self.progress and not show_bar
        if self.epoch == 0 and self.best is None:
            self._select_starting_model()
        while self.epoch < epochs:
            e = self.epoch + 1
            g = _epoch_generator(self.cfg['seed'], e)
            t0 = time.perf_counter()
            self.policy.train()
            batches = self.objective.batches(e, g)
            bar = tqdm(
                batches,
                desc=f'epoch {e}/{epochs}',
                leave=False,
                disable=not show_bar,
                mininterval=0.5,
                file=sys.stderr,
            )
            total, count = 0.0, 0
            said = time.perf_counter()
            for b, idx in enumerate(bar):
                loss = self.objective.loss(self.policy, idx, g)
                value = loss.item()
                if not math.isfinite(value) or (
                    self.ref_loss is not None and value > tc['diverge_factor'] * self.ref_loss
                ):
                    raise DivergenceError(
                        f'epoch {e}: batch loss {value:.4g} is '
                        f'{"not finite" if not math.isfinite(value) else "exploding"} '
                        f'(reference {self.ref_loss}); stopped, {self._last_good()}'
                    )
                self.opt.zero_grad(set_to_none=True)
                loss.backward()
                if tc['grad_clip'] is not None:
                    torch.nn.utils.clip_grad_norm_(self.policy.parameters(), tc['grad_clip'])
                self.opt.step()
                with torch.no_grad():
                    biggest = max(float(p.abs().max()) for p in self.policy.parameters())
                if not math.isfinite(biggest) or biggest > tc['max_param']:
                    raise DivergenceError(
                        f'epoch {e}: a parameter reached {biggest:.3g} (limit training.max_param = '
                        f'{tc["max_param"]:g}); stopped, {self._last_good()}'
                    )
                total += value * len(idx)
                count += len(idx)
                # refresh=False: the bar redraws at mininterval, not on every batch
                bar.set_postfix(loss=f'{total / count:.4g}', refresh=False)
                if heartbeat and time.perf_counter() - said >= PROGRESS_EVERY_S:
                    said = time.perf_counter()
                    self.log(f'epoch {e}/{epochs}: batch {b + 1}/{len(batches)}, loss {total / count:.4g}')
            train_loss = total / count
            if not all(torch.all(torch.isfinite(p)) for p in self.policy.parameters()):
                raise DivergenceError(
                    f'epoch {e}: parameters became non-finite; stopped, {self._last_good()}'
                )
            if self.ref_loss is None:
                self.ref_loss = train_loss
            lr = self.opt.param_groups[0]['lr']
            self.sched.step()
            epoch_s = time.perf_counter() - t0
            record: Dict[str, Any] = {
                'epoch': e,
                'train_loss': train_loss,
                'val_loss': self.val_loss(),
                'lr': lr,
                'epoch_s': round(epoch_s, 3),
            }
            # The cap holds the whole run: this epoch is the last when one more (at this epoch's
            # time, its validation loss included, then scored at the last selection's) would end
            # past it, the confirm stage's reserve left. A run cut short scores its last epoch
            # too: it is the one it ends with.
            now = time.perf_counter()
            ahead = (now - t0) + (self.select_s or 0.0) + self.confirm_reserve()
            out_of_time = tc['max_minutes'] is not None and now - start + ahead > 60 * tc['max_minutes']
            if sc['every'] and (e % sc['every'] == 0 or e == epochs or out_of_time):
                sel = self.select_metrics()
                if sel is not None:
                    record['selection'] = sel
                    self._offer(e, sel)
            self.epoch = e
            self.elapsed = time.perf_counter() - start
            record['elapsed_s'] = round(self.elapsed, 2)
            self._claim_out()
            with open(self.metrics_path, 'a') as fh:
                fh.write(json.dumps(record) + '\n')
            self._save_checkpoint()
            val = record['val_loss']
            val_text = 'None' if val is None else format(val, '.4g')
            msg = f'epoch {e}/{epochs} train {train_loss:.4g} val {val_text} lr {lr:.2e} ({epoch_s:.1f}s)'
            if 'selection' in record:
                msg += ' ' + _selection_text(record['selection'])
            self.log(msg)
            if stop_after is not None and e >= stop_after:
                return None
            if out_of_time:
                reserve = self.confirm_reserve()
                self.log(
                    f'stopping after epoch {e}: another would end past training.max_minutes = {tc["max_minutes"]}'
                    + (f' (leaving {reserve:.0f}s of it to the confirm stage)' if reserve else '')
                )
                break
        return self.finish()

    def _select_starting_model(self) -> None:
        """Fine-tuning (the objective's ``init``: ``multistep.init``): the starting model is the first
        candidate of the selection (epoch 0), so the run never returns a model that rolls out worse
        than it started."""
        if self.objective.init is None or not self.cfg['selection']['every']:
            return
        sel = self.select_metrics()
        self.start_selection = sel
        if sel is not None and math.isfinite(sel['score']):
            self._offer(0, sel)
            self.log('starting model (multistep.init) ' + _selection_text(sel))

    def _export_twin(self, path: str) -> Dict[str, Any]:
        """Write the ONNX twin of ``path``; a failed export is logged, never fatal:
        the TorchScript policy is the training artefact."""
        from .onnx_twin import export_onnx

        try:
            twin, errors = export_onnx(path)
        except (ImportError, PolicyError) as exc:
            self.log(f'ONNX twin not written: {exc}')
            return {'path': None, 'error': str(exc)}
        self.log(f'wrote {twin}: max difference to TorchScript {max(errors.values()):.2e}')
        return {'path': str(twin), 'max_difference': max(errors.values())}

    def _data_provenance(self) -> Dict[str, Any]:
        """Data files (repository-relative) and trajectory indices; lists when several files."""
        out = {
            'data': [data_reference(p) for p in self.data_paths],
            'data_file': [os.path.basename(p) for p in self.data_paths],
            'train_trajectories': [sp['train_idx'].tolist() for sp in self.splits],
            'val_trajectories': [sp['val_idx'].tolist() for sp in self.splits],
            'val_from_frame': [sp['val_from_frame'] for sp in self.splits],
        }
        if len(self.data_paths) == 1:
            return {k: v[0] for k, v in out.items()}
        out['robots'] = [int(sp['train'].shape[2]) for sp in self.splits]
        return out

    def finish(self) -> Dict[str, Any]:
        self.confirm()
        final_state = copy.deepcopy(self.policy.state_dict())
        chosen = 'last'
        if self.best is not None and math.isfinite(self.best['score']):
            self.policy.load_state_dict(self.best['state'])
            chosen = (
                f'best rollout score (epoch {self.best["epoch"]})'
                if self.best['epoch']
                else 'best rollout score (epoch 0: the starting model, multistep.init)'
            )
            if 'confirm' in self.best:
                chosen = (
                    f'best confirm score (epoch {self.best["epoch"]}, of the {len(self.confirmed)} '
                    'best by the rollout score)'
                )
        meta = self.policy.metadata(dt=self.dt)
        meta['provenance'] = {
            'trainer': 'training.train',
            'config': self.cfg,
            **self._data_provenance(),
            **self.code,
            'data_dt': self.data_dt,
            'dt_ratio': self.ratio,
            'epochs': self.epoch,
            'selected': chosen,
            'train_seconds': round(self.elapsed, 1),
            'torch': torch.__version__,
        }
        if self.derived:
            meta['provenance']['derived'] = self.derived
        if self.caveats:
            meta['provenance']['caveats'] = self.caveats
        path = os.path.join(self.out, 'policy.pt')
        export_policy(self.policy, path, meta)
        onnx_twin = self._export_twin(path)
        self.policy.load_state_dict(final_state)
        summary = {
            'policy': path,
            'epochs': self.epoch,
            'selected': chosen,
            'train_seconds': round(self.elapsed, 1),
            'prep_seconds': round(self.prep_s, 1),
            'train_samples': len(self.train),
            'dropped_saturated': self.dropped,
            'val_samples': 0 if self.val is None else len(self.val),
            'best': None if self.best is None else {k: v for k, v in self.best.items() if k != 'state'},
            'start_selection': self.start_selection,
            'confirmed': self.confirmed,
            'confirm_seconds': None if self.confirm_s is None else round(self.confirm_s, 1),
            'onnx': onnx_twin,
        }
        if self.derived:
            summary['derived'] = self.derived
        if self.caveats:
            summary['caveats'] = self.caveats
        write_json(os.path.join(self.out, 'summary.json'), summary)
        return summary
