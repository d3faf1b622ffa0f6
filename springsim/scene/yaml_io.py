"""Load a YAML scene (the assignment's "Nemo" format plus generator blocks) into a :class:`Scene`.

The format is documented key by key in ``docs/scene-format.md``. In short::

    solver:   {type: implicit_euler, timestep: 0.01, gravity: -9.81, ...}
    particles:
      - {pos: [0, 0, 1], vel: [0, 0, 0], mass: 0.1, fixed: true, drag: 0.0, radius: 0.01}
    springs:
      - {particle_ids: [0, 1], stiffness: 100.0, damping: 0.5, rest_length: 0.2}   # or ke:, kd:
    gravitational:
      - {particle_ids: [0, 1], G: 100.0, softening: 0.01}
    cloth: {nx: 64, ny: 64, size: [1, 1], total_mass: 1.0, stiffness: 1.0e4, pin: [top, {i: 0, j: 0}]}
    benchmark_cloth: {n: 64, damping: 0}
    pin: [0, {box: [[-1, -1, 0.9], [1, 1, 1.1]]}]   # fix further particles (global indices, boxes)
    plot: {particle_id: 1, dof: 2, y_range: [-1, 1]}

The keys of the force terms' data come from their declarations (:attr:`springsim.forces.ForceTerm.data`):
a pair term's list is the top-level key :attr:`~springsim.forces.ForceTerm.yaml_key` (``springs``,
``gravitational``) with ``particle_ids`` and the term's per-pair keys in each item; per-particle arrays are
keys of the ``particles`` items (``drag``); per-model arrays are keys of a mapping under the term's YAML key.

Every problem raises :class:`~springsim.errors.SceneError` whose message is one
line naming the field path (``particles[3]: unknown key 'colour'``). Items are
type-checked one by one (the YAML is a list of dicts, so that is linear in the
file size); the numbers are then converted to arrays in bulk and handed to the
builder's bulk forms, which validate values (finite, mass > 0, ids in range, ...)
vectorised.
"""

from __future__ import annotations

import gc
import hashlib
import inspect
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from .._runtime import memory
from ..errors import SceneError
from ..forces._data import data_terms, term_group
from ..model import AXES, Model
from ..model.builder import COEFFICIENT_ALIASES, ModelBuilder, resolve_cloth_grid
from ..model.topology import pin_mask
from ..run.options import SolverConfig
from ._yaml import (ALIAS_EXPANSION, MAX_NESTING, MAX_SCENE_BYTES, MIN_EXPANDED_NODES,  # noqa: F401 (the limits)
                    _check_document_shape, _Loader, _show, _type_name, _yaml_errors, open_scene_file)
from .gallery import BENCHMARK_DT, benchmark_cloth_grid

__all__ = ["Scene", "PlotSpec", "load_scene", "parse_scene", "check_generated_memory",
           "MAX_GENERATED_PARTICLES", "MAX_SCENE_BYTES", "MAX_NESTING"]


#: Largest particle count the generator blocks may create (read at call time), so a typo
#: such as ``nx: 1000000`` is an error rather than an out-of-memory crash. A smaller bound
#: comes from the memory available (:data:`GENERATED_BYTES_PER_PARTICLE`).
MAX_GENERATED_PARTICLES = 50_000_000

#: Peak memory of building a generated cloth, per particle [bytes] (1.07 GB for the 1024 x 1024
#: cloth); a generator block that would need more than the memory available is refused.
GENERATED_BYTES_PER_PARTICLE = 1100

#: Top-level keys; the force terms' keys (:func:`_term_keys`) go after ``particles``.
_TOP_KEYS = ("solver", "particles", "plot", "cloth", "benchmark_cloth", "pin", "name", "description")
#: Keys of a particle item; the per-particle arrays of the force terms follow.
_PARTICLE_KEYS = ("pos", "vel", "mass", "fixed", "radius")
_PLOT_KEYS = ("particle_id", "dof", "y_range")
_CLOTH_KEYS = tuple(p for p in inspect.signature(ModelBuilder.add_cloth_grid).parameters if p != "self")
_BENCH_KEYS = ("n",) + tuple(p for p in inspect.signature(benchmark_cloth_grid).parameters if p != "n")


# -- the result ---------------------------------------------------------------------------
@dataclass(frozen=True)
class PlotSpec:
    """The ``plot:`` block: which coordinate of which particle to plot.

    Attributes
    ----------
    particle_id : int
        Particle index, in range.
    dof : int
        Coordinate 0, 1 or 2 (x, y, z).
    y_range : tuple of float or None
        Vertical axis limits ``(lo, hi)`` [m], ``lo < hi``; None: automatic.
    """

    particle_id: int
    dof: int
    y_range: tuple[float, float] | None = None


