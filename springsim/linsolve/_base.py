"""Linear-solver interface: ``solve(A, b, *, x0=None) -> LinearSolveResult``.

``A`` is a :class:`~springsim.assembly.SystemMatrix` (or any scipy sparse matrix /
ndarray, wrapped on the fly). Options (``rtol``, ``atol``, ``maxiter``, ...) are
keyword-only constructor arguments. Solvers keep reusable work (orderings, AMG
hierarchies) between calls while the matrix pattern is unchanged.

The contract of a result (:class:`LinearSolveResult`)
-----------------------------------------------------
``converged`` is True only when the solver's own criterion holds for the returned ``x``:

* iterative solvers: the true relative residual ``|b - A x|_2 / |b|_2 <= max(rtol, atol / |b|_2)``;
* direct solvers: the normwise backward error (Rigal and Gaches 1967; Higham 2002, thm. 7.1)::

      eta = |b - A x|_inf / (|A|_inf |x|_inf + |b|_inf) <= backward_tol

  i.e. ``x`` solves a system within a relative perturbation ``eta`` of ``(A, b)``. A
  backward-stable factorisation gives ``eta`` of a few units of round-off whatever the
  conditioning; the relative residual of an exact-to-round-off solution can be as large as
  ``cond(A) u``, so it is the wrong test for a direct method.

When ``converged`` is False, ``failure`` says why (one line) and ``x`` must not be used as a
solution; when a fallback solver answered, ``fallback`` says why the primary one handed over.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
import scipy.sparse as sp

from .._runtime.threads import single_blas_thread

__all__ = ["LinearSolver", "LinearSolveResult", "as_system_matrix", "relative_residual", "backward_error",
           "inf_norm", "BACKWARD_TOL", "DEFAULT_RTOL"]

#: Default relative tolerance of iterative linear solves, ``|b - A x|_2 <= rtol |b|_2``: of every solver
#: (the ``rtol`` of :class:`LinearSolver`; the direct ones accept it and are judged by their backward error
#: instead) and of the PETSc backend's KSP solves. The run option ``linear_rtol`` overrides it.
DEFAULT_RTOL = 1e-6

#: Default normwise backward-error tolerance of the direct solvers: about 4500 units of round-off,
#: far above what a stable factorisation gives (1e-17 ... 1e-15 measured on the test systems) and
#: far below the first digit that matters to a Newton direction.
BACKWARD_TOL = 1e-12


@dataclass
class LinearSolveResult:
    """Outcome of one linear solve.

    Attributes
    ----------
    x : ndarray
        Solution (not to be used as one when ``converged`` is False).
    converged : bool
        Whether the solver's criterion holds for ``x`` (after any refinement or fallback; see
        the module docstring).
    iterations : int
        Krylov iterations (0 for direct methods; refinement steps are in ``info``).
    residual : float
        Relative residual ``|b - A x|_2 / |b|_2``.
    method : str
        Solver that produced ``x`` (after any fallback, e.g. ``"amg-cg->direct"``).
    setup_s, solve_s : float
        Wall time of setup (factorisation, hierarchy) and of the solve [s].
    failure : str or None
        Why ``converged`` is False (one line), else None.
    fallback : str or None
        Why the primary solver handed over to its fallback (e.g. ``"amg-cg: non-positive
        curvature after 3 iterations"``), else None.
    backward_error : float
        Normwise backward error of ``x`` (NaN where not computed).
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
    failure: str | None = None
    fallback: str | None = None
    backward_error: float = float("nan")
    info: dict = field(default_factory=dict)

    @property
    def time_s(self) -> float:
        """Total wall time [s]: :attr:`setup_s` + :attr:`solve_s`."""
        return self.setup_s + self.solve_s


def relative_residual(A, x: np.ndarray, b: np.ndarray) -> float:
    """``|b - A x|_2 / |b|_2`` (``|b - A x|_2`` when ``b = 0``).

    Parameters
    ----------
    A : SystemMatrix, scipy.sparse matrix or ndarray, shape (n, n)
        The matrix.
    b : ndarray, shape (n,)
        Right-hand side.
    x : ndarray, shape (n,)
        Approximate solution.

    Returns
    -------
    float
    """
    bn = np.linalg.norm(b)
    r = np.linalg.norm(b - A @ x)
    return float(r / bn) if bn > 0 else float(r)


def inf_norm(A) -> float:
    """``|A|_inf``, the largest absolute row sum of a sparse or dense matrix.

    Parameters
    ----------
    A : scipy.sparse matrix or ndarray
        The matrix.

    Returns
    -------
    float
    """
    if sp.issparse(A):
        A = A.tocsr()
        absA = sp.csr_matrix((np.abs(A.data), A.indices, A.indptr), shape=A.shape)
        return float((absA @ np.ones(A.shape[1])).max(initial=0.0))
    return float(np.abs(A).sum(axis=1).max(initial=0.0))


def backward_error(A, x: np.ndarray, b: np.ndarray, A_norm: float | None = None) -> float:
    """Normwise backward error ``|b - A x|_inf / (|A|_inf |x|_inf + |b|_inf)`` (0 for ``b = x = 0``).

    The smallest ``eta`` such that ``(A + dA) x = b + db`` with ``|dA| <= eta |A|`` and
    ``|db| <= eta |b|`` in the infinity norm (Rigal and Gaches 1967). ``A_norm`` may pass a
    precomputed ``|A|_inf``. Infinite when ``x`` is not finite.

    Parameters
    ----------
    A : SystemMatrix, scipy.sparse matrix or ndarray, shape (n, n)
        The matrix.
    b : ndarray, shape (n,)
        Right-hand side.
    x : ndarray, shape (n,)
        Approximate solution.
    A_norm : float, optional
        ``|A|_inf``, if already known.

    Returns
    -------
    float
        ``eta`` (inf when ``x`` is not finite).
    """
    if not np.all(np.isfinite(x)):
        return float("inf")
    r = float(np.abs(b - A @ x).max(initial=0.0))
    den = (inf_norm(A) if A_norm is None else A_norm) * float(np.abs(x).max(initial=0.0)) \
        + float(np.abs(b).max(initial=0.0))
    return r / den if den > 0 else (0.0 if r == 0 else float("inf"))


def as_system_matrix(A):
    """Wrap a scipy sparse matrix or ndarray as a SystemMatrix-like object.

    Parameters
    ----------
    A : SystemMatrix, scipy.sparse matrix or ndarray
        The matrix.

    Returns
    -------
    SystemMatrix or a stand-in with its attributes (``bsr``, ``shape``, ``symmetric``, ``pattern`` None, ...)
    """
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
        Stop when ``|b - A x| <= max(rtol |b|, atol)`` (iterative solvers; default ``rtol``
        :data:`DEFAULT_RTOL`, ``atol`` 0).
    maxiter : int or None
        Iteration limit (iterative solvers).
    """

    name: ClassVar[str]
    #: True for solvers that need a symmetric positive definite matrix (CG family);
    #: integrators then default to the ``spd`` Jacobian mode.
    needs_spd: bool = False

    def __init__(self, *, rtol: float = DEFAULT_RTOL, atol: float = 0.0, maxiter: int | None = None):
        if not (rtol >= 0 and atol >= 0):
            raise ValueError(f"rtol and atol must be >= 0, got {rtol}, {atol}")
        self.rtol = float(rtol)
        self.atol = float(atol)
        self.maxiter = maxiter

    def needs_spd_for(self, dofs: int) -> bool:
        """Whether systems of ``dofs`` unknowns need the ``spd`` Jacobian mode with this solver
        (integrators choose their default mode with it); ``needs_spd`` unless overridden.

        Parameters
        ----------
        dofs : int
            Number of unknowns.

        Returns
        -------
        bool
        """
        return self.needs_spd

    def solve(self, A, b: np.ndarray, *, x0: np.ndarray | None = None, rtol: float | None = None) -> LinearSolveResult:
        """Solve ``A x = b``; ``x0`` is an initial guess for iterative methods.

        ``rtol`` replaces :attr:`rtol` for this solve (iterative solvers; e.g. the forcing term of an
        inexact Newton iteration): it is passed down as an argument, the solver's own :attr:`rtol` is never
        changed; direct solvers solve to round-off whatever it is.
        Runs with one BLAS thread (:func:`springsim._runtime.threads.single_blas_thread`).

        Parameters
        ----------
        A : SystemMatrix, scipy.sparse matrix or ndarray, shape (n, n)
            The matrix.
        b : ndarray, shape (n,)
            Right-hand side.
        x0 : ndarray, shape (n,), optional
            Initial guess.
        rtol : float, optional
            Relative tolerance for this solve, >= 0.

        Returns
        -------
        LinearSolveResult
            The solution with its convergence, fallback and timing statistics.

        Raises
        ------
        ValueError
            ``b`` of the wrong shape, or a negative ``rtol``.
        """
        A = as_system_matrix(A)
        b = np.asarray(b, dtype=np.float64)
        if b.ndim != 1 or b.shape[0] != A.shape[0]:
            raise ValueError(f"b must have shape ({A.shape[0]},), got {b.shape}")
        if b.size == 0:
            return LinearSolveResult(np.zeros(0), True, 0, 0.0, self.name, backward_error=0.0)
        if rtol is not None and not rtol >= 0:
            raise ValueError(f"rtol must be >= 0, got {rtol}")
        with single_blas_thread():
            return self._solve(A, b, x0, self.rtol if rtol is None else float(rtol))

    @abstractmethod
    def _solve(self, A, b: np.ndarray, x0: np.ndarray | None, rtol: float) -> LinearSolveResult:
        """Solve the wrapped system ``A x = b`` to the relative tolerance ``rtol`` (subclasses implement it)."""
        ...

