"""springsim: large mass-spring systems with implicit time integration and fast sparse assembly.

Everyday names live here; everything else has one import path in its subpackage
(:mod:`springsim.forces`, :mod:`springsim.assembly`, :mod:`springsim.linsolve`,
:mod:`springsim.integrators`, :mod:`springsim.scene`).
"""

from .builder import ModelBuilder
from .driver import Trajectory, simulate
from .errors import (ConvergenceWarning, FallbackWarning, SceneError, SceneTypeError, SimulationError,
                     SimulationInterrupted, SolverError, SpringsimError, SpringsimWarning)
from .integrators import INTEGRATORS, make_integrator
from .linsolve import LINEAR_SOLVERS, make_linear_solver
from .model import Model, State

__version__ = "0.1.0"

__all__ = ["ModelBuilder", "Model", "State", "Trajectory", "simulate", "make_integrator", "make_linear_solver",
           "INTEGRATORS", "LINEAR_SOLVERS", "SpringsimError", "SceneError", "SceneTypeError", "SimulationError",
           "SolverError", "SimulationInterrupted", "SpringsimWarning", "ConvergenceWarning", "FallbackWarning",
           "__version__"]
