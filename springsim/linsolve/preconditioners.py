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


import numpy as np

from ..errors import registered
from ._kernels import bsr_block_diagonal
from ._preconditioner import Preconditioner
from .amg import AMGPreconditioner

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
    return bsr_block_diagonal(bsr.tobsr(blocksize=(3, 3)))


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


#: Registry: name -> preconditioner class.
PRECONDITIONERS: dict[str, type[Preconditioner]] = {
    "none": IdentityPreconditioner,
    "jacobi": JacobiPreconditioner,
    "block-jacobi": BlockJacobiPreconditioner,
    "amg": AMGPreconditioner,
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
    return registered(PRECONDITIONERS, spec, param="preconditioner", what="preconditioner")(**options)
