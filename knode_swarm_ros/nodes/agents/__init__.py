"""The ``agents`` executable: several robots' learnt controllers hosted in one ROS 2 process.

Modules: :mod:`.node` the hosting node. Each hosted robot runs the same logic as a lone agent
(:mod:`knode_swarm_ros.logic.agent.hosted`). Importing this package imports nothing heavy;
:func:`main` loads the node.
"""


def main(args=None):
    """Entry point of ``agents``: Ctrl-C during the slow imports ends quietly, then the node runs."""
    from ..common.startup import quiet_until_running

    quiet_until_running()
    from .node import main as run_node_main

    return run_node_main(args)