@dataclass
class Scene:
    """A loaded scene.

    Attributes
    ----------
    model : Model
    config : SolverConfig
    plot : PlotSpec or None
    source : str
        File path, or ``"<string>"`` for text.
    name : str
        The scene's ``name:`` or the file's stem.
    metadata : dict
        The scene's other information: ``description`` (its ``description:``, empty when not given).
    sha256 : str
        SHA-256 (hex) of the bytes the scene was loaded from (the file as it was read, or the
        UTF-8 of the text); empty for scenes built from a parsed document.
    generator : dict or None
        For a scene that is one ``cloth:`` or ``benchmark_cloth:`` block and nothing else (no ``particles``, pair
        lists, term data or ``pin``), its description, from which a distributed run generates each rank's part
        (:func:`springsim.distributed.generated_part`) without building the whole model: ``grid`` (the keywords of
        :meth:`~springsim.ModelBuilder.add_cloth_grid`), ``gravity``, ``up_axis``, ``metadata`` and ``paths`` (the
        builder's error paths -> the block's). None for other scenes.
    stream : dict or None
        For a scene file loaded with ``build=False`` that is not one generator block alone: what a
        distributed run needs to read its lists in pieces on one rank and send every rank its part
        (:func:`springsim.distributed.streamed_part`): ``outline`` (:class:`~springsim.scene.yaml_stream.SceneOutline`),
        ``gravity``, ``up_axis``, ``model_data`` (term -> its per-model values, type-checked), ``pin`` (the ``pin:``
        value, checked where it is applied), ``metadata``, ``cloths`` (the generator blocks, as :attr:`generator`'s
        ``grid`` and ``paths``: ``(path, keywords, paths)`` each, their values checked) and ``generated`` (``(key,
        particles)``: what they create). The model is then not built (``model`` None). None for other scenes.
    """

    model: Model | None
    config: SolverConfig
    plot: PlotSpec | None = None
    source: str = "<string>"
    name: str = "scene"
    metadata: dict = field(default_factory=dict)
    sha256: str = ""
    generator: dict | None = None
    stream: dict | None = None


# -- small checks -------------------------------------------------------------------------
def _is_num(v) -> bool:
    t = type(v)
    return t is float or (t is int and -1e300 < v < 1e300)


def _is_int(v) -> bool:
    return type(v) is int






def _number(path: str, v, *, lo: float | None = None, strict: bool = False) -> float:
    if not _is_num(v):
        raise SceneError(path, f"must be a number, got {_type_name(v)} {_show(v)}")
    if not math.isfinite(v):
        raise SceneError(path, f"must be finite, got {_show(v)}")
    if lo is not None and (v <= lo if strict else v < lo):
        raise SceneError(path, f"must be {'>' if strict else '>='} {lo:g}, got {_show(v)}")
    return float(v)


def _vector(path: str, v, n: int = 3) -> list:
    if type(v) is not list or len(v) != n or not all(_is_num(x) for x in v):
        if type(v) is not list:
            raise SceneError(path, f"must be a list of {n} numbers, got {_type_name(v)} {_show(v)}")
        if len(v) != n:
            raise SceneError(path, f"must have {n} components, got {len(v)}")
        k = next(k for k, x in enumerate(v) if not _is_num(x))
        raise SceneError(f"{path}[{k}]", f"must be a number, got {_type_name(v[k])} {_show(v[k])}")
    return v


def _mapping(path: str, v, allowed: tuple[str, ...], required: tuple[str, ...] = (),
             aliases: dict | None = None) -> dict:
    if type(v) is not dict:
        raise SceneError(path, f"must be a mapping, got {_type_name(v)} {_show(v)}")
    _keys(path, v, allowed, required, aliases)
    return v


def _keys(path: str, d: dict, allowed, required=(), aliases: dict | None = None) -> None:
    for k in d:
        if k not in allowed:
            raise SceneError(path, f"unknown key {_show(k)}; allowed: {', '.join(allowed)}")
    for k in required:
        if k not in d:
            alias = next((a for a, c in (aliases or {}).items() if c == k), None)
            raise SceneError(path, f"missing required key {k!r}" + (f" (or its alias {alias!r})" if alias else ""))


