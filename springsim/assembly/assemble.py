"""Numeric phase: assemble ``A = M - a dF/dq - b dF/dqd`` over the free DOFs.

Implicit Euler uses ``(a, b) = (h^2, h)`` (PA2 eq. 1); BDF2 ``((2h/3)^2, 2h/3)``.

Design: at construction (the symbolic phase, once per model) every block a term
can emit is mapped to its destination in the BSR data array; blocks that touch a
fixed particle are dropped there. The map is stored as a sparse matrix ``S``
(destination block x source block, entries +-1), so each assembly is one
sparse-times-dense product ``S @ V`` over the stacked 3x3 value blocks ``V`` of all
terms, written into the data array of a BSR matrix whose pattern never changes.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from ..errors import check_choice
from ..forces import JACOBIAN_MODES
from .pattern import BlockPattern

__all__ = ["SystemAssembler", "SystemMatrix"]


@dataclass(eq=False)
class SystemMatrix:
    """The assembled system over free DOFs, reused (updated in place) step to step.

    Attributes
    ----------
    bsr : scipy.sparse.bsr_matrix, shape (3F, 3F)
        The matrix; its ``data`` changes on every assembly, its pattern never.
    pattern : BlockPattern
    mode : str
        Jacobian mode it was assembled with.
    symmetric : bool
        True when the assembled matrix is symmetric by construction.
    positions : ndarray (F, 3) or None
        Free-particle positions at which the Jacobians were evaluated (for AMG's
        rigid-body near-null space).
    version : int
        Increments on every assembly (solvers key their caches on pattern + version).
    """

    bsr: sp.bsr_matrix
    pattern: BlockPattern
    mode: str = "exact"
    symmetric: bool = True
    positions: np.ndarray | None = None
    version: int = 0
    _cache: dict = field(default_factory=dict, repr=False)

    @property
    def shape(self):
        """``(3F, 3F)``: the shape of :attr:`bsr`."""
        return self.bsr.shape

    def _scalar(self, fmt: str):
        perm, indices, indptr = self.pattern.scalar_permutation(fmt)
        cached = self._cache.get(fmt)
        if cached is None:
            cls = sp.csr_matrix if fmt == "csr" else sp.csc_matrix
            cached = [cls((np.empty(perm.size), indices, indptr), shape=self.shape), -1]
            cached[0].has_sorted_indices = True
            self._cache[fmt] = cached
        if cached[1] != self.version:
            np.take(self.bsr.data.reshape(-1), perm, out=cached[0].data)
            cached[1] = self.version
        return cached[0]

    def tocsr(self) -> sp.csr_matrix:
        """Scalar CSR view (one gather, pattern precomputed; do not modify).

        Returns
        -------
        scipy.sparse.csr_matrix, shape (3F, 3F)
            Cached with the matrix and refreshed when :attr:`version` changed; valid until the next conversion
            after an assembly.
        """
        return self._scalar("csr")

    def tocsc(self) -> sp.csc_matrix:
        """Scalar CSC view (one gather, pattern precomputed; do not modify).

        Returns
        -------
        scipy.sparse.csc_matrix, shape (3F, 3F)
            Cached with the matrix and refreshed when :attr:`version` changed; valid until the next conversion
            after an assembly.
        """
        return self._scalar("csc")

    def toarray(self) -> np.ndarray:
        """Dense copy of the matrix (small systems and tests only).

        Returns
        -------
        ndarray, shape (3F, 3F)
        """
        return self.bsr.toarray()

    def __matmul__(self, x):
        return self.bsr @ x


try:  # scipy's compiled CSR kernel ``Y += A @ X`` (private; absent -> the public product below)
    from scipy.sparse._sparsetools import csr_matvecs as _csr_matvecs
except ImportError:  # pragma: no cover - depends on the scipy version
    _csr_matvecs = None


def _scatter_add(S: sp.csr_matrix, X: np.ndarray, Y: np.ndarray) -> None:
    """``Y += S @ X`` for a CSR ``S`` and float64 ``X``, ``Y`` (rows, 9).

    Accumulates in place with scipy's compiled CSR kernel when ``Y`` is C-contiguous, so no
    (nnzb, 9) temporary is allocated: at n = 256 that temporary is 61 MB per assembly, and
    fresh large allocations cost page faults on every call (the linear-solver notes of
    BENCHMARKS.md#cloth-grid). Otherwise (or without the kernel) the public product.
    """
    if _csr_matvecs is not None and Y.flags.c_contiguous:
        _csr_matvecs(S.shape[0], S.shape[1], X.shape[1], S.indptr, S.indices, S.data,
                     np.ascontiguousarray(X).ravel(), Y.ravel())
    else:
        Y += S @ X


class SystemAssembler:
    """Assembles the implicit system of ``model`` for the force ``terms``.

    Parameters
    ----------
    model : Model
    terms : list of ForceTerm
        Usually :func:`springsim.forces.make_force_terms` (model).

    Attributes
    ----------
    free : ndarray (F,)
        Free particle indices; the system's block row ``k`` is particle ``free[k]``.
    pattern : BlockPattern
    matrix : SystemMatrix
        The persistent result of :meth:`assemble`.
    last_time_s : float
        Wall time of the last numeric assembly (Jacobian evaluation + scatter).
    """

    def __init__(self, model, terms):
        self.model = model
        self.terms = list(terms)
        n = model.particle_count
        self.free = model.free_particles
        F = self.free.size
        self.free_map = np.full(n, -1, dtype=np.int64)
        self.free_map[self.free] = np.arange(F)

        rows, cols, srcs, signs = [], [], [], []
        self._sources = []  # (term, "q"|"qd", offset, count)
        offset = 0
        for term in self.terms:
            for which, layout in (("q", term.layout_q), ("qd", term.layout_qd)):
                if layout is None:
                    continue
                r, c = self.free_map[layout.rows], self.free_map[layout.cols]
                keep = (r >= 0) & (c >= 0)
                rows.append(r[keep])
                cols.append(c[keep])
                srcs.append(layout.src[keep] + offset)
                signs.append(layout.sign[keep])
                self._sources.append((term, which, offset, layout.value_count))
                offset += layout.value_count
        self.value_count = offset
        def cat(xs, dt):
            return np.concatenate(xs).astype(dt) if xs else np.zeros(0, dt)

        rows, cols = cat(rows, np.int64), cat(cols, np.int64)
        self.pattern = BlockPattern(F, rows, cols)
        dest = self.pattern.locate(rows, cols)
        self._scatter = sp.csr_matrix((cat(signs, np.float64), (dest, cat(srcs, np.int64))),
                                      shape=(self.pattern.nnzb, self.value_count))
        self._free_mass = model.particle_mass[self.free]
        # the mass enters the diagonal blocks only: kept per particle, not as a block array over the whole pattern
        self._diagonal = self.pattern.diagonal_positions
        self._values = np.empty((self.value_count, 3, 3))
        self._work = {id(term): {} for term in self.terms}  # per-term temporaries, kept between assemblies
        self.matrix = SystemMatrix(self.pattern.empty_bsr(), self.pattern)
        self.last_time_s = 0.0

    @property
    def dof_count(self) -> int:
        """``3F``: the unknowns of the assembled system (three per free particle)."""
        return 3 * self.free.size

    def precision_loss(self, matrix: SystemMatrix | None = None) -> float:
        """Relative precision to which the assembled matrix still holds the particle masses.

        ``u max_i max|D_i| / m_i`` over the 3x3 diagonal blocks ``D_i = m_i I - a dF_ii/dq - b dF_ii/dqd``
        of the free particles (``u`` the unit round-off): the mass enters ``D_i`` as one summand
        next to the stiffness, so it is kept only to that relative precision. It bounds the
        relative error of the motions the masses alone determine (the centre of mass of a pair
        held together by a stiff spring or a gravitational core); above 1 the masses are lost
        in rounding and the matrix is singular to working precision (docs/robustness.md).

        Parameters
        ----------
        matrix : SystemMatrix, optional
            An assembled matrix of this assembler; default :attr:`matrix`.

        Returns
        -------
        float
            The relative precision (0 when no particle is free).
        """
        m = self.matrix if matrix is None else matrix
        if self.free.size == 0:
            return 0.0
        D = m.bsr.data[self.pattern.diagonal_positions].reshape(-1, 9)
        return float(np.finfo(np.float64).eps * (np.abs(D).max(axis=1) / self._free_mass).max())

    def assemble(self, q: np.ndarray, qd: np.ndarray, a: float, b: float, mode: str = "exact", *,
                 q_start: np.ndarray | None = None, damping_geometry: np.ndarray | None = None) -> SystemMatrix:
        """Fill and return :attr:`matrix` = ``M - a dF/dq - b dF/dqd`` at ``(q, qd)``.

        Parameters
        ----------
        q, qd : ndarray (N, 3)
            State of all particles where the Jacobians are evaluated.
        a, b : float
            Coefficients of the position and velocity Jacobians.
        mode : {"exact", "symmetric", "spd"}
        q_start : ndarray (N, 3), optional
            With it, ``F`` is the energy-momentum force over the step from ``q_start`` to ``2 q - q_start``
            and ``q`` its midpoint (:meth:`~springsim.forces.ForceTerm.eval_jacobians_discrete`).
        damping_geometry : ndarray (N, 3), optional
            Positions at which the dissipative terms take their geometry (:meth:`~springsim.forces.ForceTerm.
            eval_jacobians`): the implicit stages' frozen damping.

        Returns
        -------
        SystemMatrix
            :attr:`matrix`, updated in place (its ``version`` incremented, ``mode``, ``symmetric`` and
            ``positions`` set).

        Raises
        ------
        SceneError
            A ``ValueError`` for a ``mode`` not in :data:`~springsim.forces.JACOBIAN_MODES`.
        """
        check_choice(mode, JACOBIAN_MODES, param="jacobian", what="jacobian mode")
        t0 = time.perf_counter()
        V = self._values
        for term in self.terms:
            jq, jqd = (None, None)
            if term.layout_q is not None or term.layout_qd is not None:
                if q_start is None:
                    jq, jqd = term.eval_jacobians(q, qd, mode, work=self._work[id(term)],
                                                  damping_geometry=damping_geometry)
                else:
                    jq, jqd = term.eval_jacobians_discrete(q_start, 2.0 * q - q_start, qd, mode,
                                                           work=self._work[id(term)])
            for src_term, which, off, cnt in self._sources:
                if src_term is not term:
                    continue
                blocks = jq if which == "q" else jqd
                np.multiply(blocks.values, -(a if which == "q" else b), out=V[off:off + cnt])
        data = self.matrix.bsr.data
        data.fill(0.0)
        for k in range(3):
            data[self._diagonal, k, k] = self._free_mass
        if self.value_count:
            _scatter_add(self._scatter, V.reshape(-1, 9), data.reshape(-1, 9))
        m = self.matrix
        m.mode = mode
        frozen = damping_geometry is not None
        m.symmetric = all(t.jacobian_symmetric(mode, frozen_damping=frozen) if q_start is None
                          else t.jacobian_symmetric_discrete(mode) for t in self.terms)
        m.positions = q[self.free]
        m.version += 1
        self.last_time_s = time.perf_counter() - t0
        return m

    def linearize_at(self, q: np.ndarray) -> None:
        """Make the positions ``q`` (N, 3) the previous linearisation of every term's ``mixed`` Jacobian
        (:meth:`springsim.forces.ForceTerm.linearize_at`), so that the next ``mixed`` assembly continues from
        there whatever was assembled before.

        Parameters
        ----------
        q : ndarray, shape (N, 3)
            Positions [m] of all particles.
        """
        for term in self.terms:
            term.linearize_at(q, self._work[id(term)])

    # -- helpers to move between full (N, 3) arrays and free DOF vectors -------------------
    def gather(self, x: np.ndarray) -> np.ndarray:
        """Free DOF vector (3F,) from a full (N, 3) array.

        Parameters
        ----------
        x : ndarray, shape (N, 3)
            A full state array.

        Returns
        -------
        ndarray, shape (3F,)
            Its free rows, flattened (a copy).
        """
        return x[self.free].reshape(-1)

    def scatter_add(self, target: np.ndarray, dx: np.ndarray, scale: float = 1.0) -> None:
        """``target[free] += scale * dx`` with ``dx`` a free DOF vector (3F,).

        Parameters
        ----------
        target : ndarray, shape (N, 3)
            Full state array, added to in place.
        dx : ndarray, shape (3F,)
            Free DOF vector.
        scale : float
            Factor of ``dx``; default 1.
        """
        target[self.free] += scale * dx.reshape(-1, 3)
