"""``amg-cg``: conjugate gradients preconditioned by smoothed-aggregation AMG (pyamg).

For the ``spd`` Jacobian mode (the default for this solver), where CG is guaranteed
to work. The hierarchy (BSR 3x3, rigid-body near-null space, symmetric block
Gauss-Seidel; choices measured in :mod:`springsim.linsolve._amg`) is built on the
first solve and reused across Newton iterations and time steps while the matrix
pattern is unchanged, until a solve needs ``rebuild_factor`` times the iterations it
needed right after the build (plus ``rebuild_slack``) or breaks down; then it is
rebuilt and the solve repeated from the best iterate. Breakdown that survives a
fresh hierarchy (e.g. an indefinite matrix from the ``exact`` mode) is answered by the
direct solver with a warning (``fallback="direct"``), reported as ``"amg-cg->direct"``.
"""

from __future__ import annotations

import time

import numpy as np

from ._amg import AMGHierarchy
from ._krylov import IterativeSolver, pcg

__all__ = ["LinearSolverAMGCG"]


class LinearSolverAMGCG(IterativeSolver):
    """AMG-preconditioned CG with hierarchy reuse and warm start.

    Parameters
    ----------
    rtol, atol, maxiter, fallback, warm_start
        See :class:`~springsim.linsolve._krylov.IterativeSolver` (``maxiter`` default 500).
    near_nullspace : {"rigid", "translations"}
        AMG candidate vectors: six rigid-body modes at the current positions, or the
        three translations.
    fmt : {"bsr", "csr"}
        Matrix format given to pyamg.
    smoother : str
        pyamg smoother (default symmetric ``"block_gauss_seidel"``).
    reuse : bool
        Reuse the hierarchy across solves (False: rebuild on every solve).
    rebuild_factor, rebuild_slack, cooldown, max_cooldown
        Stale-hierarchy signal and policy, see :class:`~springsim.linsolve._amg.AMGHierarchy`.
    max_coarse : int
        Coarsest AMG level size in block rows (pyamg's convention).
    sa_options : dict, optional
        Extra keywords for :func:`pyamg.smoothed_aggregation_solver`.
    """

    name = "amg-cg"
    needs_spd = True

    def __init__(self, *, near_nullspace: str = "rigid", fmt: str = "bsr", smoother: str = "block_gauss_seidel",
                 reuse: bool = True, rebuild_factor: float = 2.0, rebuild_slack: int = 4, max_coarse: int = 50,
                 cooldown: int = 4, max_cooldown: int = 64, sa_options: dict | None = None, **kw):
        super().__init__(**kw)
        self.amg = AMGHierarchy(near_nullspace=near_nullspace, fmt=fmt, symmetry="hermitian", smoother=smoother,
                                max_coarse=max_coarse, rebuild_factor=rebuild_factor, rebuild_slack=rebuild_slack,
                                reuse=reuse, cooldown=cooldown, max_cooldown=max_cooldown,
                                sa_options=sa_options)

    def _solve(self, A, b, x0):
        x0 = self._initial_guess(A, b, x0)
        M = A.bsr
        matvec = M.__matmul__
        maxiter = self._limit(500)
        precond, setup_s, fresh = self.amg.preconditioner(A)
        t0 = time.perf_counter()
        x, info = pcg(matvec, b, precond, x0, rtol=self.rtol, atol=self.atol, maxiter=self.amg.budget(maxiter, fresh))
        rebuilt = False
        if not fresh and info.breakdown is not None:  # stale: too many iterations, or breakdown
            self.amg.invalidate(stale=True)
            precond = None  # drop the old hierarchy before the new one is built (peak memory)
            precond, s2, fresh = self.amg.preconditioner(A)
            setup_s += s2
            t0 += s2
            restart = x if (np.all(np.isfinite(x)) and info.residual < 1.0) else x0
            x, info2 = pcg(matvec, b, precond, restart, rtol=self.rtol, atol=self.atol, maxiter=maxiter)
            self.amg.record(info2.iterations, fresh, info2.breakdown is None)
            info2.iterations += info.iterations
            info, rebuilt = info2, True
        else:
            self.amg.record(info.iterations, fresh, info.breakdown is None)
        solve_s = time.perf_counter() - t0
        details = dict(self.amg.describe(), rebuilt=fresh, stale_rebuild=rebuilt, warm_start=x0 is not None)
        return self._finish(A, b, x, info, setup_s, solve_s, details)
