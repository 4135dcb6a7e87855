"""``python -m knode_swarm_ros.nodes.agent``: the ``agent`` executable."""

import sys

from . import main

sys.exit(main())
