"""Constant gravity field: ``F_i = m_i g`` (PA2 sec. 5.1). No Jacobian."""

from __future__ import annotations

import numpy as np

from ._base import ForceTerm

__all__ = ["ForceGravity"]


class ForceGravity(ForceTerm):
    """Uniform gravity ``g`` [m/s^2] (3-vector) acting on masses ``mass`` (N,).

    Parameters
    ----------
    mass : array_like, shape (N,)
        Particle masses [kg].
    g : array_like, shape (3,)
        Gravitational acceleration [m/s^2].
    """

    name = "gravity"
    conservative = True
    external = True

    def __init__(self, mass, g):
        self.mass = np.asarray(mass, dtype=np.float64)
        self.g = np.asarray(g, dtype=np.float64)
        self._force = self.mass[:, None] * self.g + 0.0  # + 0.0: no -0.0 components (the sum starts from it)
        self._force.setflags(write=False)  # handed out by constant_force

    @classmethod
    def from_model(cls, model, *, skip_fixed=True, kernels="auto"):
        if model.gravity == 0.0 or model.particle_count == 0:
            return None
        return cls(model.particle_mass, model.gravity_vector)

    @classmethod
    def naive_force(cls, model, q, qd):
        return model.particle_mass[:, None] * model.gravity_vector[None, :]

    def eval_force(self, q, qd, f_out, *, damping_geometry=None):
        f_out += self._force

    def constant_force(self):
        return self._force

    def potential_energy(self, q):
        # -sum(F . q) as one dot product: no temporary (it runs after every step, in the energy bound)
        return -float(np.dot(self._force.ravel(), np.ravel(q)))

    def potential_floor(self) -> float:
        """``-inf`` (a uniform field's potential is unbounded below), 0 when the field is zero.

        Returns
        -------
        float
            The bound [J].
        """
        return -np.inf if np.any(self._force) else 0.0
