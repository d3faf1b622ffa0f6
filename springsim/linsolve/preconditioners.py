"""Preconditioners: a parameter of :class:`~springsim.linsolve.iterative.LinearSolverIterative`.

A preconditioner turns a system matrix into an approximate inverse ``r -> M^-1 r`` and
may keep it across matrices (AMG reuses its hierarchy while it stays good). The iterative
solver drives every preconditioner through the same protocol:

* :meth:`Preconditioner.setup` ``(A) -> (apply, setup_s, fresh)``: the operator for ``A``,
  the setup time, and whether it was built for ``A`` (``fresh``) or reused;
* :meth:`Preconditioner.budget` ``(maxiter, fresh)``: how many Krylov iterations a solve may
  take before a reused operator counts as stale;
* :meth:`Preconditioner.record` ``(iterations, fresh, ok)``: the outcome, for the reuse policy;
* :meth:`Preconditioner.invalidate` ``(stale)``: forget the operator (the next setup builds);
* :meth:`Preconditioner.operator` ``(A)``: the matrix as the Krylov method applies it (``A``'s
  BSR matrix, or a compiled product for it).

Preconditioners that are rebuilt for every new matrix (the Jacobi family) only implement
:meth:`Preconditioner.build`. Adding one is a class here (or in its own module) plus one
line in :data:`PRECONDITIONERS`.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import time
from typing import Callable, ClassVar

import numpy as np

from ..errors import registered

__all__ = ["Preconditioner", "IdentityPreconditioner", "JacobiPreconditioner", "BlockJacobiPreconditioner",
           "PRECONDITIONERS", "make_preconditioner", "block_diagonal"]


def block_diagonal(A) -> np.ndarray:
    """The 3x3 diagonal blocks (F, 3, 3) of a system matrix (a SystemMatrix, BSR or any sparse matrix).

    Parameters
    ----------
    A : SystemMatrix or scipy.sparse matrix, shape (n, n)
        The matrix.

    Returns
    -------
    ndarray, shape (F, 3, 3)
    """
    pattern = getattr(A, "pattern", None)
    bsr = A.bsr if hasattr(A, "bsr") else A
    if pattern is not None and bsr.data.shape[0] == pattern.nnzb:  # the assembler's matrix: a precomputed gather
        return bsr.data[pattern.diagonal_positions]
    from ._sa import bsr_block_diagonal

    return bsr_block_diagonal(bsr.tobsr(blocksize=(3, 3)))


class Preconditioner(ABC):
    """Base of the preconditioners (protocol in the module docstring).

    Subclasses set :attr:`name` and implement :meth:`build`; those that keep their operator
    across matrices override :meth:`setup` and the policy methods.
    """

    #: Registry name.
    name: ClassVar[str]
    #: Whether the operator is symmetric positive definite for SPD matrices (required by CG).
    spd: ClassVar[bool] = True

    def __init__(self):
        self._cache = None  # (matrix, its version, apply): the matrix is held, so its identity stays unique

    @abstractmethod
    def build(self, A):
        """The operator ``r -> M^-1 r`` for ``A``, or None when ``A`` does not allow one (a singular diagonal).

        Parameters
        ----------
        A : SystemMatrix or scipy.sparse matrix, shape (n, n)
            The matrix.

        Returns
        -------
        callable or None
            ``r -> M^-1 r`` on arrays of shape (n,).
        """

    def setup(self, A):
        """``(apply, setup_s, fresh)`` for ``A``; ``apply`` is None when impossible. Built once per assembled
        matrix (an assembler's matrix keeps its identity and counts its versions), else on every call.

        Parameters
        ----------
        A : SystemMatrix or scipy.sparse matrix, shape (n, n)
            The matrix.

        Returns
        -------
        apply : callable or None
            ``r -> M^-1 r``.
        setup_s : float
            Seconds spent building it.
        fresh : bool
            Always True here (reusing subclasses report reuse).
        """
        c = self._cache
        if c is not None and c[0] is A and getattr(A, "pattern", None) is not None and c[1] == A.version:
            return c[2], 0.0, True
        t0 = time.perf_counter()
        apply = self.build(A)
        self._cache = (A, getattr(A, "version", None), apply)
        return apply, time.perf_counter() - t0, True

    def operator(self, A):
        """``A`` as the Krylov method applies it (``A @ x``): its BSR matrix.

        Parameters
        ----------
        A : SystemMatrix or scipy.sparse matrix, shape (n, n)
            The matrix.

        Returns
        -------
        scipy.sparse.bsr_matrix
        """
        return A.bsr

    def budget(self, maxiter: int, fresh: bool) -> int:
        """Iterations a solve may take with the current operator: ``maxiter`` (reusing subclasses lower it).

        Parameters
        ----------
        maxiter : int
            The solver's iteration limit.
        fresh : bool
            The operator was built for this solve.

        Returns
        -------
        int
        """
        return maxiter

    def record(self, iterations: int, fresh: bool, ok: bool) -> None:
        """Remember how a solve went (reuse policies use it).

        Parameters
        ----------
        iterations : int
            Krylov iterations of the solve.
        fresh : bool
            The operator was built for it.
        ok : bool
            The solve converged.
        """

    def invalidate(self, stale: bool = False) -> None:
        """Forget the operator; the next :meth:`setup` builds a new one.

        Parameters
        ----------
        stale : bool
            The operator went stale (used by reusing subclasses).
        """
        self._cache = None

    def describe(self) -> dict:
        """Statistics for ``LinearSolveResult.info``."""
        return {}

    def default_maxiter(self, n: int) -> int:
        """Default Krylov iteration limit for ``n`` unknowns with this preconditioner.

        Parameters
        ----------
        n : int
            Number of unknowns.

        Returns
        -------
        int
        """
        return max(1000, n)

    def __repr__(self) -> str:
        return f"{type(self).__name__}()"


class IdentityPreconditioner(Preconditioner):
    """No preconditioning (``"none"``)."""

    name = "none"

    def build(self, A):
        return lambda r: r


class JacobiPreconditioner(Preconditioner):
    """The inverse of the scalar diagonal (``"jacobi"``)."""

    name = "jacobi"

    def build(self, A):
        d = np.einsum("kii->ki", block_diagonal(A)).reshape(-1)
        with np.errstate(divide="ignore"):
            dinv = 1.0 / d
        if not np.all(np.isfinite(dinv)):
            return None
        return dinv.__mul__


class BlockJacobiPreconditioner(Preconditioner):
    """The inverse of the 3x3 diagonal blocks (``"block-jacobi"``), the Baraff and Witkin (1998) choice.

    Exact for the mass plus a particle's own stiffness in every direction; cheap per iteration,
    but the iteration count grows with ``h^2 k / m`` and the grid size.
    """

    name = "block-jacobi"

    def build(self, A):
        try:
            Dinv = np.linalg.inv(block_diagonal(A))
        except np.linalg.LinAlgError:
            return None
        if not np.all(np.isfinite(Dinv)):
            return None

        def apply(r):
            return np.einsum("kij,kj->ki", Dinv, r.reshape(-1, 3)).reshape(-1)

        return apply


def _amg():
    from .amg import AMGPreconditioner

    return AMGPreconditioner


#: Registry: name -> preconditioner class (``"amg"`` is imported on first use).
PRECONDITIONERS: dict[str, Callable] = {
    "none": IdentityPreconditioner,
    "jacobi": JacobiPreconditioner,
    "block-jacobi": BlockJacobiPreconditioner,
    "amg": _amg,
}


def make_preconditioner(spec, **options) -> Preconditioner:
    """A preconditioner from a registered name (with ``options``) or an instance (passed through).

    Parameters
    ----------
    spec : str or Preconditioner
        A key of :data:`PRECONDITIONERS`, or an instance.
    **options
        Keyword options of the preconditioner class.

    Returns
    -------
    Preconditioner

    Raises
    ------
    SceneError
        ``spec`` is not registered.
    TypeError
        Options given with an instance.
    """
    if isinstance(spec, Preconditioner):
        if options:
            raise TypeError(f"options {sorted(options)} need a preconditioner name, not an instance")
        return spec
    cls = registered(PRECONDITIONERS, spec, param="preconditioner", what="preconditioner")
    if not isinstance(cls, type):
        cls = cls()  # a loader, so that the optional heavy module is imported on first use
    return cls(**options)
