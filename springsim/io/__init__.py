"""Files: trajectories read in bounded time and memory (:mod:`._npz`), every output written atomically
(:mod:`._atomic`), mesh export through meshio (:mod:`.export`) and pictures through matplotlib (:mod:`.viz`).

Nothing is imported here: the drivers use the first two without loading the optional exporters.
"""
