"""Distributed scene construction: every rank builds, or receives, only its share of the model.

A :class:`ScenePart` is what a rank needs of a scene: its :class:`~springsim.distributed.partition.LocalPart`
(owned particles, ghosts, the fixed particles its pairs touch, its owned pairs; the contiguous partition of the
free particles in the serial order), the scene's global numbers (particle and free counts, gravity, up axis,
metadata) and its share of the fixed particles (block ``rank`` of the fixed particles in id order, for the frames
gathered on the root rank and the energy bound). No rank holds the whole model:

* :func:`cloth_grid_part` (and :func:`benchmark_cloth_part`) generate a rank's rows of a cloth grid from the grid's
  description: the particles of its rows and two rows either side, the springs it owns, built with the builder's
  own arithmetic (:func:`springsim.model.builder.resolve_cloth_grid`), so the particles and springs are those of
  :meth:`springsim.ModelBuilder.add_cloth_grid` to the last bit, in the same order. Plain numpy: a rank needs no
  other rank for it. The whole grid's pin mask (one byte per particle) is computed on every rank.
* :func:`generated_part` is :func:`cloth_grid_part` for a YAML scene that is one ``cloth:`` or
  ``benchmark_cloth:`` block (:attr:`springsim.scene.Scene.generator`): the command line reads the file on rank 0
  without building the model, sends the block's description, and every rank generates its part.
* :func:`scatter_model` sends every rank its part of a model that only the root rank holds (any other YAML scene,
  read there): the root builds each part in turn (:func:`model_part`) and sends it, then the caller drops the
  model.
* :func:`model_part` is one rank's part of a whole model, with no communication (the replicated path, and the
  pieces :func:`scatter_model` sends).
"""

from __future__ import annotations

import re
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from ..errors import SceneError
from ..forces._data import data_terms
from ..model import Model
from ..model.builder import ModelBuilder, resolve_cloth_grid
from ..model.model import AXES, ClothGrid
from ..model.topology import cloth_grid_pairs, cloth_pin_mask
from .partition import LocalPart, _sub_model, contiguous_offsets, local_part, pair_families, partition

__all__ = ["ScenePart", "model_part", "cloth_grid_part", "benchmark_cloth_part", "generated_part", "scatter_model",
           "repartition"]


