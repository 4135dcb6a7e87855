"""The steps of ``python -m training.import_bag`` (bags -> trajectory files), one module each:

* :mod:`.options`: what is asked (ImportOptions, ``--id-map``) and its checks;
* :mod:`.robots`: which topics or TF child frames are robots, their checked samples;
* :mod:`.timeline`: time base, gaps, segments on the output grid, equal-length windows;
* :mod:`.derive`: velocities and headings on the grid (differences, twist, orientation);
* :mod:`.report`: message accounting, ``meta`` and the summary.

Reading the bag itself is :mod:`knode_swarm_ros.bag` (rosbags).
"""
