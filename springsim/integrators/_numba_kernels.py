"""numba kernels of the explicit integrators (loaded only when the force pass is compiled, see
:mod:`springsim._runtime.accel`).

Each kernel performs the same floating-point operations in the same order as its numpy twin (no fused
multiply-add: numba contracts only under ``fastmath``), so the two give the same states (the tests compare
them to a few ulps). ``error_model="numpy"``: IEEE results (inf, NaN) where
Python would raise, as in numpy.
"""

from __future__ import annotations

import numba

__all__ = ["symplectic_euler_update"]


@numba.njit(cache=True, error_model="numpy")
def symplectic_euler_update(q, qd, f, inv_mass, fixed, h, q1, qd1):  # pragma: no cover - compiled
    """``qd1 = qd + (f inv_mass) h`` (the acceleration zero where ``fixed``), ``q1 = q + qd1 h``, one pass."""
    for i in range(q.shape[0]):
        w = inv_mass[i]
        for c in range(3):
            a = 0.0 if fixed[i] else f[i, c] * w
            qd1[i, c] = qd[i, c] + a * h
            q1[i, c] = q[i, c] + qd1[i, c] * h  # the stored velocity, as the numpy update uses
