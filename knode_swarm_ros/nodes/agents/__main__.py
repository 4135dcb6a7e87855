"""``python -m knode_swarm_ros.nodes.agents``: the ``agents`` executable."""

import sys

from . import main

sys.exit(main())