@dataclass(eq=False)
class ScenePart:
    """One rank's share of a scene (module docstring); it stands for the model where the run needs one.

    Attributes
    ----------
    part : LocalPart
        The rank's particles and pairs (contiguous partition).
    particle_count, free_count : int
        Particles of the whole scene, and free ones among them.
    fixed_ids : ndarray of int
        Global ids of this rank's block of the fixed particles.
    fixed_model : Model
        Those particles (no pairs; gravity and the per-particle terms' data): their positions for the gathered
        frames, their constant energy for the energy bound.
    gravity : float
        Acceleration along the up axis [m/s^2].
    up_axis : int
        0, 1 or 2.
    pair_epsilon : float
        The model's pair epsilon [m].
    metadata : dict
        The model's metadata (``name``, ``source``).
    cloth_grids : tuple of ClothGrid
        The model's cloth grids.
    damped : bool
        Whether the whole model dissipates (:meth:`springsim.Model.dissipates`).
    model_fingerprint : str or None
        The whole model's :meth:`~springsim.Model.fingerprint`: computed where some rank held the model (a
        scattered one); for a generated one, None until :meth:`fingerprint` computes it from :attr:`grid`.
    pair_counts : dict
        Pair term -> number of pairs in the whole model (also as ``<term>_count`` attributes, as a Model has).
    grid : dict or None
        A generated part's description (:func:`cloth_grid_part`'s ``grid``, ``gravity`` and ``up_axis``), from
        which :meth:`fingerprint` hashes the whole model in bands (:func:`cloth_grid_fingerprint`).
    """

    part: LocalPart
    particle_count: int
    free_count: int
    fixed_ids: np.ndarray
    fixed_model: Model
    gravity: float
    up_axis: int
    pair_epsilon: float
    metadata: dict
    cloth_grids: tuple
    damped: bool
    model_fingerprint: str | None = None
    pair_counts: dict | None = None
    grid: dict | None = None

    def __getattr__(self, name: str):
        counts = self.__dict__.get("pair_counts") or {}
        if name.endswith("_count") and name[:-6] in counts:
            return counts[name[:-6]]
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    @property
    def gravity_vector(self) -> np.ndarray:
        """The gravitational acceleration (3,) [m/s^2]: :attr:`gravity` along :attr:`up_axis`."""
        g = np.zeros(3)
        g[self.up_axis] = self.gravity
        return g

    @property
    def dof_count(self) -> int:
        """Degrees of freedom of the whole system (3 per free particle)."""
        return 3 * self.free_count

    def fingerprint(self) -> str | None:
        """The whole model's fingerprint, the same as the serial model's (:meth:`springsim.Model.fingerprint`).

        A generated part computes it on the first call, from its grid's description, in bands
        (:func:`cloth_grid_fingerprint`: about 1.4 s per million particles), with no communication; every rank's run
        metadata asks for it, in parallel.

        Returns
        -------
        str or None
            :attr:`model_fingerprint`; None for a part of :func:`model_part` alone (:func:`scatter_model` sets it).
        """
        if self.model_fingerprint is None and self.grid is not None:
            self.model_fingerprint = cloth_grid_fingerprint(self.grid["grid"], gravity=self.grid["gravity"],
                                                            up_axis=self.grid["up_axis"])
        return self.model_fingerprint

    def dissipates(self) -> bool:
        """Whether any dissipation coefficient of the whole model is non-zero.

        Returns
        -------
        bool
            :attr:`damped`.
        """
        return self.damped

    def __repr__(self) -> str:
        p = self.part
        return (f"ScenePart(rank={p.rank} of {p.size}, particles={self.particle_count}, free={self.free_count}, "
                f"owned={p.n_own}, ghosts={p.n_ghost})")


def _fixed_block(fixed_ids: np.ndarray, size: int, rank: int) -> np.ndarray:
    """Block ``rank`` of ``size`` contiguous blocks of the fixed particles' ids."""
    b = contiguous_offsets(fixed_ids.size, size)
    return np.asarray(fixed_ids[b[rank]:b[rank + 1]], dtype=np.int64)


def model_part(model: Model, size: int, rank: int, offsets=None, order=None) -> ScenePart:
    """Rank ``rank``'s :class:`ScenePart` of a whole ``model`` (no communication).

    Parameters
    ----------
    model : Model
        The whole model.
    size : int
        Number of ranks.
    rank : int
        The rank whose part this is.
    offsets, order : array_like of int, optional
        As for :func:`~springsim.distributed.partition.partition` (a graph partition's numbering).

    Returns
    -------
    ScenePart
        With the model's fingerprint left unset (None): :func:`scatter_model` computes it once.
    """
    fixed = _fixed_block(np.flatnonzero(model.particle_fixed), size, rank)
    return ScenePart(part=partition(model, size, rank, offsets=offsets, order=order),
                     particle_count=model.particle_count, free_count=model.free_count, fixed_ids=fixed,
                     fixed_model=_sub_model(model, fixed, {}, keep_particle_terms=True), gravity=model.gravity,
                     up_axis=model.up_axis, pair_epsilon=model.pair_epsilon, metadata=dict(model.metadata),
                     cloth_grids=tuple(model.cloth_grids), damped=bool(model.dissipates()),
                     pair_counts={t: int(model.terms[t]["indices"].shape[0]) for t in pair_families(model)})


def _as_mpi(comm):
    """mpi4py's communicator from a petsc4py or mpi4py one (default: the world)."""
    if comm is None:
        from ._petsc import import_petsc

        _, MPI = import_petsc()
        return MPI.COMM_WORLD
    return comm.tompi4py() if hasattr(comm, "tompi4py") else comm


