"""Time integrators, registered by name. Adding one is a module plus one line in :data:`INTEGRATORS`."""

from __future__ import annotations

from ..errors import SceneError
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

__all__ = ["INTEGRATORS", "Integrator", "ImplicitIntegrator", "StepStats", "PRECISION_LOSS_LIMIT", "ConvergenceWarning",
           "NewtonConvergenceWarning",
           "IntegratorExplicitEuler", "IntegratorSymplecticEuler", "IntegratorMidpoint",
           "IntegratorLinearizedImplicit", "IntegratorImplicitEuler", "IntegratorBDF2", "IntegratorTRBDF2",
           "make_integrator"]

#: Registry: YAML/CLI name -> class.
INTEGRATORS: dict[str, type[Integrator]] = {
    "explicit_euler": IntegratorExplicitEuler,
    "symplectic_euler": IntegratorSymplecticEuler,
    "midpoint": IntegratorMidpoint,
    "linearized_implicit": IntegratorLinearizedImplicit,
    "implicit_euler": IntegratorImplicitEuler,
    "bdf2": IntegratorBDF2,
    "tr_bdf2": IntegratorTRBDF2,
}


def make_integrator(name: str, model, **options) -> Integrator:
    """Build a registered integrator; implicit-only options are dropped for explicit ones.

    Options for implicit integrators: ``solver``, ``jacobian``, ``newton_tol``,
    ``newton_maxiter``, ``on_nonconvergence``, ``solver_options``.
    """
    try:
        cls = INTEGRATORS[name]
    except KeyError:
        raise SceneError("solver.type", f"unknown integrator {name!r}; choose one of {', '.join(INTEGRATORS)}") from None
    if not cls.implicit:
        options = {k: v for k, v in options.items() if k == "terms"}
    return cls(model, **options)
