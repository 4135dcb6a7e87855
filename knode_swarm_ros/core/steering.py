"""Constant-speed steering: the command of a robot that keeps a set speed and turns its heading
by at most a bounded angle per step (``policy.speed``, ``policy.turn_limit``).

Laws of constant-speed agents (Vicsek, Couzin's zones, unicycle robots with a turn rate) do not
add a force to a velocity: each robot keeps its speed and turns towards where its interactions
point, by at most a turn limit. What such a swarm does lies in turns of a few hundredths of a
radian per step; a network that gives the whole velocity makes errors of that size, and nothing
bounds them. Here the unconstrained command ``w`` (network plus knowledge) is the deviation
from going straight on: with a set ``speed`` the robot points to ``speed h + w``, ``h`` its own
unit heading (without one, to ``w``), and turns towards that by

``turn = turn_limit x / sqrt(1 + x^2)``, ``x = angle / turn_limit``

(``angle`` from ``h`` to where the robot points): about the angle itself where it is small, never
more than the limit, and with a slope everywhere (a hard clip would leave a network that points
too far no gradient to come back along). The new direction is ``cos(turn) h + sin(turn) n``,
``n`` the unit part of the pointing normal to ``h``; pointing exactly behind (no side to turn
to) or nowhere keeps the heading. The command is that direction times ``speed`` (or times ``|w|``
where no speed is set).
Every function is TorchScript-compatible and ONNX-exportable and works on a batch.
"""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = ['steer', 'FREE_SPEED', 'FREE_TURN']

#: ``speed`` that keeps the magnitude of ``w`` (no set speed).
FREE_SPEED = 0.0
#: ``turn_limit`` that bounds nothing (every direction is within a half turn).
FREE_TURN = 3.141592653589793


def _unit(x: Tensor, fallback: Tensor) -> Tensor:
    """``x / |x|`` ``[B, p]``, or ``fallback`` where ``|x|`` is (numerically) zero."""
    norm = torch.sqrt((x * x).sum(-1, keepdim=True) + 1e-24)  # finite slope at 0
    ok = norm > 1e-9
    return torch.where(ok, x / torch.where(ok, norm, torch.ones_like(norm)), fallback)


def steer(w: Tensor, heading: Tensor, speed: float, turn_limit: float) -> Tensor:
    """The steered command ``[B, p]`` for unconstrained commands ``w [B, p]`` (deviations from
    going straight on where ``speed`` is set) of robots with headings ``heading [B, p]``
    (normalised here: noisy inputs need not be unit).

    ``speed`` > 0 sets the command's magnitude (:data:`FREE_SPEED`: ``|w|``); ``turn_limit`` in
    radians per step, in (0, pi] (:data:`FREE_TURN`: the direction of ``w``, unbounded).
    """
    h = _unit(heading, torch.zeros_like(heading))
    if speed > 0.0:
        w = w + speed * h
    direction = _unit(w, h)
    if turn_limit < 3.141592653589793:  # FREE_TURN: TorchScript cannot read module globals
        along = (direction * h).sum(-1, keepdim=True)
        side = direction - along * h
        across = torch.sqrt((side * side).sum(-1, keepdim=True) + 1e-24)
        # half-angle form of the angle in [0, pi]: atan has a finite slope everywhere (acos does
        # not at 0); exactly behind (along = -1, across = 0) it gives 0, and the heading is kept
        angle = 2.0 * torch.atan(across / torch.clamp(1.0 + along, min=1e-12))
        x = angle / turn_limit
        turn = turn_limit * x / torch.sqrt(1.0 + x * x)
        direction = _unit(torch.cos(turn) * h + torch.sin(turn) * _unit(side, torch.zeros_like(h)), h)
    if speed > 0.0:
        return direction * speed
    return direction * torch.sqrt((w * w).sum(-1, keepdim=True) + 1e-24)
