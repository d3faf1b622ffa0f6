"""The total force written straight from the model's arrays: the reference for the force terms.

:func:`naive_forces` evaluates PA2's equations (gravity, drag, damped springs, softened
gravitational pairs) with plain fancy-index gathers and ``np.add.at`` scatters, sharing no code
with the force terms. Tests check every term's ``eval_force`` against it, and
``python -m benchmarks explicit-speed`` times the terms against it; it is never used to simulate.
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
        Total force [N].
    """
    f = model.particle_mass[:, None] * model.gravity_vector[None, :]
    f = f - model.particle_drag[:, None] * qd
    pairs, eps = model.spring_indices, model.pair_epsilon
    if len(pairs):
        d = q[pairs[:, 0]] - q[pairs[:, 1]]
        l = np.linalg.norm(d, axis=1)
        safe = np.maximum(l, eps)
        fs = -(model.spring_stiffness * (1.0 - model.spring_rest_length / safe))[:, None] * d
        n = np.where((l >= eps)[:, None], d / safe[:, None], 0.0)
        v = qd[pairs[:, 0]] - qd[pairs[:, 1]]
        fs -= (model.spring_damping * np.sum(n * v, axis=1))[:, None] * n
        np.add.at(f, pairs[:, 0], fs)
        np.add.at(f, pairs[:, 1], -fs)
    pairs = model.gravitational_indices
    if len(pairs):
        d = q[pairs[:, 0]] - q[pairs[:, 1]]
        ls = np.maximum(np.linalg.norm(d, axis=1), model.gravitational_softening)
        m = model.particle_mass
        fg = -(model.gravitational_G * m[pairs[:, 0]] * m[pairs[:, 1]] / ls**3)[:, None] * d
        np.add.at(f, pairs[:, 0], fg)
        np.add.at(f, pairs[:, 1], -fg)
    return f
