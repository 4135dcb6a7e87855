"""``python -m knode_swarm_ros.nodes.monitor``: the ``monitor`` executable."""

import sys

from . import main

sys.exit(main())
