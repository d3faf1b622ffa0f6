"""Smoothed aggregation over PETSc matrices from rank-local aggregates: springsim's AMG in PETSc's PCMG.

The serial AMG-CG (:mod:`springsim.linsolve.amg`, :func:`springsim.linsolve._sa.smoothed_aggregation_levels`)
needs 7-8 CG iterations per stage solve of the benchmark cloth where PETSc's GAMG, configured as closely as its
options allow, needs 14-35 (BENCHMARKS.md#distributed): GAMG cannot be given the serial
set-up's choices (symmetric strength on the blocks' Frobenius norms, pyamg's standard aggregation, the
candidates fitted per aggregate, one Jacobi step with the inverted block diagonal weighted by a Lanczos estimate
of ``rho(D^-1 A)``). :class:`SmoothedAggregation` builds that hierarchy on the distributed matrix:

* **Rows, not PETSc products.** Each rank holds its owned block rows of every level's operator as a scipy BSR
  matrix (:mod:`springsim.distributed._rows`): the finest from the PETSc matrix (its pattern once, then the values
  read straight from PETSc's arrays), the coarser ones from the products below. The set-up's sparse products run
  rank by rank on those rows with the serial set-up's compiled block kernels and kept patterns
  (:func:`springsim.linsolve._kernels.bsr_matmat`); the rows of other ranks a product needs (the ghost rows of
  ``T`` and ``P``) come from their owners, and the rows a rank computes for other ranks' coarse nodes go to them
  and are summed there. PETSc gets the prolongators and coarse operators for its ``PCMG``, their values written
  into its arrays (:class:`springsim.distributed._aij.AIJValues`). Against PETSc's own parallel products (kept
  for their symbolic phases) this builds the hierarchy in about half the time and keeps no product matrix: on
  two ranks the peak memory per rank is 0.55x the one-rank figure at n = 512, against 0.74x
  (BENCHMARKS.md#distributed).
* **Aggregates are local** (as GAMG's): each rank aggregates the nodes it owns from its diagonal block (the rows'
  own columns), so no aggregate crosses ranks and the tentative prolongator ``T`` is block diagonal over the ranks.
  On one rank this is the serial aggregation. A node is a particle on the finest level and an aggregate of the level
  above on the coarser ones; the aggregates of every level are kept for the next matrix of the same pattern (the
  strength graph follows the springs, whose set never changes).
* **Candidates** (the six rigid-body modes at the current positions on the finest level) are fitted per
  aggregate by pyamg's :func:`~pyamg.aggregation.tentative.fit_candidates`; a candidate an aggregate cannot
  represent (collinear particles carry five rigid modes) gives a zero column of ``T``, whose coarse row gets a
  unit diagonal: a decoupled row the coarse correction leaves at zero, where SOR would otherwise divide by zero.
  Coarse nodes keep six DOFs, so every level has uniform point blocks.
* **Prolongator smoothing** ``P = T - (omega / rho) D^-1 A T``: ``A T`` over the owned rows (``T``'s ghost rows
  fetched), ``D^-1`` the inverted diagonal blocks of the owned rows, ``rho`` from a Lanczos run on ``D^-1 A`` in
  the ``D`` inner product with PETSc's product and all-reduced inner products (12 steps, or 4 from the level's
  previous top Ritz vector, as serially: :func:`springsim.linsolve._sa.lanczos_rho`).
* **Coarse operators** ``P^T (A P)``: ``A P`` over the owned rows (``P``'s ghost rows fetched), then the
  transpose of the owned rows of ``P`` times it; on one rank the product is known to be symmetric and only its
  upper half is computed, as serially. The coarsest level (at most ``max_coarse`` nodes over all ranks, or where
  aggregation stops coarsening) is factorised by LU, redundantly on every rank when there are several, or
  smoothed like the others when it is larger than ``max_direct`` DOFs.
* :meth:`SmoothedAggregation.configure` puts the levels into a ``PCMG``: a multiplicative V-cycle, every level
  but the coarsest smoothed by one Richardson iteration of a local symmetric Gauss-Seidel sweep before and after the
  coarse correction (the preconditioner is symmetric, so CG applies): PETSc's SOR, block by block on the coarser
  levels (BAIJ), by points on the finest (AIJ, most of the time of a V-cycle). ``smoother="gs"`` sweeps the finest
  level with the serial V-cycle's compiled block kernels on a copy of it instead (:class:`_Sweep`): the same
  iterations in a fifth less time per solve, for the copy's memory.

References: Vanek, Mandel and Brezina 1996 (smoothed aggregation); Bell, Olson and Schroder, pyamg (the serial
parts used per rank); Adams et al., PETSc's GAMG (local aggregation over ranks).
"""

