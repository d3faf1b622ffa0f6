"""numba kernels of :mod:`springsim.linsolve._kernels` (imported only when numba is used).

The block sizes of a cloth's hierarchy (3 and 6) get entry points that call the generic kernels with
constant sizes, so the compiler unrolls the block loops; other sizes run the generic kernels.
``cache=True`` keeps the machine code on disk between processes.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["block_gauss_seidel_forward", "bsr_matmat_numeric", "bsr_matvec"]


@numba.njit(cache=True)
def _matmat_336(Xp, Xj, Xx, Yp, Yj, Yx, Cp, Cj, Cx, marker):
    _matmat(Xp, Xj, Xx, Yp, Yj, Yx, Cp, Cj, Cx, marker, 3, 3, 6)


@numba.njit(cache=True)
def _matmat_636(Xp, Xj, Xx, Yp, Yj, Yx, Cp, Cj, Cx, marker):
    _matmat(Xp, Xj, Xx, Yp, Yj, Yx, Cp, Cj, Cx, marker, 6, 3, 6)


@numba.njit(cache=True)
def _matmat_666(Xp, Xj, Xx, Yp, Yj, Yx, Cp, Cj, Cx, marker):
    _matmat(Xp, Xj, Xx, Yp, Yj, Yx, Cp, Cj, Cx, marker, 6, 6, 6)


_SPECIAL = {(3, 3, 6): _matmat_336, (6, 3, 6): _matmat_636, (6, 6, 6): _matmat_666}


def bsr_matmat_numeric(Xp, Xj, Xx, Yp, Yj, Yx, Cp, Cj, Cx, marker, R, K, N):
    """Values ``Cx`` of ``C = X Y`` on the precomputed pattern ``(Cp, Cj)`` (BSR arrays; ``X`` has
    ``R x K`` blocks, ``Y`` ``K x N``; ``marker`` scratch of one entry per block column of ``C``)."""
    f = _SPECIAL.get((R, K, N))
    if f is None:
        _matmat(Xp, Xj, Xx, Yp, Yj, Yx, Cp, Cj, Cx, marker, R, K, N)
    else:
        f(Xp, Xj, Xx, Yp, Yj, Yx, Cp, Cj, Cx, marker)


@numba.njit(cache=True)
def _matmat(Xp, Xj, Xx, Yp, Yj, Yx, Cp, Cj, Cx, marker, R, K, N):
    for i in range(Xp.shape[0] - 1):
        for p in range(Cp[i], Cp[i + 1]):
            marker[Cj[p]] = p
            for r in range(R):
                for c in range(N):
                    Cx[p, r, c] = 0.0
        for jj in range(Xp[i], Xp[i + 1]):
            k = Xj[jj]
            for kk in range(Yp[k], Yp[k + 1]):
                p = marker[Yj[kk]]
                for r in range(R):
                    for m in range(K):
                        a = Xx[jj, r, m]
                        for c in range(N):
                            Cx[p, r, c] += a * Yx[kk, m, c]


@numba.njit(cache=True)
def _gauss_seidel(Ap, Aj, Ax, x, b, Dinv, R):
    acc = np.empty(R)
    for i in range(Ap.shape[0] - 1):
        for r in range(R):
            acc[r] = b[i * R + r]
        for jj in range(Ap[i], Ap[i + 1]):
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
def _gauss_seidel_3(Ap, Aj, Ax, x, b, Dinv):
    _gauss_seidel(Ap, Aj, Ax, x, b, Dinv, 3)


@numba.njit(cache=True)
def _gauss_seidel_6(Ap, Aj, Ax, x, b, Dinv):
    _gauss_seidel(Ap, Aj, Ax, x, b, Dinv, 6)


_GS_SPECIAL = {3: _gauss_seidel_3, 6: _gauss_seidel_6}


def block_gauss_seidel_forward(Ap, Aj, Ax, x, b, Dinv):
    """One forward block Gauss-Seidel sweep on the BSR arrays ``(Ap, Aj, Ax)`` (``Ax`` (nnzb, R, R)),
    ``x`` updated in place: ``x_i = D_i^-1 (b_i - sum_{j != i} A_ij x_j)`` row by row (``Dinv`` (nb, R, R))."""
    R = Ax.shape[1]
    f = _GS_SPECIAL.get(R)
    if f is None:
        _gauss_seidel(Ap, Aj, Ax, x, b, Dinv, R)
    else:
        f(Ap, Aj, Ax, x, b, Dinv)


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
    _matvec(Ap, Aj, Ax, x, y, alpha, beta, 3, 3)


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
