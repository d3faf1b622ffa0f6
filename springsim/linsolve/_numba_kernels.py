"""numba kernels of :mod:`springsim.linsolve._kernels` (imported only when numba is used).

The block sizes of a cloth's hierarchy (3 and 6) get entry points that call the generic kernels with
constant sizes, so the compiler unrolls the block loops; the block products for inner sizes 3 and 6
also keep the left block in scalars (``_matmat_k3``, ``_matmat_k6``). Other sizes run the generic
kernels.
``cache=True`` keeps the machine code on disk between processes.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["block_diagonal_inverse", "block_gauss_seidel_backward", "block_gauss_seidel_forward", "bsr_matmat_numeric",
           "bsr_matmat_symmetric", "bsr_matvec", "smooth_prolongator"]


@numba.njit(cache=True, inline="always")
def _start_row(Cp, Cj, Cx, marker, i, first, R, N):
    # zero the blocks (i, j >= first) of C's block row i and record their positions
    for p in range(Cp[i], Cp[i + 1]):
        if Cj[p] >= first:
            marker[Cj[p]] = p
            for r in range(R):
                for c in range(N):
                    Cx[p, r, c] = 0.0


@numba.njit(cache=True, inline="always")
def _mirror_diagonal(Cp, Cj, Cx, i, R):
    # the lower triangle of the diagonal block of row i from its upper one
    for p in range(Cp[i], Cp[i + 1]):
        if Cj[p] == i:
            for r in range(R):
                for c in range(r):
                    Cx[p, r, c] = Cx[p, c, r]


@numba.njit(cache=True)
def _matmat(Xp, Xj, Xx, Yp, Yj, Yx, Cp, Cj, Cx, marker, R, K, N, upper):
    # upper: only the blocks (i, j >= i) of C, and each diagonal block's lower triangle mirrors its upper one
    for i in range(Xp.shape[0] - 1):
        first = i if upper else 0
        _start_row(Cp, Cj, Cx, marker, i, first, R, N)
        for jj in range(Xp[i], Xp[i + 1]):
            k = Xj[jj]
            for kk in range(Yp[k], Yp[k + 1]):
                j = Yj[kk]
                if j < first:
                    continue
                p = marker[j]
                for r in range(R):
                    for m in range(K):
                        a = Xx[jj, r, m]
                        for c in range(N):
                            Cx[p, r, c] += a * Yx[kk, m, c]
        if upper:
            _mirror_diagonal(Cp, Cj, Cx, i, R)


# The kernels for the inner block sizes of a cloth's hierarchy (3 on the finest level, 6 below) hold the
# block of X in scalars (a tuple per three or six entries) across the blocks of Y it meets, instead of
# reloading it for every product: about 0.7x the time of the generic loop. Each entry is summed in the
# generic loop's order (the inner index m ascending), so the results are bitwise the same.

@numba.njit(cache=True, inline="always")
def _rows3(Xx, jj, r0):
    return (Xx[jj, r0, 0], Xx[jj, r0, 1], Xx[jj, r0, 2], Xx[jj, r0 + 1, 0], Xx[jj, r0 + 1, 1], Xx[jj, r0 + 1, 2],
            Xx[jj, r0 + 2, 0], Xx[jj, r0 + 2, 1], Xx[jj, r0 + 2, 2])


@numba.njit(cache=True, inline="always")
def _axpy3(Cx, p, r0, a, Yx, kk, N):
    # rows r0 .. r0 + 2 of block p of C += (those rows of X's block, a) @ (block kk of Y); inner size 3
    a00, a01, a02, a10, a11, a12, a20, a21, a22 = a
    for c in range(N):
        y0, y1, y2 = Yx[kk, 0, c], Yx[kk, 1, c], Yx[kk, 2, c]
        Cx[p, r0, c] = ((Cx[p, r0, c] + a00 * y0) + a01 * y1) + a02 * y2
        Cx[p, r0 + 1, c] = ((Cx[p, r0 + 1, c] + a10 * y0) + a11 * y1) + a12 * y2
        Cx[p, r0 + 2, c] = ((Cx[p, r0 + 2, c] + a20 * y0) + a21 * y1) + a22 * y2


@numba.njit(cache=True)
def _matmat_k3(Xp, Xj, Xx, Yp, Yj, Yx, Cp, Cj, Cx, marker, R, N, upper):
    # _matmat for K = 3 and R = 3 or 6 (only those: other R would get rows 0-2 only; the entry points below
    # are the only callers)
    for i in range(Xp.shape[0] - 1):
        first = i if upper else 0
        _start_row(Cp, Cj, Cx, marker, i, first, R, N)
        for jj in range(Xp[i], Xp[i + 1]):
            k = Xj[jj]
            top = _rows3(Xx, jj, 0)
            bottom = _rows3(Xx, jj, 3) if R == 6 else top
            for kk in range(Yp[k], Yp[k + 1]):
                j = Yj[kk]
                if j < first:
                    continue
                p = marker[j]
                _axpy3(Cx, p, 0, top, Yx, kk, N)
                if R == 6:
                    _axpy3(Cx, p, 3, bottom, Yx, kk, N)
        if upper:
            _mirror_diagonal(Cp, Cj, Cx, i, R)


@numba.njit(cache=True, inline="always")
def _row6(Xx, jj, r):
    return (Xx[jj, r, 0], Xx[jj, r, 1], Xx[jj, r, 2], Xx[jj, r, 3], Xx[jj, r, 4], Xx[jj, r, 5])


@numba.njit(cache=True, inline="always")
def _axpy6(Cx, p, r, a, Yx, kk, N):
    # row r of block p of C += (row r of X's block, a) @ (block kk of Y); inner size 6
    a0, a1, a2, a3, a4, a5 = a
    for c in range(N):
        Cx[p, r, c] = (((((Cx[p, r, c] + a0 * Yx[kk, 0, c]) + a1 * Yx[kk, 1, c]) + a2 * Yx[kk, 2, c])
                        + a3 * Yx[kk, 3, c]) + a4 * Yx[kk, 4, c]) + a5 * Yx[kk, 5, c]


@numba.njit(cache=True)
def _matmat_k6(Xp, Xj, Xx, Yp, Yj, Yx, Cp, Cj, Cx, marker, N, upper):
    # _matmat for R = K = 6
    for i in range(Xp.shape[0] - 1):
        first = i if upper else 0
        _start_row(Cp, Cj, Cx, marker, i, first, 6, N)
        for jj in range(Xp[i], Xp[i + 1]):
            k = Xj[jj]
            a0, a1, a2 = _row6(Xx, jj, 0), _row6(Xx, jj, 1), _row6(Xx, jj, 2)
            a3, a4, a5 = _row6(Xx, jj, 3), _row6(Xx, jj, 4), _row6(Xx, jj, 5)
            for kk in range(Yp[k], Yp[k + 1]):
                j = Yj[kk]
                if j < first:
                    continue
                p = marker[j]
                _axpy6(Cx, p, 0, a0, Yx, kk, N)
                _axpy6(Cx, p, 1, a1, Yx, kk, N)
                _axpy6(Cx, p, 2, a2, Yx, kk, N)
                _axpy6(Cx, p, 3, a3, Yx, kk, N)
                _axpy6(Cx, p, 4, a4, Yx, kk, N)
                _axpy6(Cx, p, 5, a5, Yx, kk, N)
        if upper:
            _mirror_diagonal(Cp, Cj, Cx, i, 6)


@numba.njit(cache=True)
def _matmat_336(Xp, Xj, Xx, Yp, Yj, Yx, Cp, Cj, Cx, marker):
    _matmat_k3(Xp, Xj, Xx, Yp, Yj, Yx, Cp, Cj, Cx, marker, 3, 6, False)


@numba.njit(cache=True)
def _matmat_636(Xp, Xj, Xx, Yp, Yj, Yx, Cp, Cj, Cx, marker):
    _matmat_k3(Xp, Xj, Xx, Yp, Yj, Yx, Cp, Cj, Cx, marker, 6, 6, False)


@numba.njit(cache=True)
def _matmat_666(Xp, Xj, Xx, Yp, Yj, Yx, Cp, Cj, Cx, marker):
    _matmat_k6(Xp, Xj, Xx, Yp, Yj, Yx, Cp, Cj, Cx, marker, 6, False)


_SPECIAL = {(3, 3, 6): _matmat_336, (6, 3, 6): _matmat_636, (6, 6, 6): _matmat_666}


def bsr_matmat_numeric(Xp, Xj, Xx, Yp, Yj, Yx, Cp, Cj, Cx, marker, R, K, N):
    """Values ``Cx`` of ``C = X Y`` on the precomputed pattern ``(Cp, Cj)`` (BSR arrays; ``X`` has
    ``R x K`` blocks, ``Y`` ``K x N``; ``marker`` scratch of one entry per block column of ``C``)."""
    f = _SPECIAL.get((R, K, N))
    if f is None:
        _matmat(Xp, Xj, Xx, Yp, Yj, Yx, Cp, Cj, Cx, marker, R, K, N, False)
    else:
        f(Xp, Xj, Xx, Yp, Yj, Yx, Cp, Cj, Cx, marker)


@numba.njit(cache=True)
def _mirror(Cx, lower, upper, R):
    for t in range(lower.shape[0]):
        p, q = lower[t], upper[t]
        for r in range(R):
            for c in range(R):
                Cx[p, r, c] = Cx[q, c, r]


@numba.njit(cache=True)
def _matmat_sym_636(Xp, Xj, Xx, Yp, Yj, Yx, Cp, Cj, Cx, marker, lower, upper):
    _matmat_k3(Xp, Xj, Xx, Yp, Yj, Yx, Cp, Cj, Cx, marker, 6, 6, True)
    _mirror(Cx, lower, upper, 6)


@numba.njit(cache=True)
def _matmat_sym_666(Xp, Xj, Xx, Yp, Yj, Yx, Cp, Cj, Cx, marker, lower, upper):
    _matmat_k6(Xp, Xj, Xx, Yp, Yj, Yx, Cp, Cj, Cx, marker, 6, True)
    _mirror(Cx, lower, upper, 6)


_SYM_SPECIAL = {(6, 3, 6): _matmat_sym_636, (6, 6, 6): _matmat_sym_666}


def bsr_matmat_symmetric(Xp, Xj, Xx, Yp, Yj, Yx, Cp, Cj, Cx, marker, lower, upper, R, K, N):
    """As :func:`bsr_matmat_numeric` for a product ``C`` known to be symmetric (square blocks, ``R == N``,
    symmetric pattern): the entries on and above the diagonal are computed (as ``bsr_matmat_numeric``
    computes them), each block ``lower[t]`` below the block diagonal is the transpose of block ``upper[t]``
    and the diagonal blocks' lower triangles mirror their upper ones."""
    f = _SYM_SPECIAL.get((R, K, N))
    if f is None:
        _matmat(Xp, Xj, Xx, Yp, Yj, Yx, Cp, Cj, Cx, marker, R, K, N, True)
        _mirror(Cx, lower, upper, R)
    else:
        f(Xp, Xj, Xx, Yp, Yj, Yx, Cp, Cj, Cx, marker, lower, upper)


