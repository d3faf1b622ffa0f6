"""Symplectic (semi-implicit) Euler: ``qd1 = qd + h M^-1 F(q, qd)``, ``q1 = q + h qd1``. Order 1.

When the spring force pass is compiled (``force_kernels``, :mod:`springsim._runtime.accel`), the update after the
force evaluation is one compiled pass as well
(:func:`springsim.integrators._numba_kernels.symplectic_euler_update`), with the same operations in the
same order as the numpy path (the tests compare the two).
"""

from __future__ import annotations

import numpy as np

from ._base import Integrator, StepStats

__all__ = ["IntegratorSymplecticEuler"]


class IntegratorSymplecticEuler(Integrator):
    """Symplectic Euler (module docstring): one force evaluation per step, no linear solve.

    Parameters
    ----------
    model : Model
        The model.
    **kw
        Keyword options of :class:`~springsim.integrators.Integrator` (``system``, ``terms``,
        ``force_kernels``); the implicit integrators' options are ignored with a warning
        (:func:`~springsim.integrators.make_integrator`).
    """

    name = "symplectic_euler"

    def __init__(self, model, **kw):
        super().__init__(model, **kw)
        self._update = None
        if any(getattr(t, "kernels", None) == "numba" for t in self.terms):  # numba imports: the forces did
            from ._numba_kernels import symplectic_euler_update

            self._update = symplectic_euler_update
            self._inv_mass_1d = np.ascontiguousarray(self._inv_mass[:, 0])
            self._fixed_mask = np.zeros(self._inv_mass.shape[0], dtype=bool)
            self._fixed_mask[self.fixed] = True

    def step(self, state_in, state_out, dt):
        q, qd = state_in.particle_q, state_in.particle_qd
        if self._update is not None:
            f = self.system.forces(q, qd, self._f)
            self._update(q, qd, f, self._inv_mass_1d, self._fixed_mask, float(dt), state_out.particle_q,
                         state_out.particle_qd)
            return StepStats(dt)
        a = self.acceleration(q, qd)  # a buffer of the integrator's, reused as scratch below
        qd1 = state_out.particle_qd
        np.add(qd, np.multiply(a, dt, out=a), out=qd1)
        np.add(q, np.multiply(qd1, dt, out=a), out=state_out.particle_q)
        return StepStats(dt)
