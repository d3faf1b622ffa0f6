"""Shared machinery of the implicit integrators: one Newton solver for a velocity stage.

Every implicit method here reduces each step (or stage) to finding the velocity ``v``
with::

    R(v) = c F(q_hat + c v, v) - M (v - v_hat) = 0          q = q_hat + c v

for known ``q_hat``, ``v_hat`` and coefficient ``c``. Newton's update ``dv`` solves::

    [M - c^2 dF/dq - c dF/dqd] dv = R(v_i)                  (A = M - a dF/dq - b dF/dqd)

with the Jacobians at ``(q_hat + c v_i, v_i)``. Implicit Euler is ``c = h``,
``q_hat = q^n``, ``v_hat = qd^n`` (PA2 eq. 1-2); one iteration from ``v_0 = qd^n`` is
linearized implicit Euler (PA2 eq. 3-4). The system covers free DOFs only (row and
column elimination, see :mod:`springsim.assembly.fixed`).

Stopping rule. PA2's rule stops when the update is small, ``|dv|_2 < newton_tol``.
An update can be small while the iterate is far from the root: when ``c^2 dF/dq`` dwarfs
``M`` (huge steps, very stiff springs) a position error ``e_q`` shows up in ``v`` only as
``e_q / c``. So a stage also has to balance its equation: the residual at the returned
iterate must be small against the terms it balances::

    rho = |R(v)|_2 / (|c F|_2 + |M (v - v_hat)|_2 + newton_tol |m|_2) <= residual_rtol

(all norms over free DOFs; ``|m|_2`` the norm of the mass vector, so that a state at rest
with ``F = 0`` is measured against the residual of a velocity error of ``newton_tol``). On
converged stages of the test and benchmark scenes ``rho`` is 1e-16 ... 4e-6; on the false
convergences of a 1 kg pendulum at ``h = 1e6 s`` it is 0.05 ... 1 (docs/robustness.md).

Forcing. With ``forcing="eisenstat-walker"`` the linear solves of a stage that runs to convergence are
inexact Newton steps (Dembo, Eisenstat and Steihaug 1982): each solve of ``A dv = R`` stops at the relative
residual ``eta_k`` of Eisenstat and Walker (1996, choice 2; :func:`forcing_term`), loose while ``|R|``
is far from zero (0.1 at the first iteration), tightening as it converges quadratically, never below the
solver's ``rtol``. A solve to ``rtol`` = 1e-6 at the first iterations buys nothing the next iteration keeps:
with the ``spd`` Jacobian Newton converges only linearly anyway. The stopping rule needs an update from a
solve to the solver's ``rtol``: when a loose update passes it, one more iteration solves to ``rtol`` and
decides (an inexact update can be small while the iterate is not converged: on the 64 x 64 benchmark
cloth, stopping on loose updates moved TR-BDF2's trajectory 2 cm from the converged one). So the result
is a converged stage either way (the two differ by the Newton tolerance); direct solvers ignore it.
The default ``"fixed"`` solves every system to the solver's ``rtol``.

Linear solves. Each result is checked (``LinearSolveResult.converged``). A solve that missed its
criterion after the solver's own refinement and fallback is still a usable search direction
for Newton (inexact Newton): the line search and the stopping rule judge the outcome, so in
a stage that converges it is recovered (counted in ``StepStats.extra["recovered_linear_failures"]``).
In a stage that does not converge, and in linearized implicit Euler (one solve, no stopping
rule to check it), it is a failure: counted in ``StepStats.linear_failures`` with its reason,
and the step is not ``ok``. A non-finite solution ends the step with
:class:`~springsim.errors.SolverError`.
"""

from __future__ import annotations

import time

import numpy as np

from ..assembly import SystemAssembler
from ..errors import SceneError, SolverError
from ..forces import JACOBIAN_MODES, eval_forces
from ..linsolve import make_linear_solver
from ..progress import logger, phase
from ._base import PRECISION_LOSS_LIMIT, Integrator, StepStats

_log = logger.getChild("integrators")

__all__ = ["FORCING_RULES", "ImplicitIntegrator", "StageForcing", "backtrack", "check_newton_options", "forcing_term",
           "report_stage", "record_linear_solve", "set_newton_options"]

#: Rules for the relative tolerance of a Newton stage's linear solves (``forcing``; module docstring).
FORCING_RULES = ("fixed", "eisenstat-walker")


