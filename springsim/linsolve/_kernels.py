"""Compiled numeric kernels for the AMG setup (optional: numba, the ``accel`` extra).

A smoothed-aggregation hierarchy that keeps its aggregates (:mod:`springsim.linsolve._sa`)
rebuilds the same sparse products on every new matrix: ``A T``, ``A P`` and ``R (A P)`` on each
level, whose block patterns depend only on the matrix pattern and the aggregates, both fixed for
a mass-spring system. scipy's ``bsr_matmat`` recomputes the pattern of every product and multiplies
the blocks in a loop whose trip counts (the block sizes) are only known at run time.
:class:`BsrProduct` computes the pattern of ``C = X Y`` once and then only the values, with a
numba kernel compiled for the block sizes (3x3 times 3x6 on the finest level of a cloth, 6x3 times
3x6 for its Galerkin product, 6x6 on the coarse levels), so the compiler unrolls the block loops:
about twice scipy's speed for the products of a 195,840-DOF cloth (BENCHMARKS.md#cloth-grid; per kernel:
"Compiled kernels" in the linear-solver notes of BENCHMARKS.md#cloth-grid).
The Galerkin product ``R (A P)`` is symmetric: its plan computes the entries on and above the
diagonal and mirrors them (``BsrProduct(..., symmetric=True)``), half the work. The rest of a
level's setup runs compiled too: the diagonal blocks and their inverses in one pass
(:func:`block_diagonal_inverse`), and the Jacobi smoothing of the tentative prolongator in place
on the values of ``A T`` (:func:`smoothed_prolongator`). The solve phase has compiled kernels as
well: the V-cycle (:class:`CompiledVCycle`; block Gauss-Seidel sweeps forward and backward in place,
:func:`block_gauss_seidel_forward`, :func:`block_gauss_seidel_backward`) and the matrix-vector
product that the Krylov method (with the AMG preconditioner) and the Lanczos estimate apply
(:class:`BsrOperator`).

The values are summed in the order scipy sums them (block row of ``X``, then the block row of ``Y``
it selects, then the inner block index), so both paths give bitwise the same product; the pattern
differs only in keeping blocks that cancel to zero, and in sorted rows. A hierarchy built either way
is the same to round-off.

``kernels="numpy"`` (or numba absent) keeps scipy's products: that is the pure path, and the tests
check the compiled one against it.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .._runtime import accel as _accel

__all__ = ["KERNELS", "BsrOperator", "BsrProduct", "CompiledVCycle", "block_diagonal_inverse",
           "block_gauss_seidel_backward", "block_gauss_seidel_forward", "bsr_block_diagonal", "bsr_matmat",
           "bsr_operator", "numba_available", "resolve_kernels", "smoothed_prolongator"]

#: Accepted values of the ``kernels`` option: those of every ``kernels`` option (:mod:`springsim._runtime.accel`,
#: which documents them; the former ``"scipy"`` is a deprecated alias of ``"numpy"``).
KERNELS = _accel.KERNELS


def numba_available() -> bool:
    """Whether numba can be imported (without importing it)."""
    return _accel.numba_available()


def resolve_kernels(kernels: str) -> str:
    """``"numba"`` or ``"numpy"`` for the option value ``kernels`` (``"auto"``: numba when installed;
    ``"scipy"``, the former spelling of ``"numpy"``, with a :class:`DeprecationWarning`).

    Raises
    ------
    ValueError
        For a value not in :data:`KERNELS`, or ``"numba"`` without numba installed.
    """
    return _accel.resolve(kernels, available=lambda: numba_available())


def _numba():
    """The numba kernels' module (compiled on first use, cached on disk by numba)."""
    from . import _numba_kernels
    return _numba_kernels


