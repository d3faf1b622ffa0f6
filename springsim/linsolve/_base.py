"""Linear-solver interface: ``solve(A, b, *, x0=None) -> LinearSolveResult``.

``A`` is a :class:`~springsim.assembly.SystemMatrix` (or any scipy sparse matrix /
ndarray, wrapped on the fly). Options (``rtol``, ``atol``, ``maxiter``, ...) are
keyword-only constructor arguments. Tolerances are on the relative residual
``|b - A x| / |b|``. Solvers keep reusable work (orderings, AMG hierarchies) between
calls while the matrix pattern is unchanged.
"""

from __future__ import annotations

import time
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
import scipy.sparse as sp

__all__ = ["LinearSolver", "LinearSolveResult", "as_system_matrix", "relative_residual"]


@dataclass
class LinearSolveResult:
    """Outcome of one linear solve.

    Attributes
    ----------
    x : ndarray
        Solution.
    converged : bool
        Whether the requested tolerance was met (after any fallback).
    iterations : int
        Krylov iterations (0 for direct methods).
    residual : float
        Final relative residual ``|b - A x| / |b|``.
    method : str
        Solver that produced ``x`` (after any fallback, e.g. ``"amg-cg->direct"``).
    setup_s, solve_s : float
        Wall time of setup (factorisation, hierarchy) and of the solve [s].
    fallback : str or None
        Why a fallback happened (e.g. ``"non-positive curvature"``), else None.
    info : dict
        Solver-specific details.
    """

    x: np.ndarray
    converged: bool
    iterations: int
    residual: float
    method: str
    setup_s: float = 0.0
    solve_s: float = 0.0
    fallback: str | None = None
    info: dict = field(default_factory=dict)

    @property
    def time_s(self) -> float:
        return self.setup_s + self.solve_s


def relative_residual(A, x: np.ndarray, b: np.ndarray) -> float:
    bn = np.linalg.norm(b)
    r = np.linalg.norm(b - A @ x)
    return float(r / bn) if bn > 0 else float(r)


def as_system_matrix(A):
    """Wrap a scipy sparse matrix or ndarray as a SystemMatrix-like object."""
    from ..assembly.assemble import SystemMatrix

    if isinstance(A, SystemMatrix):
        return A
    return _PlainMatrix(A)


class _PlainMatrix:
    """Minimal SystemMatrix stand-in for matrices not built by the assembler."""

    def __init__(self, A):
        self._A = A
        self.shape = A.shape
        self.mode = "exact"
        dense = not sp.issparse(A)
        M = A if dense else A.tocsr()
        diff = (M - M.T)
        self.symmetric = bool(np.abs(diff).max() <= 1e-12 * max(np.abs(M).max(), 1e-300)) if diff.size else True
        self.positions = None
        self.version = 0
        self.pattern = None

    @property
    def bsr(self):
        return sp.bsr_matrix(self._A, blocksize=(3, 3)) if self.shape[0] % 3 == 0 else sp.csr_matrix(self._A)

    def tocsr(self):
        return sp.csr_matrix(self._A)

    def tocsc(self):
        return sp.csc_matrix(self._A)

    def toarray(self):
        return self._A.toarray() if sp.issparse(self._A) else np.asarray(self._A)

    def __matmul__(self, x):
        return self._A @ x


class LinearSolver(ABC):
    """Base of all linear solvers; subclasses set :attr:`name` and implement :meth:`_solve`.

    Parameters
    ----------
    rtol, atol : float
        Stop when ``|b - A x| <= max(rtol |b|, atol)`` (iterative solvers).
    maxiter : int or None
        Iteration limit (iterative solvers).
    """

    name: ClassVar[str]
    #: True for solvers that need a symmetric positive definite matrix (CG family);
    #: integrators then default to the ``spd`` Jacobian mode.
    needs_spd: ClassVar[bool] = False

    def __init__(self, *, rtol: float = 1e-8, atol: float = 0.0, maxiter: int | None = None):
        if not (rtol >= 0 and atol >= 0):
            raise ValueError(f"rtol and atol must be >= 0, got {rtol}, {atol}")
        self.rtol = float(rtol)
        self.atol = float(atol)
        self.maxiter = maxiter

    def needs_spd_for(self, dofs: int) -> bool:
        """Whether systems of ``dofs`` unknowns need the ``spd`` Jacobian mode with this solver
        (integrators choose their default mode with it); ``needs_spd`` unless overridden."""
        return self.needs_spd

    def solve(self, A, b: np.ndarray, *, x0: np.ndarray | None = None) -> LinearSolveResult:
        """Solve ``A x = b``; ``x0`` is an initial guess for iterative methods."""
        A = as_system_matrix(A)
        b = np.asarray(b, dtype=np.float64)
        if b.size == 0:
            return LinearSolveResult(np.zeros(0), True, 0, 0.0, self.name)
        return self._solve(A, b, x0)

    @abstractmethod
    def _solve(self, A, b: np.ndarray, x0: np.ndarray | None) -> LinearSolveResult:
        ...

    def _timed(self):
        return time.perf_counter()
