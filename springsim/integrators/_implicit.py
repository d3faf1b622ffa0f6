"""The base of the implicit integrators: options, the stage solver, substep retakes and error filtering.

Each implicit method reduces a step to one or more stages ``c F(q_hat + c v, v) = M (v - v_hat)``, solved by
one :class:`~springsim.integrators._stage.StageSolver` on the integrator's
:class:`~springsim.system.System` (its module docstring gives the equations, the three stopping rules and the
line searches). Subclasses implement :meth:`ImplicitIntegrator.advance`; :meth:`ImplicitIntegrator.step`
adds what every method shares:

* **Substep retake.** A step that is not ``ok`` (a stage did not converge, a linear solve failed, the matrix
  lost the masses, a linear solve gave no finite solution) is retaken from the same state in 2, 4, ...
  ``2**retake_halvings`` equal substeps (each halving makes ``c^2 K`` four times smaller), the first attempt
  that succeeds in every substep is kept, and the abandoned ones are listed in ``StepStats.extra["retaken"]``
  and the count in ``["substeps"]``. Only if the finest attempt fails too is the step reported (and then the
  run's exit status says so). The ladder is five halvings deep (32 substeps) by default: with three, TR-BDF2 on
  the benchmark cloth at n = 64, ke = 1e8, h = 1/60 s failed 3 of 30 steps in 8 substeps (the Newton limit at
  1.85e-2 N against a tolerance of 3.3e-3 N); with five every step converges, two of them in 16 and 32 substeps,
  for the same total CPU. Adaptive runs retake nothing here: the step-size controller retries a failed
  step smaller itself.
* **Substep memory.** The phases that need substeps (a stiff cloth buckling) last for many steps, and each
  abandoned attempt costs a whole stage run to its stall or iteration limit. So the next step starts at the number
  of substeps the last retaken step needed, and one level fewer after every :data:`RETAKE_MEMORY` steps that
  succeeded at their first attempt: as a step-size controller keeps its last step. The substeps taken by memory
  are in ``StepStats.extra["substeps"]`` (and ``["remembered_substeps"]``); nothing is retaken for them. On the
  benchmark cloth (n = 32, ke = 1e8, h = 1/60 s, 30 frames) this takes implicit Euler from 23.4 to 16.5 Newton
  iterations per step and BDF2 from 35.0 to 25.6.
* **Reporting.** ``on_nonconvergence="raise"`` raises :class:`~springsim.errors.SolverError` for a step that
  is not ``ok``; otherwise the drivers report it.
"""

from __future__ import annotations

import inspect
from abc import abstractmethod

import numpy as np

from ..errors import SceneError, SolverError
from ._base import Integrator, StepStats
from ._options import LinearSolveOptions
from ._stage import (FORCING_RULES, STAGE_SOLVERS, NewtonOptions, StageForcing, StageSolver, backtrack, check_count,
                     forcing_term, record_linear_solve, report_stage)

__all__ = ["ENERGY_GAIN", "RETAKE_MEMORY", "FORCING_RULES", "STAGE_SOLVERS", "ImplicitIntegrator", "StageForcing",
           "backtrack", "forcing_term", "report_stage", "record_linear_solve"]


#: A step that lifts the energy of a conservative or damped scene above the run's by more than this fraction of the
#: state's energy scale is an instability (:meth:`ImplicitIntegrator.gained_energy`): TR-BDF2 and BDF2 retake it as
#: implicit Euler (:meth:`ImplicitIntegrator.retake_implicit_euler`), linearized implicit Euler in substeps.
ENERGY_GAIN = 1e-6
#: Steps that must succeed at their first attempt before the next step tries one substep level fewer (module
#: docstring, "Substep memory").
RETAKE_MEMORY = 4