def _item_list(path: str, v) -> list:
    if v is None:
        return []
    if type(v) is not list:
        raise SceneError(path, f"must be a list, got {_type_name(v)} {_show(v)}")
    return v


# -- sections -----------------------------------------------------------------------------
def _parse_solver(doc: dict, default_dt: float | None) -> tuple[SolverConfig, float, str]:
    """The ``solver:`` block: the run options (:class:`SolverConfig`) and the model's ``gravity`` and ``up_axis``."""
    s = doc.get("solver")
    if s is None:
        raise SceneError("solver", "missing required block (needs at least 'type' and 'timestep')")
    cfg, extra = SolverConfig.from_yaml(s, default_dt=default_dt, extra=("gravity", "up_axis"))
    gravity = _number("solver.gravity", extra.get("gravity", -9.81))
    up = extra.get("up_axis", "z")
    if up not in AXES and not (_is_int(up) and 0 <= up <= 2):
        raise SceneError("solver.up_axis", f"must be one of {', '.join(AXES)} (or 0, 1, 2), got {_show(up)}")
    return cfg, gravity, up


def _term_keys() -> list[tuple[str, type, str]]:
    """``(term, class, YAML key)`` of every registered term with a pair list or per-model data, in registry order.

    Raises ValueError when a term's YAML key is taken (by the format or another term): a registration error."""
    out = [(name, cls, term_group(name, cls)) for name, cls in data_terms()
           if any(spec.per != "particle" for spec in cls.data)]
    _distinct("top-level", _TOP_KEYS + tuple(key for _, _, key in out))
    return out


def _item_list_keys() -> tuple[str, ...]:
    """The top-level keys whose values are item lists: ``particles`` and every pair term's list."""
    return ("particles",) + tuple(key for _, cls, key in _term_keys() if any(s.per == "pair" for s in cls.data))


def _particle_specs() -> list:
    """The per-particle :class:`~springsim.forces.ArraySpec` s of the registered terms, in registry order."""
    specs = [spec for _, cls in data_terms() for spec in cls.data if spec.per == "particle"]
    _distinct("particle", _PARTICLE_KEYS + tuple(spec.key for spec in specs))
    return specs


def _distinct(what: str, keys: tuple) -> None:
    seen = set()
    for k in keys:
        if k in seen:
            raise ValueError(f"two force terms (or a force term and the scene format) declare the {what} YAML "
                             f"key {k!r}")
        seen.add(k)


def _term_value(path: str, spec, v):
    """A YAML value of ``spec``: a number (or a list of numbers for a vector array), checked for type only."""
    if spec.shape:
        return _vector(path, v, int(np.prod(spec.shape)))
    if not _is_num(v):
        _number(path, v)
    return v


def _parse_particles(items: list) -> dict[str, np.ndarray]:
    n = len(items)
    pos, vel, mass = [None] * n, [None] * n, [None] * n
    fixed, radius = [False] * n, [math.nan] * n
    specs = _particle_specs()
    keys = _PARTICLE_KEYS + tuple(spec.key for spec in specs)
    cols = {spec.name: [spec.default] * n if not spec.shape else [[spec.default] * int(np.prod(spec.shape))] * n
            for spec in specs}
    allowed, required = set(keys), ("pos", "mass")
    for k, p in enumerate(items):
        if type(p) is not dict or not allowed.issuperset(p) or "pos" not in p or "mass" not in p:
            _mapping(f"particles[{k}]", p, keys, required)
        pos[k] = _vector_fast(f"particles[{k}].pos", p["pos"])
        v = p.get("vel")
        vel[k] = (0.0, 0.0, 0.0) if v is None else _vector_fast(f"particles[{k}].vel", v)
        m = p["mass"]
        if not _is_num(m):
            _number(f"particles[{k}].mass", m)
        mass[k] = m
        if "fixed" in p:
            f = p["fixed"]
            if type(f) is not bool:
                raise SceneError(f"particles[{k}].fixed", f"must be true or false, got {_type_name(f)} {_show(f)}")
            fixed[k] = f
        r = p.get("radius")
        if r is not None:
            radius[k] = _number(f"particles[{k}].radius", r, lo=0.0)
        for spec in specs:
            x = p.get(spec.key)
            if x is not None:
                cols[spec.name][k] = _term_value(f"particles[{k}].{spec.key}", spec, x)
    out = {"pos": np.array(pos, dtype=np.float64).reshape(n, 3), "vel": np.array(vel, dtype=np.float64).reshape(n, 3),
           "mass": np.array(mass, dtype=np.float64), "fixed": np.array(fixed, dtype=bool),
           "radius": np.array(radius, dtype=np.float64)}
    out["arrays"] = {spec.name: np.array(cols[spec.name], dtype=np.float64).reshape((n,) + tuple(spec.shape))
                     for spec in specs}
    return out


