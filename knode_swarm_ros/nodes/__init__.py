"""ROS 2 plumbing for knode_swarm_ros, one folder per executable.

- :mod:`.agent`: one robot's controller (``agent``); :mod:`.agents`: several robots hosted in one
  process (``agents``); :mod:`.simulator`; :mod:`.recorder`; :mod:`.lifecycle_manager` (managed
  agents, ``swarm --managed``); :mod:`.swarm`: the multi-process launcher (no rclpy);
- :mod:`.common`: what every node shares: the executor and signals, parameters, rclpy QoS
  profiles, message conversions, RViz markers.

Each executable's node is thin: the logic it wires to topics lives in :mod:`knode_swarm_ros.logic`
(no rclpy). Importing this package, or any executable's package, has no side effects and imports
neither rclpy nor torch; an executable's ``main`` loads them. See docs/ros.md.
"""