def forcing_term(k: int, rnorm: float, rnorm_prev: float, eta_prev: float, *, eta_max: float, floor: float) -> float:
    """Relative tolerance of the ``k``-th linear solve of a Newton stage (Eisenstat and Walker 1996, choice 2).

    ``eta_0 = eta_max``; then ``eta_k = 0.9 (|R_k| / |R_{k-1}|)^2``, safeguarded by ``0.9 eta_{k-1}^2`` when that
    exceeds 0.1 (a sudden drop of ``|R|`` does not make one solve needlessly tight), capped at ``eta_max`` and
    never below ``floor`` (the solver's ``rtol``).
    """
    if k == 0 or not (rnorm_prev > 0.0 and np.isfinite(rnorm)):
        eta = eta_max
    else:
        eta = 0.9 * (rnorm / rnorm_prev) ** 2
        safeguard = 0.9 * eta_prev ** 2
        if safeguard > 0.1:
            eta = max(eta, safeguard)
    return max(min(eta, eta_max), floor)


class StageForcing:
    """The linear tolerances of one Newton stage (module docstring, "Forcing").

    :meth:`rtol` before each solve gives its relative tolerance (None: the solver's own, the ``"fixed"``
    rule); :meth:`certified` tells whether an update that passed the stopping rule may end the stage (it came
    from a solve to ``floor``), and otherwise makes the next solve one to ``floor``.
    """

    def __init__(self, rule: str, *, eta_max: float, floor: float):
        self.on = rule == "eisenstat-walker"
        self.eta_max, self.floor = eta_max, floor
        self.k, self.eta, self.rnorm_prev, self.confirm = 0, 0.0, 0.0, False

    def rtol(self, rnorm: float) -> float | None:
        """The next solve's relative tolerance, given the residual norm ``|R|`` it solves for."""
        if not self.on:
            return None
        self.eta = self.floor if self.confirm else forcing_term(self.k, rnorm, self.rnorm_prev, self.eta,
                                                                eta_max=self.eta_max, floor=self.floor)
        self.k, self.rnorm_prev = self.k + 1, rnorm
        return self.eta

    def certified(self, residual: float) -> bool:
        """Whether the update of a solve that reached the relative residual ``residual`` may end the stage."""
        if not self.on or residual <= self.floor:
            return True
        self.confirm = True  # a loose update passed: the next one is solved to the floor and decides
        return False


def backtrack(trial, rnorm: float, *, enabled: bool, min_step: float):
    """Backtracking line search on ``|R|`` (Armijo on the merit ``1/2 |R|^2``): ``(alpha, trial(alpha))``.

    ``trial(alpha)`` evaluates the iterate at step ``alpha`` and returns a tuple whose fourth entry is its
    residual norm. ``alpha`` halves from 1 until ``|R|`` decreases by ``1e-4 alpha`` relatively, ``alpha``
    reaches ``min_step``, or (``enabled`` False) at once. The trial's residual is the next iteration's, so
    a full step costs nothing extra; near the solution full steps are taken and quadratic convergence kept.
    """
    alpha = 1.0
    while True:
        result = trial(alpha)
        rn = result[3]
        if not enabled or rn <= (1.0 - 1e-4 * alpha) * rnorm or alpha <= min_step or not np.isfinite(rnorm):
            return alpha, result
        alpha *= 0.5


def set_newton_options(obj, *, jacobian: str, newton_tol, newton_maxiter, residual_rtol, on_nonconvergence: str,
                       line_search, min_step, forcing: str, forcing_max) -> None:
    """Validate (:func:`check_newton_options`) and set the options every Newton stage solver has as attributes
    of ``obj`` (the serial and the distributed implicit integrators)."""
    check_newton_options(jacobian, newton_tol, newton_maxiter, residual_rtol, on_nonconvergence, forcing, forcing_max)
    obj.jacobian = jacobian
    obj.newton_tol = float(newton_tol)
    obj.newton_maxiter = int(newton_maxiter)
    obj.residual_rtol = float(residual_rtol)
    obj.on_nonconvergence = on_nonconvergence
    obj.line_search = bool(line_search)
    obj.min_step = float(min_step)
    obj.forcing = forcing
    obj.forcing_max = float(forcing_max)