@numba.njit(cache=True)
def _block_diagonal_inverse(Ap, Aj, Ax, D, Dinv, R):
    # Gauss-Jordan elimination with partial pivoting on each diagonal block; returns the first block row
    # whose block is singular (an exactly zero pivot), or -1
    M = np.empty((R, R))
    for i in range(Ap.shape[0] - 1):
        for r in range(R):
            for c in range(R):
                D[i, r, c] = 0.0
        for p in range(Ap[i], Ap[i + 1]):
            if Aj[p] == i:
                for r in range(R):
                    for c in range(R):
                        D[i, r, c] = Ax[p, r, c]
        for r in range(R):
            for c in range(R):
                M[r, c] = D[i, r, c]
                Dinv[i, r, c] = 1.0 if r == c else 0.0
        for k in range(R):
            piv, best = k, abs(M[k, k])
            for r in range(k + 1, R):
                if abs(M[r, k]) > best:
                    piv, best = r, abs(M[r, k])
            if best == 0.0:
                return i
            if piv != k:
                for c in range(R):
                    M[k, c], M[piv, c] = M[piv, c], M[k, c]
                    Dinv[i, k, c], Dinv[i, piv, c] = Dinv[i, piv, c], Dinv[i, k, c]
            d = 1.0 / M[k, k]
            for c in range(R):
                M[k, c] *= d
                Dinv[i, k, c] *= d
            for r in range(R):
                if r != k:
                    f = M[r, k]
                    for c in range(R):
                        M[r, c] -= f * M[k, c]
                        Dinv[i, r, c] -= f * Dinv[i, k, c]
    return -1


