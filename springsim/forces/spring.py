"""Damped springs (PA2 eqs. 6-8).

For a pair (i, j) with ``d = q_i - q_j``, ``l = |d|``, ``n = d / l``, ``v = qd_i - qd_j``,
stiffness ``k``, damping ``b`` and rest length ``l0``, the force on i (minus it on j) is::

    F = -k (l - l0) n  -  b (n . v) n                          (eqs. 6 and 8)

and the local 6x6 Jacobians are ``[[K, -K], [-K, K]]`` with::

    dF/dq  : K = -k [ n n^T + (l - l0)/l (I - n n^T) ]          (eq. 7)
                 -(b/l) [ (n . v) I + n v^T ] (I - n n^T)       (damping, section 5.4)
    dF/dqd : K = -b n n^T

Energy-momentum form (:meth:`ForceSpring.eval_force_discrete`, Gonzalez 1996): over a step from ``d_0`` to
``d_1`` the elastic force is ``-k (1 - l0/lbar) d_m`` with ``lbar = (l_0 + l_1)/2`` and ``d_m = (d_0 + d_1)/2``.
Since ``d_m . (d_1 - d_0) = (l_1^2 - l_0^2)/2``, its work is ``-k (lbar - l0)(l_1 - l_0)``, exactly minus the
change of ``k/2 (l - l0)^2``; it is the midpoint force when ``l_0 = l_1`` and has no division by a small
difference. ``lbar`` is clamped at ``eps`` as ``l`` is above (the identity holds for ``lbar >= eps``).
The damping force is evaluated at the midpoint geometry ``d_m``. Its derivatives with respect to the
midpoint ``q_m = (q_0 + q_1)/2`` (``q_0`` held, :meth:`ForceSpring.eval_jacobians_discrete`) are, with
``n_1 = d_1 / l_1``::

    exact : K = -k [ (l0/lbar^2) d_m n_1^T + (1 - l0/lbar) I ]     (+ the damping terms at d_m)

(not symmetric); ``symmetric`` replaces ``d_m n_1^T`` by ``|d_m| n_m n_m^T``, and ``spd`` also clamps
``1 - l0/lbar`` at 0 as above. At ``q_0 = q_1`` all three equal the ordinary Jacobians.

Kernels: ``kernels="numba"`` (the ``accel`` extra) evaluates :meth:`ForceSpring.eval_force` in one compiled
pass over the springs (:func:`springsim.forces._numba_kernels.spring_forces`), with no temporary arrays;
``"numpy"`` is the pure path (the incidence-matrix products above); ``"auto"`` takes the compiled pass when
numba is installed and there are at least :attr:`ForceSpring.auto_min_pairs` springs (below that, the
import of numba costs more than it saves), and the numpy path when numba is installed but does not import
(``"numba"`` then raises ``ValueError``). Both give the same forces to round-off (the tests check it), except
that a spring shorter than ``eps`` contributes no damping force at all in the compiled pass, where the numpy
path's zero direction times a non-finite velocity gives NaN (a state the driver stops on either way). The
Jacobians and the energy-momentum forms always run in numpy.

Jacobian modes: ``symmetric`` drops the non-symmetric damping position term;
``spd`` also clamps the transverse coefficient ``(l - l0)/l`` at 0 so that ``-dF/dq``
is positive semi-definite. ``mixed`` is ``spd`` with the tension of the transverse term taken from the
previous assembly's linearisation: with ``C = l - l0`` and the spring's tension ``s``, the compliant form
of a stiff spring (Servin, Lacoursiere and Melin 2006; Tournier, Nesme, Gilles and Faure 2015) solves
``C(x) - s/k = 0`` beside the momentum balance, and Newton on the pair ``(x, s)``, with ``ds`` eliminated,
has the primal system's right-hand side and matrix except that the geometric stiffness is ``(s/l) (I - n
n^T)`` with the multiplier's linear prediction ``s = k (C_0 + n_0 . (d - d_0))`` from the previous
iterate ``0``, instead of ``k C(x)``. A tangential Newton step stretches a stiff spring to second order;
the primal form then sees a huge tension and overshoots back, the mixed one does not (benchmark cloth,
n = 16, h = 1/60 s, ke = 1e6: implicit Euler needs 6.8 instead of 11.0 Newton iterations per step). It changes
only the search direction: the stage's potential, gradient and line search are the primal ones, and at convergence
``s = k C``. The first assembly of a term (no previous geometry) is the ``spd`` one.

Degenerate geometry: below ``l < eps`` (``model.pair_epsilon``) the direction is
undefined. The elastic force is then ``-k (1 - l0/eps) d`` with Jacobian
``K = -k (1 - l0/eps) I`` (continuous with the formula above at ``l = eps``, and exact
for zero rest length, where ``F = -k d`` everywhere); the damping force and its
Jacobians are zero. No NaN or inf is ever produced.
"""

