"""Energy-momentum method (Simo and Tarnow 1992; Gonzalez 1996): the discrete-gradient midpoint scheme.

One step of size ``h`` from ``(q_0, v_0)``::

    q_1 = q_0 + h (v_0 + v_1) / 2
    M (v_1 - v_0) = h [ -grad_bar V(q_0, q_1) + F_d((q_0 + q_1)/2, (v_0 + v_1)/2) ]

where ``grad_bar V`` is a discrete gradient of the potential energy (springs, gravitational
pairs, gravity): ``grad_bar V . (q_1 - q_0) = V(q_1) - V(q_0)`` exactly
(:meth:`~springsim.forces.ForceTerm.eval_force_discrete`), and ``F_d`` the dissipative forces
(spring damping, drag) at the midpoint. Taking the dot product of the momentum equation with
``q_1 - q_0 = h (v_0 + v_1)/2`` gives the discrete energy balance::

    E_1 - E_0 = h F_d . (v_0 + v_1)/2 <= 0

so the total energy never grows, whatever the stiffness and step, once the stage equation is solved
(to the Newton tolerance; a step whose stage is not solved is reported, see "Retake"). The implicit
midpoint rule, ``F`` at the midpoint, has no such bound: on stiff nonlinear springs it gains energy
and blows up (Simo and Tarnow 1992). Pair forces act along the midpoint's pair vector, so linear and angular
momentum are conserved when the external forces vanish. Second order, symmetric, not L-stable: like
the trapezoidal rule it does not damp what it cannot resolve, it keeps its energy in those modes.

The unknown is the mean velocity ``w = (v_0 + v_1)/2``: ``q_1 = q_0 + h w`` and
``M (w - v_0) = (h/2) F_bar``, the Newton stage of :class:`~springsim.integrators.ImplicitIntegrator`
with ``c = h/2``, ``q_hat = q_0``, ``v_hat = v_0`` and the stage position ``q_0 + c w``, the midpoint.
Newton's matrix is ``M - c^2 K - c D`` with ``K`` and ``D`` the derivatives of the discrete force with
respect to the midpoint and the velocity (:meth:`~springsim.forces.ForceTerm.eval_jacobians_discrete`;
the midpoint force's Jacobians differ from them by terms of order ``k |q_1 - q_0|``, which at animation
steps on stiff cloth make Newton diverge); the stopping rule (residual and update) is that of implicit
Euler. The stopping rule bounds the update of ``w``; ``v_1 = 2 w - v_0`` carries twice its error. The
exact ``K`` is not symmetric; the ``symmetric`` and ``spd`` modes (for AMG-CG) are the symmetric variants
the force terms document, with which Newton converges only linearly.

Retake. A step whose stage does not converge, whose matrix lost the masses (ill-conditioned) or whose
linear solve gave a non-finite solution is retaken in 2, 4, ... 32 equal substeps (each halving makes
``c^2 K`` 4x smaller); the first attempt that succeeds in every substep is kept, the abandoned ones are
listed in ``StepStats.extra["retaken"]`` and the count in ``["substeps"]``. If even 32 substeps fail, the
step is reported as not ``ok`` (or the :class:`~springsim.errors.SolverError` is raised). Retaking it as
implicit Euler, as TR-BDF2 does, would not help: its stage coefficient ``c = h`` is twice this one's, so
its Newton fails first (on the 8 x 8 benchmark cloth at ``h = 0.1 s`` it did, and the unconverged result
gained 200 J).

Error estimate (adaptive stepping, :func:`springsim.run.adaptive.simulate_adaptive`). The method has no
embedded pair, and the predictor-corrector difference of multistep codes (Milne's device) measures a
multiple of ``y'''``, which is not the midpoint rule's local error on nonlinear problems. So the estimate
is step doubling (Hairer, Norsett and Wanner 1993, sec. II.4): while ``estimating`` is set (adaptive
runs) a step of size ``h`` is two steps of ``h/2``, giving the result ``y_2``, and one step of ``h`` from
the same state, giving ``y_1``. With local error ``C h^3`` per step, ``y_1 - y_2 = (3/4) C h^3`` to
leading order and the result's local error is::

    err = (y_1 - y_2) / 3

asymptotically exact for any smooth problem. It estimates the error of the returned two-step result,
which keeps the energy balance (a Richardson-extrapolated result would not). Newton starts the full step
from the half steps' mean velocity ``(v_0 + v_2)/2``, so it costs a few iterations. A failure in any of
the three (Newton, a linear solve, conditioning) fails the step; the adaptive driver retries it smaller,
in place of the retake below.

References: J. C. Simo and N. Tarnow, "The discrete energy-momentum method. Conserving algorithms
for nonlinear elastodynamics", ZAMP 43 (1992) 757-792; O. Gonzalez, "Time integration and discrete
Hamiltonian systems", J. Nonlinear Sci. 6 (1996) 449-467; E. Hairer, S. P. Norsett and G. Wanner,
"Solving Ordinary Differential Equations I", 2nd ed., Springer (1993).
"""

