"""Tracks: the source-neutral input of the importers (``training.import_bag``, ``training.import_tracks``).

A :class:`Track` is one robot's stamped samples, whatever they were read from (a bag topic, a CSV
file, a tracker's array); :mod:`training.data.timeline` puts the tracks of one episode on the
output grid and :mod:`training.data.derive` fills in the velocities or headings they lack. The
options of that shared part are :class:`ResampleOptions` (docs/import_bag.md, docs/scenarios.md
"Data in").
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from typing import List, Optional

import numpy as np

from knode_swarm_ros.core import get_scenario
from knode_swarm_ros.core.errors import KnodeError

from .smoother import SmoothedTrack

__all__ = [
    'add_resample_arguments',
    'resample_option_values',
    'TrackError',
    'Track',
    'ResampleOptions',
    'GAP_FACTOR',
    'SMOOTH_METHODS',
    'SHARED_META',
    'check_resample_options',
    'split_meta',
    'dataset_meta',
]

#: ``--smooth``: the smoother (default), or finite differences raw or filtered.
SMOOTH_METHODS = ('rts', 'none', 'moving-average', 'savgol')

#: Default gap threshold in units of the slowest robot's median sample interval.
GAP_FACTOR = 5.0


class TrackError(KnodeError, ValueError):
    """Tracks that cannot be resampled or derived as asked; the message names the file, robot and time."""


@dataclass
class Track:
    """One robot's samples as arrays, stamps strictly increasing.

    Attributes:
        id: the robot id (output robots are in ascending id order).
        name: where the samples came from (topic, frame, ``id 3`` of a CSV file).
        ns: int64 stamps ``[m]``; ``t`` (float seconds after the episode's first stamp) is set by
            :func:`training.data.timeline.timeline`.
        pos: positions ``[m, >= dimensions]``.
        vel: given velocities ``[m, >= dimensions]`` in the world frame, or None.
        heading: given headings ``[m, >= dimensions]`` (any norm), or None.
    """

    id: int
    name: str
    ns: np.ndarray = None
    pos: np.ndarray = None
    vel: Optional[np.ndarray] = None
    heading: Optional[np.ndarray] = None
    t: np.ndarray = None
    smoothed: Optional[SmoothedTrack] = None  # set by the smoother (--smooth rts)
    read: int = 0
    reordered: int = 0  # samples that arrived after a later stamp, placed by their stamp
    duplicates: int = 0
    non_finite: int = 0

    @property
    def label(self) -> str:
        return f'robot {self.id} ({self.name})'

    def given_velocity(self, frame: str) -> np.ndarray:
        """Velocities ``[m, >= dimensions]`` in the world frame (``frame`` matters to bag twists only)."""
        return self.vel

    def given_heading(self) -> np.ndarray:
        """Headings ``[m, >= dimensions]``, not necessarily of unit norm."""
        return self.heading


@dataclass
class ResampleOptions:
    """How tracks become trajectories: grid, gaps, lengths, derivation (shared by both importers)."""

    scenario: str
    rate: float
    max_gap: Optional[float] = None  # seconds; default GAP_FACTOR x slowest median interval
    min_duration: float = 1.0  # seconds; shorter segments are dropped
    length: Optional[int] = None  # frames per trajectory; default the shortest kept segment
    smooth: str = 'rts'  # rts (smoother, positions too) | none | moving-average | savgol (differences)
    smooth_window: int = 5  # odd, in output samples
    smooth_order: int = 2  # savgol polynomial order
    use_twist: bool = False  # velocity / heading direction from the given velocities
    twist_frame: str = 'body'  # frame of a bag's twist: body (REP 105) | world
    use_orientation: bool = False  # heading from the given headings (a bag: the pose orientation)
    heading_diff: str = 'backward'  # position_heading: backward | central differences
    min_speed: float = 1e-3  # position_heading: slower samples take the nearest valid heading
    velocity_estimator: int = 0  # N > 0: velocities by the agents' causal estimator (window N samples)
    test_trajectories: int = 0  # the last K trajectories form meta.split.test


def check_resample_options(opts: ResampleOptions, error=TrackError) -> None:
    """Refuse inconsistent options with ``error`` naming the option."""
    spec = get_scenario(opts.scenario)
    if not (np.isfinite(opts.rate) and opts.rate > 0):
        raise error(f'--rate must be a positive number of Hz, got {opts.rate}')
    if opts.use_twist and opts.use_orientation:
        raise error('--use-twist and --use-orientation exclude each other')
    if opts.use_orientation and spec.heading is None:
        raise error('--use-orientation is for boids3d headings; flock2d needs no orientation')
    if opts.smooth not in SMOOTH_METHODS:
        raise error(f'--smooth {opts.smooth}: choose {", ".join(SMOOTH_METHODS)}')
    if opts.smooth in ('moving-average', 'savgol') and (
        opts.smooth_window < 3 or opts.smooth_window % 2 == 0
    ):
        raise error(f'--smooth-window must be odd and >= 3, got {opts.smooth_window}')
    if opts.smooth == 'savgol' and not (0 <= opts.smooth_order < opts.smooth_window):
        raise error(f'--smooth-order must be >= 0 and below --smooth-window, got {opts.smooth_order}')
    if opts.max_gap is not None and not opts.max_gap > 0:
        raise error(f'--max-gap must be positive, got {opts.max_gap}')
    if opts.length is not None and opts.length < 3:
        raise error(f'--length must be at least 3 frames, got {opts.length}')
    if opts.min_duration < 0:
        raise error(f'--min-duration must be >= 0, got {opts.min_duration}')
    if opts.test_trajectories < 0:
        raise error(f'--test-trajectories must be >= 0, got {opts.test_trajectories}')
    if opts.velocity_estimator and (opts.velocity_estimator < 2 or spec.velocity is None):
        raise error(
            f'--velocity-estimator {opts.velocity_estimator}: needs a window >= 2 and a scenario with '
            'velocities (flock2d)'
        )
    # the estimator replaces the default smoother; a second smoothing on top of it is refused
    if opts.velocity_estimator and (opts.use_twist or opts.smooth in ('moving-average', 'savgol')):
        raise error('--velocity-estimator excludes --use-twist and --smooth moving-average|savgol')
    if opts.heading_diff not in ('backward', 'central'):
        raise error(f'--heading-diff {opts.heading_diff}: choose backward or central')


def split_meta(S: int, test_trajectories: int, notes: List[str]) -> dict:
    """``meta.split``: the last K of S trajectories are the test set (at least one stays for training)."""
    k_test = min(test_trajectories, S - 1) if S > 1 else 0
    if k_test != test_trajectories:
        notes.append(f'--test-trajectories {test_trajectories}: only {S} trajectories; {k_test} held out')
    return {'train': list(range(S - k_test)), 'test': list(range(S - k_test, S))}


#: ``meta`` keys that are the same for every episode of an import (the rest is per episode).
SHARED_META = (
    'generator',
    'version',
    'scenario',
    'state_layout',
    'rate',
    'dt',
    'interpolation',
    'min_duration',
    'length',
    'length_rule',
    'derivation',
)


def dataset_meta(
    per_episode: List[dict], files: List[str], traj_meta: List[dict], test_trajectories: int, notes: List[str]
) -> dict:
    """The trajectory file's ``meta`` for episodes read from ``files``.

    One episode: its meta as it is. Several: the keys of :data:`SHARED_META` once, the rest of each
    episode's meta in ``sources[e]``. Always: ``trajectories`` (each with its ``episode``),
    ``episodes`` (the episode index of each trajectory), ``episode_files``, ``notes`` and ``split``.
    """
    if len(per_episode) == 1:
        meta = dict(per_episode[0])
    else:
        meta = {k: per_episode[0][k] for k in SHARED_META if k in per_episode[0]}
        meta['sources'] = [{k: v for k, v in m.items() if k not in SHARED_META} for m in per_episode]
    meta['trajectories'] = traj_meta
    meta['episodes'] = [tm['episode'] for tm in traj_meta]
    meta['episode_files'] = [str(f) for f in files]
    meta['split'] = split_meta(len(traj_meta), test_trajectories, notes)
    meta['notes'] = notes
    return meta


def add_resample_arguments(p: argparse.ArgumentParser) -> None:
    """The options of :class:`ResampleOptions` on an importer's command line (import_bag and
    import_tracks read them alike): gaps, segments, smoothing and derivation, the test split."""
    p.add_argument(
        '--max-gap',
        type=float,
        metavar='SECONDS',
        help=f'a robot silent longer than this cuts the recording; default {GAP_FACTOR:g} x the '
        "slowest robot's median sample interval",
    )
    p.add_argument(
        '--min-duration',
        type=float,
        default=1.0,
        metavar='SECONDS',
        help='drop segments shorter than this (default 1.0)',
    )
    p.add_argument(
        '--length',
        type=int,
        metavar='FRAMES',
        help='frames per trajectory; default the shortest kept segment of all inputs. Longer '
        'segments are cut into windows sharing their boundary frame',
    )
    p.add_argument(
        '--smooth',
        choices=SMOOTH_METHODS,
        default='rts',
        help='rts (default): a Rauch-Tung-Striebel smoother with a constant-acceleration model estimates '
        "positions and velocities at the samples' stamps, its noise level estimated from the data; "
        'none: central differences of the resampled positions; moving-average, savgol: those '
        'differences filtered',
    )
    p.add_argument(
        '--smooth-window', type=int, default=5, metavar='N', help='odd window in output samples (5)'
    )
    p.add_argument(
        '--velocity-estimator',
        type=int,
        default=0,
        metavar='N',
        help="flock2d: velocities by the agents' causal estimator over N samples, as robots hearing "
        'poses only estimate them (default 0: finite differences)',
    )
    p.add_argument('--smooth-order', type=int, default=2, metavar='K', help='Savitzky-Golay order (2)')
    p.add_argument(
        '--heading-diff',
        choices=('backward', 'central'),
        default=None,
        help='headings: differences for the motion direction (default backward: the heading at '
        'frame k is the direction of the last step, as in the first-order rollout)',
    )
    p.add_argument(
        '--min-speed',
        type=float,
        default=1e-3,
        metavar='M_PER_S',
        help='headings: frames slower than this take the nearest valid heading (default 0.001)',
    )
    p.add_argument(
        '--test-trajectories',
        type=int,
        default=0,
        metavar='K',
        help='hold out the last K trajectories as meta.split.test (default 0)',
    )


def resample_option_values(args: argparse.Namespace) -> dict:
    """The :class:`ResampleOptions` fields read by :func:`add_resample_arguments`, from parsed ``args``
    (each importer adds its scenario, rate and options of its own)."""
    return dict(
        max_gap=args.max_gap,
        min_duration=args.min_duration,
        length=args.length,
        smooth=args.smooth,
        smooth_window=args.smooth_window,
        smooth_order=args.smooth_order,
        velocity_estimator=args.velocity_estimator,
        heading_diff=args.heading_diff or 'backward',
        min_speed=args.min_speed,
        test_trajectories=args.test_trajectories,
    )
