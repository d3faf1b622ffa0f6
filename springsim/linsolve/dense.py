"""``dense``: numpy LU on the dense matrix. The reference; small systems only."""

from __future__ import annotations

import time

import numpy as np

from ._base import LinearSolver, LinearSolveResult, relative_residual

__all__ = ["LinearSolverDense"]


class LinearSolverDense(LinearSolver):
    """``np.linalg.solve`` on ``A.toarray()`` (O(n^2) memory, O(n^3) time)."""

    name = "dense"

    def _solve(self, A, b, x0):
        t0 = time.perf_counter()
        D = A.toarray()
        t1 = time.perf_counter()
        try:
            x = np.linalg.solve(D, b)
            ok = bool(np.all(np.isfinite(x)))
        except np.linalg.LinAlgError:
            x, ok = np.full_like(b, np.nan), False
        t2 = time.perf_counter()
        res = relative_residual(D, x, b) if ok else float("inf")
        return LinearSolveResult(x, ok, 0, res, self.name, setup_s=t1 - t0, solve_s=t2 - t1,
                                 fallback=None if ok else "singular matrix")