def check_newton_options(jacobian: str, newton_tol, newton_maxiter, residual_rtol, on_nonconvergence: str,
                         forcing: str = "fixed", forcing_max: float = 0.1) -> None:
    """Validate the options of a Newton stage solver; a SceneError naming the parameter (ValueError for
    ``on_nonconvergence``, a programming choice rather than scene input)."""
    if forcing not in FORCING_RULES:
        raise SceneError("forcing", f"must be one of {', '.join(FORCING_RULES)}, got {forcing!r:.60}")
    if not 0.0 < forcing_max < 1.0:
        raise SceneError("forcing_max", f"must be in (0, 1), got {forcing_max!r:.60}")
    if jacobian not in JACOBIAN_MODES:
        raise SceneError("jacobian", f"must be one of {', '.join(JACOBIAN_MODES)}, got {jacobian!r}")
    if not newton_tol > 0:
        raise SceneError("newton_tol", f"must be > 0, got {newton_tol}")
    if not residual_rtol > 0:
        raise SceneError("residual_rtol", f"must be > 0, got {residual_rtol}")
    _check_count("newton_maxiter", newton_maxiter)
    if on_nonconvergence not in ("warn", "raise", "ignore"):
        raise ValueError(f"on_nonconvergence must be warn, raise or ignore, got {on_nonconvergence!r}")


def record_linear_solve(stats: StepStats, res, finite: bool) -> str | None:
    """Add a linear solve's cost and outcome to ``stats``; the failure to judge at the stage's end, or None.

    ``finite``: whether the solution is finite everywhere (on every rank, for a distributed solve).

    Raises
    ------
    SolverError
        For a non-finite solution: there is no direction to continue from.
    """
    stats.solve_s += res.time_s
    stats.linear_iterations += res.iterations
    stats.linear_solves += 1
    stats.linear_residual = max(stats.linear_residual, res.residual)
    if res.fallback:
        stats.fallbacks.append(f"{res.method}: {res.fallback}")
    if not finite:
        raise SolverError(f"linear solver {res.method!r} failed: {res.failure or 'non-finite solution'}")
    return None if res.converged else f"linear solve ({res.method}) failed: {res.failure}"


def report_stage(stats: StepStats, *, converge: bool, converged: bool, failed: list, maxiter: int, step: float,
                 rnorm: float, ratio: float, newton_tol: float, residual_rtol: float) -> bool:
    """Record the outcome of a Newton stage in ``stats`` (module docstring); whether the stage is ok.

    ``failed``: its failed linear solves. In a stage run to convergence (``converge``) that converged they were
    inexact Newton directions certified by the stopping rule (counted as recovered); otherwise they fail the step.
    Ill-conditioning is reported for the step but does not fail the stage: retaking it another way (implicit
    Euler, a larger c) would only make the conditioning worse.
    """
    stats.newton_step_norm = step
    stats.residual_norm = rnorm
    stats.residual_ratio = ratio
    if converge:
        converged = converged and bool(np.isfinite(rnorm))
        if converged and failed:
            stats.extra["recovered_linear_failures"] = stats.extra.get("recovered_linear_failures", 0) + len(failed)
            failed = []
        if not converged:
            stats.newton_converged = False
            stats.fail(f"Newton did not converge in {maxiter} iterations (|dv| {step:.1e} m/s, tol "
                       f"{newton_tol:g}; residual ratio {ratio:.1e}, tol {residual_rtol:g})")
    stats.linear_failures += len(failed)
    for reason in failed:
        stats.fail(reason)
    if stats.ill_conditioned:
        stats.fail(f"ill-conditioned matrix: it holds the masses only to {stats.precision_loss:.1e} "
                   f"(limit {PRECISION_LOSS_LIMIT:g}); reduce the step or soften the stiffest pairs")
    return not failed and (converged or not converge)


def _check_count(name: str, value) -> None:
    """A SceneError naming the parameter ``name`` unless ``value`` is an integer >= 1."""
    if isinstance(value, bool) or int(value) != value or value < 1:
        raise SceneError(name, f"must be an integer >= 1, got {value!r:.60}")