def scatter_model(model: Model | None, comm=None, root: int = 0) -> ScenePart:
    """Every rank's :class:`ScenePart` of a model that the root rank holds (collective).

    The root builds the parts one at a time and sends each to its rank (one message per rank), keeping its own, so
    the root holds the model and one part at a time; drop the model afterwards. The model's fingerprint is computed
    once, on the root, and sent with the parts.

    Parameters
    ----------
    model : Model or None
        The whole model on the root rank; ignored elsewhere (pass None).
    comm : mpi4py or petsc4py communicator, optional
        Default MPI's world.
    root : int
        The rank that holds the model.

    Returns
    -------
    ScenePart
        This rank's part.
    """
    mpi = _as_mpi(comm)
    rank, size = mpi.Get_rank(), mpi.Get_size()
    if rank != root:
        return mpi.recv(source=root, tag=35)
    fingerprint = model.fingerprint()
    own = None
    for r in range(size):  # one part per rank, each sent before the next is built
        sp = model_part(model, size, r)
        sp.model_fingerprint = fingerprint
        if r == root:
            own = sp
        else:
            mpi.send(sp, dest=r, tag=35)
        del sp
    return own


def _has_box(pin) -> bool:
    """Whether a pin specification has a ``{box: ...}`` item (which needs the positions)."""
    if isinstance(pin, dict):
        return "box" in pin
    return isinstance(pin, (list, tuple)) and any(_has_box(p) for p in pin)


