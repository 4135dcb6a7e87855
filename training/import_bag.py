"""Import a recording of a swarm (rosbag2 sqlite3 or MCAP, ROS 1 bag) into a trajectory file
(docs/DESIGN.md, "Trajectory files").

    python -m training.import_bag BAG --scenario flock2d --topics '/robot_*/odom' --rate 100 --out data/real.npz
    python -m training.import_bag BAG --scenario boids3d --frames 'cf*' --rate 60 --out data/cf.npz     # /tf
    python -m training.import_bag BAG --scenario flock2d --id-map /vicon/cf3/pose=3 --id-map /vicon/cf7/pose=7 ...
    python -m training.import_bag ep00.mcap ep01.mcap ... --scenario flock2d --topics '/robot_*/odom' --rate 100 --out data/ep.npz

``BAG`` is a rosbag2 bag directory (``metadata.yaml`` + sqlite3 or MCAP files, split bags in
order), one ``.db3`` or ``.mcap`` file, or a ROS 1 ``.bag`` file; the ``rosbags`` package reads
them all (:mod:`knode_swarm_ros.bag`). Per robot it reads nav_msgs/Odometry,
geometry_msgs/PoseStamped, or the TransformStamped of one child frame within tf2_msgs/TFMessage;
resamples all robots onto one uniform grid at ``--rate`` (linear interpolation of positions);
keeps only the time where every robot is observed; cuts the recording where any robot is
silent longer than ``--max-gap``; derives the velocities (flock2d) or unit headings (boids3d)
that the bag does not carry; and writes the trajectory file with ``dt = 1 / rate``. Several bags
are several episodes of one dataset (``meta.episodes``: the bag of each trajectory). Reading a
bag lives in :mod:`training.data.bags`, the source-neutral steps (shared with
``training.import_tracks``) in :mod:`training.data.timeline` and :mod:`training.data.derive`;
docs/import_bag.md documents every choice.

Exit status: 0 written; 2 bad input or command line (the message names the file, topic, frame
or option; nothing is written).
"""

from __future__ import annotations

import argparse
import sys
from typing import List, Optional, Sequence

import numpy as np

from knode_swarm_ros.bag import ODOMETRY, BagError, open_bag
from knode_swarm_ros.core.cli import cli
from knode_swarm_ros.core.errors import KnodeError
from knode_swarm_ros.core.scenarios import get_scenario, parse_scenario_argument
from knode_swarm_ros.core.trajectory import TrajectoryError, save_trajectories
from training.data.bags.options import (
    ImportOptions,
    ImportResult,
    check_options,
    parse_id_map,
    split_patterns,
)
from training.data.bags.report import build_meta, derivation, message_counts, summary_lines
from training.data.bags.robots import read_robots
from training.data.derive import derive_states, finite_difference, moving_average, smooth_episode
from training.data.timeline import segments, stack_episodes, timeline
from training.data.tracks import TrackError, add_resample_arguments, dataset_meta, resample_option_values

__all__ = [
    'ImportOptions',
    'ImportResult',
    'import_bag',
    'import_bags',
    'main',
    'BagError',
    'TrackError',
    'parse_id_map',
    'moving_average',
    'finite_difference',
]


def read_episode(bag_path, opts: ImportOptions, dt: float, notes: List[str]):
    """One bag: ``(bag, robots, info, timeline, segments meta, kept segments with their states)``."""
    bag = open_bag(bag_path)
    robots, info = read_robots(bag, opts, notes)
    if opts.use_twist:
        for r in robots:
            if r.lin is None:
                raise BagError(f'{r.topic}: --use-twist needs {ODOMETRY}, but it carries {r.type_name}')
    notes.extend(bag.notes)
    tl = timeline(robots, opts.max_gap, bag.path)
    info['noise'] = smooth_episode(robots, opts, tl.medians)
    metas, kept = segments(
        tl, opts, dt, lambda t, label: derive_states(t, robots, opts, dt, notes, label), bag.path
    )
    return bag, robots, info, tl, metas, kept


