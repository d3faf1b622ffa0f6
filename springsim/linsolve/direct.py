"""``direct``: scipy's SuperLU with a symmetric fill-reducing ordering.

The implicit system's pattern is structurally symmetric, so SuperLU orders it
by minimum degree on ``A^T + A`` (``MMD_AT_PLUS_A``) in symmetric mode (diagonal
pivots preferred). Measured on the benchmark cloth: n = 128 factors in 1.3 s with
8.5M nonzeros in L+U, against 4.3 s and 15.7M for the default COLAMD.

What is reused across steps is the conversion: the assembler's BSR data reaches
CSC through one precomputed gather (:meth:`SystemMatrix.tocsc`). SuperLU exposes
no reusable symbolic factorisation (re-factoring a pre-permuted matrix with
``NATURAL`` was measured 80x slower, because its postorder is lost), so each
call factors afresh.
"""

from __future__ import annotations

import time
import warnings

import numpy as np
import scipy.sparse.linalg as spla

from ._base import LinearSolver, LinearSolveResult, relative_residual

__all__ = ["LinearSolverDirect"]


class LinearSolverDirect(LinearSolver):
    """Sparse LU (SuperLU, ``MMD_AT_PLUS_A``); exact up to round-off for any nonsingular ``A``.

    Parameters
    ----------
    permc_spec : str
        SuperLU column ordering (default ``"MMD_AT_PLUS_A"``).
    """

    name = "direct"

    def __init__(self, *, permc_spec: str = "MMD_AT_PLUS_A", **kw):
        super().__init__(**kw)
        self.permc_spec = permc_spec

    def _solve(self, A, b, x0):
        t0 = time.perf_counter()
        csc = A.tocsc()
        err = None
        lu = None
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("error", spla.MatrixRankWarning)
                lu = spla.splu(csc, permc_spec=self.permc_spec, diag_pivot_thresh=0.0,
                               options=dict(SymmetricMode=True))
            t1 = time.perf_counter()
            x = lu.solve(b)
            ok = bool(np.all(np.isfinite(x)))
        except (RuntimeError, spla.MatrixRankWarning) as e:  # exactly singular
            t1 = time.perf_counter()
            x, ok, err = np.full_like(b, np.nan), False, f"singular matrix ({e})"
        t2 = time.perf_counter()
        res = relative_residual(csc, x, b) if ok else float("inf")
        if ok and not res <= max(1e-8, self.rtol):
            ok, err = False, f"inaccurate factorisation (relative residual {res:.1e})"
        # ``lu.nnz`` is nnz(L) + nnz(U) without building L and U as sparse matrices (``lu.L``/``lu.U``
        # copy the factors: 3.8 ms of a 26 ms factorisation at n = 32)
        info = {"nnz_LU": int(lu.nnz)} if lu is not None else {}
        return LinearSolveResult(x, ok, 0, res, self.name, setup_s=t1 - t0, solve_s=t2 - t1,
                                 fallback=err, info=info)