from __future__ import annotations

import atexit
import weakref

import numpy as np
import scipy.sparse as sp

from ..linsolve._kernels import (block_diagonal_inverse, block_gauss_seidel_backward, block_gauss_seidel_forward,
                                bsr_matmat, resolve_kernels, smoothed_prolongator)
from ..linsolve._sa import _block_diagonal_operator, lanczos_recurrence
from . import _rows

__all__ = ["LOG_EVENT", "SmoothedAggregation"]

#: Name of the PETSc log event around every set-up (``-log_view``, ``PETSc.Log.Event(LOG_EVENT).getPerfInfo()``).
LOG_EVENT = "SpringsimSASetUp"


def _aggregate(A: sp.bsr_matrix, theta: float) -> sp.csr_matrix:
    """pyamg's standard aggregation of the nodes of the square BSR matrix ``A`` (the rank's diagonal block) from
    symmetric strength on its blocks' Frobenius norms. Returns the node-by-aggregate operator (CSR; pyamg returns one
    empty aggregate when no node has a strong connection: the caller drops empty ones)."""
    from pyamg.aggregation.aggregate import standard_aggregation
    from pyamg.strength import symmetric_strength_of_connection

    if A.shape[0] == 0:
        return sp.csr_matrix((0, 0))
    return standard_aggregation(symmetric_strength_of_connection(A, theta=theta))[0].tocsr()


def _tentative(agg: sp.csr_matrix, B: np.ndarray, bs: int):
    """pyamg's :func:`~pyamg.aggregation.tentative.fit_candidates` on the owned nodes: ``T`` (owned rows, local
    columns; BSR of ``bs x k`` blocks), the coarse candidates, and the coarse DOFs whose column of ``T`` is zero
    (``dead``)."""
    from pyamg.aggregation.tentative import fit_candidates

    n, k = B.shape
    if agg.shape[1] == 0:
        return sp.bsr_matrix((n, 0), blocksize=(bs, k)), np.zeros((0, k)), np.zeros(0, dtype=np.int64)
    T, Bc = fit_candidates(agg, B)
    T = T.tobsr(blocksize=(bs, k))
    norms = np.sqrt(np.asarray(T.multiply(T).sum(axis=0)).ravel())
    return T, Bc, np.flatnonzero(norms < 0.5)  # fit_candidates gives orthonormal columns or zero ones


def _block_diagonal(blocks: np.ndarray) -> sp.csr_matrix:
    """The (nb, bs, bs) blocks as a block-diagonal CSR matrix."""
    return _block_diagonal_operator(blocks).tocsr()


