"""Import a rosbag2 (MCAP) recording of a swarm into a trajectory file (DESIGN.md, "Trajectory files").

    python -m training.import_bag BAG --scenario flock2d --topics '/robot_*/odom' --rate 100 --out data/real.npz
    python -m training.import_bag BAG --scenario boids3d --frames 'cf*' --rate 60 --out data/cf.npz     # /tf
    python -m training.import_bag BAG --scenario flock2d --id-map /vicon/cf3/pose=3 --id-map /vicon/cf7/pose=7 ...

``BAG`` is a rosbag2 bag directory (``metadata.yaml`` + MCAP files, split bags in order) or one
``.mcap`` file. Per robot it reads nav_msgs/Odometry, geometry_msgs/PoseStamped, or the
TransformStamped of one child frame within tf2_msgs/TFMessage; resamples all robots onto one
uniform grid at ``--rate`` (linear interpolation of positions); keeps only the time where every
robot is observed; cuts the recording where any robot is silent longer than ``--max-gap``; derives
the velocities (flock2d) or unit headings (boids3d) that the bag does not carry; and writes the
trajectory file with ``dt = 1 / rate``. docs/import_bag.md documents every choice.

Exit status: 0 written; 1 bad input (the message names the file, topic or frame; nothing is
written); 2 bad command line.
"""
from __future__ import annotations

import argparse
import fnmatch
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, List, Optional, Sequence, Tuple

import numpy as np

from knode_swarm_ros.core import get_scenario
from knode_swarm_ros.core.trajectory import TrajectoryError, save_trajectories

from .bagio import (ODOMETRY, SUPPORTED_TYPES, TF_MESSAGE, BagError, open_bag, quaternion_to_heading,
                    rotate_by_quaternion, samples_of)

__all__ = ["ImportOptions", "ImportResult", "import_bag", "main", "BagError", "parse_id_map",
           "moving_average", "finite_difference"]

FORMAT_VERSION = 1
#: Default gap threshold in units of the slowest robot's median message interval.
GAP_FACTOR = 5.0


@dataclass
class ImportOptions:
    """What ``python -m training.import_bag`` is asked to do (see ``--help`` and docs/import_bag.md)."""

    scenario: str
    rate: float
    topics: Optional[List[str]] = None          # globs; default '/tf' with frames, or the id map's names
    frames: Optional[List[str]] = None          # child frame globs on TF topics
    id_map: Optional[Dict[str, int]] = None     # source name (topic or frame) -> robot id
    max_gap: Optional[float] = None             # seconds; default GAP_FACTOR x slowest median interval
    min_duration: float = 1.0                   # seconds; shorter segments are dropped
    length: Optional[int] = None                # frames per trajectory; default the shortest kept segment
    smooth: str = "none"                        # none | moving-average | savgol
    smooth_window: int = 5                      # odd, in output samples
    smooth_order: int = 2                       # savgol polynomial order
    use_twist: bool = False                     # velocity (flock2d) / heading (boids3d) from Odometry twist
    twist_frame: str = "body"                   # body (REP 105: rotate twist by the pose orientation) | world
    use_orientation: bool = False               # boids3d heading from the pose orientation (+x axis)
    heading_diff: str = "backward"              # boids3d: backward | central differences
    min_speed: float = 1e-3                     # boids3d: slower samples take the nearest valid heading
    stamp: str = "header"                       # header | log
    test_trajectories: int = 0                  # the last K trajectories form meta.split.test


@dataclass
class ImportResult:
    states: np.ndarray          # [trajectories, T, n, d]
    dt: float
    scenario: str
    meta: Dict[str, Any]
    summary: List[str]


# --- Command-line helpers -------------------------------------------------------------------------

def parse_id_map(items: Sequence[str]) -> Dict[str, int]:
    """``NAME=ID`` items and/or YAML files ``{NAME: ID}`` -> ``{name: id}`` (ids distinct, >= 0)."""
    mapping: Dict[str, int] = {}
    for item in items:
        if "=" not in item:
            path = Path(item)
            if not path.is_file():
                raise BagError(f"--id-map {item}: neither NAME=ID nor an existing YAML file")
            import yaml
            try:
                data = yaml.safe_load(path.read_text(encoding="utf-8"))
            except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
                raise BagError(f"--id-map {item}: not a readable YAML file ({exc})") from None
            if not isinstance(data, dict) or not data:
                raise BagError(f"--id-map {item}: expected a YAML mapping NAME: ID")
            pairs = list(data.items())
        else:
            name, _, value = item.rpartition("=")
            pairs = [(name, value)]
        for name, value in pairs:
            try:
                rid = int(value)
            except (TypeError, ValueError):
                raise BagError(f"--id-map: robot id of {name!r} is {value!r}, not an integer") from None
            if rid < 0 or not str(name):
                raise BagError(f"--id-map: {name!r} -> {value!r}: ids must be >= 0 and names non-empty")
            name = str(name)
            if name in mapping and mapping[name] != rid:
                raise BagError(f"--id-map: {name} is mapped twice ({mapping[name]} and {rid})")
            mapping[name] = rid
    ids = list(mapping.values())
    dup = sorted({i for i in ids if ids.count(i) > 1})
    if dup:
        raise BagError(f"--id-map: robot id(s) {dup} given to more than one name")
    return mapping