@numba.njit(cache=True)
def _block_diagonal_inverse_3(Ap, Aj, Ax, D, Dinv):
    return _block_diagonal_inverse(Ap, Aj, Ax, D, Dinv, 3)


@numba.njit(cache=True)
def _block_diagonal_inverse_6(Ap, Aj, Ax, D, Dinv):
    return _block_diagonal_inverse(Ap, Aj, Ax, D, Dinv, 6)


_INV_SPECIAL = {3: _block_diagonal_inverse_3, 6: _block_diagonal_inverse_6}


def block_diagonal_inverse(Ap, Aj, Ax):
    """``(D, Dinv)``: the diagonal blocks of the square BSR arrays ``(Ap, Aj, Ax)`` (``Ax`` (nnzb, R, R);
    zero where absent) and their inverses, each (nb, R, R), by Gauss-Jordan elimination with partial
    pivoting. Raises ``numpy.linalg.LinAlgError`` for a singular block (as ``numpy.linalg.inv``)."""
    R = Ax.shape[1]
    nb = Ap.shape[0] - 1
    D, Dinv = np.empty((nb, R, R)), np.empty((nb, R, R))
    f = _INV_SPECIAL.get(R)
    bad = _block_diagonal_inverse(Ap, Aj, Ax, D, Dinv, R) if f is None else f(Ap, Aj, Ax, D, Dinv)
    if bad >= 0:
        raise np.linalg.LinAlgError(f"Singular matrix: diagonal block {bad}")
    return D, Dinv


