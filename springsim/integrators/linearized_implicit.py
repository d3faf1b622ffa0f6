"""Linearized implicit Euler (seed eqs. 3-4): one Newton iteration of implicit Euler.

``[M - h^2 dF/dq - h dF/dqd] dqd = h F(q^n + h qd^n, qd^n)`` with the Jacobians at
``(q^n + h qd^n, qd^n)``; then ``qd^{n+1} = qd^n + dqd``, ``q^{n+1} = q^n + h qd^{n+1}``.

Default Jacobian: ``spd``, with every linear solver
---------------------------------------------------
The other implicit integrators default to ``exact`` unless the solver needs SPD matrices: they iterate
Newton, so the exact Jacobian buys quadratic convergence, and their line search rejects updates
that increase the residual. Here there is exactly one linear step, with no convergence to gain
and nothing to catch a bad step. For a compressed spring (``l < l0``) the exact ``-dF/dq`` has
the negative transverse stiffness ``-k (l0 - l)/l`` (the linearised buckling mode). When
``h^2 k (l0 - l)/l`` is comparable to the mass, ``A = M - h^2 dF/dq`` is near-singular or
indefinite. One solve then moves particles far along a direction in which the real spring
stiffens, because the transverse motion stretches it. On the undamped ke = 1e7 cloth at
h = 1/30 s, the exact Jacobian gains 14 J at step 3, while ``A`` is still positive definite
(its smallest eigenvalue is 0.002, against a particle mass of 0.028). The gain grows to
2.6e12 J within 300 steps. ``spd`` (transverse coefficient clamped at 0, gravitational blocks
projected, damping's non-symmetric position term dropped) makes ``A >= M``: the step never
follows a negative stiffness, and the energy stays bounded (max +4.86 J in 1000 steps, from the
second-order stretch of the first step, see ``docs/robustness.md``, case 1). With one step, no
quadratic convergence is lost.

``jacobian="exact"`` (or ``"symmetric"``) is still available and is exactly seed eq. 3 with
the true Jacobian. It is accurate when ``h^2 k |l - l0| / l << m`` (e.g. the same cloth at
h = 1/60 s), but it is not energy-stable for stiff compressed springs at large steps.
Trade-off: ``spd`` also clamps the negative radial stiffness of an attracting gravitational pair,
so a close pass gets an explicit radial kick (``exact`` is bounded there). For close encounters
use ``implicit_euler``.
"""

from __future__ import annotations

from ._base import StepStats
from ._implicit import ImplicitIntegrator

__all__ = ["IntegratorLinearizedImplicit"]


class IntegratorLinearizedImplicit(ImplicitIntegrator):
    """One linear solve per step (seed eq. 3). Options as :class:`ImplicitIntegrator`.

    Parameters
    ----------
    jacobian : {"exact", "symmetric", "spd"} or None
        Default (None): ``spd`` with every solver (see the module docstring). ``newton_tol``,
        ``newton_maxiter`` and ``line_search`` are accepted but unused: the one Newton step
        is never checked, repeated or shortened.
    """

    name = "linearized_implicit"

    def __init__(self, model, *, jacobian: str | None = None, **options):
        super().__init__(model, jacobian="spd" if jacobian is None else jacobian, **options)

    def step(self, state_in, state_out, dt):
        stats = StepStats(dt)
        q, qd = state_in.particle_q, state_in.particle_qd
        q1, v1 = self.solve_stage(q, qd, dt, qd, stats, maxiter=1, converge=False)
        state_out.particle_q[...] = q1
        state_out.particle_qd[...] = v1
        return stats