def _split_patterns(items: Optional[Sequence[str]]) -> Optional[List[str]]:
    if not items:
        return None
    out = [p.strip() for item in items for p in item.split(",") if p.strip()]
    return out or None


# --- Numerics ----------------------------------------------------------------------------------------

def finite_difference(p: np.ndarray, dt: float, scheme: str) -> np.ndarray:
    """Velocities ``[L, ...]`` from positions ``p[L, ...]`` sampled every ``dt`` (L >= 3).

    ``central``: (p[k+1] - p[k-1]) / (2 dt) inside, second-order one-sided at both ends
    (``numpy.gradient(edge_order=2)``). ``backward``: (p[k] - p[k-1]) / dt, frame 0 takes frame 1's.
    """
    if scheme == "central":
        return np.gradient(p, dt, axis=0, edge_order=2)
    if scheme == "backward":
        v = np.empty_like(p)
        v[1:] = (p[1:] - p[:-1]) / dt
        v[0] = v[1]
        return v
    raise ValueError(f"unknown difference scheme {scheme!r}")


def moving_average(x: np.ndarray, window: int) -> np.ndarray:
    """Centred moving average over axis 0 with an odd ``window``; near the ends the window
    shrinks symmetrically (so the average stays centred: no lag, ends less smoothed)."""
    L = x.shape[0]
    half = window // 2
    c = np.concatenate([np.zeros((1,) + x.shape[1:]), np.cumsum(x, axis=0)], axis=0)
    k = np.arange(L)
    h = np.minimum(np.minimum(k, L - 1 - k), half)
    lo, hi = k - h, k + h + 1
    shape = (L,) + (1,) * (x.ndim - 1)
    return (c[hi] - c[lo]) / (hi - lo).reshape(shape)


def _smooth(v: np.ndarray, opts: ImportOptions, notes: List[str], label: str) -> np.ndarray:
    if opts.smooth == "none":
        return v
    L = v.shape[0]
    window = min(opts.smooth_window, L if L % 2 else L - 1)
    if window != opts.smooth_window:
        notes.append(f"{label}: {L} frames, smoothing window shrunk to {window}")
    if opts.smooth == "moving-average":
        return moving_average(v, window)
    try:
        from scipy.signal import savgol_filter
    except ImportError:
        raise BagError("--smooth savgol needs scipy (pip install scipy), or use --smooth moving-average") from None
    if window <= opts.smooth_order:
        notes.append(f"{label}: too short for a Savitzky-Golay window; not smoothed")
        return v
    return savgol_filter(v, window, opts.smooth_order, axis=0, mode="interp")


def _intersect(a: List[Tuple[float, float]], b: List[Tuple[float, float]]) -> List[Tuple[float, float]]:
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


# --- Robots ---------------------------------------------------------------------------------------------

@dataclass
class _Robot:
    id: int
    name: str                  # topic, or child frame for TF
    topic: str
    type_name: str
    ns: np.ndarray = None      # int64 stamps, strictly increasing
    pos: np.ndarray = None     # [m, 3]
    quat: np.ndarray = None    # [m, 4] (x, y, z, w)
    lin: Optional[np.ndarray] = None   # [m, 3] twist.linear or None
    t: np.ndarray = None       # float seconds since t0
    read: int = 0
    duplicates: int = 0
    non_finite: int = 0
    frame_ids: set = field(default_factory=set)

    @property
    def label(self) -> str:
        return f"robot {self.id} ({self.name})" if self.name == self.topic else \
            f"robot {self.id} (frame {self.name} on {self.topic})"


def _robot_id(name: str, label: str) -> int:
    m = re.search(r"\d+", name)
    if m is None:
        raise BagError(f"{label} {name}: no integer in the name to take as the robot id; give one with "
                       f"--id-map {name}=ID")
    return int(m.group())


