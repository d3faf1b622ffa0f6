"""``auto``: picks a solver by system size, symmetry and definiteness.

Rule (crossover measured with ``benchmarks/cloth_grid.py``, linearized implicit Euler
on the benchmark cloth, steps 10-30, rtol 1e-6; see docs/solvers.md):

* ``3F <= DIRECT_MAX_DOFS``: ``direct`` (SuperLU). Below the crossover factorisation
  beats an AMG setup plus iterations, and it is exact for indefinite and
  non-symmetric matrices alike. Measured median solve time per step (s), ``spd`` mode:

  =====  ======  ======  =======
  n      DOFs    direct  amg-cg
  =====  ======  ======  =======
  16        720  0.0027  0.0140
  24      1,656  0.018   0.033
  32      2,976  0.019   0.019
  48      6,768  0.070   0.045
  64     12,096  0.23    0.11
  96     27,360  0.59    0.36
  128    48,768  1.73    0.84
  =====  ======  ======  =======

  (2 cores shared with other jobs; the crossover lies near 3,000-5,000 DOFs, and
  SuperLU's fill grows faster than AMG's linear cost beyond it.)
* larger and symmetric (``symmetric``/``spd`` modes, or undamped ``exact``):
  ``amg-cg``. If the matrix is indefinite CG detects it and falls back to ``direct``.
* larger and non-symmetric (``exact`` with damping): ``amg-gmres``.

``needs_spd`` is True, but :meth:`LinearSolverAuto.needs_spd_for` says so only above
``direct_max_dofs``: implicit integrators give ``auto`` the ``exact`` mode on systems the
direct solver takes (Newton's quadratic convergence, and the true gravitational Jacobian:
with ``spd`` implicit Euler at h = 1/60 s is unstable on ``scenes/three_body.yaml``), and
the ``spd`` mode on larger ones, where CG needs it.
"""

from __future__ import annotations

from ._base import LinearSolver
from .direct import LinearSolverDirect
from .iterative import LinearSolverAMGCG, LinearSolverAMGGMRES

__all__ = ["LinearSolverAuto", "DIRECT_MAX_DOFS"]

#: Measured crossover [DOFs]: below it ``direct`` is faster per step than ``amg-cg``.
DIRECT_MAX_DOFS = 4000


class LinearSolverAuto(LinearSolver):
    """Chooses ``direct``, ``amg-cg`` or ``amg-gmres`` per solve (sub-solvers are kept, so
    AMG hierarchies are reused).

    Parameters
    ----------
    rtol, atol, maxiter
        Passed to the chosen solver.
    direct_max_dofs : int
        Size up to which ``direct`` is used (default :data:`DIRECT_MAX_DOFS`).
    fallback : {"direct", "none"}
        Passed to the iterative solvers.
    """

    name = "auto"
    needs_spd = True

    def __init__(self, *, rtol: float = 1e-6, atol: float = 0.0, maxiter: int | None = None,
                 direct_max_dofs: int = DIRECT_MAX_DOFS, fallback: str = "direct"):
        super().__init__(rtol=rtol, atol=atol, maxiter=maxiter)
        self.direct_max_dofs = int(direct_max_dofs)
        #: Name of the solver used for the last system (None before the first solve).
        self.last_choice: str | None = None
        self._solvers = {
            "direct": LinearSolverDirect(),
            "amg-cg": LinearSolverAMGCG(rtol=self.rtol, atol=self.atol, maxiter=maxiter, fallback=fallback),
            "amg-gmres": LinearSolverAMGGMRES(rtol=self.rtol, atol=self.atol, maxiter=maxiter, fallback=fallback),
        }

    def needs_spd_for(self, dofs: int) -> bool:
        return dofs > self.direct_max_dofs

    def choose(self, A) -> str:
        """Name of the solver used for ``A``."""
        if A.shape[0] <= self.direct_max_dofs:
            return "direct"
        return "amg-cg" if A.symmetric else "amg-gmres"

    def _solve(self, A, b, x0):
        choice = self.last_choice = self.choose(A)
        res = self._solvers[choice]._solve(A, b, x0)  # A is already wrapped by solve()
        res.method = f"auto:{res.method}"
        res.info = dict(res.info, auto_choice=choice)
        return res
