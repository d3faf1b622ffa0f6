"""Linear drag ``F_i = -beta_i qd_i`` (PA2 eq. 5), with ``dF/dqd = -beta_i I``."""

from __future__ import annotations

import numpy as np

from ._base import BlockLayout, Blocks, ForceTerm
from ._data import ArraySpec

__all__ = ["ForceDrag"]


class ForceDrag(ForceTerm):
    """Drag on the particles ``index`` (k,) with coefficients ``beta`` (k,) [N s/m].

    Parameters
    ----------
    index : array_like of int, shape (k,)
        Particles with drag.
    beta : array_like, shape (k,)
        Drag coefficients [N s/m], >= 0.
    """

    name = "drag"
    dissipative = True
    external = True
    data = (ArraySpec("drag", per="particle", unit="N s/m", lo=0.0, sample=(0.1, 1.0), dissipative=True,
                      doc="linear drag coefficient beta of F = -beta qd"),)

    def __init__(self, index, beta):
        self.index = np.asarray(index, dtype=np.int64)
        self.beta = np.asarray(beta, dtype=np.float64)
        self.layout_qd = BlockLayout.diagonal(self.index)
        self._blocks = -self.beta[:, None, None] * np.eye(3)

    @classmethod
    def from_model(cls, model, *, skip_fixed=True, kernels="auto"):
        use = model.particle_drag > 0
        if skip_fixed:
            use &= ~model.particle_fixed
        index = np.flatnonzero(use)
        if index.size == 0:
            return None
        return cls(index, model.particle_drag[index])

    @classmethod
    def naive_force(cls, model, q, qd):
        return -model.particle_drag[:, None] * qd

    def eval_force(self, q, qd, f_out, *, damping_geometry=None):
        f_out[self.index] -= self.beta[:, None] * qd[self.index]

    def eval_jacobians(self, q, qd, mode="exact", *, work=None, damping_geometry=None):
        return None, Blocks(self.layout_qd, self._blocks)

    def dissipation(self, geometry, qd):
        v = qd[self.index]
        return 0.5 * float(np.dot(self.beta, np.einsum("ij,ij->i", v, v)))