def _vector_fast(path: str, v) -> list:
    # The common case costs one type test, one len and three type tests.
    if type(v) is list and len(v) == 3 and _is_num(v[0]) and _is_num(v[1]) and _is_num(v[2]):
        return v
    return _vector(path, v)


def _ids(path: str, v, n: int) -> list:
    if type(v) is list and len(v) == 2 and type(v[0]) is int and type(v[1]) is int \
            and 0 <= v[0] < n and 0 <= v[1] < n:
        return v
    if type(v) is not list:
        raise SceneError(path, f"must be a list of 2 particle ids, got {_type_name(v)} {_show(v)}")
    if len(v) != 2:
        raise SceneError(path, f"must have 2 particle ids, got {len(v)}")
    for x in v:
        if type(x) is not int:
            raise SceneError(path, f"particle ids must be integers, got {_show(v)}")
    raise SceneError(path, f"particle id out of range [0, {n}), got {_show(v)}")


def _parse_pairs(group: str, items: list, n: int, specs) -> dict:
    """Check the items of a pair term's list, whose per-pair arrays are ``specs``
    (:class:`~springsim.forces.ArraySpec`).

    Spec aliases are accepted for their canonical keys; ``out["aliases"]`` maps the index of every item that
    used one to {canonical: alias}, so that later errors can name the key as written. A computed array's value
    may be left out or null (its default); ``out[name]`` are the columns by array name, ``out["ids"]`` the pairs.
    """
    m = len(items)
    keys = ("particle_ids",) + tuple(spec.key for spec in specs)
    aliases = {a: spec.key for spec in specs for a in spec.aliases}
    allowed = set(keys) | set(aliases)
    alias_keys = frozenset(aliases)
    required = ("particle_ids",) + tuple(spec.key for spec in specs if spec.required)
    ids = [None] * m
    cols = {spec.key: [spec.default] * m if not spec.shape else [[spec.default] * int(np.prod(spec.shape))] * m
            for spec in specs}
    by_key = {spec.key: spec for spec in specs}
    spelled: dict[int, dict] = {}
    for k, s in enumerate(items):
        if alias_keys and type(s) is dict and not alias_keys.isdisjoint(s):
            s, spelled[k] = _unalias_item(f"{group}[{k}]", s, aliases)
        if type(s) is not dict or not allowed.issuperset(s) or not all(r in s for r in required):
            _mapping(f"{group}[{k}]", s, keys + tuple(aliases), required, aliases)
        ids[k] = _ids(f"{group}[{k}].particle_ids", s["particle_ids"], n)
        for key, col in cols.items():
            if key in s:
                x = s[key]
                spec = by_key[key]
                if spec.computed:
                    if x is None:  # null: the default
                        continue
                    if x != x:  # NaN would silently mean the default too (the builder's marker for it)
                        raise SceneError(f"{group}[{k}].{key}", "must be finite (leave it out or give null "
                                                                 "for the default), got nan")
                col[k] = _term_value(f"{group}[{k}].{key}", spec, x)
    out = {spec.name: np.array(cols[spec.key], dtype=np.float64).reshape((m,) + tuple(spec.shape)) for spec in specs}
    out["ids"] = np.array(ids, dtype=np.int64).reshape(m, 2)
    out["aliases"] = spelled
    return out


def _parse_model_data(group: str, v, specs) -> dict:
    """The mapping of a term's per-model arrays under its YAML key: array name -> value (type-checked)."""
    keys = tuple(spec.key for spec in specs)
    _mapping(group, v, keys, tuple(spec.key for spec in specs if spec.required))
    return {spec.name: _term_value(f"{group}.{spec.key}", spec, v[spec.key]) for spec in specs
            if v.get(spec.key) is not None}


def _unalias_item(path: str, item: dict, aliases: dict) -> tuple[dict, dict]:
    """``item`` with its alias keys renamed to the canonical ones, and {canonical: alias} of those renamed."""
    out, used = dict(item), {}
    for alias, canon in aliases.items():
        if alias in item:
            if canon in item:
                raise SceneError(path, f"give {canon} or its alias {alias}, not both")
            x = out.pop(alias)
            if not _is_num(x):
                _number(f"{path}.{alias}", x)
            out[canon] = x
            used[canon] = alias
    return out, used


