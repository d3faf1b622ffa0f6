"""The total force written straight from the model's arrays: the reference for the force terms.

:func:`naive_forces` sums every registered term's :meth:`~springsim.forces.ForceTerm.naive_force`: PA2's
equations (gravity, drag, damped springs, softened gravitational pairs) with plain fancy-index gathers and
``np.add.at`` scatters, sharing no code with the terms' ``eval_force``. Tests check every term's
``eval_force`` against it, and ``python -m benchmarks explicit-speed`` times the terms against it; it is
never used to simulate.
"""

from __future__ import annotations

import numpy as np

__all__ = ["naive_forces"]


def naive_forces(model, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
    """Total force (N, 3) [N] on every particle of ``model`` at ``(q, qd)``, fixed ones included.

    Degenerate pairs are treated as in the force terms: below ``model.pair_epsilon`` a spring's
    elastic force is ``-k (1 - l0/eps) d`` and its damping zero; below its softening length a
    gravitational pair's force is ``-G m_i m_j d / eps^3``.

    Parameters
    ----------
    model : Model
        The model.
    q, qd : ndarray, shape (N, 3)
        Positions [m] and velocities [m/s].

    Returns
    -------
    ndarray, shape (N, 3)
        Total force [N], the sum of the terms' :meth:`~springsim.forces.ForceTerm.naive_force` in the order of
        :data:`~springsim.forces.FORCE_TERMS`.
    """
    from . import FORCE_TERMS

    f = np.zeros(np.shape(q))
    for cls in FORCE_TERMS.values():
        f += cls.naive_force(model, q, qd)
    return f
