"""The distributed system: ghost exchange, forces, assembly into a PETSc matrix and the KSP solve.

One :class:`DistributedSystem` per rank, built collectively. Vectors of the system are over the
free DOFs, distributed as the partition says (:mod:`springsim.distributed.partition`); PETSc
vectors and the matrix have block size 3.

* **Ghost exchange** (:meth:`DistributedSystem.exchange`): one PETSc scatter from the distributed
  vector to the rank's local free particles (owned and ghosts); fixed particles never move, so their
  local positions are set once.
* **Forces** (:meth:`DistributedSystem.forces`): pairwise terms over the owned pairs and per-particle
  terms over the owned particles, on the local arrays; the rows of ghosts go back to their owners by the
  same scatter in reverse, adding.
* **Assembly** (:meth:`DistributedSystem.assemble`): springsim's serial assembler scatters the 3x3 COO
  blocks of the local terms into a local block-CSR matrix over owned and ghost particles (pattern
  computed once, mass on the owned diagonal only); its rows go into the PETSc AIJ matrix (block size 3)
  with ``MatSetValuesBlockedLocal`` through the local-to-global map, adding; PETSc sends the ghost rows to
  their owners during assembly. The matrix is preallocated exactly, once, from the local pairs (the ghosts'
  rows' entries sent to their owners, :func:`part_pattern`), and a new nonzero is an error.
* **Solve** (:meth:`DistributedSystem.solve`): CG preconditioned by springsim's smoothed aggregation in PETSc's
  PCMG by default (:mod:`springsim.distributed.sa`: the serial AMG's hierarchy, aggregates local to each rank,
  kept for the run; ``-springsim_pc``), GMRES with GAMG when the matrix is not symmetric or the set-up finds it
  not positive definite. With ``-springsim_pc gamg``: CG with GAMG, the rigid-body modes at the current positions
  as GAMG's near-null space, then
  ``setFromOptions``, so every ``-ksp_*``/``-pc_*`` option (command line, ``PETSC_OPTIONS``,
  ``solver.petsc_options``) overrides the defaults. The finest level is smoothed by one symmetric SOR
  (Gauss-Seidel) sweep instead of GAMG's Chebyshev/Jacobi (:data:`SPRINGSIM_OPTIONS`); coarse levels keep
  Chebyshev/Jacobi, because GAMG's singleton aggregates leave zero rows there, on which SOR and point-block
  Jacobi divide by zero. The KSP is kept for up to ``k`` matrices (``-springsim_pc_reuse k``, default 2; 1 builds
  a new KSP and preconditioner for every matrix), re-set-up on each new one with the interpolation kept (GAMG's
  ``-pc_gamg_reuse_interpolation``, on by default, or :meth:`~springsim.distributed.sa.SmoothedAggregation.galerkin`:
  only the Galerkin coarse operators and the smoothers are recomputed; springsim's levels serve a matrix of the
  same coefficients whole until that once goes stale, :data:`SPRINGSIM_OPTIONS`). The result is checked against
  the true residual. A kept
  preconditioner gets ``2 * baseline + 4`` iterations (``baseline``: the fresh solve's count); a miss builds a
  fresh preconditioner and continues from the iterate reached. A miss with a fresh preconditioner is retried
  once with GMRES (fresh again) and five times the iteration limit from that iterate, and reported if that
  misses too (:class:`~springsim.linsolve.LinearSolveResult` contract). The measurements behind these
  choices: docs/distributed.md, "GAMG settings", and BENCHMARKS.md#distributed.
"""

from __future__ import annotations

import dataclasses
import shlex
import time

import numpy as np

from ..assembly import SystemAssembler
from ..errors import SceneError
from ..forces import make_force_terms
from ..linsolve import DEFAULT_RTOL, LinearSolveResult
from ..linsolve.amg import rigid_body_modes
from ..system import System
from ._aij import petsc_library as _petsc_library
from ._petsc import import_petsc
from .partition import PARTITIONERS, LocalPart, contiguous_offsets, pair_families, system_order
from .sa import SMOOTHERS, SmoothedAggregation
from .scene import ScenePart, model_part, repartition

__all__ = ["DistributedSystem", "GAMG_DEFAULTS", "SPRINGSIM_OPTIONS", "graph_partition", "owned_row_pattern",
           "part_pattern", "graph_parts"]

#: PETSc options springsim sets unless given (``--petsc-options``, ``PETSC_OPTIONS``, the command line).
#: GAMG's Chebyshev smoothers scale an estimate of the largest eigenvalue of each level by a safety factor
#: (default 1.1). On the benchmark cloth (n = 256, h = 1/60 s, spd Jacobian) that estimate was low enough on
#: the third step's matrix for the preconditioner to be indefinite (CG stopped, "indefinite PC", and the GMRES
#: retry needed 1,500 iterations); 1.3 gave 1, 16 and 15 CG iterations on the first three steps
#: (docs/distributed.md, "GAMG settings").
GAMG_DEFAULTS = {"mg_levels_ksp_chebyshev_esteig": "0,0.1,0,1.3"}

#: springsim's own options, read from PETSc's options database like the others (so ``--petsc-options``,
#: ``solver.petsc_options`` and ``PETSC_OPTIONS`` set them), with their defaults:
#:
#: * ``-springsim_fine_smoother``: ``sor`` (one Richardson iteration of PETSc's local symmetric SOR on GAMG's
#:   finest level, the block Gauss-Seidel sweep pair of the serial AMG in point form) or ``gamg`` (GAMG's own
#:   Chebyshev/Jacobi). Ignored when a ``-mg_levels_ksp_type`` or ``-mg_levels_pc_type`` option is set, or with
#:   another ``-pc_type``. On the benchmark cloth (n = 256, linearized implicit Euler) it cuts the CG
#:   iterations per solve from 32-72 to 21-24 at the same cost per iteration.
#: * ``-springsim_pc_reuse``: ``k``, keep the KSP and GAMG's interpolation for up to ``k`` matrices (1: a fresh
#:   preconditioner for every matrix). Default 2: on the falling benchmark cloth (n = 256, linearized implicit
#:   Euler, 4.4 solves per step) the CG iterations stay the same with the finest level's SOR, the set-up per
#:   step falls by 30 % and the step by 13-16 % on 1 rank and 8 % on 2 (BENCHMARKS.md#distributed).
#: * ``-springsim_pc``: ``sa`` (springsim's smoothed aggregation in PETSc's PCMG,
#:   :class:`~springsim.distributed.sa.SmoothedAggregation`: the serial AMG's hierarchy with aggregates local to
#:   each rank) or ``gamg`` (PETSc's GAMG). ``sa`` needs a symmetric positive definite matrix: a non-symmetric
#:   one, or one on which its set-up breaks down, gets GAMG, and so does the GMRES retry of a missed solve. A
#:   ``-pc_type`` option overrides both. With ``sa`` a kept preconditioner serves a matrix assembled with the
#:   same coefficients ``(a, b)`` whole (the new matrix on its finest level only) until that once goes stale in
#:   the run, and otherwise with its coarse operators recomputed (the prolongators kept;
#:   ``pc_stats["coarse_updates"]``).
#: * ``-springsim_sa_smoother``: ``sor`` (PETSc's local symmetric SOR on the finest level of ``sa``, point sweeps on
#:   the AIJ matrix) or ``gs`` (a symmetric block Gauss-Seidel sweep there with springsim's compiled kernels on a
#:   BSR copy of the rank's diagonal block, :class:`~springsim.distributed.sa.SmoothedAggregation`): the same
#:   iterations; on the benchmark cloth at n = 512, 22-26 % less time per solve and a one-rank step 1.14-1.20x the
#:   serial one instead of 1.24-1.40x, for 3-5 % more memory per rank (BENCHMARKS.md#distributed).
#: * ``-springsim_insertion``: ``direct`` (the owned rows' values gathered straight into the AIJ matrix's arrays,
#:   :class:`~springsim.distributed._aij.DirectInsertion`, checked once against PETSc's own insertion and replaced
#:   by it where they differ) or ``petsc`` (``MatSetValuesBlockedLocal`` for every block).
SPRINGSIM_OPTIONS = {"springsim_fine_smoother": "sor", "springsim_pc_reuse": "2", "springsim_pc": "sa",
                     "springsim_sa_smoother": "sor", "springsim_insertion": "direct"}