class _Level:
    """One level: its PETSc matrices and what the next matrix of the same pattern reuses.

    ``A`` the operator (PETSc), ``P`` the prolongator from the next coarser level (PETSc); ``rows`` the owned block
    rows of ``A`` (:class:`~springsim.distributed._rows.Rows`) and ``halo`` who sends their ghost rows;
    ``aggregates`` (node by aggregate), ``ritz`` (the top Ritz vector of ``D^-1 A``) and ``dead`` (owned coarse DOFs
    whose prolongator column is zero, or None); ``Pext`` the prolongator's owned and ghost rows over one local
    numbering of the coarse nodes, ``R`` the transpose of its owned rows; ``plans`` the products' kept patterns,
    ``merge`` the sum of the coarse rows, ``csrP`` and ``csrA`` the patterns given to PETSc, ``coarse_off`` the
    coarse nodes' ownership offsets, ``extract`` (finest level) the conversion of PETSc's rows to blocks, ``sweep``
    (finest level, ``smoother="gs"``) ``(state of A, BSR arrays of the rank's diagonal block, its inverted diagonal
    blocks)``.
    """

    __slots__ = ("A", "P", "rows", "halo", "aggregates", "ritz", "dead", "Pext", "R", "plans", "merge", "csrP",
                 "csrA", "extract", "coarse_off", "owned", "sweep")

    def __init__(self, A, owned: bool):
        self.A, self.owned = A, owned
        self.P = self.rows = self.halo = self.aggregates = self.ritz = self.dead = None
        self.Pext = self.R = self.merge = self.csrP = self.csrA = self.extract = self.coarse_off = None
        self.sweep = None
        self.plans = {}

    def destroy(self, operator: bool = True) -> None:
        if self.P is not None:
            self.P.destroy()
            self.P = None
        self.Pext = self.R = self.merge = self.csrP = None
        self.plans = {}
        if operator and self.owned and self.A is not None:
            self.A.destroy()
            self.A = None


#: The finest level's smoothers (:class:`SmoothedAggregation`'s ``smoother``).
SMOOTHERS = ("sor", "gs")

#: The hierarchies whose PCMG has :class:`_Sweep` PCs (alive ones). At exit those PCs drop their Python contexts
#: before PETSc finalises: a Python PC still alive then is destroyed during the interpreter's teardown (a crash at
#: the exit of a program that did not destroy its system).
_WITH_SWEEPS: weakref.WeakSet = weakref.WeakSet()
_EXIT_HOOK = []


def _release_sweeps() -> None:
    for sa in list(_WITH_SWEEPS):
        sa.release_sweeps()