from __future__ import annotations

import numpy as np

from .._runtime.accel import KERNELS, resolve
from ._base import (PROJECTED_MODES, BlockLayout, Blocks, ForceTerm, PairIncidence, active_pairs, outer,
                    pair_geometry, scratch, step_pairs)
from ._data import ArraySpec

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
    kernels : {"auto", "numba", "numpy"}
        How :meth:`eval_force` runs (module docstring); ``"numba"`` without numba raises ``ValueError``.
    """

    name = "spring"
    pairwise = True
    conservative = True  # the elastic part
    curved = True  # spring lengths: the second-order correction of minimisation stages
    dissipative = True   # the damping, where a spring has it (declared per family, used per instance)
    yaml_key = "springs"
    data = (
        ArraySpec("stiffness", per="pair", unit="N/m", lo=0.0, required=True, aliases=("ke",), sample=(20.0, 200.0),
                  doc="stiffness ke"),
        ArraySpec("damping", per="pair", unit="N s/m", lo=0.0, aliases=("kd",), sample=(0.1, 2.0), dissipative=True,
                  doc="damping kd of the force along the spring (PA2 eq. 8)"),
        ArraySpec("rest_length", per="pair", unit="m", lo=0.0, computed=True,
                  doc="rest length l0; computed: the initial distance"),
    )
    #: Accepted values of ``kernels`` (:data:`springsim._runtime.accel.KERNELS`).
    KERNELS = KERNELS
    #: ``kernels="auto"`` compiles the force pass from this many springs on.
    auto_min_pairs = 2048

    def __init__(self, pairs, ke, kd, rest_length, eps: float = 1e-9, kernels: str = "auto"):
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
        self._kd_zero = np.zeros_like(self.kd)  # the compiled pass without damping (frozen damping geometry)
        small = kernels == "auto" and self.pairs.shape[0] < self.auto_min_pairs
        self.kernels = resolve("numpy" if small else kernels)
        self._compiled = None  # the compiled force pass, with kernels="numba"
        if self.kernels == "numba":
            try:
                from ._numba_kernels import spring_forces
            except Exception as e:  # numba installed but unusable, e.g. built for another numpy: say so now
                if kernels != "auto":
                    raise ValueError(f"kernels='numba': numba does not import ({type(e).__name__}: {e})") from None
                self.kernels = "numpy"
            else:
                self._compiled = spring_forces

    @classmethod
    def from_model(cls, model, *, skip_fixed=True, kernels="auto"):
        keep = active_pairs(model.spring_indices, model.particle_fixed, skip_fixed)
        if keep.size == 0:
            return None
        return cls(model.spring_indices[keep], model.spring_stiffness[keep], model.spring_damping[keep],
                   model.spring_rest_length[keep], model.pair_epsilon, kernels=kernels)

    @classmethod
    def complete_data(cls, data, *, particle_q, particle_mass, pair_epsilon):
        ij, l0 = data["indices"], data["rest_length"]
        if ij.shape[0]:
            dist = np.linalg.norm(particle_q[ij[:, 0]] - particle_q[ij[:, 1]], axis=1)
            data = dict(data, rest_length=np.where(np.isnan(l0), dist, l0))
        return data

    @classmethod
    def naive_force(cls, model, q, qd):
        f = np.zeros_like(q)
        pairs, eps = model.spring_indices, model.pair_epsilon
        if len(pairs):
            d = q[pairs[:, 0]] - q[pairs[:, 1]]
            l = np.linalg.norm(d, axis=1)
            safe = np.maximum(l, eps)
            fs = -(model.spring_stiffness * (1.0 - model.spring_rest_length / safe))[:, None] * d
            n = np.where((l >= eps)[:, None], d / safe[:, None], 0.0)
            v = qd[pairs[:, 0]] - qd[pairs[:, 1]]
            fs -= (model.spring_damping * np.sum(n * v, axis=1))[:, None] * n
            np.add.at(f, pairs[:, 0], fs)
            np.add.at(f, pairs[:, 1], -fs)
        return f

    def jacobian_symmetric(self, mode: str, *, frozen_damping: bool = False) -> bool:
        # the damping force's position derivative (dF/dq of eq. 8) is not symmetric; the other modes drop it, and
        # with a frozen damping geometry there is none
        return mode != "exact" or self.damped.size == 0 or frozen_damping

    def _elastic_coef(self, l, near):
        """``1 - l0/l`` with ``l`` clamped at eps (the force is ``-k * coef * d``)."""
        return 1.0 - self.l0 / np.where(near, self.eps, l)

    def _damping(self, d, l, qd):
        """Damping forces ``b (n . v) n`` (to subtract) of the damped springs, given all pair vectors ``d`` and
        lengths ``l``; ``n = 0`` below eps."""
        s = self.damped
        ls = l[s]
        inv = np.divide(1.0, ls, out=np.zeros_like(ls), where=ls >= self.eps)
        n = d[s] * inv[:, None]
        v = self._damped_incidence.diff(qd)
        return (self._kd_damped * np.einsum("ij,ij->i", n, v))[:, None] * n

    def _scatter_elastic(self, d, length, damping, f_out):
        """Scatter ``-k (1 - l0/max(length, eps)) d - damping``; overwrites ``d`` and ``length``."""
        scale = np.maximum(length, self.eps, out=length)
        np.divide(self.l0, scale, out=scale)
        scale -= 1.0
        scale *= self.ke  # -k (1 - l0/l)
        f = np.multiply(d, scale[:, None], out=d)
        if damping is not None:
            f[self.damped] -= damping
        self.incidence.scatter(f, f_out)

    def eval_force(self, q, qd, f_out, *, damping_geometry=None):
        frozen = damping_geometry is not None and self.damped.size > 0
        if self._compiled is not None:
            kd = self._kd_zero if frozen else self.kd
            self._compiled(q, qd, self.pairs, self.ke, kd, self.l0, self.eps, f_out)
        else:
            # elastic: f = -k (1 - l0/max(l, eps)) d, no direction vector needed
            d = self.incidence.diff(q)
            l = np.sqrt(np.einsum("ij,ij->i", d, d))
            damping = self._damping(d, l, qd) if self.damped.size and not frozen else None
            self._scatter_elastic(d, l, damping, f_out)
        if frozen:
            self._damped_incidence.scatter(-self._frozen_damping(damping_geometry, qd), f_out)

    def _damped_directions(self, geometry):
        """Unit directions (zero below eps) of the damped springs at ``geometry``."""
        d = self._damped_incidence.diff(geometry)
        l = np.sqrt(np.einsum("ij,ij->i", d, d))
        inv = np.divide(1.0, l, out=np.zeros_like(l), where=l >= self.eps)
        return d * inv[:, None]

    def _frozen_damping(self, geometry, qd):
        """Damping forces ``b (n . v) n`` (to subtract) of the damped springs with ``n`` from ``geometry``."""
        n = self._damped_directions(geometry)
        v = self._damped_incidence.diff(qd)
        return (self._kd_damped * np.einsum("ij,ij->i", n, v))[:, None] * n

    def dissipation(self, geometry, qd):
        """``1/2 sum b (n . v)^2`` over the damped springs, ``n`` from ``geometry``.

        Parameters
        ----------
        geometry : ndarray, shape (N, 3)
            Positions [m] that give the spring directions.
        qd : ndarray, shape (N, 3)
            Velocities [m/s].

        Returns
        -------
        float
            Dissipation function [W].
        """
        if not self.damped.size:
            return 0.0
        n = self._damped_directions(geometry)
        nv = np.einsum("ij,ij->i", n, self._damped_incidence.diff(qd))
        return 0.5 * float(np.dot(self._kd_damped, nv * nv))

    def eval_force_discrete(self, q0, q1, qd, f_out):
        """Discrete gradient of ``k/2 (l - l0)^2`` (module docstring) plus the damping at the midpoint.

        Parameters as :meth:`ForceTerm.eval_force_discrete`.
        """
        d0, d, lbar, l1 = step_pairs(self.incidence, q0, q1)
        lbar += l1
        lbar *= 0.5
        d += d0
        d *= 0.5  # the midpoint's pair vector
        damping = None
        if self.damped.size:
            damping = self._damping(d, np.sqrt(np.einsum("ij,ij->i", d, d)), qd)
        self._scatter_elastic(d, lbar, damping, f_out)

    def eval_jacobians(self, q, qd, mode="exact", *, work=None, damping_geometry=None):
        P = self.pairs.shape[0]
        d, l, n, near = pair_geometry(q, self.pairs, self.eps, work)
        nn = outer(n, n, out=scratch(work, "nn", (P, 3, 3)))
        coef = self._elastic_coef(l, near)
        if mode == "mixed" and work is not None:
            coef = self._continued_coef(coef, d, l, n, near, work)
        if mode in PROJECTED_MODES:
            coef = np.maximum(coef, 0.0)
        # elastic: -k [ coef (I - nn^T) + nn^T ] = -k (1 - coef) nn^T - k coef I, written as one
        # scaled copy of nn^T plus a diagonal update (two passes over (P, 3, 3) instead of five)
        K = np.multiply(nn, (self.ke * (coef - 1.0))[:, None, None], out=scratch(work, "K", (P, 3, 3)))
        diag = K.reshape(-1, 9)[:, ::4]
        diag -= (self.ke * coef)[:, None]
        if damping_geometry is not None and self.damped.size:  # no position derivative; D at the geometry
            n0 = self._damped_directions(damping_geometry)
            return Blocks(self.layout_q, K), Blocks(self.layout_qd, -self._kd_damped[:, None, None] * outer(n0, n0))
        return Blocks(self.layout_q, K), self._damping_jacobians(K, l, n, nn, near, qd, mode)

    def linearize_at(self, q, work):
        d, l, n, _ = pair_geometry(q, self.pairs, self.eps)
        work["mixed_from"] = (d, l, n)

    def _continued_coef(self, coef, d, l, n, near, work):
        """The ``mixed`` mode's transverse coefficient ``s / (k l)`` (module docstring), recording this geometry."""
        prev = work.get("mixed_from")
        if prev is not None and prev[0].shape == d.shape:
            d0, l0, n0 = prev
            coef = ((l0 - self.l0) + np.einsum("ij,ij->i", n0, d - d0)) / np.where(near, self.eps, l)
        work["mixed_from"] = (d.copy(), l.copy(), n.copy())
        return coef

    def _damping_jacobians(self, K, l, n, nn, near, qd, mode):
        """Subtract the damping's position derivative (exact mode) from ``K``; return its velocity derivative."""
        if not self.damped.size:
            return None
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
        return Blocks(self.layout_qd, -b[:, None, None] * nn[s])

    def eval_jacobians_discrete(self, q0, q1, qd, mode="exact", *, work=None):
        """Derivatives of :meth:`eval_force_discrete` with respect to the midpoint (module docstring).

        Parameters and returns as :meth:`ForceTerm.eval_jacobians_discrete`.
        """
        P = self.pairs.shape[0]
        qm = 0.5 * (q0 + q1)
        d, l, n, near = pair_geometry(qm, self.pairs, self.eps, work)  # midpoint geometry, for the damping
        nn = outer(n, n, out=scratch(work, "nn", (P, 3, 3)))
        _, d1, l0, l1 = step_pairs(self.incidence, q0, q1)
        lraw = 0.5 * (l0 + l1)
        lbar = np.maximum(lraw, self.eps)
        coef = 1.0 - self.l0 / lbar
        if mode in PROJECTED_MODES:
            coef = np.maximum(coef, 0.0)
        # K = -k [ (1 - coef)/lbar d_m n_1^T + coef I ] (exact), with |d_m| n_m n_m^T for d_m n_1^T otherwise;
        # the first part is zero where the clamp at eps makes lbar constant
        w = np.where(lraw >= self.eps, (1.0 - coef) / lbar, 0.0)
        K = scratch(work, "K", (P, 3, 3))
        if mode == "exact":
            n1 = np.divide(d1, l1[:, None], out=np.zeros_like(d1), where=(l1 > 0)[:, None])  # lbar uses l1 as is
            outer(d, n1, out=K)
            K *= (-self.ke * w)[:, None, None]
        else:
            np.multiply(nn, (-self.ke * w * l)[:, None, None], out=K)
        K.reshape(-1, 9)[:, ::4] -= (self.ke * coef)[:, None]
        return Blocks(self.layout_q, K), self._damping_jacobians(K, l, n, nn, near, qd, mode)

    def jacobian_symmetric_discrete(self, mode: str) -> bool:
        return mode != "exact"

    def curvature_remainder(self, q0, q1, out):
        """Add ``-k r n0`` to the first particle of each spring and ``k r n0`` to the second, with
        ``r = l(q1) - l(q0) - n0 . (d(q1) - d(q0))`` the second-order remainder of the spring's length (its
        change beyond the linearisation at ``q0``: ``|dd_perp|^2 / (2 l)`` to leading order) and ``n0`` its
        direction at ``q0``.

        Parameters as :meth:`ForceTerm.curvature_remainder`.
        """
        d0, l0, n0, _ = pair_geometry(q0, self.pairs, self.eps)
        d1 = self.incidence.diff(q1)
        l1 = np.sqrt(np.einsum("ij,ij->i", d1, d1))
        d1 -= d0
        r = l1 - l0 - np.einsum("ij,ij->i", n0, d1)
        n0 *= (-self.ke * r)[:, None]
        self.incidence.scatter(n0, out)

    def potential_energy(self, q):
        d, l, n, near = pair_geometry(q, self.pairs, self.eps)
        return float(0.5 * np.sum(self.ke * (l - self.l0) ** 2))