from __future__ import annotations

import numpy as np

from ._implicit import ImplicitIntegrator

__all__ = ["IntegratorEnergyMomentum"]


class IntegratorEnergyMomentum(ImplicitIntegrator):
    """The energy-momentum (discrete-gradient midpoint) method; see the module docstring.

    Parameters
    ----------
    model : Model
        The model.
    **options
        Keyword options of :class:`~springsim.integrators.ImplicitIntegrator`.

    Attributes
    ----------
    estimating : bool
        Compute :attr:`error_estimate` by step doubling (module docstring); set during adaptive runs.
    error_estimate : tuple of ndarray (N, 3) or None
        Local error estimate ``(err_q [m], err_v [m/s])`` of the last step taken while estimating.
    """

    name = "energy_momentum"
    default_newton_maxiter = 50  # see ImplicitIntegrator (newton_maxiter)
    order = 2
    has_error_estimate = True
    error_estimate_costs = True
    default_filter_estimates = False
    #: The discrete gradient is not the gradient of a potential: Newton on the residual (or the seed's rule)
    stage_solvers = ("residual", "pa2")

    def __init__(self, model, **options):
        super().__init__(model, **options)
        self._q_start: np.ndarray | None = None  # q_0 while the discrete-gradient stage is solved

    def stage_overrides(self):
        """The discrete-gradient force and its matrix, while the energy-momentum stage is solved.

        Returns
        -------
        dict
            ``forces(q, v, f)``: the force over the step from ``q_0`` to ``2 q - q_0`` (the stage position is the
            midpoint), and ``matrix(q, v, c, mode)``: its stage matrix; empty for any other stage.
        """
        if self._q_start is None:  # a stage other than the discrete-gradient one
            return {}
        q0, sysm = self._q_start, self.system

        def forces(q, v, f):  # the stage position is the midpoint: q_1 = 2 q - q_0
            return sysm.forces_discrete(q0, 2.0 * q - q0, v, f)

        def matrix(q, v, c, mode):
            return sysm.assemble(q, v, c * c, c, mode, q_start=q0)

        return dict(forces=forces, matrix=matrix)

    def _substep(self, q, v, h, stats, w0=None):
        """One energy-momentum step of size ``h`` from ``(q, v)``, Newton from ``w0`` (default ``v``):
        ``(q1, v1, ok)``."""
        self._q_start = q
        try:
            _, w, ok = self.solve_stage(q, v, 0.5 * h, v if w0 is None else w0, stats)
        finally:
            self._q_start = None
        q1 = q + h * w
        q1[self.fixed] = q[self.fixed]
        v1 = 2.0 * w - v
        v1[self.fixed] = 0.0
        return q1, v1, ok

    def _doubled(self, q, v, h, stats):
        """Two steps of ``h/2``, the result, and the error estimate from one of ``h`` (module docstring):
        ``(q2, v2)``. Both half steps are always taken; when either fails the full step is skipped and
        :attr:`error_estimate` stays None (``stats`` says why). The step's statistics cover all three stages
        (Newton iterations, solves, the largest precision loss); its final Newton norms are the result's."""
        self.error_estimate = None
        q2, v2, ok_a = self._substep(q, v, 0.5 * h, stats)
        q2, v2, ok_b = self._substep(q2, v2, 0.5 * h, stats)
        if ok_a and ok_b and stats.ok:
            result = stats.newton_step_norm, stats.residual_norm, stats.residual_ratio
            q1, v1, ok = self._substep(q, v, h, stats, w0=0.5 * (v + v2))
            if ok and stats.ok:
                stats.newton_step_norm, stats.residual_norm, stats.residual_ratio = result
                self.error_estimate = ((q1 - q2) / 3.0, (v1 - v2) / 3.0)
                return q2, v2
        if stats.ok:  # never a step that passes as ok without its estimate
            stats.newton_converged = False
            stats.fail("energy_momentum: a stage of the step-doubling estimate did not converge")
        return q2, v2

    def advance(self, q, v, h, stats):
        """One energy-momentum step; while :attr:`estimating`, two half steps and the error estimate from
        the full one (step doubling, module docstring)."""
        if self.estimating:
            return self._doubled(q, v, h, stats)
        q1, v1, _ = self._substep(q, v, h, stats)
        return q1, v1
