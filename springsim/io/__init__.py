"""Files: trajectories read in bounded time and memory (``_npz.py``), every output written atomically
(``_atomic.py``), mesh export through meshio (:mod:`.export`) and pictures through matplotlib (:mod:`.viz`).

Nothing is imported here: the drivers use the first two without loading the optional exporters.
"""
