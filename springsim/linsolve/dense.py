"""``dense``: LAPACK LU with partial pivoting on the dense matrix. The reference; small systems only.

The solution is checked by its normwise backward error and refined with the same
factors when needed, as in :mod:`springsim.linsolve.direct`.
"""

from __future__ import annotations

import time

import numpy as np
import scipy.linalg as sla

from ._base import BACKWARD_TOL, LinearSolver, LinearSolveResult, inf_norm, relative_residual
from .direct import refine

__all__ = ["LinearSolverDense"]


class LinearSolverDense(LinearSolver):
    """LAPACK ``getrf`` / ``getrs`` on ``A.toarray()`` (O(n^2) memory, O(n^3) time).

    Parameters
    ----------
    backward_tol : float
        Normwise backward error a solution must reach.
    refine : int
        Refinement steps allowed.
    **kw
        ``rtol``, ``atol``, ``maxiter`` of :class:`~springsim.linsolve.LinearSolver`; accepted for a uniform
        interface, unused (the solution is judged by its backward error).
    """

    name = "dense"

    def __init__(self, *, backward_tol: float = BACKWARD_TOL, refine: int = 3, **kw):
        super().__init__(**kw)
        self.backward_tol = float(backward_tol)
        self.refine = int(refine)

    def _solve(self, A, b, x0, rtol):
        t0 = time.perf_counter()
        D = A.toarray()
        # LAPACK getrf directly: it reports an exactly zero pivot in ``info`` (lu_factor warns instead)
        lu_, piv, info = sla.lapack.dgetrf(D)
        lu = (lu_, piv)
        t1 = time.perf_counter()
        if info != 0 or not np.all(np.isfinite(lu_)):
            x, eta, done, failure = np.full_like(b, np.nan), float("inf"), 0, "singular matrix"
        else:
            def solve(r):
                return sla.lu_solve(lu, r, check_finite=False)

            x, eta, done = refine(D, solve, b, solve(b), A_norm=inf_norm(D), tol=self.backward_tol, steps=self.refine)
            failure = None if eta <= self.backward_tol else \
                f"backward error {eta:.1e} > {self.backward_tol:.0e} after {done} refinement step(s)"
        t2 = time.perf_counter()
        res = relative_residual(D, x, b) if np.all(np.isfinite(x)) else float("inf")
        return LinearSolveResult(x, failure is None, 0, res, self.name, setup_s=t1 - t0, solve_s=t2 - t1,
                                 failure=failure, backward_error=eta, info={"refinements": done})
