"""Smoothed-aggregation setup for symmetric block (BSR) systems, built from pyamg's parts.

pyamg's :func:`pyamg.smoothed_aggregation_solver` estimates the spectral radius of the Jacobi
prolongation smoother by restarted Arnoldi on the non-symmetric ``D^-1 A`` (about a third of its
setup on the benchmark cloth), and recomputes strength and aggregates although a cloth's
connectivity never changes. This module builds the same hierarchy
(symmetric strength, standard aggregation, candidate fitting, one Jacobi step with the
inverse block diagonal, Galerkin products) with two differences:

* ``rho(D^-1 A)`` comes from a short Lanczos run on ``D^-1 A`` in the ``D`` inner
  product (where it is self-adjoint, ``A`` and the block diagonal ``D`` being SPD):
  ``lanczos_steps`` products instead of ~120; the extreme Ritz value is accurate to a few
  per cent after 12 steps, which is all the smoothing weight ``omega / rho`` needs. Every
  level keeps its top Ritz vector (``level.ritz``); passed back for the next matrix with the
  same pattern (``ritz``), it starts a run of ``warm_lanczos_steps`` (4) that is as accurate
  as 12 steps from a random start ("Warm-started spectral radius" in
  the linear-solver notes of BENCHMARKS.md#cloth-grid);
* the aggregates of every level can be passed back in (``aggregates``) and are then
  reused: the strength graph of a mass-spring system follows its springs, whose set is
  fixed, so aggregates from an earlier matrix with the same pattern stay good (the
  prolongator itself is always rebuilt from the current matrix and candidates).

It gives pyamg's levels (aggregation identical) and the same CG iterations, with a setup about
40 % shorter ("Own setup" in the linear-solver notes of BENCHMARKS.md#cloth-grid).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.linalg import eigh_tridiagonal, eigvalsh_tridiagonal

from ._kernels import block_diagonal_inverse, bsr_matmat, bsr_operator, smoothed_prolongator
from ._kernels import bsr_block_diagonal  # noqa: F401  (re-exported: the setup's block-diagonal helper)

__all__ = ["bsr_block_diagonal", "lanczos_recurrence", "lanczos_rho", "smoothed_aggregation_levels"]


def _block_diagonal_operator(D: np.ndarray) -> sp.bsr_matrix:
    """``D`` (nb, bs, bs) as a block-diagonal BSR matrix: its compiled matrix-vector product is
    about twice as fast as ``einsum`` over the blocks."""
    nb, bs = D.shape[0], D.shape[1]
    return sp.bsr_matrix((D, np.arange(nb), np.arange(nb + 1)), shape=(nb * bs, nb * bs))


def lanczos_recurrence(apply_A, apply_D, apply_Dinv, q: np.ndarray, steps: int, dot=None,
                       return_vector: bool = False):
    """Largest Ritz value of ``D^-1 A`` by ``steps`` Lanczos steps in the ``D`` inner product, from ``q``.

    The recurrence behind :func:`lanczos_rho`, on any vectors: ``apply_A``, ``apply_D`` and ``apply_Dinv`` map a
    vector to its product with ``A``, ``D`` and ``D^-1``, and ``dot(u, v)`` is the inner product (default
    ``float(u @ v)``; the distributed set-up passes an all-reduced one, :mod:`springsim.distributed.sa`).

    Returns
    -------
    float or tuple
        The largest Ritz value, or ``nan`` on breakdown (``A`` or ``D`` not positive definite); with
        ``return_vector``: ``(rho, y)``, ``y`` the top Ritz vector (None on breakdown).
    """
    dot = dot or (lambda u, v: float(u @ v))
    nan = (float("nan"), None) if return_vector else float("nan")
    nq = dot(q, apply_D(q))
    if not nq > 0.0:
        return nan
    q = q / np.sqrt(nq)
    q_prev = np.zeros(q.size)
    alphas, betas, basis = [], [], []
    beta = 0.0
    for _ in range(max(int(steps), 1)):
        if return_vector:
            basis.append(q)
        Aq = apply_A(q)
        alpha = dot(q, Aq)
        w = apply_Dinv(Aq) - alpha * q - beta * q_prev
        alphas.append(alpha)
        beta2 = dot(w, apply_D(w))
        if not np.isfinite(alpha) or not np.isfinite(beta2) or beta2 < 0.0:
            return nan
        beta = np.sqrt(beta2)
        if beta <= 1e-12 * abs(alpha):  # invariant subspace: the Ritz values are exact
            break
        betas.append(beta)
        q_prev, q = q, w / beta
    k = len(alphas)
    if not return_vector:
        return float(eigvalsh_tridiagonal(np.array(alphas), np.array(betas[:k - 1]))[-1])
    theta, S = eigh_tridiagonal(np.array(alphas), np.array(betas[:k - 1]))
    return float(theta[-1]), np.column_stack(basis) @ S[:, -1]


def lanczos_rho(A: sp.bsr_matrix, D: np.ndarray, Dinv: np.ndarray, steps: int = 12, seed: int = 0,
                start: np.ndarray | None = None, return_vector: bool = False, kernels: str = "numpy"):
    """Largest eigenvalue of ``D^-1 A`` by ``steps`` Lanczos steps in the ``D`` inner product.

    ``A`` symmetric positive definite, ``D`` its block diagonal (SPD), ``Dinv`` the block
    inverses. Returns the largest Ritz value (a lower bound, converging from below), or
    ``nan`` when the run breaks down (``A`` or ``D`` not positive definite). The run starts
    from ``start`` when given (e.g. the top Ritz vector of a nearby matrix), else from a
    random vector (``seed``). With ``return_vector``: ``(rho, y)``, ``y`` the top Ritz vector
    (None on breakdown). ``kernels="numba"`` applies the three matrices with the compiled block
    product (:class:`~springsim.linsolve._kernels.BsrOperator`). The recurrence:
    :func:`lanczos_recurrence`.
    """
    n = A.shape[0]
    Dop, Dinvop = (bsr_operator(_block_diagonal_operator(M), kernels) for M in (D, Dinv))
    A = bsr_operator(A, kernels)
    q = np.random.default_rng(seed).standard_normal(n) if start is None else np.array(start, dtype=A.dtype)
    return lanczos_recurrence(lambda v: A @ v, lambda v: Dop @ v, lambda v: Dinvop @ v, q, steps,
                              return_vector=return_vector)


def smoothed_aggregation_levels(A: sp.bsr_matrix, B: np.ndarray, *, theta: float = 0.1, omega: float = 4.0 / 3.0,
                                max_coarse: int = 50, max_levels: int = 10, lanczos_steps: int = 12,
                                aggregates: list | None = None, ritz: list | None = None,
                                warm_lanczos_steps: int = 4, kernels: str = "numpy", products: list | None = None):
    """The levels of a smoothed-aggregation hierarchy for the SPD BSR matrix ``A``.

    Parameters
    ----------
    A : bsr_matrix (n, n), square blocks
        Symmetric positive definite (the ``spd`` Jacobian mode).
    B : ndarray (n, k)
        Near-null-space candidates (e.g. the six rigid-body modes).
    theta : float
        Symmetric strength-of-connection threshold.
    omega : float
        Jacobi prolongation-smoothing weight (divided by ``rho(D^-1 A)``).
    max_coarse : int
        Stop coarsening at this many block rows (pyamg's convention).
    max_levels : int
    lanczos_steps : int
        Lanczos steps of the spectral-radius estimate from a random start.
    aggregates : list of csr_matrix, optional
        Aggregation operators of a previous call with a matrix of the same pattern
        (reused instead of recomputing strength and aggregates).
    ritz : list of ndarray, optional
        The levels' ``ritz`` vectors of a previous call with a matrix of the same pattern: each
        level's estimate then starts from its vector and runs ``warm_lanczos_steps`` steps.
    warm_lanczos_steps : int
    kernels : {"numpy", "numba"}
        How the setup's sparse products are computed: scipy's products, or
        :class:`~springsim.linsolve._kernels.BsrProduct` (pattern once, compiled numeric kernel).
    products : list of dict, optional
        The levels' ``products`` of a previous call (``kernels="numba"``): the product patterns are
        reused where the operands' patterns match.

    Returns
    -------
    levels : list of pyamg ``MultilevelSolver.Level``
        With ``A``, ``B``, ``P``, ``R`` (``R = P^T``) set; the last level has ``A`` and ``B``.
        Every level's ``A`` but the last (the given ``A`` included) gets the attribute
        ``block_D_inv``, its inverted block diagonal, which pyamg's block smoothers then reuse;
        every level but the last the attributes ``ritz``, the top Ritz vector of ``D^-1 A``, and
        ``products``, the level's product plans (None each with ``kernels="numpy"``).
    aggregates : list of csr_matrix
        The aggregation operator of every level but the last (pass back to reuse).

    Raises
    ------
    ArithmeticError
        When the spectral-radius estimate breaks down (``A`` not positive definite).
    """
    from pyamg.aggregation.aggregate import standard_aggregation
    from pyamg.aggregation.tentative import fit_candidates
    from pyamg.multilevel import MultilevelSolver
    from pyamg.strength import symmetric_strength_of_connection


    levels = []
    used = []
    Ak, Bk = A, B
    while len(levels) + 1 < max_levels:
        bs = Ak.blocksize[0]
        nb = Ak.shape[0] // bs
        if nb <= max_coarse:
            break
        li = len(levels)
        if aggregates is not None and li < len(aggregates) and aggregates[li].shape[0] == nb:
            agg = aggregates[li]
        else:
            C = symmetric_strength_of_connection(Ak, theta=theta)
            agg = standard_aggregation(C)[0]
        if agg.shape[1] == 0 or agg.shape[1] >= nb:  # nothing (left) to coarsen
            break
        T, Bc = fit_candidates(agg, Bk)
        D, Dinv = block_diagonal_inverse(Ak, kernels)
        # the smoothers' block inverse too: pyamg's ``get_block_diag`` returns ``A.block_D_inv`` when
        # set, so each level inverts its diagonal once instead of three times
        Ak.block_D_inv = Dinv
        start = ritz[li] if ritz is not None and li < len(ritz) and ritz[li] is not None \
            and ritz[li].shape == (Ak.shape[0],) else None
        rho, y = lanczos_rho(Ak, D, Dinv, steps=lanczos_steps if start is None else warm_lanczos_steps,
                             start=start, return_vector=True, kernels=kernels)
        if not (np.isfinite(rho) and rho > 0.0):
            raise ArithmeticError("spectral radius estimate of D^-1 A broke down (matrix not positive definite)")
        old = products[li] if products is not None and li < len(products) else {}
        plans = {}
        AT, plans["AT"] = bsr_matmat(Ak, T, kernels, old.get("AT"))
        P = smoothed_prolongator(AT, T, Dinv, omega / rho, kernels)
        del AT
        R = P.T.tobsr(blocksize=(P.blocksize[1], P.blocksize[0]))
        level = MultilevelSolver.Level()
        level.A, level.B, level.P, level.R = Ak, Bk, P, R
        level.ritz = y
        level.products = plans  # the Galerkin products' plans join below
        levels.append(level)
        used.append(agg)
        AP, plans["AP"] = bsr_matmat(Ak, P, kernels, old.get("AP"))
        Ak, plans["RAP"] = bsr_matmat(R, AP, kernels, old.get("RAP"), symmetric=True)
        del AP
        Ak.symmetry = "hermitian"
        Bk = Bc
    last = MultilevelSolver.Level()
    last.A, last.B = Ak, Bk
    levels.append(last)
    return levels, used