def _choice(opts, name: str, choices) -> str:
    """springsim's option ``-name`` from PETSc's options database (default :data:`SPRINGSIM_OPTIONS`), one of
    ``choices``; a SceneError naming it otherwise."""
    value = opts.getString(name, SPRINGSIM_OPTIONS[name])
    if value not in choices:
        raise SceneError("petsc_options", f"-{name} must be {' or '.join(choices)}, got {value!r:.40}")
    return value


#: The values of ``-springsim_pc``.
SPRINGSIM_PCS = ("sa", "gamg")

#: A solve with a kept preconditioner may take ``REUSE_FACTOR * baseline + REUSE_SLACK`` iterations (``baseline``:
#: the count of the solve that built it) before a fresh one is built (the serial AMG's staleness rule).
REUSE_FACTOR, REUSE_SLACK = 2.0, 4


def owned_row_pattern(model, lo: int, hi: int, order: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Block pattern of the system rows ``lo .. hi``: ``(indptr, cols)``, columns sorted (rows numbered as
    :func:`~springsim.distributed.partition.system_order` with ``order`` says).

    Row ``k`` holds ``k`` and every free particle paired with it in any pair list; it is symmetric, so each
    rank computes the exact pattern of its rows, entries other ranks send included, from the pair lists.

    Parameters
    ----------
    model : Model
        The whole model.
    lo, hi : int
        The block rows owned (system numbering, ``hi`` exclusive).
    order : ndarray of int, optional
        The free particles' renumbering of a graph partition (default: the serial order).

    Returns
    -------
    indptr : ndarray of int, shape (hi - lo + 1,)
        Row pointers.
    cols : ndarray of int
        Block column indices, sorted within each row.
    """
    free = system_order(model, order)
    F = free.size
    fi = np.full(model.particle_count, -1, dtype=np.int64)
    fi[free] = np.arange(F)
    r, c = [np.arange(lo, hi)], [np.arange(lo, hi)]
    for term in pair_families(model):
        ij = fi[model.terms[term]["indices"]]
        ij = ij[(ij[:, 0] >= 0) & (ij[:, 1] >= 0)]
        for a, b in ((0, 1), (1, 0)):
            mine = (ij[:, a] >= lo) & (ij[:, a] < hi)
            r.append(ij[mine, a])
            c.append(ij[mine, b])
    key = np.unique((np.concatenate(r) - lo) * F + np.concatenate(c))
    rows, cols = key // F, key % F
    indptr = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=hi - lo))])
    return indptr, cols


def part_pattern(part: LocalPart, free_count: int, mpi) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Block pattern of a rank's owned rows from its local pairs alone: ``(indptr, cols, pairs)``. Collective.

    Row ``k`` holds ``k`` and every free particle paired with ``k`` (what :func:`owned_row_pattern` computes from
    the whole model): the rank's pairs give the entries of its owned rows and of its ghosts' rows, and the latter go
    to their owners in one all-to-all (vectorized; a loop over ranks only).

    Parameters
    ----------
    part : LocalPart
        The rank's part.
    free_count : int
        Free particles of the whole scene, F.
    mpi : mpi4py communicator
        The ranks.

    Returns
    -------
    indptr : ndarray of int, shape (n_own + 1,)
        Row pointers.
    cols : ndarray of int
        Block columns (system numbering), sorted within each row.
    pairs : ndarray of int, shape (n_own,)
        Number of pairs between each owned particle and another free particle (the graph partition's weights).
    """
    l2f = part.local_to_free
    r, c = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)]
    for term in pair_families(part.pair_model):
        ij = l2f[part.pair_model.terms[term]["indices"]]
        ij = ij[(ij[:, 0] >= 0) & (ij[:, 1] >= 0)]
        r += [ij[:, 0], ij[:, 1]]
        c += [ij[:, 1], ij[:, 0]]
    rows, cols = np.concatenate(r).astype(np.int64), np.concatenate(c).astype(np.int64)
    size = mpi.Get_size()
    dest = np.searchsorted(part.offsets, rows, side="right") - 1
    by = np.argsort(dest, kind="stable")
    rows, cols, dest = rows[by], cols[by], dest[by]
    cuts = np.searchsorted(dest, np.arange(size + 1))
    got = mpi.alltoall([(rows[cuts[k]:cuts[k + 1]], cols[cuts[k]:cuts[k + 1]]) for k in range(size)])
    lo, hi, F = part.lo, part.hi, int(free_count)
    rows = np.concatenate([g[0] for g in got] + [np.zeros(0, np.int64)]) - lo
    cols = np.concatenate([g[1] for g in got] + [np.zeros(0, np.int64)])
    pairs = np.bincount(rows, minlength=hi - lo)
    key = np.unique(np.concatenate([np.arange(hi - lo) * F + np.arange(lo, hi), rows * F + cols]))
    rows, cols = key // F, key % F
    indptr = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=hi - lo))])
    return indptr, cols, pairs


