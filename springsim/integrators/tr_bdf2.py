"""TR-BDF2 (Bank et al. 1985; Hosea and Shampine 1996), gamma = 2 - sqrt(2), solved by Newton.

One step of size ``h`` is a trapezoidal stage to ``t_n + gamma h`` followed by a BDF2
stage over the nodes ``t_n``, ``t_n + gamma h``, ``t_{n+1}``. Both fit the Newton stage
``q = q_hat + c v``, ``M (v - v_hat) = c F(q_hat + c v, v)`` of
:class:`~springsim.integrators.ImplicitIntegrator` (``a = M^-1 F``):

* trapezoidal stage, ``q_g = q_n + (gamma h/2)(v_n + v_g)``, ``v_g = v_n + (gamma h/2)(a_n + a_g)``::

      c = gamma h / 2,   q_hat = q_n + c v_n,   v_hat = v_n + c a_n

* BDF2 stage, ``y_{n+1} = (y_g - (1 - gamma)^2 y_n) / (gamma (2 - gamma)) + c f_{n+1}``::

      c = h (1 - gamma) / (2 - gamma),   q_hat = (q_g - (1-gamma)^2 q_n) / (gamma (2-gamma)),  same for v_hat

With ``gamma = 2 - sqrt(2)`` both stages have ``c = (1 - 1/sqrt(2)) h ~ 0.293 h``, so they
share the system matrix ``M - c^2 dF/dq - c dF/dqd``. The method is one-step (no history),
second order, L-stable, and much less damped than BDF2 at animation steps; the trapezoidal
rule alone conserves energy on linear problems but is not L-stable (stiff cloth modes ring).

Each step costs one extra force evaluation for ``a_n``; ``a_g`` and ``a_{n+1}`` come from
the stages as ``(v - v_hat) / c``. Newton starts the first stage from ``v_n`` and the
second from ``v_g`` (extrapolating with ``a_n`` treats stiff modes explicitly and makes
Newton fail far more often on stiff cloth), and stops as implicit Euler does, per stage.

Local error estimate (Hosea and Shampine 1996, eq. for TR-BDF2's embedded pair)::

    err = -2 k h (f_n / gamma - f_g / (gamma (1 - gamma)) + f_{n+1} / (1 - gamma))
    k = (-3 gamma^2 + 4 gamma - 2) / (12 (2 - gamma))

with ``f = qd`` for positions and ``f = a`` for velocities; the bracket is ``h^2/2`` times
the second derivative of ``f``, so ``err = -k h^3 y'''`` (sign: numerical minus exact;
checked against a Radau reference). As in Hosea and Shampine's implementation, the estimate is
then filtered through Newton's matrix, ``(I - c J)^-1 err``
(:meth:`~springsim.integrators.ImplicitIntegrator.filter_estimate`), so that stiff components the
method damps do not dominate it.
"""

from __future__ import annotations

import math

from ._implicit import ImplicitIntegrator

__all__ = ["IntegratorTRBDF2", "GAMMA"]

#: The stage fraction that makes both stage matrices equal and the method L-stable.
GAMMA = 2.0 - math.sqrt(2.0)


class IntegratorTRBDF2(ImplicitIntegrator):
    """TR-BDF2 with ``gamma = 2 - sqrt(2)``; see the module docstring.

    Parameters are those of :class:`~springsim.integrators.ImplicitIntegrator`.

    Attributes
    ----------
    error_estimate : tuple of ndarray (N, 3) or None
        Local error estimate ``(err_q [m], err_v [m/s])`` of the last step; filtered, it is computed only
        while ``estimating`` is set (adaptive runs set it).
    """

    name = "tr_bdf2"
    default_newton_maxiter = 50  # see ImplicitIntegrator (newton_maxiter)
    order = 2
    has_error_estimate = True

    def advance(self, q, v, h, stats):
        """One TR-BDF2 step: the trapezoidal stage to ``t + gamma h``, then the BDF2 stage to ``t + h`` (module
        docstring); sets :attr:`error_estimate`."""
        g = GAMMA
        self.error_estimate = None
        a_n = self.acceleration(q, v).copy()
        # trapezoidal stage to t_n + gamma h
        c1 = 0.5 * g * h
        v_hat1 = v + c1 * a_n
        q_g, v_g, ok1 = self.solve_stage(q + c1 * v, v_hat1, c1, v, stats, guesses=self.predict(v, g * h))
        if not ok1:  # the second stage would build on an unconverged one: the step is retaken smaller
            return q_g, v_g
        a_g = (v_g - v_hat1) / c1
        # BDF2 stage over t_n, t_n + gamma h, t_n + h
        c2 = h * (1.0 - g) / (2.0 - g)
        s, r = 1.0 / (g * (2.0 - g)), (1.0 - g) ** 2 / (g * (2.0 - g))
        v_hat2 = s * v_g - r * v
        q1, v1, ok2 = self.solve_stage(s * q_g - r * q, v_hat2, c2, v_g, stats,
                                       guesses=[v_g + ((1.0 - g) / g) * (v_g - v)])
        a1 = (v1 - v_hat2) / c2
        gain = self.gained_energy(q, v, q1, v1) if ok2 else None
        if gain is not None:
            q1, v1, _, self.error_estimate = self.retake_implicit_euler(
                q, v, h, a_n, stats, f"tr_bdf2 step created {gain:.3g} J")
            self.error_estimate = self.finish_estimate(q1, v1, h, self.error_estimate, stats)
        elif ok2:
            q1[self.fixed] = q[self.fixed]  # a1 q - a2 q_prev rounds: keep fixed particles bit-exact
            a1[self.fixed] = 0.0
            a_g[self.fixed] = 0.0
            k = (-3.0 * g * g + 4.0 * g - 2.0) / (12.0 * (2.0 - g))
            w0, wg, w1 = 2.0 * k * h / g, -2.0 * k * h / (g * (1.0 - g)), 2.0 * k * h / (1.0 - g)
            # sign: the estimate approximates (numerical - exact)
            self.error_estimate = (-(w0 * v + wg * v_g + w1 * v1), -(w0 * a_n + wg * a_g + w1 * a1))
            self.error_estimate = self.finish_estimate(q1, v1, c2, self.error_estimate, stats)
        return q1, v1
