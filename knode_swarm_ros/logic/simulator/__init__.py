"""The simulated swarm without ROS: states, robot models, integration and the run's phases."""
