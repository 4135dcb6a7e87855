"""The ``agent`` executable: one robot's learnt controller as a ROS 2 node.

Modules: :mod:`.node` the node: topics, parameters, timing, :mod:`.params` the per-robot parameters
(shared with ``agents``), :mod:`.health` per-agent health on ``/diagnostics``, :mod:`.managed` the
managed (lifecycle) node mode, :mod:`.link` the link model where neighbour states are received,
:mod:`.unicycle` the differential-drive output mode, :mod:`.plumbing` what it shares with
``agents`` (policy loading, odometry subscriptions, control timers). The logic it wires to
topics lives in :mod:`knode_swarm_ros.logic.agent`. Importing this package imports nothing
heavy; :func:`main` loads the node.
"""


def main(args=None):
    """Entry point of ``agent``: Ctrl-C during the slow imports ends quietly, then the node runs."""
    from ..common.startup import quiet_until_running

    quiet_until_running()
    from .node import main as run_node_main

    return run_node_main(args)
