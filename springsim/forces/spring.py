"""Damped springs (PA2 eqs. 6-8).

For a pair (i, j) with ``d = q_i - q_j``, ``l = |d|``, ``n = d / l``, ``v = qd_i - qd_j``,
stiffness ``k``, damping ``b`` and rest length ``l0``, the force on i (minus it on j) is::

    F = -k (l - l0) n  -  b (n . v) n                          (eqs. 6 and 8)

and the local 6x6 Jacobians are ``[[K, -K], [-K, K]]`` with::

    dF/dq  : K = -k [ n n^T + (l - l0)/l (I - n n^T) ]          (eq. 7)
                 -(b/l) [ (n . v) I + n v^T ] (I - n n^T)       (damping, section 5.4)
    dF/dqd : K = -b n n^T

Jacobian modes: ``symmetric`` drops the non-symmetric damping position term;
``spd`` also clamps the transverse coefficient ``(l - l0)/l`` at 0 so that ``-dF/dq``
is positive semi-definite.

Degenerate geometry: below ``l < eps`` (``model.pair_epsilon``) the direction is
undefined. The elastic force is then ``-k (1 - l0/eps) d`` with Jacobian
``K = -k (1 - l0/eps) I`` (continuous with the formula above at ``l = eps``, and exact
for zero rest length, where ``F = -k d`` everywhere); the damping force and its
Jacobians are zero. No NaN or inf is ever produced.
"""

from __future__ import annotations

import numpy as np

from ._base import BlockLayout, Blocks, ForceTerm, PairIncidence, active_pairs, outer, pair_geometry, scratch

__all__ = ["ForceSpring"]

_I3 = np.eye(3)


class ForceSpring(ForceTerm):
    """Vectorised damped springs.

    Parameters
    ----------
    pairs : ndarray (P, 2)
    ke, kd, rest_length : ndarray (P,)
        Stiffness [N/m], damping [N s/m], rest length [m].
    eps : float
        Pair distance below which the direction is undefined [m].
    """

    name = "spring"
    pairwise = True

    def __init__(self, pairs, ke, kd, rest_length, eps: float = 1e-9):
        self.pairs = np.asarray(pairs, dtype=np.int64)
        self.ke = np.asarray(ke, dtype=np.float64)
        self.kd = np.asarray(kd, dtype=np.float64)
        self.l0 = np.asarray(rest_length, dtype=np.float64)
        self.eps = float(eps)
        # damping is modelled only on the springs that have it
        self.damped = np.flatnonzero(self.kd > 0)
        self.layout_q = BlockLayout.pairs(self.pairs)
        self.layout_qd = BlockLayout.pairs(self.pairs[self.damped]) if self.damped.size else None
        self.incidence = PairIncidence(self.pairs)
        self._damped_incidence = PairIncidence(self.pairs[self.damped])
        self._kd_damped = self.kd[self.damped]

    @classmethod
    def from_model(cls, model, *, skip_fixed=True):
        keep = active_pairs(model.spring_indices, model.particle_fixed, skip_fixed)
        if keep.size == 0:
            return None
        return cls(model.spring_indices[keep], model.spring_stiffness[keep], model.spring_damping[keep],
                   model.spring_rest_length[keep], model.pair_epsilon)

    def jacobian_symmetric(self, mode: str) -> bool:
        # the damping force's position derivative (dF/dq of eq. 8) is not symmetric; the other modes drop it
        return mode != "exact" or self.damped.size == 0

    def _elastic_coef(self, l, near):
        """``1 - l0/l`` with ``l`` clamped at eps (the force is ``-k * coef * d``)."""
        return 1.0 - self.l0 / np.where(near, self.eps, l)

    def eval_force(self, q, qd, f_out):
        # elastic: f = -k (1 - l0/max(l, eps)) d, no direction vector needed
        d = self.incidence.diff(q)
        l = np.sqrt(np.einsum("ij,ij->i", d, d))
        damping = None
        if self.damped.size:  # -b (n . v) n, with n = 0 below eps
            s = self.damped
            ls = l[s]
            inv = np.divide(1.0, ls, out=np.zeros_like(ls), where=ls >= self.eps)
            n = d[s] * inv[:, None]
            v = self._damped_incidence.diff(qd)
            damping = (self._kd_damped * np.einsum("ij,ij->i", n, v))[:, None] * n
        scale = np.maximum(l, self.eps, out=l)
        np.divide(self.l0, scale, out=scale)
        scale -= 1.0
        scale *= self.ke  # -k (1 - l0/l)
        f = np.multiply(d, scale[:, None], out=d)
        if damping is not None:
            f[self.damped] -= damping
        self.incidence.scatter(f, f_out)

    def eval_jacobians(self, q, qd, mode="exact", *, work=None):
        P = self.pairs.shape[0]
        d, l, n, near = pair_geometry(q, self.pairs, self.eps, work)
        nn = outer(n, n, out=scratch(work, "nn", (P, 3, 3)))
        coef = self._elastic_coef(l, near)
        if mode == "spd":
            coef = np.maximum(coef, 0.0)
        # elastic: -k [ coef (I - nn^T) + nn^T ] = -k (1 - coef) nn^T - k coef I, written as one
        # scaled copy of nn^T plus a diagonal update (two passes over (P, 3, 3) instead of five)
        K = np.multiply(nn, (self.ke * (coef - 1.0))[:, None, None], out=scratch(work, "K", (P, 3, 3)))
        diag = K.reshape(-1, 9)[:, ::4]
        diag -= (self.ke * coef)[:, None]
        dfdqd = None
        if self.damped.size:
            s = self.damped
            b = self.kd[s]
            p = self.pairs[s]
            ns = n[s]
            if mode == "exact":
                v = qd[p[:, 0]] - qd[p[:, 1]]
                ls = np.where(near[s], self.eps, l[s])
                nv = np.einsum("ij,ij->i", ns, v)
                Kd = nv[:, None, None] * _I3 + outer(ns, v)
                Kd = Kd @ (_I3 - nn[s])
                K[s] -= (b / ls)[:, None, None] * Kd
            dfdqd = Blocks(self.layout_qd, -b[:, None, None] * nn[s])
        return Blocks(self.layout_q, K), dfdqd

    def potential_energy(self, q):
        d, l, n, near = pair_geometry(q, self.pairs, self.eps)
        return float(0.5 * np.sum(self.ke * (l - self.l0) ** 2))