def _spelled_as_written(err: SceneError, group: str, spelled: dict) -> SceneError:
    """``err`` naming ``group[k].ke`` when item ``k`` wrote the alias of the canonical key the builder reports."""
    m = re.fullmatch(re.escape(group) + r"\[(\d+)\]\.(\w+)", err.path)
    if m is not None:
        alias = spelled.get(int(m.group(1)), {}).get(m.group(2))
        if alias is not None:
            return type(err)(f"{group}[{m.group(1)}].{alias}", err.message)
    return err


def _grid_size(path: str, v) -> int:
    if not _is_int(v) or not 2 <= v <= MAX_GENERATED_PARTICLES:
        raise SceneError(path, f"must be an integer in [2, {MAX_GENERATED_PARTICLES}], got {_show(v)}")
    return v


def _parse_cloth(path: str, c) -> tuple[str, dict, dict]:
    """A ``cloth:`` block: ``(path, add_cloth_grid keywords, builder path -> YAML path)``.

    The keys are the parameters of :meth:`ModelBuilder.add_cloth_grid`, which validates their values;
    here only the keys and the grid size (for the particle-count and memory limits) are checked.
    """
    _mapping(path, c, _CLOTH_KEYS, ("nx", "ny"))
    kw = dict(c)
    kw["nx"], kw["ny"] = _grid_size(f"{path}.nx", c["nx"]), _grid_size(f"{path}.ny", c["ny"])
    return path, kw, {"cloth": path}


def _parse_benchmark(c) -> tuple[str, dict, dict]:
    """The ``benchmark_cloth:`` block (keys: the parameters of :func:`benchmark_cloth_grid`)."""
    path = "benchmark_cloth"
    _mapping(path, c, _BENCH_KEYS, ("n",))
    options = dict(c)
    n = _grid_size(f"{path}.n", options.pop("n"))
    # the grid's keyword (canonical) -> the block's key as written (an alias if the block used one)
    written = {COEFFICIENT_ALIASES.get(k, k): k for k in options}
    stiffness, damping = written.get("stiffness", "stiffness"), written.get("damping", "damping")
    paths = {"cloth.nx": f"{path}.n", "cloth.ny": f"{path}.n", "cloth.size": path, "cloth.bending": path,
             "cloth": path, "cloth.stiffness": f"{path}.{stiffness}", "cloth.damping": f"{path}.{damping}",
             "cloth.damping_shear": f"{path}.{damping}", "cloth.damping_bend": f"{path}.{damping}",
             "cloth.stiffness_shear": f"{path}.{written.get('stiffness_shear', stiffness)}",
             "cloth.stiffness_bend": f"{path}.{written.get('stiffness_bend', 'stiffness_bend')}"}
    return path, benchmark_cloth_grid(n, **options), paths


def _renamed(err: SceneError, paths: dict) -> SceneError:
    """``err`` with its builder path (``cloth.ke``) replaced by the YAML path (``cloth[1].ke``)."""
    for old in sorted(paths, key=len, reverse=True):
        if err.path == old or err.path.startswith(old + ".") or err.path.startswith(old + "["):
            return type(err)(paths[old] + err.path[len(old):], err.message)
    return err


def _parse_plot(p, n: int) -> PlotSpec:
    _mapping("plot", p, _PLOT_KEYS, ("particle_id", "dof"))
    pid, dof = p["particle_id"], p["dof"]
    if not _is_int(pid) or not 0 <= pid < n:
        raise SceneError("plot.particle_id", f"must be an integer particle id in [0, {n}), got {_show(pid)}")
    if not _is_int(dof) or not 0 <= dof <= 2:
        raise SceneError("plot.dof", f"must be 0, 1 or 2, got {_show(dof)}")
    yr = p.get("y_range")
    if yr is not None:
        lo, hi = (_number(f"plot.y_range[{k}]", x) for k, x in enumerate(_vector("plot.y_range", yr, 2)))
        if not lo < hi:
            raise SceneError("plot.y_range", f"needs lo < hi, got {_show(yr)}")
        yr = (lo, hi)
    return PlotSpec(particle_id=pid, dof=dof, y_range=yr)