class _Sweep:
    """The finest level's smoother in PETSc's PCMG with ``smoother="gs"``: the context of the ``python`` PC of a
    one-iteration Richardson KSP, which applies one symmetric block Gauss-Seidel sweep (forward, then backward; 3 x 3
    blocks) from zero over the rank's diagonal block (processor-local, as PETSc's local symmetric SOR), the serial
    V-cycle's compiled kernels (:func:`springsim.linsolve._kernels.block_gauss_seidel_forward`) on a BSR copy of that
    block (:meth:`SmoothedAggregation.sweep_arrays`, read again when the matrix's values changed).

    Richardson applies it to the residual ``b - A x`` (to ``b`` itself from a zero initial guess, with no product):
    the sweep from ``x`` in exact arithmetic.
    """

    def __init__(self, sa):
        self.sa = sa

    def apply(self, pc, x, y) -> None:
        sa = self.sa
        (indptr, indices, data), dinv = sa.sweep_arrays()
        ya, xa = y.array, x.array
        ya[:] = 0.0
        block_gauss_seidel_forward(indptr, indices, data, ya, xa, dinv, sa.kernels)
        block_gauss_seidel_backward(indptr, indices, data, ya, xa, dinv, sa.kernels)
        del ya  # (the view's release marks y changed)


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
    kernels : {"auto", "numba", "numpy"}
        The local products' and sweeps' kernels (:func:`springsim.linsolve._kernels.bsr_matmat`; ``"auto"``: numba
        when installed).
    smoother : {"sor", "gs"}
        The finest level's smoother, before and after the coarse correction. ``"sor"``: PETSc's local symmetric SOR
        (point sweeps on the AIJ matrix), as on the coarser levels (which are BAIJ). ``"gs"``: a symmetric block
        Gauss-Seidel sweep over the rank's diagonal block with the serial V-cycle's compiled kernels on a BSR copy of
        it (:class:`_Sweep`): the same iterations, a fifth less time per solve on the benchmark cloth, the memory of
        that copy (3-5 % more per rank at n = 512).

    Notes
    -----
    :meth:`build` is collective. The aggregates are reused while the matrices keep their pattern (the caller
    calls :meth:`forget` when it changes); every build recomputes candidates, prolongators and coarse operators.
    """

    def __init__(self, PETSc, comm, *, theta: float = 0.1, omega: float = 4.0 / 3.0, max_coarse: int = 50,
                 max_direct: int = 3000, max_levels: int = 10, lanczos_steps: int = 12, warm_lanczos_steps: int = 4,
                 kernels: str = "auto", smoother: str = "sor"):
        self.PETSc, self.comm, self.mpi = PETSc, comm, comm.tompi4py()
        self.theta, self.omega = float(theta), float(omega)
        self.max_coarse, self.max_direct, self.max_levels = int(max_coarse), int(max_direct), int(max_levels)
        self.lanczos_steps, self.warm_lanczos_steps = int(lanczos_steps), int(warm_lanczos_steps)
        self.kernels = resolve_kernels(kernels)
        if smoother not in SMOOTHERS:
            raise ValueError(f"smoother must be one of {', '.join(SMOOTHERS)}, got {smoother!r:.40}")
        self.smoother = smoother
        #: How often the finest level's sweeps read the matrix's values again (they changed since the last build)
        self.sweep_refreshes = 0
        self._sweep_pcs: list = []  # the PCs holding a _Sweep of this hierarchy
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

    def release_sweeps(self) -> None:
        """Take the finest level's sweeps out of the PCMGs :meth:`configure` gave them (their PCs become ``none``):
        at exit, before PETSc finalises, so that no Python PC outlives the interpreter. Not collective."""
        for pc in self._sweep_pcs:
            try:
                pc.setType("none")
            except Exception:  # noqa: BLE001 (a PC already destroyed: nothing to release)
                pass
        self._sweep_pcs = []

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

    def _finest_rows(self, lv: _Level, A, bs: int) -> None:
        """``lv.rows`` = the owned block rows of the PETSc matrix ``A`` (its current values), their pattern taken once
        per matrix (the caller's matrix keeps its pattern until :meth:`forget`)."""
        if lv.extract is None or lv.extract.matrix != A.handle:
            indptr, indices, _ = A.getValuesCSR()
            lo, hi = (r // bs for r in A.getOwnershipRange())
            lv.extract = _rows.FromScalarCSR(indptr, indices, bs, lo, hi, A.getSize()[1] // bs)
            lv.extract.matrix = A.handle
            lv.extract.reader = self._reader(A, indices, lv.extract.dest)
            if lv.extract.reader is not None:
                lv.extract.dest = None  # the reader holds it, split between PETSc's two arrays
            del indptr, indices
        lv.rows = lv.extract(A)
        if lv.halo is None or not lv.halo.matches(lv.rows.ghosts):
            lv.halo = _rows.Halo(self.mpi, _rows.offsets_of(self.mpi, lv.rows.n_own), lv.rows.ghosts)

    def _reader(self, A, indices, dest):
        """An :class:`~springsim.distributed._aij.AIJValues` reading ``A``'s arrays into blocks (``dest``), or None
        (``getValuesCSR`` then) where it cannot: also for a BAIJ matrix, whose arrays hold blocks, not the scalar rows
        ``indices`` lists. Not collective."""
        from ._aij import AIJValues, petsc_library

        if A.getType().endswith("baij"):
            return None
        try:
            return AIJValues(self.PETSc, A, indices, petsc_library(), source=dest)
        except (ValueError, OSError, AttributeError, self.PETSc.Error):
            return None

    def _build(self, A, B_own: np.ndarray, block: int) -> list:
        mpi = self.mpi
        old = self.levels
        if old:
            old[0].A = A
        levels = old[:1] if old else [_Level(A, owned=False)]
        levels[0].sweep = None  # (the old copy goes before the new rows are read)
        self._finest_rows(levels[0], A, int(block))
        Bk = np.asarray(B_own, dtype=np.float64)
        while len(levels) < self.max_levels:
            li = len(levels) - 1
            lv = levels[li]
            rows = lv.rows
            bs = rows.bsr.blocksize[0]
            n_nodes = rows.n_own
            if mpi.allreduce(n_nodes) <= self.max_coarse:
                break
            Asq = rows.square()
            if lv.aggregates is None or lv.aggregates.shape[0] != n_nodes:  # first build (or a new pattern)
                lv.destroy(operator=False)
                for stale in old[li + 1:]:  # their sizes follow these aggregates
                    stale.destroy()
                old = old[:li + 1]
                agg = _aggregate(Asq, self.theta)
                lv.aggregates, lv.ritz = agg[:, np.bincount(agg.indices, minlength=agg.shape[1]) > 0], None
            agg = lv.aggregates
            n_agg = mpi.allreduce(agg.shape[1])
            if n_agg >= mpi.allreduce(n_nodes) or n_agg == 0:
                break  # nothing (left) to coarsen
            lv.Pext = lv.R = None  # recomputed below: not alive beside the new ones
            T, Bc, dead = _tentative(agg, Bk, bs)
            D, Dinv = block_diagonal_inverse(Asq, self.kernels)
            if li == 0 and self._sweeps(lv.A):  # the diagonal block and its blocks' inverses, for the sweeps
                self._set_sweep(lv, Asq, Dinv)
            del Asq
            rho, lv.ritz = self._lanczos(lv.A, D, Dinv, lv.ritz)
            if not (np.isfinite(rho) and rho > 0.0):
                raise ArithmeticError("spectral radius estimate of D^-1 A broke down (matrix not positive definite)")
            coarse_off = _rows.offsets_of(mpi, agg.shape[1])
            c_lo, c_hi = (int(c) for c in coarse_off[mpi.Get_rank():mpi.Get_rank() + 2])
            # A T over the owned rows: T's ghost rows from their owners
            Trows = _rows.Rows(T, np.arange(c_lo, c_hi, dtype=np.int64), c_hi - c_lo)
            Text = _rows.stack_rows(Trows, *_rows.fetch_rows(lv.halo, Trows), c_lo, c_hi)
            AT, lv.plans["AT"] = bsr_matmat(rows.bsr, Text.bsr, self.kernels, lv.plans.get("AT"))
            # P = T - (omega / rho) D^-1 (A T) on the owned rows, then its ghost rows
            Pown = smoothed_prolongator(AT, _rows.head(Text.bsr, n_nodes), Dinv, self.omega / rho, self.kernels)
            Pown = _rows.Rows(Pown, Text.gids, c_hi - c_lo)
            lv.Pext = _rows.stack_rows(Pown, *_rows.fetch_rows(lv.halo, Pown), c_lo, c_hi)
            del AT, Pown, Text, T, rows  # (the level's rows go in _coarse_operator, once A P is formed)
            own = _rows.head(lv.Pext.bsr, n_nodes)
            lv.R = own.T.tobsr(blocksize=(own.blocksize[1], own.blocksize[0]))
            lv.P, lv.csrP = self._fill(lv.P, lv.csrP, _rows.Rows(own, lv.Pext.gids, c_hi - c_lo),
                                       (n_nodes * bs, (c_hi - c_lo) * Bk.shape[1]), (bs, Bk.shape[1]))
            lv.dead = dead if mpi.allreduce(int(dead.size)) else None
            coarse = old[li + 1] if li + 1 < len(old) else _Level(None, owned=True)
            lv.coarse_off = coarse_off
            self._coarse_operator(lv, coarse)
            levels.append(coarse)
            Bk = Bc
        for lv in old[len(levels):]:
            lv.destroy()
        levels[-1].rows = None  # (the others' went once used: rebuilt from the finest level's next time)
        levels[-1].destroy(operator=False)  # the coarsest level has no prolongator
        levels[-1].aggregates = levels[-1].ritz = None
        self.levels = levels
        return levels

    def galerkin(self) -> None:
        """Recompute the coarse operators ``P^T A P`` from the finest operator's current values, the prolongators
        kept (PETSc's ``-pc_gamg_reuse_interpolation`` for these levels). Collective."""
        self.event.begin()
        try:
            levels = self.levels
            if len(levels) > 1:
                levels[0].sweep = None  # (the old copy goes before the new rows are read)
                self._finest_rows(levels[0], levels[0].A, levels[0].extract.bs)
                if self._sweeps(levels[0].A):  # the sweeps' copy from the rows just read
                    self._set_sweep(levels[0], levels[0].rows.square())
            for lv, coarse in zip(levels[:-1], levels[1:]):
                self._coarse_operator(lv, coarse)
            levels[-1].rows = None
        finally:
            self.event.end()

    def _sweeps(self, A) -> bool:
        """Whether the finest level ``A`` gets :class:`_Sweep` (``smoother="gs"``, a matrix of block size 3)."""
        return self.smoother == "gs" and A.getBlockSize() == 3

    def sweep_arrays(self) -> tuple:
        """The finest level's diagonal block and its inverted diagonal blocks, for :class:`_Sweep`, read again from the
        matrix when its values changed since they were taken (a kept hierarchy serving a new matrix). Not collective.

        Returns
        -------
        (indptr, indices, data) : tuple of ndarray
            The BSR arrays of the rank's diagonal block (3 x 3 blocks).
        dinv : ndarray, shape (nb, 3, 3)
            The inverses of its diagonal blocks.
        """
        lv = self.levels[0]
        if lv.sweep is None or lv.sweep[0] != lv.A.stateGet():
            lv.sweep = None  # (the old copy goes before the new rows are read)
            self._set_sweep(lv, lv.extract(lv.A).square())
            self.sweep_refreshes += 1
        return lv.sweep[1], lv.sweep[2]

    def _set_sweep(self, lv: _Level, sq: sp.bsr_matrix, dinv: np.ndarray | None = None) -> None:
        """``lv.sweep`` from the rank's diagonal block ``sq`` of the finest level's current values (``Rows.square``:
        the rows themselves on one rank) and its inverted diagonal blocks (computed unless given)."""
        lv.sweep = None  # (the old copy goes before the new one is made)
        if dinv is None:
            _, dinv = block_diagonal_inverse(sq, self.kernels)
        lv.sweep = (lv.A.stateGet(), (sq.indptr, sq.indices, np.ascontiguousarray(sq.data)), dinv)

    def _coarse_operator(self, lv: _Level, coarse: _Level) -> None:
        """``coarse.A = P^T (A P)`` of ``lv``: each rank multiplies its rows (``R (A P_ext)``, the compiled block
        kernels with kept patterns), sends the rows of other ranks' coarse nodes to them and sums what it receives
        for its own; coarse DOFs whose prolongator column is zero get a unit diagonal (a decoupled row the coarse
        correction leaves at zero)."""
        mpi, coarse_off = self.mpi, lv.coarse_off
        c_lo, c_hi = (int(c) for c in coarse_off[mpi.Get_rank():mpi.Get_rank() + 2])
        nc = c_hi - c_lo
        AP, lv.plans["AP"] = bsr_matmat(lv.rows.bsr, lv.Pext.bsr, self.kernels, lv.plans.get("AP"))
        C, lv.plans["RAP"] = bsr_matmat(lv.R, AP, self.kernels, lv.plans.get("RAP"), symmetric=mpi.Get_size() == 1)
        del AP
        k = C.blocksize[0]
        gids = lv.Pext.gids
        # rows of other ranks' coarse nodes (the ghost part of the numbering, sorted: grouped by owner) to them
        split = int(C.indptr[nc])
        dest = np.searchsorted(coarse_off, gids[nc:], side="right") - 1
        ip, cg, blocks, tag, _ = _rows.send_rows(mpi, dest, C.indptr[nc:] - split, gids[C.indices[split:]],
                                                 C.data[split:], tag=gids[nc:])
        rows = np.concatenate([np.repeat(np.arange(nc, dtype=np.int64), np.diff(C.indptr[:nc + 1])),
                               np.repeat(tag - c_lo, np.diff(ip))])
        colgid = np.concatenate([gids[C.indices[:split]], cg])
        n_cols = int(coarse_off[-1])
        if lv.merge is None or not lv.merge.matches(rows, colgid, n_cols):
            lv.merge = _rows.RowMerge(rows, colgid, nc, n_cols)
        m = lv.merge
        data = m(np.concatenate([C.data[:split], blocks]))
        if lv.dead is not None:  # unit diagonal entries of the dead DOFs (their diagonal blocks exist: T's pattern)
            d = lv.dead
            diag = np.flatnonzero(m.rows == m.colgid - c_lo)
            data[diag[np.searchsorted(m.rows[diag], d // k)], d % k, d % k] += 1.0
        local, cgids = _rows.local_columns(m.colgid, c_lo, c_hi)
        crows = _rows.Rows(sp.bsr_matrix((data, local, m.indptr), shape=(nc * k, cgids.size * k)), cgids, nc)
        lv.rows = None  # this level's rows are done with (the next build or galerkin takes them afresh)
        coarse.rows = crows
        if coarse.halo is None or not coarse.halo.matches(crows.ghosts):
            coarse.halo = _rows.Halo(mpi, coarse_off, crows.ghosts)
        coarse.A, coarse.csrA = self._fill(coarse.A, coarse.csrA, crows, (nc * k, nc * k), (k, k))

    def _fill(self, M, csr, rows, local_shape: tuple, block_sizes: tuple):
        """``(M, csr)``: ``M`` with its owned rows set to ``rows``, ``csr`` their pattern for PETSc (global columns).

        Square blocks (the coarse operators) make a ``BAIJ`` matrix (:class:`~springsim.distributed._rows.BlockCSR`):
        PETSc's SOR then sweeps with the inverted diagonal blocks and its products run block by block, 15-20 % less
        time per V-cycle than on ``AIJ`` with the same iterations; the prolongators (rectangular blocks) are ``AIJ``
        (:class:`~springsim.distributed._rows.ScalarCSR`). The values are replaced when ``rows`` has the pattern of
        ``csr`` (written into PETSc's arrays by :class:`~springsim.distributed._aij.AIJValues` when it reproduced
        PETSc's own insertion on every rank, else through PETSc's calls); otherwise (or ``M`` None) a new matrix
        and pattern. The patterns follow the matrix pattern and the aggregates, so a new one comes only with a new
        build."""
        PETSc = self.PETSc
        blocked = block_sizes[0] == block_sizes[1] and block_sizes[0] > 1
        if csr is None or not csr.matches(rows):
            csr = _rows.BlockCSR(rows) if blocked else _rows.ScalarCSR(rows)
            if M is not None:
                M.destroy()
                M = None
        if M is not None:
            if csr.writer is not None:  # straight from the blocks
                csr.writer.insert(M, np.ascontiguousarray(rows.bsr.data).reshape(-1))
            else:
                self._set_values(M, csr, rows, blocked)
            return M, csr
        IT = PETSc.IntType
        csr.petsc = (csr.indptr.astype(IT, copy=False), csr.indices.astype(IT, copy=False))
        M = PETSc.Mat().create(comm=self.comm)
        M.setSizes(((local_shape[0], None), (local_shape[1], None)))
        M.setBlockSizes(*block_sizes)
        if blocked:  # preallocated by blocks per row in the owned columns and in the others
            M.setType(PETSc.Mat.Type.BAIJ)
            n_rows = csr.indptr.size - 1
            brow = np.repeat(np.arange(n_rows), np.diff(csr.indptr))
            lo = rows.gids[0] if rows.n_own else 0
            own = (csr.indices >= lo) & (csr.indices < lo + rows.n_own)
            M.setPreallocationNNZ((np.bincount(brow[own], minlength=n_rows).astype(IT),
                                   np.bincount(brow[~own], minlength=n_rows).astype(IT)))
            M.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, True)
            self._set_values(M, csr, rows, blocked)
        else:
            M.setType(PETSc.Mat.Type.AIJ)
            M.setPreallocationCSR((*csr.petsc, csr.values(rows)))
            M.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, True)
            M.assemble()
        csr.writer = self._writer(M, csr, rows)
        if csr.writer is not None:  # the pattern's index arrays are not needed again
            csr.indptr = csr.indices = csr.perm = csr.petsc = None
            if blocked:
                csr.entry_cols = csr.order = None
        return M, csr

    def _set_values(self, M, csr, rows, blocked: bool) -> None:
        """``M``'s owned rows = ``rows`` through PETSc's calls (``MatSetValuesBlocked`` row by row in C, or
        ``MatSetValuesCSR``), assembled. Collective."""
        if blocked:
            IT = self.PETSc.IntType
            first = M.getOwnershipRange()[0] // rows.bsr.blocksize[0]
            M.setValuesBlockedIJV(*csr.petsc, csr.values(rows),
                                  rowmap=np.arange(first, first + csr.indptr.size - 1, dtype=IT))
        else:
            M.setValuesCSR(*csr.petsc, csr.values(rows))
        M.assemble()

    def _writer(self, M, csr, rows):
        """A :class:`~springsim.distributed._aij.AIJValues` of ``rows``' blocks into ``M`` (just assembled by PETSc
        from them) when it writes the same matrix on every rank (the products with a random vector agree to 1e-12 of
        ``|M|_inf |x|_inf``; ``M`` then holds its result), else None. Collective."""
        from mpi4py import MPI

        from ._aij import AIJValues, petsc_library, reproduces

        try:
            cols = csr.entry_cols if isinstance(csr, _rows.BlockCSR) else csr.indices
            writer = AIJValues(self.PETSc, M, cols, petsc_library(), source=csr.perm)
        except (ValueError, OSError, AttributeError, self.PETSc.Error):
            writer = None
        if not self.mpi.allreduce(int(writer is not None), op=MPI.MIN):
            return None
        values = np.ascontiguousarray(rows.bsr.data).reshape(-1)
        return writer if reproduces(self.PETSc, M, lambda: writer.insert(M, values), self.mpi) else None

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
        self._sweep_pcs = [p for p in self._sweep_pcs if p.getRefCount() > 1]  # those of PCs still used elsewhere
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
        if L > 1 and self._sweeps(levels[0].A):  # the finest level: springsim's compiled sweeps
            sm = pc.getMGSmoother(L - 1)
            sweep_pc = sm.getPC()
            sweep_pc.setType("python")
            sweep_pc.setPythonContext(_Sweep(self))
            self._sweep_pcs.append(sweep_pc)
            if not _EXIT_HOOK:  # registered after petsc4py's own finaliser, so run before it
                _EXIT_HOOK.append(atexit.register(_release_sweeps))
            _WITH_SWEEPS.add(self)
        co = pc.getMGCoarseSolve()
        co.setOperators(levels[-1].A)
        if levels[-1].A.getSize()[0] > self.max_direct:  # coarsening stopped early (a diagonally dominant matrix)
            co.setType("richardson")
            co.setTolerances(max_it=1)
            co.getPC().setType("sor")
        else:
            co.setType("preonly")
            co.getPC().setType("redundant" if self.comm.getSize() > 1 else "lu")
