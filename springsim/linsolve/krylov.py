"""Krylov methods that report breakdown instead of hiding it: CG and restarted GMRES.

A Krylov method is a parameter of :class:`~springsim.linsolve.iterative.LinearSolverIterative`,
like its preconditioner. Every method is called as::

    x, info = method(A, b, precond, x0, rtol=..., atol=..., maxiter=...)

with ``A`` anything supporting ``A @ x``, ``precond`` a callable ``r -> M^-1 r`` or None and
``x0`` an initial guess or None; it returns the last iterate and a :class:`KrylovInfo` whose
``residual`` is the *true* relative residual ``|b - A x| / |b|`` recomputed at exit. Adding a
method is one class here plus one line in :data:`KRYLOV_METHODS`.

Symbols: ``A`` the system matrix (3F, 3F), ``b`` the right-hand side, ``M^-1`` the
preconditioner, ``r = b - A x``, ``z = M^-1 r``, ``p`` the search direction.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

from typing import ClassVar

import numpy as np
import scipy.sparse.linalg as spla

__all__ = ["KrylovInfo", "KrylovMethod", "CG", "GMRES", "KRYLOV_METHODS", "pcg"]


class KrylovInfo:
    """Outcome of a Krylov run: ``iterations``, ``residual`` (true relative residual) and
    ``breakdown`` (None, ``"non-positive curvature"``, ``"non-convergence"``, ``"nan"``,
    ``"indefinite preconditioner"``, ``"singular diagonal"``).

    Parameters
    ----------
    iterations : int
        Iterations taken.
    residual : float
        True relative residual ``|b - A x| / |b|`` at exit.
    breakdown : str or None
        Why the method stopped early, None when it converged.
    """

    __slots__ = ("iterations", "residual", "breakdown")

    def __init__(self, iterations: int, residual: float, breakdown: str | None):
        self.iterations = iterations
        self.residual = residual
        self.breakdown = breakdown


def _judge(A, b: np.ndarray, x: np.ndarray, rtol: float, atol: float, iterations: int,
           breakdown: str | None) -> KrylovInfo:
    """The true residual at exit, and "non-convergence" when it misses the target."""
    bnorm = float(np.linalg.norm(b))
    res = float(np.linalg.norm(b - A @ x)) / bnorm
    if not np.isfinite(res):
        breakdown = "nan"
    elif breakdown is None and res * bnorm > max(rtol * bnorm, atol) * (1 + 1e-8):
        breakdown = "non-convergence"
    return KrylovInfo(iterations, res, breakdown)


def pcg(A, b: np.ndarray, precond, x0: np.ndarray | None, *, rtol: float, atol: float,
        maxiter: int) -> tuple[np.ndarray, KrylovInfo]:
    """Preconditioned conjugate gradients (Hestenes and Stiefel 1952) with breakdown detection.

    Stops when ``|r| <= max(rtol |b|, atol)`` (confirmed with the true residual, since the
    recursive one drifts on ill-conditioned ``A``). Breakdown is ``p^T A p <= 0`` (``A`` not
    positive definite along ``p``), ``r^T M^-1 r <= 0`` (an indefinite preconditioner), a
    non-finite value, or no convergence within ``maxiter``. Returns the last iterate (on
    breakdown the caller falls back).

    Parameters
    ----------
    A : scipy.sparse matrix or LinearOperator, shape (n, n)
        Symmetric positive definite matrix (``A @ x``).
    b : ndarray, shape (n,)
        Right-hand side.
    precond : callable
        ``r -> M^-1 r``, symmetric positive definite.
    x0 : ndarray, shape (n,) or None
        Initial guess; None: zero.
    rtol, atol : float
        Relative and absolute residual tolerances.
    maxiter : int
        Iteration limit.

    Returns
    -------
    x : ndarray, shape (n,)
        Last iterate.
    info : KrylovInfo
    """
    bnorm = float(np.linalg.norm(b))
    if bnorm == 0.0:
        return np.zeros_like(b), KrylovInfo(0, 0.0, None)
    target = max(rtol * bnorm, atol)
    if x0 is None:
        x = np.zeros_like(b)
        r = b.copy()
    else:
        x = np.array(x0, dtype=np.float64)
        r = b - A @ x
    breakdown = None
    it = 0
    if float(np.linalg.norm(r)) > target:
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
            Ap = A @ p
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
            if float(np.linalg.norm(r)) <= target:
                r = b - A @ x  # confirm with the true residual
                if float(np.linalg.norm(r)) <= target:
                    break
            z = precond(r) if precond is not None else r
            rz_new = float(r @ z)
            p *= rz_new / rz
            p += z
            rz = rz_new
    return x, _judge(A, b, x, rtol, atol, it, breakdown)


class KrylovMethod(ABC):
    """Base of the Krylov methods: ``__call__(A, b, precond, x0, *, rtol, atol, maxiter) -> (x, KrylovInfo)``."""

    #: Registry name.
    name: ClassVar[str]
    #: Whether the method needs a symmetric positive definite matrix and preconditioner.
    needs_spd: ClassVar[bool] = False

    @abstractmethod
    def __call__(self, A, b, precond, x0, *, rtol: float, atol: float, maxiter: int):
        """Solve ``A x = b`` from ``x0``; ``(x, KrylovInfo)``."""

    def __repr__(self) -> str:
        return f"{type(self).__name__}()"


class CG(KrylovMethod):
    """Preconditioned conjugate gradients (:func:`pcg`): symmetric positive definite systems."""

    name = "cg"
    needs_spd = True

    def __call__(self, A, b, precond, x0, *, rtol, atol, maxiter):
        return pcg(A, b, precond, x0, rtol=rtol, atol=atol, maxiter=maxiter)


class GMRES(KrylovMethod):
    """Restarted GMRES (Saad and Schultz 1986; scipy's) for non-symmetric or indefinite systems.

    Parameters
    ----------
    restart : int
        Krylov subspace size between restarts (default 30); ``maxiter`` counts inner iterations.
    """

    name = "gmres"

    def __init__(self, restart: int = 30):
        if int(restart) != restart or restart < 1:
            raise ValueError(f"restart must be an integer >= 1, got {restart!r}")
        self.restart = int(restart)

    def __call__(self, A, b, precond, x0, *, rtol, atol, maxiter):
        n = b.size
        if float(np.linalg.norm(b)) == 0.0:
            return np.zeros_like(b), KrylovInfo(0, 0.0, None)
        count = [0]

        def callback(_):
            count[0] += 1

        P = spla.LinearOperator((n, n), matvec=precond, dtype=np.float64) if precond is not None else None
        cycles = max(1, -(-maxiter // self.restart))
        with np.errstate(all="ignore"):
            x, _ = spla.gmres(A, b, x0=x0, rtol=rtol, atol=atol, restart=self.restart, maxiter=cycles, M=P,
                              callback=callback, callback_type="pr_norm")
        return x, _judge(A, b, x, rtol, atol, count[0], None)

    def __repr__(self) -> str:
        return f"GMRES(restart={self.restart})"


#: Registry: name -> Krylov method class.
KRYLOV_METHODS: dict[str, type[KrylovMethod]] = {"cg": CG, "gmres": GMRES}
