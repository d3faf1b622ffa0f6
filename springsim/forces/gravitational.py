"""Pairwise gravitational attraction (PA2 sec. 5.5).

For a pair (i, j) with ``c = G m_i m_j``, ``d = q_i - q_j``, ``l = |d|``, ``n = d/l``::

    F   = -c d / l^3                      (on i; minus it on j)
    K   = -c / l^3 (I - 3 n n^T)          (dF/dq local blocks [[K, -K], [-K, K]])

``-K`` has eigenvalues ``c/l^3 (1, 1, -2)``: the exact Jacobian is indefinite. The
``spd`` mode projects it to ``K = -c/l^3 (I - n n^T)`` (negative eigenvalue clamped
at 0). There is no velocity dependence.

Energy-momentum form (:meth:`ForceGravitational.eval_force_discrete`, Gonzalez 1996): over a step from
``d_0`` to ``d_1`` the force is ``-s d_m``, ``d_m = (d_0 + d_1)/2``, with the difference quotient
``s = (phi(l_1) - phi(l_0)) / ((l_1^2 - l_0^2)/2)`` of the pair potential ``phi``; outside the core that is
``s = 2c / (l_0 l_1 (l_0 + l_1))`` (no cancellation), inside it ``c/eps^3``. Its work is exactly
``-(phi(l_1) - phi(l_0))`` (across the core boundary the numerator is split at ``eps`` into two positive
parts, so nothing cancels). Its derivative with respect to the midpoint
``q_m = (q_0 + q_1)/2`` (``q_0`` held; :meth:`ForceGravitational.eval_jacobians_discrete`) is::

    exact : K = -[ s I + 2 (ds/dl_1) d_m n_1^T ]

(not symmetric); ``symmetric`` replaces ``d_m n_1^T``
by ``|d_m| n_m n_m^T`` and ``spd`` also clamps the coefficient of ``n_m n_m^T`` at ``-s``. At ``q_0 = q_1``
these are the ordinary Jacobians.

Softening: below the pair's softening length ``l < eps`` the force is ``-c d / eps^3`` (a
linear core, continuous at ``l = eps``) with ``K = -c/eps^3 I``, so a close encounter or
two particles at the same place stay finite. ``eps`` is per pair
(``model.gravitational_softening``); its default keeps the implicit matrix
well-conditioned (:func:`springsim.forces.gravitational.default_softening`).
"""

from __future__ import annotations

import numpy as np

from ._base import (PROJECTED_MODES, BlockLayout, Blocks, ForceTerm, PairIncidence, active_pairs, outer,
                    pair_geometry, scratch, step_pairs)
from ._data import ArraySpec, check_rule

__all__ = ["ForceGravitational", "SOFTENING_PRECISION", "SOFTENING_TIME", "default_softening"]

_I3 = np.eye(3)


#: Largest time step [s] for which :func:`default_softening` keeps a pair's masses in the implicit matrix
#: to :data:`SOFTENING_PRECISION`.
SOFTENING_TIME = 1.0
#: Relative precision of the masses that :func:`default_softening` guarantees up to :data:`SOFTENING_TIME`.
SOFTENING_PRECISION = 1e-9


def default_softening(G, m_i, m_j) -> np.ndarray:
    """Default softening length [m] of gravitational pairs: ``(u T^2 G max(m_i, m_j) / tau)^(1/3)``.

    A pair inside its core (``l < eps``) adds the stiffness ``h^2 c / eps^3`` (``c = G m_i m_j``)
    to the diagonal of the implicit matrix, next to the masses, which then survive only to the
    relative precision ``u h^2 c / (eps^3 min(m_i, m_j))`` (``u`` the unit round-off; it is what
    :meth:`springsim.assembly.SystemAssembler.precision_loss` measures). This default makes that
    at most ``tau`` = :data:`SOFTENING_PRECISION` for every step ``h <= T`` = :data:`SOFTENING_TIME`,
    so particles that meet (or start at the same place) stay well-conditioned and the centre of
    mass of the pair moves right. It depends only on the pair's masses and ``G``, not on the
    step. For ``G`` = 1 and 1 kg masses it is 6.0 mm; give ``softening`` explicitly to resolve
    closer encounters (with smaller steps).

    Parameters
    ----------
    G : float or ndarray
        Gravitational constant of each pair [N m^2/kg^2], scalar or shape (P,).
    m_i, m_j : float or ndarray
        Masses of the pair's two particles [kg], scalar or shape (P,).

    Returns
    -------
    ndarray
        Softening length [m], shape of the broadcast inputs.
    """
    u = np.finfo(np.float64).eps
    scale = u * SOFTENING_TIME**2 / SOFTENING_PRECISION
    return portable_cbrt(scale * np.asarray(G, dtype=np.float64) * np.maximum(m_i, m_j))


