"""A YAML scene read in pieces on one rank and built in parts on every rank: no rank holds the whole model.

:func:`streamed_part` is the distributed construction of a scene file with item lists (``particles``,
``springs``, ``gravitational``), with or without generator blocks (:attr:`springsim.scene.Scene.stream`). It goes
in stages, each a few all-to-all exchanges of numpy rows (:func:`~springsim.distributed.scene._route`), with no
loop over particles or pairs:

1. **Read and checked on the root, a chunk at a time** (:func:`springsim.scene.yaml_stream.item_chunks`): each
   chunk of particles or pairs is checked as a whole load checks it (the items' types, then the values, with the
   builder's own checks), its error paths counted from the start of its list, and sent to the rank that holds
   that stretch of the list: rank ``r`` holds block ``r`` of the particles by id and block ``r`` of each pair
   list in file order (:func:`~springsim.distributed.partition.contiguous_offsets`). The generator blocks'
   particles and springs follow, generated on the root a band of grid rows at a time with the builder's
   arithmetic and order (after the file's own, as :meth:`springsim.ModelBuilder.add_cloth_grid` adds them). The
   root holds one chunk at a time besides its own blocks (and a grid's pin mask, one byte per particle).
2. **Completed where held**: the ``pin:`` section is applied to each block of particles (indices and boxes); the
   pairs' computed values (a spring's rest length, a softening length) are computed from the rows of their
   particles, fetched from the ranks that hold them, with the terms' own
   :meth:`~springsim.forces.ForceTerm.complete_data`.
3. **Fingerprint**: the whole model's :meth:`~springsim.Model.fingerprint`, hashed on the root from the blocks in
   rank order, one block of one array at a time (:func:`springsim.model.model.streamed_fingerprint`).
4. **Sent to the owners**: the free particles are numbered in id order and split into contiguous blocks as for
   :func:`~springsim.distributed.partition.partition`; every free particle goes to its owner, every pair to the
   owner of its first free particle, the fixed particles to their block of :attr:`ScenePart.fixed_ids`; each owner
   fetches the ghosts and fixed particles its pairs touch and builds its
   :class:`~springsim.distributed.partition.LocalPart` (:func:`~springsim.distributed.partition.local_part`).

The result equals :func:`~springsim.distributed.scene.model_part` of the model a whole load builds (its arrays,
its fingerprint, the run; tested on 1, 2 and 3 ranks). An invalid scene raises the same :class:`SceneError` on every
rank: the first error in the file as the checks meet it (for a scene with several errors, possibly another one
than a whole load names first).
"""

from __future__ import annotations

import re

import numpy as np

from ..errors import SceneError
from ..forces._data import data_terms, term_attributes, term_group
from ..model import AXES, Model
from ..model.model import ClothGrid
from ..model.builder import ModelBuilder, _check_pairs, resolve_cloth_grid
from ..model.model import _has_data, _model_names, fingerprint_v1_names, streamed_fingerprint
from ..model.topology import pin_boxes, pin_mask
from ..scene.yaml_io import _parse_pairs, _parse_particles, _renamed, _spelled_as_written, _term_keys
from .partition import _sub_model, contiguous_offsets, local_part
from .scene import _BASE, ScenePart, _as_mpi, _fetch, _grid_spring_count, _route

__all__ = ["streamed_part"]

_TAG = 36


# -- the root's checks, chunk by chunk ----------------------------------------------------------------------------
def _counted_from(err: SceneError, group: str, start: int) -> SceneError:
    """``err`` naming item ``k + start`` of ``group`` where it names item ``k`` of a chunk."""
    m = re.match(re.escape(group) + r"\[(\d+)\]", err.path)
    if m is None or not start:
        return err
    return type(err)(f"{group}[{int(m.group(1)) + start}]{err.path[m.end():]}", err.message)


def _particle_columns(model: Model) -> dict:
    """The per-particle columns of a model: the base arrays and every term's per-particle arrays."""
    cols = {name: np.asarray(getattr(model, name)) for name in _BASE}
    for term, cls in data_terms():
        cols.update({f"{term}.{spec.name}": model.terms[term][spec.name] for spec in cls.data
                     if spec.per == "particle"})
    return cols


