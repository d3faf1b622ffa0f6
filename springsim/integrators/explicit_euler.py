"""Explicit (forward) Euler: ``q1 = q + h qd``, ``qd1 = qd + h M^-1 F(q, qd)``. Order 1, baseline."""

from __future__ import annotations

from ._base import Integrator, StepStats

__all__ = ["IntegratorExplicitEuler"]


class IntegratorExplicitEuler(Integrator):
    """Explicit Euler (module docstring): one force evaluation per step, no linear solve.

    Parameters are those of :class:`~springsim.integrators.Integrator`; the implicit integrators' options are
    ignored with a warning (:func:`~springsim.integrators.make_integrator`).
    """

    name = "explicit_euler"

    def step(self, state_in, state_out, dt):
        q, qd = state_in.particle_q, state_in.particle_qd
        a = self.acceleration(q, qd)
        state_out.particle_q[...] = q + dt * qd
        state_out.particle_qd[...] = qd + dt * a
        return StepStats(dt)
