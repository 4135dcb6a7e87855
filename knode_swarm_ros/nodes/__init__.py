"""ROS 2 plumbing for knode_swarm_ros: the agent, simulator, recorder and swarm executables.

Each node module (``agent``, ``simulator``, ``recorder``) is a thin Node subclass with a
module-level ``main()`` that its console script calls; the logic lives in ROS-free classes
(``agent_logic``, ``simulator_logic``, ``recorder_logic``) on top of knode_swarm_ros.core.
``conversions`` holds the one state/command <-> message mapping, ``qos`` one QoS profile per
topic, ``swarm`` the multi-process launcher. See docs/ros.md.

Importing this package imports neither rclpy nor torch.
"""
from .startup import quiet_until_running

quiet_until_running()  # in a node executable only: Ctrl-C during the slow imports exits quietly
