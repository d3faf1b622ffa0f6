"""numba kernels of the force terms (imported only when ``kernels="numba"``, see :mod:`springsim._runtime.accel`).

``cache=True`` keeps the machine code on disk between processes; ``error_model="numpy"`` gives IEEE results
(inf, NaN) where Python would raise, as the numpy path does.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["spring_forces"]


@numba.njit(cache=True, error_model="numpy")
def spring_forces(q, qd, pairs, ke, kd, l0, eps, out):  # pragma: no cover - compiled
    """Add every spring's force to ``out`` in one pass over the springs (:meth:`ForceSpring.eval_force`).

    Elastic ``-k (1 - l0 / max(l, eps)) d``; damping ``-b (n . v) n = -b (d . v) / l^2 d`` where
    ``b > 0`` and ``l >= eps`` (zero below eps).

    Parameters
    ----------
    q, qd : ndarray, shape (N, 3)
        Positions [m] and velocities [m/s].
    pairs : ndarray of int64, shape (P, 2)
        Spring end particles.
    ke : ndarray, shape (P,)
        Spring stiffness [N/m].
    kd : ndarray, shape (P,)
        Spring damping [N s/m].
    l0 : ndarray, shape (P,)
        Rest lengths [m].
    eps : float
        Length [m] below which a spring counts as degenerate.
    out : ndarray, shape (N, 3)
        Force accumulator [N], added to in place.
    """
    for p in range(pairs.shape[0]):
        i = pairs[p, 0]
        j = pairs[p, 1]
        dx = q[i, 0] - q[j, 0]
        dy = q[i, 1] - q[j, 1]
        dz = q[i, 2] - q[j, 2]
        l = np.sqrt(dx * dx + dy * dy + dz * dz)
        s = (l0[p] / max(l, eps) - 1.0) * ke[p]
        if kd[p] > 0.0 and l >= eps:
            vx = qd[i, 0] - qd[j, 0]
            vy = qd[i, 1] - qd[j, 1]
            vz = qd[i, 2] - qd[j, 2]
            s -= kd[p] * (dx * vx + dy * vy + dz * vz) / (l * l)
        fx = s * dx
        fy = s * dy
        fz = s * dz
        out[i, 0] += fx
        out[i, 1] += fy
        out[i, 2] += fz
        out[j, 0] -= fx
        out[j, 1] -= fy
        out[j, 2] -= fz
