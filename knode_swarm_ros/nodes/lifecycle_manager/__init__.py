"""The ``lifecycle_manager`` executable: configures every managed agent, then activates them together
(``swarm --managed``).

Modules: :mod:`.node` the node. Importing this package imports nothing heavy; :func:`main` loads
the node.
"""


def main(args=None):
    """Entry point of ``lifecycle_manager``: Ctrl-C during the slow imports ends quietly, then the node runs."""
    from ..common.startup import quiet_until_running

    quiet_until_running()
    from .node import main as run_node_main

    return run_node_main(args)
