"""Force terms. Adding one is a new module plus one line in :data:`FORCE_TERMS`: the term declares its data
(:attr:`ForceTerm.data`, :class:`ArraySpec`), and the model, the builder, the YAML loader, the partitioner, the
fingerprint and the naive reference take it from the registry (CONTRIBUTING.md, "Adding a force term")."""

from __future__ import annotations

import numpy as np

from .._runtime.accel import check_kernels
from ._base import JACOBIAN_MODES, PROJECTED_MODES, BlockLayout, Blocks, ForceTerm
from ._data import ArraySpec, data_terms
from .drag import ForceDrag
from .gravitational import ForceGravitational
from .gravity import ForceGravity
from .spring import ForceSpring

__all__ = ["FORCE_TERMS", "JACOBIAN_MODES", "PROJECTED_MODES", "ArraySpec", "BlockLayout", "Blocks", "ForceTerm",
           "ForceDrag", "data_terms",
           "ForceGravitational", "ForceGravity", "ForceSpring", "make_force_terms", "eval_forces",
           "eval_forces_discrete", "dense_jacobians"]

#: Registry of force families, in evaluation order.
FORCE_TERMS: dict[str, type[ForceTerm]] = {
    "gravity": ForceGravity,
    "drag": ForceDrag,
    "spring": ForceSpring,
    "gravitational": ForceGravitational,
}


def make_force_terms(model, *, skip_fixed: bool = True, kernels: str = "auto") -> list[ForceTerm]:
    """Instantiate only the force terms ``model`` uses.

    ``kernels``: ``"auto"`` (compiled force passes where numba is installed and the term is large enough),
    ``"numba"`` or ``"numpy"`` (the pure path; :mod:`springsim._runtime.accel` documents the values, which every
    ``kernels`` option shares), checked once here and passed to every term's :meth:`ForceTerm.from_model`.

    Parameters
    ----------
    model : Model
        The model.
    skip_fixed : bool
        Drop items that act only between fixed particles.
    kernels : {"auto", "numba", "numpy"}
        Force evaluation path.

    Returns
    -------
    list of ForceTerm
        In the order of :data:`FORCE_TERMS`.

    Raises
    ------
    ValueError
        For a ``kernels`` value that is not one of :data:`springsim._runtime.accel.KERNELS`.
    """
    kernels = check_kernels(kernels)
    terms = (cls.from_model(model, skip_fixed=skip_fixed, kernels=kernels) for cls in FORCE_TERMS.values())
    return [t for t in terms if t is not None]


def eval_forces(terms, q, qd, out: np.ndarray | None = None, *, damping_geometry=None) -> np.ndarray:
    """Total force (N, 3) [N] of ``terms`` at ``(q, qd)``.

    The sum starts from the first term's :meth:`~ForceTerm.constant_force` when it has one (a copy, where
    zeroing and adding would be two passes; the same result, as ``0 + x = x``).

    Parameters
    ----------
    terms : sequence of ForceTerm
        The force terms.
    q : ndarray, shape (N, 3)
        Positions [m] of all particles.
    qd : ndarray, shape (N, 3)
        Velocities [m/s] of all particles.
    out : ndarray, shape (N, 3), optional
        Output array, overwritten; default a new one.
    damping_geometry : ndarray, shape (N, 3), optional
        Positions at which the dissipative terms take their geometry (:meth:`ForceTerm.eval_force`).

    Returns
    -------
    ndarray, shape (N, 3)
        Total force [N] (``out`` when given).
    """
    terms = terms if isinstance(terms, (list, tuple)) else list(terms)
    f = np.empty_like(q) if out is None else out
    start = terms[0].constant_force() if terms else None
    if start is None:
        f.fill(0.0)
    else:
        np.copyto(f, start)
    for t in (terms[1:] if start is not None else terms):
        if damping_geometry is None:
            t.eval_force(q, qd, f)
        else:
            t.eval_force(q, qd, f, damping_geometry=damping_geometry)
    return f


def eval_forces_discrete(terms, q0, q1, qd, out: np.ndarray) -> np.ndarray:
    """Total energy-momentum force (N, 3) [N] of ``terms`` over the step from ``q0`` to ``q1`` with the midpoint
    velocity ``qd`` (:meth:`ForceTerm.eval_force_discrete`), into ``out``.

    Parameters
    ----------
    terms : sequence of ForceTerm
        The force terms.
    q0, q1 : ndarray, shape (N, 3)
        Positions [m] at the start and the end of the step.
    qd : ndarray, shape (N, 3)
        Midpoint velocity [m/s].
    out : ndarray, shape (N, 3)
        Output array [N], overwritten.

    Returns
    -------
    ndarray, shape (N, 3)
        ``out``.
    """
    out.fill(0.0)
    for t in terms:
        t.eval_force_discrete(q0, q1, qd, out)
    return out


def dense_jacobians(terms, q, qd, mode: str = "exact") -> tuple[np.ndarray, np.ndarray]:
    """Dense ``(dF/dq, dF/dqd)``, each (3N, 3N), summed over ``terms`` (small scenes only).

    Parameters
    ----------
    terms : sequence of ForceTerm
        The force terms.
    q : ndarray, shape (N, 3)
        Positions [m] of all particles.
    qd : ndarray, shape (N, 3)
        Velocities [m/s] of all particles.
    mode : {"exact", "symmetric", "spd"}
        Jacobian mode (:data:`JACOBIAN_MODES`).

    Returns
    -------
    dq : ndarray, shape (3N, 3N)
        ``dF/dq`` [N/m].
    dqd : ndarray, shape (3N, 3N)
        ``dF/dqd`` [N s/m].
    """
    n = q.shape[0]
    dq = np.zeros((3 * n, 3 * n))
    dqd = np.zeros((3 * n, 3 * n))
    for t in terms:
        jq, jqd = t.eval_jacobians(q, qd, mode)
        if jq is not None:
            dq += jq.toarray(n)
        if jqd is not None:
            dqd += jqd.toarray(n)
    return dq, dqd
