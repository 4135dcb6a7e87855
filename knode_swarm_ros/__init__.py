"""knode_swarm_ros: learn decentralised swarm controllers with KNODE and deploy them in ROS 2."""

__version__ = '0.1.0'
