"""Import tracked swarms (CSV tracks, video trackers' ``.npy`` arrays) into one trajectory file
(docs/scenarios.md, "Data in").

    python -m training.import_tracks run1.csv run2.csv --scenario my_swarm.yaml --out data/my.npz
    python -m training.import_tracks fish.npy --fps 30 --scenario my_fish.yaml --out data/fish.npz

Each file is one episode (:mod:`training.data.track_files` reads them). The tracks are resampled
onto the scenario's ``dt`` (or ``--dt``) with the rules of ``training.import_bag``, through the same
code (:mod:`training.data.timeline`, :mod:`training.data.derive`): linear interpolation of
positions; only the time where every robot is observed; a cut where any robot is missing longer
than ``--max-gap``; velocities or headings the file lacks derived from the positions, given
``vx, vy`` / ``hx, hy`` columns used as they are. Every episode's segments are cut into windows of
one length T (``--length``, default the shortest kept segment of all files), so
``meta.episodes[i]`` says which file trajectory i came from. A file that is a single frame with
the full state is an initial condition (a trajectory of T = 1).

Exit status: 0 written; 2 bad input or command line (the message names the file, robot, time,
column or option; nothing is written).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path
from typing import Any, Dict, List, Optional, Sequence

import numpy as np

from knode_swarm_ros.core.cli import cli
from knode_swarm_ros.core.errors import KnodeError
from knode_swarm_ros.core.scenarios import Scenario, get_scenario, parse_scenario_argument
from knode_swarm_ros.core.trajectory import TrajectoryError, save_trajectories
from training.data.bags.options import ImportResult
from training.data.derive import (
    derive_states,
    noise_lines,
    smooth_episode,
    smoother_derivation,
    uses_smoother,
)
from training.data.timeline import segments, stack_episodes, timeline
from training.data.track_files import read_track_file, single_frame
from training.data.tracks import (
    ResampleOptions,
    Track,
    TrackError,
    add_resample_arguments,
    check_resample_options,
    dataset_meta,
    resample_option_values,
)

__all__ = ['import_tracks', 'main', 'TrackError']

FORMAT_VERSION = 1


def _given(info: Dict[str, Any], spec: Scenario) -> str:
    """What the file gives beyond positions that the state uses: ``velocity``, ``heading`` or ``none``."""
    cols = info['columns']
    has_v, has_h = 'vx' in cols, 'hx' in cols
    if spec.velocity is not None and has_v:
        return 'velocity'
    if spec.heading is not None and has_h:
        return 'heading'
    if spec.heading is not None and has_v:
        return 'velocity'  # the heading is the direction of the given velocity
    return 'none'


def _derivation(spec: Scenario, given: str, opts: ResampleOptions) -> Dict[str, Any]:
    if spec.state == 'position':
        return {'nothing': 'the state is the position alone'}
    key = 'velocity' if spec.velocity is not None else 'heading'
    if given == 'velocity':
        how = 'the given vx, vy[, vz], linear interpolation' + (
            ', their direction' if key == 'heading' else ''
        )
    elif given == 'heading':
        how = 'the given hx, hy[, hz], linearly interpolated and renormalised'
    elif uses_smoother(opts):
        how = smoother_derivation(opts)
    elif key == 'velocity':
        how = 'central differences of the resampled positions (second-order one-sided at segment ends)'
    else:
        how = f'direction of {opts.heading_diff} differences of the resampled positions'
    out: Dict[str, Any] = {key: how}
    if key == 'heading' and given != 'heading':
        out['min_speed'] = opts.min_speed
    differences = given == 'none'
    if differences and uses_smoother(opts):
        out['smoothing'] = {'method': 'rts', 'applies_to': "positions and velocities, at the samples' stamps"}
        return out
    out['smoothing'] = (
        {
            'method': opts.smooth,
            'window': opts.smooth_window,
            'applies_to': 'the finite-difference velocities',
        }
        if opts.smooth in ('moving-average', 'savgol') and differences
        else {'method': 'none'}
    )
    return out


def _initial_condition(tracks: List[Track], spec: Scenario, given: str, where: str, t: float) -> np.ndarray:
    """States ``[1, n, d]`` of a one-frame file; refused when the state needs what one frame cannot give."""
    p = spec.dimensions
    pos = np.stack([r.pos[0, :p] for r in tracks])
    if spec.state == 'position':
        return pos[None]
    kind = 'velocity' if spec.velocity is not None else 'heading'
    if given == 'none':
        need = ', '.join(kind[0] + a for a in 'xyz'[:p])
        raise TrackError(
            f'{where}: a single frame (t = {t:.3f} s) gives no {need} for {tracks[0].label}: '
            f'a {kind} cannot be derived from one frame'
        )
    extra = np.stack([(r.vel if given == 'velocity' else r.heading)[0, :p] for r in tracks])
    if spec.heading is not None:
        norm = np.linalg.norm(extra, axis=1)
        if np.any(norm < 1e-12):
            r = tracks[int(np.argmax(norm < 1e-12))]
            raise TrackError(f'{where}: {r.label} has a zero heading at t = {t:.3f} s')
        extra = extra / norm[:, None]
    return np.concatenate([pos, extra], axis=1)[None]


def import_tracks(paths: Sequence, opts: ResampleOptions, fps: Optional[float] = None) -> ImportResult:
    """Read each track file as one episode and build one dataset; raises :class:`TrackError`."""
    check_resample_options(opts)
    spec = get_scenario(opts.scenario)
    dt = 1.0 / opts.rate
    notes: List[str] = []
    files = [read_track_file(path, spec, fps) for path in paths]
    given = [_given(info, spec) for _, info in files]
    if len(set(given)) > 1:
        k = given.index(next(g for g in given if g != given[0]))
        raise TrackError(
            f'{paths[k]}: gives {given[k]} columns but {paths[0]} gives {given[0]}; the files of one '
            f'dataset need the same columns'
        )
    opts = dataclasses.replace(
        opts, use_twist=given[0] == 'velocity', twist_frame='world', use_orientation=given[0] == 'heading'
    )
    for path, (_, info) in zip(paths, files):
        if info.get('ignored_columns'):
            notes.append(f'{path}: columns not used: {", ".join(info["ignored_columns"])}')
    frames = [single_frame(tracks) for tracks, _ in files]
    if any(t is not None for t in frames):
        return _initial_conditions(paths, files, frames, spec, given[0], opts, dt, notes)

    episodes = []
    for path, (tracks, _) in zip(paths, files):
        for r in tracks:
            if r.ns.size < 2:
                raise TrackError(
                    f'{path}: {r.label} has one usable sample (t = {r.ns[0] * 1e-9:.3f} s) while the '
                    f'file holds more frames; nothing to interpolate'
                )
        tl = timeline(tracks, opts.max_gap, str(path))
        noise = smooth_episode(tracks, opts, tl.medians)
        metas, kept = segments(
            tl,
            opts,
            dt,
            lambda t, label, tracks=tracks: derive_states(t, tracks, opts, dt, notes, label),
            str(path),
        )
        episodes.append((tracks, tl, metas, kept, noise))
    states, traj_meta, T = stack_episodes(
        [(tl, metas, kept) for _, tl, metas, kept, _ in episodes], opts.length, dt, [str(p) for p in paths]
    )
    derived = _derivation(spec, given[0], opts)
    length_rule = '--length' if opts.length is not None else 'the shortest kept segment of all files'
    per_episode = []
    for path, (_, info), (tracks, tl, metas, _, noise) in zip(paths, files, episodes):
        per_episode.append(
            {
                **_common_meta(opts, spec, dt, derived),
                'length': T,
                'length_rule': length_rule
                + '; longer segments are cut into windows of T frames sharing their boundary frame',
                'file': {'path': str(Path(path).resolve()), **info},
                'robot_ids': [r.id for r in tracks],
                'samples': {
                    str(r.id): {'read': r.read, 'duplicates': r.duplicates, 'non_finite': r.non_finite}
                    for r in tracks
                },
                't0_ns': tl.t0_ns,
                'grid': {
                    'anchor': tl.anchor,
                    'rule': 'frame j of trajectory i is at t0 + anchor + (trajectories[i].grid_index + j) * dt',
                },
                'max_gap': tl.max_gap,
                'max_gap_rule': tl.gap_rule,
                'gaps': tl.gaps,
                'segments': metas,
                'noise': noise,
            }
        )
    meta = dataset_meta(per_episode, list(paths), traj_meta, opts.test_trajectories, notes)
    summary = []
    for e, (path, (tracks, tl, metas, _, noise)) in enumerate(zip(paths, episodes)):
        ids = ', '.join(str(r.id) for r in tracks)
        kept = [s for s in metas if s['kept']]
        summary.append(
            f'episode {e}: {path}: {len(tracks)} robots (ids {ids}); max gap {tl.max_gap:.4g} s; '
            f'{len(tl.gaps)} gap(s); {len(kept)} of {len(metas)} segment(s) kept -> '
            f'{meta["episodes"].count(e)} trajectories'
        )
        summary.extend(f'  {line}' for line in noise_lines(noise))
        for g in tl.gaps:
            summary.append(
                f'  robot {g["robot"]} missing {g["duration"]:.3f} s from t = {g["from"]:.3f} s to {g["to"]:.3f} s'
            )
        for s in metas:
            if not s['kept']:
                summary.append(f'  t = {s["start"]:.3f} .. {s["end"]:.3f} s dropped: {s["reason"]}')
    S = states.shape[0]
    summary.append(f'trajectories: {S} x {T} frames ({(T - 1) * dt:.3f} s each, length = {length_rule})')
    summary.append(f'derived: {derived.get("velocity") or derived.get("heading") or "nothing"}')
    summary.extend(f'note: {note}' for note in notes)
    return ImportResult(states, dt, opts.scenario, meta, summary)


def _common_meta(opts: ResampleOptions, spec: Scenario, dt: float, derived) -> Dict[str, Any]:
    return {
        'generator': 'training.import_tracks',
        'version': FORMAT_VERSION,
        'scenario': opts.scenario,
        'state_layout': list(spec.state_layout),
        'rate': 1.0 / dt,
        'dt': dt,
        'interpolation': 'linear in time (positions; given velocities; given headings renormalised)',
        'min_duration': opts.min_duration,
        'derivation': derived,
    }


def _initial_conditions(paths, files, frames, spec, given, opts, dt, notes) -> ImportResult:
    """Files of one frame each: one trajectory of T = 1 per file."""
    several = [p for p, t in zip(paths, frames) if t is None]
    if several:
        one = paths[frames.index(next(t for t in frames if t is not None))]
        raise TrackError(
            f'{several[0]}: holds several frames but {one} is a single frame (an initial condition); '
            f'import initial conditions and trajectories separately'
        )
    states = []
    for path, (tracks, _), t in zip(paths, files, frames):
        states.append(_initial_condition(tracks, spec, given, str(path), t))
    n = {s.shape[1] for s in states}
    if len(n) > 1:
        raise TrackError(
            f'{paths[-1]}: the files of one dataset need the same number of robots ({sorted(n)})'
        )
    derived = {'nothing': 'initial conditions: the state as given'}
    per_episode = [
        {
            **_common_meta(opts, spec, dt, derived),
            'length': 1,
            'length_rule': 'a single frame: an initial condition',
            'file': {'path': str(Path(path).resolve()), **info},
            'robot_ids': [r.id for r in tracks],
            'time': t,
        }
        for path, (tracks, info), t in zip(paths, files, frames)
    ]
    traj_meta = [{'episode': e, 'start_time': t, 'frames': 1} for e, t in enumerate(frames)]
    meta = dataset_meta(per_episode, list(paths), traj_meta, opts.test_trajectories, notes)
    summary = [f'initial conditions: {len(states)} file(s), {states[0].shape[1]} robots each (T = 1)']
    summary.extend(f'note: {note}' for note in notes)
    return ImportResult(np.stack(states), dt, opts.scenario, meta, summary)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog='python -m training.import_tracks',
        description='Import tracked swarms (CSV tracks, .npy arrays of video trackers) into one trajectory file (.npz).',
        epilog='Details: docs/scenarios.md, "Data in"',
    )
    p.add_argument(
        'files',
        nargs='+',
        metavar='FILE',
        help='.csv with a header t,id,x,y[,z] (optional vx,vy[,vz] or hx,hy[,hz]), or .npy [T, n, dim] '
        'with --fps; each file is one episode',
    )
    p.add_argument(
        '--scenario', required=True, metavar='NAME|FILE.yaml', help='the swarm (docs/scenarios.md)'
    )
    p.add_argument('--out', required=True, metavar='FILE.npz', help='trajectory file to write')
    p.add_argument('--fps', type=float, metavar='HZ', help='frame rate of .npy arrays')
    p.add_argument('--dt', type=float, metavar='SECONDS', help="output step; default the scenario's dt")
    add_resample_arguments(p)
    return p


@cli('python -m training.import_tracks')
def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    args.scenario = parse_scenario_argument(args.scenario)
    dt = get_scenario(args.scenario).dt if args.dt is None else args.dt
    if not (np.isfinite(dt) and dt > 0):
        parser.error(f'argument --dt: must be a positive number of seconds, got {dt}')
    if args.fps is not None and not (np.isfinite(args.fps) and args.fps > 0):
        parser.error(f'argument --fps: must be a positive number, got {args.fps}')
    try:  # a failure writes nothing (save_trajectories is atomic): say so
        opts = ResampleOptions(
            scenario=args.scenario,
            rate=1.0 / dt,
            **resample_option_values(args),
        )
        result = import_tracks(args.files, opts, args.fps)
        meta = dict(
            result.meta,
            command=' '.join(
                ['python -m training.import_tracks'] + list(sys.argv[1:] if argv is None else argv)
            ),
        )
        save_trajectories(args.out, result.states, result.dt, result.scenario, meta)
    except (TrackError, TrajectoryError, OSError) as exc:
        raise KnodeError(f'{exc}; nothing written') from None
    for line in result.summary:
        print(line)
    print(
        f'wrote {args.out}: states {list(result.states.shape)} ({get_scenario(result.scenario).name}, dt {result.dt:.6g} s)'
    )
    return 0


if __name__ == '__main__':
    sys.exit(main())
