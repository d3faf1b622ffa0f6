"""Smoothed aggregation over PETSc matrices from rank-local aggregates: springsim's AMG in PETSc's PCMG.

The serial AMG-CG (:mod:`springsim.linsolve.amg`, :func:`springsim.linsolve._sa.smoothed_aggregation_levels`)
needs 7-8 CG iterations per stage solve of the benchmark cloth where PETSc's GAMG, configured as closely as its
options allow, needs 14-35 (BENCHMARKS.md#distributed): GAMG cannot be given the serial
set-up's choices (symmetric strength on the blocks' Frobenius norms, pyamg's standard aggregation, the
candidates fitted per aggregate, one Jacobi step with the inverted block diagonal weighted by a Lanczos estimate
of ``rho(D^-1 A)``). :class:`SmoothedAggregation` builds that hierarchy on the distributed matrix:

* **Aggregates are local** (as GAMG's): each rank aggregates the nodes it owns from its diagonal block
  (``MatGetDiagonalBlock``), so no aggregate crosses ranks and the tentative prolongator ``T`` is block
  diagonal over the ranks. On one rank this is the serial aggregation. A node is a particle on the finest level
  and an aggregate of the level above on the coarser ones; the aggregates of every level are kept for the next
  matrix of the same pattern (the strength graph follows the springs, whose set never changes).
* **Candidates** (the six rigid-body modes at the current positions on the finest level) are fitted per
  aggregate by pyamg's :func:`~pyamg.aggregation.tentative.fit_candidates`; a candidate an aggregate cannot
  represent (collinear particles carry five rigid modes) gives a zero column of ``T``, whose coarse row gets a
  unit diagonal: a decoupled row the coarse correction leaves at zero, where SOR would otherwise divide by zero.
  Coarse nodes keep six DOFs, so every level has uniform point blocks.
* **Prolongator smoothing** ``P = T - (omega / rho) D^-1 A T``: ``A T`` by PETSc's parallel ``MatMatMult`` (it
  fetches the rows of ``T`` other ranks own), ``D^-1`` the inverted point blocks (``MatInvertBlockDiagonal``) as a
  block-diagonal matrix, ``rho`` from a Lanczos run on ``D^-1 A`` in the ``D`` inner product (12 steps, or 4 from
  the level's previous top Ritz vector, as serially: :func:`springsim.linsolve._sa.lanczos_rho`).
* **Coarse operators** ``P^T (A P)`` by an explicit transpose and two parallel products (about 0.6x the time of
  ``MatPtAP``). Every product keeps its result matrix, so its symbolic phase is done once per run; that costs
  memory (about 1.3-1.7x GAMG's peak). The coarsest level (at most ``max_coarse``
  nodes over all ranks, or where aggregation stops coarsening) is factorised by LU, redundantly on every rank
  when there are several, or smoothed like the others when it is larger than ``max_direct`` DOFs.
* :meth:`SmoothedAggregation.configure` puts the levels into a ``PCMG``: a multiplicative V-cycle, every level
  but the coarsest smoothed by one Richardson iteration of PETSc's local symmetric SOR before and after the
  coarse correction (the symmetric Gauss-Seidel pair of the serial AMG in point form; the preconditioner is
  symmetric, so CG applies).

References: Vanek, Mandel and Brezina 1996 (smoothed aggregation); Bell, Olson and Schroder, pyamg (the serial
parts used per rank); Adams et al., PETSc's GAMG (local aggregation over ranks).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..linsolve._sa import _block_diagonal_operator, lanczos_recurrence

__all__ = ["LOG_EVENT", "SmoothedAggregation"]

#: Name of the PETSc log event around every set-up (``-log_view``, ``PETSc.Log.Event(LOG_EVENT).getPerfInfo()``).
LOG_EVENT = "SpringsimSASetUp"


def _local_csr(M) -> sp.csr_matrix:
    """The rank's diagonal block of the PETSc matrix ``M`` (owned rows and columns) as scipy CSR."""
    D = M.getDiagonalBlock() if M.getComm().getSize() > 1 else M
    indptr, indices, data = D.getValuesCSR()
    return sp.csr_matrix((data, indices, indptr), shape=D.getSize())


