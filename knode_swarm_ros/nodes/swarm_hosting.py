"""Moved to :mod:`knode_swarm_ros.nodes.swarm.hosting`; this name stays for bench/bench_scale.py."""
from .swarm.hosting import *  # noqa: F401,F403
from .swarm.hosting import __all__  # noqa: F401
