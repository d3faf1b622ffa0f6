"""The stage solver of every implicit integrator, written once over the system interface.

Every implicit method here reduces each step (or stage) to finding the velocity ``v`` with::

    R(v) = c F(q_hat + c v, v) - M (v - v_hat) = 0          q = q_hat + c v

for known ``q_hat``, ``v_hat`` and coefficient ``c`` (implicit Euler: ``c = h``, ``q_hat = q^n``,
``v_hat = qd^n``, PA2 eqs. 1-2; BDF2, TR-BDF2 and energy-momentum: their own, see their modules). Newton's
update ``dv`` solves::

    [M - c^2 dF/dq - c dF/dqd] dv = R(v_i)                  (A dv = R)

over the free DOFs (row and column elimination, :mod:`springsim.assembly.fixed`), through the
:class:`~springsim.system.System` of the integrator, so the same code runs serially and on PETSc.

Three rules decide how the iteration is globalised and when it stops (``stage_solver``):

``"minimize"`` (the default where every force term is conservative or dissipative)
    The stage is the minimisation of the incremental potential (Gast, Schroeder, Stomakhin, Jiang and
    Teran 2015; Li et al. 2020, IPC's projected Newton) in the stage position ``x = q_hat + c v``::

        E(x) = 1/(2 c^2) |x - x_tilde|_M^2 + V(x) + c Psi_g((x - q_hat)/c),   x_tilde = q_hat + c v_hat

    with ``V`` the potential of the conservative terms (springs, gravity, gravitational pairs) and ``Psi_g``
    the Rayleigh dissipation function of the damping (spring damping, drag) with its geometry frozen at
    ``g = x_tilde``, the inertial predictor (:meth:`~springsim.forces.ForceTerm.dissipation`). Its gradient
    is ``grad E = -R / c``, a force [N]: the stage's force imbalance, with the damping force taken along the
    directions of ``x_tilde``. Freezing the direction changes the damping force by ``O(|x - x_tilde|) =
    O(c^2)``, so first- and second-order methods keep their order; the dissipation stays a convex potential,
    so damped scenes keep the guarantee below. Newton's matrix is the projected Hessian ``c^2 H = A`` in
    the ``mixed`` mode (default; or ``spd``: compressed springs' transverse term clamped at 0, gravitational
    pairs' negative eigenvalue clamped, damping ``D >= 0``; ``mixed`` also takes each spring's tension in
    that term from the previous iterate's linearisation, :mod:`springsim.forces.spring`), so ``A >= M`` is
    positive definite by construction, ``dv`` is a descent direction and a backtracking (Armijo) line search
    on ``E`` itself always finds a decrease. Two refinements for nonconvex stages: where a full step from a
    solve to the solver's own tolerance lowers ``E`` by more than its quadratic model allows, beyond ``E``'s
    round-off (negative curvature the projection removed), the step is doubled while ``E`` keeps falling by
    more than its round-off; and where full steps stall (three in a row each reducing ``|grad E|`` by less
    than 30 %: the projection of a slack cloth's compressed springs is far stiffer than ``E``), the
    stage continues with ``E``'s exact Hessian (the ``symmetric`` mode, the damping frozen), positive definite
    near a minimum, for as long as it gives descent directions and the solver takes indefinite matrices (on
    the README's builder cloth, 32 x 32 held at two corners: implicit Euler 144 -> 28 iterations per step). A
    stage stops when the gradient is small in newtons against the forces it balances::

        |grad E|_2 <= force_atol + force_rtol f_ref,    f_ref = |M (v - v_hat)|_2 / c + |F|_2 + |M g|_2

    (2-norms over free DOFs at the current iterate: inertia, applied force and, as a floor, the free particles'
    weight ``|M g|``), or, when round-off leaves no decrease to find, when the gradient is within ``1e3`` times
    that and the line search reports stagnation. Measured against the iterate's own forces, the rule does not
    loosen when the starting iterate is far off (a stiff spring stretched by the predictor exerts forces many
    orders above the motion's). Damped or not, the largest ``E`` of the last five iterates falls at every iteration
    and no iterate's ``E`` exceeds the start's (below, "Nonmonotone line search").

    The default ``force_rtol = 1e-3`` puts the stage's own error well below the step's truncation error. A
    gradient ``g`` left in the stage moves its solution by about ``c^2 M^-1 g`` along the mass-dominated directions
    of the Hessian (``c^2 H >= M`` where ``E`` is convex; less along the stiff ones). Where the inertia dominates the
    force scale, ``|g| <= force_rtol |M (v - v_hat)| / c`` bounds that by ``force_rtol c |v - v_hat|``, ``2
    force_rtol`` times implicit Euler's local truncation error ``c |v - v_hat| / 2 = h^2 |a| / 2``: 0.2 %. Stiff
    ODE codes stop Newton at a fraction of their error test in the same way (CVODE at 0.1 of it, Hindmarsh et al.
    2005; scipy's BDF at ``min(0.03, rtol^0.5)``). On the benchmark cloth (n = 32, 30 frames at h = 1/60 s, ke =
    1e4 and 1e6, undamped and damped; BENCHMARKS.md#stiff-convergence) runs at 1e-3 stay within
    0.13 mm RMS of runs at 1e-8 (or as far as runs at 1e-5 are, where the buckling took another branch), against
    errors of 0.8-5 cm from the validated reference, and take 3.1-9.5 Newton iterations per stage instead of
    3.7-10.3 at the former default 1e-5 (both with a monotone line search). Adaptive stepping caps the tolerance at
    ``0.1 time_rtol`` (:attr:`StageSolver.force_rtol_cap`), so that the Newton error stays below its error test.

``"residual"``
    Newton on the residual with a backtracking line search on ``|R|`` (Armijo on ``1/2 |R|^2``), stopping
    when ``|dv|_2 < newton_tol`` and ``|R|_2 / (|c F|_2 + |M (v - v_hat)|_2 + newton_tol |m|_2) <=
    residual_rtol``, with the escalation from the projected to the exact Jacobian when it stalls. Used by
    the energy-momentum method, whose discrete gradient is not the gradient of a potential.

``"pa2"``
    The seed's rule (PA2 section 4): plain Newton from ``v_0``, no line search, stop when
    ``|dv|_2 < newton_tol`` or after ``newton_maxiter`` (5) iterations, exact Jacobian: the course code,
    reproduced.

Linearized implicit Euler is one plain iteration of any of them (``converge=False``).

Stalls. Where the solver cannot take ``E``'s exact Hessian (CG-type solvers), a ``minimize`` stage that has not
halved ``|grad E|`` in its last 10 iterations stops unconverged (a slack, buckling cloth whose projected Hessian
is far from ``E``'s):
its step is then retaken in substeps (:mod:`springsim.integrators._implicit`), whose stages are closer to convex,
instead of spending the rest of ``newton_maxiter`` on it. The last retake, with nothing smaller to fall back on,
runs to ``newton_maxiter``.

Curved steps. On very stiff springs a full Newton step that turns a spring moves its end along the tangent,
and the spring's length grows by ``|dd_perp|^2 / (2 l)`` where the linearisation saw none: ``E`` rises by
``k`` times the square of that, and the line search cuts the step to a fraction (the Maratos effect of
constrained optimisation). Before backtracking, a rejected full step is given a second-order correction
(Nocedal and Wright 2006, section 18.3): ``dv' = dv + A^-1 (c F_r)`` with the same matrix ``A`` (its
factorisation or hierarchy reused) and ``F_r`` the force of the springs' length remainders along their
directions at the iterate (:meth:`~springsim.forces.ForceTerm.curvature_remainder`), which pulls the turned
ends back onto the arcs; it is kept where it passes the same Armijo test against ``dv``'s slope. On the
benchmark cloth (n = 16, h = 1/60 s, ke = 1e8) this takes implicit Euler from 15.0 to 9.6 Newton iterations per
step and TR-BDF2 from 8.2 to 5.8 per stage.

Nonmonotone line search. The Armijo test compares a trial's ``E`` with the largest ``E`` of the last five iterates
rather than the current one (Grippo, Lampariello and Lucidi 1986; Nocedal and Wright 2006, section 3.5, where
the watchdog technique of section 15.6 has the same purpose). Where the second-order correction does not bring
a turned spring back onto its arc, a full Newton step raises ``E`` a little before the next one lowers it far
more. A monotone search cut such steps to 1/8-1/16 of their length, and the stage crawled; in the damped
benchmark cloth at ke = 1e6 (n = 32) a stage took 50 iterations of alternating full and cut steps that way.
The reference value, the largest ``E`` of the window, never rises, so the stage still converges to a
stationary point of ``E`` under the same conditions as the monotone search (GLL's theorem). Over 30 frames of
the benchmark cloth (n = 32, h = 1/60 s) the Newton iterations per stage fell at ke = 1e8 from 15.8 to 11.5
(implicit Euler), 23.0 to 18.0 (BDF2) and 11.2 to 8.7 (TR-BDF2), by up to 14 % at ke = 1e6, and the errors
against the validated reference stayed the same (BENCHMARKS.md#stiff-convergence).

Starting point. A stage starts from the velocity its method gives (``v0``: the step's input velocity, or the
previous stage's); the integrators also offer predictors (:meth:`ImplicitIntegrator.predict
<springsim.integrators.ImplicitIntegrator.predict>`: the input velocity advanced with the acceleration of the
last step taken), and the ``minimize`` rule starts from whichever has the lowest ``E``, one evaluation of ``E``
each. The start does not change what the stage converges to (the minimiser, to the tolerance), only how many
iterations it takes: on the benchmark cloth (n = 16, h = 1/60 s) implicit Euler needs 3.5, 5.2 and 15.6 Newton
iterations per step at ke = 1e4, 1e6 and 1e8 instead of 4.5, 7.3 and 24.3 from the input velocity.

Forcing. With ``forcing="eisenstat-walker"`` the linear solves of a stage run to convergence are inexact
Newton steps (Dembo, Eisenstat and Steihaug 1982): each solve of ``A dv = R`` stops at the relative residual
``eta_k`` of Eisenstat and Walker (1996, choice 2; :func:`forcing_term`), never below the system's linear
``rtol``. An update from a loose solve can pass a stopping rule while the iterate is not converged, so it is
confirmed by one more solve to ``rtol`` (:class:`StageForcing`).

Linear solves. In a ``minimize`` stage a solve need not be more accurate than the stopping rule needs: a Newton
step whose linear residual is ``eta |R|`` leaves a gradient of about ``eta |grad E|`` plus the quadratic
remainder, so the solve from an iterate with ``|grad E| = g`` stops at the relative residual ``max(rtol, min(s
tol / g, 0.1))`` (``tol`` the stage's stopping tolerance, ``rtol`` the system's): the solver's own tolerance
while the gradient is far above ``tol``, looser in the last iterations (the gradient at the new iterate,
evaluated exactly, still decides). The share is ``s = 0.5`` up to a stiffness ratio ``S = 1.6e7`` of the stage
matrix and ``s = 0.5 sqrt(1.6e7 / S)`` above it (:func:`solve_share`), with ``S = max_i max|D_i| / m_i`` over its
3x3 diagonal blocks (:meth:`~springsim.system.System.precision_loss` over the unit round-off; about ``4 c^2 k /
m`` on a cloth). The remainder is what the loose solve leaves in the soft directions: a velocity error ``e``
there, which the residual weighs by the mass alone, moves a particle by ``c e`` across a spring of stiffness
``k`` and length ``l`` and stretches it to second order, a gradient of ``k (c e)^2 / (2 l)``; kept below the
tolerance, that bounds the residual share by a multiple of ``sqrt(m^2 / (c^4 k))``, ``S^-1/2`` at fixed mass and
step. The constants were measured on the benchmark cloth at h = 1/60 s with AMG-CG, 30 frames: with ``s = 0.5``
at ke = 1e8 and n = 64 the stages alternated between loose steps that turned stiff springs and steps that took the
stretch back (implicit Euler, ``S`` = 4.6e8: 65 Newton iterations per step against about 20 with ``s = 0.05``, and
2.1x the CPU; TR-BDF2, ``S`` = 3.9e7: 51 Newton iterations per stage against 24 with ``s = 0.32``); at ke = 1e4 and
1e6 (``S`` up to 4.6e6) ``s = 0.5`` cost the least CPU, and TR-BDF2 at n = 128, ke = 1e7 (``S`` = 1.6e7) took
about the same Newton iterations with 0.5 and 0.28 and less CPU with 0.5 (benchmark notes on loose solves on
stiff cloth). A solve that missed its criterion is still a usable search direction (inexact Newton) in a stage whose
own stopping rule then certifies the result (counted in ``StepStats.extra["recovered_linear_failures"]``); in a
stage that does not converge, and in linearized implicit Euler, it fails the step (``StepStats.linear_failures``).
A non-finite solution ends the step with :class:`~springsim.errors.SolverError`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..errors import SceneError, SolverError
from ..forces import JACOBIAN_MODES, PROJECTED_MODES
from ._base import PRECISION_LOSS_LIMIT, StepStats
from ._options import ByRule, DefaultRule, OptionGroup, option

__all__ = ["STAGE_SOLVERS", "FORCING_RULES", "NewtonOptions", "StageOptions", "StageSolver", "StageForcing",
           "forcing_term", "backtrack", "record_linear_solve", "report_stage", "check_count", "solve_share"]

#: Rules of the stage solver (module docstring).
STAGE_SOLVERS = ("minimize", "residual", "pa2")
#: Rules for the relative tolerance of a Newton stage's linear solves (``forcing``; module docstring).
FORCING_RULES = ("fixed", "eisenstat-walker")
#: Armijo's sufficient-decrease constant.
_ARMIJO = 1e-4
#: A minimisation stage that has not halved its gradient norm in this many iterations stops (module docstring,
#: "Stalls").
_STALL_WINDOW = 10
#: A minimisation stage's linear solve need not leave a residual below this share of the stopping tolerance
#: (module docstring, "Linear solves"), nor be looser than ``_SOLVE_LOOSEST``; the share falls as
#: ``sqrt(_SOLVE_STIFF / S)`` above the stiffness ratio ``S = _SOLVE_STIFF`` of the stage matrix.
_SOLVE_SHARE, _SOLVE_LOOSEST, _SOLVE_STIFF = 0.5, 0.1, 1.6e7
#: The Armijo test of a minimisation stage compares with the largest ``E`` of this many last iterates (module
#: docstring, "Nonmonotone line search").
_NONMONOTONE = 5


def solve_share(precision_loss: float) -> float:
    """Share of a ``minimize`` stage's stopping tolerance its linear solves may leave as residual (module
    docstring, "Linear solves").

    Parameters
    ----------
    precision_loss : float
        The stage matrix's :meth:`~springsim.system.System.precision_loss`, ``u max_i max|D_i| / m_i``
        (``u`` the unit round-off): ``S = precision_loss / u`` is its stiffness ratio.

    Returns
    -------
    float
        ``0.5 min(1, sqrt(1.6e7 / S))``.
    """
    ratio = precision_loss / np.finfo(np.float64).eps
    return _SOLVE_SHARE * float(np.sqrt(_SOLVE_STIFF / ratio)) if ratio > _SOLVE_STIFF else _SOLVE_SHARE


def forcing_term(k: int, rnorm: float, rnorm_prev: float, eta_prev: float, *, eta_max: float, floor: float) -> float:
    """Relative tolerance of the ``k``-th linear solve of a Newton stage (Eisenstat and Walker 1996, choice 2).

    ``eta_0 = eta_max``; then ``eta_k = 0.9 (|R_k| / |R_{k-1}|)^2``, safeguarded by ``0.9 eta_{k-1}^2`` when that
    exceeds 0.1 (a sudden drop of ``|R|`` does not make one solve needlessly tight), capped at ``eta_max`` and
    never below ``floor`` (the solver's ``rtol``).

    Parameters
    ----------
    k : int
        Index of the solve in the stage (0 first).
    rnorm, rnorm_prev : float
        Residual norms before this solve and before the previous one.
    eta_prev : float
        The previous solve's forcing term.
    eta_max, floor : float
        Upper and lower bounds.

    Returns
    -------
    float
        The relative tolerance of this solve.
    """
    if k == 0 or not (rnorm_prev > 0.0 and np.isfinite(rnorm)):
        eta = eta_max
    else:
        eta = 0.9 * (rnorm / rnorm_prev) ** 2
        safeguard = 0.9 * eta_prev ** 2
        if safeguard > 0.1:
            eta = max(eta, safeguard)
    return max(min(eta, eta_max), floor)


class StageForcing:
    """The linear tolerances of one Newton stage (module docstring, "Forcing").

    :meth:`rtol` before each solve gives its relative tolerance (None: the solver's own, the ``"fixed"``
    rule); :meth:`certified` tells whether an update that passed the stopping rule may end the stage (it came
    from a solve to ``floor``), and otherwise makes the next solve one to ``floor``.

    Parameters
    ----------
    rule : {"fixed", "eisenstat-walker"}
    eta_max : float
        First and largest forcing term.
    floor : float
        Smallest forcing term (the linear solver's ``rtol``).
    """

    def __init__(self, rule: str, *, eta_max: float, floor: float):
        self.on = rule == "eisenstat-walker"
        self.eta_max, self.floor = eta_max, floor
        self.k, self.eta, self.rnorm_prev, self.confirm = 0, 0.0, 0.0, False

    def rtol(self, rnorm: float) -> float | None:
        """The next solve's relative tolerance, given the residual norm ``|R|`` it solves for."""
        if not self.on:
            return None
        self.eta = self.floor if self.confirm else forcing_term(self.k, rnorm, self.rnorm_prev, self.eta,
                                                                eta_max=self.eta_max, floor=self.floor)
        self.k, self.rnorm_prev = self.k + 1, rnorm
        return self.eta

    def certified(self, residual: float) -> bool:
        """Whether the update of a solve that reached the relative residual ``residual`` may end the stage."""
        if not self.on or residual <= self.floor:
            return True
        self.confirm = True  # a loose update passed: the next one is solved to the floor and decides
        return False


def backtrack(trial, rnorm: float, *, enabled: bool, min_step: float):
    """Backtracking line search on ``|R|`` (Armijo on the merit ``1/2 |R|^2``): ``(alpha, trial(alpha))``.

    ``trial(alpha)`` evaluates the iterate at step ``alpha`` and returns a tuple whose fourth entry is its
    residual norm. ``alpha`` halves from 1 until ``|R|`` decreases by ``1e-4 alpha`` relatively, ``alpha``
    reaches ``min_step``, or (``enabled`` False) at once. The trial's residual is the next iteration's, so
    a full step costs nothing extra; near the solution full steps are taken and quadratic convergence kept.
    """
    alpha = 1.0
    while True:
        result = trial(alpha)
        rn = result[3]
        if not enabled or rn <= (1.0 - _ARMIJO * alpha) * rnorm or alpha <= min_step or not np.isfinite(rnorm):
            return alpha, result
        alpha *= 0.5


def record_linear_solve(stats: StepStats, res, finite: bool) -> str | None:
    """Add a linear solve's cost and outcome to ``stats``; the failure to judge at the stage's end, or None.

    ``finite``: whether the solution is finite everywhere (on every rank, for a distributed solve).

    Raises
    ------
    SolverError
        For a non-finite solution: there is no direction to continue from.
    """
    stats.solve_s += res.time_s
    stats.linear_iterations += res.iterations
    stats.linear_solves += 1
    stats.linear_residual = max(stats.linear_residual, res.residual)
    if res.fallback:
        stats.fallbacks.append(f"{res.method}: {res.fallback}")
    if not finite:
        raise SolverError(f"linear solver {res.method!r} failed: {res.failure or 'non-finite solution'}")
    return None if res.converged else f"linear solve ({res.method}) failed: {res.failure}"


def report_stage(stats: StepStats, *, converge: bool, converged: bool, failed: list, why: str) -> bool:
    """Record the outcome of a stage in ``stats`` (module docstring); whether the stage is ok.

    ``failed``: its failed linear solves. In a stage run to convergence (``converge``) that converged they were
    inexact Newton directions certified by the stopping rule (counted as recovered); otherwise they fail the step.
    ``why``: the reason of a non-converged stage. Ill-conditioning is reported for the step but does not fail the
    stage: retaking it another way would not make the conditioning better.
    """
    if converge:
        if converged and failed:
            stats.extra["recovered_linear_failures"] = stats.extra.get("recovered_linear_failures", 0) + len(failed)
            failed = []
        if not converged:
            stats.newton_converged = False
            stats.fail(why)
    stats.linear_failures += len(failed)
    for reason in failed:
        stats.fail(reason)
    if stats.ill_conditioned:
        stats.fail(f"ill-conditioned matrix: it holds the masses only to {stats.precision_loss:.1e} "
                   f"(limit {PRECISION_LOSS_LIMIT:g}); reduce the step or soften the stiffest pairs")
    return not failed and (converged or not converge)


def check_count(name: str, value) -> None:
    """A SceneError naming the parameter ``name`` unless ``value`` is an integer >= 1."""
    if isinstance(value, bool) or int(value) != value or value < 1:
        raise SceneError(name, f"must be an integer >= 1, got {value!r:.60}")


def _default_stage_solver(integrator, given, resolved) -> str:
    """the method's first stage rule (minimize; energy_momentum: residual), residual where a force has no potential
    or the jacobian given is not a projected mode

    Parameters
    ----------
    integrator : ImplicitIntegrator
        The integrator being built (its ``stage_solvers`` and force terms).
    given : NewtonOptions
        The options given.
    resolved : dict
        The fields resolved so far.

    Returns
    -------
    str
        A stage rule.
    """
    rule = integrator.stage_solvers[0]
    # a minimisation needs forces with a potential and a projected Hessian: a Jacobian mode that is not one asks
    # for Newton on the residual
    if rule == "minimize" and (not _has_potential(integrator) or given.jacobian not in (None, *PROJECTED_MODES)):
        rule = "residual"
    return rule


def _default_jacobian(integrator, given, resolved) -> str:
    """mixed for minimize stages, else exact where the solver takes any matrix and spd where it needs SPD matrices

    Parameters
    ----------
    integrator : ImplicitIntegrator
        The integrator being built (its system's :meth:`~springsim.system.System.default_jacobian`).
    given : NewtonOptions
        The options given.
    resolved : dict
        The fields resolved so far (``stage_solver``).

    Returns
    -------
    str
        A Jacobian mode.
    """
    return "mixed" if resolved["stage_solver"] == "minimize" else integrator.system.default_jacobian()


def _has_potential(integrator) -> bool:
    """Whether every force term of ``integrator`` is conservative or dissipative (a stage is then a minimisation)."""
    return all(t.conservative or t.dissipative for t in integrator.terms)


#: Every stage rule, and ``"plain"``: a fixed number of plain Newton iterations (``converge=False``), linearized
#: implicit Euler's step.
_ALL = (*STAGE_SOLVERS, "plain")
_CONVERGED = STAGE_SOLVERS


@dataclass(frozen=True)
class NewtonOptions(OptionGroup):
    """How the stages of implicit integrators are solved: the stage rule, its Jacobian, stopping rule and limits.

    Each field is declared once (:func:`~springsim.integrators._options.option`: type, bounds, default, YAML key,
    flag, help, and the stage rules that read it); ``None`` stands for the declared default, which may depend on
    the stage rule and the integrator (:meth:`resolve`). The group is frozen and checked on construction; the
    stage solver (:class:`StageSolver`) takes a resolved one (:meth:`resolve`), so nothing is checked twice.

    Parameters
    ----------
    stage_solver : {"minimize", "residual", "pa2"}, optional
        How stages are solved (module docstring). Default: the integrator's first rule (``minimize``;
        ``residual`` for the energy-momentum method), ``residual`` where a force term has no potential or
        ``jacobian`` is not a projected mode.
    jacobian : {"exact", "symmetric", "spd", "mixed"}, optional
        Jacobian mode of Newton's matrix (:data:`springsim.forces.JACOBIAN_MODES`); ``minimize`` needs a projected
        one. Default ``mixed`` for ``minimize``, else ``spd`` for solvers that need SPD matrices at this size
        (:meth:`~springsim.system.System.default_jacobian`) and ``exact`` otherwise.
    force_rtol, force_atol : float, optional
        Stopping rule of ``minimize``: ``|grad E|_2 <= force_atol + force_rtol f_ref`` [N] (module docstring;
        default ``1e-3``, a Newton error near 0.2 % of implicit Euler's truncation error, and ``0``).
    newton_tol : float, optional
        Update tolerance of ``residual`` and ``pa2``: a stage may stop when ``|dv|_2 < newton_tol`` [m/s]
        (default 1e-5, PA2's).
    newton_maxiter : int, optional
        Iteration limit of a stage: 50 with ``minimize``, 5 with ``pa2`` (PA2), and the integrator's
        ``default_newton_maxiter`` with ``residual`` (5 for implicit Euler, 50 for the others).
    residual_rtol : float, optional
        Residual tolerance of ``residual`` (module docstring), default 1e-3.
    forcing : {"fixed", "eisenstat-walker"}, optional
        Relative tolerance of the linear solves of stages run to convergence: the solver's ``rtol`` (``fixed``,
        the default), or Eisenstat-Walker forcing terms (module docstring, "Forcing").
    forcing_max : float, optional
        Largest (and first) Eisenstat-Walker forcing term, in (0, 1); default 0.1.
    line_search : bool, optional
        Backtrack the update of ``residual`` on ``|R|`` (default True; ``minimize`` always searches on ``E``,
        ``pa2`` never searches).
    min_step : float, optional
        Smallest line-search step, in (0, 1] (default ``2**-20`` for ``minimize``, ``1/64`` otherwise).
    escalate_jacobian : bool, optional
        ``residual`` with the ``spd`` or ``symmetric`` Jacobian: when Newton reaches its limit, continue the
        stage from its last iterate with the ``exact`` Jacobian before reporting non-convergence (default True).
    escalate_after : int, optional
        Iterations with the projected Jacobian before escalating (default: the Newton limit).

    Raises
    ------
    SceneError
        On construction, naming the field of a value its declaration refuses, or ``jacobian`` for a mode that is
        not projected with ``minimize`` stages.
    """

    stage_solver: str | None = option(
        DefaultRule(_default_stage_solver), kind="name", cli="--stage-solver", metavar="RULE", choices=STAGE_SOLVERS,
        what="stage solver", rules=_ALL,
        help="how implicit stages are solved: minimize (the incremental potential, projected Newton and a line "
             "search on it), residual (Newton with a line search on the residual) or pa2 (the course's rule)")
    jacobian: str | None = option(DefaultRule(_default_jacobian), kind="name", cli="--jacobian", metavar="MODE",
                                  choices=JACOBIAN_MODES, what="jacobian mode", rules=_ALL, help="Jacobian mode")
    force_rtol: float | None = option(1e-3, kind="float", cli="--force-rtol", metavar="R", lo=0.0, strict=True,
                                      rules=("minimize",),
                                      help="minimize stages: stop when the force imbalance |grad E| is below this "
                                           "fraction of the stage's force scale")
    force_atol: float | None = option(0.0, kind="float", cli="--force-atol", metavar="F", lo=0.0,
                                      rules=("minimize",),
                                      help="minimize stages: absolute force imbalance tolerance [N]")
    newton_tol: float | None = option(1e-5, kind="float", cli="--newton-tol", metavar="TOL", lo=0.0, strict=True,
                                      rules=("residual", "pa2"),
                                      help="residual and pa2 stages: Newton update tolerance on |dv| [m/s]")
    newton_maxiter: int | None = option(ByRule({"minimize": 50, "pa2": 5, "residual": None},
                                               attr="default_newton_maxiter"),
                                        kind="int", cli="--newton-maxiter", metavar="N", lo=1, hi=10**6,
                                        rules=_CONVERGED, help="Newton iteration limit of a stage")
    residual_rtol: float | None = option(1e-3, kind="float", cli="--residual-rtol", metavar="R", lo=0.0,
                                         strict=True, rules=("residual",),
                                         help="Newton residual tolerance, relative to the balanced terms")
    forcing: str | None = option("fixed", kind="name", cli="--forcing", metavar="RULE", choices=FORCING_RULES,
                                 what="forcing rule", rules=_CONVERGED,
                                 help="relative tolerance of Newton's linear solves: fixed (the solver's rtol) or "
                                      "eisenstat-walker (loose far from the root, tightening as Newton converges)")
    forcing_max: float | None = option(0.1, kind="float", yaml=False, lo=0.0, strict=True, hi=1.0, hi_strict=True,
                                       rules=_CONVERGED, help="largest (and first) Eisenstat-Walker forcing term")
    line_search: bool | None = option(True, kind="bool", yaml=False, rules=("residual",),
                                      help="backtrack the update of residual stages on |R|")
    min_step: float | None = option(ByRule({"minimize": 2.0 ** -20, "residual": 1.0 / 64, "pa2": 1.0 / 64}),
                                    kind="float", yaml=False, lo=0.0, strict=True, hi=1.0,
                                    rules=("minimize", "residual"), help="smallest line-search step")
    escalate_jacobian: bool | None = option(True, kind="bool", yaml=False, rules=("residual",),
                                            help="residual stages with a projected Jacobian: finish a stage that "
                                                 "reaches the Newton limit with the exact one")
    escalate_after: int | None = option(None, kind="int", yaml=False, lo=1, rules=("residual",),
                                        default_text="the Newton limit",
                                        help="iterations with the projected Jacobian before escalating")

    def check_combination(self) -> None:
        """``minimize`` stages need a projected Jacobian mode.

        Raises
        ------
        SceneError
            Naming ``jacobian``.
        """
        if self.stage_solver == "minimize" and self.jacobian is not None and self.jacobian not in PROJECTED_MODES:
            raise SceneError("jacobian", f"the minimize stage solver needs a projected Hessian "
                                         f"({' or '.join(PROJECTED_MODES)}), got {self.jacobian!r}; choose "
                                         f"stage_solver residual or pa2 for another mode")

    @classmethod
    def read_by(cls, rule: str) -> frozenset:
        """The fields stage rule ``rule`` reads, from their declarations (the others it ignores).

        Parameters
        ----------
        rule : {"minimize", "residual", "pa2", "plain"}
            A stage rule, or ``"plain"``: plain Newton iterations (linearized implicit Euler).

        Returns
        -------
        frozenset of str
        """
        return frozenset(name for name, f in cls.declarations().items() if rule in f.metadata["rules"])

    @property
    def resolved(self) -> bool:
        """Whether every field with a default holds a value (:meth:`resolve`'s result)."""
        return all(getattr(self, name) is not None for name, f in self.declarations().items()
                   if f.metadata["default"] is not None)

    def resolve(self, integrator) -> "NewtonOptions":
        """These options with every default filled in for ``integrator``: the group :class:`StageSolver` takes.

        The stage rule is checked against the ones the method admits (``integrator.stage_solvers``) and its
        forces; then each field not given takes its declared default, in declaration order: a value, a value by
        stage rule (:class:`~springsim.integrators._options.ByRule`), or a rule function
        (:class:`~springsim.integrators._options.DefaultRule`).

        Parameters
        ----------
        integrator : ImplicitIntegrator
            The integrator being built (its class, ``stage_solvers``, force terms and system).

        Returns
        -------
        NewtonOptions
            Resolved (:attr:`resolved`).

        Raises
        ------
        SceneError
            Naming ``stage_solver`` for a rule the method or its forces do not admit.
        """
        rule = self.stage_solver
        if rule is not None and rule not in integrator.stage_solvers:
            raise SceneError("stage_solver", f"{integrator.name} stages are solved with "
                                             f"{' or '.join(integrator.stage_solvers)}, got {rule!r:.60}")
        if rule == "minimize" and not _has_potential(integrator):
            bad = [t.name for t in integrator.terms if not (t.conservative or t.dissipative)]
            raise SceneError("stage_solver", f"minimize needs forces with a potential; {', '.join(bad)} has none")
        values: dict = {}
        for name, f in self.declarations().items():
            value, default = getattr(self, name), f.metadata["default"]
            if value is None:
                if isinstance(default, DefaultRule):
                    value = default.fn(integrator, self, values)
                elif isinstance(default, ByRule):
                    value = default.value(values["stage_solver"], type(integrator))
                else:
                    value = default
            values[name] = value
        return NewtonOptions(**values)


#: The former name of :class:`NewtonOptions`.
StageOptions = NewtonOptions


class StageSolver:
    """Solves ``c F(q_hat + c v, v) = M (v - v_hat)`` for ``v`` on a :class:`~springsim.system.System`.

    Parameters
    ----------
    system : System
    options : NewtonOptions
        Resolved (:meth:`NewtonOptions.resolve`).
    stage_forces, stage_matrix : callable, optional
        Replace the system's forces ``F(q, v)`` and stage matrix (the energy-momentum method's discrete
        gradient); only the ``residual`` and ``pa2`` rules take them.
    """

    def __init__(self, system, options: NewtonOptions):
        if not isinstance(options, NewtonOptions) or not options.resolved:
            raise TypeError("StageSolver takes resolved NewtonOptions (NewtonOptions.resolve)")
        self.system = system
        self.options = options
        mass = system.particle_mass
        self._mass = mass[:, None]
        m_free = system.free_rows(mass)
        # floor of the residual scale: the residual of a velocity error of newton_tol in every DOF
        self._mass_norm = float(np.sqrt(3.0 * system.sum(float(np.dot(m_free, m_free)))))
        self._mass_dofs = system.gather(np.repeat(self._mass, 3, axis=1))
        self._weight = None  # |M g| over free DOFs, on first use
        self._warm: np.ndarray | None = None
        self._failed: list[str] = []
        self.trace = None
        #: Upper bound of ``force_rtol`` set by a driver for a run (None: none): adaptive stepping sets ``0.1
        #: time_rtol``, so that the Newton error stays below the error test (module docstring).
        self.force_rtol_cap: float | None = None
        #: Whether a stalled ``minimize`` stage stops early (module docstring, "Stalls"); the integrators turn it
        #: off in the last substep retake, which has nothing smaller to fall back on.
        self.stop_stalls = True
        self._precision_loss = 0.0

    def reset(self) -> None:
        """Forget the warm start of the first linear solve."""
        self._warm = None

    # -- the public entry point ---------------------------------------------------------------------------------
    def solve(self, q_hat, v_hat, c: float, v0, stats: StepStats, *, maxiter: int | None = None,
              converge: bool = True, final_residual: bool = True, forces=None, matrix=None, guesses=()):
        """Solve the stage from ``v0``: ``(q, v, ok)``.

        Parameters
        ----------
        q_hat, v_hat, v0 : ndarray (n, 3)
            State arrays of the stage (module docstring).
        c : float
            Stage coefficient [s].
        stats : StepStats
            Accumulates iterations, times, norms and failures.
        maxiter : int, optional
            Iteration limit (default the options' ``newton_maxiter``); 1 with ``converge=False`` is the
            linearized method.
        converge : bool
            Apply the stopping rule, line search and non-convergence report (False: exactly ``maxiter`` plain
            Newton iterations, no line search).
        final_residual : bool
            With ``converge=False``: evaluate the residual at the returned iterate for ``stats`` (False: NaN,
            one force evaluation saved).
        forces, matrix : callable, optional
            ``forces(q, v, out)`` and ``matrix(q, v, c, mode)`` replacing the system's (residual and pa2 rules).
        guesses : sequence of ndarray (n, 3), optional
            Other starting velocities (predictors); the ``minimize`` rule starts from whichever of ``v0`` and
            these has the lowest ``E`` (module docstring, "Starting point"); the other rules start from ``v0``.

        Returns
        -------
        q, v : ndarray (n, 3)
        ok : bool
            Whether the stage converged (when ``converge``; else whether its linear solves met their criterion).
        """
        o = self.options
        maxiter = o.newton_maxiter if maxiter is None else maxiter
        self._failed = []
        stats.extra["stages"] = stats.extra.get("stages", 0) + 1
        v = np.array(v0, dtype=np.float64)
        v[self.system.fixed] = 0.0
        if converge and o.stage_solver == "minimize" and forces is None:
            q, v, converged, why = self._minimize(q_hat, v_hat, c, v, stats, maxiter, guesses)
        else:
            q, v, converged, why = self._newton_escalating(q_hat, v_hat, c, v, stats, maxiter, converge,
                                                           final_residual or converge, forces, matrix)
        ok = report_stage(stats, converge=converge, converged=converged, failed=self._failed, why=why)
        return q, v, ok

    # -- shared pieces ------------------------------------------------------------------------------------------
    def _assemble(self, q, v, c, mode, stats, *, matrix=None, geometry=None):
        sysm = self.system
        if matrix is not None:
            A = matrix(q, v, c, mode)
        else:
            A = sysm.assemble(q, v, c * c, c, mode, damping_geometry=geometry)
        stats.assembly_s += sysm.last_assembly_s
        self._precision_loss = sysm.precision_loss(A)
        stats.precision_loss = max(stats.precision_loss, self._precision_loss)
        return A

    def _solve_rtol(self, rtol: float | None, gnorm: float, tol: float) -> tuple[float | None, bool]:
        """``(rtol, by_need)`` of the next solve of a ``minimize`` stage, once its matrix is assembled: the forcing
        rule's tolerance ``rtol``, or the looser one the stopping rule needs (module docstring, "Linear solves")."""
        need = min(solve_share(self._precision_loss) * tol / gnorm, _SOLVE_LOOSEST)
        by_need = need > (self.system.linear_rtol if rtol is None else rtol)
        return (need if by_need else rtol), by_need

    def _linear_solve(self, A, b, stats, first: bool, rtol: float | None = None):
        sysm = self.system
        x0 = self._warm if (first and self._warm is not None and self._warm.shape == b.shape) else None
        res = sysm.solve(A, b, x0=x0, rtol=rtol)
        failure = record_linear_solve(stats, res, sysm.all_finite(res.x))
        if failure:
            self._failed.append(failure)
        if first:
            self._warm = res.x
        return res

    def _step_to(self, v, dv, alpha, q_hat, c):
        v_try = v.copy()
        self.system.scatter_add(v_try, dv, alpha)
        return v_try, q_hat + c * v_try

    # -- the minimisation -----------------------------------------------------------------------------------------
    def _weight_norm(self) -> float:
        if self._weight is None:
            sysm = self.system
            g = sysm.model.gravity_vector
            w = sysm.free_rows(self._mass) * g
            self._weight = float(np.sqrt(sysm.sum(float(np.sum(w * w)))))
        return self._weight

    def _potential(self, q, v, v_hat, c, geometry, f):
        """``(E, grad E, |grad E|, kinetic part of E, force scale)`` at ``v`` (module docstring); ``f`` receives the
        stage force."""
        sysm = self.system
        t0 = time.perf_counter()
        potential, dissipation = sysm.stage_terms(q, v, f, geometry)
        dv = v - v_hat
        inertia = self._mass * dv
        grad = inertia / c - f  # -R / c, a force [N]
        grad[sysm.fixed] = 0.0
        kinetic = 0.5 * sysm.dot(inertia, dv)
        energy = kinetic + potential + c * dissipation
        gnorm = sysm.norm(grad)
        scale = sysm.norm(inertia) / c + sysm.norm(f) + self._weight_norm()
        self._force_s += time.perf_counter() - t0
        return energy, grad, gnorm, kinetic, scale

    def _minimize(self, q_hat, v_hat, c, v, stats, maxiter, guesses=()):
        """Projected Newton with Armijo backtracking on the incremental potential (module docstring)."""
        o, sysm = self.options, self.system
        self._force_s = 0.0
        geometry = q_hat + c * v_hat  # the inertial predictor: the frozen damping geometry
        f = np.empty_like(v)
        q = q_hat + c * v
        E, grad, gnorm, kinetic, scale = self._potential(q, v, v_hat, c, geometry, f)
        for guess in guesses:  # the start with the lowest E ("Starting point")
            v_g = np.array(guess, dtype=np.float64)
            v_g[sysm.fixed] = 0.0
            if not sysm.all_finite(v_g):
                continue
            f_g = np.empty_like(f)
            q_g = q_hat + c * v_g
            trial = self._potential(q_g, v_g, v_hat, c, geometry, f_g)
            if trial[0] < E:
                v, q, f = v_g, q_g, f_g
                E, grad, gnorm, kinetic, scale = trial
                stats.extra["predicted_starts"] = stats.extra.get("predicted_starts", 0) + 1
        force_rtol = o.force_rtol if self.force_rtol_cap is None else min(o.force_rtol, self.force_rtol_cap)
        tol = o.force_atol + force_rtol * scale
        forcing = StageForcing(o.forcing, eta_max=o.forcing_max, floor=sysm.linear_rtol)
        converged, stagnated, step, alpha = gnorm <= tol, False, 0.0, 1.0
        it = flat = 0
        slow, exact, stalled, history = 0, False, False, [gnorm]
        exact_ok = sysm.default_jacobian() == "exact"  # the solver takes indefinite matrices
        e_hist = [E]
        if self.trace is not None:
            self.trace.append((0, 0.0, gnorm, tol, E))
        while not converged and it < maxiter and np.isfinite(gnorm):
            R = sysm.gather(grad) * (-c)
            forced = forcing.rtol(gnorm)
            slope = 0.0
            if exact:
                # a stalled projected iteration (a slack, buckling cloth: the projection of the compressed springs
                # is far stiffer than E): E's exact Hessian (symmetric mode, the damping frozen), positive definite
                # near a minimum, where it gives a descent direction
                A = self._assemble(q, v, c, "symmetric", stats, geometry=geometry)
                rtol, by_need = self._solve_rtol(forced, gnorm, tol)
                failed = list(self._failed)
                try:
                    res = self._linear_solve(A, R, stats, first=False, rtol=rtol)
                    dv = res.x
                    slope = -sysm.dot(R, dv) if res.converged else 0.0
                except SolverError:  # singular where E is not convex: the projected Hessian instead
                    slope = 0.0
                self._failed = failed  # a failed try is no failure of the stage: the projected one follows
                exact = slope < 0.0
                stats.extra["exact_hessian_steps"] = stats.extra.get("exact_hessian_steps", 0) + exact
            if not exact:
                A = self._assemble(q, v, c, o.jacobian, stats, geometry=geometry)
                rtol, by_need = self._solve_rtol(forced, gnorm, tol)
                res = self._linear_solve(A, R, stats, first=(it == 0), rtol=rtol)
                dv = res.x
                slope = -sysm.dot(R, dv)  # d/dalpha E(v + alpha dv) at 0 = grad_x . (c dv) = -R . dv
            stats.newton_iterations += 1
            it += 1
            g_before = gnorm
            if not slope < 0.0:  # not a descent direction (an inexact solve): the mass-preconditioned gradient
                dv = R / self._mass_dofs
                slope = -sysm.dot(R, dv)
                stats.extra["gradient_steps"] = stats.extra.get("gradient_steps", 0) + 1
            step = sysm.norm(dv)
            # Armijo on E with an allowance for the round-off of its evaluation
            noise = 64.0 * np.finfo(np.float64).eps * (abs(E) + abs(kinetic))
            # where Newton's decrement is below E's round-off (a large constant in V, such as a softened
            # gravitational core's), E cannot judge the step: its gradient norm does (Armijo on 1/2 |grad E|^2)
            by_gradient = -slope <= noise
            alpha, curved = 1.0, False
            E_ref = max(e_hist[-_NONMONOTONE:])  # nonmonotone ("Nonmonotone line search")
            while True:
                v_try, q_try = self._step_to(v, dv, alpha, q_hat, c)
                trial = self._potential(q_try, v_try, v_hat, c, geometry, f)
                decrease = E_ref + _ARMIJO * alpha * slope
                if (trial[2] <= (1.0 - _ARMIJO * alpha) * gnorm if by_gradient
                        # a step E accepts only within its round-off must lower the gradient norm too
                        else trial[0] <= decrease or (trial[0] <= decrease + noise and trial[2] < gnorm)):
                    break
                if alpha == 1.0 and not by_gradient and np.isfinite(trial[0]):
                    corrected = self._corrected(A, rtol, q, q_try, v, dv, q_hat, v_hat, c, geometry, stats)
                    if corrected is not None and corrected[3][0] <= E + _ARMIJO * slope + noise:
                        dv, v_try, q_try, trial, f_c = corrected
                        f[...] = f_c
                        stats.extra["corrected_steps"] = stats.extra.get("corrected_steps", 0) + 1
                        curved = True
                        break
                if alpha <= o.min_step or not np.isfinite(E):
                    stagnated = True
                    break
                alpha *= 0.5
            if alpha == 1.0 and not (by_gradient or curved or by_need) and trial[0] - E + noise < 0.9 * slope:
                # E fell by more than its quadratic model allows (half the slope): negative curvature the
                # projection removed (a buckling cloth); follow it with longer steps while E keeps falling
                v_try, q_try, trial, alpha = self._expand(v, dv, q_hat, v_hat, c, geometry, f, trial, v_try, q_try,
                                                          noise)
                stats.extra["longer_steps"] = stats.extra.get("longer_steps", 0) + (alpha > 1.0)
            stats.extra["min_line_search_step"] = min(alpha, stats.extra.get("min_line_search_step", 1.0))
            if stagnated and not (trial[2] <= gnorm if by_gradient else trial[0] <= E + noise):
                # no decrease to find at the smallest step: round-off (or a wrong direction); keep the iterate
                break
            # a step accepted only within E's round-off: twice in a row is stagnation, whatever the gradient says
            flat = flat + 1 if not by_gradient and trial[0] > E_ref + _ARMIJO * alpha * slope else 0
            v, q = v_try, q_try
            E, grad, gnorm, kinetic, scale = trial
            tol = o.force_atol + force_rtol * scale
            # full steps that barely reduce the gradient: the Hessian, not the nonlinearity, is at fault
            slow = slow + 1 if gnorm > 0.7 * g_before and alpha >= 1.0 else 0
            exact = exact_ok and (exact or slow >= 3)
            stagnated = False
            if self.trace is not None:
                self.trace.append((it, alpha, gnorm, tol, E))
            history.append(gnorm)
            e_hist.append(E)
            if gnorm <= tol and (by_need or forcing.certified(res.residual)):
                converged = True
            elif flat >= 2:
                stagnated = True
                break
            elif (self.stop_stalls and not exact_ok and len(history) > _STALL_WINDOW
                  and min(history[-_STALL_WINDOW:]) > 0.5 * history[-_STALL_WINDOW - 1]):
                stalled = True  # ("Stalls") the step is retaken in substeps, where the stages are closer to convex
                break
        if not converged and stagnated and gnorm <= 1e3 * tol:
            converged = True  # round-off leaves no decrease: the gradient is as small as it can be made
            stats.extra["roundoff_stops"] = stats.extra.get("roundoff_stops", 0) + 1
        stats.force_s += self._force_s
        stats.newton_step_norm = step
        stats.residual_norm = c * gnorm  # |R| = c |grad E| [N s]
        stats.residual_ratio = gnorm / scale if scale > 0 else 0.0
        stats.extra["gradient_norm"] = gnorm
        stats.extra["gradient_tol"] = tol
        reason = (f"no halving of |grad E| in the last {_STALL_WINDOW} iterations" if stalled
                  else "line search stagnated" if stagnated else "iteration limit")
        why = (f"the stage did not converge in {it} Newton iterations: |grad E| {gnorm:.2e} N, tolerance "
               f"{tol:.2e} N ({reason})")
        return q, v, converged and bool(np.isfinite(gnorm)), why

    def _corrected(self, A, rtol, q, q_full, v, dv, q_hat, v_hat, c, geometry, stats):
        """The second-order correction of the rejected full step from ``q`` to ``q_full`` (module docstring,
        "Curved steps"): ``(dv', v', q', trial', f')`` for ``dv' = dv + A^-1 (c F_r)``, or None where no term has
        curved lengths or the solve gave no direction."""
        sysm = self.system
        remainder = sysm.curvature_forces(q, q_full, np.empty_like(v))
        if remainder is None:
            return None
        failed = list(self._failed)
        try:
            res = self._linear_solve(A, sysm.gather(remainder) * c, stats, first=False, rtol=rtol)
        except SolverError:
            res = None
        self._failed = failed  # a failed correction is no failure of the stage: backtracking follows
        if res is None or not res.converged:
            return None
        dv_c = dv + res.x
        v_c, q_c = self._step_to(v, dv_c, 1.0, q_hat, c)
        f_c = np.empty_like(v)
        return dv_c, v_c, q_c, self._potential(q_c, v_c, v_hat, c, geometry, f_c), f_c

    def _expand(self, v, dv, q_hat, v_hat, c, geometry, f, trial, v_try, q_try, noise, most: int = 4):
        """Doubling the accepted full step up to ``2**most`` times while ``E`` keeps falling: the best trial."""
        alpha = 1.0
        for _ in range(most):
            v2, q2 = self._step_to(v, dv, 2.0 * alpha, q_hat, c)
            f2 = np.empty_like(f)
            t2 = self._potential(q2, v2, v_hat, c, geometry, f2)
            if not t2[0] < trial[0] - noise:
                break
            alpha, v_try, q_try, trial = 2.0 * alpha, v2, q2, t2
            f[...] = f2
        return v_try, q_try, trial, alpha

    # -- Newton on the residual (residual and pa2 rules, and every plain iteration) ---------------------------------
    def _newton_escalating(self, q_hat, v_hat, c, v, stats, maxiter, converge, final_residual, forces, matrix):
        o = self.options
        escalate = converge and o.stage_solver == "residual" and o.escalate_jacobian and o.jacobian != "exact"
        first = min(maxiter, o.escalate_after) if escalate and o.escalate_after is not None else maxiter
        q, v, step, rnorm, ratio, converged = self._newton(q_hat, v_hat, c, v, stats, first, converge, o.jacobian,
                                                           final_residual, forces, matrix)
        if escalate and not converged and np.isfinite(rnorm):
            # the projected Jacobian slows Newton to linear convergence where it differs from the exact one
            # (compressed springs); finish the stage with the exact Jacobian
            stats.extra["jacobian_escalations"] = stats.extra.get("jacobian_escalations", 0) + 1
            q, v, step, rnorm, ratio, converged = self._newton(q_hat, v_hat, c, v, stats, maxiter, converge, "exact",
                                                               final_residual, forces, matrix)
        stats.newton_step_norm = step
        stats.residual_norm = rnorm
        stats.residual_ratio = ratio
        rule = "" if o.stage_solver == "pa2" else f"; residual ratio {ratio:.1e}, tol {o.residual_rtol:g}"
        why = f"Newton did not converge in {maxiter} iterations (|dv| {step:.1e} m/s, tol {o.newton_tol:g}{rule})"
        return q, v, converged and bool(np.isfinite(rnorm)), why

    def _newton(self, q_hat, v_hat, c, v, stats, maxiter, converge, mode, final_residual, forces, matrix):
        """Newton iterations from ``v`` with the Jacobian ``mode``: ``(q, v, |dv|, |R|, rho, converged)``."""
        o, sysm = self.options, self.system
        f = np.empty_like(v)
        q = q_hat + c * v
        R, rnorm, ratio = self._residual(q, v, v_hat, c, f, stats, forces)
        converged, step = False, 0.0
        search = converge and o.stage_solver == "residual" and o.line_search
        judge = converge and o.stage_solver == "residual"
        forcing = StageForcing(o.forcing if converge else "fixed", eta_max=o.forcing_max, floor=sysm.linear_rtol)
        for it in range(maxiter):
            A = self._assemble(q, v, c, mode, stats, matrix=matrix)
            res = self._linear_solve(A, sysm.gather(R), stats, first=(it == 0), rtol=forcing.rtol(rnorm))
            dv = res.x
            step = sysm.norm(dv)
            stats.newton_iterations += 1

            def trial(alpha, v=v, dv=dv, judged=True):
                v_try, q_try = self._step_to(v, dv, alpha, q_hat, c)
                if not judged:
                    return v_try, q_try, None, float("nan"), float("nan")
                return (v_try, q_try, *self._residual(q_try, v_try, v_hat, c, f, stats, forces))

            if not final_residual and it == maxiter - 1:  # nothing reads the last residual: not computed
                alpha, (v, q, R, rnorm, ratio) = 1.0, trial(1.0, judged=False)
            else:
                # min_step read only where the rule searches (NewtonOptions declares which rules read it)
                alpha, (v, q, R, rnorm, ratio) = backtrack(trial, rnorm, enabled=search,
                                                           min_step=o.min_step if search else 1.0)
            stats.extra["min_line_search_step"] = min(alpha, stats.extra.get("min_line_search_step", 1.0))
            if not np.isfinite(step):
                break
            if (converge and step < o.newton_tol and (not judge or ratio <= o.residual_rtol)
                    and forcing.certified(res.residual)):
                converged = True
                break
        return q, v, step, rnorm, ratio, converged

    def _residual(self, q, v, v_hat, c, f, stats, forces=None):
        """``R = c F(q, v) - M (v - v_hat)`` (n, 3), ``|R|_2`` and ``rho`` over free DOFs (module docstring)."""
        sysm = self.system
        t0 = time.perf_counter()
        if forces is None:
            sysm.forces(q, v, f)
        else:
            forces(q, v, f)
        cf = c * f
        mdv = self._mass * (v - v_hat)
        R = cf - mdv
        rnorm = sysm.norm(R)
        scale = sysm.norm(cf) + sysm.norm(mdv) + self.options.newton_tol * self._mass_norm
        stats.force_s += time.perf_counter() - t0
        return R, rnorm, (rnorm / scale if scale > 0 else 0.0)
