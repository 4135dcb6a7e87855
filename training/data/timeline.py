"""Where and when the robots of one episode are observed together: the time base, the gaps, the
segments on the output grid, and the equal-length windows cut from them (docs/import_bag.md,
"Resampling"). Works on :class:`~training.data.tracks.Track` objects, whatever their source."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Dict, List, Optional, Tuple

import numpy as np

from .tracks import GAP_FACTOR, ResampleOptions, Track, TrackError

__all__ = ['Timeline', 'timeline', 'segments', 'common_length', 'windows', 'stack_episodes']

Interval = Tuple[float, float]

#: Positions farther from the origin than this (m) are refused: a million kilometres, far beyond
#: any map or UTM coordinate (northings are below 1e7 m).
POSITION_LIMIT_M = 1e9
#: Output frames a segment may have per sample of its sparsest robot: beyond, the grid is not a
#: resampling of the data but a fabrication (and its size unbounded by the file's: times in
#: nanoseconds read as seconds asked for 1e8 frames a sample).
FRAMES_PER_SAMPLE_LIMIT = 1000


@dataclass
class Timeline:
    """The time base (seconds after ``t0_ns``) and where every robot is observed (``common``)."""

    t0_ns: int
    medians: Dict[int, float]  # robot id -> median message interval (s)
    max_gap: float
    gap_rule: str
    gaps: List[Dict[str, Any]]  # every silent stretch of every robot
    common: List[Interval]  # maximal stretches where all robots are observed
    samples: List[int]  # per stretch of ``common``: the fewest samples a robot has in it

    @property
    def anchor(self) -> float:
        """Start of the first common stretch: the grid is ``anchor + k dt``."""
        return self.common[0][0]


def _intersect(a: List[Interval], b: List[Interval]) -> List[Interval]:
    out, i, j = [], 0, 0
    while i < len(a) and j < len(b):
        lo, hi = max(a[i][0], b[j][0]), min(a[i][1], b[j][1])
        if lo <= hi:
            out.append((lo, hi))
        if a[i][1] < b[j][1]:
            i += 1
        else:
            j += 1
    return out


def timeline(robots: List[Track], max_gap: Optional[float], where) -> Timeline:
    """Set each robot's ``t`` (seconds after the first stamp) and find the gaps (longer than
    ``max_gap``, default :data:`GAP_FACTOR` x the slowest median interval) and the stretches
    where all robots are observed; ``where`` names the source (bag, file) in errors.

    Raises:
        TrackError: no common stretch, or a position beyond :data:`POSITION_LIMIT_M` (the
            smoother squares positions: 1e160 m already overflows a float).
    """
    for r in robots:
        far = np.abs(r.pos) > POSITION_LIMIT_M
        if np.any(far):
            k = int(np.nonzero(far.any(axis=1))[0][0])
            raise TrackError(
                f'{where}: {r.label} is at {r.pos[k].tolist()} m (sample {k}), beyond '
                f'{POSITION_LIMIT_M:g} m from the origin: not a position in metres'
            )
    t0_ns = min(int(r.ns[0]) for r in robots)
    for r in robots:
        r.t = (r.ns - t0_ns).astype(np.float64) * 1e-9
    medians = {r.id: float(np.median(np.diff(r.t))) for r in robots}
    if max_gap is None:
        max_gap = GAP_FACTOR * max(medians.values())
        gap_rule = (
            f"{GAP_FACTOR:g} x the slowest robot's median message interval ({max(medians.values()):.6g} s)"
        )
    else:
        max_gap, gap_rule = float(max_gap), '--max-gap'
    gaps, common = [], None
    for r in robots:
        d = np.diff(r.t)
        cut = np.nonzero(d > max_gap)[0]
        starts = np.concatenate([[0], cut + 1])
        ends = np.concatenate([cut, [r.t.size - 1]])
        intervals = [(float(r.t[a]), float(r.t[b])) for a, b in zip(starts, ends)]
        for k in cut:
            gaps.append(
                {
                    'robot': r.id,
                    'source': r.name,
                    'from': float(r.t[k]),
                    'to': float(r.t[k + 1]),
                    'duration': float(d[k]),
                    'from_ns': int(r.ns[k]),
                    'to_ns': int(r.ns[k + 1]),
                }
            )
        common = intervals if common is None else _intersect(common, intervals)
    gaps.sort(key=lambda g: (g['from'], g['robot']))
    if not common:
        raise TrackError(
            f'{where}: the robots are never all observed at the same time '
            f'({"; ".join(f"{r.label}: {r.t[0]:.3f}..{r.t[-1]:.3f} s" for r in robots)})'
        )
    samples = [
        min(int(np.searchsorted(r.t, b, 'right') - np.searchsorted(r.t, a, 'left')) for r in robots)
        for a, b in common
    ]
    return Timeline(t0_ns, medians, max_gap, gap_rule, gaps, common, samples)


def segments(
    tl: Timeline,
    opts: ResampleOptions,
    dt: float,
    derive: Callable[[np.ndarray, str], Tuple[Optional[np.ndarray], Optional[str]]],
    where,
):
    """Each common stretch on the grid: ``(segments meta, [(segment, states [L, n, d])])`` for the
    ones long enough whose states ``derive(grid times, label)`` defines; the others say why not."""
    anchor, rate = tl.anchor, 1.0 / dt
    metas: List[Dict[str, Any]] = []
    kept = []
    for (a, b), samples in zip(tl.common, tl.samples):
        ka = int(np.ceil((a - anchor) * rate - 1e-9))
        kb = int(np.floor((b - anchor) * rate + 1e-9))
        L = kb - ka + 1
        seg = {
            'start': a,
            'end': b,
            'grid_index': ka,
            'frames': max(L, 0),
            'kept': False,
            'reason': None,
            'trajectories': [],
        }
        metas.append(seg)
        duration = (L - 1) * dt
        if L < 3 or duration < opts.min_duration:
            seg['reason'] = (
                f'{max(L, 0)} frame(s), {max(duration, 0):.3f} s < --min-duration {opts.min_duration:g} s'
                if L >= 3
                else f'{max(L, 0)} frame(s) < 3'
            )
            continue
        if opts.length is not None and L < opts.length:
            seg['reason'] = f'{L} frames < --length {opts.length}'
            continue
        if L > FRAMES_PER_SAMPLE_LIMIT * samples:
            seg['reason'] = (
                f'{L} frames from {samples} samples of a robot: more than {FRAMES_PER_SAMPLE_LIMIT} '
                f'frames of {dt:g} s a sample (times in ms or ns instead of seconds? a --rate too high?)'
            )
            continue
        states, reason = derive(
            anchor + (ka + np.arange(L)) * dt, f'segment {len(metas) - 1} [{a:.3f}, {b:.3f}] s'
        )
        if states is None:
            seg['reason'] = reason
            continue
        kept.append((seg, states))
    if not kept:
        why = '; '.join(f'[{s["start"]:.3f}, {s["end"]:.3f}] s: {s["reason"]}' for s in metas)
        raise TrackError(f'{where}: no segment is long enough to keep ({why})')
    return metas, kept


def common_length(kept_per_episode, length: Optional[int]) -> int:
    """T of every trajectory: ``length`` if given, else the shortest kept segment of all episodes."""
    if length is not None:
        return length
    return min(s['frames'] for kept in kept_per_episode for s, _ in kept)


def windows(
    tl: Timeline, metas: List[Dict[str, Any]], kept, T: int, dt: float, first: int = 0, episode: int = 0
):
    """Cut the kept segments into windows of T frames sharing their boundary frame:
    ``(states [S, T, n, d], trajectories meta)``; the windows are trajectories ``first, first + 1, ...``
    of the dataset, all from ``episode``."""
    out, traj_meta = [], []
    for seg, states in kept:
        seg['kept'] = True
        L = states.shape[0]
        start, end = 0, 0
        while start + T <= L:
            seg['trajectories'].append(first + len(out))
            out.append(states[start : start + T])
            k = seg['grid_index'] + start
            t = tl.anchor + k * dt
            traj_meta.append(
                {
                    'episode': episode,
                    'segment': metas.index(seg),
                    'grid_index': k,
                    'frame_in_segment': start,
                    'start_time': t,
                    'start_ns': tl.t0_ns + int(round(t * 1e9)),
                    'frames': T,
                }
            )
            end = start + T
            start += T - 1  # windows share their boundary frame: no transition is lost
        seg['unused_frames'] = L - end
    return np.stack(out).astype(np.float64), traj_meta


def stack_episodes(episodes, length: Optional[int], dt: float, where: List[str]):
    """Several episodes, each ``(timeline, segments meta, kept)`` from :func:`segments`, into one
    dataset: ``(states [S, T, n, d], trajectories meta with their episode, T)``. T is common to all
    (:func:`common_length`); every episode must have the same number of robots (``where`` names
    each episode's source in errors)."""
    n = {e: kept[0][1].shape[1] for e, (_, _, kept) in enumerate(episodes)}
    odd = [e for e in n if n[e] != n[0]]
    if odd:
        raise TrackError(
            f'{where[odd[0]]}: {n[odd[0]]} robots, but {where[0]} has {n[0]}; the episodes of one '
            f'dataset need the same number of robots'
        )
    T = common_length([kept for _, _, kept in episodes], length)
    states, traj_meta = [], []
    for e, (tl, metas, kept) in enumerate(episodes):
        s, tm = windows(tl, metas, kept, T, dt, first=len(traj_meta), episode=e)
        states.append(s)
        traj_meta.extend(tm)
    return np.concatenate(states), traj_meta, T
