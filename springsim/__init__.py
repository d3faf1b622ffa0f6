"""springsim: large mass-spring systems with implicit time integration and fast sparse assembly.

Everyday names live here; everything else has one import path in its subpackage
(:mod:`springsim.model`, :mod:`springsim.forces`, :mod:`springsim.assembly`, :mod:`springsim.linsolve`,
:mod:`springsim.integrators`, :mod:`springsim.run`, :mod:`springsim.scene`, :mod:`springsim.io`,
:mod:`springsim.analysis`). The former paths of modules that moved into these (``springsim.driver``, ...)
still import, with a DeprecationWarning (``springsim/_compat.py``).

The names are loaded on first use (PEP 562), so ``import springsim`` and the command
line start without importing numpy and scipy; a Ctrl-C during start-up is then handled
by the command line like any other interrupt.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from .errors import (ConvergenceWarning, FallbackWarning, SceneError, SceneTypeError, SimulationError,
                     SimulationInterrupted, SolverError, SpringsimError, SpringsimWarning)
from . import _compat
from ._runtime import accel as _accel  # noqa: F401  (sets NUMBA_CACHE_DIR to a user cache before numba is imported)

_compat.install()  # the former paths of moved modules (``springsim.driver``, ...) keep importing, with a warning

__version__ = "0.1.0"

#: Lazily loaded names -> the module that defines them.
_LAZY = {
    "ModelBuilder": ".model.builder",
    "Model": ".model",
    "State": ".model",
    "Trajectory": ".run.driver",
    "simulate": ".run.driver",
    "simulate_adaptive": ".run.adaptive",
    "make_integrator": ".integrators",
    "INTEGRATORS": ".integrators",
    "make_linear_solver": ".linsolve",
    "LINEAR_SOLVERS": ".linsolve",
    "load_scene": ".scene",
}

__all__ = ["ModelBuilder", "Model", "State", "Trajectory", "simulate", "simulate_adaptive", "make_integrator",
           "make_linear_solver", "load_scene", "INTEGRATORS", "LINEAR_SOLVERS", "SpringsimError", "SceneError",
           "SceneTypeError", "SimulationError", "SolverError", "SimulationInterrupted", "SpringsimWarning",
           "ConvergenceWarning", "FallbackWarning", "__version__"]


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        if f"{__name__}.{name}" in _compat.MOVED:  # a moved module asked for as an attribute: its former path
            return importlib.import_module(f"{__name__}.{name}")
        raise AttributeError(f"module 'springsim' has no attribute {name!r}")
    value = getattr(importlib.import_module(module, __name__), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_LAZY))


if TYPE_CHECKING:  # pragma: no cover
    from .integrators import INTEGRATORS, make_integrator
    from .linsolve import LINEAR_SOLVERS, make_linear_solver
    from .model import Model, State
    from .model.builder import ModelBuilder
    from .run.adaptive import simulate_adaptive
    from .run.driver import Trajectory, simulate
    from .scene import load_scene
