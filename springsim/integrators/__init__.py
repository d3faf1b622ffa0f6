"""Time integrators, registered by name. Adding one is a module plus one line in :data:`INTEGRATORS`."""

from __future__ import annotations

import inspect
import warnings

from ..model import Model
from ..errors import SceneError, UnusedOptionWarning, registered
from ._base import PRECISION_LOSS_LIMIT, Integrator, StepStats
from ..errors import ConvergenceWarning, NewtonConvergenceWarning
from ._implicit import ImplicitIntegrator
from .explicit_euler import IntegratorExplicitEuler
from .implicit_euler import IntegratorImplicitEuler
from .linearized_implicit import IntegratorLinearizedImplicit
from .midpoint import IntegratorMidpoint
from .symplectic_euler import IntegratorSymplecticEuler
from .bdf2 import IntegratorBDF2
from .tr_bdf2 import IntegratorTRBDF2
from .energy_momentum import IntegratorEnergyMomentum

__all__ = ["INTEGRATORS", "Integrator", "ImplicitIntegrator", "StepStats", "PRECISION_LOSS_LIMIT", "ConvergenceWarning",
           "NewtonConvergenceWarning",
           "IntegratorExplicitEuler", "IntegratorSymplecticEuler", "IntegratorMidpoint",
           "IntegratorLinearizedImplicit", "IntegratorImplicitEuler", "IntegratorBDF2", "IntegratorTRBDF2",
           "IntegratorEnergyMomentum", "make_integrator", "integrator_class", "IMPLICIT_OPTIONS"]

def _implicit_options() -> frozenset:
    """The keyword options of :class:`ImplicitIntegrator`'s constructor beyond those of :class:`Integrator`'s."""
    own = set(inspect.signature(Integrator.__init__).parameters)
    return frozenset(name for name, p in inspect.signature(ImplicitIntegrator.__init__).parameters.items()
                     if p.kind is p.KEYWORD_ONLY and name not in own)


#: The options of the implicit integrators (``solver``, ``jacobian``, ``newton_tol``, ...), derived from the
#: signature of :class:`ImplicitIntegrator`: the explicit integrators ignore them (their ``unused_options``).
IMPLICIT_OPTIONS: frozenset = _implicit_options()
Integrator.unused_options = IMPLICIT_OPTIONS

#: Registry: YAML/CLI name -> class.
INTEGRATORS: dict[str, type[Integrator]] = {
    "explicit_euler": IntegratorExplicitEuler,
    "symplectic_euler": IntegratorSymplecticEuler,
    "midpoint": IntegratorMidpoint,
    "linearized_implicit": IntegratorLinearizedImplicit,
    "implicit_euler": IntegratorImplicitEuler,
    "bdf2": IntegratorBDF2,
    "tr_bdf2": IntegratorTRBDF2,
    "energy_momentum": IntegratorEnergyMomentum,
}


def integrator_class(name: str) -> type[Integrator]:
    """The registered integrator class ``name``; a SceneError naming ``integrator`` and the choices if unknown."""
    return registered(INTEGRATORS, name, param="integrator", what="integrator")


def make_integrator(name: str, model: Model, **options) -> Integrator:
    """Build the registered integrator ``name`` for ``model`` with keyword ``options``.

    Every integrator takes ``system`` (the backend, :mod:`springsim.system`; default serial) and
    ``force_kernels`` (``"auto"``, ``"numba"``, ``"numpy"``: the compiled spring force pass of the ``accel`` extra
    or the pure path, see :func:`springsim.forces.make_force_terms`). Options of implicit integrators (see
    :class:`ImplicitIntegrator`): ``solver``, ``solver_options``, ``linear_rtol``, ``stage_solver``, ``jacobian``,
    ``force_rtol``, ``force_atol``, ``newton_tol``, ``newton_maxiter``, ``residual_rtol``,
    ``on_nonconvergence``, ``line_search``, ``min_step``, ``escalate_jacobian``, ``escalate_after``,
    ``forcing``, ``forcing_max``, ``retake_halvings``, ``filter_estimates``. Options the chosen integrator
    or its stage rule does not use (Newton options for explicit or linearized methods, the residual rule's
    tolerances with minimize stages, ...) are ignored with an :class:`~springsim.errors.UnusedOptionWarning`
    naming them, never silently. ``linear_rtol`` is the linear solver's relative tolerance, the run option of
    that name (``solver.linear_rtol``, ``--linear-rtol``): the same as ``solver_options={"rtol": ...}``.

    Raises
    ------
    SceneError
        A ``ValueError`` whose path names the parameter (``integrator``, ``jacobian``, ...); ``linear_rtol``
        when it and ``solver_options["rtol"]`` are both given and differ.
    """
    cls = integrator_class(name)
    skip = cls.unused_options
    if "solver_options" in skip:  # no linear solver: linear_rtol is unused like solver_options
        skip = skip | {"linear_rtol"}
    elif "linear_rtol" in options:
        options = _linear_rtol_as_solver_option(options)
    unused = sorted(k for k, v in options.items() if k in skip and v is not None)
    integ = cls(model, **{k: v for k, v in options.items() if k not in skip})
    ignored = getattr(integ, "ignored_options", frozenset)()
    unused = sorted(set(unused) | {k for k, v in options.items() if k in ignored and v is not None})
    if unused:
        rule = f" with {integ.stage_solver} stages" if ignored & set(unused) else ""
        warnings.warn(f"{name}{rule} does not use the option(s) {', '.join(unused)}; ignored", UnusedOptionWarning,
                      stacklevel=2)
    return integ


def _linear_rtol_as_solver_option(options: dict) -> dict:
    """``options`` with ``linear_rtol`` moved into ``solver_options["rtol"]`` (dropped when None)."""
    options = dict(options)
    rtol = options.pop("linear_rtol")
    if rtol is None:
        return options
    solver_options = dict(options.get("solver_options") or {})
    if "rtol" in solver_options and solver_options["rtol"] != rtol:
        raise SceneError("linear_rtol", f"given twice: linear_rtol={rtol!r:.60} and solver_options['rtol']="
                                        f"{solver_options['rtol']!r:.60}")
    solver_options["rtol"] = rtol
    options["solver_options"] = solver_options
    return options
