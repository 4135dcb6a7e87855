"""Data in: tracks of any source (:mod:`.tracks`, :mod:`.timeline`, :mod:`.derive`), their readers
for ROS bags (:mod:`.bags`) and track files (:mod:`.track_files`), and the Unity recordings (:mod:`.unity`)."""