@numba.njit(cache=True)
def _smooth_prolongator(Cp, Cj, Cx, Dinv, scale, Tp, Tj, Tx, R, N):
    # Cx <- T - scale * Dinv C, block row by block row, on the pattern of C (which holds T's); returns the
    # first block row with a block of T outside that pattern, or -1
    tmp = np.empty(R)
    for i in range(Cp.shape[0] - 1):
        for p in range(Cp[i], Cp[i + 1]):
            for c in range(N):
                for r in range(R):
                    s = 0.0
                    for m in range(R):
                        s += Dinv[i, r, m] * Cx[p, m, c]
                    tmp[r] = s
                for r in range(R):
                    Cx[p, r, c] = -(tmp[r] * scale)
        for t in range(Tp[i], Tp[i + 1]):
            found = False
            for p in range(Cp[i], Cp[i + 1]):
                if Cj[p] == Tj[t]:
                    for r in range(R):
                        for c in range(N):
                            Cx[p, r, c] += Tx[t, r, c]
                    found = True
                    break
            if not found:
                return i
    return -1


@numba.njit(cache=True)
def _smooth_prolongator_36(Cp, Cj, Cx, Dinv, scale, Tp, Tj, Tx):
    return _smooth_prolongator(Cp, Cj, Cx, Dinv, scale, Tp, Tj, Tx, 3, 6)


@numba.njit(cache=True)
def _smooth_prolongator_66(Cp, Cj, Cx, Dinv, scale, Tp, Tj, Tx):
    return _smooth_prolongator(Cp, Cj, Cx, Dinv, scale, Tp, Tj, Tx, 6, 6)


_SP_SPECIAL = {(3, 6): _smooth_prolongator_36, (6, 6): _smooth_prolongator_66}


def smooth_prolongator(Cp, Cj, Cx, Dinv, scale, Tp, Tj, Tx):
    """``Cx <- T - scale D^-1 C`` in place: ``(Cp, Cj, Cx)`` the BSR arrays of ``C = A T`` (``Cx`` (nnzb, R, N),
    C-contiguous), ``Dinv`` (nb, R, R) the inverted diagonal blocks of ``A``, ``(Tp, Tj, Tx)`` those of ``T``,
    whose blocks must lie in the pattern of ``C`` (``ValueError`` otherwise)."""
    R, N = Cx.shape[1], Cx.shape[2]
    f = _SP_SPECIAL.get((R, N))
    args = (Cp, Cj, Cx, Dinv, float(scale), Tp, Tj, np.ascontiguousarray(Tx))
    bad = _smooth_prolongator(*args, R, N) if f is None else f(*args)
    if bad >= 0:
        raise ValueError(f"block row {bad} of T lies outside the pattern of A T")


