"""The ``simulator`` executable: integrates the swarm and publishes every robot's state.

Modules: :mod:`.node` the node, :mod:`.robot_model` the ``robot_model`` parameters. The swarm
it integrates and its robot models live in :mod:`knode_swarm_ros.logic.simulator`.
Importing this package imports nothing heavy; :func:`main` loads the node.
"""


def main(args=None):
    """Entry point of ``simulator``: Ctrl-C during the slow imports ends quietly, then the node runs."""
    from ..common.startup import quiet_until_running

    quiet_until_running()
    from .node import main as run_node_main

    return run_node_main(args)