def _grid_positions(c: dict, ids: np.ndarray) -> np.ndarray:
    """Positions of grid particles ``ids`` with :func:`~springsim.model.builder.cloth_grid_positions`' arithmetic."""
    pos = np.tile(np.asarray(c["origin"]), (ids.size, 1))
    a, b = c["axes"]
    pos[:, a] += (ids % c["nx"]).astype(np.float64) * c["dx"]
    pos[:, b] += (ids // c["nx"]).astype(np.float64) * c["dy"]
    return pos


def _resolved_grid(grid: dict):
    """A grid's resolved description (:func:`~springsim.model.builder.resolve_cloth_grid`) and its whole pin mask
    (one byte per particle; the positions are computed only for a ``box`` pin)."""
    kw = dict(grid)
    pin = kw.pop("pin", "edge")
    c = resolve_cloth_grid(**kw)
    positions = _grid_positions(c, np.arange(c["nx"] * c["ny"], dtype=np.int64)) if _has_box(pin) else None
    return c, cloth_pin_mask(c["nx"], c["ny"], pin, positions=positions, path="cloth.pin")


def cloth_grid_part(grid: dict, size: int, rank: int, *, gravity: float = -9.81, up_axis="z",
                    metadata: dict | None = None) -> ScenePart:
    """Rank ``rank``'s :class:`ScenePart` of the model of one cloth grid, built from the grid's description alone.

    The model is the one ``ModelBuilder(gravity=gravity, up_axis=up_axis).add_cloth_grid(**grid)`` makes; this
    builds only the rank's rows of it, two rows either side (bending springs reach two rows) and its block of the
    fixed particles (module docstring). No communication.

    Parameters
    ----------
    grid : dict
        Keyword arguments of :meth:`springsim.ModelBuilder.add_cloth_grid` (``nx``, ``ny``, ``pin``, ...), checked
        as it checks them.
    size : int
        Number of ranks.
    rank : int
        This rank.
    gravity : float
        Acceleration along the up axis [m/s^2].
    up_axis : str or int
        ``"x"``, ``"y"``, ``"z"`` or 0, 1, 2.
    metadata : dict, optional
        The model's metadata.

    Returns
    -------
    ScenePart
        Its fingerprint computed on demand (:meth:`ScenePart.fingerprint`).

    Raises
    ------
    SceneError
        An invalid grid argument, with the builder's message (``cloth.<argument>``).
    """
    c, fixed = _resolved_grid(grid)
    nx, ny = c["nx"], c["ny"]
    n = nx * ny
    free = np.flatnonzero(~fixed)
    F = int(free.size)
    offsets = contiguous_offsets(F, size)
    lo, hi = int(offsets[rank]), int(offsets[rank + 1])
    fixed_ids = _fixed_block(np.flatnonzero(fixed), size, rank)
    if hi > lo:  # the window: the owned rows and two either side
        w0, w1 = max(int(free[lo]) // nx - 2, 0), min(int(free[hi - 1]) // nx + 3, ny)
    else:
        w0 = w1 = 0
    del free
    ids = np.arange(w0 * nx, w1 * nx, dtype=np.int64)
    wfixed = fixed[w0 * nx:w1 * nx]
    free_index = np.where(wfixed, -1, np.count_nonzero(~fixed[:w0 * nx]) + np.cumsum(~wfixed) - 1)
    owner = np.where(wfixed, -1, np.searchsorted(offsets, free_index, side="right") - 1)

    b = ModelBuilder(gravity=gravity, up_axis=up_axis)
    b.add_particles(_grid_positions(c, ids), None, c["mass"], drag=c["drag"], fixed=wfixed)
    topo = cloth_grid_pairs(nx, w1 - w0, bending=c["bending"]) if w1 > w0 else {}
    damped = c["drag"] != 0.0
    for family, (ke, kd) in c["springs"].items():
        ij = topo.get(family, np.zeros((0, 2), dtype=np.int64))
        first = np.where(owner[ij[:, 0]] >= 0, owner[ij[:, 0]], owner[ij[:, 1]]) if ij.size else np.zeros(0, int)
        b.add_springs(ij[first == rank], ke, kd)
        has_pairs = (nx >= 3 or ny >= 3) if family == "bending" else True  # families of the whole grid
        damped = damped or (kd != 0.0 and has_pairs)
    with _global_ids(ids):  # finalize checks the positions
        piece = b.finalize()
    part = local_part(piece, size, rank, offsets, free_index, owner, ids=ids)

    fb = ModelBuilder(gravity=gravity, up_axis=up_axis)
    fb.add_particles(_grid_positions(c, fixed_ids), None, c["mass"], drag=c["drag"], fixed=True)
    with _global_ids(fixed_ids):
        fixed_model = fb.finalize()
    springs = _grid_spring_count(nx, ny, c["bending"])
    counts = {t: 0 for t in pair_families(piece)}
    counts["spring"] = springs
    return ScenePart(part=part, particle_count=n, free_count=F, fixed_ids=fixed_ids, fixed_model=fixed_model,
                     gravity=piece.gravity, up_axis=piece.up_axis, pair_epsilon=piece.pair_epsilon,
                     metadata=dict(metadata or {}), cloth_grids=(ClothGrid(0, nx, ny),), damped=bool(damped),
                     pair_counts=counts, grid={"grid": dict(grid), "gravity": gravity, "up_axis": up_axis})


def _grid_spring_count(nx: int, ny: int, bending: bool) -> int:
    """Springs of a whole ``nx`` x ``ny`` grid (:func:`~springsim.model.topology.cloth_grid_pairs`)."""
    springs = ny * (nx - 1) + (ny - 1) * nx + 2 * (ny - 1) * (nx - 1)
    if bending:
        springs += ny * max(nx - 2, 0) + max(ny - 2, 0) * nx
    return springs


#: Particles per piece of :func:`cloth_grid_fingerprint` (whole grid rows: at least one row).
FINGERPRINT_PIECE = 1 << 16


def cloth_grid_fingerprint(grid: dict, *, gravity: float = -9.81, up_axis="z") -> str:
    """The :meth:`~springsim.Model.fingerprint` of the model of one cloth grid, computed in bands of grid rows.

    Equal to ``ModelBuilder(gravity=gravity, up_axis=up_axis).add_cloth_grid(**grid).finalize().fingerprint()``
    (tested), without building that model: the hash is one byte stream (:func:`springsim.model.model.
    streamed_fingerprint`), fed array by array with pieces of about :data:`FINGERPRINT_PIECE` particles (or their
    springs) generated with :func:`cloth_grid_part`'s arithmetic. Memory: the pin mask (one byte per particle)
    and one piece. Time: one pass over the model's arrays (measured in docs/distributed.md, "Scene construction").

    Parameters
    ----------
    grid : dict
        Keyword arguments of :meth:`springsim.ModelBuilder.add_cloth_grid`.
    gravity : float
        Acceleration along the up axis [m/s^2].
    up_axis : str or int
        ``"x"``, ``"y"``, ``"z"`` or 0, 1, 2.

    Returns
    -------
    str
        64 hexadecimal digits.

    Raises
    ------
    SceneError
        An invalid grid argument, as :func:`cloth_grid_part` raises it.
    """
    from ..forces import FORCE_TERMS
    from ..model.model import fingerprint_v1_names, streamed_fingerprint

    c, fixed = _resolved_grid(grid)
    nx, ny = c["nx"], c["ny"]
    n = nx * ny
    band = max(FINGERPRINT_PIECE // nx, 1)
    bands = [(r, min(r + band, ny)) for r in range(0, ny, band)]

    # the template: the builder's model of the first rows, one spring per family, for the dtypes, the defaults
    # and the scalars
    rows = min(ny, 3)
    ids = np.arange(rows * nx, dtype=np.int64)
    topo = cloth_grid_pairs(nx, rows, bending=c["bending"])
    tb = ModelBuilder(gravity=gravity, up_axis=up_axis)
    tb.add_particles(_grid_positions(c, ids), None, c["mass"], drag=c["drag"], fixed=fixed[:ids.size])
    for family, (ke, kd) in c["springs"].items():
        tb.add_springs(topo[family][:1], ke, kd)
    with _global_ids(ids):
        t = tb.finalize()

    blocks = _grid_spring_blocks(c)
    counts = {}  # (block, band) -> springs: the coefficients need only the counts

    def block_pairs(b, r0, r1):
        ij, w1 = _grid_block_pairs(c, blocks[b], r0, r1)
        counts[b, r0] = len(ij)
        return ij, w1

    def spring_pieces(what):
        spring = FORCE_TERMS["spring"]
        for b, (_, (ke, kd), _) in enumerate(blocks):
            for r0, r1 in bands:
                if what in ("stiffness", "damping"):
                    k = counts[b, r0] if (b, r0) in counts else len(block_pairs(b, r0, r1)[0])
                    yield np.full(k, ke if what == "stiffness" else kd)
                    continue
                ij, w1 = block_pairs(b, r0, r1)
                if what == "indices":
                    yield ij + r0 * nx
                else:  # rest_length (the callers' names)
                    q = _grid_positions(c, np.arange(r0 * nx, w1 * nx, dtype=np.int64))
                    yield spring.complete_data({"indices": ij, "rest_length": np.full(len(ij), np.nan)},
                                               particle_q=q, particle_mass=None,
                                               pair_epsilon=t.pair_epsilon)["rest_length"]

    def particle_pieces(name, proto):
        for r0, r1 in bands:
            k = (r1 - r0) * nx
            if name == "particle_q":
                yield _grid_positions(c, np.arange(r0 * nx, r1 * nx, dtype=np.int64))
            elif name == "particle_fixed":
                yield fixed[r0 * nx:r1 * nx]
            elif name == "particle_qd":
                yield np.zeros((k, 3))
            else:  # mass, radius, drag: one value for the whole grid, the template's
                yield np.full((k,) + proto.shape[1:], proto[0], dtype=proto.dtype)

    springs = _grid_spring_count(nx, ny, c["bending"])
    v1 = []
    for name in fingerprint_v1_names():
        proto = getattr(t, name)
        if name.startswith("particle_"):
            v1.append((name, (n,) + proto.shape[1:], proto.dtype, particle_pieces(name, proto)))
        elif name in ("spring_indices", "spring_stiffness", "spring_damping", "spring_rest_length"):
            what = name[len("spring_"):]
            v1.append((name, (springs,) + proto.shape[1:], proto.dtype, spring_pieces(what)))
        else:  # another term's pairs or per-model data: a grid adds none, so the template's array is the model's
            v1.append((name, proto.shape, proto.dtype, [proto]))
    beyond = [(name, a.shape, a.dtype, [a]) for name, a in t.data_beyond_v1()]  # none for a grid (tested equal)
    return streamed_fingerprint(v1, gravity=t.gravity, up_axis=t.up_axis, pair_epsilon=t.pair_epsilon,
                                cloth_grids=(ClothGrid(0, nx, ny),), beyond=beyond)


def _grid_spring_blocks(c: dict) -> list:
    """A resolved grid's springs (:func:`~springsim.model.builder.resolve_cloth_grid`) in the builder's order, as
    blocks ``(family, (stiffness, damping), offset j - i)``: family by family, within a family its blocks of one
    offset in :func:`~springsim.model.topology.cloth_grid_pairs`' order, each in row-major order of its first
    particle (:func:`_grid_block_pairs`)."""
    topo = cloth_grid_pairs(c["nx"], min(c["ny"], 3), bending=c["bending"])
    blocks = []
    for family, coef in c["springs"].items():
        d = topo[family][:, 1] - topo[family][:, 0]
        blocks += [(family, coef, int(off)) for off in d[np.sort(np.unique(d, return_index=True)[1])]]
    return blocks


def _grid_block_pairs(c: dict, block: tuple, r0: int, r1: int) -> tuple:
    """The springs of one block of :func:`_grid_spring_blocks` whose first particle is in rows ``r0 .. r1 - 1``, as
    pairs of grid indices less ``r0 * nx``, and the row after the last one they reach."""
    family, _, off = block
    nx, ny = c["nx"], c["ny"]
    w1 = min(r1 + 2, ny)  # pairs reach two rows down
    ij = cloth_grid_pairs(nx, w1 - r0, bending=c["bending"])[family]
    return ij[(ij[:, 1] - ij[:, 0] == off) & (ij[:, 0] < (r1 - r0) * nx)], w1


@contextmanager
def _global_ids(ids: np.ndarray):
    """A builder's error about ``particles[k]`` of a piece names the particle's id in the whole grid, ``ids[k]``."""
    try:
        yield
    except SceneError as e:
        m = re.match(r"particles\[(\d+)\]", e.path)
        if m is None:
            raise
        raise SceneError(f"particles[{int(ids[int(m.group(1))])}]{e.path[m.end():]}", e.message) from None


def benchmark_cloth_part(n: int, size: int, rank: int, **options) -> ScenePart:
    """Rank ``rank``'s part of :func:`springsim.scene.benchmark_cloth` ``(n, **options)``, generated on the rank.

    Parameters
    ----------
    n : int
        Particles per side.
    size : int
        Number of ranks.
    rank : int
        This rank.
    **options
        As for :func:`springsim.scene.benchmark_cloth`.

    Returns
    -------
    ScenePart
        The same particles and springs as the rank's part of ``benchmark_cloth(n, **options)``.
    """
    from ..scene.gallery import benchmark_cloth_grid

    return cloth_grid_part(benchmark_cloth_grid(n, **options), size, rank, gravity=-9.81, up_axis=AXES[2],
                           metadata={"name": f"benchmark_cloth_{n}"})


def generated_part(generator: dict, size: int, rank: int) -> ScenePart:
    """Rank ``rank``'s part of a YAML scene of one generator block, from the block's description alone.

    Parameters
    ----------
    generator : dict
        :attr:`springsim.scene.Scene.generator` (``grid``, ``gravity``, ``up_axis``, ``metadata``, ``paths``).
    size : int
        Number of ranks.
    rank : int
        This rank.

    Returns
    -------
    ScenePart
        The rank's part of the model the scene file describes (:func:`cloth_grid_part`).

    Raises
    ------
    SceneError
        An invalid value of the block, naming it as written in the file (``benchmark_cloth.stiffness``).
    """
    from ..scene.yaml_io import _renamed

    try:
        return cloth_grid_part(generator["grid"], size, rank, gravity=generator["gravity"],
                               up_axis=generator["up_axis"], metadata=generator["metadata"])
    except SceneError as e:
        raise _renamed(e, generator["paths"]) from None


_BASE = ("particle_q", "particle_qd", "particle_mass", "particle_radius", "particle_fixed")


def _route(mpi, dest: np.ndarray, arrays: dict) -> dict:
    """Send row ``i`` of every array of ``arrays`` to rank ``dest[i]``; the rows received, by source rank (one
    all-to-all; a loop over ranks only)."""
    size = mpi.Get_size()
    by = np.argsort(dest, kind="stable")
    cuts = np.searchsorted(dest[by], np.arange(size + 1))
    got = mpi.alltoall([{k: v[by[cuts[r]:cuts[r + 1]]] for k, v in arrays.items()} for r in range(size)])
    return {k: np.concatenate([g[k] for g in got]) for k in arrays}


def _fetch(mpi, ids: np.ndarray, offsets: np.ndarray, cols: dict) -> dict:
    """Rows ``ids`` (global indices: particle ids, system rows) of the columns ``cols``, which the ranks hold in the
    contiguous blocks ``offsets`` (collective): asked of their holders (two all-to-alls), in the order of ``ids``."""
    rank = mpi.Get_rank()
    holder = np.searchsorted(offsets, ids, side="right") - 1
    ask = _route(mpi, holder, {"id": ids, "rank": np.full(ids.size, rank, dtype=np.int64),
                               "slot": np.arange(ids.size, dtype=np.int64)})
    k = ask["id"] - offsets[rank]
    reply = _route(mpi, ask["rank"], {"slot": ask["slot"], **{c: v[k] for c, v in cols.items()}})
    out = {}
    for c, v in reply.items():
        if c != "slot":
            a = np.empty((ids.size,) + v.shape[1:], dtype=v.dtype)
            a[reply["slot"]] = v
            out[c] = a
    return out


def repartition(scene: ScenePart, parts: np.ndarray, comm=None) -> ScenePart:
    """Move a scene's particles and pairs to new owners (collective): ``parts[i]`` is the new rank of this rank's
    owned particle ``i``; the system is then numbered part by part, the serial order kept within a part.

    Every rank sends its owned particles' data to their new owners and each of its pairs, with the data of both its
    particles, to the pair's new owner (the new owner of its first free particle); the ghosts' new owners and
    numbers come from their current owners. All-to-all exchanges of numpy rows; no loop over particles or pairs.
    The fixed particles' blocks do not move.

    Parameters
    ----------
    scene : ScenePart
        This rank's part (any partition).
    parts : ndarray of int, shape (n_own,)
        New rank of each owned particle.
    comm : mpi4py or petsc4py communicator, optional
        Default MPI's world.

    Returns
    -------
    ScenePart
        This rank's new part; its ``part.order`` is None (the frames are gathered by particle id).
    """
    mpi = _as_mpi(comm)
    size, rank = mpi.Get_size(), mpi.Get_rank()
    p = scene.part
    parts = np.asarray(parts, dtype=np.int64)
    counts = np.bincount(parts, minlength=size)
    every = np.array(mpi.allgather(counts))                     # (ranks, parts)
    offsets = np.concatenate([[0], np.cumsum(every.sum(axis=0))])
    before = every[:rank].sum(axis=0)                           # particles of each part on lower ranks
    by = np.argsort(parts, kind="stable")                       # serial order kept within a part
    ps = parts[by]
    new_sys = np.empty(p.n_own, dtype=np.int64)         # part's first row, lower ranks' share, place on this rank
    new_sys[by] = offsets[ps] + before[ps] + np.arange(p.n_own) - np.searchsorted(ps, ps)
    # the new owner and number of every local particle: owned ones known, ghosts asked of their owners
    L = p.local_particles.size
    owner, sys = np.full(L, -1, dtype=np.int64), np.full(L, -1, dtype=np.int64)
    owner[:p.n_own], sys[:p.n_own] = parts, new_sys
    g = np.arange(p.n_own, p.n_local_free)
    reply = _fetch(mpi, p.local_to_free[g], p.offsets, {"owner": parts, "sys": new_sys})
    owner[g], sys[g] = reply["owner"], reply["sys"]

    pm, om = p.pair_model, p.particle_model
    registered = dict(data_terms())
    pair_cols = {name: np.asarray(getattr(pm, name)) for name in _BASE}
    for term, data in pm.terms.items():  # the pairwise terms' per-particle data (the others': the owners')
        cls = registered.get(term)
        if cls is not None and cls.pairwise:
            pair_cols.update({f"{term}.{spec.name}": data[spec.name] for spec in cls.data if spec.per == "particle"})
    pair_cols.update(id=p.local_particles, owner=owner, sys=sys)
    own_cols = {f"{term}.{spec.name}": data[spec.name] for term, data in om.terms.items()
                for spec in getattr(registered.get(term), "data", ()) if spec.per == "particle"}
    own_cols.update({k: v[:p.n_own] for k, v in pair_cols.items()})
    mine = _route(mpi, parts, own_cols)                         # the new owned particles, all their data

    # pairs, with both particles' rows, to the owner of the first free particle
    rows, terms_out = [{k: mine[k] for k in pair_cols}], {}
    for term in [t for t in pm.terms if "indices" in pm.terms[t] and t in registered]:
        data, cls = pm.terms[term], registered[term]
        ij = np.asarray(data["indices"])
        first = np.where(owner[ij[:, 0]] >= 0, owner[ij[:, 0]], owner[ij[:, 1]])
        per_pair = {spec.name: data[spec.name] for spec in cls.data if spec.per == "pair"}
        sent = _route(mpi, first, {"i": p.local_particles[ij[:, 0]], "j": p.local_particles[ij[:, 1]], **per_pair})
        terms_out[term] = sent
        for end in (0, 1):
            rows.append(_route(mpi, first, {k: v[ij[:, end]] for k, v in pair_cols.items()}))
    got = {k: np.concatenate([r[k] for r in rows] + [pair_cols[k][:0]]) for k in pair_cols}
    ids, first_row = np.unique(got["id"], return_index=True)
    particles = {k: v[first_row] for k, v in got.items()}
    n = ids.size
    model_terms = {}
    for term, data in pm.terms.items():
        cls = registered.get(term)
        if cls is None or not cls.pairwise:
            continue
        d = {}
        for spec in cls.data:
            if spec.per == "particle":
                d[spec.name] = particles[f"{term}.{spec.name}"]
            elif spec.per == "model":
                d[spec.name] = np.array(data[spec.name])
        if term in terms_out:
            t = terms_out[term]
            d["indices"] = np.stack([np.searchsorted(ids, t["i"]), np.searchsorted(ids, t["j"])], axis=1)
            d.update({spec.name: t[spec.name] for spec in cls.data if spec.per == "pair"})
        model_terms[term] = d
    at = np.searchsorted(ids, mine["id"])
    for term, data in om.terms.items():
        cls = registered.get(term)
        if cls is None or cls.pairwise:
            continue
        d = model_terms.setdefault(term, {})
        for spec in cls.data:
            if spec.per == "particle":
                a = np.full((n,) + tuple(spec.shape), spec.default, dtype=np.float64)
                a[at] = mine[f"{term}.{spec.name}"]
                d[spec.name] = a
            elif spec.per == "model":
                d[spec.name] = np.array(data[spec.name])
    piece = Model(**{k: particles[k] for k in _BASE}, terms=model_terms, gravity=om.gravity, up_axis=om.up_axis,
                  pair_epsilon=om.pair_epsilon, metadata=dict(om.metadata))
    new = local_part(piece, size, rank, offsets, particles["sys"], particles["owner"], ids=ids)
    return ScenePart(part=new, particle_count=scene.particle_count, free_count=scene.free_count,
                     fixed_ids=scene.fixed_ids, fixed_model=scene.fixed_model, gravity=scene.gravity,
                     up_axis=scene.up_axis, pair_epsilon=scene.pair_epsilon, metadata=scene.metadata,
                     cloth_grids=scene.cloth_grids, damped=scene.damped, model_fingerprint=scene.model_fingerprint,
                     pair_counts=scene.pair_counts, grid=scene.grid)