def _scalar_csr(indptr: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Scalar CSR (3 rows per block row, 3 columns per block) of a block pattern."""
    m = np.diff(indptr)                        # blocks per block row
    cols3 = (3 * cols[:, None] + np.arange(3)).ravel()
    lengths = np.repeat(3 * m, 3)              # entries per scalar row
    starts = np.repeat(3 * indptr[:-1], 3)     # where each scalar row's columns start in cols3
    sptr = np.concatenate([[0], np.cumsum(lengths)])
    idx = np.repeat(starts - sptr[:-1], lengths) + np.arange(sptr[-1])
    return sptr, cols3[idx]


def graph_partition(model, comm, method: str) -> tuple[np.ndarray, np.ndarray]:
    """``(order, offsets)``: a partition of the free-particle graph (an edge per pair) into one part per rank by
    PETSc's ``MatPartitioning`` of type ``method``, as a renumbering of the free particles (part by part, the
    serial order kept within a part) and the parts' row offsets. Collective over ``comm``.

    Parameters
    ----------
    model : Model
        The whole model (on every rank).
    comm : petsc4py Comm
        The communicator; one part per rank.
    method : str
        A ``MatPartitioning`` type (``ptscotch``, ``parmetis``).

    Returns
    -------
    order : ndarray of int, shape (F,)
        The free particles (serial indices) in the partitioned order.
    offsets : ndarray of int, shape (size + 1,)
        Each part's first row in that order.
    """
    PETSc, MPI = import_petsc()
    size, rank = comm.getSize(), comm.getRank()
    F = int(model.free_count)
    lo, hi = (int(x) for x in contiguous_offsets(F, size)[rank:rank + 2])
    indptr, cols = owned_row_pattern(model, lo, hi)
    rows = np.repeat(np.arange(lo, hi), np.diff(indptr))
    off = cols != rows  # the adjacency has no diagonal
    adj_ptr = np.concatenate([[0], np.cumsum(np.bincount(rows[off] - lo, minlength=hi - lo))])
    adj = PETSc.Mat().createAIJ(((hi - lo, F), (hi - lo, F)), comm=comm,
                                csr=(adj_ptr.astype(PETSc.IntType), cols[off].astype(PETSc.IntType),
                                     np.ones(int(off.sum()))))
    mp = PETSc.MatPartitioning().create(comm=comm)
    mp.setType(method)
    mp.setAdjacency(adj)
    mp.setFromOptions()
    part = PETSc.IS()
    mp.apply(part)
    owner = np.concatenate(comm.tompi4py().allgather(np.array(part.getIndices(), dtype=np.int64)))
    for obj in (part, mp, adj):
        obj.destroy()
    order = np.argsort(owner, kind="stable")
    return order, np.concatenate([[0], np.cumsum(np.bincount(owner, minlength=size))])


def graph_parts(part: LocalPart, free_count: int, comm, method: str, *, weights: bool = True) -> np.ndarray:
    """The new rank of each of this rank's owned particles: PETSc's ``MatPartitioning`` of type ``method`` on the
    distributed particle graph (an edge per pair; each rank gives its owned rows, :func:`part_pattern`), each
    particle weighted by its pairs. Collective over ``comm``; no rank holds the whole graph.

    Parameters
    ----------
    part : LocalPart
        This rank's part (its owned rows are its rows of the graph).
    free_count : int
        Free particles of the whole scene.
    comm : petsc4py Comm
        The ranks; one part per rank.
    method : str
        A ``MatPartitioning`` type (``ptscotch``, ``parmetis``).
    weights : bool
        Weigh each particle by its number of pairs (at least 1), so that parts balance the pair work.

    Returns
    -------
    ndarray of int, shape (n_own,)
        The part (rank) of each owned particle.
    """
    PETSc, _ = import_petsc()
    mpi = comm.tompi4py()
    F = int(free_count)
    lo, hi = part.lo, part.hi
    indptr, cols, pairs = part_pattern(part, F, mpi)
    rows = np.repeat(np.arange(lo, hi), np.diff(indptr))
    off = cols != rows  # the adjacency has no diagonal
    adj_ptr = np.concatenate([[0], np.cumsum(np.bincount(rows[off] - lo, minlength=hi - lo))])
    adj = PETSc.Mat().createAIJ(((hi - lo, F), (hi - lo, F)), comm=comm,
                                csr=(adj_ptr.astype(PETSc.IntType), cols[off].astype(PETSc.IntType),
                                     np.ones(int(off.sum()))))
    mp = PETSc.MatPartitioning().create(comm=comm)
    try:
        mp.setType(method)
        mp.setAdjacency(adj)
        if weights:
            _set_vertex_weights(mp, np.maximum(pairs, 1))
        mp.setFromOptions()
        out = PETSc.IS()
        mp.apply(out)
        parts = np.array(out.getIndices(), dtype=np.int64)
        out.destroy()
    finally:
        mp.destroy()
        adj.destroy()
    return parts


def _set_vertex_weights(mp, w: np.ndarray) -> None:
    """``MatPartitioningSetVertexWeights`` (not in petsc4py 3.18) through ctypes: PETSc takes the array and frees it
    with ``PetscFree``, so it is allocated with PETSc's own ``PetscMallocA``."""
    import ctypes

    PETSc, _ = import_petsc()
    lib = _petsc_library()
    itemsize = np.dtype(PETSc.IntType).itemsize
    ptr = ctypes.c_void_p()
    lib.PetscMallocA.restype = ctypes.c_int
    err = lib.PetscMallocA(ctypes.c_int(1), ctypes.c_int(0), ctypes.c_int(0), ctypes.c_char_p(b"springsim"),
                           ctypes.c_char_p(b"system.py"), ctypes.c_size_t(max(w.size, 1) * itemsize),
                           ctypes.byref(ptr))
    if err:
        raise PETSc.Error(err)
    data = np.ascontiguousarray(w, dtype=PETSc.IntType)
    ctypes.memmove(ptr, data.ctypes.data, data.nbytes)
    lib.MatPartitioningSetVertexWeights.restype = ctypes.c_int
    err = lib.MatPartitioningSetVertexWeights(ctypes.c_void_p(mp.handle), ptr)
    if err:
        raise PETSc.Error(err)


class _Operator:
    """``A @ x`` on DOF vectors for the matrix a :class:`DistributedSystem` assembled last."""

    def __init__(self, system):
        self.system = system

    def __matmul__(self, x):
        s = self.system
        s.b.array[:] = np.asarray(x).ravel()
        s.A.mult(s.b, s.w)
        return s.w.array.copy()


