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

from ._amg import AMGKrylovSolver
from ._krylov import IterativeSolver, pcg

__all__ = ["LinearSolverAMGCG"]


class LinearSolverAMGCG(AMGKrylovSolver, IterativeSolver):
    """AMG-preconditioned CG with hierarchy reuse and warm start.

    Parameters
    ----------
    rtol, atol, maxiter, fallback, warm_start
        See :class:`~springsim.linsolve._krylov.IterativeSolver` (``maxiter`` default 500).
    near_nullspace, fmt, smoother, reuse, rebuild_factor, rebuild_slack, max_coarse, cooldown, max_cooldown,
    sa_options
        See :class:`~springsim.linsolve._amg.AMGKrylovSolver`.
    """

    name = "amg-cg"
    needs_spd = True
    amg_symmetry = "hermitian"

    def _krylov(self, A, b, precond, x0, maxiter):
        return pcg(A.bsr.__matmul__, b, precond, x0, rtol=self.rtol, atol=self.atol, maxiter=maxiter)

    def _solve(self, A, b, x0):
        return self._amg_solve(A, b, self._initial_guess(A, b, x0), self._limit(500))
