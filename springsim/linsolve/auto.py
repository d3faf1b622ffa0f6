"""``auto``: picks a solver by system size and symmetry.

* ``3F <= direct_max_dofs`` (default :data:`DIRECT_MAX_DOFS`, 4,000): ``direct`` (SuperLU). Below
  this size a factorisation beats an AMG setup plus its iterations, and it is exact for indefinite
  and non-symmetric matrices alike; above it SuperLU's fill grows faster than AMG's linear cost
  (the crossover, 3,000 to 5,000 DOFs on the benchmark cloth, is measured in "`auto` crossover" of
  the linear-solver notes of BENCHMARKS.md#cloth-grid; BENCHMARKS.md#scaling has the current step times on both sides).
* larger and symmetric (``symmetric``/``spd`` modes, or undamped ``exact``): ``amg-cg``; if the
  matrix is indefinite, CG detects it and hands over to ``direct``.
* larger and non-symmetric (``exact`` with damping): ``amg-gmres``.

:meth:`LinearSolverAuto.needs_spd_for` asks integrators for the ``spd`` mode only above
``direct_max_dofs``: below it they keep the ``exact`` Jacobian (quadratic Newton convergence, and
the true gravitational Jacobian, with which implicit Euler stays stable on close passes).
:attr:`LinearSolverAuto.last_choice` names the solver used for the last system.
"""

from __future__ import annotations

from ._base import DEFAULT_RTOL, LinearSolver
from .direct import LinearSolverDirect
from .iterative import LinearSolverAMGCG, LinearSolverAMGGMRES

__all__ = ["LinearSolverAuto", "DIRECT_MAX_DOFS"]

#: Largest system [DOFs] ``auto`` gives to ``direct`` (the measured crossover,
#: the linear-solver notes of BENCHMARKS.md#cloth-grid).
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

    def __init__(self, *, rtol: float = DEFAULT_RTOL, atol: float = 0.0, maxiter: int | None = None,
                 direct_max_dofs: int = DIRECT_MAX_DOFS, fallback: str = "direct"):
        super().__init__(rtol=rtol, atol=atol, maxiter=maxiter)
        self.direct_max_dofs = int(direct_max_dofs)
        #: Name of the solver used for the last system, and why (None before the first solve).
        self.last_choice: str | None = None
        self.last_reason: str | None = None
        self._solvers = {
            "direct": LinearSolverDirect(),
            "amg-cg": LinearSolverAMGCG(rtol=self.rtol, atol=self.atol, maxiter=maxiter, fallback=fallback),
            "amg-gmres": LinearSolverAMGGMRES(rtol=self.rtol, atol=self.atol, maxiter=maxiter, fallback=fallback),
        }

    @property
    def rtol(self) -> float:
        """Relative residual tolerance; setting it sets it on the iterative sub-solvers too."""
        return self._rtol

    @rtol.setter
    def rtol(self, value: float) -> None:  # the sub-solvers follow (a per-solve rtol is passed to them instead)
        self._rtol = value
        for solver in getattr(self, "_solvers", {}).values():
            solver.rtol = value

    def needs_spd_for(self, dofs: int) -> bool:
        """Whether ``auto`` asks for the ``spd`` Jacobian: only above ``direct_max_dofs``, where it uses AMG-CG.

        Parameters
        ----------
        dofs : int
            Number of unknowns.

        Returns
        -------
        bool
        """
        return dofs > self.direct_max_dofs

    def choose(self, A) -> str:
        """Name of the solver used for ``A``.

        Parameters
        ----------
        A : SystemMatrix
            The matrix.

        Returns
        -------
        str
            ``"direct"``, ``"amg-cg"`` or ``"amg-gmres"``.
        """
        return self._choose(A)[0]

    def _choose(self, A) -> tuple[str, str]:
        n = A.shape[0]
        if n <= self.direct_max_dofs:
            return "direct", f"{n} DOFs <= {self.direct_max_dofs}"
        if A.symmetric:
            return "amg-cg", f"{n} DOFs > {self.direct_max_dofs}, symmetric matrix"
        return "amg-gmres", f"{n} DOFs > {self.direct_max_dofs}, non-symmetric matrix"

    def _solve(self, A, b, x0, rtol):
        choice, self.last_reason = self._choose(A)
        self.last_choice = choice
        res = self._solvers[choice]._solve(A, b, x0, rtol)  # A is already wrapped by solve()
        res.method = f"auto:{res.method}"
        res.info = dict(res.info, auto_choice=choice)
        return res
