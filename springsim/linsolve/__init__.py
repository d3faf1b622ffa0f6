"""Linear solvers, registered by name.

``dense`` and ``direct`` factor the matrix; ``cg``, ``amg-cg`` and ``amg-gmres`` are presets of
:class:`LinearSolverIterative` (a Krylov method, a preconditioner and a fallback solver); ``auto``
chooses among them by size and symmetry. Adding a solver is a module plus one line in
:data:`LINEAR_SOLVERS`; adding a Krylov method or a preconditioner is a class plus one line in
:data:`~springsim.linsolve.krylov.KRYLOV_METHODS` or
:data:`~springsim.linsolve.preconditioners.PRECONDITIONERS`.
"""

from __future__ import annotations

from ..errors import registered
from ._base import BACKWARD_TOL, DEFAULT_RTOL, LinearSolver, LinearSolveResult, backward_error, relative_residual
from .auto import LinearSolverAuto
from .dense import LinearSolverDense
from .direct import LinearSolverDirect
from .iterative import LinearSolverAMGCG, LinearSolverAMGGMRES, LinearSolverCG, LinearSolverIterative
from .krylov import CG, GMRES, KRYLOV_METHODS
from .preconditioners import PRECONDITIONERS, Preconditioner

__all__ = ["LINEAR_SOLVERS", "LinearSolver", "LinearSolveResult", "LinearSolverDense", "LinearSolverDirect",
           "LinearSolverIterative", "LinearSolverCG", "LinearSolverAMGCG", "LinearSolverAMGGMRES", "LinearSolverAuto",
           "CG", "GMRES", "KRYLOV_METHODS", "Preconditioner", "PRECONDITIONERS", "make_linear_solver",
           "linear_solver_class", "relative_residual", "backward_error", "BACKWARD_TOL",
           "DEFAULT_RTOL"]

#: Registry: name -> solver class (the iterative ones are presets of :class:`LinearSolverIterative`).
LINEAR_SOLVERS: dict[str, type[LinearSolver]] = {
    "dense": LinearSolverDense,
    "direct": LinearSolverDirect,
    "cg": LinearSolverCG,
    "amg-cg": LinearSolverAMGCG,
    "amg-gmres": LinearSolverAMGGMRES,
    "auto": LinearSolverAuto,
}


def linear_solver_class(name: str) -> type[LinearSolver]:
    """The registered solver class ``name``; a SceneError naming ``linear_solver`` and the choices if unknown.

    Parameters
    ----------
    name : str
        A key of :data:`LINEAR_SOLVERS`.

    Returns
    -------
    type
        A :class:`LinearSolver` subclass.

    Raises
    ------
    SceneError
        ``name`` is not registered.
    """
    return registered(LINEAR_SOLVERS, name, param="linear_solver", what="linear solver")


def make_linear_solver(name: str | LinearSolver, **options) -> LinearSolver:
    """Instantiate a registered solver by name with ``options`` (an instance passes through unchanged).

    Parameters
    ----------
    name : str or LinearSolver
        A key of :data:`LINEAR_SOLVERS`, or an instance.
    **options
        Keyword options of the solver class (``rtol``, ``atol``, ``maxiter``, ...).

    Returns
    -------
    LinearSolver

    Raises
    ------
    SceneError
        A ``ValueError`` naming ``linear_solver`` for an unknown name, listing the registered ones.
    """
    if isinstance(name, LinearSolver):
        if options:
            raise TypeError(f"solver options {sorted(options)} need a solver name, not an instance")
        return name
    return linear_solver_class(name)(**options)
