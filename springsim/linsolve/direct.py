"""``direct``: scipy's SuperLU with a symmetric fill-reducing ordering, checked by its backward error.

The implicit system's pattern is structurally symmetric, so SuperLU orders it by
minimum degree on ``A^T + A`` (``MMD_AT_PLUS_A``) in symmetric mode, taking diagonal
pivots (``diag_pivot_thresh = 0``): far less fill than the default COLAMD ordering with
partial pivoting on these matrices (SuperLU Users' Guide, Demmel, Gilbert and Li 1999; the factor times:
BENCHMARKS.md#sparse-vs-dense). Diagonal pivoting is not
backward stable for every matrix (an indefinite ``exact``-mode Jacobian can have tiny
pivots), so every solution is checked:

1. solve with the factors and compute the normwise backward error ``eta``
   (:func:`~springsim.linsolve._base.backward_error`);
2. while ``eta > backward_tol``: iterative refinement with the same factors,
   ``x <- x + (LU)^-1 (b - A x)``, at most ``refine`` steps (one step in working
   precision makes Gaussian elimination backward stable in practice; Skeel 1980,
   Higham 2002, sec. 12.2);
3. if that does not reach ``backward_tol``: factor again with threshold partial pivoting
   (``diag_pivot_thresh = 1``, COLAMD ordering) and refine again;
4. if that fails too (the matrix is singular to working precision): ``converged=False``
   with the reason in ``failure``.

What is reused across steps is the conversion: the assembler's BSR data reaches
CSC through one precomputed gather (:meth:`SystemMatrix.tocsc`). SuperLU exposes
no reusable symbolic factorisation, so each call factors afresh, unless
``reuse_factors`` is set: then a new matrix of the same shape is first solved with the
previous call's factors as an approximate inverse, by at most ``reuse_factors`` steps of
the same iterative refinement (step 2; it converges when ``|I - (LU)^-1 A| < 1``, i.e.
when the matrix changed little, as between the Newton iterations and the two stages of
one TR-BDF2 step), and the result is kept only when it reaches ``backward_tol``: the
guarantee is the same, only the cost differs (``info["reused_factors"]``). Otherwise the
matrix is factored as above and its factors are kept for the next call.
"""

from __future__ import annotations

import time

import numpy as np
import scipy.sparse.linalg as spla

from ._base import BACKWARD_TOL, LinearSolver, LinearSolveResult, backward_error, inf_norm, relative_residual

__all__ = ["LinearSolverDirect", "refine"]


def refine(A, solve, b: np.ndarray, x: np.ndarray, *, A_norm: float, tol: float, steps: int):
    """Fixed-precision iterative refinement of ``x`` for ``A x = b`` with an approximate inverse ``solve``.

    Stops when the normwise backward error is ``<= tol``, after ``steps`` corrections, or
    when a correction does not reduce it. Returns ``(x, eta, corrections)``.

    Parameters
    ----------
    A : SystemMatrix, scipy.sparse matrix or ndarray, shape (n, n)
        The matrix.
    b : ndarray, shape (n,)
        Right-hand side.
    solve : callable
        Approximate inverse ``r -> (LU)^-1 r``.
    x : ndarray, shape (n,)
        Starting solution.
    A_norm : float
        ``|A|_inf``.
    tol : float
        Target normwise backward error.
    steps : int
        Largest number of corrections.

    Returns
    -------
    x : ndarray, shape (n,)
        The refined solution.
    eta : float
        Its backward error.
    corrections : int
        Corrections applied.
    """
    eta = backward_error(A, x, b, A_norm)
    done = 0
    while eta > tol and done < steps and np.isfinite(eta):
        x_new = x + solve(b - A @ x)
        eta_new = backward_error(A, x_new, b, A_norm)
        if not eta_new < eta:
            break
        x, eta = x_new, eta_new
        done += 1
    return x, eta, done


