"""Exceptions raised by springsim.

Every error springsim raises on purpose derives from :class:`SpringsimError`, so a
caller (and the CLI) can tell user errors from bugs.
"""

from __future__ import annotations

__all__ = ["SpringsimError", "SceneError", "SimulationError", "SolverError"]


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


class SolverError(SpringsimError):
    """A linear or nonlinear solve failed and no fallback could recover."""


class SimulationError(SpringsimError):
    """A simulation stopped early (blow-up to NaN/inf, interruption).

    The frames computed before the failure are kept in :attr:`trajectory`
    (a :class:`springsim.driver.Trajectory` or ``None``).
    """

    def __init__(self, message: str, trajectory=None, step: int | None = None):
        super().__init__(message)
        self.trajectory = trajectory
        self.step = step
