"""The objective registry (training.learning.objectives): its names, each objective's loss on a tiny
hand-built batch against the value worked out by hand, unknown names refused, a new entry trained."""

import json
import math
import os

import numpy as np
import pytest
import torch
from test_multistep import _data

from knode_swarm_ros.core import get_scenario
from training.learning.config import ConfigError, normalise_config
from training.learning.objectives import OBJECTIVES, Objective, TrainingData, make_objective
from training.learning.objectives.one_step import OneStepObjective
from training.learning.samples import Samples
from training.learning.trainer import Trainer

FLOCK = get_scenario('flock2d')
DOCUMENTED = ('one_step', 'multi_step')  # docs/training.md, "Objectives"
DT = 0.5  # exact in binary: the hand-computed losses below hold to the last bit
U = (3.0, 4.0)  # the constant command of the test policy


class ConstantCommand(torch.nn.Module):
    """u = U for every robot, whatever it hears: the loss is then worked out by hand."""

    def __init__(self):
        super().__init__()
        self.u = torch.nn.Parameter(torch.tensor(U))

    def forward(self, Y, mask):
        return self.u.expand(Y.shape[0], 2)


def _states() -> np.ndarray:
    """``[1, 4, 2, 4]``: two robots coasting (zero command) at integer velocities, frames DT apart."""
    p0 = np.array([[0.0, 0.0], [1.0, 0.0]])
    v = np.array([[1.0, 0.0], [0.0, 1.0]])
    frames = [np.concatenate([p0 + v * t * DT, v], axis=1) for t in range(4)]
    return np.stack(frames)[None].astype(np.float32)


def _samples(states: np.ndarray) -> Samples:
    """Frame 0 -> 1 of each robot: own row, then the other robot's row."""
    z0, z1 = torch.from_numpy(states[0, 0]), torch.from_numpy(states[0, 1])
    Y = torch.stack([z0, z0.flip(0)], dim=1)  # [2, k = 2, 4]
    return Samples(Y=Y, mask=torch.ones(2, 2), target=z1, clean_own=z0)


def _cfg(objective: str):
    return normalise_config(
        {
            'scenario': 'flock2d',
            'policy': {'k': 2, 'd_cr': 3.0, 'tau': 0},
            'training': {'objective': objective},
            'augment': {'rotate': False, 'velocity_boost': 0.0},
            'multistep': {'horizons': [2], 'epochs': [1]},
        }
    )


def test_the_registry_lists_exactly_the_documented_objectives():
    assert tuple(OBJECTIVES) == DOCUMENTED
    assert all(issubclass(cls, Objective) for cls in OBJECTIVES.values())
    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    with open(os.path.join(here, 'docs', 'training.md')) as fh:
        doc = fh.read()
    for name in DOCUMENTED:
        assert f'`{name}`' in doc, name
        assert normalise_config({'scenario': 'flock2d', 'training': {'objective': name}})


# Against a coasting swarm, a constant command U is off by exactly U at every frame in command units
# (position error 0.5 U (h dt)^2 over 0.5 (h dt)^2, velocity error U h dt over h dt), so the loss is
# the mean of (3^2, 4^2, 3^2, 4^2) = 12.5: one step from each robot, or windows of 2 steps.
@pytest.mark.parametrize(
    'name, batch, expected',
    [
        ('one_step', torch.tensor([0, 1]), 12.5),
        ('multi_step', torch.tensor([[0, 0], [0, 1]]), 12.5),
    ],
)
def test_each_objective_loss_on_a_hand_built_batch(name, batch, expected):
    assert name in OBJECTIVES
    states = _states()
    data = TrainingData(samples=_samples(states), trajectories=[states], ratio=1)
    objective = make_objective(_cfg(name), FLOCK, DT, data)
    assert type(objective) is OBJECTIVES[name] and objective.init is None
    objective.batches(1, torch.Generator().manual_seed(0))  # sets the epoch's horizon (multi_step)
    policy = ConstantCommand()
    loss = objective.loss(policy, batch, None)
    assert math.isfinite(loss.item()) and loss.item() == expected
    loss.backward()  # d/du_j mean(u_j^2 over its 2 of 4 entries) = u_j
    torch.testing.assert_close(policy.u.grad, torch.tensor(U))


def test_an_unknown_objective_is_refused_naming_the_field():
    with pytest.raises(ConfigError, match=r'training\.objective.*one_step, multi_step'):
        normalise_config({'scenario': 'flock2d', 'training': {'objective': 'two_step'}})
    cfg = _cfg('one_step')
    cfg['training']['objective'] = 'two_step'
    states = _states()
    with pytest.raises(ConfigError, match=r'training\.objective'):
        make_objective(cfg, FLOCK, DT, TrainingData(_samples(states), [states], 1))


class HalvedOneStep(OneStepObjective):
    """A new objective in one class: half the one-step loss."""

    def loss(self, policy, idx, g):
        return 0.5 * super().loss(policy, idx, g)


def test_a_registered_objective_is_configurable_and_trained(tmp_path, monkeypatch):
    # one registry line is all the config and the trainer need
    monkeypatch.setitem(OBJECTIVES, 'halved', HalvedOneStep)
    data = _data(tmp_path)
    losses = {}
    for name in ('one_step', 'halved'):
        raw = {
            'scenario': 'flock2d',
            'seed': 3,
            'policy': {'hidden': 8, 'd_cr': 3.0, 'k': 4},
            'data': {'val_trajectories': 1},
            'training': {'objective': name, 'epochs': 1, 'batch_size': 'full'},
            'selection': {'every': 0},
        }
        run = Trainer(normalise_config(raw), data, str(tmp_path / name), progress=False, log=lambda *a: None)
        assert isinstance(run.objective, OBJECTIVES[name])
        run.run()
        losses[name] = json.loads((tmp_path / name / 'metrics.jsonl').read_text())['train_loss']
    # one full batch: the first epoch's loss is that of the starting model, the same for both
    assert losses['halved'] == 0.5 * losses['one_step']