class DistributedSystem(System):
    """Rank-local part of the distributed system of ``model`` (build it on every rank of ``comm``).

    Parameters
    ----------
    model : Model or ScenePart
        The whole model, the same on every rank; or this rank's part of a scene built per rank
        (:mod:`springsim.distributed.scene`), where no rank holds the whole model.
    comm : petsc4py Comm, optional
        Default ``PETSc.COMM_WORLD``.
    rtol, atol, maxiter : float, float, int
        Linear tolerance (true relative residual; default :data:`~springsim.linsolve._base.DEFAULT_RTOL`) and
        iteration limit of the first attempt.
    petsc_options : str or dict, optional
        PETSc options (``"-pc_gamg_threshold 0.02"`` or ``{"pc_gamg_threshold": 0.02}``) inserted into the
        options database before the solver reads it.
    ksp_type, pc_type : str, optional
        Defaults before the options database: ``cg`` or ``gmres`` by the matrix symmetry when None; a PETSc
        preconditioner type, or None for ``-springsim_pc`` (:data:`SPRINGSIM_OPTIONS`: springsim's smoothed
        aggregation by default, else GAMG).
    partitioner : str
        One of :data:`PARTITIONERS`: ``contiguous`` (default) keeps the serial numbering, so the gathered matrix
        is the serial one; a graph partitioner gives each rank a compact part of the particle graph (fewer
        ghosts on scenes numbered at random) and numbers the system part by part. For a scene part it runs on the
        distributed graph (:func:`graph_parts`) and the particles and pairs then move
        (:func:`~springsim.distributed.scene.repartition`).
    force_kernels : {"auto", "numba", "numpy"}
        Compiled force passes or the pure numpy path (:func:`springsim.forces.make_force_terms`).

    Notes
    -----
    It implements :class:`springsim.system.System`: state arrays are the owned particles (all free), DOF vectors
    their three components, every reduction an MPI all-reduce, so the integrators run on it unchanged.
    """

    #: Fixed particles are not in the state arrays: the energy bound adds their constant gravity itself.
    holds_fixed = False

    def __init__(self, model, comm=None, *, rtol: float = DEFAULT_RTOL, atol: float = 0.0, maxiter: int = 1000,
                 petsc_options=None, ksp_type: str | None = None, pc_type: str | None = None,
                 partitioner: str = "contiguous", force_kernels: str = "auto"):
        PETSc, MPI = import_petsc()
        self.PETSc, self.MPI = PETSc, MPI
        self.comm = PETSc.COMM_WORLD if comm is None else comm
        self.mpi = self.comm.tompi4py()
        self.rank, self.size = self.comm.getRank(), self.comm.getSize()
        self.model = model
        self.partitioner = partitioner
        if partitioner not in PARTITIONERS:
            raise SceneError("partitioner", f"must be one of {', '.join(PARTITIONERS)}, got {partitioner!r:.60}")
        order = offsets = None
        if isinstance(model, ScenePart):  # built per rank: no rank has the whole model
            scene = model
            if partitioner != "contiguous":  # the distributed graph, then the particles and pairs move
                try:
                    parts = graph_parts(scene.part, scene.free_count, self.comm, partitioner)
                except PETSc.Error as e:
                    raise SceneError("partitioner", f"PETSc's MatPartitioning {partitioner!r} failed (error code "
                                                    f"{e.ierr}); is it in this PETSc build?") from None
                scene = repartition(scene, parts, self.mpi)
        else:
            if partitioner != "contiguous":
                try:
                    order, offsets = graph_partition(model, self.comm, partitioner)
                except PETSc.Error as e:
                    raise SceneError("partitioner", f"PETSc's MatPartitioning {partitioner!r} failed (error code "
                                                    f"{e.ierr}); is it in this PETSc build?") from None
            scene = model_part(model, self.size, self.rank, offsets=offsets, order=order)
        #: This rank's share of the scene (:class:`~springsim.distributed.scene.ScenePart`).
        self.scene = scene
        #: Whether :attr:`model` is the whole Model (False: a :class:`~springsim.distributed.scene.ScenePart`).
        self.whole_model = not isinstance(model, ScenePart)
        self.part: LocalPart = scene.part
        p = self.part
        self.free_count = int(scene.free_count)
        self.rtol, self.atol, self.maxiter = float(rtol), float(atol), int(maxiter)
        self.ksp_type, self.pc_type = ksp_type, pc_type or "gamg"
        if petsc_options:
            self.insert_options(petsc_options)
        opts = PETSc.Options()
        for name, value in GAMG_DEFAULTS.items():  # only where no source (flags, PETSC_OPTIONS) set them
            if not opts.hasName(name):
                opts[name] = value
        self.fine_smoother = _choice(opts, "springsim_fine_smoother", ("sor", "gamg"))
        self.springsim_pc = _choice(opts, "springsim_pc", SPRINGSIM_PCS)
        self.insertion = _choice(opts, "springsim_insertion", ("direct", "petsc"))
        #: the preconditioner is springsim's smoothed aggregation (no -pc_type option and no other pc_type given)
        self.use_sa = self.springsim_pc == "sa" and pc_type is None and not opts.hasName("pc_type")
        sa_smoother = _choice(opts, "springsim_sa_smoother", SMOOTHERS)
        self._sa = SmoothedAggregation(PETSc, self.comm, smoother=sa_smoother) if self.use_sa else None
        self._sa_whole = True  # kept levels serve a matrix of the same coefficients whole (until that goes stale)
        self._coefficients = None  # (a, b) of the last assembly
        try:
            self.pc_reuse = int(opts.getString("springsim_pc_reuse", SPRINGSIM_OPTIONS["springsim_pc_reuse"]))
        except ValueError:
            self.pc_reuse = 0
        if self.pc_reuse < 1:
            raise SceneError("petsc_options", f"-springsim_pc_reuse must be an integer >= 1, got "
                                              f"{opts.getString('springsim_pc_reuse')!r:.40}")
        #: the user set a level smoother: the finest level keeps it
        self._user_smoother = any(opts.hasName(k) for k in ("mg_levels_ksp_type", "mg_levels_pc_type"))
        # (ksp, ksp type, baseline iterations, solves served, user max_it, springsim's levels?, the (a, b) of the
        # matrix it was built for) of a kept KSP
        self._kept = None
        #: preconditioner builds, re-set-ups with a kept interpolation, kept ones found stale, and (springsim's
        #: levels) kept ones whose coarse operators were recomputed for a matrix of other coefficients
        self.pc_stats = dict(builds=0, reuses=0, stale=0, coarse_updates=0)
        #: ghost scatters forward (owners to ghosts) and in reverse (ghost rows added to their owners), assemblies
        self.comm_counts = dict(forward_scatters=0, reverse_scatters=0, assemblies=0)
        self._offproc_blocks = 0  # 3x3 blocks of the local matrix in ghost rows (sent to their owners)

        # local arrays (owned, ghosts, fixed); the fixed rows are constant
        self.q_loc = np.array(p.pair_model.particle_q)
        self.v_loc = np.array(p.pair_model.particle_qd)
        self.v_loc[p.n_local_free:] = 0.0
        self.f_loc = np.zeros_like(self.q_loc)
        self.g_loc = np.array(self.q_loc)   # damping geometry (owned, ghosts; fixed rows constant)
        self.q0_loc = np.array(self.q_loc)  # start positions of energy-momentum steps
        self.pair_terms = [t for t in make_force_terms(p.pair_model, kernels=force_kernels) if t.pairwise]
        self.particle_terms = [t for t in make_force_terms(p.particle_model, kernels=force_kernels) if not t.pairwise]
        self.terms = self.pair_terms + self.particle_terms
        self.mass = np.array(p.pair_model.particle_mass[:p.n_own])
        #: per-particle terms over this rank's block of the fixed particles (their constant energy)
        self.fixed_terms = [t for t in make_force_terms(scene.fixed_model, kernels="numpy", skip_fixed=False)
                            if not t.pairwise]
        self.particle_mass = self.mass
        self.fixed = np.zeros(0, dtype=np.int64)  # no rank owns a fixed particle
        self.root = 0
        self.is_root = self.rank == self.root
        self._last_assembly_s = 0.0

        # PETSc vectors and the ghost scatter
        own3, F3, nlf = 3 * p.n_own, 3 * self.free_count, p.n_local_free
        self.x = PETSc.Vec().createMPI((own3, F3), bsize=3, comm=self.comm)
        self.b, self.w = self.x.duplicate(), self.x.duplicate()
        self.loc = PETSc.Vec().createSeq(3 * nlf, bsize=3, comm=PETSc.COMM_SELF)
        gidx = (3 * p.local_to_free[:nlf, None] + np.arange(3)).ravel().astype(PETSc.IntType)
        is_g = PETSc.IS().createGeneral(gidx, comm=PETSc.COMM_SELF)
        is_l = PETSc.IS().createStride(3 * nlf, 0, 1, comm=PETSc.COMM_SELF)
        self.scatter = PETSc.Scatter().create(self.x, is_g, self.loc, is_l)

        # local assembler: owned and ghost particles free, mass on the owned diagonal only
        mass = np.array(p.pair_model.particle_mass)
        mass[p.n_own:] = 0.0
        self.asm = SystemAssembler(dataclasses.replace(p.pair_model, particle_mass=mass),
                                   self.pair_terms + self.particle_terms)
        self.lgmap = PETSc.LGMap().create(p.local_to_free[:nlf].astype(PETSc.IntType), bsize=3, comm=self.comm)

        # the matrix, preallocated exactly from the global pattern of the owned rows
        indptr, cols = self._owned_row_pattern()
        self._pattern = (indptr, cols) if self.insertion == "direct" else None  # block level, for the direct insertion
        sptr, scols = _scalar_csr(indptr, cols)
        A = PETSc.Mat().create(comm=self.comm)
        A.setSizes(((own3, F3), (own3, F3)), bsize=3)
        A.setType(PETSc.Mat.Type.AIJ)
        A.setPreallocationCSR((sptr.astype(PETSc.IntType), scols.astype(PETSc.IntType), np.zeros(scols.size)))
        A.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, True)
        A.setLGMap(self.lgmap, self.lgmap)
        self.A = A
        self._local_csr = None
        self._direct = None  # the direct insertion, after the first assembly ("-springsim_insertion")
        self.symmetric = True
        self.timings = dict(exchange_s=0.0, force_s=0.0, assembly_s=0.0, insert_s=0.0, setup_s=0.0, solve_s=0.0)
        # what the root needs to gather frames: every rank's owned ids in system order, and the fixed particles
        own_ids = self.mpi.gather(np.asarray(p.local_particles[:p.n_own], dtype=np.int64), root=self.root)
        fixed = self.mpi.gather((scene.fixed_ids, np.asarray(scene.fixed_model.particle_q)), root=self.root)
        #: On the root: the free particles' ids in the system's order (block row k first); None elsewhere.
        self.system_particles = np.concatenate(own_ids) if self.is_root else None
        self._fixed_ids = np.concatenate([f[0] for f in fixed]) if self.is_root else None
        self._fixed_q = np.concatenate([f[1] for f in fixed]).reshape(-1, 3) if self.is_root else None
        del own_ids, fixed

    def _owned_row_pattern(self) -> tuple[np.ndarray, np.ndarray]:
        """The block pattern of the owned rows from the local pairs (:func:`part_pattern`). Collective."""
        return part_pattern(self.part, self.free_count, self.mpi)[:2]

    def initial_state(self):
        """This rank's state arrays at the start: the owned particles' positions [m] and velocities [m/s] (copies).

        Returns
        -------
        q, qd : ndarray, shape (n_own, 3)
        """
        m = self.part.particle_model
        return np.array(m.particle_q, dtype=np.float64), np.array(m.particle_qd, dtype=np.float64)

    def energy_start(self, q_own, qd_own) -> dict:
        """What the energy bound needs of the whole scene at the start, summed over every rank (collective).

        Pairs between two fixed particles are in no rank's part: their constant energy is left out.

        Parameters
        ----------
        q_own, qd_own : ndarray, shape (n_own, 3)
            This rank's owned positions [m] and velocities [m/s].

        Returns
        -------
        dict
            ``kinetic`` [J]; ``parts``: term name -> potential energy [J] (fixed particles included);
            ``floor``: the sum of the finite potential floors [J]; ``unbounded``: names of the terms without one;
            ``mass`` [kg] of every particle; ``extent`` [m], the diagonal of the bounding box of every particle;
            ``fixed_unbounded`` [J], the unbounded terms' energy of the fixed particles.
        """
        self.exchange(q_own, qd_own)
        n = self.part.n_own
        fq = np.asarray(self.scene.fixed_model.particle_q)
        parts, floors, fixed_unb = {}, {}, 0.0
        for t, q in ([(t, self.q_loc) for t in self.pair_terms] + [(t, self.q_loc[:n]) for t in self.particle_terms]
                     + [(t, fq) for t in self.fixed_terms]):
            parts[t.name] = parts.get(t.name, 0.0) + float(t.potential_energy(q))
            floors[t.name] = floors.get(t.name, 0.0) + float(t.potential_floor())
            if q is fq and not np.isfinite(t.potential_floor()):
                fixed_unb += float(t.potential_energy(q))
        pts = np.concatenate([np.asarray(q_own).reshape(-1, 3), fq])
        box = np.concatenate([pts.min(axis=0), -pts.max(axis=0)]) if pts.size else np.full(6, np.inf)
        box = np.ascontiguousarray(box, dtype=np.float64)
        self.mpi.Allreduce(self.MPI.IN_PLACE, box, op=self.MPI.MIN)
        local = dict(kinetic=self._local_kinetic(qd_own),
                     mass=float(self.mass.sum() + np.sum(self.scene.fixed_model.particle_mass)),
                     fixed_unbounded=fixed_unb, parts=parts, floors=floors)
        every = self.mpi.allgather(local)
        out = {k: float(sum(e[k] for e in every)) for k in ("kinetic", "mass", "fixed_unbounded")}
        names = sorted({k for e in every for k in e["parts"]})
        out["parts"] = {k: float(sum(e["parts"].get(k, 0.0) for e in every)) for k in names}
        fl = {k: float(sum(e["floors"].get(k, 0.0) for e in every)) for k in names}
        out["floor"] = float(sum(v for v in fl.values() if np.isfinite(v)))
        out["unbounded"] = [k for k in names if not np.isfinite(fl[k])]
        out["extent"] = float(np.linalg.norm(-box[3:] - box[:3])) if np.all(np.isfinite(box)) else 0.0
        return out

    def frame_energy(self, q_own, qd_own) -> float:
        """Kinetic plus potential energy [J] of the whole scene at a state, but the constant energy of pairs between
        fixed particles (collective); the energy-growth check compares frames with it.

        Parameters
        ----------
        q_own, qd_own : ndarray, shape (n_own, 3)
            This rank's owned positions [m] and velocities [m/s].

        Returns
        -------
        float
            The energy [J], the same on every rank.
        """
        self.exchange(q_own)
        fq = np.asarray(self.scene.fixed_model.particle_q)
        local = (self._local_potential(self.q_loc) + self._local_kinetic(qd_own)
                 + sum(float(t.potential_energy(fq)) for t in self.fixed_terms if t.conservative))
        return self.sum(local)

    # -- options ------------------------------------------------------------------------------------------------
    def insert_options(self, options) -> None:
        """Insert ``options`` into PETSc's options database.

        Parameters
        ----------
        options : str or dict
            A string of ``-name value`` pairs (``"-ksp_type gmres"``), or a mapping name -> value (a value of
            None or True gives a flag).
        """
        if isinstance(options, dict):
            text = " ".join(f"-{str(k).lstrip('-')} {'' if v is None or v is True else v}" for k, v in options.items())
        else:
            text = " ".join(shlex.split(str(options)))
        self.PETSc.Options().insertString(text)

    # -- the System interface: set-up and reductions -------------------------------------------------------------
    def metadata(self) -> dict:
        return {"backend": "petsc", "ranks": self.size, "partitioner": self.partitioner,
                "preconditioner": "springsim-sa" if self.use_sa else self.pc_type}

    def local_state(self, q, qd):
        own = self.part.local_particles[:self.part.n_own]
        return np.array(q[own], dtype=np.float64), np.array(qd[own], dtype=np.float64)

    def gather_state(self, q, qd):
        return self.gather_full(q, qd, root=self.root)

    @property
    def linear_rtol(self) -> float:
        return self.rtol

    def default_jacobian(self) -> str:
        return "spd"  # CG + GAMG, PETSc's default here, needs a symmetric positive definite matrix

    def sum(self, value):
        return float(self.mpi.allreduce(float(value)))

    def max(self, value):
        return float(self.mpi.allreduce(float(value), op=self.MPI.MAX))

    def all(self, flag):
        return bool(self.mpi.allreduce(bool(flag), op=self.MPI.LAND))

    def free_rows(self, x):
        return x  # every owned particle is free

    @property
    def free_dof_count(self) -> int:
        return 3 * self.free_count

    def gather(self, x):
        return x.reshape(-1)

    def scatter_add(self, target, dx, scale=1.0):
        target += scale * dx.reshape(-1, 3)

    # -- ghosts, forces ------------------------------------------------------------------------------------------
    def _exchange_into(self, own: np.ndarray, loc: np.ndarray) -> None:
        """Fill the free local rows of ``loc`` (owned and ghosts) from the owned arrays ``own`` of every rank."""
        nlf = self.part.n_local_free
        self.x.array[:] = own.ravel()
        self.scatter.scatter(self.x, self.loc, addv=self.PETSc.InsertMode.INSERT_VALUES,
                             mode=self.PETSc.ScatterMode.FORWARD)
        loc[:nlf] = self.loc.array.reshape(-1, 3)
        self.comm_counts["forward_scatters"] += 1

    def exchange(self, q_own: np.ndarray, v_own: np.ndarray | None = None, *, geometry=None, q_start=None) -> None:
        """Fill the local positions and velocities (owned and ghosts) from the owned arrays of every rank; also
        the local damping geometry and start positions when given. Collective.

        Parameters
        ----------
        q_own : ndarray, shape (n_own, 3)
            This rank's owned positions [m].
        v_own : ndarray, shape (n_own, 3), optional
            Its owned velocities [m/s].
        geometry : ndarray, shape (n_own, 3), optional
            Owned positions of the frozen damping geometry [m].
        q_start : ndarray, shape (n_own, 3), optional
            Owned start positions of an energy-momentum step [m].
        """
        t0 = time.perf_counter()
        self._exchange_into(q_own, self.q_loc)
        if v_own is not None:
            self._exchange_into(v_own, self.v_loc)
        for own, loc in ((geometry, self.g_loc), (q_start, self.q0_loc)):
            if own is not None:
                self._exchange_into(own, loc)
        self.timings["exchange_s"] += time.perf_counter() - t0

    def _reverse_add(self, f_loc: np.ndarray, out: np.ndarray) -> np.ndarray:
        """``out`` (owned) = the local rows of ``f_loc``, ghost rows added to their owners."""
        self.loc.array[:] = f_loc[:self.part.n_local_free].ravel()
        self.w.set(0.0)
        self.scatter.scatter(self.loc, self.w, addv=self.PETSc.InsertMode.ADD_VALUES,
                             mode=self.PETSc.ScatterMode.REVERSE)
        out[...] = self.w.array.reshape(-1, 3)
        self.comm_counts["reverse_scatters"] += 1
        return out

    def forces(self, q_own, v_own, out=None, *, damping_geometry=None, exchange: bool = True):
        """Total force [N] on the owned particles at the global state whose owned parts are given. Collective.

        Parameters
        ----------
        q_own, v_own : ndarray, shape (n_own, 3)
            This rank's owned positions [m] and velocities [m/s].
        out : ndarray, shape (n_own, 3), optional
            Receives the force (default: a new array).
        damping_geometry : ndarray, shape (n_own, 3), optional
            Owned positions at which the dissipative terms take their directions.
        exchange : bool
            Exchange the ghosts first (False: the local arrays were filled from these arrays already).

        Returns
        -------
        ndarray, shape (n_own, 3)
            ``out``.
        """
        if exchange:
            self.exchange(q_own, v_own, geometry=damping_geometry)
        t0 = time.perf_counter()
        n, f = self.part.n_own, self.f_loc
        g = None if damping_geometry is None else self.g_loc
        f.fill(0.0)
        for t in self.pair_terms:
            t.eval_force(self.q_loc, self.v_loc, f, damping_geometry=g)
        for t in self.particle_terms:
            t.eval_force(self.q_loc[:n], self.v_loc[:n], f[:n], damping_geometry=None if g is None else g[:n])
        out = np.empty((n, 3)) if out is None else out
        self._reverse_add(f, out)
        self.timings["force_s"] += time.perf_counter() - t0
        return out

    def forces_discrete(self, q0, q1, qd, out):
        self.exchange(q1, qd, q_start=q0)
        n, f = self.part.n_own, self.f_loc
        f.fill(0.0)
        for t in self.pair_terms:
            t.eval_force_discrete(self.q0_loc, self.q_loc, self.v_loc, f)
        for t in self.particle_terms:
            t.eval_force_discrete(self.q0_loc[:n], self.q_loc[:n], self.v_loc[:n], f[:n])
        return self._reverse_add(f, out)

    def curvature_forces(self, q0, q1, out):
        curved = [t for t in self.pair_terms if t.curved]
        if self.all(not curved):  # no rank has a curved term
            return None
        self.exchange(q1, q_start=q0)
        f = self.f_loc
        f.fill(0.0)
        for t in curved:
            t.curvature_remainder(self.q0_loc, self.q_loc, f)
        return self._reverse_add(f, out)

    def _local_kinetic(self, qd_own) -> float:
        return 0.5 * float(np.sum(self.mass[:, None] * np.asarray(qd_own) ** 2))

    def _local_potential(self, q_loc) -> float:
        n = self.part.n_own
        local = sum(float(t.potential_energy(q_loc)) for t in self.pair_terms if t.conservative)
        return local + sum(float(t.potential_energy(q_loc[:n])) for t in self.particle_terms if t.conservative)

    def _local_dissipation(self, g_loc, v_loc) -> float:
        n = self.part.n_own
        local = sum(float(t.dissipation(g_loc, v_loc)) for t in self.pair_terms if t.dissipative)
        return local + sum(float(t.dissipation(g_loc[:n], v_loc[:n])) for t in self.particle_terms if t.dissipative)

    def potential_energy(self, q) -> float:
        self.exchange(q)
        return self.sum(self._local_potential(self.q_loc))

    def dissipation(self, geometry, qd) -> float:
        self.exchange(geometry, qd)
        return self.sum(self._local_dissipation(self.q_loc, self.v_loc))

    def stage_terms(self, q, qd, out, geometry):
        """One ghost exchange for the forces and both potentials, and one reduction for the potentials."""
        self.exchange(q, qd, geometry=geometry)
        self.forces(q, qd, out, damping_geometry=geometry, exchange=False)
        both = self.mpi.allreduce(np.array([self._local_potential(self.q_loc),
                                            self._local_dissipation(self.g_loc, self.v_loc)]))
        return float(both[0]), float(both[1])

    # -- assembly --------------------------------------------------------------------------------------------------
    def assemble(self, q_own, v_own, a: float, b: float, mode: str, *, q_start=None, damping_geometry=None):
        """``A = M - a dF/dq - b dF/dqd`` at the given state, into :attr:`A` (the PETSc matrix). Collective.

        Parameters
        ----------
        q_own, v_own : ndarray, shape (n_own, 3)
            This rank's owned positions [m] and velocities [m/s].
        a, b : float
            Coefficients of the position and velocity Jacobians [s^2, s].
        mode : str
            Jacobian mode (:data:`springsim.forces.JACOBIAN_MODES`).
        q_start : ndarray, shape (n_own, 3), optional
            Owned start positions: the energy-momentum force's Jacobian over the step.
        damping_geometry : ndarray, shape (n_own, 3), optional
            Owned positions at which the dissipative terms take their geometry.

        Returns
        -------
        operator
            ``A @ x`` on this rank's DOF vectors (the solve uses :attr:`A` itself).
        """
        self.exchange(q_own, v_own, geometry=damping_geometry, q_start=q_start)
        t0 = time.perf_counter()
        m = self.asm.assemble(self.q_loc, self.v_loc, a, b, mode, q_start=None if q_start is None else self.q0_loc,
                              damping_geometry=None if damping_geometry is None else self.g_loc)
        t1 = time.perf_counter()
        bsr = m.bsr
        A = self.A
        if self._direct is not None:
            self._direct.insert(A, bsr.data)
        else:
            first = self._local_csr is None
            if first:  # the local pattern never changes
                self._local_csr = (bsr.indptr.astype(self.PETSc.IntType), bsr.indices.astype(self.PETSc.IntType))
                self._offproc_blocks = int(bsr.indptr[-1] - bsr.indptr[self.part.n_own])
            self._petsc_insert(bsr.data)
            if first and self.insertion == "direct":
                self._direct = self._direct_insertion(bsr)
        self.symmetric = self.all(bool(m.symmetric))
        self._positions = q_own
        self._coefficients = (float(a), float(b))
        self.comm_counts["assemblies"] += 1
        self._last_assembly_s = time.perf_counter() - t0
        self.timings["assembly_s"] += t1 - t0
        self.timings["insert_s"] += time.perf_counter() - t1
        return _Operator(self)

    def _direct_insertion(self, bsr):
        """A :class:`~springsim.distributed._aij.DirectInsertion` for :attr:`A` when it reproduces the insertion just
        done by PETSc on every rank (:meth:`~springsim.distributed._aij.DirectInsertion.matches`; :attr:`A` then holds
        its result), else None, with PETSc's insertion redone (it stays). Collective."""
        from ._aij import DirectInsertion

        p = self.part
        try:
            direct = DirectInsertion(self.PETSc, self.A, self._pattern, bsr.indptr, bsr.indices,
                                     p.local_to_free[:p.n_local_free], p.n_own, _petsc_library())
        except (ValueError, OSError, AttributeError, self.PETSc.Error):
            direct = None
        self._pattern = None
        if not self.all(direct is not None):
            return None
        if direct.matches(self.A, bsr.data, self.mpi):
            return direct
        self._petsc_insert(bsr.data)  # PETSc's insertion again
        return None

    def _petsc_insert(self, data) -> None:
        """:attr:`A` = the local BSR matrix of values ``data`` by PETSc's ``MatSetValuesBlockedLocal`` (adding; the
        ghost rows go to their owners in the assembly). Collective."""
        self.A.zeroEntries()
        self.A.setValuesBlockedLocalCSR(*self._local_csr, data.reshape(-1), addv=self.PETSc.InsertMode.ADD_VALUES)
        self.A.assemble()

    def communication(self) -> dict:
        """This rank's share of the communication so far, counted from the ghost scatter's and the matrix's sizes.

        Not collective. A forward ghost scatter receives the rank's ghost rows (3 doubles per ghost particle);
        a reverse one sends as many; an assembly sends the 3x3 blocks of the ghost rows to their owners (72 bytes
        of values per block, their indices not counted).

        Returns
        -------
        dict
            ``ghosts`` (ghost particles of this rank), ``offproc_blocks`` (blocks in ghost rows per assembly),
            :attr:`comm_counts`, and the bytes moved by the ghost scatters (``ghost_bytes``) and by the
            off-process matrix entries (``offproc_bytes``) over them.
        """
        c = self.comm_counts
        ghost_row = 24 * self.part.n_ghost
        return dict(ghosts=int(self.part.n_ghost), offproc_blocks=self._offproc_blocks, **c,
                    ghost_bytes=ghost_row * (c["forward_scatters"] + c["reverse_scatters"]),
                    offproc_bytes=72 * self._offproc_blocks * c["assemblies"])

    def linearize_at(self, q_own):
        """Record the springs' geometry at this state for the ``mixed`` mode's next assembly. Collective.

        Parameters
        ----------
        q_own : ndarray, shape (n_own, 3)
            This rank's owned positions [m].
        """
        self.exchange(q_own)
        self.asm.linearize_at(self.q_loc)

    @property
    def last_assembly_s(self) -> float:
        return self._last_assembly_s

    def precision_loss(self, A=None) -> float:
        """Relative precision to which the assembled matrix holds the masses, max over ranks:
        ``u max_k A_kk / m_k`` over the diagonal entries of the free DOFs (ghost contributions included).

        The serial :meth:`~springsim.assembly.SystemAssembler.precision_loss` takes the largest entry of each
        3x3 diagonal block; for the positive semi-definite blocks of the ``spd`` mode that is a diagonal entry,
        so the two agree there (for the other modes this one can be smaller by the blocks' off-diagonal/diagonal
        ratio).

        Parameters
        ----------
        A : object, optional
            Ignored: the last assembled matrix is measured.

        Returns
        -------
        float
            The relative precision (0 for a matrix that holds the masses exactly).
        """
        d = self.A.getDiagonal()
        local = 0.0
        if self.part.n_own:
            ratio = np.abs(d.array.reshape(-1, 3)).max(axis=1) / self.mass
            local = float(np.finfo(np.float64).eps * ratio.max())
        d.destroy()
        return float(self.mpi.allreduce(local, op=self.MPI.MAX))

    # -- solve -----------------------------------------------------------------------------------------------------
    def _ksp(self, ksp_type: str, maxiter: int, x0_nonzero: bool, rtol: float, sa_levels: bool = False):
        """A KSP on :attr:`A`; with ``sa_levels`` its PC is the PCMG over :attr:`_sa`'s levels (built)."""
        PETSc = self.PETSc
        ksp = PETSc.KSP().create(comm=self.comm)
        ksp.setOperators(self.A)
        ksp.setType(ksp_type)
        if sa_levels:
            self._sa.configure(ksp.getPC())
        else:
            ksp.getPC().setType(self.pc_type)
        ksp.setTolerances(rtol=rtol, atol=self.atol, max_it=maxiter)
        ksp.setNormType(PETSc.KSP.NormType.UNPRECONDITIONED)
        ksp.setInitialGuessNonzero(x0_nonzero)
        ksp.setFromOptions()
        return ksp

    def _set_fine_smoother(self, ksp) -> None:
        """After ``ksp.setUp()``: one local symmetric SOR sweep as the finest level's smoother (see
        :data:`SPRINGSIM_OPTIONS`), unless the user chose smoothers or another preconditioner."""
        pc = ksp.getPC()
        if self.fine_smoother != "sor" or self._user_smoother or pc.getType() != "gamg":
            return
        levels = pc.getMGLevels()
        if levels < 2:
            return
        fine = pc.getMGSmoother(levels - 1)
        opts, name = self.PETSc.Options(), f"mg_levels_{levels - 1}_"
        if opts.hasName(name + "ksp_type") or opts.hasName(name + "pc_type"):
            return
        fine.setType("richardson")
        fine.getPC().setType("sor")
        fine.setTolerances(max_it=1)

    def _build_sa(self, kind: str) -> bool:
        """Build :attr:`_sa`'s levels for :attr:`A` when springsim's smoothed aggregation applies (a symmetric
        matrix, CG); False when it does not or its set-up broke down (the matrix is not positive definite: GAMG
        then). Collective."""
        if not (self.use_sa and self.symmetric and kind == "cg"):
            return False
        try:
            self._sa.build(self.A, rigid_body_modes(np.asarray(self._positions)))
        except ArithmeticError:  # the same on every rank: the estimate's inner products are all-reduced
            self._sa.forget()
            return False
        return True

    def _near_null_space(self):
        coords = self.x.duplicate()
        coords.array[:] = np.asarray(self._positions).ravel()
        ns = self.PETSc.NullSpace().createRigidBody(coords)
        self.A.setNearNullSpace(ns)
        return ns

    def _drop_kept(self) -> None:
        if self._kept is not None:
            self._kept[0].destroy()
            self._kept = None

    def solve(self, A, rhs_own: np.ndarray, *, x0: np.ndarray | None = None,
              rtol: float | None = None) -> LinearSolveResult:
        """Solve ``A x = rhs`` to the relative residual ``rtol``; see the module docstring for the defaults, checks
        and retries. Collective.

        Parameters
        ----------
        A : object
            What :meth:`assemble` returned (the last assembled matrix is solved).
        rhs_own : ndarray, shape (3 n_own,)
            This rank's part of the right-hand side.
        x0 : ndarray, shape (3 n_own,), optional
            Initial guess.
        rtol : float, optional
            Relative tolerance on the true residual (default :attr:`rtol`).

        Returns
        -------
        LinearSolveResult
            This rank's part of the solution, with the iterations, residual, times and any retry or failure.
        """
        rtol = self.rtol if rtol is None else float(rtol)
        b, x = self.b, self.x
        b.array[:] = rhs_own.ravel()
        bn = b.norm()
        if bn == 0.0:
            return LinearSolveResult(np.zeros(rhs_own.size), True, 0, 0.0, "petsc")
        first = self.ksp_type or ("cg" if self.symmetric else "gmres")
        kept = self._kept
        reuse = kept is not None and kept[1] == first and kept[3] < self.pc_reuse
        if not reuse:
            self._drop_kept()
        # (preconditioner, Krylov method, iteration limit): a kept one first, then fresh ones. springsim's levels are
        # kept whole for a matrix of the same coefficients until that once goes stale, and with the coarse operators
        # recomputed otherwise ("kept", "whole", "coarse", "fresh")
        attempts = []
        if reuse and kept[5]:
            if kept[6] == self._coefficients and self._sa_whole:
                attempts.append(("whole", first, 0))
            attempts.append(("coarse", first, 0))
        elif reuse:
            attempts.append(("kept", first, 0))
        attempts += [("fresh", first, self.maxiter), ("fresh", "gmres", 5 * self.maxiter)]
        its, setup, solve = 0, 0.0, 0.0
        fallback, method, rel, reason = None, "", float("inf"), 0
        target = max(rtol, self.atol / bn)
        ns, sa_built = None, False
        for k, (mode, kind, maxiter) in enumerate(attempts):
            if k == 0:
                x.array[:] = 0.0 if x0 is None else np.asarray(x0).ravel()
            use_kept = mode != "fresh"
            t0 = time.perf_counter()
            if use_kept:
                ksp, _, baseline, served, user_max, _, _ = kept
                cap = min(int(REUSE_FACTOR * baseline + REUSE_SLACK), user_max)
                ksp.setTolerances(rtol=rtol, atol=self.atol, max_it=cap)
                ksp.setInitialGuessNonzero(k > 0 or x0 is not None)
                if mode == "coarse":
                    self._sa.galerkin()  # the coarse operators of the new matrix, the prolongators kept
                    self.pc_stats["coarse_updates"] += 1
                ksp.setOperators(self.A)  # new values: smoothers (and GAMG's coarse operators) set up again
                self.pc_stats["reuses"] += 1
            else:
                self._drop_kept()
                sa_built = self._build_sa(kind)  # the GMRES retry gets GAMG
                if not sa_built and ns is None:
                    ns = self._near_null_space()
                ksp = self._ksp(kind, maxiter, x0_nonzero=(k > 0 or x0 is not None), rtol=rtol, sa_levels=sa_built)
                self.pc_stats["builds"] += 1
            ksp.setUp()
            if not use_kept:
                self._set_fine_smoother(ksp)
                ksp.setUp()
            t1 = time.perf_counter()
            ksp.solve(b, x)
            t2 = time.perf_counter()
            setup += t1 - t0
            solve += t2 - t1
            k_its = ksp.getIterationNumber()
            its += k_its
            reason = int(ksp.getConvergedReason())
            method = f"petsc {ksp.getType()}+{ksp.getPC().getType()}"
            self.A.mult(x, self.w)
            self.w.aypx(-1.0, b)              # w = b - A x
            rel = self.w.norm() / bn
            # 1 % slack: Krylov recurrences track the true residual only to round-off
            ok = reason > 0 and np.isfinite(rel) and rel <= 1.01 * target
            if use_kept:
                if ok:
                    kept[3] += 1
                    break
                self.pc_stats["stale"] += 1  # the next attempt continues from the iterate
                if mode == "whole":
                    self._sa_whole = False  # this run's matrices move too far between solves: recompute from now on
                else:
                    self._drop_kept()
                continue
            if ok and self.pc_reuse > 1 and kind == first:
                self._kept = [ksp, kind, max(k_its, 1), 1, ksp.getTolerances()[3], bool(sa_built), self._coefficients]
            else:
                ksp.destroy()
            if ok:
                break
            if fallback is None:
                fallback = (f"{method}: {'not converged' if reason <= 0 else 'true residual above tolerance'} "
                            f"(reason {reason}, relative residual {rel:.2e} after {k_its} iterations)")
        if ns is not None:
            ns.destroy()
        self.timings["setup_s"] += setup
        self.timings["solve_s"] += solve
        ok = reason > 0 and np.isfinite(rel) and rel <= 1.01 * target
        failure = None if ok else (f"{method}: relative residual {rel:.2e} above rtol {rtol:g} "
                                   f"(PETSc reason {reason}) after the retry")
        return LinearSolveResult(x.array.copy(), ok, its, float(rel),
                                 method + ("" if fallback is None else " (retry)"), setup, solve, failure, fallback)

    # -- gathering -------------------------------------------------------------------------------------------------
    def gather_full(self, q_own: np.ndarray, v_own: np.ndarray, root: int = 0):
        """Full positions and velocities on ``root``: the owned arrays of every rank in rank order are the free
        particles in the system's order; fixed particles from the model. Collective.

        Parameters
        ----------
        q_own, v_own : ndarray, shape (n_own, 3)
            This rank's owned positions [m] and velocities [m/s].
        root : int
            The rank that receives them.

        Returns
        -------
        q, v : ndarray, shape (N, 3), or None
            On ``root``; None on the other ranks.
        """
        counts = self.mpi.gather(3 * q_own.shape[0], root=root)
        out = []
        for own, init in ((q_own, True), (v_own, False)):
            if self.rank == root:
                buf = np.empty(3 * self.free_count)
                self.mpi.Gatherv(np.ascontiguousarray(own).ravel(), (buf, counts), root=root)
                full = np.zeros((self.scene.particle_count, 3))
                if init:
                    full[self._fixed_ids] = self._fixed_q
                full[self.system_particles] = buf.reshape(-1, 3)
                out.append(full)
            else:
                self.mpi.Gatherv(np.ascontiguousarray(own).ravel(), None, root=root)
                out.append(None)
        return out[0], out[1]

    def gather_matrix(self, root: int = 0):
        """The assembled matrix as a scipy CSR on ``root``, for checks on small systems. Collective.

        Parameters
        ----------
        root : int
            The rank that receives it.

        Returns
        -------
        scipy.sparse.csr_matrix or None
            The matrix over all free DOFs (system order) on ``root``; None elsewhere.
        """
        import scipy.sparse as sp

        indptr, indices, data = self.A.getValuesCSR()
        r0, _ = self.A.getOwnershipRange()
        rows = np.repeat(np.arange(r0, r0 + indptr.size - 1), np.diff(indptr))
        parts = self.mpi.gather((rows, np.asarray(indices), np.asarray(data)), root=root)
        if self.rank != root:
            return None
        n = 3 * self.free_count
        r, c, v = (np.concatenate([p[i] for p in parts]) for i in range(3))
        return sp.csr_matrix((v, (r, c)), shape=(n, n))

    def destroy(self) -> None:
        """Free the PETSc objects (matrix, vectors, scatters, kept preconditioner); the system is unusable after."""
        self._drop_kept()
        if self._sa is not None:
            self._sa.destroy()
        for obj in (self.A, self.x, self.b, self.w, self.loc, self.scatter, self.lgmap):
            obj.destroy()
