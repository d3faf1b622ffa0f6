"""numba kernels of :mod:`springsim.linsolve._kernels` (imported only when numba is used).

Compiled once per block-size triple: the sizes are passed as literals, so the block loops have
constant trip counts that the compiler unrolls. ``cache=True`` keeps the machine code on disk
between processes.
"""

from __future__ import annotations

import numba

__all__ = ["bsr_matmat_numeric"]


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