def _aggregate(A: sp.csr_matrix, bs: int, theta: float) -> sp.csr_matrix:
    """pyamg's standard aggregation of the nodes (``bs`` DOFs each) from symmetric strength on the node blocks'
    Frobenius norms, as pyamg computes it for BSR matrices. Returns the node-by-aggregate operator (CSR; pyamg
    returns one empty aggregate when no node has a strong connection: the caller drops empty ones)."""
    from pyamg.aggregation.aggregate import standard_aggregation
    from pyamg.strength import symmetric_strength_of_connection

    if A.shape[0] == 0:
        return sp.csr_matrix((0, 0))
    C = symmetric_strength_of_connection(sp.bsr_matrix(A, blocksize=(bs, bs)), theta=theta)
    return standard_aggregation(C)[0].tocsr()


def _tentative(agg: sp.csr_matrix, B: np.ndarray):
    """pyamg's :func:`~pyamg.aggregation.tentative.fit_candidates` on the owned nodes: ``T`` (owned rows, local
    columns), the coarse candidates, and the coarse DOFs whose column of ``T`` is zero (``dead``)."""
    from pyamg.aggregation.tentative import fit_candidates

    n, k = B.shape
    if agg.shape[1] == 0:
        return sp.csr_matrix((n, 0)), np.zeros((0, k)), np.zeros(0, dtype=np.int64)
    T, Bc = fit_candidates(agg, B)
    T = T.tocsr()
    norms = np.sqrt(np.asarray(T.multiply(T).sum(axis=0)).ravel())
    return T, Bc, np.flatnonzero(norms < 0.5)  # fit_candidates gives orthonormal columns or zero ones


