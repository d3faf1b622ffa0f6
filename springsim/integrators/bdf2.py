"""Variable-step BDF2 (second-order backward differentiation), solved by Newton.

For ``y' = f(y)`` with steps ``h_{n-1} = t_n - t_{n-1}``, ``h = h_n = t_{n+1} - t_n`` and
ratio ``w = h / h_{n-1}``, BDF2 sets the derivative at ``t_{n+1}`` of the quadratic
through ``(t_{n-1}, y_{n-1})``, ``(t_n, y_n)``, ``(t_{n+1}, y_{n+1})`` equal to ``f(y_{n+1})``::

    y_{n+1} = a1 y_n - a2 y_{n-1} + c f(y_{n+1})
    a1 = (1 + w)^2 / (1 + 2w),   a2 = w^2 / (1 + 2w),   c = h (1 + w) / (1 + 2w)

(``w = 1``: ``a1 = 4/3``, ``a2 = 1/3``, ``c = 2h/3``). Applied to ``q' = qd`` and
``qd' = M^-1 F(q, qd)`` this is exactly the Newton stage of
:class:`~springsim.integrators.ImplicitIntegrator`::

    q^{n+1} = q_hat + c v,   M (v - v_hat) = c F(q_hat + c v, v)
    q_hat = a1 q^n - a2 q^{n-1},   v_hat = a1 qd^n - a2 qd^{n-1}

with system matrix ``M - c^2 dF/dq - c dF/dqd`` (constant step: ``c = 2h/3``). Fixed
particles stay put because ``a1 - a2 = 1``.

Start-up and history: the first step after :meth:`reset` (or from a state that is not the
output of the previous step) is one implicit Euler step. The integrator remembers its last
input and output, so a step repeated from the same input (a rejected adaptive step) reuses
the same history, and a step from the previous output continues the multistep sequence.

Newton starts from ``qd^n`` and stops as implicit Euler does (``|dv|_2 < newton_tol`` or
``newton_maxiter``). Starting from the predictor below, or from a linear extrapolation of
the velocity, is worse on stiff cloth: it extrapolates the stiff modes explicitly, and on
the 32x32 benchmark cloth at h = 1/60 s Newton then missed its 5-iteration limit on 23-25
of 30 steps instead of 8 (implicit Euler: 8).

Local error estimate (used by :func:`springsim.run.adaptive.simulate_adaptive`): the predictor
is the quadratic ``p`` with ``p(t_{n-1}) = y_{n-1}``, ``p(t_n) = y_n``, ``p'(t_n) = y'_n``
(``y' = qd`` for positions, the acceleration ``(v - v_hat)/c`` of the previous stage for
velocities, so it costs no force evaluation). With ``y'''`` the third derivative,
``y(t_{n+1}) - p(t_{n+1}) ~ h^2 (h + h_{n-1}) y'''/6`` and the BDF2 local error is
``y_{n+1} - y(t_{n+1}) ~ c h (h + h_{n-1}) y'''/6``, so::

    err ~ c / (c + h) (y_{n+1} - p(t_{n+1}))            (constant step: 2/5)

For the implicit Euler start step the predictor is ``y_n + h y'_n`` and ``err ~ (y_{n+1} - p)/2``.
With ``filter_estimates=True`` every estimate is then filtered through Newton's matrix, ``(I - c J)^-1 err``
(:meth:`~springsim.integrators.ImplicitIntegrator.filter_estimate`; Shampine 1982): more accurate, but not
cheaper on stiff cloth, so not the default here (docs/accuracy.md).
"""

from __future__ import annotations

import numpy as np

from ._implicit import ImplicitIntegrator

__all__ = ["IntegratorBDF2", "StepHistory"]


class StepHistory:
    """Remembers a one-step method's last input/output so multistep methods can continue or retry.

    States are compared on every process of the system (:meth:`~springsim.system.System.all_equal`).

    :attr:`last` holds the last step's record, ``None`` before it: copies of ``q_in, v_in`` (N, 3), its input,
    and ``q_out, v_out``, its output; ``h`` its size [s], ``a_out`` the acceleration at the output [m/s^2] (as
    given), ``used`` whatever history record that step used.

    Parameters
    ----------
    system : System
        The system whose reductions compare states.
    """

    def __init__(self, system):
        self.system = system
        self.last = None

    def record(self, q_in, v_in, q_out, v_out, h, a_out, used):
        """Remember the step just taken.

        Parameters
        ----------
        q_in, v_in : ndarray, shape (n, 3)
            The step's input positions [m] and velocities [m/s] (copied).
        q_out, v_out : ndarray, shape (n, 3)
            Its output (copied).
        h : float
            Its size [s].
        a_out : ndarray, shape (n, 3)
            Acceleration [m/s^2] at the output (kept as given).
        used : tuple or None
            The history record the step used (what :meth:`lookup` returned for its input).
        """
        self.last = dict(q_in=q_in.copy(), v_in=v_in.copy(), q_out=q_out.copy(), v_out=v_out.copy(), h=float(h),
                         a_out=a_out, used=used)

    def lookup(self, q, v):
        """History record for a step from ``(q, v)``: ``(q_prev, v_prev, h_prev, a_n)`` or None.

        Parameters
        ----------
        q, v : ndarray, shape (n, 3)
            Positions [m] and velocities [m/s] the next step starts from.

        Returns
        -------
        tuple or None
            ``(q_prev, v_prev, h_prev, a_n)`` when ``(q, v)`` is the last step's output (a continuation);
            the record the last step used when it is that step's input (a retry); else None.
        """
        L = self.last
        if L is None:
            return None
        eq = self.system.all_equal
        if eq(q, L["q_out"]) and eq(v, L["v_out"]):
            return (L["q_in"], L["v_in"], L["h"], L["a_out"])
        if eq(q, L["q_in"]) and eq(v, L["v_in"]):
            return L["used"]
        return None

    def clear(self):
        """Forget the last step: the next one starts afresh."""
        self.last = None


