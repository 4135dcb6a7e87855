"""Bags without ROS: read rosbag2 (sqlite3, mcap) and ROS 1 recordings, write rosbag2 MCAP bags.

Built on the ``rosbags`` package (the ``bag`` extra: ``pip install 'knode_swarm_ros[bag]'``),
imported only when a bag is opened or written, so robots don't need it.

* :mod:`.messages`: type names, stamp <-> nanoseconds, the state -> Odometry mapping, the
  poses a message carries;
* :mod:`.reader`: :func:`open_bag` -> :class:`Bag` (topics, decoded messages);
* :mod:`.writer`: :class:`BagWriter`, :func:`write_odometry_bag`;
* :mod:`.qos`: the nodes' QoS profiles in rosbag2's format;
* the orientation maths a pose needs (:func:`quaternion_to_heading`, :func:`rotate_by_quaternion`,
  from :mod:`knode_swarm_ros.logic.contract.orientation`, ROS-free), so that bag users import one package.

``training.import_bag`` turns bags into trajectory files; the recorder (``-p bag:=...``,
``swarm --bag``) writes them. docs/import_bag.md documents both.
"""

from knode_swarm_ros.logic.contract.orientation import quaternion_to_heading, rotate_by_quaternion

from .messages import (
    ODOMETRY,
    POSE_STAMPED,
    SUPPORTED_TYPES,
    TF_MESSAGE,
    BagError,
    BagWriteError,
    Sample,
    normalise_type,
    ns_to_stamp,
    odometry_message,
    samples_of,
    stamp_to_ns,
)
from .reader import Bag, open_bag
from .writer import BagWriter, write_odometry_bag

__all__ = [
    'ODOMETRY',
    'POSE_STAMPED',
    'TF_MESSAGE',
    'SUPPORTED_TYPES',
    'BagError',
    'BagWriteError',
    'Sample',
    'normalise_type',
    'ns_to_stamp',
    'stamp_to_ns',
    'odometry_message',
    'samples_of',
    'Bag',
    'open_bag',
    'BagWriter',
    'write_odometry_bag',
    'quaternion_to_heading',
    'rotate_by_quaternion',
]
