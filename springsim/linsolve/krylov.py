"""``amg-gmres``: restarted GMRES preconditioned by smoothed-aggregation AMG.

For the ``exact`` Jacobian with damping, whose matrix is non-symmetric (the damping
force's position derivative) and may be indefinite (compressed springs), where CG
theory does not apply. The AMG hierarchy is built with pyamg's ``nonsymmetric``
setting on the same BSR 3x3 / rigid-body near-null space as ``amg-cg`` and reused the
same way. The Krylov method is scipy's GMRES; the true relative residual is checked
afterwards, and a miss (or NaN) falls back to the direct solver with a warning.
"""

from __future__ import annotations

import time

import numpy as np
import scipy.sparse.linalg as spla

from ._amg import AMGHierarchy
from ._krylov import IterativeSolver, KrylovInfo

__all__ = ["LinearSolverAMGGMRES", "gmres"]


def gmres(M, b, precond, x0, *, rtol: float, atol: float, maxiter: int, restart: int) -> tuple[np.ndarray, KrylovInfo]:
    """scipy GMRES(``restart``) with at most ``maxiter`` inner iterations, reporting breakdown.

    Returns the iterate and a :class:`~springsim.linsolve._krylov.KrylovInfo` whose
    residual is the true ``|b - M x| / |b|``.
    """
    n = b.size
    bnorm = float(np.linalg.norm(b))
    if bnorm == 0.0:
        return np.zeros_like(b), KrylovInfo(0, 0.0, None)
    count = [0]

    def callback(_):
        count[0] += 1

    P = spla.LinearOperator((n, n), matvec=precond, dtype=np.float64) if precond is not None else None
    cycles = max(1, -(-maxiter // restart))
    with np.errstate(all="ignore"):
        x, _ = spla.gmres(M, b, x0=x0, rtol=rtol, atol=atol, restart=restart, maxiter=cycles, M=P,
                          callback=callback, callback_type="pr_norm")
    res = float(np.linalg.norm(b - M @ x)) / bnorm
    if not np.isfinite(res):
        breakdown = "nan"
    elif res * bnorm > max(rtol * bnorm, atol) * (1 + 1e-8):
        breakdown = "non-convergence"
    else:
        breakdown = None
    return x, KrylovInfo(count[0], res, breakdown)


class LinearSolverAMGGMRES(IterativeSolver):
    """AMG-preconditioned restarted GMRES for non-symmetric systems.

    Parameters
    ----------
    restart : int
        GMRES restart length (default 30).
    rtol, atol, maxiter, fallback, warm_start
        See :class:`~springsim.linsolve._krylov.IterativeSolver` (``maxiter`` default 300
        inner iterations).
    near_nullspace, fmt, smoother, reuse, rebuild_factor, rebuild_slack, max_coarse, cooldown, max_cooldown,
    sa_options
        As for :class:`~springsim.linsolve.amg_cg.LinearSolverAMGCG`.
    """

    name = "amg-gmres"

    def __init__(self, *, restart: int = 30, near_nullspace: str = "rigid", fmt: str = "bsr",
                 smoother: str = "block_gauss_seidel", reuse: bool = True, rebuild_factor: float = 2.0,
                 rebuild_slack: int = 4, max_coarse: int = 50, cooldown: int = 4, max_cooldown: int = 64,
                 sa_options: dict | None = None, **kw):
        super().__init__(**kw)
        self.restart = int(restart)
        self.amg = AMGHierarchy(near_nullspace=near_nullspace, fmt=fmt, symmetry="nonsymmetric", smoother=smoother,
                                max_coarse=max_coarse, rebuild_factor=rebuild_factor, rebuild_slack=rebuild_slack,
                                reuse=reuse, cooldown=cooldown, max_cooldown=max_cooldown,
                                sa_options=sa_options)

    def _solve(self, A, b, x0):
        x0 = self._initial_guess(A, b, x0)
        M = A.bsr
        maxiter = self._limit(300)
        opts = dict(rtol=self.rtol, atol=self.atol, maxiter=maxiter, restart=self.restart)
        precond, setup_s, fresh = self.amg.preconditioner(A)
        t0 = time.perf_counter()
        x, info = gmres(M, b, precond, x0, **dict(opts, maxiter=self.amg.budget(maxiter, fresh)))
        rebuilt = False
        if not fresh and info.breakdown is not None:  # stale: too many iterations, or breakdown
            self.amg.invalidate(stale=True)
            precond = None  # drop the old hierarchy before the new one is built (peak memory)
            precond, s2, fresh = self.amg.preconditioner(A)
            setup_s += s2
            t0 += s2
            restart = x if (np.all(np.isfinite(x)) and info.residual < 1.0) else x0
            x, info2 = gmres(M, b, precond, restart, **opts)
            self.amg.record(info2.iterations, fresh, info2.breakdown is None)
            info2.iterations += info.iterations
            info, rebuilt = info2, True
        else:
            self.amg.record(info.iterations, fresh, info.breakdown is None)
        details = dict(self.amg.describe(), rebuilt=fresh, stale_rebuild=rebuilt, warm_start=x0 is not None)
        return self._finish(A, b, x, info, setup_s, time.perf_counter() - t0, details)
