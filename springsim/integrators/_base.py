"""Integrator interface and per-step statistics.

An integrator is built with the model (and, for implicit ones, a linear solver);
``step(state_in, state_out, dt)`` writes only ``state_out`` and returns a
:class:`StepStats`. Fixed particles never move.
"""

from __future__ import annotations

import contextlib
import functools
import threading
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from ..errors import SpringsimError
from ..system import SerialSystem

__all__ = ["Integrator", "StepStats", "PRECISION_LOSS_LIMIT"]


#: A step whose system matrix holds some particle's mass only to a relative precision worse than this
#: (:meth:`springsim.assembly.SystemAssembler.precision_loss`) is reported as ill-conditioned.
PRECISION_LOSS_LIMIT = 1e-6


@dataclass
class StepStats:
    """What one step cost and how it went.

    A step is trustworthy when :attr:`ok` is True. Otherwise its result is still returned
    (and recorded by the drivers), but the reasons are in :attr:`failures` and the drivers
    report it: a warning once per run, the run summary, and in adaptive runs a retry with a
    smaller step.

    Attributes
    ----------
    dt : float
        Step size [s].
    newton_iterations : int
        Newton iterations (0 for explicit methods).
    newton_converged : bool
        Whether every Newton stage that produced the result met its stopping rule (the
        update and the residual tests, see :class:`~springsim.integrators.ImplicitIntegrator`);
        True for explicit and linearized methods.
    newton_step_norm : float
        2-norm of the last Newton update ``|dqd|`` [m/s].
    residual_norm : float
        2-norm of the nonlinear residual at the returned state [N s] (NaN if not computed: explicit
        methods, and linearized implicit Euler, whose one plain iteration nothing judges).
    residual_ratio : float
        That residual relative to the size of the balanced terms (NaN if not computed).
    linear_iterations : int
        Krylov iterations summed over the step.
    linear_residual : float
        Largest relative residual of any linear solve in the step.
    linear_solves : int
        Linear solves in the step.
    linear_failures : int
        Linear solves of the result-producing stages that missed their criterion after every
        refinement and fallback.
    precision_loss : float
        Largest :meth:`~springsim.assembly.SystemAssembler.precision_loss` of the step's
        matrices: the relative precision to which they hold the particle masses.
    assembly_s, solve_s, force_s : float
        Wall time in numeric assembly, linear solves and force evaluation [s].
    fallbacks : list of str
        Linear-solver fallbacks that happened, with reasons.
    failures : list of str
        Why the step is not :attr:`ok` (empty when it is).
    extra : dict
        Integrator-specific counters (``stages``: stage solves, retakes included; ``jacobian_escalations``,
        ``order_reduced``, ``retaken``, ...).
    """

    dt: float
    newton_iterations: int = 0
    newton_converged: bool = True
    newton_step_norm: float = 0.0
    residual_norm: float = float("nan")
    residual_ratio: float = float("nan")
    linear_iterations: int = 0
    linear_residual: float = 0.0
    linear_solves: int = 0
    linear_failures: int = 0
    precision_loss: float = 0.0
    assembly_s: float = 0.0
    solve_s: float = 0.0
    force_s: float = 0.0
    fallbacks: list = field(default_factory=list)
    failures: list = field(default_factory=list)
    extra: dict = field(default_factory=dict)

    @property
    def ill_conditioned(self) -> bool:
        """Whether a matrix of the step held the masses worse than :data:`PRECISION_LOSS_LIMIT`."""
        return self.precision_loss > PRECISION_LOSS_LIMIT

    @property
    def ok(self) -> bool:
        """Newton converged, every linear solve met its criterion, the matrices were well-conditioned, and
        nothing else failed the step (:meth:`fail`: e.g. a step that created energy)."""
        return (self.newton_converged and self.linear_failures == 0 and not self.ill_conditioned
                and not self.failures)

    def fail(self, reason: str) -> None:
        """Record why the step is not ok (kept once per distinct reason).

        Parameters
        ----------
        reason : str
            One line, appended to :attr:`failures` unless already there.
        """
        if reason not in self.failures:
            self.failures.append(reason)

    def retake(self, reason: str) -> None:
        """Forget the outcome of an abandoned attempt before the step is taken again another way.

        The work stays counted (iterations, times); the failures move to ``extra["retaken"]``.

        Parameters
        ----------
        reason : str
            Why the attempt was abandoned, appended to ``extra["retaken"]``.
        """
        self.extra.setdefault("retaken", []).append(reason)
        self.newton_converged = True
        self.linear_failures = 0
        self.precision_loss = 0.0
        self.failures = []


def _exclusive(step):
    """``step`` holding the integrator (:meth:`Integrator.exclusive`) while it runs."""
    @functools.wraps(step)
    def guarded(self, state_in, state_out, dt):
        with self.exclusive():
            return step(self, state_in, state_out, dt)
    return guarded


