"""The preconditioner protocol: :class:`Preconditioner`, the base of every preconditioner.

The protocol is described in :mod:`springsim.linsolve.preconditioners`, which holds the Jacobi
family and the registry; :mod:`springsim.linsolve.amg` implements it for algebraic multigrid.
Both import the base from here, so the registry can import its implementations directly.
"""

from __future__ import annotations

import time
from abc import ABC, abstractmethod
from typing import ClassVar

__all__ = ["Preconditioner"]


class Preconditioner(ABC):
    """Base of the preconditioners (protocol: :mod:`springsim.linsolve.preconditioners`).

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
        """Statistics for ``LinearSolveResult.info``.

        Returns
        -------
        dict
            Name -> value (JSON-able); empty here.
        """
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
