"""The immutable :class:`Model` (what is constant during a run) and the :class:`State`.

Symbols used throughout springsim: ``N`` particles, ``q`` positions and ``qd``
velocities of shape (N, 3) [m], [m/s]; ``M`` the diagonal mass matrix.
"""

from __future__ import annotations

import functools
import hashlib
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from types import MappingProxyType
from typing import NamedTuple

import numpy as np

__all__ = ["Model", "State", "ClothGrid", "AXES", "FINGERPRINT_V1"]

#: Names of the coordinate axes, as accepted for ``up_axis``.
AXES = ("x", "y", "z")


def _frozen_data(a: np.ndarray) -> bool:
    """Whether ``a`` is a read-only C-contiguous view of an immutable ``bytes`` object (made by :func:`_readonly`)."""
    base = a
    while isinstance(base, np.ndarray):
        base = base.base
    return type(base) is bytes and not a.flags.writeable and a.flags.c_contiguous


def _readonly(a: np.ndarray) -> np.ndarray:
    """``a`` as a C-contiguous array over a private, immutable copy of its data.

    The data lives in a ``bytes`` object, so neither ``setflags(write=True)`` (numpy refuses it for an
    array whose base is read-only) nor writing through the caller's array can change it.
    """
    if _frozen_data(a):
        return a  # already private and immutable (a shallow copy of a model shares it)
    a = np.ascontiguousarray(a)
    return np.frombuffer(a.tobytes(), dtype=a.dtype).reshape(a.shape)


def _rebuild(cls, kwargs: dict):
    """Unpickle (or copy) a :class:`Model`: through ``__init__``, so that its arrays are frozen again."""
    return cls(**kwargs)


class ClothGrid(NamedTuple):
    """A cloth grid inside a model: particle ``(i, j)`` is ``start + j*nx + i``.

    Attributes
    ----------
    start : int
        Index of the grid's particle (0, 0) in the model.
    nx, ny : int
        Particles along the grid's first and second axis.
    """

    start: int
    nx: int
    ny: int


#: The arrays the fingerprint hashed before force terms declared their data (the model's fields then), in that
#: order: every model's fingerprint stays what it was (saved trajectories and the reference cache record it).
FINGERPRINT_V1 = ("particle_q", "particle_qd", "particle_mass", "particle_radius", "particle_drag", "particle_fixed",
                  "spring_indices", "spring_stiffness", "spring_damping", "spring_rest_length",
                  "gravitational_indices", "gravitational_G", "gravitational_softening")


def fingerprint_v1_names() -> list[str]:
    """The names of :data:`FINGERPRINT_V1` that a model has with the registered terms, in the order
    :meth:`Model.fingerprint` hashes them.

    Returns
    -------
    list of str
    """
    from ..forces._data import term_attributes

    table = term_attributes(reserved=_model_names())
    return [name for name in FINGERPRINT_V1 if name in table or name in Model.__dataclass_fields__]