class ImplicitIntegrator(Integrator):
    """Base of the implicit integrators.

    Parameters
    ----------
    model : Model
    solver : str or LinearSolver
        Linear solver name (see :data:`springsim.linsolve.LINEAR_SOLVERS`) or instance; default ``"auto"``
        (``direct`` up to 4,000 DOFs, AMG-preconditioned Krylov above).
    jacobian : {"exact", "symmetric", "spd"} or None
        Jacobian mode; default ``spd`` for solvers that need SPD matrices at this size
        (:meth:`~springsim.linsolve.LinearSolver.needs_spd_for`), else ``exact``.
    newton_tol : float
        Update tolerance: a stage may stop when ``|dv|_2 < newton_tol`` [m/s] (PA2: 1e-5).
    newton_maxiter : int or None
        Iteration limit; default the class's ``default_newton_maxiter``: PA2's 5 for
        implicit Euler, 50 for BDF2 and TR-BDF2, which retake a step whose stage did not
        converge with implicit Euler and so must let Newton finish (docs/accuracy.md).
    residual_rtol : float
        Residual tolerance of the stopping rule (module docstring), default 1e-3.
    on_nonconvergence : {"warn", "raise", "ignore"}
        What happens to a step that is not ``ok`` (Newton missed its limit, a linear solve
        failed, the matrix lost the masses): ``"warn"``: the drivers warn once per run;
        ``"raise"``: :class:`~springsim.errors.SolverError` at once; ``"ignore"``: recorded in
        :class:`StepStats` only.
    line_search : bool
        Backtrack the Newton update (halving, down to ``min_step``) until the residual
        norm decreases (Armijo). Full steps are taken near the solution, so quadratic
        convergence is kept; far from it (stiff cloth at large ``h``) plain Newton
        diverges. Only used when Newton runs to convergence (``converge=True``), so
        linearized implicit Euler is PA2 eq. 3 exactly.
    min_step : float
        Smallest line-search step.
    solver_options : dict, optional
        Passed to the linear solver's constructor (e.g. ``{"rtol": 1e-6}``).
    escalate_jacobian : bool
        When Newton with the ``spd`` or ``symmetric`` Jacobian reaches its limit, continue the
        stage from its last iterate with the ``exact`` Jacobian (up to the limit again) before
        reporting non-convergence; counted in ``StepStats.extra["jacobian_escalations"]``.
        The projected matrices slow Newton to linear convergence where they differ from the
        true Jacobian (compressed springs), which is where it misses its limit. Only stages
        that run Newton to convergence escalate, so linearized implicit Euler is unaffected.
    escalate_after : int or None
        Iterations with the projected Jacobian before escalating (default: the Newton limit).
    forcing : {"fixed", "eisenstat-walker"}
        Relative tolerance of the linear solves of stages run to convergence: the solver's ``rtol``
        (``"fixed"``), or Eisenstat-Walker forcing terms (module docstring).
    forcing_max : float
        Largest (and first) Eisenstat-Walker forcing term (default 0.1).
    filter_estimates : bool or None
        Pass the local error estimate through Shampine's stiff filter (:meth:`filter_estimate`; one extra
        linear solve per step); default the class's ``default_filter_estimates``: True for TR-BDF2, False
        for BDF2, as measured on the benchmark cloth (docs/accuracy.md). Only integrators with such an
        estimate use it.
    terms : list of ForceTerm, optional
        Force terms (default: those the model uses).
    force_kernels : {"auto", "numba", "numpy"}
        Compiled force passes where numba is installed (``"auto"``; see :func:`springsim.forces.make_force_terms`)
        or the pure numpy path; used only when ``terms`` is not given.
    """

    implicit = True
    unused_options = frozenset()
    #: Newton iteration limit when none is given
    default_newton_maxiter = 5
    #: Whether the local error estimate is filtered when ``filter_estimates`` is not given
    default_filter_estimates = True

    def __init__(self, model, *, solver="auto", jacobian: str | None = None, newton_tol: float = 1e-5,
                 newton_maxiter: int | None = None, residual_rtol: float = 1e-3, on_nonconvergence: str = "warn",
                 solver_options: dict | None = None, line_search: bool = True, min_step: float = 1.0 / 64,
                 escalate_jacobian: bool = True, escalate_after: int | None = None, forcing: str = "fixed",
                 forcing_max: float = 0.1, filter_estimates: bool | None = None, terms=None,
                 force_kernels: str = "auto"):
        super().__init__(model, terms=terms, force_kernels=force_kernels)
        self.solver = make_linear_solver(solver, **(solver_options or {}))
        if jacobian is None:
            jacobian = "spd" if self.solver.needs_spd_for(3 * model.free_count) else "exact"
        if newton_maxiter is None:
            newton_maxiter = self.default_newton_maxiter
        set_newton_options(self, jacobian=jacobian, newton_tol=newton_tol, newton_maxiter=newton_maxiter,
                           residual_rtol=residual_rtol, on_nonconvergence=on_nonconvergence, line_search=line_search,
                           min_step=min_step, forcing=forcing, forcing_max=forcing_max)
        self.escalate_jacobian = bool(escalate_jacobian)
        if escalate_after is not None:
            _check_count("escalate_after", escalate_after)
        self.escalate_after = None if escalate_after is None else int(escalate_after)
        with phase(f"{self.name}: sparsity pattern of {3 * model.free_count} DOFs", _log, announce=False):
            self.assembler = SystemAssembler(model, self.terms)
        self._mass = model.particle_mass[:, None]
        self._mass_dofs = np.repeat(model.particle_mass[self.free], 3)  # M as a free DOF vector
        # floor of the residual scale: the residual of a velocity error of newton_tol in every DOF
        self._mass_norm = float(np.linalg.norm(self._mass_dofs))
        self._warm: np.ndarray | None = None
        self._stage_failures: list[str] = []
        self.filter_estimates = self.has_error_estimate and bool(
            self.default_filter_estimates if filter_estimates is None else filter_estimates)
        if self.filter_estimates:
            self.estimating = False  # a filtered estimate costs a solve per step: only while estimating (adaptive)

    def reset(self):
        super().reset()
        self._warm = None

    def blowup_hint(self) -> str:
        return "try a smaller time step"

    # -- the Newton stage solver -----------------------------------------------------------
    def solve_stage(self, q_hat: np.ndarray, v_hat: np.ndarray, c: float, v0: np.ndarray, stats: StepStats,
                    *, maxiter: int | None = None, converge: bool = True, final_residual: bool = True):
        """Solve ``c F(q_hat + c v, v) = M (v - v_hat)`` for ``v`` by Newton from ``v0``.

        Parameters
        ----------
        q_hat, v_hat, v0 : ndarray (N, 3)
        c : float
            Stage coefficient [s].
        stats : StepStats
            Accumulates iterations, times, norms and failures.
        maxiter : int, optional
            Iteration limit (default ``newton_maxiter``); 1 gives the linearized method.
        converge : bool
            Apply the stopping rule, line search and non-convergence report (False: exactly
            ``maxiter`` plain Newton iterations).
        final_residual : bool
            With ``converge=False``: whether to evaluate the residual at the returned iterate for
            ``stats.residual_norm`` and ``stats.residual_ratio`` (False: NaN, one force evaluation
            saved where nothing reads them, as in linearized implicit Euler).

        Returns
        -------
        q, v : ndarray (N, 3)
        ok : bool
            Whether the stage converged (when ``converge``; else whether its linear solves met their
            criterion); the reasons otherwise are in ``stats.failures``. Ill-conditioning is reported
            in ``stats`` but does not make a stage fail.
        """
        maxiter = self.newton_maxiter if maxiter is None else maxiter
        self._stage_failures = []  # failed linear solves of this stage, judged at its end
        v = np.array(v0, dtype=np.float64)
        v[self.fixed] = 0.0
        escalate = converge and self.escalate_jacobian and self.jacobian != "exact"
        first = min(maxiter, self.escalate_after) if escalate and self.escalate_after is not None else maxiter
        q, v, step, rnorm, ratio, converged = self._newton(q_hat, v_hat, c, v, stats, first, converge, self.jacobian,
                                                           final_residual or converge)
        if escalate and not converged and np.isfinite(rnorm):  # a non-finite v makes rnorm non-finite
            # the projected Jacobian slows Newton to linear convergence where it differs from the
            # exact one (compressed springs); finish the stage with the exact Jacobian
            stats.extra["jacobian_escalations"] = stats.extra.get("jacobian_escalations", 0) + 1
            q, v, step, rnorm, ratio, converged = self._newton(q_hat, v_hat, c, v, stats, maxiter, converge, "exact")
        ok = report_stage(stats, converge=converge, converged=converged, failed=self._stage_failures, maxiter=maxiter,
                          step=step, rnorm=rnorm, ratio=ratio, newton_tol=self.newton_tol,
                          residual_rtol=self.residual_rtol)
        return q, v, ok

    def _newton(self, q_hat, v_hat, c, v, stats, maxiter, converge, mode, final_residual=True):
        """Newton iterations of :meth:`solve_stage` from ``v`` with the Jacobian ``mode``:
        ``(q, v, |dv|, |R|, rho, converged)``."""
        asm = self.assembler
        f = np.empty_like(v)
        q = q_hat + c * v
        R, rnorm, ratio = self._residual(q, v, v_hat, c, f, stats)
        converged = False
        step = 0.0
        forcing = StageForcing(self.forcing if converge else "fixed", eta_max=self.forcing_max, floor=self.solver.rtol)
        for it in range(maxiter):
            A = self.stage_matrix(q, v, c, mode)
            stats.assembly_s += asm.last_time_s
            stats.precision_loss = max(stats.precision_loss, asm.precision_loss(A))
            res = self._linear_solve(A, asm.gather(R), stats, first=(it == 0), rtol=forcing.rtol(rnorm))
            dv = res.x
            step = float(np.linalg.norm(dv))
            stats.newton_iterations += 1
            def trial(alpha, v=v, dv=dv, judged=True):
                v_try = v.copy()
                asm.scatter_add(v_try, dv, alpha)
                q_try = q_hat + c * v_try
                if not judged:
                    return v_try, q_try, None, float("nan"), float("nan")
                return (v_try, q_try, *self._residual(q_try, v_try, v_hat, c, f, stats))

            if not final_residual and it == maxiter - 1:  # nothing reads the last residual: not computed
                alpha, (v, q, R, rnorm, ratio) = 1.0, trial(1.0, judged=False)
            else:
                alpha, (v, q, R, rnorm, ratio) = backtrack(trial, rnorm, enabled=converge and self.line_search,
                                                           min_step=self.min_step)
            stats.extra["min_line_search_step"] = min(alpha, stats.extra.get("min_line_search_step", 1.0))
            if not np.isfinite(step):
                break
            if converge and step < self.newton_tol and ratio <= self.residual_rtol and forcing.certified(res.residual):
                converged = True
                break
        return q, v, step, rnorm, ratio, converged

    def _residual(self, q, v, v_hat, c, f, stats):
        """``R = c F(q, v) - M (v - v_hat)`` (N, 3), ``|R|_2`` and ``rho`` over free DOFs (module docstring)."""
        t0 = time.perf_counter()
        self.stage_forces(q, v, f)
        free = self.free
        cf = c * f[free]
        mdv = self._mass[free] * (v[free] - v_hat[free])
        R = c * f - self._mass * (v - v_hat)
        rnorm = float(np.linalg.norm(cf - mdv))
        scale = float(np.linalg.norm(cf)) + float(np.linalg.norm(mdv)) + self.newton_tol * self._mass_norm
        stats.force_s += time.perf_counter() - t0
        return R, rnorm, (rnorm / scale if scale > 0 else 0.0)

    def stage_forces(self, q: np.ndarray, v: np.ndarray, f: np.ndarray) -> None:
        """The force ``F(q, v)`` of the stage equation into ``f`` (N, 3); methods whose stage balances another
        force (:mod:`~springsim.integrators.energy_momentum`) override it."""
        eval_forces(self.terms, q, v, out=f)

    def stage_matrix(self, q: np.ndarray, v: np.ndarray, c: float, mode: str):
        """Newton's matrix ``M - c^2 dF/dq - c dF/dqd`` of the stage equation at ``(q, v)``, for the force of
        :meth:`stage_forces`."""
        return self.assembler.assemble(q, v, c * c, c, mode)

    def _linear_solve(self, A, b, stats, first: bool, rtol: float | None = None):
        x0 = self._warm if (first and self._warm is not None and self._warm.shape == b.shape) else None
        res = self.solver.solve(A, b, x0=x0, rtol=rtol)
        failure = record_linear_solve(stats, res, bool(np.all(np.isfinite(res.x))))
        if failure:
            self._stage_failures.append(failure)
        if first:
            self._warm = res.x
        return res

    def finish_estimate(self, q: np.ndarray, v: np.ndarray, c: float, err, stats: StepStats):
        """The error estimate a step of a method with a difference-formula estimate ``err`` publishes: None while
        not :attr:`estimating`, else ``err`` through :meth:`filter_estimate` when :attr:`filter_estimates` is set
        and the step is ok (``(q, v)`` the step's result, ``c`` its last stage's coefficient)."""
        if not self.estimating:
            return None
        return self.filter_estimate(q, v, c, err, stats) if stats.ok else err

    def filter_estimate(self, q: np.ndarray, v: np.ndarray, c: float, err, stats: StepStats):
        """Shampine's stiff filter of a local error estimate ``err = (e_q, e_v)``: ``(I - c J)^-1 e``.

        ``J = [[0, I], [M^-1 dF/dq, M^-1 dF/dqd]]`` is the Jacobian of the first-order system at ``(q, v)``
        and ``c`` the stage coefficient, so ``I - c J`` is Newton's matrix in first-order form. The
        difference formulas of the estimates measure ``h^3`` times the third derivative, which in a stiff component is
        ``(h lambda)^3`` times its size however well the L-stable method damps it; the filter scales each
        eigencomponent by ``1 / (1 - c lambda)``, leaving the non-stiff ones (``c lambda`` small) unchanged
        to leading order (Shampine 1982; Hosea and Shampine 1996). Eliminating the position block::

            (M - c^2 dF/dq - c dF/dqd) x_v = M e_v + c (dF/dq) e_q,     x_q = e_q + c x_v

        with the Jacobian mode of the Newton stages: one assembly of ``M - dF/dq`` for the product, one of
        Newton's matrix and one linear solve, counted in ``stats``. Off with :attr:`filter_estimates`
        False. A solve that misses its criterion leaves the estimate unfiltered (it is then the larger one on
        stiff components: the controller errs on the safe side), counted in
        ``stats.extra["unfiltered_estimates"]``; it does not fail the step.
        """
        if not self.filter_estimates:
            return err
        asm = self.assembler
        e_q, e_v = asm.gather(err[0]), asm.gather(err[1])
        m = self._mass_dofs
        K = asm.assemble(q, v, 1.0, 0.0, self.jacobian)  # M - dF/dq, for the product only
        stats.assembly_s += asm.last_time_s
        rhs = m * e_v + c * (m * e_q - K @ e_q)
        A = self.stage_matrix(q, v, c, self.jacobian)
        stats.assembly_s += asm.last_time_s
        res = self.solver.solve(A, rhs)
        finite = bool(np.all(np.isfinite(res.x)))
        # finite=True: a non-finite filter solve only leaves the estimate unfiltered, it does not end the step
        if record_linear_solve(stats, res, True) or not finite:
            stats.extra["unfiltered_estimates"] = stats.extra.get("unfiltered_estimates", 0) + 1
            return err
        x_q, x_v = np.zeros_like(err[0]), np.zeros_like(err[1])
        asm.scatter_add(x_q, e_q + c * res.x)
        asm.scatter_add(x_v, res.x)
        return x_q, x_v

    def implicit_euler_stage(self, q, v, h: float, a_n, stats: StepStats):
        """One implicit Euler step from ``(q, v)`` as a stage: ``(q1, v1, ok, error_estimate)``.

        ``a_n`` is the acceleration at the start [m/s^2]; ``error_estimate = (err_q, err_v)`` is
        half the difference to explicit Euler, implicit Euler's local error to leading order.
        Used as the start step of multistep methods and to retake failed steps.
        """
        q1, v1, ok = self.solve_stage(q, v, h, v, stats)
        q1[self.fixed] = q[self.fixed]
        return q1, v1, ok, (0.5 * (q1 - (q + h * v)), 0.5 * (v1 - (v + h * a_n)))

    def retake_implicit_euler(self, q, v, h: float, a_n, stats: StepStats, why: str):
        """:meth:`implicit_euler_stage` after a higher-order attempt at the step failed (order reduction).

        An unconverged BDF2 or TR-BDF2 stage is amplified by the method (on a ke = 1e7 cloth the
        energy grew from 0 to 1e7 ... 1e9 J), while L-stable implicit Euler damps what it cannot
        resolve. The failed attempt's reasons move to ``stats.extra["retaken"]`` (``why`` names it)
        and ``stats.extra["order_reduced"]`` is set.
        """
        stats.retake(f"{why}: {'; '.join(stats.failures) or 'failed'}; retaken as implicit Euler")
        stats.extra["order_reduced"] = True
        return self.implicit_euler_stage(q, v, h, a_n, stats)

    def check_step(self, stats: StepStats) -> StepStats:
        """Apply ``on_nonconvergence="raise"`` to a finished step; returns ``stats``."""
        if self.on_nonconvergence == "raise" and not stats.ok:
            raise SolverError(f"{self.name} step at dt={stats.dt:g} failed: {'; '.join(stats.failures)}")
        return stats