def _select(bag, opts: ImportOptions, notes: List[str]):
    """Matched topics and the robot sources on them: ``(topics, {source name: robot id}, tf)``."""
    topics = bag.topics()
    if opts.frames:
        patterns = opts.topics or ["/tf"]
    elif opts.topics:
        patterns = opts.topics
    elif opts.id_map:
        patterns = sorted(opts.id_map)
    else:
        raise BagError("say which topics hold the robots: --topics GLOB (e.g. '/robot_*/odom'), --frames GLOB "
                       "for /tf, or --id-map")
    matched = sorted(t for t in topics if any(fnmatch.fnmatchcase(t, p) for p in patterns))
    if not matched:
        listing = ", ".join(f"{t} ({ty})" for t, ty in sorted(topics.items())) or "none"
        raise BagError(f"{bag.path}: topic pattern {' '.join(patterns)!s} matches no topic; the bag has: {listing}")
    for t in matched:
        if topics[t] not in SUPPORTED_TYPES:
            raise BagError(f"{bag.path}: topic {t} carries {topics[t]}, which is not supported "
                           f"(supported: {', '.join(SUPPORTED_TYPES)}); narrow --topics")
    tf_topics = [t for t in matched if topics[t] == TF_MESSAGE]
    if opts.frames and len(tf_topics) != len(matched):
        other = [t for t in matched if t not in tf_topics]
        raise BagError(f"{bag.path}: --frames selects child frames of {TF_MESSAGE} topics, but {other[0]} "
                       f"carries {topics[other[0]]}")
    if tf_topics and not opts.frames:
        raise BagError(f"{bag.path}: topic {tf_topics[0]} is {TF_MESSAGE}; say which child frames are robots "
                       f"with --frames GLOB")
    return matched, topics, bool(opts.frames)


def _read_robots(bag, opts: ImportOptions, notes: List[str]) -> Tuple[List[_Robot], Dict[str, Any]]:
    matched, topics, tf = _select(bag, opts, notes)
    robots: Dict[str, _Robot] = {}
    ignored: Dict[str, int] = {}
    stamps_raw: Dict[str, List[int]] = {}

    def wanted(name: str) -> bool:
        if tf and not any(fnmatch.fnmatchcase(name, p) for p in opts.frames):
            return False
        if opts.id_map is not None and name not in opts.id_map:
            return False
        return True

    for path, topic, type_name, log_ns, msg in bag.messages(matched):
        if type_name not in SUPPORTED_TYPES:
            raise BagError(f"{path}: topic {topic} carries {type_name}, which is not supported")
        for child, sample in samples_of(type_name, msg, log_ns):
            name = child if tf else topic
            if not wanted(name):
                ignored[name] = ignored.get(name, 0) + 1
                continue
            robot = robots.get(name)
            if robot is None:
                rid = opts.id_map[name] if opts.id_map is not None else _robot_id(name, "frame" if tf else "topic")
                robot = robots[name] = _Robot(rid, name, topic, type_name)
                robot._samples = []
            elif robot.topic != topic:
                raise BagError(f"{path}: frame {name} appears on both {robot.topic} and {topic}; narrow --topics")
            robot._samples.append(sample)

    if opts.id_map is not None:
        missing = [(n, i) for n, i in opts.id_map.items() if n not in robots]
        if missing:
            n, i = missing[0]
            where = "child frame" if tf else "topic"
            raise BagError(f"{bag.path}: robot {i} of --id-map ({where} {n}) never appears among the matched "
                           f"{where}s (topics: {', '.join(matched)})")
    for t in matched:
        if not tf and t not in robots and t not in ignored:
            if opts.id_map is None:
                raise BagError(f"{bag.path}: topic {t} matches but holds no message (robot "
                               f"{_robot_id(t, 'topic')} never appears)")
    if not robots:
        raise BagError(f"{bag.path}: no child frame matching {' '.join(opts.frames or [])} on "
                       f"{', '.join(matched)}; frames seen: {', '.join(sorted(ignored)) or 'none'}")
    by_id: Dict[int, _Robot] = {}
    for r in robots.values():
        if r.id in by_id:
            raise BagError(f"{bag.path}: {by_id[r.id].name} and {r.name} both give robot id {r.id}; use --id-map")
        by_id[r.id] = r

    for r in robots.values():
        _finalise(r, opts)
    frames = sorted({f for r in robots.values() for f in r.frame_ids})
    if len(frames) > 1:
        detail = "; ".join(f"{r.name}: {', '.join(sorted(r.frame_ids))}" for r in robots.values())
        raise BagError(f"{bag.path}: the robots' poses are given in different frames ({detail}); positions "
                       f"must share one world frame")
    info = {"matched_topics": matched, "types": {t: topics[t] for t in matched},
            "ignored_sources": ignored, "frame_id": frames[0] if frames else ""}
    return [by_id[i] for i in sorted(by_id)], info


