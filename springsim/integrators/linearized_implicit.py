"""Linearized implicit Euler (seed eqs. 3-4): one Newton iteration of implicit Euler.

``[M - h^2 dF/dq - h dF/dqd] dqd = h F(q^n + h qd^n, qd^n)`` with the Jacobians at
``(q^n + h qd^n, qd^n)``; then ``qd^{n+1} = qd^n + dqd``, ``q^{n+1} = q^n + h qd^{n+1}``.
"""

from __future__ import annotations

from ._base import StepStats
from ._implicit import ImplicitIntegrator

__all__ = ["IntegratorLinearizedImplicit"]


class IntegratorLinearizedImplicit(ImplicitIntegrator):
    name = "linearized_implicit"

    def step(self, state_in, state_out, dt):
        stats = StepStats(dt)
        q, qd = state_in.particle_q, state_in.particle_qd
        q1, v1 = self.solve_stage(q, qd, dt, qd, stats, maxiter=1, converge=False)
        state_out.particle_q[...] = q1
        state_out.particle_qd[...] = v1
        return stats
