"""Exceptions, warnings and the interrupt raised by springsim.

Every error springsim raises on purpose derives from :class:`SpringsimError`, so a
caller (and the CLI) can tell user errors from bugs. Input errors are
:class:`SceneError` (a ``ValueError``) or :class:`SceneTypeError` (also a ``TypeError``),
with a one-line message naming the field or parameter. An interrupted run raises
:class:`SimulationInterrupted`, a ``KeyboardInterrupt``: ``except Exception`` and
``except SimulationError`` do not swallow Ctrl-C.
"""

from __future__ import annotations

__all__ = ["EnergyGrowthWarning", "SpringsimError", "SceneError", "SceneTypeError", "SimulationError", "SolverError",
           "SimulationInterrupted", "SpringsimWarning", "ConvergenceWarning", "FallbackWarning",
           "NewtonConvergenceWarning", "UnusedOptionWarning", "registered", "check_choice", "check_numeric"]


class SpringsimError(Exception):
    """Base class of every springsim error."""


class SceneError(SpringsimError, ValueError):
    """Invalid scene or model input.

    Parameters
    ----------
    path
        Location of the offending item, e.g. ``"springs[12].stiffness"``.
    message
        What is wrong, e.g. ``"must be >= 0, got -3"``.
    """

    def __init__(self, path: str, message: str):
        self.path = path
        self.message = message
        super().__init__(f"{path}: {message}" if path else message)


class SceneTypeError(SceneError, TypeError):
    """Scene or model input of the wrong type (e.g. a string where a number belongs)."""


def check_numeric(name: str, value, dtype=None):
    """``value`` as a float64 array; a SceneTypeError naming ``name`` for strings, booleans and other non-numbers.

    Integers are converted exactly (never truncated); booleans are refused as numbers (``mass=True`` is a mistake,
    not 1 kg).

    Parameters
    ----------
    name : str
        Path of the value in error messages (``particles[3].mass``).
    value : array_like
        The value.
    dtype : numpy dtype, optional
        Result type (default float64).

    Returns
    -------
    ndarray

    Raises
    ------
    SceneTypeError
        For strings, booleans, ragged sequences and other non-numbers.
    """
    import numpy as np

    dtype = np.float64 if dtype is None else dtype
    if isinstance(value, (str, bytes)):
        raise SceneTypeError(name, f"must be numeric, got {type(value).__name__} {value!r:.60}")
    try:
        a = np.asarray(value)
    except (TypeError, ValueError):  # ragged nested lists
        raise SceneTypeError(name, "must be numeric, got a ragged or non-numeric sequence") from None
    if a.dtype.kind not in "iuf":
        what = {"b": "booleans", "U": "strings", "S": "bytes", "O": "objects", "c": "complex numbers"}.get(
            a.dtype.kind, str(a.dtype))
        raise SceneTypeError(name, f"must be numeric, got {what}")
    return a.astype(dtype)


def check_choice(value, choices, *, param: str, what: str):
    """``value`` when it is one of ``choices``, else a :class:`SceneError` naming ``param`` and listing them.

    The one check of a name against the names a registry or a tuple of modes allows (the Jacobian
    modes, the forcing rules, the registered integrators, ...): every layer that validates such a name
    (the run configuration, a factory, the assembler) calls it, so they agree on what is valid and on
    the message.

    Parameters
    ----------
    value : object
        The name given (any type: a non-string is reported, not raised as a TypeError).
    choices : iterable of str
        The allowed names (a tuple, or a registry's keys).
    param : str
        Field path named by the error (``"solver.jacobian"``).
    what : str
        What the names are, for the message (``"jacobian mode"``).

    Returns
    -------
    object
        ``value``.

    Raises
    ------
    SceneError
        ``value`` is not one of ``choices``.
    """
    try:
        ok = value in choices
    except TypeError:  # an unhashable value looked up in a registry
        ok = False
    if not ok:
        raise SceneError(param, f"unknown {what} {value!r:.60}; choose one of {', '.join(choices)}")
    return value


def registered(registry: dict, name, *, param: str, what: str):
    """``registry[name]``, or a :class:`SceneError` naming ``param`` and listing the registered names.

    Parameters
    ----------
    registry : dict
        Name -> registered object (``INTEGRATORS``, ``LINEAR_SOLVERS``, ...).
    name : object
        The name asked for (any type: a non-string is reported, not raised as a TypeError).
    param : str
        Field path named by the error (``"solver.integrator"``).
    what : str
        What the registry holds, for the message (``"integrator"``).

    Returns
    -------
    object
        ``registry[name]``.

    Raises
    ------
    SceneError
        ``name`` is not registered.
    """
    return registry[check_choice(name, registry, param=param, what=what)]


class SolverError(SpringsimError):
    """A linear or nonlinear solve failed and no fallback could recover."""


class SimulationError(SpringsimError):
    """A simulation stopped early (blow-up, failed solve).

    The frames computed before the failure are kept in :attr:`trajectory`
    (a :class:`springsim.run.driver.Trajectory` or ``None``); :attr:`step` is the step at which
    it stopped.

    Parameters
    ----------
    message : str
        What stopped the run.
    trajectory : Trajectory, optional
        The frames computed before the failure.
    step : int, optional
        The step at which the run stopped.
    """

    def __init__(self, message: str, trajectory=None, step: int | None = None):
        super().__init__(message)
        self.trajectory = trajectory
        self.step = step


class SimulationInterrupted(KeyboardInterrupt):
    """The run was interrupted (Ctrl-C); :attr:`trajectory` holds the frames so far.

    A ``KeyboardInterrupt``, so that it stops the caller too unless caught by name.

    Parameters
    ----------
    message : str
        What was interrupted.
    trajectory : Trajectory, optional
        The frames computed before the interrupt.
    step : int, optional
        The step at which the run stopped.
    """

    def __init__(self, message: str, trajectory=None, step: int | None = None):
        super().__init__(message)
        self.trajectory = trajectory
        self.step = step


class SpringsimWarning(UserWarning):
    """Base class of springsim's warnings."""


class ConvergenceWarning(SpringsimWarning, RuntimeWarning):
    """Steps of a run did not meet their criteria (Newton, a linear solve, the matrix conditioning).

    The drivers emit it once per run with the count; the details are in each step's
    :class:`~springsim.integrators.StepStats` (``ok``, ``failures``).
    """


#: Former name of :class:`ConvergenceWarning`.
NewtonConvergenceWarning = ConvergenceWarning


class FallbackWarning(SpringsimWarning, RuntimeWarning):
    """A linear solver handed over to its fallback during a run (the results are right, but slower).

    Emitted once per run by the drivers with the count; reasons in ``StepStats.fallbacks``.
    """


class EnergyGrowthWarning(SpringsimWarning, RuntimeWarning):
    """The energy of a scene whose forces all conserve or dissipate it grew during a run: an instability of the
    integrator at that step (the exact motion never gains energy). Emitted once per run by the drivers; in a
    damped scene the step where it happened is also failed (:attr:`~springsim.integrators.StepStats.failures`)."""


class UnusedOptionWarning(SpringsimWarning):
    """An option was given that the chosen integrator (or driver) does not use; it is ignored."""
