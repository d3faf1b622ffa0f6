"""Integrator interface and per-step statistics.

An integrator is built with the model (and, for implicit ones, a linear solver);
``step(state_in, state_out, dt)`` writes only ``state_out`` and returns a
:class:`StepStats`. Fixed particles never move.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from ..forces import eval_forces, make_force_terms

__all__ = ["Integrator", "StepStats"]


@dataclass
class StepStats:
    """What one step cost and how it went.

    Attributes
    ----------
    dt : float
        Step size [s].
    newton_iterations : int
        Newton iterations (0 for explicit methods).
    newton_converged : bool
        Whether the Newton stopping rule was met (True for explicit/linearized methods).
    newton_step_norm : float
        2-norm of the last Newton update ``|dqd|`` [m/s].
    residual_norm : float
        2-norm of the nonlinear residual at the returned state [N s] (NaN if not computed).
    linear_iterations : int
        Krylov iterations summed over the step.
    linear_residual : float
        Largest relative residual of any linear solve in the step.
    assembly_s, solve_s, force_s : float
        Wall time in numeric assembly, linear solves and force evaluation [s].
    fallbacks : list of str
        Linear-solver fallbacks that happened, with reasons.
    """

    dt: float
    newton_iterations: int = 0
    newton_converged: bool = True
    newton_step_norm: float = 0.0
    residual_norm: float = float("nan")
    linear_iterations: int = 0
    linear_residual: float = 0.0
    linear_solves: int = 0
    assembly_s: float = 0.0
    solve_s: float = 0.0
    force_s: float = 0.0
    fallbacks: list = field(default_factory=list)
    extra: dict = field(default_factory=dict)


class Integrator(ABC):
    """Base class. Subclasses set :attr:`name` and implement :meth:`step`.

    Parameters
    ----------
    model : Model
    terms : list of ForceTerm, optional
        Force terms (default: those the model uses).
    """

    name: ClassVar[str]
    implicit: ClassVar[bool] = False
    #: Formal order of accuracy.
    order: ClassVar[int] = 1

    def __init__(self, model, *, terms=None):
        self.model = model
        self.terms = make_force_terms(model) if terms is None else list(terms)
        self.free = model.free_particles
        self.fixed = model.particle_fixed
        self._inv_mass = np.where(self.fixed, 0.0, 1.0 / model.particle_mass)[:, None]
        self._f = np.zeros((model.particle_count, 3))

    def acceleration(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """``M^-1 F(q, qd)``, zero for fixed particles, shape (N, 3)."""
        eval_forces(self.terms, q, qd, out=self._f)
        a = self._f * self._inv_mass
        a[self.fixed] = 0.0  # not inf * 0 = NaN when a force overflows on a fixed particle
        return a

    @abstractmethod
    def step(self, state_in, state_out, dt: float) -> StepStats:
        """Advance ``state_in`` by ``dt`` into ``state_out``."""

    def reset(self) -> None:
        """Forget any history (multistep methods, warm starts)."""
