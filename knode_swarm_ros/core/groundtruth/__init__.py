"""Ground-truth swarms of the paper (numpy only): what the learner observes but never sees.

* ``flock2d``: Tanner, Jadbabaie and Pappas' global flocking controller, classical RK4,
  dt = 0.01 (:mod:`.tanner`); presets (variants) ``paper`` and ``gym_flock``.
* ``boids3d``: Reynolds boids after Sebastian Lague's Unity implementation, dt = 1/60,
  walls of the cube [-5, 5]^3 (:mod:`.boids`); presets ``paper`` and ``published``.

:func:`simulate` turns either into observation arrays ``[S, T, n, d]`` for trajectory files;
:class:`TannerSwarm` and :class:`BoidsSwarm` step one or S swarms at a time (the simulator's
ground-truth mode). See docs/groundtruth.md.
"""

from __future__ import annotations

from typing import Any, Dict, Optional

import numpy as np

from knode_swarm_ros.core.scenarios import get_scenario

from . import boids, tanner
from .boids import DISCARD_FRAMES, BoidsParams, BoidsSwarm
from .boids import PRESETS as BOIDS_PRESETS
from .tanner import VARIANTS as TANNER_VARIANTS
from .tanner import TannerSwarm

__all__ = [
    'simulate',
    'follow',
    'parameters',
    'presets',
    'default_preset',
    'TannerSwarm',
    'BoidsSwarm',
    'BoidsParams',
    'DISCARD_FRAMES',
    'tanner',
    'boids',
]


def presets(scenario: str) -> tuple:
    """Names of the presets of ``scenario`` (flock2d: its variants), the paper's first."""
    get_scenario(scenario)
    return tuple(TANNER_VARIANTS) if scenario == 'flock2d' else tuple(BOIDS_PRESETS)


def default_preset(scenario: str) -> str:
    """``paper`` for both scenarios."""
    return presets(scenario)[0]


def _check_preset(scenario: str, preset: str) -> None:
    if preset not in presets(scenario):
        kind = 'variant' if scenario == 'flock2d' else 'preset'
        raise ValueError(f'unknown {scenario} {kind} {preset!r}; known: {", ".join(presets(scenario))}')


def _check_min_separation(scenario: str, min_separation: Optional[float]) -> None:
    if min_separation is None:
        return
    if scenario != 'flock2d':
        raise ValueError('min_separation applies to flock2d only')
    if not (np.isfinite(min_separation) and min_separation > 0):
        raise ValueError(f'min_separation must be a positive number, got {min_separation!r}')


def parameters(
    scenario: str, preset: str = 'paper', min_separation: Optional[float] = None
) -> Dict[str, Any]:
    """Every parameter of the ground truth ``scenario``/``preset`` as a JSON-able dict (for ``meta``)."""
    _check_preset(scenario, preset)
    _check_min_separation(scenario, min_separation)
    if scenario == 'flock2d':
        return {
            'model': 'tanner_global',
            'variant': preset,
            'dt': tanner.DT,
            'integrator': 'rk4_classical',
            'accel_clip': tanner.variant_clip(preset),
            'v_max': tanner.V_MAX,
            'v_bias': tanner.V_BIAS,
            'min_separation': min_separation,
            'potential': 'V(r) = 1/r^2 + log r^2',
            **{k: v for k, v in TANNER_VARIANTS[preset].items() if k != 'clip'},
        }
    return {
        'model': 'lague_boids',
        'preset': preset,
        'discard_frames': DISCARD_FRAMES,
        'observation': '[p, v/|v|]',
        **BOIDS_PRESETS[preset].as_dict(),
    }


class _NoBar:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def update(self, n: int = 1) -> None:
        pass


def _progress_bar(enabled: bool, total: int, desc: str):
    if not enabled:
        return _NoBar()
    from tqdm.auto import tqdm  # only here: robots importing the core need not have tqdm

    return tqdm(total=total, desc=desc, unit='step', leave=False)


