"""Model selection by rollouts: score a module on whole rollouts from recorded starts, keep the best
few epochs, and confirm the choice on more starts at the end of the run.

The one-step loss does not rank models by how their swarms behave over hundreds of steps, so the
trainer rolls the module out from the validation trajectories' first frames every
``selection.every`` epochs (:func:`rollout_metrics`). Two validation starts rank epochs by a
noisy score when the swarm's fate depends on its start (it splits from some, not from others), so
with ``selection.confirm`` the best few epochs by that score (:class:`Candidates`) are scored again
after training on the validation starts plus the first frames of ``selection.confirm_trajectories``
training trajectories (:func:`confirm_truths`). A training trajectory's first frame is a start like
any other: the one-step objective fits its 0.05 s steps, not where its swarm is after 400 of them.
"""

from __future__ import annotations

import copy
import math
from typing import Any, Dict, List, Optional

import numpy as np
import torch

from knode_swarm_ros.core import Scenario
from training.assessment.scores import final_metrics, perturbed_starts, rollout_module, selection_score

from .period import subsample

#: Per-rollout metrics whose mean (min_distance: minimum) the score's record carries.
_REPORTED = ('avd_final', 'amd_final', 'truth_amd_final', 'truth_avd_final', 'pod_kld', 'min_distance')


def _horizon(truth: np.ndarray, steps: Optional[int]) -> np.ndarray:
    """``truth [S, T, n, d]`` cut to ``selection.steps`` steps (all when None)."""
    last = truth.shape[1] - 1 if steps is None else min(steps, truth.shape[1] - 1)
    return truth[:, : last + 1]


def selection_truths(splits: List[Dict[str, Any]], sc: Dict[str, Any], ratio: int) -> List[np.ndarray]:
    """The recorded rollouts selection compares with: each file's first ``selection.trajectories``
    validation trajectories at the policy's dt, ``[S, T, n, d]`` per file (swarm size)."""
    return [
        _horizon(subsample(sp['val'][: sc['trajectories']], ratio), sc['steps'])
        for sp in splits
        if len(sp['val'])
    ]


def confirm_truths(splits: List[Dict[str, Any]], sc: Dict[str, Any], ratio: int) -> List[np.ndarray]:
    """The confirm stage's recorded rollouts: the selection's, plus each file's first
    ``selection.confirm_trajectories`` training trajectories (null: all of them)."""
    extra = [
        _horizon(subsample(sp['train'][: sc['confirm_trajectories']], ratio), sc['steps'])
        for sp in splits
        if len(sp['train']) and sp['train'].shape[1] > ratio
    ]
    return selection_truths(splits, sc, ratio) + extra


def rollout_groups(
    module: torch.nn.Module,
    spec: Scenario,
    truths: List[np.ndarray],
    copies: int,
    perturb: float,
    cfg_policy: Dict[str, Any],
    dt: float,
) -> Optional[List[Dict[str, List[float]]]]:
    """Per-rollout metrics of ``module`` rolled out from the first frame of every trajectory in
    each group of ``truths`` (``copies`` perturbed copies each, start-major as
    :func:`~training.assessment.scores.perturbed_starts`): one dict of lists per group, or None
    when a rollout blows up."""
    module.eval()
    groups = []
    try:
        for truth in truths:  # one batch of rollouts per group (a swarm size, a horizon)
            # several rollouts per start sample the chaotic spread (copy 0 is the start itself; the
            # same perturbations every epoch and run, so epochs are ranked on the same draws)
            starts = perturbed_starts(truth[:, 0], copies, perturb, spec.position_dim)
            pred = rollout_module(module, spec, starts, truth.shape[1] - 1, cfg_policy, dt)
            if not np.all(np.isfinite(pred)):
                return None
            groups.append(final_metrics(spec, pred, np.repeat(truth, copies, axis=0), dt=dt))
    finally:
        module.train()
    return groups


def rollout_metrics(
    module: torch.nn.Module,
    spec: Scenario,
    truths: List[np.ndarray],
    sc: Dict[str, Any],
    cfg_policy: Dict[str, Any],
    dt: float,
) -> Dict[str, Any]:
    """Roll ``module`` out from the first frame of every trajectory in ``truths`` (``selection.rollouts``
    perturbed copies each) and score the rollouts against them: ``{'score', 'rollouts', ...}``
    (:func:`training.assessment.scores.selection_score`, lower is better; +inf when a rollout blows up)."""
    groups = rollout_groups(module, spec, truths, sc['rollouts'], sc['perturb'], cfg_policy, dt)
    if groups is None:
        return {'score': float('inf')}
    m: Dict[str, Any] = {}
    for group in groups:
        for key, values in group.items():
            m.setdefault(key, []).extend(values)
    out = {'score': selection_score(spec, m), 'rollouts': len(m['amd_final'])}
    # the spread behind the score: standard error of its per-rollout term over the rollouts
    spread_key = 'avd_final' if spec.name == 'flock2d' else 'pod_kld'
    if len(m.get(spread_key, [])) > 1:
        out[spread_key + '_se'] = float(np.std(m[spread_key], ddof=1) / np.sqrt(len(m[spread_key])))
    # the paper's scenarios compare the medians of amd, any other the means: both reported
    out['amd_median'] = float(np.median(m['amd_final']))
    out['truth_amd_median'] = float(np.median(m['truth_amd_final']))
    for key in _REPORTED:
        if key in m:
            out[key] = float(np.min(m[key]) if key == 'min_distance' else np.mean(m[key]))
    if 'stays_inside' in m:
        out['stays_inside'] = float(np.mean(m['stays_inside']))
    return out


class Candidates:
    """The ``size`` best-scoring epochs so far, best first: ``{'epoch', 'score', 'metrics', 'state'}``.

    ``size`` 1 keeps the best alone (no confirm stage). A tie keeps the earlier epoch, as the
    selection always has.
    """

    def __init__(self, size: int, kept: Optional[List[Dict[str, Any]]] = None):
        self.size = max(1, size)
        self.kept: List[Dict[str, Any]] = list(kept or [])

    @property
    def best(self) -> Optional[Dict[str, Any]]:
        return self.kept[0] if self.kept else None

    def offer(self, epoch: int, metrics: Dict[str, Any], module: torch.nn.Module) -> bool:
        """Keep ``module``'s state if its score is among the best ``size``; True if it is the best."""
        score = metrics['score']
        if not math.isfinite(score):
            return False
        if len(self.kept) == self.size and score >= self.kept[-1]['score']:
            return False
        entry = {
            'epoch': epoch,
            'score': score,
            'metrics': metrics,
            'state': copy.deepcopy(module.state_dict()),
        }
        at = sum(1 for c in self.kept if c['score'] <= score)
        self.kept.insert(at, entry)
        del self.kept[self.size :]
        return at == 0
