"""Shared machinery of the implicit integrators: one Newton solver for a velocity stage.

Every implicit method here reduces each step (or stage) to finding the velocity ``v``
with::

    R(v) = c F(q_hat + c v, v) - M (v - v_hat) = 0          q = q_hat + c v

for known ``q_hat``, ``v_hat`` and coefficient ``c``. Newton's update ``dv`` solves::

    [M - c^2 dF/dq - c dF/dqd] dv = R(v_i)                  (A = M - a dF/dq - b dF/dqd)

with the Jacobians at ``(q_hat + c v_i, v_i)``. Implicit Euler is ``c = h``,
``q_hat = q^n``, ``v_hat = qd^n`` (seed eq. 1-2); one iteration from ``v_0 = qd^n`` is
linearized implicit Euler (seed eq. 3-4). The system covers free DOFs only (row and
column elimination, see :mod:`springsim.assembly.fixed`).
"""

from __future__ import annotations

import time
import warnings

import numpy as np

from ..assembly import SystemAssembler
from ..errors import SceneError, SolverError
from ..forces import JACOBIAN_MODES, eval_forces
from ..linsolve import make_linear_solver
from ._base import Integrator, StepStats

__all__ = ["ImplicitIntegrator", "NewtonConvergenceWarning"]


def _check_count(field: str, value) -> None:
    """A SceneError naming ``field`` unless ``value`` is an integer >= 1."""
    if int(value) != value or value < 1:
        raise SceneError(field, f"must be an integer >= 1, got {value}")


class NewtonConvergenceWarning(RuntimeWarning):
    """Newton stopped at its iteration limit without meeting the tolerance."""