# -- entry points -------------------------------------------------------------------------
def check_generated_memory(where: str, particles: int, ranks: int = 1) -> None:
    """Refuse generator blocks whose model would not fit in the memory available (a one-line error, before any
    allocation).

    Parameters
    ----------
    where : str
        The block's path, for the message (``cloth``, ``benchmark_cloth``).
    particles : int
        Particles the blocks create.
    ranks : int
        Processes that share them (a distributed run generates ``1/ranks`` of them in each process).

    Raises
    ------
    SceneError
        Building needs more than the available memory (:data:`GENERATED_BYTES_PER_PARTICLE` per particle).
    """
    need, have = particles * GENERATED_BYTES_PER_PARTICLE / ranks, memory.available_memory()
    if have is not None and need > have:
        share = "" if ranks == 1 else f" ({ranks} processes share them)"
        raise SceneError(where, f"generator blocks would create {particles} particles{share}, which need about "
                                f"{need / 2**30:.1f} GiB to build; {have / 2**30:.1f} GiB of memory are available")


def _check_top(doc, source: str) -> list:
    """Check the top level of a document (a mapping of known keys, ``name`` and ``description`` strings); the
    registered terms' keys (:func:`_term_keys`)."""
    if doc is None:
        raise SceneError(source, "empty scene file")
    if type(doc) is not dict:
        raise SceneError(source, f"the top level must be a mapping of sections, got {_type_name(doc)}")
    terms = _term_keys()
    allowed = _TOP_KEYS[:2] + tuple(key for _, _, key in terms) + _TOP_KEYS[2:]
    for k in doc:
        if k not in allowed and not (isinstance(k, str) and k.startswith("x-")):
            raise SceneError(source, f"unknown top-level key {_show(k)}; allowed: {', '.join(allowed)} (and x-* keys)")
    for key in ("name", "description"):
        if key in doc and not isinstance(doc[key], str):
            raise SceneError(key, f"must be a string, got {_type_name(doc[key])}")
    return terms


def _model_data(doc: dict, terms: list) -> dict:
    """Term -> its per-model values (the mapping under its YAML key), for the terms without a pair list."""
    return {term: _parse_model_data(key, doc[key], [spec for spec in cls.data if spec.per == "model"])
            for term, cls, key in terms
            if not any(spec.per == "pair" for spec in cls.data) and doc.get(key) is not None}


def _parse_generators(doc: dict) -> tuple[list, int, str]:
    """The generator blocks (``cloth:``, a list of them, ``benchmark_cloth:``) in the order they add particles:
    ``(path, add_cloth_grid keywords, builder path -> YAML path)`` each; the particles they create, at most
    :data:`MAX_GENERATED_PARTICLES`; the key to name in errors about them."""
    cloth = doc.get("cloth")
    if cloth is None:
        cloths = []
    elif type(cloth) is dict:
        cloths = [_parse_cloth("cloth", cloth)]
    elif type(cloth) is list:
        cloths = [_parse_cloth(f"cloth[{k}]", c) for k, c in enumerate(cloth)]
    else:
        raise SceneError("cloth", f"must be a mapping or a list of mappings, got {_type_name(cloth)}")
    if "benchmark_cloth" in doc:
        cloths.append(_parse_benchmark(doc["benchmark_cloth"]))
    generated = sum(kw["nx"] * kw["ny"] for _, kw, _ in cloths)
    where = "cloth" if "cloth" in doc else "benchmark_cloth"
    if generated > MAX_GENERATED_PARTICLES:
        raise SceneError(where, f"generator blocks would create {generated} particles, more than the limit "
                                f"springsim.scene.yaml_io.MAX_GENERATED_PARTICLES = {MAX_GENERATED_PARTICLES}")
    return cloths, generated, where


def _single_generator(doc: dict, cloths: list, terms: list) -> bool:
    """Whether a scene is one generator block and nothing else (no particles, pair lists, term data or ``pin``):
    a distributed run generates its parts (:attr:`Scene.generator`)."""
    return len(cloths) == 1 and all(doc.get(key) is None for key in ("particles", "pin") + tuple(
        key for _, _, key in terms))


