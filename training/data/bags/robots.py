"""The robots of a bag: which topics or TF child frames they are, their ids, their checked samples."""

from __future__ import annotations

import fnmatch
import re
from dataclasses import dataclass, field
from typing import Any, Dict, List, Optional, Tuple

import numpy as np

from knode_swarm_ros.bag import (
    SUPPORTED_TYPES,
    TF_MESSAGE,
    BagError,
    Sample,
    quaternion_to_heading,
    rotate_by_quaternion,
    samples_of,
)

from ..tracks import Track
from .options import ImportOptions

__all__ = ['Robot', 'read_robots', 'robot_id']


@dataclass
class Robot(Track):
    """One robot of a bag: raw samples while reading (``samples``), then arrays (:func:`finalise`);
    ``pos`` is ``[m, 3]``, the given velocity is the twist, the given heading the orientation's +x axis."""

    topic: str = ''
    type_name: str = ''
    quat: np.ndarray = None  # [m, 4] (x, y, z, w)
    lin: Optional[np.ndarray] = None  # [m, 3] twist.linear or None
    frame_ids: set = field(default_factory=set)
    samples: List[Sample] = field(default_factory=list)

    @property
    def label(self) -> str:
        return (
            f'robot {self.id} ({self.name})'
            if self.name == self.topic
            else f'robot {self.id} (frame {self.name} on {self.topic})'
        )

    def given_velocity(self, frame: str) -> np.ndarray:
        return self.lin if frame == 'world' else rotate_by_quaternion(self.quat, self.lin)

    def given_heading(self) -> np.ndarray:
        return quaternion_to_heading(self.quat)


def robot_id(name: str, label: str) -> int:
    m = re.search(r'\d+', name)
    if m is None:
        raise BagError(
            f'{label} {name}: no integer in the name to take as the robot id; give one with '
            f'--id-map {name}=ID'
        )
    return int(m.group())


def select_topics(bag, opts: ImportOptions, notes: List[str]):
    """Matched topics and the robot sources on them: ``(topics, {source name: robot id}, tf)``."""
    topics = bag.topics()
    if opts.frames:
        patterns = opts.topics or ['/tf']
    elif opts.topics:
        patterns = opts.topics
    elif opts.id_map:
        patterns = sorted(opts.id_map)
    else:
        raise BagError(
            "say which topics hold the robots: --topics GLOB (e.g. '/robot_*/odom'), --frames GLOB "
            'for /tf, or --id-map'
        )
    matched = sorted(t for t in topics if any(fnmatch.fnmatchcase(t, p) for p in patterns))
    if not matched:
        listing = ', '.join(f'{t} ({ty})' for t, ty in sorted(topics.items())) or 'none'
        raise BagError(
            f'{bag.path}: topic pattern {" ".join(patterns)!s} matches no topic; the bag has: {listing}'
        )
    for t in matched:
        if topics[t] not in SUPPORTED_TYPES:
            raise BagError(
                f'{bag.path}: topic {t} carries {topics[t]}, which is not supported '
                f'(supported: {", ".join(SUPPORTED_TYPES)}); narrow --topics'
            )
    tf_topics = [t for t in matched if topics[t] == TF_MESSAGE]
    if opts.frames and len(tf_topics) != len(matched):
        other = [t for t in matched if t not in tf_topics]
        raise BagError(
            f'{bag.path}: --frames selects child frames of {TF_MESSAGE} topics, but {other[0]} '
            f'carries {topics[other[0]]}'
        )
    if tf_topics and not opts.frames:
        raise BagError(
            f'{bag.path}: topic {tf_topics[0]} is {TF_MESSAGE}; say which child frames are robots '
            f'with --frames GLOB'
        )
    return matched, topics, bool(opts.frames)