class ImplicitIntegrator(Integrator):
    """Base of the implicit integrators.

    Parameters
    ----------
    model : Model
    solver : str or LinearSolver
        Linear solver name (see :data:`springsim.linsolve.LINEAR_SOLVERS`) or instance.
    jacobian : {"exact", "symmetric", "spd"} or None
        Jacobian mode; default ``spd`` for solvers that need SPD matrices at this size
        (:meth:`~springsim.linsolve.LinearSolver.needs_spd_for`), else ``exact``.
    newton_tol : float
        Stop when ``|dv|_2 < newton_tol`` [m/s] (seed: 1e-5).
    newton_maxiter : int or None
        Iteration limit; default the class's ``default_newton_maxiter``: the seed's 5 for
        implicit Euler, 50 for BDF2 and TR-BDF2. These retake a step whose stage did not
        converge with implicit Euler, so their limit must let Newton finish: on the 16 x 16
        benchmark cloth at h = 1/60 s (0.5 s) 5 iterations leave errors of 0.045 m (BDF2)
        and 0.034 m (TR-BDF2), 20 give 0.020 m and 0.0057 m in less CPU time; on the 64 x 64
        issue-7 cloth (1.17 s) BDF2 with 20 misses the limit on 4 of 70 steps and ends
        0.086 m off, with 50 on none and 0.018 m off (docs/accuracy.md).
    on_nonconvergence : {"warn", "raise", "ignore"}
        What to do when Newton hits its limit.
    line_search : bool
        Backtrack the Newton update (halving, down to ``min_step``) until the residual
        norm decreases (Armijo). Full steps are taken near the solution, so quadratic
        convergence is kept; far from it (stiff cloth at large ``h``) plain Newton
        diverges. Only used when Newton runs to convergence (``converge=True``), so
        linearized implicit Euler is seed eq. 3 exactly.
    solver_options : dict, optional
        Passed to the linear solver's constructor (e.g. ``{"rtol": 1e-6}``).
    escalate_jacobian : bool
        When Newton with the ``spd`` or ``symmetric`` Jacobian reaches its limit, continue the
        stage from its last iterate with the ``exact`` Jacobian (up to the limit again) before
        reporting non-convergence; counted in ``StepStats.extra["jacobian_escalations"]``.
        The projected matrices only slow Newton to linear convergence where they differ from
        the true Jacobian (compressed springs), which is where it misses its limit: TR-BDF2
        at h = 1/60 s on the 64 x 64 issue-7 cloth with ``auto`` (``spd``, AMG-CG) missed it on
        3 of 70 steps, retook them as implicit Euler and ended 0.075 m off against 0.013 m
        with the exact Jacobian (docs/accuracy.md). Only stages that run Newton to
        convergence escalate, so linearized implicit Euler (one plain iteration) is unaffected.
    escalate_after : int or None
        Iterations with the projected Jacobian before escalating (default: the Newton limit).
    """

    implicit = True
    #: Newton iteration limit when none is given
    default_newton_maxiter = 5

    def __init__(self, model, *, solver="direct", jacobian: str | None = None, newton_tol: float = 1e-5,
                 newton_maxiter: int | None = None, on_nonconvergence: str = "warn", solver_options: dict | None = None,
                 line_search: bool = True, min_step: float = 1.0 / 64, escalate_jacobian: bool = True,
                 escalate_after: int | None = None, terms=None):
        super().__init__(model, terms=terms)
        self.solver = make_linear_solver(solver, **(solver_options or {}))
        if jacobian is None:
            jacobian = "spd" if self.solver.needs_spd_for(3 * model.free_count) else "exact"
        if jacobian not in JACOBIAN_MODES:
            raise SceneError("solver.jacobian", f"must be one of {', '.join(JACOBIAN_MODES)}, got {jacobian!r}")
        if not newton_tol > 0:
            raise SceneError("solver.newton_tol", f"must be > 0, got {newton_tol}")
        if newton_maxiter is None:
            newton_maxiter = self.default_newton_maxiter
        _check_count("solver.newton_maxiter", newton_maxiter)
        if on_nonconvergence not in ("warn", "raise", "ignore"):
            raise ValueError(f"on_nonconvergence must be warn, raise or ignore, got {on_nonconvergence!r}")
        self.jacobian = jacobian
        self.newton_tol = float(newton_tol)
        self.newton_maxiter = int(newton_maxiter)
        self.on_nonconvergence = on_nonconvergence
        self.line_search = bool(line_search)
        self.min_step = float(min_step)
        self.escalate_jacobian = bool(escalate_jacobian)
        if escalate_after is not None:
            _check_count("solver.escalate_after", escalate_after)
        self.escalate_after = None if escalate_after is None else int(escalate_after)
        self.assembler = SystemAssembler(model, self.terms)
        self._mass = model.particle_mass[:, None]
        self._warm: np.ndarray | None = None

    def reset(self):
        self._warm = None

    # -- the Newton stage solver -----------------------------------------------------------
    def solve_stage(self, q_hat: np.ndarray, v_hat: np.ndarray, c: float, v0: np.ndarray, stats: StepStats,
                    *, maxiter: int | None = None, converge: bool = True):
        """Solve ``c F(q_hat + c v, v) = M (v - v_hat)`` for ``v`` by Newton from ``v0``.

        Parameters
        ----------
        q_hat, v_hat, v0 : ndarray (N, 3)
        c : float
            Stage coefficient [s].
        stats : StepStats
            Accumulates iterations, times and norms.
        maxiter : int, optional
            Iteration limit (default ``newton_maxiter``); 1 gives the linearized method.
        converge : bool
            Apply the stopping rule, line search and non-convergence report (False: exactly
            ``maxiter`` plain Newton iterations).

        Returns
        -------
        q, v : ndarray (N, 3)
        """
        maxiter = self.newton_maxiter if maxiter is None else maxiter
        v = np.array(v0, dtype=np.float64)
        v[self.fixed] = 0.0
        escalate = converge and self.escalate_jacobian and self.jacobian != "exact"
        first = min(maxiter, self.escalate_after) if escalate and self.escalate_after is not None else maxiter
        q, v, step, rnorm, converged = self._newton(q_hat, v_hat, c, v, stats, first, converge, self.jacobian)
        if escalate and not converged and np.isfinite(rnorm):  # a non-finite v makes rnorm non-finite
            # the projected Jacobian slows Newton to linear convergence where it differs from the
            # exact one (compressed springs); finish the stage with the exact Jacobian
            stats.extra["jacobian_escalations"] = stats.extra.get("jacobian_escalations", 0) + 1
            q, v, step, rnorm, converged = self._newton(q_hat, v_hat, c, v, stats, maxiter, converge, "exact")
        stats.newton_step_norm = step
        stats.residual_norm = rnorm
        if converge:
            stats.newton_converged = converged and bool(np.isfinite(rnorm))
            if not stats.newton_converged:
                self._report_nonconvergence(stats, maxiter)
        return q, v

    def _newton(self, q_hat, v_hat, c, v, stats, maxiter, converge, mode):
        """Newton iterations of :meth:`solve_stage` from ``v`` with the Jacobian ``mode``:
        ``(q, v, |dv|, |R|, converged)``."""
        asm = self.assembler
        f = np.empty_like(v)
        q = q_hat + c * v
        R = self._residual(q, v, v_hat, c, f, stats)
        rnorm = float(np.linalg.norm(asm.gather(R)))
        converged = False
        step = 0.0
        for it in range(maxiter):
            A = asm.assemble(q, v, c * c, c, mode)
            stats.assembly_s += asm.last_time_s
            dv = self._linear_solve(A, asm.gather(R), stats, first=(it == 0)).x
            step = float(np.linalg.norm(dv))
            stats.newton_iterations += 1
            # Backtracking on |R| (Armijo on the merit 1/2 |R|^2): the trial residual is
            # the next iteration's residual, so a full step costs nothing extra.
            alpha = 1.0
            while True:
                v_try = v.copy()
                asm.scatter_add(v_try, dv, alpha)
                q_try = q_hat + c * v_try
                R_try = self._residual(q_try, v_try, v_hat, c, f, stats)
                rn_try = float(np.linalg.norm(asm.gather(R_try)))
                if (not (converge and self.line_search) or rn_try <= (1.0 - 1e-4 * alpha) * rnorm
                        or alpha <= self.min_step or not np.isfinite(rnorm)):
                    break
                alpha *= 0.5
            stats.extra["min_line_search_step"] = min(alpha, stats.extra.get("min_line_search_step", 1.0))
            v, q, R, rnorm = v_try, q_try, R_try, rn_try
            if not np.isfinite(step):
                break
            if converge and step < self.newton_tol:
                converged = True
                break
        return q, v, step, rnorm, converged

    def _residual(self, q, v, v_hat, c, f, stats):
        t0 = time.perf_counter()
        eval_forces(self.terms, q, v, out=f)
        R = c * f - self._mass * (v - v_hat)
        stats.force_s += time.perf_counter() - t0
        return R

    def _linear_solve(self, A, b, stats, first: bool):
        x0 = self._warm if (first and self._warm is not None and self._warm.shape == b.shape) else None
        res = self.solver.solve(A, b, x0=x0)
        stats.solve_s += res.time_s
        stats.linear_iterations += res.iterations
        stats.linear_solves += 1
        stats.linear_residual = max(stats.linear_residual, res.residual)
        if res.fallback:
            stats.fallbacks.append(f"{res.method}: {res.fallback}")
        if not np.all(np.isfinite(res.x)):
            raise SolverError(f"linear solver {res.method!r} failed: {res.fallback or 'non-finite solution'}")
        if first:
            self._warm = res.x
        return res

    def _report_nonconvergence(self, stats, maxiter):
        if self.on_nonconvergence == "raise":
            raise SolverError(f"Newton did not converge in {maxiter} iterations at dt={stats.dt:g}: "
                              f"|dv|={stats.newton_step_norm:.3e} (tol {self.newton_tol:g}), "
                              f"residual {stats.residual_norm:.3e}")
        if self.on_nonconvergence == "warn":
            # a constant message, so the default warning filter reports it once per run;
            # the numbers are in StepStats (newton_converged, newton_step_norm, residual_norm)
            warnings.warn(f"{type(self).name}: Newton stopped at its iteration limit ({maxiter}) without "
                          f"meeting |dv| < {self.newton_tol:g}; see StepStats.newton_converged",
                          NewtonConvergenceWarning, stacklevel=4)
