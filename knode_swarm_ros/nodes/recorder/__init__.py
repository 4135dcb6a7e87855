"""The ``recorder`` executable: every robot's odometry into a trajectory file.

Modules: :mod:`.node` the node. The frame collection lives in
:mod:`knode_swarm_ros.logic.recorder`. Importing this package imports nothing heavy; :func:`main`
loads the node.
"""


def main(args=None):
    """Entry point of ``recorder``: Ctrl-C during the slow imports ends quietly, then the node runs."""
    from ..common.startup import quiet_until_running

    quiet_until_running()
    from .node import main as run_node_main

    return run_node_main(args)