@numba.njit(cache=True, inline="always")
def _gauss_seidel_row(Ap, Aj, Ax, x, b, Dinv, i, backward, acc, R):
    # block row i of a sweep: x_i = D_i^-1 (b_i - sum_{j != i} A_ij x_j); backward: the row's blocks from last
    # to first (so that a backward sweep is bitwise the forward sweep on the matrix with its block rows and
    # columns reversed, and pyamg's backward sweep, which walks a row's blocks forwards, to round-off)
    for r in range(R):
        acc[r] = b[i * R + r]
    start, stop = Ap[i], Ap[i + 1]
    for u in range(stop - start):
        jj = stop - 1 - u if backward else start + u
        j = Aj[jj]
        if j != i:
            for r in range(R):
                s = 0.0
                for c in range(R):
                    s += Ax[jj, r, c] * x[j * R + c]
                acc[r] -= s
    for r in range(R):
        s = 0.0
        for c in range(R):
            s += Dinv[i, r, c] * acc[c]
        x[i * R + r] = s


@numba.njit(cache=True)
def _gauss_seidel(Ap, Aj, Ax, x, b, Dinv, R, backward):
    acc = np.empty(R)
    nb = Ap.shape[0] - 1
    for t in range(nb):
        _gauss_seidel_row(Ap, Aj, Ax, x, b, Dinv, nb - 1 - t if backward else t, backward, acc, R)


@numba.njit(cache=True, inline="always")
def _gauss_seidel_row3(Ap, Aj, Ax, x, b, Dinv, i, backward):
    # block row i of a sweep with 3x3 blocks, the sums in scalars (in the generic kernel's order: bitwise
    # the same); backward: the row's blocks from last to first
    a0, a1, a2 = b[3 * i], b[3 * i + 1], b[3 * i + 2]
    start, stop = Ap[i], Ap[i + 1]
    for u in range(stop - start):
        jj = stop - 1 - u if backward else start + u
        j = Aj[jj]
        if j != i:
            x0, x1, x2 = x[3 * j], x[3 * j + 1], x[3 * j + 2]
            a0 -= (Ax[jj, 0, 0] * x0 + Ax[jj, 0, 1] * x1) + Ax[jj, 0, 2] * x2
            a1 -= (Ax[jj, 1, 0] * x0 + Ax[jj, 1, 1] * x1) + Ax[jj, 1, 2] * x2
            a2 -= (Ax[jj, 2, 0] * x0 + Ax[jj, 2, 1] * x1) + Ax[jj, 2, 2] * x2
    x[3 * i] = (Dinv[i, 0, 0] * a0 + Dinv[i, 0, 1] * a1) + Dinv[i, 0, 2] * a2
    x[3 * i + 1] = (Dinv[i, 1, 0] * a0 + Dinv[i, 1, 1] * a1) + Dinv[i, 1, 2] * a2
    x[3 * i + 2] = (Dinv[i, 2, 0] * a0 + Dinv[i, 2, 1] * a1) + Dinv[i, 2, 2] * a2


@numba.njit(cache=True, inline="always")
def _gauss_seidel_3(Ap, Aj, Ax, x, b, Dinv, backward):
    nb = Ap.shape[0] - 1
    for t in range(nb):
        _gauss_seidel_row3(Ap, Aj, Ax, x, b, Dinv, nb - 1 - t if backward else t, backward)


@numba.njit(cache=True)
def _gauss_seidel_forward_3(Ap, Aj, Ax, x, b, Dinv):
    _gauss_seidel_3(Ap, Aj, Ax, x, b, Dinv, False)


@numba.njit(cache=True)
def _gauss_seidel_forward_6(Ap, Aj, Ax, x, b, Dinv):
    _gauss_seidel(Ap, Aj, Ax, x, b, Dinv, 6, False)


@numba.njit(cache=True)
def _gauss_seidel_backward_3(Ap, Aj, Ax, x, b, Dinv):
    _gauss_seidel_3(Ap, Aj, Ax, x, b, Dinv, True)


@numba.njit(cache=True)
def _gauss_seidel_backward_6(Ap, Aj, Ax, x, b, Dinv):
    _gauss_seidel(Ap, Aj, Ax, x, b, Dinv, 6, True)


_GS_SPECIAL = {(3, False): _gauss_seidel_forward_3, (6, False): _gauss_seidel_forward_6,
               (3, True): _gauss_seidel_backward_3, (6, True): _gauss_seidel_backward_6}