def _inverse_diagonal_blocks(M, bs: int) -> np.ndarray:
    """The inverses of ``M``'s owned ``bs x bs`` diagonal node blocks, shape ``(owned nodes, bs, bs)``.

    PETSc's ``MatInvertBlockDiagonal`` when ``M`` carries the block size; otherwise (a product algorithm chosen by
    the user's options, such as ``-matmatmult_via backend``, may return a coarse operator with block size 1) the
    blocks are read from the rank's diagonal block and inverted here, so the hierarchy does not depend on it."""
    if M.getBlockSize() == bs:
        return np.asarray(M.invertBlockDiagonal()).reshape(-1, bs, bs)
    D = _local_csr(M).tocoo()
    keep = D.row // bs == D.col // bs
    blocks = np.zeros((D.shape[0] // bs, bs, bs))
    blocks[D.row[keep] // bs, D.row[keep] % bs, D.col[keep] % bs] = D.data[keep]
    return np.linalg.inv(blocks)


def _block_diagonal(blocks: np.ndarray) -> sp.csr_matrix:
    """The (nb, bs, bs) blocks as a block-diagonal CSR matrix."""
    return _block_diagonal_operator(blocks).tocsr()


class _Level:
    """One level's PETSc matrices and what the next matrix of the same pattern reuses.

    ``A`` the operator, ``P`` the prolongator from the next coarser level; ``T``, ``Dinv``, ``AT``, ``Pt``, ``AP``
    the intermediate matrices kept for their patterns (PETSc's symbolic phase is done once); ``aggregates``
    (node by aggregate), ``ritz`` (the top Ritz vector of ``D^-1 A``) and ``dead`` (owned coarse DOFs whose
    prolongator column is zero, or None).
    """

    __slots__ = ("A", "P", "T", "Dinv", "AT", "Pt", "AP", "aggregates", "ritz", "dead", "owned")

    def __init__(self, A, owned: bool):
        self.A, self.owned = A, owned
        self.P = self.T = self.Dinv = self.AT = self.Pt = self.AP = None
        self.aggregates = self.ritz = self.dead = None

    def destroy(self, operator: bool = True) -> None:
        for name in ("P", "T", "Dinv", "AT", "Pt", "AP"):
            m = getattr(self, name)
            if m is not None:
                m.destroy()
                setattr(self, name, None)
        if operator and self.owned and self.A is not None:
            self.A.destroy()
            self.A = None


class SmoothedAggregation:
    """A smoothed-aggregation hierarchy over PETSc matrices, aggregates local to each rank (module docstring).

    Parameters
    ----------
    PETSc : module
        ``petsc4py.PETSc``.
    comm : petsc4py Comm
    theta : float
        Symmetric strength-of-connection threshold (the serial AMG's 0.1).
    omega : float
        Jacobi prolongation-smoothing weight, divided by ``rho(D^-1 A)``.
    max_coarse : int
        Stop coarsening at this many nodes over all ranks.
    max_direct : int
        The coarsest level is factorised (LU) up to this many DOFs; a larger one (where coarsening stopped early:
        no strong connections, as in a matrix close to the mass matrix) is smoothed like the others.
    max_levels : int
    lanczos_steps, warm_lanczos_steps : int
        Lanczos steps of the spectral-radius estimate from a random start and from the level's previous top Ritz
        vector.

    Notes
    -----
    :meth:`build` is collective. The aggregates are reused while the matrices keep their pattern (the caller
    calls :meth:`forget` when it changes); every build recomputes candidates, prolongators and coarse operators.
    """

    def __init__(self, PETSc, comm, *, theta: float = 0.1, omega: float = 4.0 / 3.0, max_coarse: int = 50,
                 max_direct: int = 3000, max_levels: int = 10, lanczos_steps: int = 12, warm_lanczos_steps: int = 4):
        self.PETSc, self.comm, self.mpi = PETSc, comm, comm.tompi4py()
        self.theta, self.omega = float(theta), float(omega)
        self.max_coarse, self.max_direct, self.max_levels = int(max_coarse), int(max_direct), int(max_levels)
        self.lanczos_steps, self.warm_lanczos_steps = int(lanczos_steps), int(warm_lanczos_steps)
        self.levels: list[_Level] = []
        #: PETSc log event of :meth:`build` and :meth:`galerkin` (its message lengths are their communication)
        self.event = PETSc.Log.Event(LOG_EVENT)

    # -- set-up ----------------------------------------------------------------------------------------------------
    def forget(self) -> None:
        """Drop everything kept for the next matrix (call when the matrices' pattern changes)."""
        self.destroy()

    def destroy(self) -> None:
        """Free the PETSc matrices of the levels (the finest operator belongs to the caller)."""
        for lv in self.levels:
            lv.destroy()
        self.levels = []

    def build(self, A, B_own: np.ndarray, block: int = 3) -> list:
        """The levels of ``A`` (finest first), reusing the aggregates, Ritz vectors and product patterns of the last
        build (the same pattern is assumed; :meth:`forget` otherwise). Collective.

        Parameters
        ----------
        A : petsc4py Mat
            Symmetric positive definite, distributed by rows; its owned rows are ``block`` DOFs per node.
        B_own : ndarray, shape (owned DOFs, k)
            The near-null-space candidates' owned rows (the rigid-body modes).
        block : int
            DOFs per node of ``A``.

        Returns
        -------
        list of _Level
            ``levels[0].A`` is ``A``; ``levels[l].P`` maps level ``l + 1`` to level ``l`` (None on the last).

        Raises
        ------
        ArithmeticError
            When a spectral-radius estimate breaks down (``A`` not positive definite), on every rank.
        """
        self.event.begin()
        try:
            return self._build(A, B_own, block)
        finally:
            self.event.end()

    def _build(self, A, B_own: np.ndarray, block: int) -> list:
        PETSc, mpi = self.PETSc, self.mpi
        old = self.levels
        if old:
            old[0].A = A
        levels = old[:1] if old else [_Level(A, owned=False)]
        Ak, Bk, bs = A, np.asarray(B_own, dtype=np.float64), int(block)
        while len(levels) < self.max_levels:
            li = len(levels) - 1
            lv = levels[li]
            n_nodes = Ak.getLocalSize()[0] // bs
            if mpi.allreduce(n_nodes) <= self.max_coarse:
                break
            if lv.aggregates is None or lv.aggregates.shape[0] != n_nodes:  # first build (or a new pattern)
                lv.destroy(operator=False)
                for stale in old[li + 1:]:  # their sizes follow these aggregates
                    stale.destroy()
                old = old[:li + 1]
                agg = _aggregate(_local_csr(Ak), bs, self.theta)
                lv.aggregates, lv.ritz = agg[:, np.bincount(agg.indices, minlength=agg.shape[1]) > 0], None
            agg = lv.aggregates
            n_agg = mpi.allreduce(agg.shape[1])
            if n_agg >= mpi.allreduce(n_nodes) or n_agg == 0:
                break  # nothing (left) to coarsen
            k = Bk.shape[1]
            Tl, Bc, dead = _tentative(agg, Bk)
            lv.T = self._fill(lv.T, Tl, (bs, k), mpi.exscan(Tl.shape[1]) or 0)
            Dinv = _inverse_diagonal_blocks(Ak, bs)
            lv.Dinv = self._fill(lv.Dinv, _block_diagonal(Dinv), (bs, bs), Ak.getOwnershipRange()[0])
            rho, lv.ritz = self._lanczos(Ak, np.linalg.inv(Dinv), Dinv, lv.ritz)
            if not (np.isfinite(rho) and rho > 0.0):
                raise ArithmeticError("spectral radius estimate of D^-1 A broke down (matrix not positive definite)")
            lv.AT = Ak.matMult(lv.T, result=lv.AT)
            # P = T - (omega / rho) D^-1 (A T), computed into the product D^-1 (A T) itself: T's pattern is in it
            # (D^-1 and A hold their diagonal blocks), so the axpy adds no entry and the product's symbolic phase
            # stays valid for the next build
            lv.P = lv.Dinv.matMult(lv.AT, result=lv.P)
            lv.P.scale(-self.omega / rho)
            lv.P.axpy(1.0, lv.T, structure=PETSc.Mat.Structure.SUBSET)
            coarse = old[li + 1] if li + 1 < len(old) else _Level(None, owned=True)
            lv.Pt = lv.P.transpose(lv.Pt if lv.Pt is not None else PETSc.Mat())
            lv.dead = dead if mpi.allreduce(int(dead.size)) else None
            self._coarse_operator(lv, coarse)
            levels.append(coarse)
            Ak, Bk, bs = coarse.A, Bc, k
        for lv in old[len(levels):]:
            lv.destroy()
        levels[-1].destroy(operator=False)  # the coarsest level has no prolongator
        levels[-1].aggregates = levels[-1].ritz = None
        self.levels = levels
        return levels

    def galerkin(self) -> None:
        """Recompute the coarse operators ``P^T A P`` from the finest operator's current values, the prolongators
        kept (PETSc's ``-pc_gamg_reuse_interpolation`` for these levels). Collective."""
        self.event.begin()
        try:
            for lv, coarse in zip(self.levels[:-1], self.levels[1:]):
                self._coarse_operator(lv, coarse)
        finally:
            self.event.end()

    def _coarse_operator(self, lv: _Level, coarse: _Level) -> None:
        """``coarse.A = P^T (A P)`` of ``lv``, by the kept transpose and two products (about 0.6x the time of
        PETSc's ``MatPtAP`` on the benchmark cloth), the symbolic phases reused; coarse DOFs whose prolongator
        column is zero get a unit diagonal (a decoupled row the coarse correction leaves at zero)."""
        lv.AP = lv.A.matMult(lv.P, result=lv.AP)
        coarse.A = lv.Pt.matMult(lv.AP, result=coarse.A)
        if lv.dead is not None:
            ones = coarse.A.createVecs()[0]
            ones.array[:] = 0.0
            ones.array[lv.dead] = 1.0
            coarse.A.setDiagonal(ones, addv=self.PETSc.InsertMode.ADD_VALUES)
            ones.destroy()

    def _fill(self, M, local: sp.csr_matrix, block_sizes: tuple, col_offset: int):
        """``M`` with its owned rows set to ``local`` (columns shifted by ``col_offset``): a new distributed AIJ
        matrix when ``M`` is None, else the values of the same pattern replaced."""
        PETSc = self.PETSc
        IT = PETSc.IntType
        local = local.tocsr()
        local.sort_indices()
        indptr, indices = local.indptr.astype(IT), (local.indices + col_offset).astype(IT)
        if M is None:
            M = PETSc.Mat().create(comm=self.comm)
            M.setSizes(((local.shape[0], None), (local.shape[1], None)))
            M.setBlockSizes(*block_sizes)
            M.setType(PETSc.Mat.Type.AIJ)
            M.setPreallocationCSR((indptr, indices, local.data))
            M.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, True)
        else:
            M.setValuesCSR(indptr, indices, local.data)
        M.assemble()
        return M

    def _lanczos(self, A, D: np.ndarray, Dinv: np.ndarray, start):
        """``(rho, y)``: the largest Ritz value of ``D^-1 A`` in the ``D`` inner product (``D`` and ``D^-1`` the
        owned diagonal node blocks) and its Ritz vector's owned rows: the serial recurrence
        (:func:`springsim.linsolve._sa.lanczos_recurrence`) with PETSc's product and all-reduced inner products."""
        mpi = self.mpi
        x, Ax = A.createVecs()
        n = x.getLocalSize()
        Dop, Dinvop = _block_diagonal(D), _block_diagonal(Dinv)

        def apply_A(v):
            x.array[:] = v
            A.mult(x, Ax)
            return Ax.array.copy()

        if start is None or start.shape != (n,):
            q, steps = np.random.default_rng(self.comm.getRank()).standard_normal(n), self.lanczos_steps
        else:
            q, steps = np.array(start), self.warm_lanczos_steps
        try:
            return lanczos_recurrence(apply_A, lambda v: Dop @ v, lambda v: Dinvop @ v, q, steps,
                                      dot=lambda u, v: mpi.allreduce(float(u @ v)), return_vector=True)
        finally:
            x.destroy()
            Ax.destroy()

    # -- the preconditioner ----------------------------------------------------------------------------------------
    def configure(self, pc) -> None:
        """Make ``pc`` a PCMG over :attr:`levels` (call after :meth:`build` and before ``setFromOptions``).

        Parameters
        ----------
        pc : petsc4py PC
            The preconditioner of a KSP whose operator is the finest level's matrix.
        """
        PETSc = self.PETSc
        levels = self.levels
        L = len(levels)
        pc.setType("mg")
        pc.setMGLevels(L)
        pc.setMGType(PETSc.PC.MGType.MULTIPLICATIVE)
        pc.setMGCycleType(PETSc.PC.MGCycleType.V)
        for lev in range(1, L):  # PETSc's level L - 1 is the finest; interpolation into lev from lev - 1
            pc.setMGInterpolation(lev, levels[L - 1 - lev].P)
        for lev in range(1, L):
            sm = pc.getMGSmoother(lev)
            sm.setType("richardson")
            sm.setTolerances(max_it=1)
            sm.getPC().setType("sor")
            sm.setOperators(levels[L - 1 - lev].A)
        co = pc.getMGCoarseSolve()
        co.setOperators(levels[-1].A)
        if levels[-1].A.getSize()[0] > self.max_direct:  # coarsening stopped early (a diagonally dominant matrix)
            co.setType("richardson")
            co.setTolerances(max_it=1)
            co.getPC().setType("sor")
        else:
            co.setType("preonly")
            co.getPC().setType("redundant" if self.comm.getSize() > 1 else "lu")
