"""``amg-gmres``: restarted GMRES preconditioned by smoothed-aggregation AMG.

For the ``exact`` Jacobian with damping, whose matrix is non-symmetric (the damping
force's position derivative) and may be indefinite (compressed springs), where CG
theory does not apply. The AMG hierarchy is built with pyamg's ``nonsymmetric``
setting on the same BSR 3x3 / rigid-body near-null space as ``amg-cg`` and reused the
same way. The Krylov method is scipy's GMRES; the true relative residual is checked
afterwards, and a miss (or NaN) falls back to the direct solver with a warning.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse.linalg as spla

from ._amg import AMGKrylovSolver
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


class LinearSolverAMGGMRES(AMGKrylovSolver, IterativeSolver):
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
        See :class:`~springsim.linsolve._amg.AMGKrylovSolver`.
    """

    name = "amg-gmres"
    amg_symmetry = "nonsymmetric"

    def __init__(self, *, restart: int = 30, **kw):
        super().__init__(**kw)
        self.restart = int(restart)

    def _krylov(self, A, b, precond, x0, maxiter):
        return gmres(A.bsr, b, precond, x0, rtol=self.rtol, atol=self.atol, maxiter=maxiter, restart=self.restart)

    def _solve(self, A, b, x0):
        return self._amg_solve(A, b, self._initial_guess(A, b, x0), self._limit(300))