def import_bags(bag_paths: Sequence, opts: ImportOptions) -> ImportResult:
    """Read each bag as one episode and build one dataset; raises :class:`BagError` or
    :class:`TrackError` on bad input.

    Steps per bag: open it; read and check each robot's samples; find the time base, gaps and the
    stretches where all robots are observed; derive the states on the grid of each long enough
    stretch. Then cut all episodes into windows of one length T and record what was done
    (``meta.episodes``: the bag of each trajectory).
    """
    check_options(opts)
    dt = 1.0 / float(opts.rate)
    notes: List[str] = []
    episodes = [read_episode(path, opts, dt, notes) for path in bag_paths]
    states, traj_meta, T = stack_episodes(
        [(tl, metas, kept) for _, _, _, tl, metas, kept in episodes],
        opts.length,
        dt,
        [str(ep[0].path) for ep in episodes],
    )
    derived = derivation(opts, notes)
    per_episode = []
    for e, (bag, robots, info, tl, metas, _) in enumerate(episodes):
        mine = [tm for tm in traj_meta if tm['episode'] == e]
        messages = message_counts(robots, tl, mine, T, dt, info['ignored_sources'])
        per_episode.append(build_meta(opts, bag, robots, info, tl, dt, metas, T, derived, messages))
    meta = dataset_meta(
        per_episode, [ep[0].path for ep in episodes], traj_meta, opts.test_trajectories, notes
    )
    summary = []
    for e, (bag, robots, info, _, _, _) in enumerate(episodes):
        mine = np.asarray(meta['episodes']) == e
        view = dict(per_episode[e], notes=[] if len(episodes) > 1 else notes)
        lines = summary_lines(bag, robots, info, view, states[mine])
        summary.extend(lines if len(episodes) == 1 else [f'episode {e}: {line}' for line in lines])
    if len(episodes) > 1:
        summary.append(f'dataset: {states.shape[0]} trajectories from {len(episodes)} bags')
        summary.extend(f'note: {note}' for note in notes)
    return ImportResult(states, dt, opts.scenario, meta, summary)


def import_bag(bag_path, opts: ImportOptions) -> ImportResult:
    """Read one bag into a dataset (:func:`import_bags` of one episode)."""
    return import_bags([bag_path], opts)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog='python -m training.import_bag',
        description='Import a recording of a swarm (rosbag2 sqlite3 or MCAP, ROS 1 bag) into a trajectory file (.npz).',
        epilog='Details: docs/import_bag.md',
    )
    p.add_argument(
        'bag',
        nargs='+',
        help='rosbag2 bag directory (metadata.yaml + .db3 or .mcap files), one .db3 or .mcap '
        'file, or a ROS 1 .bag file; several bags are several episodes of one dataset',
    )
    p.add_argument(
        '--scenario',
        required=True,
        metavar='NAME|FILE.yaml',
        help='a shipped scenario (flock2d, boids3d) or a scenario file (docs/scenarios.md)',
    )
    p.add_argument(
        '--topics',
        action='append',
        metavar='GLOB',
        help='topics holding the robots, shell-style glob (repeat or comma-separate), e.g. '
        "'/robot_*/odom'; default /tf with --frames, or the --id-map names",
    )
    p.add_argument(
        '--frames',
        action='append',
        metavar='GLOB',
        help="child frames of tf2_msgs/TFMessage topics that are robots, e.g. 'cf*'",
    )
    p.add_argument('--rate', required=True, type=float, metavar='HZ', help='output rate; dt = 1 / rate')
    p.add_argument('--out', required=True, metavar='FILE.npz', help='trajectory file to write')
    p.add_argument(
        '--id-map',
        action='append',
        metavar='NAME=ID|FILE.yaml',
        help='explicit robot ids (repeatable), or a YAML mapping NAME: ID; only these names are '
        'robots. Default: the first integer in each topic or frame name',
    )
    add_resample_arguments(p)
    p.add_argument(
        '--use-twist',
        action='store_true',
        help='velocities (flock2d) or headings (boids3d) from Odometry twist.twist.linear instead '
        'of finite differences',
    )
    p.add_argument(
        '--twist-frame',
        choices=('world', 'body'),
        default='body',
        help='frame of the twist: body (default; REP 105 child frame, rotated by the pose '
        "orientation, as this project's nodes and every robot driver publish it) or world",
    )
    p.add_argument(
        '--use-orientation',
        action='store_true',
        help='boids3d: heading = +x axis of the pose orientation instead of the motion direction',
    )
    p.add_argument(
        '--stamp',
        choices=('header', 'log'),
        default='header',
        help="time of a sample: header.stamp (default) or the bag's log (receive) time",
    )
    return p


@cli('python -m training.import_bag')
def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    args.scenario = parse_scenario_argument(args.scenario)
    if args.heading_diff is not None and get_scenario(args.scenario).heading is None:
        parser.error('argument --heading-diff: only for a scenario with headings (as boids3d)')
    try:  # a failure writes nothing (save_trajectories is atomic): say so
        opts = ImportOptions(
            scenario=args.scenario,
            rate=args.rate,
            topics=split_patterns(args.topics),
            frames=split_patterns(args.frames),
            id_map=parse_id_map(args.id_map) if args.id_map else None,
            use_twist=args.use_twist,
            twist_frame=args.twist_frame,
            use_orientation=args.use_orientation,
            stamp=args.stamp,
            **resample_option_values(args),
        )
        result = import_bags(args.bag, opts)
        meta = dict(
            result.meta,
            command=' '.join(
                ['python -m training.import_bag'] + list(sys.argv[1:] if argv is None else argv)
            ),
        )
        save_trajectories(args.out, result.states, result.dt, result.scenario, meta)
    except (BagError, TrackError, TrajectoryError, OSError) as exc:
        raise KnodeError(f'{exc}; nothing written') from None
    for line in result.summary:
        print(line)
    name = get_scenario(result.scenario).name
    print(f'wrote {args.out}: states {list(result.states.shape)} ({name}, dt {result.dt:.6g} s)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
