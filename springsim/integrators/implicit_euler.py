"""Full implicit Euler (PA2 eqs. 1-2), solved by Newton.

``qd^{n+1} = qd^n + h M^-1 F(q^{n+1}, qd^{n+1})``, ``q^{n+1} = q^n + h qd^{n+1}``; each
Newton iteration solves ``[M - h^2 dF/dq - h dF/dqd] dqd = -M (qd_i - qd^n) + h F(q^n + h qd_i, qd_i)``
starting from ``qd_0 = qd^n`` and stops when ``|dqd|_2 < newton_tol`` (and the residual
test of :class:`~springsim.integrators.ImplicitIntegrator` holds) or after ``newton_maxiter``
iterations. Order 1, L-stable (strongly damped at large ``h``).
"""

from __future__ import annotations

from ._base import StepStats
from ._implicit import ImplicitIntegrator

__all__ = ["IntegratorImplicitEuler"]


class IntegratorImplicitEuler(ImplicitIntegrator):
    name = "implicit_euler"
    unused_options = frozenset({"filter_estimates"})  # no error estimate

    def step(self, state_in, state_out, dt):
        stats = StepStats(dt)
        q, qd = state_in.particle_q, state_in.particle_qd
        q1, v1, _ = self.solve_stage(q, qd, dt, qd, stats)
        state_out.particle_q[...] = q1
        state_out.particle_qd[...] = v1
        return self.check_step(stats)