def simulate(
    scenario: str,
    trajectories: int,
    robots: int,
    steps: int,
    seed: int,
    preset: str = 'paper',
    progress: bool = True,
    min_separation: Optional[float] = None,
) -> np.ndarray:
    """Simulate ``trajectories`` independent swarms of ``robots`` robots, all stepped together.

    Args:
        scenario: ``flock2d`` or ``boids3d``.
        steps: T, the number of recorded frames. flock2d: frame 0 is the initial condition,
            followed by T - 1 RK4 steps of dt = 0.01. boids3d: frame 0 is the spawn; frames
            0 .. 9 (DISCARD_FRAMES = 10 frames) are discarded as in the paper and frames
            10 .. 9 + T are recorded, so 9 + T frames are stepped in all.
        seed: seeds ``numpy.random.default_rng``; the only randomness is the initial condition.
        preset: flock2d ``paper`` | ``gym_flock`` (initial conditions and acceleration clip);
            boids3d ``paper`` | ``published`` (boid settings).
        progress: show a tqdm progress bar on stderr.
        min_separation: flock2d only; redraw initial positions until no pair is closer than
            this (default None: the paper's draw, see :func:`tanner.initial_states`).

    Returns:
        float64 ``[trajectories, T, robots, d]``: flock2d z = [px, py, vx, vy] (d = 4);
        boids3d z = [px, py, pz, hx, hy, hz] with h = v / |v| (d = 6).
    """
    get_scenario(scenario)
    _check_preset(scenario, preset)
    _check_min_separation(scenario, min_separation)
    for name, value in (('trajectories', trajectories), ('robots', robots), ('steps', steps)):
        if int(value) != value or value < 1:
            raise ValueError(f'{name} must be a positive integer, got {value!r}')
    trajectories, robots, steps = int(trajectories), int(robots), int(steps)
    rng = np.random.default_rng(seed)
    if scenario == 'flock2d':
        swarm = TannerSwarm(tanner.initial_states(rng, trajectories, robots, preset, min_separation), preset)
        skip = 0
    else:
        swarm = BoidsSwarm.spawn(rng, trajectories, robots, BOIDS_PRESETS[preset])
        skip = DISCARD_FRAMES
    out = np.empty((trajectories, steps, robots, get_scenario(scenario).state_dim))
    frame = swarm.observe()
    with _progress_bar(progress, skip + steps - 1, f'{scenario} {preset}') as bar:
        for _ in range(skip):
            frame = swarm.step()
            bar.update()
        out[:, 0] = frame
        for t in range(1, steps):
            out[:, t] = swarm.step()
            bar.update()
    return out


def follow(scenario: str, z0: np.ndarray, frames: int, dt: float, preset: str = 'paper') -> np.ndarray:
    """The ground-truth swarm from a given start ``z0 [n, d]``: ``[frames, n, d]`` sampled every
    ``dt`` (frame 0 = ``z0``), e.g. beside a recorded run of a learnt policy from the same start.

    flock2d: the Tanner law at its own step (0.01 s) when ``dt`` is a whole multiple of it, else
    at ``dt``. boids3d: observations keep the heading, not the speed, so the boids start at their
    spawn speed ((min_speed + max_speed) / 2, what every boids3d start of this project has) and
    step at their own dt (1/60 s); ``dt`` must be a whole multiple of it. Raises ValueError for a
    bad argument.
    """
    spec = get_scenario(scenario)
    _check_preset(scenario, preset)
    z0 = np.asarray(z0, dtype=np.float64)
    if z0.ndim != 2 or z0.shape[-1] != spec.state_dim or not np.all(np.isfinite(z0)):
        raise ValueError(f'z0 must be a finite [n, {spec.state_dim}] {scenario} state, got shape {z0.shape}')
    if int(frames) != frames or frames < 1 or not (np.isfinite(dt) and dt > 0):
        raise ValueError(f'frames must be a positive integer and dt > 0, got {frames!r}, {dt!r}')
    own = tanner.DT if scenario == 'flock2d' else boids.get_preset(preset).dt
    ratio = float(dt) / own
    whole = abs(ratio - round(ratio)) < 1e-6 and round(ratio) >= 1
    sub = int(round(ratio)) if whole else 1
    if scenario == 'flock2d':
        swarm = TannerSwarm(z0[None], preset, dt=own if whole else float(dt))
    else:
        if not whole:
            raise ValueError(f'boids3d ground truth steps at {own:g} s; dt {dt:g} s is not a whole multiple')
        swarm = BoidsSwarm.from_observation(z0[None], boids.get_preset(preset))
    out = np.empty((int(frames),) + z0.shape)
    out[0] = z0
    for t in range(1, int(frames)):
        for _ in range(sub):
            frame = swarm.step()
        out[t] = frame[0]
    return out
