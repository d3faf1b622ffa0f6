"""Time integrators, registered by name. Adding one is a module plus one line in :data:`INTEGRATORS`."""

from __future__ import annotations

import inspect
import warnings

from ..model import Model
from ..errors import SceneError, UnusedOptionWarning, registered
from ._base import PRECISION_LOSS_LIMIT, Integrator, StepStats
from ..errors import ConvergenceWarning, NewtonConvergenceWarning
from ._implicit import ImplicitIntegrator
from ._options import LinearSolveOptions
from ._stage import NewtonOptions
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
           "IntegratorEnergyMomentum", "make_integrator", "integrator_class", "IMPLICIT_OPTIONS", "NewtonOptions",
           "LinearSolveOptions"]

def _implicit_options() -> frozenset:
    """The keyword options of :class:`ImplicitIntegrator`'s constructor beyond those of :class:`Integrator`'s (its
    signature spells out the option groups' keywords, from their declarations).

    Returns
    -------
    frozenset of str
    """
    own = set(inspect.signature(Integrator.__init__).parameters)
    return frozenset(name for name, p in inspect.signature(ImplicitIntegrator.__init__).parameters.items()
                     if p.kind is p.KEYWORD_ONLY and name not in own)


#: The options of the implicit integrators (``solver``, ``jacobian``, ``newton_tol``, ..., and the groups ``newton``
#: and ``linear``), derived from the signature of :class:`ImplicitIntegrator` (which spells out the declared
#: fields of :class:`NewtonOptions` and :class:`LinearSolveOptions`): the explicit integrators ignore them (their
#: ``unused_options``).
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
    """The registered integrator class ``name``.

    Parameters
    ----------
    name : str
        A key of :data:`INTEGRATORS`.

    Returns
    -------
    type
        The :class:`Integrator` subclass.

    Raises
    ------
    SceneError
        Naming ``integrator`` and the choices, for an unknown name.
    """
    return registered(INTEGRATORS, name, param="integrator", what="integrator")


def make_integrator(name: str, model: Model, *, newton: NewtonOptions | None = None,
                    linear: LinearSolveOptions | None = None, **options) -> Integrator:
    """Build the registered integrator ``name`` for ``model`` with keyword ``options``.

    Every integrator takes ``system`` (the backend, :mod:`springsim.system`; default serial) and
    ``force_kernels`` (``"auto"``, ``"numba"``, ``"numpy"``: the compiled spring force pass of the ``accel`` extra
    or the pure path, see :func:`springsim.forces.make_force_terms`). The options of implicit integrators (see
    :class:`ImplicitIntegrator`) come in two frozen groups, given as groups or field by field as keywords:
    :class:`NewtonOptions` (``stage_solver``, ``jacobian``, ``force_rtol``, ``force_atol``, ``newton_tol``,
    ``newton_maxiter``, ``residual_rtol``, ``forcing``, ``forcing_max``, ``line_search``, ``min_step``,
    ``escalate_jacobian``, ``escalate_after``) and :class:`LinearSolveOptions` (``solver``, ``linear_rtol``);
    besides them ``solver_options``, ``on_nonconvergence``, ``retake_halvings`` and ``filter_estimates``.
    Options the chosen integrator or its stage rule does not read (derived from what each declares it reads:
    Newton options for explicit or linearized methods, the residual rule's tolerances with minimize stages, ...)
    are ignored with an :class:`~springsim.errors.UnusedOptionWarning` naming them, never silently.
    ``linear_rtol`` is the linear solver's relative tolerance, the run option of that name
    (``solver.linear_rtol``, ``--linear-rtol``): the same as ``solver_options={"rtol": ...}``.

    Parameters
    ----------
    name : str
        A key of :data:`INTEGRATORS`.
    model : Model
        The model to integrate.
    newton : NewtonOptions, optional
        The stage options as a group (a keyword may repeat one of its fields only with the same value).
    linear : LinearSolveOptions, optional
        The linear solve options as a group.
    **options
        Keyword options (above).

    Returns
    -------
    Integrator

    Raises
    ------
    SceneError
        A ``ValueError`` whose path names the parameter (``integrator``, ``jacobian``, ...); ``linear_rtol``
        when it and ``solver_options["rtol"]`` are both given and differ.
    TypeError
        ``newton`` or ``linear`` of the wrong class, or an unknown keyword.
    """
    cls = integrator_class(name)
    for group, cls_ in ((newton, NewtonOptions), (linear, LinearSolveOptions)):
        if group is not None:  # the groups as keywords: one path for the unused-option check below
            if not isinstance(group, cls_):
                raise TypeError(f"expected a {cls_.__name__}, got {type(group).__name__}")
            for field_name, value in group.given().items():
                kw = cls_.keyword(field_name)
                if options.get(kw) is not None and options[kw] != value:
                    raise SceneError(kw, f"given twice: {kw}={options[kw]!r:.60} and {cls_.__name__}("
                                         f"{field_name}={value!r:.60})")
                options[kw] = value
    skip = cls.unused_options
    unused = sorted(k for k, v in options.items() if k in skip and v is not None)
    integ = cls(model, **{k: v for k, v in options.items() if k not in skip})
    ignored = getattr(integ, "ignored_options", frozenset)()
    unused = sorted(set(unused) | {k for k, v in options.items() if k in ignored and v is not None})
    if unused:
        rule = f" with {integ.stage_solver} stages" if ignored & set(unused) else ""
        warnings.warn(f"{name}{rule} does not use the option(s) {', '.join(unused)}; ignored", UnusedOptionWarning,
                      stacklevel=2)
    return integ
