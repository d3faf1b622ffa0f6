"""Time integrators of the distributed backend, on the owned parts of the state.

The same methods and equations as the serial integrators (:mod:`springsim.integrators`): explicit Euler,
symplectic Euler and the midpoint rule; linearized implicit Euler (PA2 eqs. 3-4, one Newton iteration) and
implicit Euler (PA2 eqs. 1-2) by Newton with the serial stopping rule (update norm below ``newton_tol``
*and* residual ratio below ``residual_rtol``, :class:`springsim.integrators.ImplicitIntegrator`) and the
same Armijo backtracking line search. Every norm is global (an MPI reduction), so every rank takes the
same decisions. A state is the pair of owned arrays ``(q, v)``, each (n_own, 3).

What the serial path has and this one does not: BDF2 and TR-BDF2 (their stage solver works on the full
state; not ported), the escalation from the ``spd`` to the ``exact`` Jacobian (GAMG with CG needs the
symmetric ``spd`` matrix; the nonsymmetric exact Jacobian with damping did not converge with GMRES + GAMG
on the benchmark cloth). The Jacobian mode defaults to ``spd``.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

from ..errors import SceneError, SolverError
from ..integrators import StepStats
from ..integrators._implicit import StageForcing, backtrack, record_linear_solve, report_stage, set_newton_options

__all__ = ["DISTRIBUTED_INTEGRATORS", "DistributedIntegrator", "DistributedExplicitEuler",
           "DistributedSymplecticEuler", "DistributedMidpoint", "DistributedLinearizedImplicit",
           "DistributedImplicitEuler", "make_distributed_integrator"]


class DistributedIntegrator(ABC):
    """Base: :meth:`step` ``(q, v, dt) -> (q1, v1, StepStats)`` over the owned arrays of ``system``."""

    name = ""
    implicit = False

    def __init__(self, system):
        self.system = system
        self.inv_mass = (1.0 / system.mass)[:, None]

    def acceleration(self, q, v):
        return self.system.forces(q, v) * self.inv_mass

    @abstractmethod
    def step(self, q, v, dt):
        """Advance the owned state ``(q, v)`` by ``dt``: ``(q1, v1, StepStats)``."""


class DistributedExplicitEuler(DistributedIntegrator):
    """``q1 = q + h v``, ``v1 = v + h a(q, v)``."""

    name = "explicit_euler"

    def step(self, q, v, dt):
        a = self.acceleration(q, v)
        return q + dt * v, v + dt * a, StepStats(dt)


class DistributedSymplecticEuler(DistributedIntegrator):
    """``v1 = v + h a(q, v)``, ``q1 = q + h v1``."""

    name = "symplectic_euler"

    def step(self, q, v, dt):
        v1 = v + dt * self.acceleration(q, v)
        return q + dt * v1, v1, StepStats(dt)


class DistributedMidpoint(DistributedIntegrator):
    """Explicit midpoint rule, as :class:`springsim.integrators.IntegratorMidpoint`."""

    name = "midpoint"

    def step(self, q, v, dt):
        a0 = self.acceleration(q, v)
        qm, vm = q + 0.5 * dt * v, v + 0.5 * dt * a0
        a1 = self.acceleration(qm, vm)
        return q + dt * vm, v + dt * a1, StepStats(dt)


class DistributedImplicitEuler(DistributedIntegrator):
    """Implicit Euler by Newton (options as :class:`springsim.integrators.ImplicitIntegrator`)."""

    name = "implicit_euler"
    implicit = True
    converge = True

    def __init__(self, system, *, jacobian: str | None = None, newton_tol: float = 1e-5,
                 newton_maxiter: int | None = None, residual_rtol: float = 1e-3, line_search: bool = True,
                 min_step: float = 1.0 / 64, on_nonconvergence: str = "warn", forcing: str = "fixed",
                 forcing_max: float = 0.1):
        super().__init__(system)
        jacobian = "spd" if jacobian is None else jacobian
        newton_maxiter = 5 if newton_maxiter is None else newton_maxiter
        set_newton_options(self, jacobian=jacobian, newton_tol=newton_tol, newton_maxiter=newton_maxiter,
                           residual_rtol=residual_rtol, on_nonconvergence=on_nonconvergence, line_search=line_search,
                           min_step=min_step, forcing=forcing, forcing_max=forcing_max)
        self.mass = system.mass[:, None]
        self._mass_norm = float(np.sqrt(3.0) * np.sqrt(system.mpi.allreduce(float(np.sum(system.mass ** 2)))))
        self._warm = None

    def _residual(self, q, v, v_hat, c):
        sysm = self.system
        cf = c * sysm.forces(q, v)
        mdv = self.mass * (v - v_hat)
        R = cf - mdv
        rnorm = sysm.norm(R)
        scale = sysm.norm(cf) + sysm.norm(mdv) + self.newton_tol * self._mass_norm
        return R, rnorm, (rnorm / scale if scale > 0 else 0.0)

    def solve_stage(self, q_hat, v_hat, c, v0, stats: StepStats, *, maxiter: int, converge: bool):
        """Newton for ``c F(q_hat + c v, v) = M (v - v_hat)`` from ``v0``: ``(q, v, ok)`` (as the serial one)."""
        sysm = self.system
        v = np.array(v0, dtype=np.float64)
        q = q_hat + c * v
        R, rnorm, ratio = self._residual(q, v, v_hat, c)
        converged, step, failed = False, 0.0, []
        # global norms and residuals: every rank computes the same forcing terms and decisions
        forcing = StageForcing(self.forcing if converge else "fixed", eta_max=self.forcing_max, floor=sysm.rtol)
        for it in range(maxiter):
            sysm.assemble(q, v, c * c, c, self.jacobian, exchange=False)  # the residual exchanged (q, v)
            stats.precision_loss = max(stats.precision_loss, sysm.precision_loss())
            res = sysm.solve(R, x0=self._warm if it == 0 else None, rtol=forcing.rtol(rnorm))
            failure = record_linear_solve(stats, res, sysm.all_finite(res.x))
            if failure:
                failed.append(failure)
            if it == 0:
                self._warm = res.x
            dv = res.x
            step = sysm.norm(dv)
            stats.newton_iterations += 1
            def trial(alpha, v=v, dv=dv):
                v_try = v + alpha * dv
                q_try = q_hat + c * v_try
                return (v_try, q_try, *self._residual(q_try, v_try, v_hat, c))

            if not converge and it == maxiter - 1:  # nothing judges the last plain iterate (as the serial stage)
                v = v + dv
                q, R, rnorm, ratio = q_hat + c * v, None, float("nan"), float("nan")
            else:
                _, (v, q, R, rnorm, ratio) = backtrack(trial, rnorm, enabled=converge and self.line_search,
                                                       min_step=self.min_step)
            if not np.isfinite(step):
                break
            if converge and step < self.newton_tol and ratio <= self.residual_rtol and forcing.certified(res.residual):
                converged = True
                break
        ok = report_stage(stats, converge=converge, converged=converged, failed=failed, maxiter=maxiter, step=step,
                          rnorm=rnorm, ratio=ratio, newton_tol=self.newton_tol, residual_rtol=self.residual_rtol)
        return q, v, ok

    def step(self, q, v, dt):
        stats = StepStats(dt)
        q1, v1, _ = self.solve_stage(q, v, dt, v, stats, maxiter=self.newton_maxiter, converge=self.converge)
        if self.on_nonconvergence == "raise" and not stats.ok:
            raise SolverError(f"{self.name} step at dt={dt:g} failed: {'; '.join(stats.failures)}")
        return q1, v1, stats


class DistributedLinearizedImplicit(DistributedImplicitEuler):
    """One Newton iteration of implicit Euler (PA2 eq. 3), never checked, repeated or shortened."""

    name = "linearized_implicit"
    converge = False

    def step(self, q, v, dt):
        stats = StepStats(dt)
        q1, v1, _ = self.solve_stage(q, v, dt, v, stats, maxiter=1, converge=False)
        if self.on_nonconvergence == "raise" and not stats.ok:
            raise SolverError(f"{self.name} step at dt={dt:g} failed: {'; '.join(stats.failures)}")
        return q1, v1, stats


#: Registry of the distributed integrators (names as in :data:`springsim.integrators.INTEGRATORS`).
DISTRIBUTED_INTEGRATORS = {c.name: c for c in (DistributedExplicitEuler, DistributedSymplecticEuler,
                                               DistributedMidpoint, DistributedLinearizedImplicit,
                                               DistributedImplicitEuler)}


def make_distributed_integrator(name: str, system, **options):
    """The distributed integrator ``name`` over ``system``; a SceneError naming ``integrator`` if it has none."""
    cls = DISTRIBUTED_INTEGRATORS.get(name)
    if cls is None:
        raise SceneError("integrator", f"{name!r:.60} has no distributed version; the petsc backend runs "
                                       f"{', '.join(DISTRIBUTED_INTEGRATORS)}")
    if not cls.implicit:
        return cls(system)
    return cls(system, **options)