def _finalise(r: _Robot, opts: ImportOptions) -> None:
    samples = r._samples
    del r._samples
    r.read = len(samples)
    where = f"{r.topic}" + ("" if r.name == r.topic else f" (frame {r.name})")
    ns = np.array([s.stamp_ns if opts.stamp == "header" else s.log_ns for s in samples], dtype=np.int64)
    if opts.stamp == "header" and np.all(ns == 0):
        raise BagError(f"{where}: every header.stamp is zero; use --stamp log to take the recording time")
    back = np.nonzero(np.diff(ns) < 0)[0]
    if back.size:
        k = int(back[0]) + 1
        raise BagError(f"{where}: {opts.stamp} stamps go backwards at message {k} "
                       f"({ns[k - 1]} ns then {ns[k]} ns, {(ns[k - 1] - ns[k]) * 1e-9:.6f} s earlier)")
    pos = np.array([s.position for s in samples], dtype=np.float64).reshape(-1, 3)
    quat = np.array([s.orientation for s in samples], dtype=np.float64).reshape(-1, 4)
    lin = None
    if samples and samples[0].linear is not None:
        lin = np.array([s.linear for s in samples], dtype=np.float64).reshape(-1, 3)
    keep = np.ones(len(samples), dtype=bool)
    keep[1:] = np.diff(ns) > 0
    r.duplicates = int((~keep).sum())
    finite = np.all(np.isfinite(pos), axis=1)
    if opts.use_orientation or (opts.use_twist and opts.twist_frame == "body"):
        finite &= np.all(np.isfinite(quat), axis=1) & (np.linalg.norm(np.nan_to_num(quat), axis=1) > 1e-9)
    if opts.use_twist and lin is not None:
        finite &= np.all(np.isfinite(lin), axis=1)
    r.non_finite = int((keep & ~finite).sum())
    keep &= finite
    r.ns, r.pos, r.quat = ns[keep], pos[keep], quat[keep]
    r.lin = lin[keep] if lin is not None else None
    r.frame_ids = {s.frame_id for s, k in zip(samples, keep) if k}
    if r.ns.size < 2:
        raise BagError(f"{where}: only {r.ns.size} usable message(s) for {r.label}; nothing to interpolate")


# --- Import ------------------------------------------------------------------------------------------------

def _check_options(opts: ImportOptions) -> None:
    spec = get_scenario(opts.scenario)
    if not (np.isfinite(opts.rate) and opts.rate > 0):
        raise BagError(f"--rate must be a positive number of Hz, got {opts.rate}")
    if opts.use_twist and opts.use_orientation:
        raise BagError("--use-twist and --use-orientation exclude each other")
    if opts.use_orientation and spec.heading is None:
        raise BagError("--use-orientation is for boids3d headings; flock2d needs no orientation")
    if opts.smooth not in ("none", "moving-average", "savgol"):
        raise BagError(f"--smooth {opts.smooth}: choose none, moving-average or savgol")
    if opts.smooth != "none" and (opts.smooth_window < 3 or opts.smooth_window % 2 == 0):
        raise BagError(f"--smooth-window must be odd and >= 3, got {opts.smooth_window}")
    if opts.smooth == "savgol" and not (0 <= opts.smooth_order < opts.smooth_window):
        raise BagError(f"--smooth-order must be >= 0 and below --smooth-window, got {opts.smooth_order}")
    if opts.max_gap is not None and not opts.max_gap > 0:
        raise BagError(f"--max-gap must be positive, got {opts.max_gap}")
    if opts.length is not None and opts.length < 3:
        raise BagError(f"--length must be at least 3 frames, got {opts.length}")
    if opts.min_duration < 0:
        raise BagError(f"--min-duration must be >= 0, got {opts.min_duration}")
    if opts.test_trajectories < 0:
        raise BagError(f"--test-trajectories must be >= 0, got {opts.test_trajectories}")
    if opts.heading_diff not in ("backward", "central"):
        raise BagError(f"--heading-diff {opts.heading_diff}: choose backward or central")


