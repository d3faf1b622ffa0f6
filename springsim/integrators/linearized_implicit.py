"""Linearized implicit Euler (PA2 eqs. 3-4): one Newton iteration of implicit Euler.

``[M - h^2 dF/dq - h dF/dqd] dqd = h F(q^n + h qd^n, qd^n)`` with the Jacobians at
``(q^n + h qd^n, qd^n)``; then ``qd^{n+1} = qd^n + dqd``, ``q^{n+1} = q^n + h qd^{n+1}``.

The Jacobian mode defaults to ``spd`` (the projected Jacobian of the ``minimize`` stage rule, on every
backend); ``stage_solver="pa2"`` gives PA2 eq. 3 with the exact Jacobian, as the course code.

Energy caveat of the exact Jacobian (docs/robustness.md): for a compressed spring
(``l < l0``) the exact ``-dF/dq`` has the negative transverse stiffness ``-k (l0 - l)/l``.
When ``h^2 k (l0 - l)/l`` is comparable to the mass, one unchecked linear step can move
particles far along a direction in which the real spring stiffens, and the step gains
energy; on very stiff cloth at large steps this compounds (a ke = 1e7 cloth at h = 1/30 s
gains thousands of joules). ``jacobian="spd"`` (transverse coefficient clamped at 0,
gravitational blocks projected, damping's non-symmetric position term dropped) makes
``A >= M``, so the step never follows a negative stiffness and the energy stays bounded;
it is the robust choice for stiff cloth at large steps. It clamps the negative radial
stiffness of an attracting gravitational pair too, so a close pass gets an explicit
radial kick; for close encounters use ``implicit_euler``.
"""

from __future__ import annotations

from ._implicit import ImplicitIntegrator

__all__ = ["IntegratorLinearizedImplicit"]


class IntegratorLinearizedImplicit(ImplicitIntegrator):
    """One linear solve per step (PA2 eq. 3). Options as :class:`ImplicitIntegrator`;
    ``newton_tol``, ``newton_maxiter``, ``residual_rtol`` and ``line_search`` are accepted but
    unused: the one Newton step is never repeated or shortened. A step that creates more than
    :data:`~springsim.integrators._implicit.ENERGY_GAIN` of the state's energy scale (where every force has
    a potential or dissipates) is not ``ok`` and is retaken in substeps like a failed stage."""

    name = "linearized_implicit"
    converges = False  # one plain Newton iteration

    def blowup_hint(self) -> str:
        if self.jacobian != "spd":
            return (f"with the {self.jacobian} Jacobian one unchecked linear step can gain energy on stiff "
                    f"compressed springs: try jacobian spd (--jacobian spd), a smaller time step or implicit_euler")
        return "try a smaller time step or implicit_euler"

    def advance(self, q, v, h, stats):
        """One linearized implicit Euler step: one Newton iteration of the implicit Euler stage, and the energy
        check (a step that creates energy fails in ``stats``)."""
        q1, v1, ok = self.solve_stage(q, v, h, v, stats, maxiter=1, converge=False, final_residual=False)
        gain = self.gained_energy(q, v, q1, v1) if ok else None
        if gain is not None:  # one unchecked linear step created energy: retaken in substeps
            stats.fail(f"the linear step created {gain:.3g} J")
        return q1, v1
