"""Explicit midpoint rule (RK2). Order 2, baseline.

``qm = q + h/2 qd``, ``qdm = qd + h/2 a(q, qd)``; ``q1 = q + h qdm``, ``qd1 = qd + h a(qm, qdm)``.
"""

from __future__ import annotations

from ._base import Integrator, StepStats

__all__ = ["IntegratorMidpoint"]


class IntegratorMidpoint(Integrator):
    """The explicit midpoint rule (module docstring): two force evaluations per step, no linear solve.

    Parameters are those of :class:`~springsim.integrators.Integrator`; the implicit integrators' options are
    ignored with a warning (:func:`~springsim.integrators.make_integrator`).
    """

    name = "midpoint"
    order = 2

    def step(self, state_in, state_out, dt):
        q, qd = state_in.particle_q, state_in.particle_qd
        a0 = self.acceleration(q, qd)
        qm = q + 0.5 * dt * qd
        qdm = qd + 0.5 * dt * a0
        a1 = self.acceleration(qm, qdm)
        state_out.particle_q[...] = q + dt * qdm
        state_out.particle_qd[...] = qd + dt * a1
        return StepStats(dt)