def streamed_fingerprint(v1, *, gravity, up_axis, pair_epsilon, cloth_grids, beyond=()) -> str:
    """:meth:`Model.fingerprint` of arrays given in pieces: the same SHA-256 as the whole arrays give.

    A model's fingerprint is the hash of one byte stream: each array's name, dtype and shape, then its bytes
    (little-endian); then the scalars; then the arrays beyond :data:`FINGERPRINT_V1`. So an array may come as
    a sequence of pieces along its first axis, generated one at a time, and the memory is one piece's rather than
    the model's (:func:`springsim.distributed.scene.cloth_grid_fingerprint`).

    Parameters
    ----------
    v1 : iterable of (str, tuple, dtype, iterable of ndarray)
        The arrays of :func:`fingerprint_v1_names`, in that order: name, whole shape, dtype, and the pieces, which
        concatenated along the first axis make the array.
    gravity, up_axis, pair_epsilon, cloth_grids
        The model's scalars (:class:`Model`).
    beyond : iterable of (str, tuple, dtype, iterable of ndarray)
        :meth:`Model.data_beyond_v1`, likewise.

    Returns
    -------
    str
        64 hexadecimal digits.

    Raises
    ------
    ValueError
        Pieces of another dtype or trailing shape than declared, or not adding up to the declared length.
    """
    h = hashlib.sha256()

    def array(name, shape, dtype, pieces):
        dtype = np.dtype(dtype).newbyteorder("<")
        shape = tuple(int(x) for x in shape)
        h.update(name.encode())
        h.update(f"{dtype.str}{shape}".encode())
        rows = 0
        for p in pieces:
            p = np.asarray(p)
            if p.dtype.newbyteorder("<") != dtype or p.shape[1:] != shape[1:]:
                raise ValueError(f"{name}: a piece of dtype {p.dtype} and shape {p.shape}, declared {dtype} {shape}")
            h.update(np.ascontiguousarray(p, dtype=dtype).tobytes())
            rows += p.shape[0]
        if rows != shape[0]:
            raise ValueError(f"{name}: the pieces have {rows} rows, declared {shape[0]}")

    for item in v1:
        array(*item)
    for name, v in (("gravity", gravity), ("up_axis", up_axis), ("pair_epsilon", pair_epsilon),
                    ("cloth_grids", cloth_grids)):
        v = tuple(tuple(int(x) for x in g) for g in v) if name == "cloth_grids" else float(v)
        h.update(name.encode())
        h.update(repr(v).encode())
    for item in beyond:
        array(*item)
    return h.hexdigest()


@functools.lru_cache(maxsize=1)
def _model_names() -> frozenset:
    """The names the :class:`Model` itself has (fields, properties, methods): not term data."""
    return frozenset(dir(Model)) | frozenset(Model.__dataclass_fields__)


def _registered() -> dict:
    from ..forces import FORCE_TERMS

    return FORCE_TERMS


def _term_arrays(name: str, cls, given: dict, n: int) -> dict:
    """The data of term ``name`` (class ``cls``) for ``n`` particles: the arrays of ``given`` (array name -> values)
    checked against the term's specs, the others at their defaults; read-only."""
    given = dict(given)
    out = {}
    specs = cls.data
    if any(s.per == "pair" for s in specs):
        ij = np.asarray(given.pop("indices", np.zeros((0, 2), dtype=np.int64)))
        if ij.size == 0:
            ij = ij.reshape(0, 2)
        if ij.ndim != 2 or ij.shape[1] != 2:
            raise ValueError(f"{name}_indices must have shape (P, 2), got {ij.shape}")
        out["indices"] = _readonly(ij.astype(np.int64, copy=False))
    count = {"particle": n, "pair": out["indices"].shape[0] if "indices" in out else 0}
    for spec in specs:
        shape = tuple(spec.shape) if spec.per == "model" else (count[spec.per],) + tuple(spec.shape)
        v = given.pop(spec.name, None)
        if v is None:
            a = np.full(shape, spec.default, dtype=np.float64)
        else:
            a = np.asarray(v, dtype=np.float64)
            if a.shape != shape:
                what = f"particle_{spec.name}" if spec.per == "particle" else f"{name}_{spec.name}"
                raise ValueError(f"{what} must have shape {shape}, got {a.shape}")
        out[spec.name] = _readonly(a)
    if given:
        raise ValueError(f"force term {name!r} declares no array {sorted(given)[0]!r}")
    return out


def _has_data(cls, data) -> bool:
    """Whether a term's data does anything: a pair, or a value other than its default (for a term no longer
    registered, whose defaults are unknown: a pair, or a value other than 0 and NaN)."""
    if cls is None:
        if "indices" in data:
            return bool(np.asarray(data["indices"]).size)
        return any(np.any(np.nan_to_num(np.asarray(v, dtype=np.float64)) != 0) for v in data.values())
    if "indices" in data and data["indices"].shape[0]:
        return True
    for spec in cls.data:
        a = data.get(spec.name)
        if spec.per != "pair" and a is not None and a.size:
            same = (a == spec.default) | (np.isnan(a) & (spec.default != spec.default))
            if not np.all(same):
                return True
    return False


