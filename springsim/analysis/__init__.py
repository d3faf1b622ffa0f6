"""Looking at a model from outside a run: spectral estimates (:mod:`.spectral`: the stiffness matrix, the largest
natural frequency, explicit substeps) and independent reference trajectories from scipy's ``solve_ivp``
(:mod:`.reference`).

The names of :mod:`springsim.analysis.spectral` are re-exported here (``from springsim.analysis import
max_frequency``); :mod:`.reference` loads the drivers, so it is imported by name.
"""

from .spectral import explicit_substeps, max_frequency, stiffness_matrix

__all__ = ["stiffness_matrix", "max_frequency", "explicit_substeps"]
