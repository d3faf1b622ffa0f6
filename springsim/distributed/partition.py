"""Partition of a model across MPI ranks: owned particles, owned pairs, ghosts and the local models.

The unknowns of the distributed system are the free particles, by default in the order of the serial
system (:attr:`springsim.assembly.SystemAssembler.free`: free particle ``k`` is block row ``k``), split
into contiguous blocks, one per rank (:func:`contiguous_offsets`). So the distributed matrix, gathered, is
the serial matrix in the same order, and frames gathered in rank order are the free particles in order.
A graph partition renumbers them (``order``, :func:`system_order`) so that each rank's block is one of its
parts; the gathered matrix is then the serial one with rows and columns permuted alike.

A pair (a spring, a gravitational pair) belongs to the rank that owns its first particle, or its second
when the first is fixed; pairs between two fixed particles are dropped (they never move anything). A
rank's **local particles** are, in this order: its owned free particles, the **ghosts** (free particles of
other ranks that its pairs touch) and the fixed particles its pairs touch. Two local models describe them:

* the **pair model**: every local particle, the owned pairs (re-indexed), no gravity and none of the data of
  the per-particle terms (drag, ...: their declared defaults). The pairwise force terms
  (:attr:`springsim.forces.ForceTerm.pairwise`) are built from it; their forces and Jacobian blocks on
  ghost rows belong to the ghosts' owners and are sent there (forces by a reverse scatter that adds, blocks
  as off-process COO entries).
* the **particle model**: the owned particles only, no pairs. The per-particle terms (gravity, drag, ...)
  are built from it, so each particle's own force is evaluated once, by its owner. Owned particles come
  first in the local order, so its indices are local indices too.

Both are built from the terms' declared data (:attr:`springsim.forces.ForceTerm.data`): per-particle arrays
are sliced by particle, per-pair arrays by pair, per-model arrays kept, so a new term reaches every rank.
Everything here is plain numpy, so the partition can be built and checked without MPI.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..forces._data import data_terms
from ..model import Model

__all__ = ["PARTITIONERS", "contiguous_offsets", "pair_families", "system_order", "LocalPart", "partition",
           "local_part"]

#: How the free particles are split over the ranks: ``contiguous`` (equal blocks of the serial order), or a
#: PETSc ``MatPartitioning`` type that partitions the particle graph (``ptscotch``, ``parmetis``: whichever the
#: PETSc build has; Debian's has PT-Scotch).
PARTITIONERS = ("contiguous", "ptscotch", "parmetis")


def contiguous_offsets(count: int, size: int) -> np.ndarray:
    """Offsets (size + 1,) of ``size`` contiguous blocks of ``count`` items, sizes differing by at most one.

    Parameters
    ----------
    count : int
        Number of items (free particles).
    size : int
        Number of blocks (ranks), >= 1.

    Returns
    -------
    ndarray of int64, shape (size + 1,)
        Block ``r`` is ``offsets[r] .. offsets[r+1]``; the first ``count % size`` blocks have one item more.

    Raises
    ------
    ValueError
        ``size`` < 1.
    """
    if size < 1:
        raise ValueError(f"size must be >= 1, got {size}")
    base, extra = divmod(int(count), int(size))
    sizes = np.full(size, base, dtype=np.int64)
    sizes[:extra] += 1
    return np.concatenate([[0], np.cumsum(sizes)])


def pair_families(model: Model) -> dict[str, list[str]]:
    """The model's pair lists: ``{term: [array, ...]}`` for every term with a pair list in
    :attr:`~springsim.model.model.Model.terms`, its per-pair arrays in declared order after ``"indices"``. With the
    built-in terms: ``spring`` and ``gravitational``.

    Parameters
    ----------
    model : Model
        The model.

    Returns
    -------
    dict of str to list of str
        Term name -> ``["indices", <per-pair array>, ...]``.
    """
    specs = dict(data_terms())
    out = {}
    for term, data in model.terms.items():
        if "indices" in data:
            cls = specs.get(term)
            per_pair = [s.name for s in cls.data if s.per == "pair"] if cls is not None else [
                k for k, v in data.items() if k != "indices" and v.shape[:1] == data["indices"].shape[:1]]
            out[term] = ["indices"] + per_pair
    return out


@dataclass(eq=False)
class LocalPart:
    """One rank's share of a model (see the module docstring).

    Attributes
    ----------
    rank, size : int
        This rank and the number of ranks.
    offsets : ndarray (size + 1,)
        Owned free-index range of every rank: rank ``r`` owns ``offsets[r] .. offsets[r+1]``.
    local_particles : ndarray (L,)
        Global particle ids of the local particles: owned, ghosts, fixed.
    n_own, n_ghost : int
        Numbers of owned and of ghost particles.
    local_to_free : ndarray (L,)
        System block row of each local particle, -1 for fixed ones.
    order : ndarray (F,) or None
        The permutation of the free particles that numbers the system (None: the serial order).
    owned_pairs : dict
        Global indices of the owned pairs of each family (``spring``, ``gravitational``).
    pair_model, particle_model : Model
        The local models (module docstring).
    """

    rank: int
    size: int
    offsets: np.ndarray
    local_particles: np.ndarray
    n_own: int
    n_ghost: int
    local_to_free: np.ndarray
    owned_pairs: dict
    pair_model: Model
    particle_model: Model
    order: np.ndarray | None = None

    @property
    def lo(self) -> int:
        """First system block row (free index) this rank owns: ``offsets[rank]``."""
        return int(self.offsets[self.rank])

    @property
    def hi(self) -> int:
        """One past the last block row this rank owns: ``offsets[rank + 1]``."""
        return int(self.offsets[self.rank + 1])

    @property
    def n_local_free(self) -> int:
        """Owned plus ghost particles (the local rows the ghost exchange fills)."""
        return self.n_own + self.n_ghost


def _sub_model(model: Model, particles: np.ndarray, pairs: dict, *, keep_particle_terms: bool) -> Model:
    """The model restricted to ``particles`` (global ids, in local order) with the pairs ``pairs``
    ({term: global pair indices}, the others dropped), re-indexed, from the terms' declared data: per-particle
    arrays sliced by particle, per-pair arrays by pair, per-model arrays kept. Gravity and the data of the
    per-particle terms (those not :attr:`~springsim.forces.ForceTerm.pairwise`) only with
    ``keep_particle_terms`` (else their defaults: the terms are then absent)."""
    local = np.full(model.particle_count, -1, dtype=np.int64)
    local[particles] = np.arange(particles.size)
    kw = {name: np.array(getattr(model, name)[particles])
          for name in ("particle_q", "particle_qd", "particle_mass", "particle_radius", "particle_fixed")}
    registered = dict(data_terms())
    terms = {}
    for term, data in model.terms.items():
        cls = registered.get(term)
        if cls is None:
            continue  # no longer registered: no term would use it
        if not (keep_particle_terms or cls.pairwise):
            continue  # its declared defaults
        d = {}
        if "indices" in data:
            sel = pairs.get(term, np.zeros(0, dtype=np.int64))
            d["indices"] = local[data["indices"][sel]]
        for spec in cls.data:
            a = data[spec.name]
            d[spec.name] = (np.array(a[particles]) if spec.per == "particle" else
                            np.array(a[sel]) if spec.per == "pair" else np.array(a))
        terms[term] = d
    return Model(**kw, terms=terms, gravity=model.gravity if keep_particle_terms else 0.0, up_axis=model.up_axis,
                 pair_epsilon=model.pair_epsilon, metadata=dict(model.metadata))


def system_order(model: Model, order: np.ndarray | None = None) -> np.ndarray:
    """The free particles in the order of the distributed system's block rows: ``model.free_particles``, or
    ``model.free_particles[order]`` for a permutation ``order`` of them (a graph partition's numbering).

    Parameters
    ----------
    model : Model
        The model.
    order : array_like of int, shape (F,), optional
        A permutation of ``0 .. F-1``; default the serial order.

    Returns
    -------
    ndarray of int64, shape (F,)
        Global particle ids, block row ``k`` first.

    Raises
    ------
    ValueError
        ``order`` is not a permutation of the free particles.
    """
    free = model.free_particles
    if order is None:
        return free
    order = np.asarray(order, dtype=np.int64)
    if order.shape != free.shape or not np.array_equal(np.sort(order), np.arange(free.size)):
        raise ValueError(f"order must be a permutation of the {free.size} free particles")
    return free[order]


def partition(model: Model, size: int, rank: int, offsets: np.ndarray | None = None,
              order: np.ndarray | None = None) -> LocalPart:
    """Rank ``rank``'s part of ``model`` split over ``size`` ranks.

    Block row ``k`` of the system is free particle ``system_order(model, order)[k]`` (the serial order unless
    ``order``); rank ``r`` owns rows ``offsets[r] .. offsets[r+1]`` (equal contiguous blocks unless ``offsets``).

    Parameters
    ----------
    model : Model
        The whole model (the same on every rank).
    size : int
        Number of ranks.
    rank : int
        This rank, ``0 <= rank < size``.
    offsets : array_like of int, shape (size + 1,), optional
        Owned block-row ranges, rising from 0 to F; default :func:`contiguous_offsets`.
    order : array_like of int, shape (F,), optional
        Numbering of the free particles (:func:`system_order`); default the serial order.

    Returns
    -------
    LocalPart

    Raises
    ------
    ValueError
        ``rank`` out of range, invalid ``offsets`` or ``order``.
    """
    if not 0 <= rank < size:
        raise ValueError(f"rank must be in [0, {size}), got {rank}")
    free = system_order(model, order)
    offsets = contiguous_offsets(free.size, size) if offsets is None else np.asarray(offsets, dtype=np.int64)
    if offsets.shape != (size + 1,) or offsets[0] != 0 or offsets[-1] != free.size or np.any(np.diff(offsets) < 0):
        raise ValueError(f"offsets must rise from 0 to {free.size} in {size} blocks")
    free_index = np.full(model.particle_count, -1, dtype=np.int64)
    free_index[free] = np.arange(free.size)
    owner = np.full(model.particle_count, -1, dtype=np.int64)  # owning rank of each free particle
    owner[free] = np.searchsorted(offsets, np.arange(free.size), side="right") - 1
    return local_part(model, size, rank, offsets, free_index, owner,
                      order=None if order is None else np.asarray(order, dtype=np.int64))


def local_part(piece: Model, size: int, rank: int, offsets: np.ndarray, free_index: np.ndarray,
               owner: np.ndarray, *, ids: np.ndarray | None = None, order: np.ndarray | None = None) -> LocalPart:
    """Rank ``rank``'s :class:`LocalPart` from a ``piece`` of the model that holds at least its owned particles, its
    owned pairs and every particle they touch (the whole model, or what a rank built or received by itself).

    Parameters
    ----------
    piece : Model
        The piece: particles (in increasing global id) and pairs; the pairs owned by other ranks are left out.
    size : int
        Number of ranks.
    rank : int
        This rank.
    offsets : ndarray of int, shape (size + 1,)
        Owned block-row ranges of the ranks.
    free_index : ndarray of int, shape (piece.particle_count,)
        System block row of each particle of the piece, -1 for fixed ones.
    owner : ndarray of int, shape (piece.particle_count,)
        Owning rank of each particle of the piece, -1 for fixed ones.
    ids : ndarray of int, shape (piece.particle_count,), optional
        Global particle ids of the piece's particles (default: the piece is the whole model).
    order : ndarray of int, optional
        The graph partition's numbering, recorded in the result.

    Returns
    -------
    LocalPart
        Its ``local_particles`` are global ids; its ``owned_pairs`` index the piece's pair lists.
    """
    owned = np.flatnonzero(owner == rank)
    owned = owned[np.argsort(free_index[owned], kind="stable")]
    owned_pairs, touched = {}, [np.zeros(0, dtype=np.int64)]
    for prefix in pair_families(piece):
        ij = piece.terms[prefix]["indices"]
        first = np.where(owner[ij[:, 0]] >= 0, owner[ij[:, 0]], owner[ij[:, 1]]) if ij.size else np.zeros(0, int)
        sel = np.flatnonzero(first == rank)
        owned_pairs[prefix] = sel
        touched.append(ij[sel].ravel())
    touched = np.unique(np.concatenate(touched))
    is_owned = np.zeros(piece.particle_count, dtype=bool)
    is_owned[owned] = True
    others = touched[~is_owned[touched]]
    ghosts = others[~piece.particle_fixed[others]]
    ghosts = ghosts[np.argsort(free_index[ghosts], kind="stable")]
    fixed = others[piece.particle_fixed[others]]
    local = np.concatenate([owned, ghosts, fixed]).astype(np.int64)
    return LocalPart(rank=rank, size=size, offsets=offsets, local_particles=local if ids is None else ids[local],
                     n_own=int(owned.size), n_ghost=int(ghosts.size), local_to_free=free_index[local],
                     owned_pairs=owned_pairs,
                     pair_model=_sub_model(piece, local, owned_pairs, keep_particle_terms=False),
                     particle_model=_sub_model(piece, owned, {}, keep_particle_terms=True), order=order)