def _particle_chunk(items: list, start: int) -> dict:
    """A chunk of ``particles`` items as columns, checked as :func:`springsim.scene.load_scene` checks them."""
    try:
        p = _parse_particles(items)
        b = ModelBuilder()
        b.add_particles(p["pos"], p["vel"], p["mass"], radius=p["radius"], fixed=p["fixed"], **p["arrays"])
        return _particle_columns(b.finalize())
    except SceneError as e:
        raise _counted_from(e, "particles", start) from None


def _pair_chunk(cls, key: str, items: list, start: int, n: int) -> dict:
    """A chunk of a pair list's items as columns (``indices`` and the per-pair arrays), checked."""
    specs = [s for s in cls.data if s.per == "pair"]
    try:
        p = _parse_pairs(key, items, n, specs)
        try:
            _check_pairs(key, p["ids"], n)
            cols = {"indices": p["ids"]}
            for s in specs:
                cols[s.name] = s.as_values(f"{key}.{s.key}", p[s.name], len(items))
                s.validate(key, cols[s.name])
        except SceneError as e:
            raise _spelled_as_written(e, key, p["aliases"]) from None
        return cols
    except SceneError as e:
        raise _counted_from(e, key, start) from None


def _model_values(term: str, cls, given: dict) -> dict:
    """A term's per-model arrays, as :meth:`springsim.ModelBuilder.finalize` makes and checks them."""
    out = {}
    for spec in cls.data:
        if spec.per == "model":
            v = given.get(spec.name)
            out[spec.name] = a = np.array(spec.filled(1)[0] if v is None else v, dtype=np.float64)
            spec.validate(term_group(term, cls), a, per_item=False)
    return out


# -- collective helpers -------------------------------------------------------------------------------------------
def _agree(mpi, err: SceneError | None) -> None:
    """Raise on every rank the lowest rank's error, if any rank has one (collective)."""
    got = mpi.allgather(None if err is None else (err.path, err.message))
    first = next((e for e in got if e is not None), None)
    if first is not None:
        raise SceneError(*first)


def _stacked(pieces: list) -> dict:
    return {c: np.concatenate([p[c] for p in pieces]) for c in pieces[0]}


# -- the stages ----------------------------------------------------------------------------------------------------
def _read(mpi, stream: dict, poff: np.ndarray, qoff: dict, terms: list, root: int):
    """Stage 1: the root reads and checks the lists a chunk at a time and sends every chunk's stretches to their
    holders; every rank returns its blocks (particle columns, and each pair term's columns)."""
    from ..scene.yaml_stream import item_chunks

    rank, size = mpi.Get_rank(), mpi.Get_size()
    outline = stream["outline"]
    n = int(poff[-1])  # every particle, the generated ones too (explicit pairs may join them)
    by_key = {key: (term, cls) for term, cls, key in terms}
    got = {"particles": [(-1, _particle_chunk([], 0))]}  # empty pieces: the columns of an empty block
    for term, cls, key in terms:
        got[term] = [(-1, _pair_chunk(cls, key, [], 0, n))]

    def keep(what, start, cols):
        got[what].append((start, cols))

    def chunks():
        """(what, start, columns): the file's items, then the generator blocks' particles and springs."""
        for key, start, items in item_chunks(outline):
            if key == "particles":
                yield key, start, _particle_chunk(items, start)
            else:
                term, cls = by_key[key]
                yield term, start, _pair_chunk(cls, key, items, start, n)
        yield from _grid_chunks(stream, outline.counts.get("particles", 0),
                                outline.counts.get(_list_key(terms, "spring"), 0))

    if rank == root:
        err = None
        try:
            for what, start, cols in chunks():
                off = poff if what == "particles" else qoff[what]
                k = len(next(iter(cols.values())))
                for r in range(np.searchsorted(off, start, side="right") - 1, size):
                    a, b = max(start, off[r]), min(start + k, off[r + 1])
                    if a >= start + k:
                        break
                    if b <= a:
                        continue
                    piece = {c: v[a - start:b - start] for c, v in cols.items()}
                    if r == rank:
                        keep(what, a, piece)
                    else:
                        mpi.send(("rows", what, a, piece), dest=r, tag=_TAG)
                del cols
        except SceneError as e:
            err = e
        for r in range(size):
            if r != rank:
                mpi.send(("end", None, None, None if err is None else (err.path, err.message)), dest=r, tag=_TAG)
        if err is not None:
            raise err
    else:
        while True:
            kind, what, start, payload = mpi.recv(source=root, tag=_TAG)
            if kind == "end":
                if payload is not None:
                    raise SceneError(*payload)
                break
            keep(what, start, payload)
    return {what: _stacked([cols for _, cols in sorted(pieces, key=lambda x: x[0])]) for what, pieces in got.items()}