def _derive(seg_t: np.ndarray, robots: List[_Robot], opts: ImportOptions, dt: float, notes: List[str],
            label: str) -> Tuple[Optional[np.ndarray], Optional[str]]:
    """States ``[L, n, d]`` on the grid times ``seg_t``, or (None, reason) when undefined."""
    spec = get_scenario(opts.scenario)
    p = spec.position_dim
    L, n = seg_t.size, len(robots)
    pos = np.empty((L, n, p))
    for i, r in enumerate(robots):
        for c in range(p):
            pos[:, i, c] = np.interp(seg_t, r.t, r.pos[:, c])

    def interp_twist() -> np.ndarray:
        out = np.empty((L, n, 3))
        for i, r in enumerate(robots):
            lin = r.lin if opts.twist_frame == "world" else rotate_by_quaternion(r.quat, r.lin)
            for c in range(3):
                out[:, i, c] = np.interp(seg_t, r.t, lin[:, c])
        return out

    if spec.velocity is not None:  # flock2d
        if opts.use_twist:
            vel = interp_twist()[:, :, :p]
        else:
            vel = _smooth(finite_difference(pos, dt, "central"), opts, notes, label)
        return np.concatenate([pos, vel], axis=2), None

    # boids3d headings
    if opts.use_orientation:
        head = np.empty((L, n, 3))
        for i, r in enumerate(robots):
            h_raw = quaternion_to_heading(r.quat)
            for c in range(3):
                head[:, i, c] = np.interp(seg_t, r.t, h_raw[:, c])
            norm = np.linalg.norm(head[:, i], axis=1)
            bad = norm < 1e-6   # antipodal headings on both sides: take the nearer sample
            if np.any(bad):
                idx = np.clip(np.searchsorted(r.t, seg_t[bad]), 1, r.t.size - 1)
                nearer = np.where(np.abs(r.t[idx - 1] - seg_t[bad]) <= np.abs(r.t[idx] - seg_t[bad]), idx - 1, idx)
                head[bad, i] = h_raw[nearer]
                norm[bad] = 1.0
            head[:, i] /= norm[:, None]
        return np.concatenate([pos, head], axis=2), None
    vel = interp_twist() if opts.use_twist else _smooth(finite_difference(pos, dt, opts.heading_diff), opts,
                                                          notes, label)
    speed = np.linalg.norm(vel, axis=2)
    head = np.empty_like(vel)
    for i, r in enumerate(robots):
        valid = speed[:, i] > opts.min_speed
        if not np.any(valid):
            return None, (f"{r.label} never moves faster than --min-speed {opts.min_speed} m/s, so its heading "
                          f"is undefined (try --use-orientation)")
        idx = np.nonzero(valid)[0]
        nearest = idx[np.clip(np.searchsorted(idx, np.arange(L)), 0, idx.size - 1)]
        prev = idx[np.clip(np.searchsorted(idx, np.arange(L)) - 1, 0, idx.size - 1)]
        nearest = np.where(np.abs(prev - np.arange(L)) <= np.abs(nearest - np.arange(L)), prev, nearest)
        nearest = np.where(valid, np.arange(L), nearest)
        head[:, i] = vel[nearest, i] / speed[nearest, i][:, None]
        if not np.all(valid):
            notes.append(f"{label}: {r.label}: {int((~valid).sum())} frame(s) slower than --min-speed take the "
                         f"nearest valid heading")
    return np.concatenate([pos, head], axis=2), None


