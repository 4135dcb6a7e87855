"""``python -m knode_swarm_ros.nodes.recorder``: the ``recorder`` executable."""

import sys

from . import main

sys.exit(main())
