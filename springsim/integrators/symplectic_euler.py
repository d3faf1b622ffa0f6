"""Symplectic (semi-implicit) Euler: ``qd1 = qd + h M^-1 F(q, qd)``, ``q1 = q + h qd1``. Order 1."""

from __future__ import annotations

import numpy as np

from ._base import Integrator, StepStats

__all__ = ["IntegratorSymplecticEuler"]


class IntegratorSymplecticEuler(Integrator):
    name = "symplectic_euler"

    def step(self, state_in, state_out, dt):
        q, qd = state_in.particle_q, state_in.particle_qd
        a = self.acceleration(q, qd)  # a buffer of the integrator's, reused as scratch below
        qd1 = state_out.particle_qd
        np.add(qd, np.multiply(a, dt, out=a), out=qd1)
        np.add(q, np.multiply(qd1, dt, out=a), out=state_out.particle_q)
        return StepStats(dt)
