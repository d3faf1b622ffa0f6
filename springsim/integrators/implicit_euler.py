"""Full implicit Euler (PA2 eqs. 1-2).

``qd^{n+1} = qd^n + h M^-1 F(q^{n+1}, qd^{n+1})``, ``q^{n+1} = q^n + h qd^{n+1}``: one stage with ``c = h``,
``q_hat = q^n``, ``v_hat = qd^n`` (:mod:`springsim.integrators._stage`). By default the stage minimises the
incremental potential ``E(x) = 1/(2h^2) |x - q^n - h qd^n|_M^2 + V(x) + h Psi(...)`` with projected Newton and
a line search on ``E``, stopping on its gradient; ``stage_solver="pa2"`` is PA2's Newton exactly (each
iteration solves ``[M - h^2 dF/dq - h dF/dqd] dqd = -M (qd_i - qd^n) + h F(q^n + h qd_i, qd_i)`` from
``qd_0 = qd^n`` and stops when ``|dqd|_2 < newton_tol`` or after 5 iterations). Order 1, L-stable (strongly
damped at large ``h``).
"""

from __future__ import annotations

from ._implicit import ImplicitIntegrator

__all__ = ["IntegratorImplicitEuler"]


class IntegratorImplicitEuler(ImplicitIntegrator):
    """Implicit Euler; options as :class:`~springsim.integrators.ImplicitIntegrator`."""

    name = "implicit_euler"

    def advance(self, q, v, h, stats):
        """One implicit Euler step of size ``h`` from ``(q, v)``: one stage with ``c = h`` (module docstring)."""
        q1, v1, _ = self.solve_stage(q, v, h, v, stats, guesses=self.predict(v, h))
        return q1, v1
