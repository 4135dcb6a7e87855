"""What an import records: message accounting, how states were derived, ``meta`` and the summary."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Dict, List

import numpy as np

from knode_swarm_ros.core import get_scenario

from ..derive import noise_lines, smoother_derivation, uses_smoother
from ..timeline import Timeline
from .options import FORMAT_VERSION, ImportOptions
from .robots import Robot

__all__ = ['message_counts', 'derivation', 'build_meta', 'summary_lines']


def message_counts(
    robots: List[Robot], tl: Timeline, traj_meta, T: int, dt: float, ignored: Dict[str, int]
) -> Dict[str, Any]:
    """Read / used / dropped messages, in total and per robot. A message is used when it brackets
    or lies inside a kept trajectory's span."""
    used = 0
    per_robot = {}
    for r in robots:
        mask = np.zeros(r.t.size, dtype=bool)
        for tm in traj_meta:
            ta, tb = tm['start_time'], tm['start_time'] + (T - 1) * dt
            lo = max(int(np.searchsorted(r.t, ta - 1e-9, 'right')) - 1, 0)
            hi = min(int(np.searchsorted(r.t, tb + 1e-9, 'left')), r.t.size - 1)
            mask[lo : hi + 1] = True
        u = int(mask.sum())
        used += u
        per_robot[str(r.id)] = {
            'source': r.name,
            'read': r.read,
            'used': u,
            'duplicates': r.duplicates,
            'reordered': r.reordered,
            'non_finite': r.non_finite,
            'unused': r.read - u - r.duplicates - r.non_finite,
            'median_interval': tl.medians[r.id],
        }
    read = sum(r.read for r in robots)
    duplicates = sum(r.duplicates for r in robots)
    reordered = sum(r.reordered for r in robots)
    non_finite = sum(r.non_finite for r in robots)
    return {
        'read': read,
        'used': used,
        'duplicates': duplicates,
        'reordered': reordered,
        'non_finite': non_finite,
        'unused': read - used - duplicates - non_finite,
        'ignored_sources': ignored,
        'per_robot': per_robot,
    }


def derivation(opts: ImportOptions, notes: List[str]) -> Dict[str, Any]:
    """Where the velocities or headings came from, and the smoothing applied."""
    spec = get_scenario(opts.scenario)
    if spec.state == 'position':
        return {'nothing': 'the state is the position alone'}
    if uses_smoother(opts):
        derived = {
            spec.state.split('_')[1]: smoother_derivation(opts),
            'smoothing': {'method': 'rts', 'applies_to': "positions and velocities, at the samples' stamps"},
        }
        if spec.heading is not None:
            derived['min_speed'] = opts.min_speed
        return derived
    if spec.velocity is not None:
        derived = {
            'velocity': 'Odometry twist.twist.linear (' + opts.twist_frame + ' frame), linear interpolation'
            if opts.use_twist
            else 'central differences of the resampled positions (second-order one-sided at segment ends)'
        }
    elif opts.use_orientation:
        derived = {'heading': '+x axis of the pose orientation, linearly interpolated and renormalised'}
    else:
        derived = {
            'heading': ('direction of the Odometry twist.twist.linear (' + opts.twist_frame + ' frame)')
            if opts.use_twist
            else f'direction of {opts.heading_diff} differences of the resampled positions',
            'min_speed': opts.min_speed,
        }
    uses_differences = not (opts.use_twist or opts.use_orientation)
    derived['smoothing'] = (
        {
            'method': opts.smooth,
            'window': opts.smooth_window,
            **({'order': opts.smooth_order} if opts.smooth == 'savgol' else {}),
            'applies_to': 'the finite-difference velocities (positions are not smoothed)',
        }
        if opts.smooth in ('moving-average', 'savgol') and uses_differences
        else {'method': 'none'}
    )
    if opts.smooth in ('moving-average', 'savgol') and not uses_differences:
        notes.append(
            '--smooth applies to finite-difference velocities only; ignored with '
            + ('--use-twist' if opts.use_twist else '--use-orientation')
        )
    return derived