def import_bag(bag_path, opts: ImportOptions) -> ImportResult:
    """Read ``bag_path`` and build the trajectories; raises :class:`BagError` on bad input."""
    _check_options(opts)
    spec = get_scenario(opts.scenario)
    rate = float(opts.rate)
    dt = 1.0 / rate
    notes: List[str] = []
    bag = open_bag(bag_path)
    robots, info = _read_robots(bag, opts, notes)
    if opts.use_twist:
        for r in robots:
            if r.lin is None:
                raise BagError(f"{r.topic}: --use-twist needs {ODOMETRY}, but it carries {r.type_name}")
    notes.extend(bag.notes)

    t0_ns = min(int(r.ns[0]) for r in robots)
    for r in robots:
        r.t = (r.ns - t0_ns).astype(np.float64) * 1e-9
    medians = {r.id: float(np.median(np.diff(r.t))) for r in robots}
    if opts.max_gap is None:
        max_gap = GAP_FACTOR * max(medians.values())
        gap_rule = f"{GAP_FACTOR:g} x the slowest robot's median message interval ({max(medians.values()):.6g} s)"
    else:
        max_gap, gap_rule = float(opts.max_gap), "--max-gap"

    # Where every robot is observed: per robot, intervals between gaps; then their intersection.
    gaps, common = [], None
    for r in robots:
        d = np.diff(r.t)
        cut = np.nonzero(d > max_gap)[0]
        starts = np.concatenate([[0], cut + 1])
        ends = np.concatenate([cut, [r.t.size - 1]])
        intervals = [(float(r.t[a]), float(r.t[b])) for a, b in zip(starts, ends)]
        for k in cut:
            gaps.append({"robot": r.id, "source": r.name, "from": float(r.t[k]), "to": float(r.t[k + 1]),
                         "duration": float(d[k]), "from_ns": int(r.ns[k]), "to_ns": int(r.ns[k + 1])})
        common = intervals if common is None else _intersect(common, intervals)
    gaps.sort(key=lambda g: (g["from"], g["robot"]))
    if not common:
        raise BagError(f"{bag.path}: the robots are never all observed at the same time "
                       f"({'; '.join(f'{r.label}: {r.t[0]:.3f}..{r.t[-1]:.3f} s' for r in robots)})")

    anchor = common[0][0]
    segments: List[Dict[str, Any]] = []
    candidates = []
    for a, b in common:
        ka = int(np.ceil((a - anchor) * rate - 1e-9))
        kb = int(np.floor((b - anchor) * rate + 1e-9))
        L = kb - ka + 1
        seg = {"start": a, "end": b, "grid_index": ka, "frames": max(L, 0), "kept": False, "reason": None,
               "trajectories": []}
        segments.append(seg)
        duration = (L - 1) * dt
        if L < 3 or duration < opts.min_duration:
            seg["reason"] = (f"{max(L, 0)} frame(s), {max(duration, 0):.3f} s < --min-duration "
                             f"{opts.min_duration:g} s" if L >= 3 else f"{max(L, 0)} frame(s) < 3")
            continue
        if opts.length is not None and L < opts.length:
            seg["reason"] = f"{L} frames < --length {opts.length}"
            continue
        seg_t = anchor + (ka + np.arange(L)) * dt
        label = f"segment {len(segments) - 1} [{a:.3f}, {b:.3f}] s"
        states, reason = _derive(seg_t, robots, opts, dt, notes, label)
        if states is None:
            seg["reason"] = reason
            continue
        candidates.append((seg, states))
    if not candidates:
        why = "; ".join(f"[{s['start']:.3f}, {s['end']:.3f}] s: {s['reason']}" for s in segments)
        raise BagError(f"{bag.path}: no segment is long enough to keep ({why})")

    T = opts.length if opts.length is not None else min(s["frames"] for s, _ in candidates)
    length_rule = "--length" if opts.length is not None else "the shortest kept segment"
    trajectories, traj_meta = [], []
    for seg, states in candidates:
        seg["kept"] = True
        L = states.shape[0]
        start, end = 0, 0
        while start + T <= L:
            seg["trajectories"].append(len(trajectories))
            trajectories.append(states[start:start + T])
            k = seg["grid_index"] + start
            traj_meta.append({"segment": segments.index(seg), "grid_index": k, "frame_in_segment": start,
                              "start_time": anchor + k * dt, "start_ns": t0_ns + int(round((anchor + k * dt) * 1e9)),
                              "frames": T})
            end = start + T
            start += T - 1      # windows share their boundary frame: no transition is lost
        seg["unused_frames"] = L - end
    out = np.stack(trajectories).astype(np.float64)

    # Message accounting: a message is used when it brackets or lies inside a kept trajectory's span.
    used = 0
    per_robot = {}
    for r in robots:
        mask = np.zeros(r.t.size, dtype=bool)
        for tm in traj_meta:
            ta, tb = tm["start_time"], tm["start_time"] + (T - 1) * dt
            lo = max(int(np.searchsorted(r.t, ta - 1e-9, "right")) - 1, 0)
            hi = min(int(np.searchsorted(r.t, tb + 1e-9, "left")), r.t.size - 1)
            mask[lo:hi + 1] = True
        u = int(mask.sum())
        used += u
        per_robot[str(r.id)] = {"source": r.name, "read": r.read, "used": u, "duplicates": r.duplicates,
                                "non_finite": r.non_finite, "unused": r.read - u - r.duplicates - r.non_finite,
                                "median_interval": medians[r.id]}
    read = sum(r.read for r in robots)
    duplicates = sum(r.duplicates for r in robots)
    non_finite = sum(r.non_finite for r in robots)
    messages = {"read": read, "used": used, "duplicates": duplicates, "non_finite": non_finite,
                "unused": read - used - duplicates - non_finite, "ignored_sources": info["ignored_sources"],
                "per_robot": per_robot}

    if spec.velocity is not None:
        derived = {"velocity": "Odometry twist.twist.linear (" + opts.twist_frame + " frame), linear interpolation"
                   if opts.use_twist else "central differences of the resampled positions (second-order one-sided "
                                          "at segment ends)"}
    elif opts.use_orientation:
        derived = {"heading": "+x axis of the pose orientation, linearly interpolated and renormalised"}
    else:
        derived = {"heading": ("direction of the Odometry twist.twist.linear (" + opts.twist_frame + " frame)")
                   if opts.use_twist else f"direction of {opts.heading_diff} differences of the resampled positions",
                   "min_speed": opts.min_speed}
    uses_differences = not (opts.use_twist or opts.use_orientation)
    derived["smoothing"] = ({"method": opts.smooth, "window": opts.smooth_window,
                             **({"order": opts.smooth_order} if opts.smooth == "savgol" else {}),
                             "applies_to": "the finite-difference velocities (positions are not smoothed)"}
                            if opts.smooth != "none" and uses_differences else {"method": "none"})
    if opts.smooth != "none" and not uses_differences:
        notes.append("--smooth applies to finite-difference velocities only; ignored with "
                     + ("--use-twist" if opts.use_twist else "--use-orientation"))
    S = out.shape[0]
    k_test = min(opts.test_trajectories, S - 1) if S > 1 else 0
    if k_test != opts.test_trajectories:
        notes.append(f"--test-trajectories {opts.test_trajectories}: only {S} trajectories; {k_test} held out")
    meta = {
        "generator": "training.import_bag",
        "version": FORMAT_VERSION,
        "scenario": opts.scenario,
        "state_layout": list(spec.state_layout),
        "bag": {"path": str(Path(bag.path).resolve()), "kind": bag.kind, "files": [f.name for f in bag.files]},
        "topic_patterns": opts.topics or (["/tf"] if opts.frames else sorted(opts.id_map or {})),
        "frame_patterns": opts.frames,
        "topics": info["matched_topics"],
        "message_types": info["types"],
        "frame_id": info["frame_id"],
        "robots": [{"index": i, "id": r.id, "source": r.name, "topic": r.topic, "type": r.type_name}
                   for i, r in enumerate(robots)],
        "robot_ids": [r.id for r in robots],
        "id_map": opts.id_map,
        "id_rule": "--id-map" if opts.id_map is not None else "first integer in the topic or frame name",
        "rate": rate,
        "dt": dt,
        "stamp": opts.stamp,
        "t0_ns": t0_ns,
        "grid": {"anchor": anchor, "anchor_ns": t0_ns + int(round(anchor * 1e9)),
                 "rule": "frame j of trajectory i is at t0 + anchor + (trajectories[i].grid_index + j) * dt"},
        "interpolation": "linear in time (positions; headings renormalised)",
        "max_gap": max_gap,
        "max_gap_rule": gap_rule,
        "gaps": gaps,
        "min_duration": opts.min_duration,
        "segments": segments,
        "length": T,
        "length_rule": length_rule + "; longer segments are cut into windows of T frames sharing their boundary frame",
        "trajectories": traj_meta,
        "derivation": derived,
        "messages": messages,
        "notes": notes,
        "split": {"train": list(range(S - k_test)), "test": list(range(S - k_test, S))},
    }
    summary = _summary(bag, robots, info, meta, out)
    return ImportResult(out, dt, opts.scenario, meta, summary)