def _list_key(terms: list, term: str) -> str:
    """The YAML key of a pair term's list (``spring`` -> ``springs``)."""
    return next(key for t, _, key in terms if t == term)


def _grid_chunks(stream: dict, start: int, springs: int):
    """The generator blocks' particles and springs as chunks ``(what, start, columns)``, in the builder's order after
    the file's own (particles from ``start``, springs from ``springs``), a band of grid rows at a time
    (:data:`~springsim.distributed.scene.FINGERPRINT_PIECE` particles): the values of
    :meth:`springsim.ModelBuilder.add_cloth_grid` to the last bit (the same resolved grid and arithmetic,
    :func:`~springsim.distributed.scene._grid_spring_blocks`). Memory: the grid's pin mask and one band."""
    from ..forces import FORCE_TERMS
    from .scene import FINGERPRINT_PIECE, _grid_positions, _resolved_grid, _grid_block_pairs, _grid_spring_blocks

    specs = [s for s in FORCE_TERMS["spring"].data if s.per == "pair"]
    for path, kw, paths in stream.get("cloths", ()):
        try:
            c, fixed = _resolved_grid(kw)
        except SceneError as e:
            raise _renamed(e, paths) from None
        nx, ny = c["nx"], c["ny"]
        band = max(FINGERPRINT_PIECE // nx, 1)
        bands = [(r, min(r + band, ny)) for r in range(0, ny, band)]
        for r0, r1 in bands:
            ids = np.arange(r0 * nx, r1 * nx, dtype=np.int64)
            b = ModelBuilder()
            b.add_particles(_grid_positions(c, ids), None, c["mass"], drag=c["drag"], fixed=fixed[r0 * nx:r1 * nx])
            try:
                cols = _particle_columns(b.finalize())
            except SceneError as e:
                raise _counted_from(e, "particles", start + r0 * nx) from None
            yield "particles", start + r0 * nx, cols
        for block in _grid_spring_blocks(c):
            ke, kd = block[1]
            for r0, r1 in bands:
                ij, _ = _grid_block_pairs(c, block, r0, r1)
                k = len(ij)
                if not k:
                    continue
                cols = {"indices": ij + (start + r0 * nx)}
                for spec in specs:
                    cols[spec.name] = (np.full(k, ke) if spec.name == "stiffness" else
                                       np.full(k, kd) if spec.name == "damping" else spec.filled(k))
                yield "spring", springs, cols
                springs += k
        start += nx * ny


def _pin(mpi, stream: dict, n: int, lo: int, hi: int, parts: dict) -> None:
    """Stage 2a: the ``pin:`` section applied to this rank's block of particles (collective), velocities of the fixed
    ones zeroed, as :meth:`springsim.ModelBuilder.finalize` does; a box that holds no particle of any block is the
    error a whole load gives (:func:`springsim.model.topology.pin_mask`)."""
    pin, q, err = stream["pin"], parts["particle_q"], None
    try:
        if pin is not None:
            parts["particle_fixed"] = parts["particle_fixed"] | pin_mask(pin, n, positions=q, path="pin",
                                                                           rows=(lo, hi))
    except SceneError as e:
        err = e
    _agree(mpi, err)
    boxes = pin_boxes(pin) if pin is not None else []
    if boxes:
        inside = [int(np.all((q >= c[0]) & (q <= c[1]), axis=1).any()) for _, c in boxes]
        span = (q.min(axis=0), q.max(axis=0)) if q.shape[0] else None
        every = mpi.allgather((inside, span))
        spans = [s for _, s in every if s is not None]
        for k, (path, _) in enumerate(boxes):
            if not any(got[k] for got, _ in every):
                lo_, hi_ = np.min([s[0] for s in spans], axis=0), np.max([s[1] for s in spans], axis=0)
                raise SceneError(path, f"contains no particle (the particles span [{', '.join(f'{x:g}' for x in lo_)}]"
                                       f" to [{', '.join(f'{x:g}' for x in hi_)}])")
    parts["particle_qd"] = np.where(parts["particle_fixed"][:, None], 0.0, parts["particle_qd"])


def _completed(term: str, cls, key: str, pairs: dict, local_ij: np.ndarray, model: dict, start: int, ends: dict,
               eps: float) -> dict:
    """Stage 2b: a block of a pair list with its computed values filled in (:meth:`ForceTerm.complete_data`), from
    the rows ``ends`` of its particles, which ``local_ij`` index."""
    d = {spec.name: ends[f"{term}.{spec.name}"] for spec in cls.data if spec.per == "particle"}
    d["indices"] = local_ij
    for spec in cls.data:
        if spec.per == "pair":
            d[spec.name] = pairs[spec.name]
        elif spec.per == "model":
            d[spec.name] = model[spec.name]
    try:
        out = cls.complete_data(d, particle_q=ends["particle_q"], particle_mass=ends["particle_mass"],
                                pair_epsilon=eps)
    except SceneError as e:
        raise _counted_from(e, key, start) from None
    return dict(pairs, **{spec.name: out[spec.name] for spec in cls.data if spec.per == "pair"})


def _fingerprint(mpi, root: int, n: int, parts: dict, pairs: dict, model: dict, counts: dict, scalars: dict):
    """Stage 3: the whole model's fingerprint, on every rank: hashed on the root from the blocks of every rank,
    one block of one array at a time, in the order :meth:`springsim.Model.fingerprint` hashes the arrays."""
    rank, size = mpi.Get_rank(), mpi.Get_size()
    registered = dict(data_terms())
    table = term_attributes(reserved=_model_names())

    def locate(term, key):
        """(this rank's piece, the whole array's length or None for a per-model array)."""
        if key == "indices":
            return pairs[term]["indices"], counts[term]
        spec = next(s for s in registered[term].data if s.name == key)
        if spec.per == "particle":
            return parts[f"{term}.{key}"], n
        if spec.per == "pair":
            return pairs[term][key], counts[term]
        return model[term][key], None

    items = []
    for name in fingerprint_v1_names():
        if name in _BASE:
            items.append((name, parts[name], n))
        else:
            items.append((name,) + locate(*table[name]))
    # then the data of the other terms that have some (Model.data_beyond_v1), in the order a built model keeps
    done = {table[name] for name in fingerprint_v1_names() if name in table}
    beyond = []
    for term in sorted(registered):
        cls = registered[term]
        keys = [s.name for s in cls.data if s.per == "particle"]
        keys += ["indices"] if term in pairs else []
        keys += [s.name for s in cls.data if s.per != "particle"]
        local = {k: locate(term, k)[0] for k in keys}
        beyond.append((term, [k for k in keys if (term, k) not in done], _has_data(cls, local)))
    has = np.any(np.array(mpi.allgather([h for _, _, h in beyond]), dtype=bool).reshape(size, -1), axis=0)
    extra = [(f"{term}.{k}",) + locate(term, k) for (term, keys, _), h in zip(beyond, has) if h for k in keys]

    def pieces(name, piece, whole):
        if whole is None:  # a per-model array: the root's
            yield piece
            return
        for r in range(size):  # the blocks in rank order
            yield piece if r == root else mpi.recv(source=r, tag=_TAG + 1)

    if rank == root:
        def declared(name, piece, whole):
            shape = piece.shape if whole is None else (whole,) + piece.shape[1:]
            return name, shape, piece.dtype, pieces(name, piece, whole)

        fp = streamed_fingerprint([declared(*i) for i in items], beyond=[declared(*i) for i in extra], **scalars)
    else:
        for _, piece, whole in items + extra:
            if whole is not None:
                mpi.send(np.ascontiguousarray(piece), dest=root, tag=_TAG + 1)
        fp = None
    return mpi.bcast(fp, root=root)


def streamed_part(scene, comm=None, root: int = 0) -> ScenePart:
    """This rank's :class:`ScenePart` of a scene file read in pieces on the root rank (collective; module docstring).

    Parameters
    ----------
    scene : springsim.scene.Scene
        A scene loaded with ``build=False`` that has :attr:`~springsim.scene.Scene.stream` (a file with item lists),
        the same on every rank.
    comm : mpi4py or petsc4py communicator, optional
        Default MPI's world.
    root : int
        The rank that reads the file.

    Returns
    -------
    ScenePart
        This rank's part, with the whole model's fingerprint.

    Raises
    ------
    SceneError
        On every rank, an invalid item or value, naming it (``springs[12].stiffness: must be >= 0, got -3``), or a
        file that changed while it was read.
    """
    if scene.stream is None:
        raise ValueError("streamed_part needs a scene loaded with build=False from a file with item lists "
                         "(Scene.stream)")
    mpi = _as_mpi(comm)
    rank, size = mpi.Get_rank(), mpi.Get_size()
    stream = scene.stream
    counts_by_key = stream["outline"].counts
    terms = [(term, cls, key) for term, cls, key in _term_keys() if any(s.per == "pair" for s in cls.data)]
    counts = {term: counts_by_key.get(key, 0) for term, _, key in terms}
    n = counts_by_key.get("particles", 0)
    grids = []  # the generator blocks' grids, after the file's particles; their springs after the file's
    for _, kw, _ in stream.get("cloths", ()):
        c = resolve_cloth_grid(**{k: v for k, v in kw.items() if k != "pin"})  # (checked by the outline)
        grids.append(ClothGrid(n, c["nx"], c["ny"]))
        n += c["nx"] * c["ny"]
        counts["spring"] += _grid_spring_count(c["nx"], c["ny"], c["bending"])
    poff = contiguous_offsets(n, size)
    qoff = {term: contiguous_offsets(counts[term], size) for term in counts}
    lo, hi = int(poff[rank]), int(poff[rank + 1])
    registered = dict(data_terms())
    eps = ModelBuilder().pair_epsilon
    up = stream["up_axis"]
    scalars = dict(gravity=float(stream["gravity"]), up_axis=AXES.index(up) if isinstance(up, str) else int(up),
                   pair_epsilon=eps, cloth_grids=tuple(grids))

    # 1. read on the root, blocks on every rank
    blocks = _read(mpi, stream, poff, qoff, terms, root)
    parts = blocks["particles"]
    # the per-model data: the same on every rank, and so are its errors
    model = {term: _model_values(term, cls, stream["model_data"].get(term, {})) for term, cls in registered.items()}
    _pin(mpi, stream, n, lo, hi, parts)

    # 2. owners and numbers of the free particles (id order), the fixed particles' blocks
    fixed = parts["particle_fixed"]
    free_here = int((~fixed).sum())
    every = np.array(mpi.allgather((free_here, int(fixed.sum()))), dtype=np.int64).reshape(size, 2)
    F, n_fixed = int(every[:, 0].sum()), int(every[:, 1].sum())
    offsets = contiguous_offsets(F, size)
    free_index = np.where(fixed, -1, every[:rank, 0].sum() + np.cumsum(~fixed) - 1).astype(np.int64)
    owner = np.where(fixed, -1, np.searchsorted(offsets, free_index, side="right") - 1).astype(np.int64)
    parts.update(id=np.arange(lo, hi, dtype=np.int64), free_index=free_index, owner=owner)

    # 2b. the pairs' computed values, from their particles' rows
    pairs, owners, err = {}, {}, None
    for term, cls, key in terms:
        p = blocks[term]
        ids, inv = np.unique(p["indices"], return_inverse=True)
        ends = _fetch(mpi, ids, poff, parts)
        local_ij = inv.reshape(-1, 2)
        if err is None:
            try:
                p = _completed(term, cls, key, p, local_ij, model[term], int(qoff[term][rank]), ends, eps)
            except SceneError as e:
                err = e
        pairs[term] = p
        owners[term] = ends["owner"][local_ij]
    _agree(mpi, err)

    # 3. the fingerprint and the whole model's flags
    fp = _fingerprint(mpi, root, n, parts, pairs, model, counts, scalars)
    dissipative = any(np.any(parts[f"{t}.{s.name}"] != 0) if s.per == "particle" else
                      np.any(pairs[t][s.name] != 0) if s.per == "pair" else np.any(model[t][s.name] != 0)
                      for t, cls in registered.items() for s in cls.data if s.dissipative)
    damped = bool(mpi.allreduce(int(dissipative)))

    # 4. to the owners: free particles, pairs (by the owner of their first free particle), fixed blocks
    mine = _route(mpi, owner[owner >= 0], {c: v[owner >= 0] for c, v in parts.items()})
    got = {}
    for term, cls, _ in terms:
        p, o = pairs[term], owners[term]
        dest = np.where(o[:, 0] >= 0, o[:, 0], o[:, 1])
        keep = dest >= 0  # pairs between two fixed particles move nothing: no rank keeps them
        cols = {"i": p["indices"][keep, 0], "j": p["indices"][keep, 1]}
        cols.update({s.name: p[s.name][keep] for s in cls.data if s.per == "pair"})
        got[term] = _route(mpi, dest[keep], cols)
    touched = np.unique(np.concatenate([np.concatenate([g["i"], g["j"]]) for g in got.values()] +
                                       [np.zeros(0, dtype=np.int64)]))
    touched = touched[~np.isin(touched, mine["id"])]
    rows = _fetch(mpi, touched, poff, parts)
    rows["id"] = touched
    local = {c: np.concatenate([mine[c], rows[c]]) for c in mine}
    order = np.argsort(local["id"], kind="stable")
    local = {c: v[order] for c, v in local.items()}
    ids = local["id"]

    def piece_model(cols, pair_cols):
        model_terms = {}
        for term, cls in registered.items():
            d = {s.name: cols[f"{term}.{s.name}"] for s in cls.data if s.per == "particle"}
            if any(s.per == "pair" for s in cls.data):
                pc = pair_cols.get(term)
                d["indices"] = (np.zeros((0, 2), dtype=np.int64) if pc is None else
                                np.stack([np.searchsorted(cols["id"], pc["i"]),
                                          np.searchsorted(cols["id"], pc["j"])], axis=1).astype(np.int64))
            for s in cls.data:
                if s.per == "pair":
                    d[s.name] = (pair_cols[term][s.name] if term in pair_cols else
                                 np.zeros((0,) + tuple(s.shape), dtype=np.float64))
                elif s.per == "model":
                    d[s.name] = np.array(model[term][s.name])
            model_terms[term] = d
        return Model(**{c: cols[c] for c in _BASE}, terms=model_terms, **{k: v for k, v in scalars.items()
                                                                          if k != "cloth_grids"},
                     metadata=dict(stream["metadata"]))

    part = local_part(piece_model(local, got), size, rank, offsets, local["free_index"], local["owner"], ids=ids)

    fixed_off = contiguous_offsets(n_fixed, size)
    fixed_index = every[:rank, 1].sum() + np.cumsum(fixed) - 1
    fdest = np.searchsorted(fixed_off, fixed_index[fixed], side="right") - 1
    fixed_rows = _route(mpi, fdest, {c: v[fixed] for c, v in parts.items()})
    order = np.argsort(fixed_rows["id"], kind="stable")
    fixed_rows = {c: v[order] for c, v in fixed_rows.items()}
    fm = piece_model(fixed_rows, {})
    fixed_model = _sub_model(fm, np.arange(fm.particle_count), {}, keep_particle_terms=True)

    return ScenePart(part=part, particle_count=n, free_count=F, fixed_ids=fixed_rows["id"].astype(np.int64),
                     fixed_model=fixed_model, gravity=scalars["gravity"], up_axis=scalars["up_axis"],
                     pair_epsilon=eps, metadata=dict(stream["metadata"]), cloth_grids=tuple(grids), damped=damped,
                     model_fingerprint=fp, pair_counts=dict(counts))