class ImplicitIntegrator(Integrator):
    """Base of the implicit integrators.

    The options of the stages and of the linear solves are two frozen groups, each field declared once with its
    default: :class:`~springsim.integrators._stage.NewtonOptions` and
    :class:`~springsim.integrators._options.LinearSolveOptions`. They are given as groups (``newton=``,
    ``linear=``) or field by field as keywords (``jacobian="spd"``, ``solver="cg"``; a keyword may repeat a
    group's field only with the same value); the signature lists every keyword, derived from the declarations.

    Parameters
    ----------
    model : Model
        The model to integrate.
    system : System, optional
        The backend (default: a :class:`~springsim.system.SerialSystem` with the linear solver, ``solver_options``,
        ``terms`` and ``force_kernels``).
    newton : NewtonOptions, optional
        How stages are solved: ``stage_solver``, ``jacobian``, ``force_rtol``, ``force_atol``, ``newton_tol``,
        ``newton_maxiter``, ``residual_rtol``, ``forcing``, ``forcing_max``, ``line_search``, ``min_step``,
        ``escalate_jacobian``, ``escalate_after`` (each documented, with its default or default rule, by
        :class:`~springsim.integrators._stage.NewtonOptions`); also accepted as keywords.
    linear : LinearSolveOptions, optional
        The linear solver (keyword ``solver``: a name of :data:`springsim.linsolve.LINEAR_SOLVERS` or a
        :class:`~springsim.linsolve.LinearSolver` instance, default ``"auto"``: ``direct`` up to 4,000 DOFs,
        AMG-preconditioned Krylov above) and ``linear_rtol``, its relative tolerance; also accepted as keywords.
        Serial systems only.
    solver_options : dict, optional
        Passed to the linear solver's constructor (e.g. ``{"maxiter": 50}``; ``{"rtol": ...}`` is
        ``linear_rtol``). Serial systems only.
    on_nonconvergence : {"warn", "raise", "ignore"}
        What happens to a step that is not ``ok`` after its retakes: ``"warn"``: the drivers warn once per run;
        ``"raise"``: :class:`~springsim.errors.SolverError` at once; ``"ignore"``: recorded in
        :class:`StepStats` only.
    retake_halvings : int
        A step that fails is retaken in up to ``2**retake_halvings`` substeps (module docstring; default 5: up to
        32; 0: never).
    filter_estimates : bool or None
        Pass the local error estimate through Shampine's stiff filter (:meth:`filter_estimate`; one extra
        linear solve per step); default the class's ``default_filter_estimates``. Only integrators whose
        estimate comes from a difference formula use it.
    terms : list of ForceTerm, optional
        Force terms (default: those the model uses); only without ``system``.
    force_kernels : {"auto", "numba", "numpy"}
        Compiled force passes where numba is installed, or the pure numpy path; only without ``system``.
    **options
        The fields of ``newton`` and ``linear`` as keywords (above).

    Raises
    ------
    SceneError
        For an option its declaration refuses, naming the keyword; ``linear_rtol`` given twice with different
        values (also as ``solver_options["rtol"]``).
    TypeError
        For an unknown keyword, or linear solver options together with a ``system``.
    """

    implicit = True
    unused_options = frozenset()
    #: Newton iteration limit of the residual rule when none is given
    default_newton_maxiter = 5
    #: Whether the local error estimate is filtered when ``filter_estimates`` is not given
    default_filter_estimates = True
    #: The stage rules the method's stages admit, the first its default where the forces allow it
    stage_solvers: tuple = ("minimize", "residual", "pa2")
    #: Whether the method solves its stages to convergence (False: a fixed number of plain Newton iterations)
    converges: bool = True

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        cls.unused_options = cls.derived_unused_options()

    @classmethod
    def derived_unused_options(cls) -> frozenset:
        """The keyword options this class accepts but never reads, derived from what it declares it reads.

        The Newton options no stage rule the method admits reads (:meth:`NewtonOptions.read_by
        <springsim.integrators._stage.NewtonOptions.read_by>` over :attr:`stage_solvers`, or ``"plain"`` for a
        method that does not iterate to convergence), and ``filter_estimates`` unless the method has a free local
        error estimate to filter (:attr:`has_error_estimate` without :attr:`error_estimate_costs`). It becomes
        the class's ``unused_options``.

        Returns
        -------
        frozenset of str
        """
        rules = cls.stage_solvers if cls.converges else ("plain",)
        read = frozenset().union(*(NewtonOptions.read_by(rule) for rule in rules))
        unused = set(NewtonOptions.declarations()) - read
        if not (cls.has_error_estimate and not cls.error_estimate_costs):
            unused.add("filter_estimates")
        return frozenset(unused)

    def __init__(self, model, *, system=None, newton: NewtonOptions | None = None,
                 linear: LinearSolveOptions | None = None, solver_options: dict | None = None,
                 on_nonconvergence: str = "warn", retake_halvings: int = 5, filter_estimates: bool | None = None,
                 terms=None, force_kernels: str = "auto", **options):
        solver = options.get("solver")
        instance = solver is not None and not isinstance(solver, str)  # a LinearSolver instance: no name to check
        if instance:
            options = {k: v for k, v in options.items() if k != "solver"}
        newton, rest = NewtonOptions.from_keywords(options, newton)
        linear, rest = LinearSolveOptions.from_keywords(rest, linear)
        if rest:
            raise TypeError(f"{type(self).__name__}() got an unexpected keyword argument {next(iter(rest))!r}")
        solver_options = _with_linear_rtol(solver_options, linear.linear_rtol)
        if system is not None:
            if instance or linear.linear_solver not in (None, "auto") or solver_options:
                raise TypeError("solver and solver_options belong to the system when a system is given")
            serial = {}
        else:
            serial = dict(solver=solver if instance else (linear.linear_solver or LinearSolveOptions.default(
                "linear_solver")), solver_options=solver_options)
        super().__init__(model, system=system, terms=terms, force_kernels=force_kernels, **serial)
        if on_nonconvergence not in ("warn", "raise", "ignore"):
            raise ValueError(f"on_nonconvergence must be warn, raise or ignore, got {on_nonconvergence!r}")
        check_count("retake_halvings", retake_halvings + 1)
        self.retake_halvings = int(retake_halvings)
        self.on_nonconvergence = on_nonconvergence
        #: The linear solve options as given (:class:`~springsim.integrators._options.LinearSolveOptions`).
        self.linear_options = linear
        #: The stage options, resolved for this integrator (:meth:`NewtonOptions.resolve
        #: <springsim.integrators._stage.NewtonOptions.resolve>`).
        self.options = newton.resolve(self)
        self.stage = StageSolver(self.system, self.options)
        self.filter_estimates = self.has_error_estimate and bool(
            self.default_filter_estimates if filter_estimates is None else filter_estimates)
        if self.filter_estimates:
            self.estimating = False  # a filtered estimate costs a solve per step: only while estimating (adaptive)
        self._mass = self.system.particle_mass[:, None]
        self._energy_guarded = all(t.conservative or t.dissipative for t in self.terms)
        self._energy_ceiling, self._last_output = None, None
        g = float(np.linalg.norm(model.gravity_vector))
        self._weight_scale = self.system.sum(float(np.sum(self.system.free_rows(self.system.particle_mass)))) * g
        #: Whether failed steps are retaken in substeps (the adaptive driver turns it off: it retries smaller).
        self.retake = True
        self._recent_acceleration = None  # of the last (sub)step taken, for :meth:`predict`
        self._start_level, self._clean_steps = 0, 0  # the substep memory (module docstring)

    def ignored_options(self) -> frozenset:
        """The Newton options this integrator accepts but, with its stage rule, does not read.

        Returns
        -------
        frozenset of str
            Derived from the declarations (:meth:`NewtonOptions.read_by
            <springsim.integrators._stage.NewtonOptions.read_by>`).
        """
        return frozenset(NewtonOptions.declarations()) - NewtonOptions.read_by(self.stage_solver)

    # the options as attributes (read-only views of :attr:`options`)
    stage_solver = property(lambda self: self.options.stage_solver)
    jacobian = property(lambda self: self.options.jacobian)
    newton_tol = property(lambda self: self.options.newton_tol)
    newton_maxiter = property(lambda self: self.options.newton_maxiter)
    residual_rtol = property(lambda self: self.options.residual_rtol)

    @property
    def solver(self):
        """The linear solver of a serial system (None for a distributed one, which solves with PETSc's KSP)."""
        return getattr(self.system, "solver", None)

    @property
    def assembler(self):
        """The block assembler of a serial system."""
        return self.system.assembler

    def reset(self):
        super().reset()
        self.stage.reset()
        self._energy_ceiling, self._last_output = None, None
        self._recent_acceleration = None
        self._start_level, self._clean_steps = 0, 0

    def blowup_hint(self) -> str:
        return "try a smaller time step"

    # -- stages ---------------------------------------------------------------------------------------------------
    def solve_stage(self, q_hat: np.ndarray, v_hat: np.ndarray, c: float, v0: np.ndarray, stats: StepStats,
                    *, maxiter: int | None = None, converge: bool = True, final_residual: bool = True,
                    guesses=()):
        """Solve ``c F(q_hat + c v, v) = M (v - v_hat)`` for ``v`` from ``v0`` (or the best of ``guesses``).

        :meth:`springsim.integrators._stage.StageSolver.solve` with this method's stage force and matrix
        (:meth:`stage_overrides`).

        Parameters
        ----------
        q_hat, v_hat : ndarray, shape (n, 3)
            The stage's known positions [m] and velocities [m/s]: ``q = q_hat + c v``.
        c : float
            Stage coefficient [s].
        v0 : ndarray, shape (n, 3)
            Starting velocity [m/s].
        stats : StepStats
            Accumulates iterations, times, norms and failures.
        maxiter : int, optional
            Newton iteration limit (default: the options' ``newton_maxiter``).
        converge : bool
            Apply the stopping rule and line search (False: exactly ``maxiter`` plain Newton iterations).
        final_residual : bool
            With ``converge=False``: evaluate the residual at the result for ``stats``.
        guesses : sequence of ndarray, shape (n, 3)
            Other starting velocities (:meth:`predict`); the ``minimize`` rule starts from the lowest ``E``.

        Returns
        -------
        q, v : ndarray, shape (n, 3)
            The stage's positions [m] and velocities [m/s].
        ok : bool
            Whether the stage converged (with ``converge``), else whether its linear solves met their criterion.
        """
        return self.stage.solve(q_hat, v_hat, c, v0, stats, maxiter=maxiter, converge=converge,
                                final_residual=final_residual, guesses=guesses, **self.stage_overrides())

    def predict(self, v: np.ndarray, dt: float) -> list:
        """Predictors of the velocity ``dt`` [s] after a state with velocity ``v``: ``[v + dt a]`` with ``a`` the
        mean acceleration of the last (sub)step this integrator took successfully, or ``[]`` before the first
        one, after a failed attempt and after :meth:`reset`. A stage started from it converges to the same
        minimiser (the stage rule picks the lower ``E``: :mod:`~springsim.integrators._stage`, "Starting point").

        Parameters
        ----------
        v : ndarray, shape (n, 3)
            Velocity [m/s] the prediction starts from.
        dt : float
            How far ahead [s].

        Returns
        -------
        list of ndarray
            Zero or one predicted velocity.
        """
        a = self._recent_acceleration
        if a is None or a.shape != v.shape:
            return []
        return [v + dt * a]

    def stage_overrides(self) -> dict:
        """``forces`` and ``matrix`` replacing the system's in the stages (none: the method's stage balances the
        model's force; :mod:`~springsim.integrators.energy_momentum` overrides it).

        Returns
        -------
        dict
            Keyword arguments of :meth:`springsim.integrators._stage.StageSolver.solve` (``forces``, ``matrix``).
        """
        return {}

    # -- steps ------------------------------------------------------------------------------------------------------
    @abstractmethod
    def advance(self, q: np.ndarray, v: np.ndarray, h: float, stats: StepStats) -> tuple[np.ndarray, np.ndarray]:
        """One step of size ``h`` from ``(q, v)``: ``(q1, v1)`` (new arrays); failures go to ``stats``.

        Parameters
        ----------
        q, v : ndarray, shape (n, 3)
            Positions [m] and velocities [m/s] at the start.
        h : float
            Step [s].
        stats : StepStats
            Receives the step's iterations, times and failures.

        Returns
        -------
        q1, v1 : ndarray, shape (n, 3)
            Positions and velocities after the step.
        """

    def step(self, state_in, state_out, dt):
        stats = StepStats(dt)
        h = float(dt)
        q, v = state_in.particle_q, state_in.particle_qd
        q1, v1 = self._retaken(q, v, h, stats)
        state_out.particle_q[...] = q1
        state_out.particle_qd[...] = v1
        return self.check_step(stats)

    def _attempt(self, q, v, h, stats, n, last):
        """``n`` equal substeps from ``(q, v)``: ``(q1, v1, ok, error)``; unless ``last``, stopping at the first
        that fails (the attempt is then abandoned), else taking them all (the result covers the whole step)."""
        q1, v1, ok = q, v, True
        for _ in range(n):
            if self.jacobian == "mixed":  # the step's stages continue from its input, whatever came before
                self.system.linearize_at(q1)
            v_in = v1
            try:
                q1, v1 = self.advance(q1, v1, h / n, stats)
            except SolverError as e:  # a linear solve with no finite solution: smaller substeps, or the error
                stats.fail(str(e))
                self._recent_acceleration = None
                return q1, v1, False, e
            ok = ok and stats.ok
            self._recent_acceleration = (v1 - v_in) * (n / h) if ok else None
            if not ok and not last:
                break
        return q1, v1, ok, None

    def _retaken(self, q, v, h, stats):
        """A step of ``h``, retaken in 2, 4, ... substeps while it fails, starting at the remembered level (module
        docstring, "Substep retake" and "Substep memory")."""
        levels = self.retake_halvings if self.retake else 0
        start = min(self._start_level, levels)
        if start:
            stats.extra["remembered_substeps"] = 2 ** start
        for level in range(start, levels + 1):
            n = 2 ** level
            self.stage.stop_stalls = level < levels  # the last attempt has nothing smaller to fall back on
            try:
                q1, v1, ok, err = self._attempt(q, v, h, stats, n, last=level == levels)
            finally:
                self.stage.stop_stalls = True
            if ok:
                break
            if level == levels:
                if err is not None:
                    raise err
                break
            stats.retake(f"{self.name} in {n} substep(s): {'; '.join(stats.failures) or 'failed'}; "
                         f"retaken in {2 * n}")
            self.after_retake()
        self._remember(start, level, ok)
        if n > 1:
            stats.extra["substeps"] = n
            self.error_estimate = None  # the estimate of a substep is not the step's
            self.after_retake()
        return q1, v1

    def _remember(self, start: int, level: int, ok: bool) -> None:
        """Update the substep memory after a step that started at ``start`` and ended at ``level``."""
        if level > start or not ok:
            self._start_level, self._clean_steps = level, 0
            return
        self._clean_steps += 1
        if self._clean_steps >= RETAKE_MEMORY and start > 0:
            self._start_level, self._clean_steps = start - 1, 0

    def after_retake(self) -> None:
        """Called before a failed step is retaken in substeps and after a retaken step (multistep methods forget
        their history: a substep's size is not the step's)."""

    def check_step(self, stats: StepStats) -> StepStats:
        """Apply ``on_nonconvergence="raise"`` to a finished step.

        Parameters
        ----------
        stats : StepStats
            The step's statistics.

        Returns
        -------
        StepStats
            ``stats``.

        Raises
        ------
        SolverError
            With ``on_nonconvergence="raise"``, for a step that is not ``ok``.
        """
        if self.on_nonconvergence == "raise" and not stats.ok:
            raise SolverError(f"{self.name} step at dt={stats.dt:g} failed: {'; '.join(stats.failures)}")
        return stats

    def mechanical_energy(self, q: np.ndarray, v: np.ndarray) -> float:
        """``T + V`` [J] of a state (pairs between fixed particles left out: a constant), over every process.

        Parameters
        ----------
        q, v : ndarray, shape (n, 3)
            Positions [m] and velocities [m/s] (the system's state arrays).

        Returns
        -------
        float
            Kinetic plus potential energy [J].
        """
        sysm = self.system
        return 0.5 * sysm.dot(self._mass * v, v) + sysm.potential_energy(q)

    def gained_energy(self, q, v, q1, v1) -> float | None:
        """The energy [J] by which a step from ``(q, v)`` to ``(q1, v1)`` rose above the run's energy, when that
        is more than :data:`ENERGY_GAIN` times the energy scale (``T + |V| + m_total |g| (1 m)`` of the input),
        else None; always None where a force term is neither conservative nor dissipative (the exact energy may
        then grow).

        The run's energy is the largest input energy seen since :meth:`reset` that was not the output of a
        step: along the exact motion the energy never grows, so no step may lift it above where the run began
        (one that does is an instability, however small each step's share).

        Parameters
        ----------
        q, v : ndarray, shape (n, 3)
            The step's input positions [m] and velocities [m/s].
        q1, v1 : ndarray, shape (n, 3)
            Its output.

        Returns
        -------
        float or None
            The gain [J] above the run's energy, or None when it is within the allowance (or not judged).
        """
        if not self._energy_guarded:
            return None
        t0 = 0.5 * self.system.dot(self._mass * v, v)
        v0 = self.system.potential_energy(q)
        e0, e1 = t0 + v0, self.mechanical_energy(q1, v1)
        if self._energy_ceiling is None or (e0 > self._energy_ceiling and not self._continues(q, v)):
            self._energy_ceiling = e0
        scale = t0 + abs(v0) + self._weight_scale
        self._last_output = (q1, v1)
        gain = e1 - self._energy_ceiling
        return gain if gain > ENERGY_GAIN * scale else None

    def _continues(self, q, v) -> bool:
        last = self._last_output
        return last is not None and self.system.all_equal(q, last[0]) and self.system.all_equal(v, last[1])

    def retake_implicit_euler(self, q, v, h: float, a_n, stats: StepStats, why: str):
        """:meth:`implicit_euler_stage` in place of a step of an L-stable second-order method that created energy
        (order reduction): the trapezoidal and BDF2 stages can move the energy of a stiff mode they do not
        resolve into the motion (a spring of ``k = 1e8`` at ``omega h = 1000``: 50 J became 100 J in one TR-BDF2
        step, both stages converged), where implicit Euler, whose step minimises the incremental potential from
        the state itself, dissipates it. ``stats.extra["order_reduced"]`` records it with ``why``.

        Parameters
        ----------
        q, v : ndarray, shape (n, 3)
            The step's input positions [m] and velocities [m/s].
        h : float
            Step [s].
        a_n : ndarray, shape (n, 3)
            Acceleration at the start [m/s^2].
        stats : StepStats
            The step's statistics.
        why : str
            What the discarded step did (recorded).

        Returns
        -------
        tuple
            As :meth:`implicit_euler_stage`.
        """
        stats.extra["order_reduced"] = why
        return self.implicit_euler_stage(q, v, h, a_n, stats)

    def implicit_euler_stage(self, q, v, h: float, a_n, stats: StepStats):
        """One implicit Euler step from ``(q, v)`` as a stage: ``(q1, v1, ok, error_estimate)``.

        ``a_n`` is the acceleration at the start [m/s^2]; ``error_estimate = (err_q, err_v)`` is half the
        difference to explicit Euler, implicit Euler's local error to leading order. Used as the start step of
        multistep methods.

        Parameters
        ----------
        q, v : ndarray, shape (n, 3)
            Positions [m] and velocities [m/s] at the start.
        h : float
            Step [s].
        a_n : ndarray, shape (n, 3)
            Acceleration at the start [m/s^2].
        stats : StepStats
            The step's statistics.

        Returns
        -------
        q1, v1 : ndarray, shape (n, 3)
            The step's result.
        ok : bool
            Whether the stage converged.
        error_estimate : tuple of ndarray
            ``(err_q, err_v)`` [m, m/s].
        """
        q1, v1, ok = self.solve_stage(q, v, h, v, stats)
        q1[self.fixed] = q[self.fixed]
        return q1, v1, ok, (0.5 * (q1 - (q + h * v)), 0.5 * (v1 - (v + h * a_n)))

    # -- error estimates ----------------------------------------------------------------------------------------
    def finish_estimate(self, q: np.ndarray, v: np.ndarray, c: float, err, stats: StepStats):
        """The error estimate a step of a method with a difference-formula estimate ``err`` publishes: None while
        not :attr:`estimating`, else ``err`` through :meth:`filter_estimate` when :attr:`filter_estimates` is set
        and the step is ok (``(q, v)`` the step's result, ``c`` its last stage's coefficient).

        Parameters
        ----------
        q, v : ndarray, shape (n, 3)
            The step's result [m, m/s].
        c : float
            Its last stage's coefficient [s].
        err : tuple of ndarray
            The difference-formula estimate ``(e_q, e_v)``.
        stats : StepStats
            The step's statistics.

        Returns
        -------
        tuple of ndarray or None
            The estimate to publish.
        """
        if not self.estimating:
            return None
        return self.filter_estimate(q, v, c, err, stats) if stats.ok else err

    def filter_estimate(self, q: np.ndarray, v: np.ndarray, c: float, err, stats: StepStats):
        """Shampine's stiff filter of a local error estimate ``err = (e_q, e_v)``: ``(I - c J)^-1 e``.

        ``J = [[0, I], [M^-1 dF/dq, M^-1 dF/dqd]]`` is the Jacobian of the first-order system at ``(q, v)``
        and ``c`` the stage coefficient, so ``I - c J`` is Newton's matrix in first-order form. The
        difference formulas of the estimates measure ``h^3`` times the third derivative, which in a stiff component
        is ``(h lambda)^3`` times its size however well the L-stable method damps it; the filter scales each
        eigencomponent by ``1 / (1 - c lambda)``, leaving the non-stiff ones (``c lambda`` small) unchanged
        to leading order (Shampine 1982; Hosea and Shampine 1996). Eliminating the position block::

            (M - c^2 dF/dq - c dF/dqd) x_v = M e_v + c (dF/dq) e_q,     x_q = e_q + c x_v

        with the Jacobian mode of the Newton stages: one assembly of ``M - dF/dq`` for the product, one of
        Newton's matrix and one linear solve, counted in ``stats``. Off with :attr:`filter_estimates`
        False. A solve that misses its criterion leaves the estimate unfiltered (it is then the larger one on
        stiff components: the controller errs on the safe side), counted in
        ``stats.extra["unfiltered_estimates"]``; it does not fail the step.

        Parameters
        ----------
        q, v : ndarray, shape (n, 3)
            State [m, m/s] at which ``J`` is taken (the step's result).
        c : float
            Stage coefficient [s].
        err : tuple of ndarray
            The estimate ``(e_q, e_v)``, shape (n, 3) each.
        stats : StepStats
            The step's statistics.

        Returns
        -------
        tuple of ndarray
            The filtered estimate (``err`` itself when filtering is off or its solve missed).
        """
        if not self.filter_estimates:
            return err
        sysm = self.system
        e_q, e_v = sysm.gather(err[0]), sysm.gather(err[1])
        m = self.stage._mass_dofs
        K = sysm.assemble(q, v, 1.0, 0.0, self.jacobian)  # M - dF/dq, for the product only
        stats.assembly_s += sysm.last_assembly_s
        rhs = m * e_v + c * (m * e_q - K @ e_q)
        A = sysm.assemble(q, v, c * c, c, self.jacobian)
        stats.assembly_s += sysm.last_assembly_s
        res = sysm.solve(A, rhs)
        finite = sysm.all_finite(res.x)
        # finite=True: a non-finite filter solve only leaves the estimate unfiltered, it does not end the step
        if record_linear_solve(stats, res, True) or not finite:
            stats.extra["unfiltered_estimates"] = stats.extra.get("unfiltered_estimates", 0) + 1
            return err
        x_q, x_v = np.zeros_like(err[0]), np.zeros_like(err[1])
        sysm.scatter_add(x_q, e_q + c * res.x)
        sysm.scatter_add(x_v, res.x)
        return x_q, x_v


