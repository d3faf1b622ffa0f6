"""ROS2, the two-stage second-order L-stable Rosenbrock-W method (Verwer, Spee, Blom and Hundsdorfer 1999).

For the first-order system ``y' = f(y)``, ``y = (q, qd)``, ``f = (qd, M^-1 F(q, qd))``, with ``W`` the
Jacobian ``J = [[0, I], [M^-1 K, M^-1 D]]`` (``K = dF/dq``, ``D = dF/dqd``) at the step's start, or an
approximation of it::

    (I - gamma h W) k1 = h f(y_n)
    (I - gamma h W) k2 = h f(y_n + k1) - 2 k1
    y_{n+1} = y_n + 3/2 k1 + 1/2 k2

There is no Newton iteration: a step is one matrix, two force evaluations and two linear solves with that one
matrix (the direct solver factors it once, AMG builds one hierarchy). The method is second order for *any*
``W`` and any ``gamma`` (a W-method; Verwer et al. 1999, sec. 2), so the ``spd`` Jacobian of the CG solvers
keeps the order. With ``W = J`` its stability function is ``R(z) = (1 + (1 - 2 gamma) z + (gamma^2 - 2 gamma +
1/2) z^2) / (1 - gamma z)^2``; both roots ``gamma = 1 -+ 1/sqrt(2)`` of the ``z^2`` coefficient make it
L-stable (``R(inf) = 0``; A-stable for ``gamma >= 1/4``). Verwer et al. take ``gamma = 1 + 1/sqrt(2)``, so that
``R >= 0`` on the negative axis, and so does this module. The other root, TR-BDF2's ``1 - 1/sqrt(2)``, has a
smaller error constant (5 ... 10 times smaller errors on the 5 x 5 benchmark cloth at ke = 1e3), but its stage
point ``y_n + k1`` overshoots stiff components by ``1 - 1/gamma = -2.4`` and the stiff springs' nonlinearity then
feeds the second stage. With ``1 + 1/sqrt(2)`` the stage point keeps ``0.41`` of a stiff component: an undamped
1e8 N/m spring on 1 kg at h = 0.1 s (a hard case of ``tests/verification/test_hard_cases.py``) keeps its energy
with it and gains energy with the other root (blowing up with the ``exact`` Jacobian), and so does the 32 x 32 benchmark cloth at h = 1/240 s with the ``spd``
Jacobian (stable over 1.2 s against a blow-up after 66 steps). With the ``exact`` Jacobian both blow up on that
cloth at 1/240 s; at 1/960 s the other root is 1.8 cm off against 3.5 cm (BENCHMARKS.md): robustness costs
accuracy here.

Where it stands (BENCHMARKS.md, "ROS2"): a step costs about what a linearized implicit Euler step costs, but on
the stiff benchmark cloth the method is far from its asymptotic regime (stage order 1, the usual order reduction
of Rosenbrock methods on stiff problems): at ke = 1e4, n = 32, it blows up at h = 1/240 s and is 3.5 cm off at
1/960 s, where TR-BDF2 is within 1 cm at 1/120 s for less CPU. It suits mildly stiff scenes at small steps, where
no Newton iteration is needed; it is no remedy for stiff cloth at animation steps.

Second-order structure. With ``c = gamma h``, eliminating the position block of ``(I - c W) k = r``,
``r = (r_q, r_v)``, leaves Newton's matrix of the implicit integrators::

    (M - c^2 K - c D) k_v = M r_v + c K r_q,      k_q = r_q + c k_v

over the free DOFs (fixed particles have ``k = 0``). The product ``K r_q`` uses the ``K`` of the matrix,
assembled from the same Jacobian evaluation (:meth:`~springsim.assembly.SystemAssembler.assemble`, ``also``):
only then is the solve an exact solve with ``I - c W``, which the order conditions of a W-method assume.

Error estimate. The embedded solution ``y_hat = y_n + k1`` (linearly implicit Euler with coefficient ``c``) is
first order; ``err = y_hat - y_{n+1} = -(k1 + k2)/2`` estimates *its* local error (Verwer et al. 1999), so the
step-size controller uses the exponent ``1/2`` (:attr:`estimate_order` = 1) and the step keeps the
second-order result (local extrapolation). In stiff components ``err`` tends to ``(2 - 1/gamma)/(2 gamma) y
= 0.41 y`` however well ``R`` damps them, so it is passed through Shampine's filter ``(I - c W)^-1 err`` by default (one
more solve with the step's matrix; with the direct solver a substitution with the kept factors), computed
only while :attr:`estimating` is set.

Linear solves are checked: a solve that missed its criterion fails the step (nothing else judges it, as in
linearized implicit Euler), a non-finite one ends it with :class:`~springsim.errors.SolverError`. Energy
caveat: nothing corrects the linearisation, so on stiff cloth at large steps a step can gain energy with either
Jacobian mode (a ke = 1e7 cloth at h = 1/30 s, the benchmark cloth at h = 0.1 s: the drivers stop with the
energy-bound error; pinned in ``tests/verification/test_rosenbrock.py`` and ``test_hard_cases.py``). Use a Newton
method there.
"""

from __future__ import annotations

import math

import numpy as np

from ..forces import eval_forces
from ._base import StepStats
from ._implicit import ImplicitIntegrator, record_linear_solve, report_stage

__all__ = ["IntegratorROS2", "GAMMA"]

#: ROS2's diagonal coefficient (Verwer et al. 1999; module docstring): L-stable, and R(z) >= 0 for real z <= 0.
GAMMA = 1.0 + 1.0 / math.sqrt(2.0)