def build_meta(
    opts: ImportOptions,
    bag,
    robots: List[Robot],
    info: Dict[str, Any],
    tl: Timeline,
    dt: float,
    segments,
    T: int,
    derived,
    messages,
) -> Dict[str, Any]:
    """One bag's part of the trajectory file's ``meta`` (docs/import_bag.md, "Output"); the
    trajectories, episodes, notes and split are added by :func:`training.data.tracks.dataset_meta`."""
    length_rule = '--length' if opts.length is not None else 'the shortest kept segment'
    return {
        'generator': 'training.import_bag',
        'version': FORMAT_VERSION,
        'scenario': opts.scenario,
        'state_layout': list(get_scenario(opts.scenario).state_layout),
        'bag': {
            'path': str(Path(bag.path).resolve()),
            'kind': bag.kind,
            'files': [f.name for f in bag.files],
        },
        'topic_patterns': opts.topics or (['/tf'] if opts.frames else sorted(opts.id_map or {})),
        'frame_patterns': opts.frames,
        'topics': info['matched_topics'],
        'message_types': info['types'],
        'frame_id': info['frame_id'],
        'robots': [
            {'index': i, 'id': r.id, 'source': r.name, 'topic': r.topic, 'type': r.type_name}
            for i, r in enumerate(robots)
        ],
        'robot_ids': [r.id for r in robots],
        'id_map': opts.id_map,
        'id_rule': '--id-map' if opts.id_map is not None else 'first integer in the topic or frame name',
        'rate': 1.0 / dt,
        'dt': dt,
        'stamp': opts.stamp,
        't0_ns': tl.t0_ns,
        'grid': {
            'anchor': tl.anchor,
            'anchor_ns': tl.t0_ns + int(round(tl.anchor * 1e9)),
            'rule': 'frame j of trajectory i is at t0 + anchor + (trajectories[i].grid_index + j) * dt',
        },
        'interpolation': 'linear in time (positions; headings renormalised)',
        'max_gap': tl.max_gap,
        'max_gap_rule': tl.gap_rule,
        'gaps': tl.gaps,
        'min_duration': opts.min_duration,
        'segments': segments,
        'length': T,
        'length_rule': length_rule
        + '; longer segments are cut into windows of T frames sharing their boundary frame',
        'derivation': derived,
        'noise': info.get('noise'),
        'messages': messages,
    }


def summary_lines(bag, robots: List[Robot], info, meta, out) -> List[str]:
    lines = []
    nfiles = len(meta['bag']['files'])
    lines.append(f'bag: {meta["bag"]["path"]} ({bag.kind}, {nfiles} file{"s" * (nfiles != 1)})')
    types = sorted(set(info['types'].values()))
    ids = [r.id for r in robots]
    lines.append(
        f'robots: {len(robots)} (ids {", ".join(map(str, ids))}) from {len(info["matched_topics"])} '
        f"topic(s) [{', '.join(types)}], frame '{meta['frame_id']}'"
    )
    span = max(r.t[-1] for r in robots)
    lines.append(
        f'recording: {span:.3f} s; resampled at {meta["rate"]:g} Hz (dt {meta["dt"]:.6g} s); '
        f'max gap {meta["max_gap"]:.4g} s ({meta["max_gap_rule"]})'
    )
    if meta['gaps']:
        lines.append(f'gaps: {len(meta["gaps"])} (every robot is cut there)')
        for g in meta['gaps']:
            lines.append(
                f'  robot {g["robot"]} ({g["source"]}) silent {g["duration"]:.3f} s '
                f'from t = {g["from"]:.3f} s to {g["to"]:.3f} s'
            )
    else:
        lines.append('gaps: none')
    kept = [s for s in meta['segments'] if s['kept']]
    lines.append(
        f'segments: {len(meta["segments"])} where all robots are observed, {len(kept)} kept, '
        f'{len(meta["segments"]) - len(kept)} dropped'
    )
    for i, s in enumerate(meta['segments']):
        what = (
            f'kept -> trajectories {s["trajectories"]}, {s["unused_frames"]} trailing frame(s) unused'
            if s['kept']
            else f'dropped: {s["reason"]}'
        )
        lines.append(f'  [{i}] t = {s["start"]:.3f} .. {s["end"]:.3f} s, {s["frames"]} frames: {what}')
    S, T = out.shape[:2]
    lines.append(
        f'trajectories: {S} x {T} frames ({(T - 1) * meta["dt"]:.3f} s each, length = '
        f'{meta["length_rule"].split(";")[0]})'
    )
    d = meta['derivation']
    lines.append(
        f'derived: {d.get("velocity") or d.get("heading")}; smoothing {d["smoothing"]["method"]}'
        + (f' (window {d["smoothing"]["window"]})' if 'window' in d['smoothing'] else '')
    )
    lines.extend(noise_lines(meta.get('noise')))
    m = meta['messages']
    lines.append(
        f'messages: {m["read"]} read, {m["used"]} used, {m["read"] - m["used"]} not used '
        f'({m["duplicates"]} duplicate stamps, {m["non_finite"]} non-finite, {m["unused"]} outside the '
        f'kept trajectories)'
        + (f'; {m["reordered"]} arrived late, placed by stamp' if m.get('reordered') else '')
    )
    if m['ignored_sources']:
        lines.append('ignored: ' + ', '.join(f'{k} ({v})' for k, v in sorted(m['ignored_sources'].items())))
    for note in meta['notes']:
        lines.append(f'note: {note}')
    return lines