def _sweep(Ap, Aj, Ax, x, b, Dinv, backward):
    R = Ax.shape[1]
    f = _GS_SPECIAL.get((R, backward))
    if f is None:
        _gauss_seidel(Ap, Aj, Ax, x, b, Dinv, R, backward)
    else:
        f(Ap, Aj, Ax, x, b, Dinv)


def block_gauss_seidel_forward(Ap, Aj, Ax, x, b, Dinv):
    """One forward block Gauss-Seidel sweep on the BSR arrays ``(Ap, Aj, Ax)`` (``Ax`` (nnzb, R, R)),
    ``x`` updated in place: ``x_i = D_i^-1 (b_i - sum_{j != i} A_ij x_j)`` row by row (``Dinv`` (nb, R, R))."""
    _sweep(Ap, Aj, Ax, x, b, Dinv, False)


def block_gauss_seidel_backward(Ap, Aj, Ax, x, b, Dinv):
    """One backward block Gauss-Seidel sweep, as :func:`block_gauss_seidel_forward` with the block rows
    (and the blocks within each row) taken from last to first."""
    _sweep(Ap, Aj, Ax, x, b, Dinv, True)


@numba.njit(cache=True)
def _matvec(Ap, Aj, Ax, x, y, alpha, beta, R, C):
    for i in range(Ap.shape[0] - 1):
        for r in range(R):
            y[i * R + r] = 0.0 if beta == 0.0 else beta * y[i * R + r]
        for jj in range(Ap[i], Ap[i + 1]):
            j = Aj[jj]
            for r in range(R):
                s = 0.0
                for c in range(C):
                    s += Ax[jj, r, c] * x[j * C + c]
                y[i * R + r] += alpha * s


@numba.njit(cache=True)
def _matvec_33(Ap, Aj, Ax, x, y, alpha, beta):
    # _matvec with the sums of a block row in scalars (one store per row; equal to it to round-off)
    for i in range(Ap.shape[0] - 1):
        s0 = s1 = s2 = 0.0
        for jj in range(Ap[i], Ap[i + 1]):
            j = 3 * Aj[jj]
            x0, x1, x2 = x[j], x[j + 1], x[j + 2]
            s0 += (Ax[jj, 0, 0] * x0 + Ax[jj, 0, 1] * x1) + Ax[jj, 0, 2] * x2
            s1 += (Ax[jj, 1, 0] * x0 + Ax[jj, 1, 1] * x1) + Ax[jj, 1, 2] * x2
            s2 += (Ax[jj, 2, 0] * x0 + Ax[jj, 2, 1] * x1) + Ax[jj, 2, 2] * x2
        if beta == 0.0:
            y[3 * i], y[3 * i + 1], y[3 * i + 2] = alpha * s0, alpha * s1, alpha * s2
        else:
            y[3 * i] = beta * y[3 * i] + alpha * s0
            y[3 * i + 1] = beta * y[3 * i + 1] + alpha * s1
            y[3 * i + 2] = beta * y[3 * i + 2] + alpha * s2


@numba.njit(cache=True)
def _matvec_66(Ap, Aj, Ax, x, y, alpha, beta):
    _matvec(Ap, Aj, Ax, x, y, alpha, beta, 6, 6)


@numba.njit(cache=True)
def _matvec_36(Ap, Aj, Ax, x, y, alpha, beta):
    _matvec(Ap, Aj, Ax, x, y, alpha, beta, 3, 6)


@numba.njit(cache=True)
def _matvec_63(Ap, Aj, Ax, x, y, alpha, beta):
    _matvec(Ap, Aj, Ax, x, y, alpha, beta, 6, 3)


_MV_SPECIAL = {(3, 3): _matvec_33, (6, 6): _matvec_66, (3, 6): _matvec_36, (6, 3): _matvec_63}


def bsr_matvec(Ap, Aj, Ax, x, y, alpha=1.0, beta=0.0):
    """``y = beta y + alpha A x`` for the BSR arrays ``(Ap, Aj, Ax)`` (``Ax`` (nnzb, R, C)), in place;
    ``beta = 0`` overwrites ``y`` (whatever it held)."""
    f = _MV_SPECIAL.get((Ax.shape[1], Ax.shape[2]))
    if f is None:
        _matvec(Ap, Aj, Ax, x, y, float(alpha), float(beta), Ax.shape[1], Ax.shape[2])
    else:
        f(Ap, Aj, Ax, x, y, float(alpha), float(beta))
