"""Benchmark reading and writing bags: rosbags in every format, against the
mcap-ros2-support decoder the importer used before, in the same run.

    python bench/bench_bag.py [--robots 10] [--seconds 20] [--rate 100] [--repeat 3]

One swarm run (``--robots`` robots' nav_msgs/Odometry at ``--rate`` Hz for ``--seconds``) is
written as: a rosbag2 MCAP bag by the project's writer (knode_swarm_ros.bag, rosbags underneath),
and rosbag2 sqlite3 and ROS 1 bags by rosbags' writers. Times, best of ``--repeat``:

* write: the project's writer (states -> Odometry dicts -> typed messages -> CDR -> MCAP);
* read: ``Bag.messages`` (open, read, decode every message) for each format, in messages/s;
* baseline: the same MCAP file decoded by ``mcap`` + ``mcap-ros2-support`` (the reader the
  importer had before), if installed; ratios are against it.
* import: ``python -m training.import_bag``'s ``import_bag`` on the MCAP bag (read, resample,
  derive), end to end.

Nothing here asserts timings.
"""

from __future__ import annotations

import argparse
import datetime
import platform
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from knode_swarm_ros.bag import ODOMETRY, open_bag, write_odometry_bag
from knode_swarm_ros.bag.messages import odometry_message, to_message


def best(fn, repeat):
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def read_all(path):
    bag = open_bag(path)
    return sum(1 for _ in bag.messages(list(bag.topics())))


def read_mcap_ros2(path):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    n = 0
    with open(path, 'rb') as fh:
        for _ in make_reader(fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages(
            log_time_order=True
        ):
            n += 1
    return n


def write_rosbags(path, fmt, states, stamps):
    from rosbags.rosbag1 import Writer as W1
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as W2
    from rosbags.typesys import Stores, get_typestore

    T, n, _ = states.shape
    store = get_typestore(Stores.ROS1_NOETIC if fmt == 'ros1' else Stores.ROS2_JAZZY)
    ser = store.serialize_ros1 if fmt == 'ros1' else store.serialize_cdr
    writer = W1(path) if fmt == 'ros1' else W2(path, version=9, storage_plugin=StoragePlugin.SQLITE3)
    with writer:
        conns = [writer.add_connection(f'/robot_{i}/odom', ODOMETRY, typestore=store) for i in range(n)]
        for t in range(T):
            for i in range(n):
                msg = to_message(
                    ODOMETRY, odometry_message('flock2d', states[t, i], int(stamps[t]), i), store
                )
                writer.write(conns[i], int(stamps[t]), ser(msg, ODOMETRY))


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    p.add_argument('--robots', type=int, default=10)
    p.add_argument('--seconds', type=float, default=20.0)
    p.add_argument('--rate', type=float, default=100.0)
    p.add_argument('--repeat', type=int, default=3)
    args = p.parse_args(argv)
    T, n = int(args.seconds * args.rate) + 1, args.robots
    t = np.arange(T) / args.rate
    a = t[:, None] + np.arange(n)[None, :]
    states = np.stack([2 * np.cos(a), 2 * np.sin(a), -2 * np.sin(a), 2 * np.cos(a)], axis=-1)
    stamps = np.rint(t * 1e9).astype(np.int64) + 1_700_000_000 * 10**9
    messages = T * n
    print(f'# bench/bench_bag.py {" ".join(sys.argv[1:])}')
    print(
        f'# {datetime.date.today()} {platform.machine()} {platform.python_version()}, {messages} Odometry messages '
        f'({n} robots, {args.rate:g} Hz, {args.seconds:g} s)'
    )
    tmp = Path(tempfile.mkdtemp(prefix='bench_bag.'))
    try:
        mcap_dir = tmp / 'mcap_bag'
        w = best(
            lambda: write_odometry_bag(
                mcap_dir, states, 1 / args.rate, 'flock2d', stamps=stamps, overwrite=True
            ),
            args.repeat,
        )
        print(f'write  project writer (rosbags, mcap)  {w:7.2f} s  {messages / w:9.0f} msg/s')
        write_rosbags(tmp / 'sqlite_bag', 'sqlite3', states, stamps)
        write_rosbags(tmp / 'run.bag', 'ros1', states, stamps)
        mcap_file = next(mcap_dir.glob('*.mcap'))
        base = None
        try:
            base = best(lambda: read_mcap_ros2(mcap_file), args.repeat)
            print(
                f'read   mcap-ros2-support (baseline)    {base:7.2f} s  {messages / base:9.0f} msg/s  1.00x'
            )
        except ImportError:
            print('read   mcap-ros2-support (baseline)    not installed')
        for label, path in (
            ('rosbags, rosbag2 mcap', mcap_dir),
            ('rosbags, rosbag2 sqlite3', tmp / 'sqlite_bag'),
            ('rosbags, ROS 1', tmp / 'run.bag'),
        ):
            assert read_all(path) == messages
            r = best(lambda: read_all(path), args.repeat)
            ratio = f'  {base / r:.2f}x' if base else ''
            print(f'read   {label:<31} {r:7.2f} s  {messages / r:9.0f} msg/s{ratio}')
        from training.import_bag import ImportOptions, import_bag

        opts = ImportOptions(scenario='flock2d', rate=args.rate, topics=['/robot_*/odom'])
        i = best(lambda: import_bag(mcap_dir, opts), args.repeat)
        print(f'import training.import_bag (mcap)      {i:7.2f} s  {messages / i:9.0f} msg/s')
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == '__main__':
    main()
