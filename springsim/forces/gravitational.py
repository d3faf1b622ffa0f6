"""Pairwise gravitational attraction (PA2 sec. 5.5).

For a pair (i, j) with ``c = G m_i m_j``, ``d = q_i - q_j``, ``l = |d|``, ``n = d/l``::

    F   = -c d / l^3                      (on i; minus it on j)
    K   = -c / l^3 (I - 3 n n^T)          (dF/dq local blocks [[K, -K], [-K, K]])

``-K`` has eigenvalues ``c/l^3 (1, 1, -2)``: the exact Jacobian is indefinite. The
``spd`` mode projects it to ``K = -c/l^3 (I - n n^T)`` (negative eigenvalue clamped
at 0). There is no velocity dependence.

Softening: below the pair's softening length ``l < eps`` the force is ``-c d / eps^3`` (a
linear core, continuous at ``l = eps``) with ``K = -c/eps^3 I``, so a close encounter or
two particles at the same place stay finite. ``eps`` is per pair
(``model.gravitational_softening``); its default keeps the implicit matrix
well-conditioned (:func:`springsim.builder.default_softening`).
"""

from __future__ import annotations

import numpy as np

from ._base import BlockLayout, Blocks, ForceTerm, PairIncidence, active_pairs, outer, pair_geometry, scratch

__all__ = ["ForceGravitational"]

_I3 = np.eye(3)


class ForceGravitational(ForceTerm):
    """Vectorised gravitational pairs.

    Parameters
    ----------
    pairs : ndarray (P, 2)
    c : ndarray (P,)
        ``G m_i m_j`` [N m^2].
    eps : float or ndarray (P,)
        Softening lengths [m].
    """

    name = "gravitational"
    pairwise = True

    def __init__(self, pairs, c, eps):
        self.pairs = np.asarray(pairs, dtype=np.int64)
        self.c = np.asarray(c, dtype=np.float64)
        self.eps = np.broadcast_to(np.asarray(eps, dtype=np.float64), self.c.shape).copy()
        self.layout_q = BlockLayout.pairs(self.pairs)
        self.incidence = PairIncidence(self.pairs)

    @classmethod
    def from_model(cls, model, *, skip_fixed=True):
        keep = active_pairs(model.gravitational_indices, model.particle_fixed, skip_fixed)
        keep = keep[model.gravitational_G[keep] > 0]
        if keep.size == 0:
            return None
        pairs = model.gravitational_indices[keep]
        m = model.particle_mass
        return cls(pairs, model.gravitational_G[keep] * m[pairs[:, 0]] * m[pairs[:, 1]],
                   model.gravitational_softening[keep])

    def eval_force(self, q, qd, f_out):
        d = self.incidence.diff(q)
        ls = np.maximum(np.sqrt(np.einsum("ij,ij->i", d, d)), self.eps)
        d *= (-self.c / ls**3)[:, None]
        self.incidence.scatter(d, f_out)

    def eval_jacobians(self, q, qd, mode="exact", *, work=None):
        P = self.pairs.shape[0]
        d, l, n, near = pair_geometry(q, self.pairs, self.eps, work)
        s = (self.c / np.maximum(l, self.eps) ** 3)[:, None, None]
        # K = -s (I - w nn^T), w = 1 (spd) or 3 (exact): s w nn^T, then -s on the diagonal
        K = outer(n, n, out=scratch(work, "K", (P, 3, 3)))
        K *= s * (1.0 if mode == "spd" else 3.0)
        K.reshape(-1, 9)[:, ::4] -= s.reshape(-1, 1)
        return Blocks(self.layout_q, K), None

    def potential_floor(self) -> float:
        # the softened potential is smallest at zero distance: c * 0 / (2 eps^3) - 3 c / (2 eps)
        return float(-1.5 * np.sum(self.c / self.eps))

    def potential_energy(self, q):
        d, l, n, near = pair_geometry(q, self.pairs, self.eps)
        far = -self.c / np.maximum(l, self.eps)
        core = self.c * l**2 / (2 * self.eps**3) - 1.5 * self.c / self.eps
        return float(np.sum(np.where(near, core, far)))