class LinearSolverDirect(LinearSolver):
    """Sparse LU (SuperLU) whose solutions are checked and refined to a small backward error.

    Parameters
    ----------
    permc_spec : str
        SuperLU column ordering of the first (diagonal-pivot) factorisation (default
        ``"MMD_AT_PLUS_A"``).
    backward_tol : float
        Normwise backward error a solution must reach (default
        :data:`~springsim.linsolve._base.BACKWARD_TOL`).
    refine : int
        Refinement steps allowed per factorisation (default 3).
    reuse_factors : int
        Refinement steps allowed with the previous call's factors before factoring afresh (module
        docstring); 0 (default) factors every matrix.
    **kw
        ``rtol``, ``atol``, ``maxiter`` of :class:`~springsim.linsolve.LinearSolver`: accepted for a uniform
        interface; unused (a direct solve is judged by its backward error, see :mod:`springsim.linsolve._base`).

    Raises
    ------
    ValueError
        ``backward_tol`` not > 0, or ``refine`` or ``reuse_factors`` not an integer >= 0.
    """

    name = "direct"

    def __init__(self, *, permc_spec: str = "MMD_AT_PLUS_A", backward_tol: float = BACKWARD_TOL, refine: int = 3,
                 reuse_factors: int = 0, **kw):
        super().__init__(**kw)
        if not backward_tol > 0:
            raise ValueError(f"backward_tol must be > 0, got {backward_tol}")
        for name, value in (("refine", refine), ("reuse_factors", reuse_factors)):
            if int(value) != value or value < 0:
                raise ValueError(f"{name} must be an integer >= 0, got {value}")
        self.permc_spec = permc_spec
        self.backward_tol = float(backward_tol)
        self.refine = int(refine)
        self.reuse_factors = int(reuse_factors)
        self._kept = None  # (shape, factors) of the last factorisation, for reuse_factors

    def _factor(self, csc, pivoting: bool):
        """SuperLU factors, or the error message when SuperLU finds the matrix exactly singular."""
        try:
            if pivoting:
                return spla.splu(csc, permc_spec="COLAMD", diag_pivot_thresh=1.0), None
            return spla.splu(csc, permc_spec=self.permc_spec, diag_pivot_thresh=0.0,
                             options=dict(SymmetricMode=True)), None
        except RuntimeError as e:  # "Factor is exactly singular"
            return None, f"singular matrix ({e})"

    def _refined(self, csc, lu, b, A_norm, steps):
        """The solution with the factors ``lu`` refined (:func:`refine`) by at most ``steps`` steps."""
        return refine(csc, lu.solve, b, lu.solve(b), A_norm=A_norm, tol=self.backward_tol, steps=steps)

    def _solve(self, A, b, x0, rtol):
        t0 = time.perf_counter()
        csc = A.tocsc()
        A_norm = inf_norm(csc)
        setup_s = solve_s = 0.0
        x, eta, failure = np.full_like(b, np.nan), float("inf"), None
        info: dict = {"refinements": 0, "pivoting": False, "reused_factors": False}
        if self.reuse_factors and self._kept is not None and self._kept[0] == csc.shape:
            t1 = time.perf_counter()
            x_try, eta_try, done = self._refined(csc, self._kept[1], b, A_norm, self.reuse_factors)
            solve_s += time.perf_counter() - t1
            if eta_try <= self.backward_tol:
                x, eta = x_try, eta_try
                info.update(refinements=done, reused_factors=True)
        if not info["reused_factors"]:
            self._kept = None  # the old factors go before the new ones are made: one set alive at the peak
        for pivoting in (() if info["reused_factors"] else (False, True)):
            t1 = time.perf_counter()
            lu, err = self._factor(csc, pivoting)
            t2 = time.perf_counter()
            setup_s += t2 - t1
            if lu is None:
                failure = err
            else:
                # ``lu.nnz`` is nnz(L) + nnz(U) without building L and U as sparse matrices
                info["nnz_LU"] = int(lu.nnz)
                if self.reuse_factors:
                    self._kept = (csc.shape, lu)
                info["pivoting"] = pivoting
                x_try, eta_try, done = self._refined(csc, lu, b, A_norm, self.refine)
                info["refinements"] += done
                if eta_try < eta:
                    x, eta = x_try, eta_try
                failure = None if eta <= self.backward_tol else (
                    f"backward error {eta:.1e} > {self.backward_tol:.0e} after {info['refinements']} refinement "
                    f"step(s){' and partial pivoting' if pivoting else ''}")
            solve_s += time.perf_counter() - t2
            if failure is None:
                break
        converged = failure is None
        res = relative_residual(csc, x, b) if np.all(np.isfinite(x)) else float("inf")
        setup_s += (time.perf_counter() - t0) - setup_s - solve_s  # the conversion counts as setup
        return LinearSolveResult(x, converged, 0, res, self.name, setup_s=setup_s, solve_s=solve_s,
                                 failure=failure, backward_error=eta, info=info)
