"""``python -m knode_swarm_ros.nodes.lifecycle_manager``: the ``lifecycle_manager`` executable."""

import sys

from . import main

sys.exit(main())