def portable_cbrt(x) -> np.ndarray:
    """Cube root of ``x >= 0`` from IEEE's correctly rounded operations only: the same bits on every machine.

    ``np.cbrt`` calls the platform's math library (or numpy's own SIMD code), whose last bit differs between
    builds; a computed softening enters the model, hence its fingerprint (:meth:`springsim.Model.fingerprint`), which
    must not. Here ``x = m 2^(3q)`` exactly (``frexp``, ``ldexp``, with ``m`` in [1/2, 4)), then eight Newton steps
    ``y <- y - (y^3 - m) / (3 y^2)`` from ``y = 1`` (quadratic convergence: full precision after five), then
    ``y 2^q``. Accurate to about one unit in the last place.

    Parameters
    ----------
    x : float or ndarray
        Non-negative finite values.

    Returns
    -------
    ndarray
        ``x^(1/3)``, shape of ``x``; 0 where ``x`` is 0.
    """
    x = np.asarray(x, dtype=np.float64)
    m, e = np.frexp(x)
    r = np.mod(e, 3)
    m = np.ldexp(m, r)
    y = np.ones_like(m)
    for _ in range(8):
        y = y - (y * y * y - m) / (3.0 * (y * y))
    return np.where(x == 0.0, 0.0, np.ldexp(y, (e - r) // 3))


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
    conservative = True
    yaml_key = "gravitational"
    pair_label = "gravitational pairs"
    data = (
        ArraySpec("G", per="pair", unit="N m^2/kg^2", lo=0.0, required=True, sample=(0.5, 2.0),
                  doc="gravitational constant of the pair"),
        ArraySpec("softening", per="pair", unit="m", lo=0.0, lo_strict=True, computed=True,
                  doc="softening length; computed: springsim.forces.gravitational.default_softening of the pair"),
    )

    def __init__(self, pairs, c, eps):
        self.pairs = np.asarray(pairs, dtype=np.int64)
        self.c = np.asarray(c, dtype=np.float64)
        self.eps = np.broadcast_to(np.asarray(eps, dtype=np.float64), self.c.shape).copy()
        self.layout_q = BlockLayout.pairs(self.pairs)
        self.incidence = PairIncidence(self.pairs)

    @classmethod
    def from_model(cls, model, *, skip_fixed=True, kernels="auto"):
        keep = active_pairs(model.gravitational_indices, model.particle_fixed, skip_fixed)
        keep = keep[model.gravitational_G[keep] > 0]
        if keep.size == 0:
            return None
        pairs = model.gravitational_indices[keep]
        m = model.particle_mass
        return cls(pairs, model.gravitational_G[keep] * m[pairs[:, 0]] * m[pairs[:, 1]],
                   model.gravitational_softening[keep])

    @classmethod
    def complete_data(cls, data, *, particle_q, particle_mass, pair_epsilon):
        gij, G, soft = data["indices"], data["G"], data["softening"]
        if not gij.shape[0]:
            return data
        mass = particle_mass
        c = G * mass[gij[:, 0]] * mass[gij[:, 1]]
        # the default, at least pair_epsilon (a vanishing G or mass would give a vanishing length)
        auto = np.maximum(default_softening(G, mass[gij[:, 0]], mass[gij[:, 1]]), pair_epsilon)
        soft = np.where(np.isnan(soft), auto, soft)
        with np.errstate(over="ignore", under="ignore", divide="ignore", invalid="ignore"):
            cube = soft**3
            core = c / cube
        check_rule("gravitational", "softening", soft, cube >= np.finfo(np.float64).tiny,
                    "is too small: its cube underflows (must be >= 3e-103)")
        check_rule("gravitational", "softening", soft, np.isfinite(core),
                    "is too small for the pair: G m_i m_j / softening^3 overflows")
        return dict(data, softening=soft)

    @classmethod
    def naive_force(cls, model, q, qd):
        f = np.zeros_like(q)
        pairs = model.gravitational_indices
        if len(pairs):
            d = q[pairs[:, 0]] - q[pairs[:, 1]]
            ls = np.maximum(np.linalg.norm(d, axis=1), model.gravitational_softening)
            m = model.particle_mass
            fg = -(model.gravitational_G * m[pairs[:, 0]] * m[pairs[:, 1]] / ls**3)[:, None] * d
            np.add.at(f, pairs[:, 0], fg)
            np.add.at(f, pairs[:, 1], -fg)
        return f

    def eval_force(self, q, qd, f_out, *, damping_geometry=None):
        d = self.incidence.diff(q)
        ls = np.maximum(np.sqrt(np.einsum("ij,ij->i", d, d)), self.eps)
        d *= (-self.c / ls**3)[:, None]
        self.incidence.scatter(d, f_out)

    @staticmethod
    def _potential(l, c, eps):
        """Pair potentials ``phi(l)`` of the softened attraction (module docstring)."""
        return np.where(l < eps, c * l**2 / (2 * eps**3) - 1.5 * c / eps, -c / np.maximum(l, eps))

    def _discrete_coefficient(self, q0, q1):
        """``(d_m, l_1, d_1, s, ds/dl_1)`` of the discrete gradient ``-s d_m`` (module docstring)."""
        d0, d1, l0, l1 = step_pairs(self.incidence, q0, q1)
        dm = 0.5 * (d0 + d1)
        far = (l0 >= self.eps) & (l1 >= self.eps)
        s = self.c / self.eps**3  # both ends in the core: phi is quadratic there
        s1 = np.zeros_like(l0)
        lsum = l0[far] + l1[far]
        s[far] = 2.0 * self.c[far] / (l0[far] * l1[far] * lsum)
        s1[far] = -s[far] * (1.0 / l1[far] + 1.0 / lsum)
        cross = np.flatnonzero(~far & ((l0 >= self.eps) | (l1 >= self.eps)))
        if cross.size:  # one end in the core: the difference quotient, its numerator split at eps (no cancellation)
            a, b, c, e = l0[cross], l1[cross], self.c[cross], self.eps[cross]
            lo, hi = np.minimum(a, b), np.maximum(a, b)
            # phi(hi) - phi(lo) = c (hi - e)/(hi e) + c (e - lo)(e + lo)/(2 e^3), over (hi^2 - lo^2)/2
            s[cross] = ((c * (hi - e) / (hi * e) + c * (e - lo) * (e + lo) / (2.0 * e**3))
                        / (0.5 * (hi - lo) * (hi + lo)))
            dphi = np.where(b < e, c * b / e**3, c / np.maximum(b, e) ** 2)  # phi'(l_1)
            s1[cross] = (dphi - s[cross] * b) / (0.5 * (b - a) * (b + a))
        return dm, l1, d1, s, s1

    def eval_force_discrete(self, q0, q1, qd, f_out):
        """Discrete gradient of the softened pair potential ``phi(l)`` (module docstring).

        Parameters as :meth:`ForceTerm.eval_force_discrete`.
        """
        dm, _, _, s, _ = self._discrete_coefficient(q0, q1)
        dm *= -s[:, None]
        self.incidence.scatter(dm, f_out)

    def eval_jacobians_discrete(self, q0, q1, qd, mode="exact", *, work=None):
        """Derivative of :meth:`eval_force_discrete` with respect to the midpoint (module docstring).

        Parameters and returns as :meth:`ForceTerm.eval_jacobians_discrete`.
        """
        P = self.pairs.shape[0]
        dm, l1, d1, s, s1 = self._discrete_coefficient(q0, q1)
        K = scratch(work, "K", (P, 3, 3))
        if mode == "exact":
            n1 = np.divide(d1, l1[:, None], out=np.zeros_like(d1), where=(l1 > 0)[:, None])
            outer(dm, n1, out=K)
            K *= (-2.0 * s1)[:, None, None]
        else:
            lm = np.sqrt(np.einsum("ij,ij->i", dm, dm))
            nm = np.divide(dm, lm[:, None], out=np.zeros_like(dm), where=(lm > 0)[:, None])
            w = 2.0 * s1 * lm
            if mode in PROJECTED_MODES:
                w = np.maximum(w, -s)
            outer(nm, nm, out=K)
            K *= -w[:, None, None]
        K.reshape(-1, 9)[:, ::4] -= s[:, None]
        return Blocks(self.layout_q, K), None

    def jacobian_symmetric_discrete(self, mode: str) -> bool:
        return mode != "exact"

    def eval_jacobians(self, q, qd, mode="exact", *, work=None, damping_geometry=None):
        P = self.pairs.shape[0]
        d, l, n, near = pair_geometry(q, self.pairs, self.eps, work)
        s = (self.c / np.maximum(l, self.eps) ** 3)[:, None, None]
        # K = -s (I - w nn^T), w = 1 (spd) or 3 (exact): s w nn^T, then -s on the diagonal
        K = outer(n, n, out=scratch(work, "K", (P, 3, 3)))
        K *= s * (1.0 if mode in PROJECTED_MODES else 3.0)
        K.reshape(-1, 9)[:, ::4] -= s.reshape(-1, 1)
        return Blocks(self.layout_q, K), None

    def potential_floor(self) -> float:
        """The sum of the pairs' minima, each at zero distance: ``-3/2 sum c / eps`` [J] (finite, by the softening).

        Returns
        -------
        float
            The bound [J].
        """
        # the softened potential is smallest at zero distance: c * 0 / (2 eps^3) - 3 c / (2 eps)
        return float(-1.5 * np.sum(self.c / self.eps))

    def potential_energy(self, q):
        d, l, n, near = pair_geometry(q, self.pairs, self.eps)
        return float(np.sum(self._potential(l, self.c, self.eps)))
