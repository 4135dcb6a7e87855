"""The ``monitor`` executable: watch a simulated or real swarm live, in RViz and in a browser.

Modules: :mod:`.node` the node (markers, metrics), :mod:`.web` the web page and its WebSocket
(aiohttp, in a thread of its own), ``page.html`` the page. The logic lives in
:mod:`knode_swarm_ros.logic.monitor`. Importing this package imports nothing heavy; :func:`main`
loads the node.
"""


def main(args=None):
    """Entry point of ``monitor``: Ctrl-C during the slow imports ends quietly, then the node runs."""
    from ..common.startup import quiet_until_running

    quiet_until_running()
    from .node import main as run_node_main

    return run_node_main(args)