def _outlined_scene(outline) -> Scene:
    """The :class:`Scene` of a file's outline (:func:`springsim.scene.yaml_stream.outline`) with item lists: every
    section but the lists checked (the generator blocks' values too), the model left to be built in parts
    (:attr:`Scene.stream`)."""
    doc, source = outline.doc, outline.source
    terms = _check_top(doc, source)
    for key in _item_list_keys():  # a list read in pieces is [] here; anything else but null is an error
        _item_list(key, doc.get(key))
    cloths, generated, where = _parse_generators(doc)
    grids = []
    for path, kw, paths in cloths:  # the blocks' values, checked now; their pins where they are generated
        try:
            grids.append(resolve_cloth_grid(**{k: v for k, v in kw.items() if k != "pin"}))
        except SceneError as e:
            raise _renamed(e, paths) from None
    cfg, gravity, up = _parse_solver(doc, BENCHMARK_DT if "benchmark_cloth" in doc else None)
    n = outline.counts.get("particles", 0) + generated
    if n == 0:
        raise SceneError("particles", "the scene has no particles (give 'particles', 'cloth' or 'benchmark_cloth')")
    model_data = _model_data(doc, terms)
    plot = _parse_plot(doc["plot"], n) if doc.get("plot") is not None else None
    name = doc.get("name") or Path(source).stem
    stream = dict(outline=outline, gravity=gravity, up_axis=up, model_data=model_data, pin=doc.get("pin"),
                  metadata=dict(name=name, source=source), cloths=cloths, generated=(where, generated))
    return Scene(model=None, config=cfg, plot=plot, source=source, name=name,
                 metadata={"description": doc.get("description", "")}, sha256=outline.sha256, stream=stream)


def parse_scene(doc, *, source: str = "<string>", build: bool = True) -> Scene:
    """Build a :class:`Scene` from an already-parsed YAML document (a dict).

    Parameters
    ----------
    doc : dict
        The parsed YAML document.
    source : str
        Name of the document's origin (file path) for error messages.
    build : bool
        If False and the scene is one generator block (:attr:`Scene.generator`), the model is not built
        (``model`` None; the block's values are then checked where its parts are generated) and the memory the
        whole model would need is not required here (:func:`check_generated_memory` with the number of
        processes, where they are known); other scenes are built either way.

    Returns
    -------
    Scene

    Raises
    ------
    SceneError
        On any invalid content, with a one-line message naming the field path.
    """
    terms = _check_top(doc, source)

    # generator blocks first, to know the particle count for id checks
    cloths, generated, where = _parse_generators(doc)
    # one generator block alone: a distributed run generates its parts (Scene.generator)
    single = _single_generator(doc, cloths, terms)
    lazy = single and not build
    if not lazy:
        check_generated_memory(where, generated)
    cfg, gravity, up = _parse_solver(doc, BENCHMARK_DT if "benchmark_cloth" in doc else None)

    particles = _parse_particles(_item_list("particles", doc.get("particles")))
    n_explicit = particles["pos"].shape[0]
    n = n_explicit + generated
    if n == 0:
        raise SceneError("particles", "the scene has no particles (give 'particles', 'cloth' or 'benchmark_cloth')")
    pairs = {term: _parse_pairs(key, _item_list(key, doc.get(key)), n, [spec for spec in cls.data if spec.per == "pair"])
             for term, cls, key in terms if any(spec.per == "pair" for spec in cls.data)}
    model_data = _model_data(doc, terms)
    plot = _parse_plot(doc["plot"], n) if doc.get("plot") is not None else None

    name = doc.get("name") or (Path(source).stem if source != "<string>" else "scene")
    generator = None
    if single:
        _, kw, paths = cloths[0]
        generator = dict(grid=dict(kw), gravity=gravity, up_axis=up, metadata=dict(name=name, source=source),
                         paths=dict(paths))
    if lazy:
        return Scene(model=None, config=cfg, plot=plot, source=source, name=name,
                     metadata={"description": doc.get("description", "")}, generator=generator)
    b = ModelBuilder(gravity=gravity, up_axis=up)
    if n_explicit:
        b.add_particles(particles["pos"], particles["vel"], particles["mass"], radius=particles["radius"],
                        fixed=particles["fixed"], **particles["arrays"])
    # explicit pairs before generated ones, so builder paths springs[k] match the file
    for term, items in pairs.items():
        if items["ids"].shape[0]:
            b.add_pairs(term, items["ids"], **{k: v for k, v in items.items() if k not in ("ids", "aliases")})
    for term, values in model_data.items():
        b.set_term_data(term, **values)
    for path, kw, paths in cloths:
        try:
            b.add_cloth_grid(**kw)
        except SceneError as e:
            raise _renamed(e, paths) from None
    if doc.get("pin") is not None:  # after every particle exists: global indices, boxes over the whole scene
        b.set_fixed(pin_mask(doc["pin"], b.particle_count, positions=b.particle_q, path="pin"))
    b.metadata.update(name=name, source=source)
    try:
        model = b.finalize()
    except SceneError as e:
        for term, cls, key in terms:
            if term in pairs:
                e = _spelled_as_written(e, key, pairs[term]["aliases"])
        raise e from None
    return Scene(model=model, config=cfg, plot=plot, source=source, name=name,
                 metadata={"description": doc.get("description", "")}, generator=generator)


