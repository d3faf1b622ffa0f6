"""Shared machinery of the iterative solvers: a PCG with breakdown detection, the
warm-start check and the fallback solver.

Symbols: ``A`` the system matrix (3F, 3F), ``b`` the right-hand side (3F,), ``M^-1``
the preconditioner, ``r = b - A x`` the residual, ``z = M^-1 r``, ``p`` the search
direction. All tolerances are on the relative residual ``|b - A x|_2 / |b|_2``.
"""

from __future__ import annotations

import time

import numpy as np

from ._base import LinearSolver, LinearSolveResult

__all__ = ["IterativeSolver", "KrylovInfo", "pcg"]


class KrylovInfo:
    """Outcome of a Krylov run: ``iterations``, ``residual`` (true relative residual) and
    ``breakdown`` (None, ``"non-positive curvature"``, ``"non-convergence"``, ``"nan"``,
    ``"indefinite preconditioner"``)."""

    __slots__ = ("iterations", "residual", "breakdown")

    def __init__(self, iterations: int, residual: float, breakdown: str | None):
        self.iterations = iterations
        self.residual = residual
        self.breakdown = breakdown


def pcg(matvec, b: np.ndarray, precond, x0: np.ndarray | None, *, rtol: float, atol: float,
        maxiter: int) -> tuple[np.ndarray, KrylovInfo]:
    """Preconditioned conjugate gradients that reports breakdown instead of hiding it.

    Parameters
    ----------
    matvec : callable
        ``x -> A x`` for a (3F,) vector.
    b : ndarray (3F,)
    precond : callable or None
        ``r -> M^-1 r`` (symmetric positive definite for CG theory to hold).
    x0 : ndarray (3F,) or None
        Initial guess (zero when None).
    rtol, atol : float
        Stop when ``|r| <= max(rtol |b|, atol)``.
    maxiter : int

    Returns
    -------
    x : ndarray (3F,)
        Last iterate (the best one is not tracked: on breakdown the caller falls back).
    info : KrylovInfo
        The residual is recomputed as ``|b - A x| / |b|`` at exit (the recursive one drifts).

    Notes
    -----
    Breakdown is detected as ``p^T A p <= 0`` (A not positive definite along ``p``),
    ``r^T M^-1 r <= 0`` (indefinite preconditioner), a non-finite value, or no
    convergence within ``maxiter``.
    """
    bnorm = float(np.linalg.norm(b))
    target = max(rtol * bnorm, atol)
    if bnorm == 0.0:
        return np.zeros_like(b), KrylovInfo(0, 0.0, None)
    if x0 is None:
        x = np.zeros_like(b)
        r = b.copy()
    else:
        x = np.array(x0, dtype=np.float64)
        r = b - matvec(x)
    rnorm = float(np.linalg.norm(r))
    breakdown = None
    it = 0
    if rnorm > target:
        z = precond(r) if precond is not None else r
        rz = float(r @ z)
        p = z.copy()
        while True:
            if not np.isfinite(rz):
                breakdown = "nan"
                break
            if rz <= 0.0:
                breakdown = "indefinite preconditioner"
                break
            if it >= maxiter:
                breakdown = "non-convergence"
                break
            Ap = matvec(p)
            pAp = float(p @ Ap)
            it += 1
            if not np.isfinite(pAp):
                breakdown = "nan"
                break
            if pAp <= 0.0:
                breakdown = "non-positive curvature"
                break
            alpha = rz / pAp
            x += alpha * p
            r -= alpha * Ap
            rnorm = float(np.linalg.norm(r))
            if rnorm <= target:
                # confirm with the true residual (the recursive one drifts on ill-conditioned A)
                r = b - matvec(x)
                rnorm = float(np.linalg.norm(r))
                if rnorm <= target:
                    break
            z = precond(r) if precond is not None else r
            rz_new = float(r @ z)
            beta = rz_new / rz
            rz = rz_new
            p *= beta
            p += z
    res = float(np.linalg.norm(b - matvec(x))) / bnorm
    if not np.isfinite(res):
        breakdown = "nan"
    elif breakdown is None and res * bnorm > target * (1 + 1e-8):
        breakdown = "non-convergence"
    return x, KrylovInfo(it, res, breakdown)


class IterativeSolver(LinearSolver):
    """Base of the Krylov solvers: warm start, default limits and the fallback policy.

    Parameters
    ----------
    rtol : float
        Relative residual target (default 1e-6).
    atol : float
        Absolute residual floor.
    maxiter : int or None
        Krylov iteration limit (default: solver-specific).
    fallback : LinearSolver, "direct", "none" or None
        Solver that answers when the Krylov method breaks down or misses its tolerance
        (default ``"direct"``: a :class:`~springsim.linsolve.LinearSolverDirect`). Its result
        is returned with ``method = "<name>-><fallback>"`` and the breakdown in ``fallback``.
        ``"none"``/None: the last iterate is returned with ``converged=False`` and the reason
        in ``failure``.
    warm_start : bool
        Use the caller's ``x0`` when its residual is smaller than ``|b|``.
    """

    def __init__(self, *, rtol: float = 1e-6, atol: float = 0.0, maxiter: int | None = None,
                 fallback: LinearSolver | str | None = "direct", warm_start: bool = True):
        super().__init__(rtol=rtol, atol=atol, maxiter=maxiter)
        if fallback == "direct":
            from .direct import LinearSolverDirect

            fallback = LinearSolverDirect()
        elif fallback == "none":
            fallback = None
        if fallback is not None and not isinstance(fallback, LinearSolver):
            raise ValueError(f"fallback must be a LinearSolver, 'direct' or 'none', got {fallback!r}")
        self.fallback = fallback
        self.warm_start = bool(warm_start)

    def _initial_guess(self, A, b, x0):
        """``x0`` if it is a better start than zero (``|b - A x0| < |b|``), else None."""
        if not self.warm_start or x0 is None or x0.shape != b.shape or not np.all(np.isfinite(x0)):
            return None
        r = b - A @ x0
        return x0 if np.linalg.norm(r) < np.linalg.norm(b) else None

    def _finish(self, A, b, x, info: KrylovInfo, setup_s: float, solve_s: float, details: dict) -> LinearSolveResult:
        """Result of a Krylov run, with the fallback applied on breakdown."""
        details = dict(details, breakdown=info.breakdown)
        if info.breakdown is None:
            return LinearSolveResult(x, True, info.iterations, info.residual, self.name, setup_s, solve_s,
                                     info=details)
        reason = f"{info.breakdown} after {info.iterations} iterations (relative residual {info.residual:.1e})"
        if self.fallback is None:
            return LinearSolveResult(x, False, info.iterations, info.residual, self.name, setup_s, solve_s,
                                     failure=reason, info=details)
        t0 = time.perf_counter()
        d = self.fallback._solve(A, b, None)  # A is already wrapped, and the thread policy applied, by solve()
        details.update(fallback_info=d.info, krylov_residual=info.residual)
        return LinearSolveResult(d.x, d.converged, info.iterations, d.residual, f"{self.name}->{d.method}",
                                 setup_s + d.setup_s, solve_s + (time.perf_counter() - t0) - d.setup_s,
                                 failure=d.failure, fallback=f"{self.name}: {reason}",
                                 backward_error=d.backward_error, info=details)

    def _limit(self, default: int) -> int:
        """The iteration limit: ``maxiter`` if given, else ``default``."""
        return int(self.maxiter) if self.maxiter is not None else int(default)
