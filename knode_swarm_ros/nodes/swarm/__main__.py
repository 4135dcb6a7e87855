"""``python -m knode_swarm_ros.nodes.swarm``: the ``swarm`` executable."""

from .cli import main

if __name__ == '__main__':
    main()