def _read_scene_file(source: str) -> tuple[str, bytes]:
    """The text of a scene file (a regular file of at most :data:`MAX_SCENE_BYTES`, UTF-8) and its bytes."""
    fh, _ = open_scene_file(source)
    try:
        with fh:
            data = fh.read(MAX_SCENE_BYTES + 1)  # bounded even if the file grows while it is read
    except OSError as e:
        raise SceneError(source, f"cannot read: {e.strerror or e}") from None
    if len(data) > MAX_SCENE_BYTES:
        raise SceneError(source, f"is more than the limit of {MAX_SCENE_BYTES} bytes")
    try:
        return data.decode("utf-8"), data
    except UnicodeDecodeError as e:
        raise SceneError(source, f"not UTF-8 text (byte {e.start})") from None


def _looks_like_path(x) -> bool:
    if isinstance(x, os.PathLike):
        return True
    if not isinstance(x, str) or "\n" in x:
        return False
    return x.endswith((".yaml", ".yml")) or os.path.isfile(x)


def load_scene(path_or_text, *, build: bool = True) -> Scene:
    """Load a scene from a YAML file path or from YAML text.

    Parameters
    ----------
    path_or_text : str or os.PathLike
        A path (a ``PathLike``, or a one-line string ending in ``.yaml``/``.yml`` or
        naming an existing file) or the YAML text itself.
    build : bool
        False, for a file: the model is not built. A scene of one generator block is described
        (:attr:`Scene.generator`); any other is outlined, its item lists not read (:attr:`Scene.stream`,
        :mod:`springsim.scene.yaml_stream`).

    Returns
    -------
    Scene

    Raises
    ------
    SceneError
        One-line ``path: message`` for every problem: missing or unreadable file, YAML
        syntax errors (with line and column), invalid content.

    Examples
    --------
    >>> s = load_scene("solver: {type: implicit_euler, timestep: 0.01}\\n"
    ...                "particles: [{pos: [0, 0, 0], mass: 1}]\\n")
    >>> s.model.particle_count, s.config.integrator
    (1, 'implicit_euler')
    """
    if not build and _looks_like_path(path_or_text):
        return _outlined(os.fspath(path_or_text))
    if _looks_like_path(path_or_text):
        source = os.fspath(path_or_text)
        text, data = _read_scene_file(source)
    elif isinstance(path_or_text, str):
        source, text = "<string>", path_or_text
        if len(text) > MAX_SCENE_BYTES:
            raise SceneError(source, f"is more than the limit of {MAX_SCENE_BYTES} bytes")
        data = text.encode("utf-8", "surrogatepass")
    else:
        raise SceneError("", f"expected a path or YAML text, got {type(path_or_text).__name__}")
    with _yaml_errors(source):
        _check_document_shape(text, source)
        gc_was = gc.isenabled()
        gc.disable()  # the collector would scan the growing document again and again (3x the time of a big load)
        try:
            doc = yaml.load(text, Loader=_Loader)  # noqa: S506 (a SafeLoader subclass)
        finally:
            if gc_was:
                gc.enable()
    try:
        scene = parse_scene(doc, source=source, build=build)
    except RecursionError:
        raise SceneError(source, "YAML document is nested too deeply") from None
    except MemoryError:
        raise SceneError(source, "the scene does not fit in memory") from None
    scene.sha256 = hashlib.sha256(data).hexdigest()  # of the bytes parsed, whatever happens to the file later
    return scene


def _outlined(source: str) -> Scene:
    """The scene of a file read as an outline (:func:`load_scene` with ``build=False``): a scene of one generator block
    left to be generated per rank (:attr:`Scene.generator`), any other left to be read and built in parts
    (:attr:`Scene.stream`)."""
    from .yaml_stream import outline

    o = outline(source, _item_list_keys())
    try:
        if not o.counts and type(o.doc) is dict and _single_generator(o.doc, _parse_generators(o.doc)[0],
                                                                       _term_keys()):
            scene = parse_scene(o.doc, source=source, build=False)  # generated per rank from its description
        else:
            scene = _outlined_scene(o)
    except RecursionError:
        raise SceneError(source, "YAML document is nested too deeply") from None
    scene.sha256 = o.sha256
    return scene
