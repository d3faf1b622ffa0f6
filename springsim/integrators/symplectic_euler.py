"""Symplectic (semi-implicit) Euler: ``qd1 = qd + h M^-1 F(q, qd)``, ``q1 = q + h qd1``. Order 1."""

from __future__ import annotations

from ._base import Integrator, StepStats

__all__ = ["IntegratorSymplecticEuler"]


class IntegratorSymplecticEuler(Integrator):
    name = "symplectic_euler"

    def step(self, state_in, state_out, dt):
        q, qd = state_in.particle_q, state_in.particle_qd
        a = self.acceleration(q, qd)
        qd1 = qd + dt * a
        state_out.particle_q[...] = q + dt * qd1
        state_out.particle_qd[...] = qd1
        return StepStats(dt)