def _summary(bag, robots: List[_Robot], info, meta, out) -> List[str]:
    lines = []
    nfiles = len(meta["bag"]["files"])
    lines.append(f"bag: {meta['bag']['path']} ({bag.kind}, {nfiles} file{'s' * (nfiles != 1)})")
    types = sorted(set(info["types"].values()))
    ids = [r.id for r in robots]
    lines.append(f"robots: {len(robots)} (ids {', '.join(map(str, ids))}) from {len(info['matched_topics'])} "
                 f"topic(s) [{', '.join(types)}], frame '{meta['frame_id']}'")
    span = max(r.t[-1] for r in robots)
    lines.append(f"recording: {span:.3f} s; resampled at {meta['rate']:g} Hz (dt {meta['dt']:.6g} s); "
                 f"max gap {meta['max_gap']:.4g} s ({meta['max_gap_rule']})")
    if meta["gaps"]:
        lines.append(f"gaps: {len(meta['gaps'])} (every robot is cut there)")
        for g in meta["gaps"]:
            lines.append(f"  robot {g['robot']} ({g['source']}) silent {g['duration']:.3f} s "
                         f"from t = {g['from']:.3f} s to {g['to']:.3f} s")
    else:
        lines.append("gaps: none")
    kept = [s for s in meta["segments"] if s["kept"]]
    lines.append(f"segments: {len(meta['segments'])} where all robots are observed, {len(kept)} kept, "
                 f"{len(meta['segments']) - len(kept)} dropped")
    for i, s in enumerate(meta["segments"]):
        what = (f"kept -> trajectories {s['trajectories']}, {s['unused_frames']} trailing frame(s) unused"
                if s["kept"] else f"dropped: {s['reason']}")
        lines.append(f"  [{i}] t = {s['start']:.3f} .. {s['end']:.3f} s, {s['frames']} frames: {what}")
    S, T = out.shape[:2]
    lines.append(f"trajectories: {S} x {T} frames ({(T - 1) * meta['dt']:.3f} s each, length = "
                 f"{meta['length_rule'].split(';')[0]})")
    d = meta["derivation"]
    lines.append(f"derived: {d.get('velocity') or d.get('heading')}; smoothing {d['smoothing']['method']}"
                 + (f" (window {d['smoothing']['window']})" if d["smoothing"]["method"] != "none" else ""))
    m = meta["messages"]
    lines.append(f"messages: {m['read']} read, {m['used']} used, {m['read'] - m['used']} not used "
                 f"({m['duplicates']} duplicate stamps, {m['non_finite']} non-finite, {m['unused']} outside the "
                 f"kept trajectories)")
    if m["ignored_sources"]:
        lines.append("ignored: " + ", ".join(f"{k} ({v})" for k, v in sorted(m["ignored_sources"].items())))
    for note in meta["notes"]:
        lines.append(f"note: {note}")
    return lines


# --- CLI ----------------------------------------------------------------------------------------------

