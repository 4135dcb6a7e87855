"""Reading bags for ``python -m training.import_bag`` (bags -> trajectory files), one module each:

* :mod:`.options`: what is asked (ImportOptions, ``--id-map``) and its checks;
* :mod:`.robots`: which topics or TF child frames are robots, their checked samples (:class:`.robots.Robot`,
  a :class:`~training.data.tracks.Track`);
* :mod:`.report`: message accounting, each bag's ``meta`` and the summary.

The time base, gaps, segments and windows (:mod:`training.data.timeline`) and the derived
velocities and headings (:mod:`training.data.derive`) are shared with ``training.import_tracks``.
Reading the bag itself is :mod:`knode_swarm_ros.bag` (rosbags).
"""