def _with_linear_rtol(solver_options: dict | None, rtol: float | None) -> dict | None:
    """``solver_options`` with ``linear_rtol`` as its ``"rtol"`` (unchanged when ``rtol`` is None).

    Parameters
    ----------
    solver_options : dict or None
        The linear solver's constructor options.
    rtol : float or None
        ``linear_rtol``.

    Returns
    -------
    dict or None

    Raises
    ------
    SceneError
        Naming ``linear_rtol`` when ``solver_options`` holds another ``"rtol"``.
    """
    if rtol is None:
        return solver_options
    solver_options = dict(solver_options or {})
    if "rtol" in solver_options and solver_options["rtol"] != rtol:
        raise SceneError("linear_rtol", f"given twice: linear_rtol={rtol!r:.60} and solver_options['rtol']="
                                        f"{solver_options['rtol']!r:.60}")
    solver_options["rtol"] = rtol
    return solver_options


def _signature() -> inspect.Signature:
    """:class:`ImplicitIntegrator`'s signature with ``**options`` spelt out: the keywords of the option groups,
    from their declarations (so :func:`inspect.signature` and ``help`` list every option)."""
    sig = inspect.signature(ImplicitIntegrator.__init__)
    params = [p for p in sig.parameters.values() if p.kind is not p.VAR_KEYWORD]
    for group in (LinearSolveOptions, NewtonOptions):
        for kw, name in group.keywords().items():
            params.append(inspect.Parameter(kw, inspect.Parameter.KEYWORD_ONLY, default=None,
                                            annotation=group.declarations()[name].type))
    return sig.replace(parameters=params)


ImplicitIntegrator.__init__.__signature__ = _signature()