class IntegratorBDF2(ImplicitIntegrator):
    """Variable-step BDF2 with an implicit Euler start; see the module docstring.

    Parameters
    ----------
    model : Model
        The model.
    **options
        Keyword options of :class:`~springsim.integrators.ImplicitIntegrator`.

    Attributes
    ----------
    error_estimate : tuple of ndarray (N, 3) or None
        Local error estimate ``(err_q [m], err_v [m/s])`` of the last step; filtered
        (``filter_estimates=True``), it is computed only while ``estimating`` is set (adaptive runs set it).
    """

    name = "bdf2"
    default_newton_maxiter = 50  # see ImplicitIntegrator (newton_maxiter)
    order = 2
    has_error_estimate = True
    #: The filtered estimate is more accurate, but on stiff cloth it took 1.2-1.5x the steps at each tolerance and
    #: 1.3-1.6x the CPU at equal error (one more solve per step; docs/accuracy.md): off unless asked for.
    default_filter_estimates = False
    #: Largest step ratio ``w`` the adaptive driver uses (variable-step BDF2 is zero-stable for w < 1 + sqrt(2)).
    max_step_ratio = 2.0

    def __init__(self, model, **options):
        super().__init__(model, **options)
        self.history = StepHistory(self.system)

    def reset(self):
        super().reset()
        self.history.clear()

    def after_retake(self):
        self.history.clear()

    def advance(self, q, v, h, stats):
        """One BDF2 step, continuing the history when ``(q, v)`` is the last step's output (or retrying its
        input), else an implicit Euler start step (module docstring); sets :attr:`error_estimate`."""
        hist = self.history.lookup(q, v)
        if hist is not None:
            q_prev, v_prev, h_prev, a_n = hist
            w = h / h_prev
            den = 1.0 + 2.0 * w
            ca, cb = (1.0 + w) ** 2 / den, w * w / den
            c = h * (1.0 + w) / den
            q_hat = ca * q - cb * q_prev
            v_hat = ca * v - cb * v_prev
            q1, v1, ok = self.solve_stage(q_hat, v_hat, c, v, stats, guesses=self.predict(v, h))
            c_est = c
            q1[self.fixed] = q[self.fixed]  # a1 q - a2 q_prev rounds: keep fixed particles bit-exact
            a1 = (v1 - v_hat) / c
            k = c / (c + h)
            self.error_estimate = (k * (q1 - _hermite_predict(q, v, q_prev, h_prev, h)),
                                   k * (v1 - _hermite_predict(v, a_n, v_prev, h_prev, h)))
            gain = self.gained_energy(q, v, q1, v1) if ok else None
            if gain is not None:  # restart the history from an implicit Euler step
                hist = None
                a_n = self.acceleration(q, v).copy()
                q1, v1, _, self.error_estimate = self.retake_implicit_euler(
                    q, v, h, a_n, stats, f"bdf2 step created {gain:.3g} J")
                a1 = (v1 - v) / h
                c_est = h
        else:
            a_n = self.acceleration(q, v).copy()
            q1, v1, _, self.error_estimate = self.implicit_euler_stage(q, v, h, a_n, stats)
            a1 = (v1 - v) / h
            c_est = h
            stats.extra["bdf2_start"] = True
        self.error_estimate = self.finish_estimate(q1, v1, c_est, self.error_estimate, stats)
        a1[self.fixed] = 0.0
        if stats.ok:
            self.history.record(q, v, q1, v1, h, a1, hist)
        else:  # the two-step recurrence would amplify an unconverged stage: the retake restarts the history
            self.history.clear()
        return q1, v1


def _hermite_predict(y, dy, y_prev, h_prev, h):
    """Quadratic through ``y_prev`` at ``-h_prev`` and ``y`` at 0 with slope ``dy`` at 0, evaluated at ``h``."""
    alpha = (y_prev - y + h_prev * dy) / (h_prev * h_prev)
    return y + h * dy + (h * h) * alpha