class IntegratorROS2(ImplicitIntegrator):
    """ROS2 (module docstring): two linear solves with one matrix per step, no Newton iteration.

    Parameters are those of :class:`~springsim.integrators.ImplicitIntegrator`; the Newton options are accepted
    but unused. ``filter_estimates`` (default True) filters the error estimate, which is computed only while
    :attr:`estimating` is set when filtered.

    Attributes
    ----------
    error_estimate : tuple of ndarray (N, 3) or None
        ``(err_q [m], err_v [m/s])`` of the embedded first-order solution of the last step.
    """

    name = "ros2"
    order = 2
    estimate_order = 1
    has_error_estimate = True
    unused_options = frozenset({"newton_tol", "newton_maxiter", "residual_rtol", "line_search", "min_step",
                                "escalate_jacobian", "escalate_after", "forcing", "forcing_max"})

    def __init__(self, model, **options):
        super().__init__(model, **options)
        self._k_matrix = self.assembler.new_matrix()  # M - K at the step's start, for the products K r_q
        self._f0 = np.zeros((model.particle_count, 3))
        self._f1 = np.zeros((model.particle_count, 3))
        self._warm_stages: list = [None, None]

    def reset(self):
        super().reset()
        self._warm_stages = [None, None]

    def blowup_hint(self) -> str:
        return "a linearly implicit step can gain energy on stiff springs: try a smaller time step or tr_bdf2"

    def _solve_w(self, A, rq: np.ndarray, mrv: np.ndarray, c: float, stats: StepStats, failures: list,
                 warm: int | None = None):
        """``(k_q, k_v)`` (free DOF vectors) with ``(I - c W) k = (r_q, r_v)``, given ``r_q`` and ``M r_v``; the
        failure of its linear solve is appended to ``failures``."""
        k_product = self._mass_dofs * rq - self._k_matrix @ rq  # K r_q
        x0 = self._warm_stages[warm] if warm is not None else None
        if x0 is not None and x0.shape != rq.shape:
            x0 = None
        res = self.solver.solve(A, mrv + c * k_product, x0=x0)
        failure = record_linear_solve(stats, res, bool(np.all(np.isfinite(res.x))))
        if failure:
            failures.append(failure)
        if warm is not None:
            self._warm_stages[warm] = res.x
        return rq + c * res.x, res.x

    def step(self, state_in, state_out, dt):
        stats = StepStats(dt)
        h = float(dt)
        c = GAMMA * h
        asm = self.assembler
        q, v = state_in.particle_q, state_in.particle_qd
        m = self._mass_dofs
        A = asm.assemble(q, v, c * c, c, self.jacobian, also=(1.0, 0.0, self._k_matrix))
        stats.assembly_s += asm.last_time_s
        stats.precision_loss = max(stats.precision_loss, asm.precision_loss(A))
        failures: list[str] = []
        vf = asm.gather(v)
        eval_forces(self.terms, q, v, out=self._f0)
        with self.solver.repeated_solves():  # both stages and the filter solve with A: factored once
            # stage 1: r = h f(y_n)
            k1q, k1v = self._solve_w(A, h * vf, h * asm.gather(self._f0), c, stats, failures, warm=0)
            # stage 2: r = h f(y_n + k1) - 2 k1
            q_s, v_s = q.copy(), v.copy()
            asm.scatter_add(q_s, k1q)
            asm.scatter_add(v_s, k1v)
            eval_forces(self.terms, q_s, v_s, out=self._f1)
            k2q, k2v = self._solve_w(A, h * (vf + k1v) - 2.0 * k1q, h * asm.gather(self._f1) - 2.0 * m * k1v, c,
                                     stats, failures, warm=1)
            q1, v1 = q.copy(), np.zeros_like(v)  # fixed particles: at rest where they are
            asm.scatter_add(q1, 1.5 * k1q + 0.5 * k2q)
            asm.scatter_add(v1, vf + 1.5 * k1v + 0.5 * k2v)
            # no Newton update to report (0.0, as for explicit methods) and no residual (NaN)
            report_stage(stats, converge=False, converged=True, failed=failures, maxiter=1, step=0.0,
                         rnorm=float("nan"), ratio=float("nan"), newton_tol=self.newton_tol,
                         residual_rtol=self.residual_rtol)
            self.error_estimate = None
            if self.estimating:  # set by default when the estimate is free (unfiltered), else by adaptive runs
                e_q, e_v = -0.5 * (k1q + k2q), -0.5 * (k1v + k2v)
                if self.filter_estimates and stats.ok:
                    e_q, e_v = self._filtered(A, e_q, e_v, c, stats)
                self.error_estimate = (self._full(e_q), self._full(e_v))
        state_out.particle_q[...] = q1
        state_out.particle_qd[...] = v1
        return self.check_step(stats)

    def _filtered(self, A, e_q, e_v, c, stats):
        """Shampine's filter ``(I - c W)^-1 (e_q, e_v)`` with the step's matrix; the estimate unchanged (counted in
        ``stats.extra["unfiltered_estimates"]``) when the solve misses its criterion or is not finite."""
        res = self.solver.solve(A, self._mass_dofs * e_v + c * (self._mass_dofs * e_q - self._k_matrix @ e_q))
        record_linear_solve(stats, res, True)  # a failed filter solve leaves the estimate raw, it does not end the step
        if not res.converged or not np.all(np.isfinite(res.x)):
            stats.extra["unfiltered_estimates"] = stats.extra.get("unfiltered_estimates", 0) + 1
            return e_q, e_v
        return e_q + c * res.x, res.x

    def _full(self, x: np.ndarray) -> np.ndarray:
        """An (N, 3) array from a free DOF vector, zero on fixed particles."""
        out = np.zeros((self.model.particle_count, 3))
        self.assembler.scatter_add(out, x)
        return out
