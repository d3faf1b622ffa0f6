"""``auto``: picks a solver by system size and symmetry, and on stiff systems by AMG-CG's iteration counts.

* ``3F <= direct_max_dofs`` (default :data:`DIRECT_MAX_DOFS`, 4,000): ``direct`` (SuperLU). Below
  this size a factorisation beats an AMG setup plus its iterations, and it is exact for indefinite
  and non-symmetric matrices alike; above it SuperLU's fill grows faster than AMG's linear cost
  (the crossover, 3,000 to 5,000 DOFs on the benchmark cloth, is measured in "`auto` crossover" of
  the linear-solver notes of BENCHMARKS.md#cloth-grid; BENCHMARKS.md#scaling has the current step times on both sides).
* larger and symmetric (``symmetric``/``spd`` modes, or undamped ``exact``): ``amg-cg``; if the
  matrix is indefinite, CG detects it and hands over to ``direct``.
* larger and non-symmetric (``exact`` with damping): ``amg-gmres``.
* **stiff systems of moderate size**: when an ``amg-cg`` solve of a system of at most
  ``stiff_direct_max_dofs`` unknowns (default :data:`STIFF_DIRECT_MAX_DOFS`, 25,000: a 90 x 90 cloth) needs
  more than ``switch_iterations`` CG iterations (default 100), the next ``cooldown`` solves go to ``direct``;
  then AMG-CG is tried again, and if it is still that slow the cooldown doubles (at most
  ``max_cooldown``; it returns to ``cooldown`` when a try stays within the limit). Sheets whose in-plane
  springs are 1e7-1e8 times stiffer than their inertia (``h^2 k / m``) leave AMG's smoothers the bending
  modes to resolve by CG (100-150 iterations a solve on the 64 x 64 cloth at ke = 1e8), where a
  factorisation costs about 100 of them and solves the system exactly, which also takes the Newton
  iteration of a stage fewer iterations than loose CG solves (measured in the notes on factoring stiff stages of
  BENCHMARKS.md#stiff-convergence). The choice depends on iteration counts only, not on timings, so a run
  is reproducible.

:meth:`LinearSolverAuto.needs_spd_for` asks integrators for the ``spd`` mode only above
``direct_max_dofs``: below it they keep the ``exact`` Jacobian (quadratic Newton convergence, and
the true gravitational Jacobian, with which implicit Euler stays stable on close passes).
:attr:`LinearSolverAuto.last_choice` names the solver used for the last system.
"""

from __future__ import annotations

from ._base import DEFAULT_RTOL, LinearSolver
from .direct import LinearSolverDirect
from .iterative import LinearSolverAMGCG, LinearSolverAMGGMRES

__all__ = ["LinearSolverAuto", "DIRECT_MAX_DOFS", "STIFF_DIRECT_MAX_DOFS"]

#: Largest system [DOFs] ``auto`` gives to ``direct`` (the measured crossover,
#: the linear-solver notes of BENCHMARKS.md#cloth-grid).
DIRECT_MAX_DOFS = 4000
#: Largest system [DOFs] ``auto`` factors after a slow AMG-CG solve (module docstring). The 64 x 64 cloth (12,096
#: DOFs) factors in about 100 AMG-CG iterations' time (0.19 s), the 128 x 128 one (48,768) in about 160 (1.2 s, 21
#: million entries in the factors): there the switch at 100 iterations measured no gain (the notes on factoring
#: stiff stages of BENCHMARKS.md#stiff-convergence).
STIFF_DIRECT_MAX_DOFS = 25_000


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
    stiff_direct_max_dofs : int
        Size up to which slow AMG-CG solves hand the following ones to ``direct`` (default
        :data:`STIFF_DIRECT_MAX_DOFS`; 0 turns the switch off).
    switch_iterations : int
        CG iterations above which an AMG-CG solve counts as slow (default 100).
    cooldown, max_cooldown : int
        Solves given to ``direct`` after a slow one, and the largest doubled count (defaults 8 and 128).

    Raises
    ------
    ValueError
        A negative size, or ``switch_iterations`` or ``cooldown`` not >= 1.
    """

    name = "auto"
    needs_spd = True

    def __init__(self, *, rtol: float = DEFAULT_RTOL, atol: float = 0.0, maxiter: int | None = None,
                 direct_max_dofs: int = DIRECT_MAX_DOFS, fallback: str = "direct",
                 stiff_direct_max_dofs: int = STIFF_DIRECT_MAX_DOFS, switch_iterations: int = 100, cooldown: int = 8,
                 max_cooldown: int = 128):
        super().__init__(rtol=rtol, atol=atol, maxiter=maxiter)
        if min(direct_max_dofs, stiff_direct_max_dofs) < 0:
            raise ValueError(f"direct_max_dofs and stiff_direct_max_dofs must be >= 0, got {direct_max_dofs}, "
                             f"{stiff_direct_max_dofs}")
        if min(switch_iterations, cooldown) < 1:
            raise ValueError(f"switch_iterations and cooldown must be >= 1, got {switch_iterations}, {cooldown}")
        self.direct_max_dofs = int(direct_max_dofs)
        self.stiff_direct_max_dofs = int(stiff_direct_max_dofs)
        self.switch_iterations = int(switch_iterations)
        self.cooldown = int(cooldown)
        self.max_cooldown = max(int(max_cooldown), self.cooldown)
        self._next_cooldown = self.cooldown
        #: Solves left to ``direct`` after a slow AMG-CG solve, and how many times AMG-CG was found slow.
        self.direct_left = 0
        self.switches = 0
        self._slow_its = 0
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
        if A.symmetric and self.direct_left > 0 and n <= self.stiff_direct_max_dofs:
            return "direct", (f"{n} DOFs <= {self.stiff_direct_max_dofs} and amg-cg needed {self._slow_its} > "
                              f"{self.switch_iterations} iterations")
        if A.symmetric:
            return "amg-cg", f"{n} DOFs > {self.direct_max_dofs}, symmetric matrix"
        return "amg-gmres", f"{n} DOFs > {self.direct_max_dofs}, non-symmetric matrix"

    def _solve(self, A, b, x0, rtol):
        choice, self.last_reason = self._choose(A)
        self.last_choice = choice
        res = self._solvers[choice]._solve(A, b, x0, rtol)  # A is already wrapped by solve()
        if choice == "direct" and self.direct_left > 0:
            self.direct_left -= 1
        elif choice == "amg-cg" and A.shape[0] <= self.stiff_direct_max_dofs:
            self._judge_amg(res.iterations)
        res.method = f"auto:{res.method}"
        res.info = dict(res.info, auto_choice=choice)
        return res

    def _judge_amg(self, iterations: int) -> None:
        """After an AMG-CG solve: hand the next ``cooldown`` solves to ``direct`` when it was slow (doubling the
        cooldown while AMG-CG stays slow; the AMG hierarchy is dropped), or return the cooldown to its start when it
        was not."""
        if iterations > self.switch_iterations:
            self.switches += 1
            self._slow_its = int(iterations)
            self.direct_left = self._next_cooldown
            self._next_cooldown = min(2 * self._next_cooldown, self.max_cooldown)
            # the hierarchy would be many matrices old at the next try: free it now (the factors need the memory),
            # so that the try builds one for its own matrix and is judged on it
            self._solvers["amg-cg"].preconditioner.invalidate()
        else:
            self._next_cooldown = self.cooldown