class BsrProduct:
    """The product ``C = X Y`` of two BSR matrices with fixed block patterns.

    Built from one pair ``(X, Y)``: the block pattern of ``C`` (all blocks that the patterns can
    produce, sorted, none dropped for being numerically zero). Called with matrices of the same
    patterns (:meth:`matches`), it computes only the values of ``C``.

    With ``symmetric=True`` the caller asserts that ``C`` is symmetric (a Galerkin product
    ``P^T (A P)`` with ``A`` symmetric): the entries on and above the diagonal are computed, as in
    the general product, and each entry below it is a copy of its mirror image, which halves the
    work and makes ``C`` exactly symmetric (equal to the general product to round-off).
    ``C`` must then be square with square blocks and a symmetric block pattern (``ValueError``
    otherwise).
    """

    def __init__(self, X: sp.bsr_matrix, Y: sp.bsr_matrix, symmetric: bool = False):
        R, K = X.blocksize
        K2, N = Y.blocksize
        if K != K2 or X.shape[1] != Y.shape[0]:
            raise ValueError(f"incompatible BSR operands {X.shape} {X.blocksize} and {Y.shape} {Y.blocksize}")
        # the block pattern of C: the product of the block patterns with positive entries (nothing cancels)
        Xs = sp.csr_matrix((np.ones(X.indices.size), X.indices, X.indptr), shape=(X.shape[0] // R, X.shape[1] // K))
        Ys = sp.csr_matrix((np.ones(Y.indices.size), Y.indices, Y.indptr), shape=(Y.shape[0] // K, Y.shape[1] // N))
        Cs = Xs @ Ys
        Cs.sort_indices()
        self.indptr, self.indices = Cs.indptr, Cs.indices
        self.shape, self.blocksize = (X.shape[0], Y.shape[1]), (R, N)
        self._patterns = (X.indptr.copy(), X.indices.copy(), Y.indptr.copy(), Y.indices.copy())
        self._dims = (X.shape, X.blocksize, Y.shape, Y.blocksize)
        self._marker = np.zeros(Y.shape[1] // N, dtype=Cs.indices.dtype)
        self.symmetric = bool(symmetric)
        if self.symmetric:
            nb = Cs.shape[0]
            if R != N or Cs.shape[0] != Cs.shape[1]:
                raise ValueError(f"a symmetric product must be square with square blocks, got {self.shape} {(R, N)}")
            # position of every block in the transposed pattern: Ct.data[p] - 1 is where block (j, i) is stored
            Cs.data = np.arange(1, Cs.nnz + 1, dtype=np.float64)
            Ct = Cs.T.tocsr()
            Ct.sort_indices()
            if not (np.array_equal(Ct.indptr, Cs.indptr) and np.array_equal(Ct.indices, Cs.indices)):
                raise ValueError("a symmetric product needs a symmetric block pattern")
            rows = np.repeat(np.arange(nb, dtype=Cs.indices.dtype), np.diff(Cs.indptr))
            self._lower = np.flatnonzero(Cs.indices < rows)
            self._upper = Ct.data[self._lower].astype(np.int64) - 1

    def matches(self, X: sp.bsr_matrix, Y: sp.bsr_matrix) -> bool:
        """Whether ``X`` and ``Y`` have the block patterns this product was built for."""
        if (X.shape, X.blocksize, Y.shape, Y.blocksize) != self._dims:
            return False
        return all(np.array_equal(a, b) for a, b in zip(self._patterns, (X.indptr, X.indices, Y.indptr, Y.indices)))

    def __call__(self, X: sp.bsr_matrix, Y: sp.bsr_matrix) -> sp.bsr_matrix:
        """``X @ Y`` as a BSR matrix with this product's pattern (``X`` and ``Y`` must match it)."""
        R, N = self.blocksize
        K = X.blocksize[1]
        data = np.empty((self.indices.size, R, N))
        operands = (X.indptr, X.indices, np.ascontiguousarray(X.data), Y.indptr, Y.indices,
                    np.ascontiguousarray(Y.data), self.indptr, self.indices, data, self._marker)
        if self.symmetric:
            _numba().bsr_matmat_symmetric(*operands, self._lower, self._upper, R, K, N)
        else:
            _numba().bsr_matmat_numeric(*operands, R, K, N)
        return sp.bsr_matrix((data, self.indices, self.indptr), shape=self.shape, copy=False)


def bsr_matmat(X: sp.bsr_matrix, Y: sp.bsr_matrix, kernels: str = "numpy",
               plan: BsrProduct | None = None, symmetric: bool = False) -> tuple[sp.bsr_matrix, BsrProduct | None]:
    """``(X @ Y, plan)`` as BSR with blocks ``(X.blocksize[0], Y.blocksize[1])``.

    With ``kernels="numba"`` the product goes through ``plan`` when it matches the operands' patterns,
    else through a new :class:`BsrProduct` (returned for the next call; ``symmetric``, see there); with
    ``"numpy"`` through scipy's product (``plan`` None).
    """
    if kernels == "numba":
        if plan is None or not plan.matches(X, Y) or plan.symmetric != symmetric:
            plan = BsrProduct(X, Y, symmetric)
        return plan(X, Y), plan
    return (X @ Y).tobsr(blocksize=(X.blocksize[0], Y.blocksize[1])), None


def bsr_block_diagonal(A: sp.bsr_matrix) -> np.ndarray:
    """The diagonal blocks of a square BSR matrix with square blocks, (nb, bs, bs) (zero where absent)."""
    bs = A.blocksize[0]
    nb = A.shape[0] // bs
    rows = np.repeat(np.arange(nb), np.diff(A.indptr))
    on = rows == A.indices
    D = np.zeros((nb, bs, bs))
    D[rows[on]] = A.data[on]
    return D


def block_diagonal_inverse(A: sp.bsr_matrix, kernels: str = "numpy") -> tuple[np.ndarray, np.ndarray]:
    """``(D, Dinv)``: the diagonal blocks of the square BSR matrix ``A`` (zero where absent), (nb, bs, bs),
    and their inverses. ``kernels="numba"``: one compiled pass (Gauss-Jordan with partial pivoting);
    ``"numpy"``: :func:`bsr_block_diagonal` and ``numpy.linalg.inv`` (LAPACK).
    Both raise ``numpy.linalg.LinAlgError`` for a singular block and agree to round-off otherwise."""
    if kernels == "numba":
        return _numba().block_diagonal_inverse(A.indptr, A.indices, np.ascontiguousarray(A.data))
    D = bsr_block_diagonal(A)
    return D, np.linalg.inv(D)


def smoothed_prolongator(AT: sp.bsr_matrix, T: sp.bsr_matrix, Dinv: np.ndarray, scale: float,
                         kernels: str = "numpy") -> sp.bsr_matrix:
    """The Jacobi-smoothed prolongator ``P = T - scale D^-1 (A T)`` from ``AT = A T`` (BSR), the tentative
    prolongator ``T`` and ``Dinv`` (nb, R, R), the inverted diagonal blocks of ``A``.

    ``kernels="numba"``: one compiled pass that overwrites ``AT``'s values and returns ``P`` on its pattern
    (which holds ``T``'s when ``A`` has all its diagonal blocks); ``"numpy"``: scaled blocks and scipy's
    sparse difference. The two agree to round-off.
    """
    if kernels == "numba":
        data = np.ascontiguousarray(AT.data)
        _numba().smooth_prolongator(AT.indptr, AT.indices, data, np.ascontiguousarray(Dinv), scale,
                                    T.indptr, T.indices, T.data)
        return sp.bsr_matrix((data, AT.indices, AT.indptr), shape=AT.shape, copy=False)
    AT.data = np.matmul(np.repeat(Dinv, np.diff(AT.indptr), axis=0), AT.data)
    AT.data *= scale  # in place: one (nnzb, 3, 6) temporary fewer to page in
    return (T - AT).tobsr(blocksize=T.blocksize)


def block_gauss_seidel_forward(indptr: np.ndarray, indices: np.ndarray, data: np.ndarray, x: np.ndarray,
                               b: np.ndarray, dinv: np.ndarray, kernels: str = "numpy") -> None:
    """One forward block Gauss-Seidel sweep, ``x`` updated in place.

    ``(indptr, indices, data)`` the BSR arrays of a square matrix with ``R x R`` blocks (``data`` (nnzb, R, R),
    C-contiguous), ``dinv`` (nb, R, R) the inverses of its diagonal blocks. ``kernels="numba"``: the compiled
    kernel (about twice as fast as pyamg's on 3x3 blocks, same sweep to round-off); ``"numpy"``: pyamg's.
    """
    if kernels == "numba":
        _numba().block_gauss_seidel_forward(indptr, indices, data, x, b, dinv)
        return
    from pyamg import amg_core

    nb, bs = dinv.shape[0], dinv.shape[1]
    amg_core.block_gauss_seidel(indptr, indices, data.reshape(-1), x, b, dinv.reshape(-1), 0, nb, 1, bs)


def block_gauss_seidel_backward(indptr: np.ndarray, indices: np.ndarray, data: np.ndarray, x: np.ndarray,
                                b: np.ndarray, dinv: np.ndarray, kernels: str = "numpy") -> None:
    """One backward block Gauss-Seidel sweep (block rows last to first), ``x`` updated in place; arguments as
    :func:`block_gauss_seidel_forward`. ``kernels="numba"``: the compiled kernel, walking the rows and each
    row's blocks backwards (the same sweep as pyamg's to round-off); ``"numpy"``: pyamg's."""
    if kernels == "numba":
        _numba().block_gauss_seidel_backward(indptr, indices, data, x, b, dinv)
        return
    from pyamg import amg_core

    nb, bs = dinv.shape[0], dinv.shape[1]
    amg_core.block_gauss_seidel(indptr, indices, data.reshape(-1), x, b, dinv.reshape(-1), nb - 1, -1, -1, bs)


class BsrOperator:
    """``x -> A x`` for a BSR matrix through the compiled block kernel (``A @ x`` for the Krylov methods).

    About 0.6x the time of scipy's ``bsr_matvec`` on the 3x3 blocks of a cloth (the block loops unrolled;
    "Compiled kernels" in the linear-solver notes of BENCHMARKS.md#cloth-grid); equal to it to round-off
    (the products within each block are summed before they are added to the result). Holds ``A``'s arrays,
    so it follows in-place updates of ``A``'s values.
    A vector of another length, dtype or dimension goes through scipy's product (which checks it).
    """

    def __init__(self, A: sp.bsr_matrix):
        self.matrix = A
        self.shape, self.dtype = A.shape, A.dtype
        self._arrays = (A.indptr, A.indices, np.ascontiguousarray(A.data))

    def matvec(self, x: np.ndarray) -> np.ndarray:
        """``A x`` (a new array); a 2-D ``x`` goes through scipy's product."""
        x = np.asarray(x)
        if x.ndim != 1 or x.dtype != np.float64 or x.shape[0] != self.shape[1]:
            return self.matrix @ x
        y = np.empty(self.shape[0])
        _numba().bsr_matvec(*self._arrays, np.ascontiguousarray(x), y, 1.0, 0.0)
        return y

    __matmul__ = dot = matvec


def bsr_operator(A: sp.bsr_matrix, kernels: str = "numpy"):
    """``A`` itself (``kernels="numpy"``) or a :class:`BsrOperator` for it (``"numba"``, float64 BSR)."""
    if kernels == "numba" and sp.issparse(A) and A.format == "bsr" and A.dtype == np.float64:
        return BsrOperator(A)
    return A


class _Level:
    """The arrays of one level of :class:`CompiledVCycle`."""

    def __init__(self, level):
        from pyamg.util.utils import get_block_diag

        A, P, R = level.A, level.P, level.R
        dinv = get_block_diag(A, blocksize=A.blocksize[0], inv_flag=True)  # A.block_D_inv when the setup left it
        self.nc = P.shape[1]
        self.A = (A.indptr, A.indices, np.ascontiguousarray(A.data))
        self.dinv = np.ascontiguousarray(dinv)
        self.P = (P.indptr, P.indices, np.ascontiguousarray(P.data))
        self.R = (R.indptr, R.indices, np.ascontiguousarray(R.data))


class CompiledVCycle:
    """One V-cycle from zero over a pyamg hierarchy, in compiled kernels (numba).

    The cycle of pyamg's ``MultilevelSolver`` with block Gauss-Seidel smoothing, a forward sweep
    before and a backward one after (a symmetric cycle, as CG needs), the coarse correction through
    each level's ``R`` and ``P``, and the coarsest level by ``coarse_solver(A, b)`` (pyamg's): equal to
    pyamg's cycle to round-off, in less time (the compiled sweeps and mat-vecs, no temporaries beyond
    the level vectors; measured per kernel in the linear-solver notes of BENCHMARKS.md#cloth-grid, "Compiled kernels").
    Single-precision copies of the levels' matrices were tried and not kept: no faster (same note, "Tried and not kept").

    Called with a right-hand side ``r``, returns the cycle's ``M^-1 r`` (a new array).
    """

    def __init__(self, levels, coarse_solver):
        self.kernels = _numba()
        self.levels = [_Level(lv) for lv in levels[:-1]]
        self.coarse_A, self.coarse_solver = levels[-1].A, coarse_solver

    def prepare(self) -> None:
        """Run the coarse solver's lazy setup (pyamg's ``pinv`` factorises on its first call) now, without a
        whole cycle."""
        self.coarse_solver(self.coarse_A, np.zeros(self.coarse_A.shape[0]))

    def __call__(self, r: np.ndarray) -> np.ndarray:
        return self._cycle(0, np.ascontiguousarray(r, dtype=np.float64))

    def _cycle(self, lvl: int, b: np.ndarray) -> np.ndarray:
        k, L = self.kernels, self.levels[lvl]
        x = np.zeros_like(b)
        k.block_gauss_seidel_forward(*L.A, x, b, L.dinv)
        res = b.copy()
        k.bsr_matvec(*L.A, x, res, -1.0, 1.0)
        cb = np.empty(L.nc)
        k.bsr_matvec(*L.R, res, cb, 1.0, 0.0)
        if lvl + 1 == len(self.levels):
            cx = np.ascontiguousarray(np.asarray(self.coarse_solver(self.coarse_A, cb)).reshape(-1))
        else:
            cx = self._cycle(lvl + 1, cb)
        k.bsr_matvec(*L.P, cx, x, 1.0, 1.0)
        k.block_gauss_seidel_backward(*L.A, x, b, L.dinv)
        return x