@dataclass(frozen=True, eq=False, init=False)
class Model:
    """A validated mass-spring system; build it with :class:`springsim.ModelBuilder`.

    All arrays are read-only, over private copies of the data that nothing can make writable (not
    ``setflags(write=True)``, not writing to the arrays the model was built from); pickling and
    copying (``copy.copy``, ``copy.deepcopy``) give models that are just as immutable. Integrators
    never write to a model.

    The particles' own data (positions, velocities, masses, radii, fixed flags) are fields; everything a
    force term needs is the term's data (:attr:`terms`), declared by the term
    (:attr:`springsim.forces.ForceTerm.data`) and exposed as attributes: ``particle_<array>`` for per-particle
    arrays, ``<term>_<array>`` for per-pair and per-model ones, ``<term>_indices`` for a pair list and
    ``<term>_count`` for its length. The constructor takes them as keywords of those names too
    (``spring_stiffness=...``), or per term in ``terms``; arrays not given take their declared defaults (no
    pairs, default values).

    Attributes
    ----------
    particle_q : ndarray, shape (N, 3)
        Initial positions [m].
    particle_qd : ndarray, shape (N, 3)
        Initial velocities [m/s] (zero for fixed particles).
    particle_mass : ndarray, shape (N,)
        Masses [kg], all > 0.
    particle_radius : ndarray, shape (N,)
        Radii [m] used only for drawing (NaN where not given).
    particle_fixed : ndarray of bool, shape (N,)
        Fixed particles never move.
    terms : mapping
        Term name -> (array name -> read-only array) for every registered term that declares data
        (:data:`springsim.forces.FORCE_TERMS`), in registry order; a pair term's pair list is ``"indices"``.
        With the built-in terms: ``particle_drag`` (N,) [N s/m], the linear drag coefficients beta of
        ``F = -beta qd``; ``spring_indices`` (S, 2), ``spring_stiffness`` (S,) ke [N/m], ``spring_damping``
        (S,) kd [N s/m] of the damping force along the spring (PA2 eq. 8), ``spring_rest_length`` (S,) l0 [m];
        ``gravitational_indices`` (P, 2), ``gravitational_G`` (P,), the gravitational constant of each pair
        [N m^2/kg^2], and ``gravitational_softening`` (P,), the softening length of each pair [m] (below it
        the attraction has a linear core, see :mod:`springsim.forces.gravitational`; default
        :func:`springsim.forces.gravitational.default_softening`).
    gravity : float
        Acceleration along the up axis [m/s^2] (default -9.81).
    up_axis : int
        0, 1 or 2 for x, y, z.
    pair_epsilon : float
        Distance [m] below which a spring's direction is treated as undefined (see
        :mod:`springsim.forces.spring`).
    cloth_grids : tuple of ClothGrid
        The cloth grids added by :meth:`springsim.ModelBuilder.add_cloth_grid` (for drawing and
        export: their quads are faces).
    metadata : dict
        Free-form information (``name``, ``source``) carried along; not used by the numerics.

    Parameters
    ----------
    particle_q : array_like, shape (N, 3)
        Initial positions [m].
    particle_qd : array_like, shape (N, 3)
        Initial velocities [m/s].
    particle_mass : array_like, shape (N,)
        Masses [kg].
    particle_radius : array_like, shape (N,), optional
        Drawing radii [m]; default NaN (not given).
    particle_fixed : array_like of bool, shape (N,), optional
        Fixed particles; default none.
    terms : mapping, optional
        Term name -> (array name -> array): the term data given per term; arrays not given take their declared
        defaults (no pairs, default values).
    gravity : float
        Acceleration along the up axis [m/s^2]; default -9.81.
    up_axis : int
        0, 1 or 2; default 2 (z).
    pair_epsilon : float
        Distance [m] below which a spring's direction is undefined; default 1e-9.
    cloth_grids : sequence of ClothGrid
        The model's cloth grids; default none.
    metadata : dict, optional
        Free-form information; default an empty dict.
    **arrays
        Term data by attribute name (``spring_stiffness=...``, ``particle_drag=...``), merged into ``terms``.

    Raises
    ------
    TypeError
        A keyword that names no term array (a ``<term>_count`` included).
    ValueError
        A term array of the wrong shape, or an unknown array name of a term.

    Notes
    -----
    The constructor checks the term arrays' shapes, not their values (:meth:`springsim.ModelBuilder.finalize`
    does): make models with the builder or the scene loader.
    """

    particle_q: np.ndarray
    particle_qd: np.ndarray
    particle_mass: np.ndarray
    particle_radius: np.ndarray
    particle_fixed: np.ndarray
    terms: Mapping
    gravity: float = -9.81
    up_axis: int = 2
    pair_epsilon: float = 1e-9
    cloth_grids: tuple = ()
    metadata: dict = field(default_factory=dict)

    def __init__(self, particle_q, particle_qd, particle_mass, particle_radius=None, particle_fixed=None,
                 terms: Mapping | None = None, gravity: float = -9.81, up_axis: int = 2, pair_epsilon: float = 1e-9,
                 cloth_grids: tuple = (), metadata: dict | None = None, **arrays):
        from ..forces._data import data_terms, term_attributes

        q = np.asarray(particle_q, dtype=np.float64).reshape(-1, 3)
        n = q.shape[0]
        radius = np.full(n, np.nan) if particle_radius is None else particle_radius
        fixed = np.zeros(n, dtype=bool) if particle_fixed is None else particle_fixed
        base = dict(particle_q=q, particle_qd=particle_qd, particle_mass=particle_mass, particle_radius=radius,
                    particle_fixed=fixed)
        for k, v in base.items():
            object.__setattr__(self, k, _readonly(np.asarray(v)))
        given = {t: dict(d) for t, d in (terms or {}).items()}
        table = term_attributes(reserved=_model_names())
        for attr, v in arrays.items():
            hit = table.get(attr)
            if hit is None or hit[1] == "count":
                raise TypeError(f"Model() got an unexpected keyword argument {attr!r}")
            given.setdefault(hit[0], {})[hit[1]] = v
        out = {}
        for name, cls in data_terms():
            out[name] = MappingProxyType(_term_arrays(name, cls, given.pop(name, {}), n))
        for name, d in given.items():  # a term no longer registered: kept as it was
            out[name] = MappingProxyType({k: _readonly(np.asarray(v)) for k, v in d.items()})
        object.__setattr__(self, "terms", MappingProxyType(out))
        object.__setattr__(self, "gravity", gravity)
        object.__setattr__(self, "up_axis", up_axis)
        object.__setattr__(self, "pair_epsilon", pair_epsilon)
        object.__setattr__(self, "cloth_grids", tuple(cloth_grids))
        object.__setattr__(self, "metadata", {} if metadata is None else metadata)

    def __getattr__(self, name: str):
        # only reached when ordinary lookup fails: the term data's names (``spring_stiffness``, ``particle_drag``)
        if name.startswith("__") or name == "terms":
            raise AttributeError(name)
        from ..forces._data import term_attributes

        hit = term_attributes(reserved=_model_names()).get(name)
        if hit is None:
            raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")
        term, array = hit
        data = self.terms.get(term)
        if data is None:  # a term registered after the model was built: its defaults
            data = _term_arrays(term, _registered()[term], {}, self.particle_count)
        value = int(data["indices"].shape[0]) if array == "count" else data[array]
        object.__setattr__(self, name, value)  # the next access is an ordinary one (the data never change)
        return value

    def __reduce__(self):
        # The default would restore the fields without __init__: unpickled arrays would be writable.
        kw = {f.name: getattr(self, f.name) for f in fields(self)}
        kw["terms"] = {t: dict(d) for t, d in self.terms.items()}
        return _rebuild, (type(self), kw)

    # -- counts ---------------------------------------------------------------
    @property
    def particle_count(self) -> int:
        """Number of particles N, fixed ones included."""
        return int(self.particle_mass.shape[0])

    @property
    def free_particles(self) -> np.ndarray:
        """Indices of the particles that move, shape (F,)."""
        return np.flatnonzero(~self.particle_fixed)

    @property
    def free_count(self) -> int:
        """Number of particles that move, F."""
        return int(self.particle_count - np.count_nonzero(self.particle_fixed))

    @property
    def dof_count(self) -> int:
        """Degrees of freedom of the implicit system (3 per free particle)."""
        return 3 * self.free_count

    @property
    def gravity_vector(self) -> np.ndarray:
        """The gravitational acceleration (3,) [m/s^2]: :attr:`gravity` along :attr:`up_axis`."""
        g = np.zeros(3)
        g[self.up_axis] = self.gravity
        return g

    def dissipates(self) -> bool:
        """Whether any dissipation coefficient of the model is non-zero.

        Returns
        -------
        bool
            True where an array its force terms declare ``dissipative`` (:class:`springsim.forces.ArraySpec`:
            spring damping, drag) has a non-zero value.
        """
        from ..forces._data import data_terms

        return any(np.any(self.terms[name][spec.name] != 0) for name, cls in data_terms() if name in self.terms
                   for spec in cls.data if spec.dissipative)

    def state(self) -> "State":
        """A fresh :class:`State` initialised from the model.

        Returns
        -------
        State
            Writable copies of :attr:`particle_q` and :attr:`particle_qd`.
        """
        return State(self.particle_q.copy(), self.particle_qd.copy())

    def fingerprint(self) -> str:
        """SHA-256 (hex) of everything that determines the motion: every array, ``gravity``,
        ``up_axis``, ``pair_epsilon`` and the cloth grids, not ``metadata``.

        Two models with equal fingerprints simulate identically; the value is the same on every
        machine (arrays are hashed as little-endian bytes with their dtype and shape). Saved
        trajectories record it (:meth:`springsim.run.driver.Trajectory.save`). The arrays of
        :data:`FINGERPRINT_V1` come first, as they always have; then the scalars; then, by term name, the data
        of every other term that has any (a pair, or a value other than its default). So registering a term
        does not change the fingerprint of a model that does not use it.

        Returns
        -------
        str
            64 hexadecimal digits.
        """
        def whole(name, v):
            return name, v.shape, v.dtype, [v]

        return streamed_fingerprint([whole(name, getattr(self, name)) for name in fingerprint_v1_names()],
                                    gravity=self.gravity, up_axis=self.up_axis, pair_epsilon=self.pair_epsilon,
                                    cloth_grids=self.cloth_grids,
                                    beyond=[whole(name, v) for name, v in self.data_beyond_v1()])

    def data_beyond_v1(self) -> list[tuple[str, np.ndarray]]:
        """The term data that :data:`FINGERPRINT_V1` does not cover, of the terms that have data (a pair, or a value
        other than the default): what :meth:`fingerprint` hashes after the scalars, and what any other key of a
        model's data (a cache key) must add to the V1 arrays.

        Returns
        -------
        list of (str, ndarray)
            ``("<term>.<array>", array)`` by term name, each term's pair list first, then its arrays in declared
            order; empty for every model of the built-in terms.
        """
        from ..forces._data import term_attributes

        table = term_attributes(reserved=_model_names())
        done = {table[name] for name in FINGERPRINT_V1 if name in table}
        registry = _registered()
        out = []
        for term in sorted(self.terms):
            data = self.terms[term]
            if _has_data(registry.get(term), data):
                out.extend((f"{term}.{key}", v) for key, v in data.items() if (term, key) not in done)
        return out

    def __repr__(self) -> str:
        from ..forces._data import data_terms, term_group

        pairs = "".join(f", {term_group(name, cls)}={getattr(self, name + '_count')}"
                        for name, cls in data_terms() if any(s.per == "pair" for s in cls.data))
        return f"Model(particles={self.particle_count}, fixed={int(self.particle_fixed.sum())}{pairs})"


@dataclass
class State:
    """Positions and velocities of all particles.

    Attributes
    ----------
    particle_q : ndarray, shape (N, 3)
        Positions [m].
    particle_qd : ndarray, shape (N, 3)
        Velocities [m/s].
    """

    particle_q: np.ndarray
    particle_qd: np.ndarray

    def copy(self) -> "State":
        """A deep copy (new position and velocity arrays).

        Returns
        -------
        State
        """
        return State(self.particle_q.copy(), self.particle_qd.copy())

    def is_finite(self) -> bool:
        """Whether every position and velocity is finite.

        Returns
        -------
        bool
        """
        return bool(np.isfinite(self.particle_q).all() and np.isfinite(self.particle_qd).all())
