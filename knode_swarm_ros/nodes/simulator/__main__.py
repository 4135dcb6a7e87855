"""``python -m knode_swarm_ros.nodes.simulator``: the ``simulator`` executable."""

import sys

from . import main

sys.exit(main())
