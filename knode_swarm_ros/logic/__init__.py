"""What robots, the simulated swarm and the recorder decide, without ROS (imports only the core).

- :mod:`.agent`: one robot's controller: what it hears (:mod:`.agent.hearing`), its neighbour
  matrix and command (:mod:`.agent.batch`, :mod:`.agent.agent_logic`), several robots in one
  process (:mod:`.agent.hosted`), realtime ticks and the control period;
- :mod:`.simulator`: the simulated swarm (:mod:`.simulator.swarm_sim`), its robot models
  (:mod:`.simulator.robot_models`) and its run phases (:mod:`.simulator.run_phases`);
- :mod:`.recorder`: states into frames and a trajectory file;
- :mod:`.contract`: the message contract that needs no rclpy: REP 105 mapping, orientations,
  QoS specs; :mod:`.common`: topic names, stamps, exit statuses, statuses as JSON;
- :mod:`.reporting`: throttled logs and exit reports.

The nodes (:mod:`knode_swarm_ros.nodes`), the bag tools and training build on this layer.
"""