class Integrator(ABC):
    """Base class. Subclasses set :attr:`name` and implement :meth:`step`.

    Every integrator is written once against a :class:`~springsim.system.System`: the serial one by default,
    or the PETSc one (:class:`springsim.distributed.DistributedSystem`) for distributed runs. Its states are
    then the system's state arrays (every particle serially, the owned particles of a rank otherwise).

    Parameters
    ----------
    model : Model
    system : System, optional
        The backend (default: a :class:`~springsim.system.SerialSystem` of ``model`` with ``terms`` and
        ``force_kernels``).
    terms : list of ForceTerm, optional
        Force terms (default: those the model uses); only without ``system``.
    force_kernels : {"auto", "numba", "numpy"}
        Compiled force passes where numba is installed (``"auto"``; see :func:`springsim.forces.make_force_terms`)
        or the pure numpy path; used only when neither ``system`` nor ``terms`` is given.
    **system_options
        Passed to the :class:`~springsim.system.SerialSystem` made when ``system`` is not given (``solver``,
        ``solver_options``).

    Raises
    ------
    TypeError
        ``terms`` or ``system_options`` together with a ``system``.
    """

    name: ClassVar[str]
    implicit: ClassVar[bool] = False
    #: Formal order of accuracy.
    order: ClassVar[int] = 1
    #: Whether :meth:`step` can set :attr:`error_estimate` (needed by adaptive stepping).
    has_error_estimate: ClassVar[bool] = False
    #: Whether that estimate costs extra work (step doubling), so that a step computes it only while
    #: :attr:`estimating` is set (adaptive runs set it); estimates that come free are always computed
    #: (a filtered one, :meth:`~springsim.integrators.ImplicitIntegrator.filter_estimate`, also costs).
    error_estimate_costs: ClassVar[bool] = False
    #: Largest ratio of consecutive step sizes the method tolerates (adaptive stepping).
    max_step_ratio: ClassVar[float] = float("inf")
    #: Keyword options other integrators take that this one ignores (:func:`make_integrator` warns about them).
    #: For the explicit integrators, every option of the implicit ones:
    #: :data:`springsim.integrators.IMPLICIT_OPTIONS`, derived from the signature of
    #: :class:`~springsim.integrators.ImplicitIntegrator` and set here by :mod:`springsim.integrators`.
    unused_options: ClassVar[frozenset] = frozenset()

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        if "step" in cls.__dict__ and not getattr(cls.__dict__["step"], "__isabstractmethod__", False):
            cls.step = _exclusive(cls.__dict__["step"])

    def __init__(self, model, *, system=None, terms=None, force_kernels: str = "auto", **system_options):
        self._busy = threading.RLock()
        self.model = model
        if system is None:
            system = SerialSystem(model, terms=terms, force_kernels=force_kernels, **system_options)
        elif terms is not None or system_options:
            raise TypeError("terms and solver options belong to the system when a system is given")
        self.system = system
        self.terms = system.terms
        #: Indices of the fixed particles in the state arrays (held by every step).
        self.fixed = system.fixed
        n = system.particle_mass.shape[0]
        inv = 1.0 / system.particle_mass
        inv[self.fixed] = 0.0
        self._inv_mass = inv[:, None]
        self._f = np.zeros((n, 3))
        self._a = np.zeros((n, 3))
        #: ``(err_q [m], err_v [m/s])``, arrays (N, 3): local error estimate of the last step
        #: (integrators with :attr:`has_error_estimate`), else None.
        self.error_estimate: tuple[np.ndarray, np.ndarray] | None = None
        #: Whether :meth:`step` computes :attr:`error_estimate` (see :attr:`error_estimate_costs`).
        self.estimating: bool = self.has_error_estimate and not self.error_estimate_costs

    def acceleration(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """``M^-1 F(q, qd)``, zero for fixed particles, shape (N, 3).

        The result lives in a buffer of the integrator's, overwritten by the next call.

        Parameters
        ----------
        q : ndarray, shape (n, 3)
            Positions [m] (a state array of the system).
        qd : ndarray, shape (n, 3)
            Velocities [m/s].

        Returns
        -------
        ndarray, shape (n, 3)
            Accelerations [m/s^2] (the integrator's buffer).
        """
        self.system.forces(q, qd, self._f)
        a = np.multiply(self._f, self._inv_mass, out=self._a)
        a[self.fixed] = 0.0  # not inf * 0 = NaN when a force overflows on a fixed particle
        return a

    @contextlib.contextmanager
    def exclusive(self):
        """Hold this integrator for one thread while the block runs (a run, a step).

        An integrator keeps state between steps (buffers, warm starts, multistep history, the energy of its run), so
        it is not safe to share between threads: use one integrator per thread. Using one from a second thread while
        another holds it raises :class:`~springsim.errors.SpringsimError` at once, never a wrong answer.
        The same thread may nest blocks (a run holds it, and each of its steps).

        Yields
        ------
        Integrator
            This integrator.

        Raises
        ------
        SpringsimError
            Another thread holds the integrator.
        """
        if not self._busy.acquire(blocking=False):
            raise SpringsimError(f"the {self.name} integrator is in use by another thread; integrators keep state "
                                 f"between steps: build one per thread (make_integrator)")
        try:
            yield self
        finally:
            self._busy.release()

    def blowup_hint(self) -> str:
        """Advice for a run of this integrator that blew up (part of the drivers' error message).

        Returns
        -------
        str
            A clause such as ``"try a smaller time step or an implicit integrator"``.
        """
        return "try a smaller time step or an implicit integrator"

    @abstractmethod
    def step(self, state_in, state_out, dt: float) -> StepStats:
        """Advance ``state_in`` by ``dt`` into ``state_out``.

        Subclasses' steps hold the integrator while they run (:meth:`exclusive`); fixed particles do not move.

        Parameters
        ----------
        state_in : State
            The state at the start of the step (state arrays of the system); not modified.
        state_out : State
            Written with the state at the end of the step (its arrays are overwritten in place).
        dt : float
            Step size [s].

        Returns
        -------
        StepStats
            What the step cost and whether it can be trusted (:attr:`StepStats.ok`).
        """

    def reset(self) -> None:
        """Forget any history (multistep methods, warm starts) and the last error estimate."""
        self.error_estimate = None
