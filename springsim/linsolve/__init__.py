"""Linear solvers, registered by name. Adding one is a module plus one line in :data:`LINEAR_SOLVERS`."""

from __future__ import annotations

from ..errors import SceneError
from ._base import BACKWARD_TOL, LinearSolver, LinearSolveResult, backward_error, relative_residual
from .amg_cg import LinearSolverAMGCG
from .auto import LinearSolverAuto
from .cg import LinearSolverCG
from .dense import LinearSolverDense
from .direct import LinearSolverDirect
from .krylov import LinearSolverAMGGMRES

__all__ = ["LINEAR_SOLVERS", "LinearSolver", "LinearSolverAMGCG", "LinearSolverAMGGMRES", "LinearSolverAuto",
           "LinearSolverCG", "LinearSolveResult", "LinearSolverDense", "LinearSolverDirect",
           "make_linear_solver", "relative_residual", "backward_error", "BACKWARD_TOL"]

#: Registry: name -> class.
LINEAR_SOLVERS: dict[str, type[LinearSolver]] = {
    "dense": LinearSolverDense,
    "direct": LinearSolverDirect,
    "cg": LinearSolverCG,
    "amg-cg": LinearSolverAMGCG,
    "amg-gmres": LinearSolverAMGGMRES,
    "auto": LinearSolverAuto,
}


def make_linear_solver(name: str | LinearSolver, **options) -> LinearSolver:
    """Instantiate a registered solver by name (instances pass through unchanged)."""
    if isinstance(name, LinearSolver):
        return name
    try:
        cls = LINEAR_SOLVERS[name]
    except KeyError:
        raise SceneError("solver.linear_solver",
                         f"unknown linear solver {name!r}; choose one of {', '.join(LINEAR_SOLVERS)}") from None
    return cls(**options)