def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m training.import_bag",
        description="Import a rosbag2 (MCAP) recording of a swarm into a trajectory file (.npz).",
        epilog="Details: docs/import_bag.md")
    p.add_argument("bag", help="rosbag2 bag directory (metadata.yaml + .mcap files) or one .mcap file")
    p.add_argument("--scenario", required=True, choices=("flock2d", "boids3d"))
    p.add_argument("--topics", action="append", metavar="GLOB",
                   help="topics holding the robots, shell-style glob (repeat or comma-separate), e.g. "
                        "'/robot_*/odom'; default /tf with --frames, or the --id-map names")
    p.add_argument("--frames", action="append", metavar="GLOB",
                   help="child frames of tf2_msgs/TFMessage topics that are robots, e.g. 'cf*'")
    p.add_argument("--rate", required=True, type=float, metavar="HZ", help="output rate; dt = 1 / rate")
    p.add_argument("--out", required=True, metavar="FILE.npz", help="trajectory file to write")
    p.add_argument("--id-map", action="append", metavar="NAME=ID|FILE.yaml",
                   help="explicit robot ids (repeatable), or a YAML mapping NAME: ID; only these names are "
                        "robots. Default: the first integer in each topic or frame name")
    p.add_argument("--max-gap", type=float, metavar="SECONDS",
                   help=f"a robot silent longer than this cuts the recording; default {GAP_FACTOR:g} x the "
                        "slowest robot's median message interval")
    p.add_argument("--min-duration", type=float, default=1.0, metavar="SECONDS",
                   help="drop segments shorter than this (default 1.0)")
    p.add_argument("--length", type=int, metavar="FRAMES",
                   help="frames per trajectory; default the shortest kept segment. Longer segments are cut "
                        "into windows sharing their boundary frame")
    p.add_argument("--smooth", choices=("none", "moving-average", "savgol"), default="none",
                   help="filter the finite-difference velocities (default none)")
    p.add_argument("--smooth-window", type=int, default=5, metavar="N", help="odd window in output samples (5)")
    p.add_argument("--smooth-order", type=int, default=2, metavar="K", help="Savitzky-Golay order (2)")
    p.add_argument("--use-twist", action="store_true",
                   help="velocities (flock2d) or headings (boids3d) from Odometry twist.twist.linear instead "
                        "of finite differences")
    p.add_argument("--twist-frame", choices=("world", "body"), default="body",
                   help="frame of the twist: body (default; REP 105 child frame, rotated by the pose "
                        "orientation, as this project's nodes and every robot driver publish it) or world")
    p.add_argument("--use-orientation", action="store_true",
                   help="boids3d: heading = +x axis of the pose orientation instead of the motion direction")
    p.add_argument("--heading-diff", choices=("backward", "central"), default=None,
                   help="boids3d: differences for the motion direction (default backward: the heading at "
                        "frame k is the direction of the last step, as in the first-order rollout)")
    p.add_argument("--min-speed", type=float, default=1e-3, metavar="M_PER_S",
                   help="boids3d: frames slower than this take the nearest valid heading (default 0.001)")
    p.add_argument("--stamp", choices=("header", "log"), default="header",
                   help="time of a sample: header.stamp (default) or the bag's log (receive) time")
    p.add_argument("--test-trajectories", type=int, default=0, metavar="K",
                   help="hold out the last K trajectories as meta.split.test (default 0)")
    return p


def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.heading_diff is not None and args.scenario != "boids3d":
        parser.error("argument --heading-diff: only for --scenario boids3d")
    try:
        opts = ImportOptions(
            scenario=args.scenario, rate=args.rate, topics=_split_patterns(args.topics),
            frames=_split_patterns(args.frames), id_map=parse_id_map(args.id_map) if args.id_map else None,
            max_gap=args.max_gap, min_duration=args.min_duration, length=args.length, smooth=args.smooth,
            smooth_window=args.smooth_window, smooth_order=args.smooth_order, use_twist=args.use_twist,
            twist_frame=args.twist_frame, use_orientation=args.use_orientation,
            heading_diff=args.heading_diff or "backward", min_speed=args.min_speed, stamp=args.stamp,
            test_trajectories=args.test_trajectories)
        result = import_bag(args.bag, opts)
        meta = dict(result.meta, command=" ".join(["python -m training.import_bag"] + list(
            sys.argv[1:] if argv is None else argv)))
        save_trajectories(args.out, result.states, result.dt, result.scenario, meta)
    except (BagError, TrajectoryError, OSError) as exc:
        print(f"import_bag: error: {exc}", file=sys.stderr)
        print("import_bag: nothing written", file=sys.stderr)
        return 1
    for line in result.summary:
        print(line)
    print(f"wrote {args.out}: states {list(result.states.shape)} ({result.scenario}, dt {result.dt:.6g} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
