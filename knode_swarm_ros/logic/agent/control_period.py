"""Does the agent's control period match the dt its policy was trained for? (ROS-free)

A policy learns the command to hold over one step of its dt (knode.json ``dt``). A realtime
agent holds each command for one control period, ``1 / control_rate``; when the two differ
the swarm runs a controller other than the one trained (a 100 Hz policy at 20 Hz holds every
command five times too long). :func:`check_control_period` compares them; the agent stays
silent when they are equal, warns once or refuses otherwise (parameter ``rate_check``), and
reports the ratio in its status. :func:`shipped_policy_for_rate` is how the realtime defaults
(the agent with an empty ``policy``, ``swarm --mode realtime``) pick the shipped policy trained
for their rate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Tuple

__all__ = [
    'PeriodCheck',
    'check_control_period',
    'shipped_policy_for_rate',
    'RATE_CHECKS',
    'PERIOD_TOLERANCE',
]

#: What the agent does when its control period differs from the policy's dt.
# accept: run without a log line, where someone has said it once already (the swarm launcher)
RATE_CHECKS = ('warn', 'refuse', 'accept')
#: Relative tolerance of "equal" and "whole multiple" (rates are floats: 1 / 20.0 vs 0.05).
PERIOD_TOLERANCE = 1e-6


@dataclass(frozen=True)
class PeriodCheck:
    """``control_period`` and ``policy_dt`` in seconds; ``ratio`` = control period / policy dt."""

    control_period: float
    policy_dt: float

    @property
    def ratio(self) -> float:
        return self.control_period / self.policy_dt

    @property
    def equal(self) -> bool:
        return math.isclose(self.control_period, self.policy_dt, rel_tol=PERIOD_TOLERANCE)

    @property
    def whole_multiple(self) -> bool:
        """The control period is a whole number (>= 2) of policy steps."""
        n = round(self.ratio)
        return n >= 2 and math.isclose(self.ratio, n, rel_tol=PERIOD_TOLERANCE)

    def describe(self, rate_name: str = 'control_rate') -> str:
        """Both periods, both rates and what the difference means ('' when equal); ``rate_name``
        is what the reader sets the rate with (the agent's parameter, the launcher's ``--rate``)."""
        if self.equal:
            return ''
        period, dt = self.control_period, self.policy_dt
        if self.whole_multiple:
            how = f'every command is held {round(self.ratio)} policy steps'
        elif self.ratio > 1:
            how = f'every command is held {self.ratio:.3g} policy steps (not a whole number)'
        else:
            how = f'every command is held {self.ratio:.3g} of a policy step (the policy expects longer holds)'
        return (
            f"control period {period:g} s ({rate_name} {1 / period:g} Hz) differs from the policy's dt "
            f'{dt:g} s ({1 / dt:g} Hz): {how}, so the swarm does not run the controller that was trained. '
            f'Use a policy trained for this period (training.train --set data.policy_dt={period:g}) or '
            f'{rate_name} {1 / dt:g}'
        )


def check_control_period(control_rate: float, policy_dt: float) -> PeriodCheck:
    """Compare a control rate in Hz with a policy's dt in seconds (both > 0)."""
    if not (control_rate > 0 and math.isfinite(control_rate)):
        raise ValueError(f'control_rate must be > 0 Hz, got {control_rate}')
    if not (policy_dt > 0 and math.isfinite(policy_dt)):
        raise ValueError(f'policy dt must be > 0 s, got {policy_dt}')
    return PeriodCheck(1.0 / float(control_rate), float(policy_dt))


def shipped_policy_for_rate(scenario: str, rate: float) -> Tuple[Path, bool]:
    """The shipped policy of ``scenario`` for realtime control at ``rate`` Hz.

    ``policies/<scenario>_<rate>hz.pt`` (e.g. ``flock2d_20hz.pt``) when it is shipped and its
    dt is ``1 / rate``, else the scenario's default ``policies/<scenario>.pt``. Returns
    ``(path, matched)``: ``matched`` says whether the policy's dt equals the control period.

    Raises:
        PolicyError: no shipped policy of ``scenario`` at all.
    """
    # knode.json only: an onnxruntime robot never imports torch to pick its policy
    from knode_swarm_ros.core.policy_meta import PolicyError, read_pt_meta, shipped_policy_path

    default = shipped_policy_path(scenario)
    try:
        path = shipped_policy_path(f'{scenario}_{rate:g}hz')
        if check_control_period(rate, float(read_pt_meta(path)['dt'])).equal:
            return path, True
    except PolicyError:
        pass
    return default, check_control_period(rate, float(read_pt_meta(default)['dt'])).equal
