"""Spectral estimates of a model at a state: the stiffness matrix and the largest natural frequency.

``K = -dF/dq`` (exact Jacobian, free DOFs) and the masses ``m`` define the linearised
oscillation ``M x'' + K x = 0`` with angular frequencies ``omega = sqrt(lambda(M^-1 K))``.
The largest one limits explicit time steps (symplectic Euler and the explicit midpoint rule
are stable for ``h omega_max < 2``) and measures how stiff a scene is for implicit ones
(``h omega_max >> 1``).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.linalg import eigvalsh_tridiagonal

__all__ = ["stiffness_matrix", "max_frequency", "explicit_substeps"]


def stiffness_matrix(assembler, q: np.ndarray, qd: np.ndarray):
    """``K = -dF/dq`` over the free DOFs (BSR 3x3, exact Jacobian) and the DOF masses (3F,).

    Assembles ``A = M - 1 * dF/dq`` with the model's :class:`~springsim.assembly.SystemAssembler`
    and removes ``M`` from the diagonal blocks.

    Parameters
    ----------
    assembler : SystemAssembler
        The model's assembler.
    q, qd : ndarray, shape (N, 3)
        Positions [m] and velocities [m/s] at which the Jacobian is taken.

    Returns
    -------
    K : scipy.sparse.bsr_matrix, shape (3F, 3F)
        Stiffness [N/m] over the F free particles.
    m : ndarray, shape (3F,)
        Mass of each free DOF [kg].
    """
    A = assembler.assemble(q, qd, 1.0, 0.0, "exact")
    K = A.bsr.copy()
    m = assembler.model.particle_mass[assembler.free]
    K.data[assembler.pattern.diagonal_positions] -= m[:, None, None] * np.eye(3)
    return K, np.repeat(m, 3)


def max_frequency(assembler, q: np.ndarray, qd: np.ndarray | None = None, *, max_steps: int = 500,
                  tol: float = 1e-7, seed: int = 0) -> dict:
    """Largest angular frequency ``sqrt(lambda_max(M^-1 K))`` [rad/s] at ``(q, qd)``.

    Plain Lanczos (Lanczos 1950; three-term recurrence without reorthogonalisation, which leaves the
    extreme Ritz value unaffected) on ``S = M^-1/2 K M^-1/2``, stopped when the top Ritz value changed
    by less than ``tol`` (relative) over the last 10 steps, after at least 20. The Ritz value
    converges from below; the Gershgorin bound ``max_i sum_j |K_ij| / m_i`` (from above) is returned
    alongside.

    Parameters
    ----------
    assembler : SystemAssembler
        The model's assembler.
    q : ndarray, shape (N, 3)
        Positions [m].
    qd : ndarray, shape (N, 3), optional
        Velocities [m/s] (they enter through damping); default at rest.
    max_steps : int
        Largest number of Lanczos steps.
    tol : float
        Relative change of the top Ritz value over 10 steps that stops the iteration.
    seed : int
        Seed of the random start vector.

    Returns
    -------
    dict
        ``omega`` [rad/s], ``lambda`` [1/s^2], ``steps`` (Lanczos steps), ``gershgorin`` (upper
        bound on omega [rad/s]).
    """
    qd = np.zeros_like(q) if qd is None else qd
    K, m = stiffness_matrix(assembler, q, qd)
    if m.size == 0:
        return {"omega": 0.0, "lambda": 0.0, "steps": 0, "gershgorin": 0.0}
    s = 1.0 / np.sqrt(m)
    nb = K.shape[0] // 3
    rows = np.repeat(np.arange(nb), np.diff(K.indptr))
    blk = np.abs(K.data).sum(axis=2)  # (nnzb, 3): |row| sums of each block
    row_abs = np.stack([np.bincount(rows, weights=blk[:, i], minlength=nb) for i in range(3)], axis=1)
    gersh = float(np.max(row_abs.reshape(-1) / m))
    rng = np.random.default_rng(seed)
    v = rng.standard_normal(m.size)
    v /= np.linalg.norm(v)
    v_prev = np.zeros_like(v)
    alphas: list[float] = []
    betas: list[float] = []
    tops: list[float] = []
    beta = 0.0
    for k in range(max_steps):
        w = s * (K @ (s * v))
        alpha = float(v @ w)
        w -= alpha * v + beta * v_prev
        alphas.append(alpha)
        theta = eigvalsh_tridiagonal(np.array(alphas), np.array(betas))[-1] if k else alpha
        tops.append(float(theta))
        beta = float(np.linalg.norm(w))
        if beta <= 1e-13 * max(abs(theta), 1e-300):  # invariant subspace: the Ritz values are exact
            break
        if k >= 20 and abs(tops[-1] - tops[-11]) <= tol * abs(tops[-1]):
            break
        betas.append(beta)
        v_prev, v = v, w / beta
    lam = max(tops[-1], 0.0)
    return {"omega": math.sqrt(lam), "lambda": lam, "steps": len(tops), "gershgorin": math.sqrt(max(gersh, 0.0))}


def explicit_substeps(omega: float, frame_dt: float) -> int:
    """Substeps per frame for ``h = frame_dt / S < 2 / omega``: ``S = ceil(frame_dt omega / 2)`` (at least 1).

    Parameters
    ----------
    omega : float
        Largest angular frequency [rad/s] (:func:`max_frequency`).
    frame_dt : float
        Frame length [s].

    Returns
    -------
    int
        Substeps per frame, >= 1.
    """
    if not omega > 0:
        return 1
    return max(1, math.ceil(frame_dt * omega / 2.0 * (1.0 + 1e-12)))