def read_robots(bag, opts: ImportOptions, notes: List[str]) -> Tuple[List[Robot], Dict[str, Any]]:
    """The robots of ``bag`` in ascending id order, each checked (:func:`finalise`), and what was
    selected: ``{matched_topics, types, ignored_sources, frame_id}``."""
    matched, topics, tf = select_topics(bag, opts, notes)
    robots: Dict[str, Robot] = {}
    ignored: Dict[str, int] = {}

    def wanted(name: str) -> bool:
        if tf and not any(fnmatch.fnmatchcase(name, p) for p in opts.frames):
            return False
        if opts.id_map is not None and name not in opts.id_map:
            return False
        return True

    for path, topic, type_name, log_ns, msg in bag.messages(matched):
        if type_name not in SUPPORTED_TYPES:
            raise BagError(f'{path}: topic {topic} carries {type_name}, which is not supported')
        try:
            samples = samples_of(type_name, msg, log_ns)
        except (AttributeError, TypeError, ValueError) as exc:
            # the bag carries its own definition of each type: a damaged or foreign one decodes to
            # a message without the fields of the standard type
            raise BagError(
                f'{path}: a message on {topic} lacks the fields of {type_name} ({exc}); the bag '
                f'defines {type_name} otherwise than ROS 2 does'
            ) from None
        for child, sample in samples:
            name = child if tf else topic
            if not wanted(name):
                ignored[name] = ignored.get(name, 0) + 1
                continue
            robot = robots.get(name)
            if robot is None:
                rid = (
                    opts.id_map[name]
                    if opts.id_map is not None
                    else robot_id(name, 'frame' if tf else 'topic')
                )
                robot = robots[name] = Robot(rid, name, topic=topic, type_name=type_name)
            elif robot.topic != topic:
                raise BagError(
                    f'{path}: frame {name} appears on both {robot.topic} and {topic}; narrow --topics'
                )
            robot.samples.append(sample)

    if opts.id_map is not None:
        missing = [(n, i) for n, i in opts.id_map.items() if n not in robots]
        if missing:
            n, i = missing[0]
            where = 'child frame' if tf else 'topic'
            raise BagError(
                f'{bag.path}: robot {i} of --id-map ({where} {n}) never appears among the matched '
                f'{where}s (topics: {", ".join(matched)})'
            )
    for t in matched:
        if not tf and t not in robots and t not in ignored:
            if opts.id_map is None:
                raise BagError(
                    f'{bag.path}: topic {t} matches but holds no message (robot '
                    f'{robot_id(t, "topic")} never appears)'
                )
    if not robots:
        raise BagError(
            f'{bag.path}: no child frame matching {" ".join(opts.frames or [])} on '
            f'{", ".join(matched)}; frames seen: {", ".join(sorted(ignored)) or "none"}'
        )
    by_id: Dict[int, Robot] = {}
    for r in robots.values():
        if r.id in by_id:
            raise BagError(
                f'{bag.path}: {by_id[r.id].name} and {r.name} both give robot id {r.id}; use --id-map'
            )
        by_id[r.id] = r

    for r in robots.values():
        finalise(r, opts)
    frames = sorted({f for r in robots.values() for f in r.frame_ids})
    if len(frames) > 1:
        detail = '; '.join(f'{r.name}: {", ".join(sorted(r.frame_ids))}' for r in robots.values())
        raise BagError(
            f"{bag.path}: the robots' poses are given in different frames ({detail}); positions "
            f'must share one world frame'
        )
    info = {
        'matched_topics': matched,
        'types': {t: topics[t] for t in matched},
        'ignored_sources': ignored,
        'frame_id': frames[0] if frames else '',
    }
    return [by_id[i] for i in sorted(by_id)], info


def finalise(r: Robot, opts: ImportOptions) -> None:
    """Check one robot's samples and keep the usable ones as arrays (stamps strictly increasing)."""
    samples, r.samples = r.samples, []
    r.read = len(samples)
    where = f'{r.topic}' + ('' if r.name == r.topic else f' (frame {r.name})')
    ns = np.array([s.stamp_ns if opts.stamp == 'header' else s.log_ns for s in samples], dtype=np.int64)
    if opts.stamp == 'header' and np.all(ns == 0):
        raise BagError(f'{where}: every header.stamp is zero; use --stamp log to take the recording time')
    # a message that arrived late is placed by its stamp; one going back to a stamp already seen
    # is a clock or publisher problem, not a late arrival
    late = np.nonzero(ns[1:] < np.maximum.accumulate(ns)[:-1])[0] + 1
    for k in late:
        if np.any(ns[:k] == ns[k]):
            raise BagError(
                f'{where}: {opts.stamp} stamps go backwards at message {k} to a stamp already seen '
                f'({ns[k - 1]} ns then {ns[k]} ns, {(ns[k - 1] - ns[k]) * 1e-9:.6f} s earlier)'
            )
    order = np.argsort(ns, kind='stable')
    r.reordered = int(late.size)
    samples = [samples[k] for k in order]
    ns = ns[order]
    pos = np.array([s.position for s in samples], dtype=np.float64).reshape(-1, 3)
    quat = np.array([s.orientation for s in samples], dtype=np.float64).reshape(-1, 4)
    lin = None
    if samples and samples[0].linear is not None:
        lin = np.array([s.linear for s in samples], dtype=np.float64).reshape(-1, 3)
    keep = np.ones(len(samples), dtype=bool)
    keep[1:] = np.diff(ns) > 0
    r.duplicates = int((~keep).sum())
    finite = np.all(np.isfinite(pos), axis=1)
    if opts.use_orientation or (opts.use_twist and opts.twist_frame == 'body'):
        finite &= np.all(np.isfinite(quat), axis=1) & (np.linalg.norm(np.nan_to_num(quat), axis=1) > 1e-9)
    if opts.use_twist and lin is not None:
        finite &= np.all(np.isfinite(lin), axis=1)
    r.non_finite = int((keep & ~finite).sum())
    keep &= finite
    r.ns, r.pos, r.quat = ns[keep], pos[keep], quat[keep]
    r.lin = lin[keep] if lin is not None else None
    r.frame_ids = {s.frame_id for s, k in zip(samples, keep) if k}
    if r.ns.size < 2:
        raise BagError(f'{where}: only {r.ns.size} usable message(s) for {r.label}; nothing to interpolate')
