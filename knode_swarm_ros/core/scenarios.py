"""The two swarm scenarios of the paper: state layout, dynamics and command kind.

A state vector z has ``state_dim`` entries laid out as ``state_layout``; positions always
come first (``position``), followed by velocity (flock2d) or unit heading (boids3d).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Dict, Optional, Tuple

__all__ = ['Scenario', 'SCENARIOS', 'get_scenario']


@dataclass(frozen=True)
class Scenario:
    """Static description of a scenario (see docs/DESIGN.md, "Scenarios").

    Attributes:
        name: ``flock2d`` or ``boids3d``.
        state_layout: names of the ``state_dim`` entries of z.
        position_dim: p, the number of position entries (z[:p] is the position).
        command: ``acceleration`` (double integrator) or ``velocity`` (first order).
        command_dim: m, the number of command entries (equals ``position_dim``).
        dt: the ground-truth integration step in seconds.
        box: half width of the cube walls, or None for an unbounded plane.
        translation_invariant: whether the true dynamics ignore absolute position
            (no walls), which lets the ``relative`` input frame drop the own position.
    """

    name: str
    state_layout: Tuple[str, ...]
    position_dim: int
    command: str
    dt: float
    box: Optional[float]

    @property
    def state_dim(self) -> int:
        return len(self.state_layout)

    @property
    def command_dim(self) -> int:
        return self.position_dim

    @property
    def position(self) -> slice:
        """Slice of z holding the position."""
        return slice(0, self.position_dim)

    @property
    def velocity(self) -> Optional[slice]:
        """Slice of z holding the velocity (flock2d), else None."""
        return slice(self.position_dim, self.state_dim) if self.command == 'acceleration' else None

    @property
    def heading(self) -> Optional[slice]:
        """Slice of z holding the unit heading (boids3d), else None."""
        return slice(self.position_dim, self.state_dim) if self.command == 'velocity' else None

    @property
    def translation_invariant(self) -> bool:
        return self.box is None


SCENARIOS: Dict[str, Scenario] = {
    'flock2d': Scenario('flock2d', ('px', 'py', 'vx', 'vy'), 2, 'acceleration', 0.01, None),
    'boids3d': Scenario('boids3d', ('px', 'py', 'pz', 'hx', 'hy', 'hz'), 3, 'velocity', 1.0 / 60.0, 5.0),
}


def get_scenario(name: str) -> Scenario:
    """Return the scenario called ``name``; unknown names raise ValueError listing the known ones."""
    try:
        return SCENARIOS[name]
    except KeyError:
        raise ValueError(f'unknown scenario {name!r}; known: {", ".join(sorted(SCENARIOS))}') from None
