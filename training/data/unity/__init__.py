"""The Unity boids study: libraries shared by its commands (``training.import_unity``,
``training.studies.compare_unity``, ``training.studies.unity_retime``, ``training.studies.unity_policies``).

* :mod:`.recordings`: read and check a recording, the shipped ones (data in ``training/unity_boids/``);
* :mod:`.frames`: Unity's frame times recovered from a recording, our boids stepped with them;
* :mod:`.statistics`: run statistics independent of initial conditions, group comparisons, POD-KLD pairs.

Commands import these modules, never each other.
"""
