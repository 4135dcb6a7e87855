"""What :class:`training.learning.trainer.Trainer` calls on a training objective.

An objective turns the training data into the batches of an epoch and a batch into a loss. The
trainer owns everything else (optimiser, schedule, divergence checks, selection, export) and
never asks which objective it runs.

Shapes: N trajectories, T frames, n robots, d state entries; a batch is whatever the objective's
``batches`` returns (one-step: sample indices ``[B]``; multi-step: window starts ``[B, 2]``),
``len(batch)`` being the number of samples the batch's loss averages.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, Dict, List, Optional

import numpy as np
import torch
from torch import Tensor, nn

from knode_swarm_ros.core.scenarios import Scenario

from ..samples import Samples


@dataclass
class TrainingData:
    """The training split, in the forms the objectives draw from.

    ``samples``: the one-step samples pooled over every data file (saturated ones dropped when
    ``data.drop_saturated``). ``trajectories``: per data file, its training trajectories
    ``[N, T, n, d]`` at the data's dt. ``ratio``: policy dt / data dt (a whole number).
    """

    samples: Samples
    trajectories: List[np.ndarray]
    ratio: int


class Objective(ABC):
    """A training objective: ``batches`` of one epoch, the ``loss`` of one batch."""

    #: the starting model (policy file or run directory) when the objective fine-tunes, else None
    init: Optional[str] = None

    @classmethod
    @abstractmethod
    def from_data(cls, cfg: Dict[str, Any], spec: Scenario, dt: float, data: TrainingData) -> Objective:
        """The objective of config ``cfg`` over ``data`` at the policy's ``dt``; a
        :class:`~knode_swarm_ros.core.errors.ConfigError` naming the field when the data does not fit."""

    @abstractmethod
    def batches(self, epoch: int, g: torch.Generator) -> List[Tensor]:
        """The batches of 1-based ``epoch``, drawn with ``g``."""

    @abstractmethod
    def loss(self, policy: nn.Module, batch: Tensor, g: Optional[torch.Generator]) -> Tensor:
        """Scalar loss of ``policy`` on ``batch``; ``g`` draws its augmentation and noise (None: none)."""

    def load_init(self, policy: nn.Module) -> None:
        """Load the starting model :attr:`init` into ``policy`` (nothing to do for a fresh model)."""
