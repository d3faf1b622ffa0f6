"""Fixed particles: row-and-column elimination versus the identity rows of PA2, section 7.

PA2 (section 7) keeps all 3N unknowns and, for each fixed DOF, zeroes its
row and column of ``A``, puts 1 on the diagonal and 0 in ``b``. The solution then
has ``x_fixed = 0`` and, because the fixed columns are zero, the free rows read
``A_ff x_f = b_f``. Elimination solves exactly that reduced system, so both give
the same ``x`` (``expand(solve(*condense(A, b, free)))``). springsim assembles only
``A_ff``: blocks coupling a free to a fixed particle are never stored.
"""

from __future__ import annotations

import numpy as np

__all__ = ["free_dofs", "condense", "expand", "enforce_identity"]


def free_dofs(fixed: np.ndarray) -> np.ndarray:
    """DOF indices (3 per particle) of the particles with ``fixed == False``.

    Parameters
    ----------
    fixed : array_like of bool, shape (N,)
        Fixed-particle mask.

    Returns
    -------
    ndarray of int, shape (3F,)
        ``3 p, 3 p + 1, 3 p + 2`` for each free particle ``p``, in increasing order.
    """
    p = np.flatnonzero(~np.asarray(fixed, dtype=bool))
    return (3 * p[:, None] + np.arange(3)).ravel()


def condense(A, b: np.ndarray, free: np.ndarray):
    """``(A[free][:, free], b[free])``: eliminate the other DOFs (their values are zero updates).

    Parameters
    ----------
    A : ndarray or scipy.sparse matrix, shape (3N, 3N)
        The full system (a sparse one is converted to CSR).
    b : ndarray, shape (3N,)
        The full right-hand side.
    free : ndarray of int, shape (3F,)
        DOFs kept (:func:`free_dofs`).

    Returns
    -------
    A_free : ndarray or scipy.sparse.csr_matrix, shape (3F, 3F)
    b_free : ndarray, shape (3F,)
    """
    A = A[free][:, free] if not hasattr(A, "tocsr") else A.tocsr()[free][:, free]
    return A, b[free]


def expand(x_free: np.ndarray, free: np.ndarray, size: int, fill: float = 0.0) -> np.ndarray:
    """Full vector of length ``size`` with ``x_free`` at ``free`` and ``fill`` elsewhere.

    Parameters
    ----------
    x_free : ndarray, shape (3F,)
        Values of the free DOFs.
    free : ndarray of int, shape (3F,)
        Their DOF indices (:func:`free_dofs`).
    size : int
        Length of the result (3N).
    fill : float
        Value of the other DOFs; default 0.

    Returns
    -------
    ndarray, shape (size,)
        Float64 (or complex, following ``x_free``).
    """
    x = np.full(size, fill, dtype=np.result_type(x_free, np.float64))
    x[free] = x_free
    return x


def enforce_identity(A: np.ndarray, b: np.ndarray, fixed_dofs: np.ndarray):
    """PA2 section 7 on a dense system: zero fixed rows/columns, 1 on their diagonal, 0 in ``b``.

    Parameters
    ----------
    A : array_like, shape (3N, 3N)
        The full system.
    b : array_like, shape (3N,)
        The full right-hand side.
    fixed_dofs : ndarray of int
        DOF indices to hold.

    Returns
    -------
    A : ndarray, shape (3N, 3N)
        A float64 copy with identity rows and columns at ``fixed_dofs``.
    b : ndarray, shape (3N,)
        A float64 copy, 0 at ``fixed_dofs``.
    """
    A = np.array(A, dtype=np.float64)
    b = np.array(b, dtype=np.float64)
    A[fixed_dofs, :] = 0.0
    A[:, fixed_dofs] = 0.0
    A[fixed_dofs, fixed_dofs] = 1.0
    b[fixed_dofs] = 0.0
    return A, b
