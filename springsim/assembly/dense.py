"""Dense reference assembly, deliberately naive: all 3N DOFs and the identity rows of PA2, section 7.

For tests and small scenes only (memory is O(N^2)).
"""

from __future__ import annotations

import numpy as np

from ..forces import dense_jacobians, make_force_terms
from .fixed import enforce_identity, free_dofs

__all__ = ["dense_system", "dense_system_free"]


def dense_system(model, q, qd, a: float, b: float, rhs: np.ndarray | None = None, mode: str = "exact",
                 terms=None):
    """``(A, rhs)`` with ``A = M - a dF/dq - b dF/dqd`` over all 3N DOFs, fixed DOFs as identity rows.

    Terms are built with ``skip_fixed=False`` (every pair, even between fixed
    particles), independently of the sparse path's pruning.

    Parameters
    ----------
    model : Model
        The model.
    q : ndarray, shape (N, 3)
        Positions [m] at which the Jacobians are evaluated.
    qd : ndarray, shape (N, 3)
        Velocities [m/s] at which the Jacobians are evaluated.
    a : float
        Coefficient [s^2] of ``dF/dq``.
    b : float
        Coefficient [s] of ``dF/dqd``.
    rhs : array_like, shape (3N,) or (N, 3), optional
        Right-hand side (a copy is returned with its fixed entries zeroed); default zeros.
    mode : {"exact", "symmetric", "spd"}
        Jacobian mode (:data:`springsim.forces.JACOBIAN_MODES`).
    terms : sequence of ForceTerm, optional
        Force terms; default ``make_force_terms(model, skip_fixed=False)``.

    Returns
    -------
    A : ndarray, shape (3N, 3N)
        The system matrix [kg], identity rows and columns at fixed DOFs.
    rhs : ndarray, shape (3N,)
        The right-hand side, 0 at fixed DOFs.
    """
    terms = make_force_terms(model, skip_fixed=False) if terms is None else terms
    n = model.particle_count
    dq, dqd = dense_jacobians(terms, q, qd, mode)
    A = np.diag(np.repeat(model.particle_mass, 3)) - a * dq - b * dqd
    rhs = np.zeros(3 * n) if rhs is None else np.asarray(rhs, dtype=np.float64).reshape(-1)
    fixed = np.setdiff1d(np.arange(3 * n), free_dofs(model.particle_fixed))
    return enforce_identity(A, rhs, fixed)


def dense_system_free(model, q, qd, a: float, b: float, mode: str = "exact") -> np.ndarray:
    """The dense reference restricted to free DOFs (what the sparse assembler stores).

    Parameters
    ----------
    model : Model
        The model.
    q, qd : ndarray, shape (N, 3)
        Positions [m] and velocities [m/s] at which the Jacobians are evaluated.
    a, b : float
        Coefficients [s^2] and [s] of ``dF/dq`` and ``dF/dqd``.
    mode : {"exact", "symmetric", "spd"}
        Jacobian mode (:data:`springsim.forces.JACOBIAN_MODES`).

    Returns
    -------
    ndarray, shape (3F, 3F)
        ``M - a dF/dq - b dF/dqd`` over the free DOFs [kg].
    """
    A, _ = dense_system(model, q, qd, a, b, mode=mode)
    free = free_dofs(model.particle_fixed)
    return A[np.ix_(free, free)]
