"""One robot's controller without ROS: hearing, neighbour matrices, commands, timing."""
