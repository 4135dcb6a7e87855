"""Data in: readers of ROS bags (:mod:`.bags`) and of the Unity recordings (:mod:`.unity`)."""
