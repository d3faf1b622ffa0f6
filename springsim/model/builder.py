"""`ModelBuilder`: assemble a :class:`~springsim.model.model.Model` item by item or in bulk.

Single-item calls (``add_particle``, ``add_spring``, ``add_gravitational``) return the
new item's index; their bulk twins (``add_particles``, ``add_springs``,
``add_gravitationals``) take arrays and return the index range, so a million springs
are added without a Python loop. Every force term's data goes in through its declarations
(:attr:`springsim.forces.ForceTerm.data`): :meth:`ModelBuilder.add_pairs` for a pair term (``add_springs``
and ``add_gravitationals`` are thin wrappers), keywords of :meth:`ModelBuilder.add_particles` for per-particle
arrays (``drag``), :meth:`ModelBuilder.set_term_data` for per-model ones.
:meth:`ModelBuilder.finalize` validates everything
and raises :class:`~springsim.errors.SceneError` naming the first offending item,
with the same field paths as the YAML scene format (``springs[12].stiffness``).
"""

from __future__ import annotations

import numpy as np

from ..errors import SceneError, SceneTypeError
from ..errors import check_numeric as _numeric
from ..forces._data import check_rule as _check_rule
from ..forces._data import data_terms, format_value as _fmt, term_group
from ..forces.gravitational import SOFTENING_PRECISION, SOFTENING_TIME, default_softening
from .model import AXES, ClothGrid, Model
from .topology import PLANES, cloth_grid_pairs, cloth_pin_mask, index_mask

__all__ = ["COEFFICIENT_ALIASES", "SOFTENING_PRECISION", "SOFTENING_TIME", "ModelBuilder", "cloth_grid_positions",
           "default_softening", "resolve_cloth_grid"]

#: Alias -> canonical name of the spring coefficients. The assignment's ``stiffness`` and ``damping`` are
#: canonical (``Model.spring_stiffness``, the YAML ``springs:`` keys); ``ke``/``kd`` and their suffixed forms
#: are accepted wherever the canonical name is (builder keywords, YAML ``springs:``, ``cloth:`` and
#: ``benchmark_cloth:``). Giving both spellings of one coefficient is a SceneError.
COEFFICIENT_ALIASES = {"ke": "stiffness", "kd": "damping", "ke_y": "stiffness_y", "kd_y": "damping_y",
                       "ke_shear": "stiffness_shear", "kd_shear": "damping_shear", "ke_bend": "stiffness_bend",
                       "kd_bend": "damping_bend"}



def unalias(path: str, given: dict) -> dict:
    """Merge the aliases of :data:`COEFFICIENT_ALIASES` in ``given`` (name -> value, None: not given).

    Returns canonical name -> ``(value, spelling)``, the spelling being the key the value came under
    (for error paths); canonical names of ``given`` without a given value map to ``(None, name)``.
    Raises a SceneError at ``path`` when a coefficient is given under both spellings.

    Parameters
    ----------
    path : str
        Item path for error messages (``"springs"``, ``"cloth[2]"``).
    given : dict
        Coefficient name (canonical or alias) -> value, None where not given.

    Returns
    -------
    dict
        Canonical name -> ``(value, spelling)``.

    Raises
    ------
    SceneError
        A coefficient given under both its name and its alias.
    """
    out = {}
    for name, value in given.items():
        canon = COEFFICIENT_ALIASES.get(name, name)
        if value is None:
            out.setdefault(canon, (None, name))
            continue
        prev = out.get(canon)
        if prev is not None and prev[0] is not None:
            alias, canonical = (name, canon) if name != canon else (prev[1], canon)
            raise SceneError(path, f"give {canonical} or its alias {alias}, not both")
        out[canon] = (value, name)
    return out


def _as_rows(name: str, value, count: int | None = None, width: int = 3) -> np.ndarray:
    a = _numeric(name, value)
    if a.ndim == 1 and a.shape[0] == width and count in (None, 1) and width > 1:
        a = a[None, :]
    if a.ndim != 2 or a.shape[1] != width:
        raise SceneError(name, f"must have shape (n, {width}), got {a.shape}")
    if count is not None and a.shape[0] != count:
        raise SceneError(name, f"must have {count} rows, got {a.shape[0]}")
    return a


def _as_column(name: str, value, count: int) -> np.ndarray:
    a = _numeric(name, value)
    if a.ndim == 0:
        return np.full(count, a, dtype=np.float64)
    if a.shape != (count,):
        raise SceneError(name, f"must be a scalar or have shape ({count},), got {a.shape}")
    return a


def _as_flags(name: str, value, count: int) -> np.ndarray:
    """Booleans (or integers 0 and 1) as a bool array (count,); strings such as ``"false"`` are refused."""
    if isinstance(value, (str, bytes)):
        raise SceneTypeError(name, f"must be True or False, got {type(value).__name__} {value!r:.60}")
    try:
        a = np.asarray(value)
    except (TypeError, ValueError):
        raise SceneTypeError(name, "must be booleans, got a ragged or non-boolean sequence") from None
    if a.dtype.kind in "iu" and np.all((a == 0) | (a == 1)):
        a = a.astype(bool)
    if a.dtype.kind != "b":
        raise SceneTypeError(name, f"must be True or False (or 0 and 1), got {a.dtype} values")
    if a.ndim == 0:
        return np.full(count, bool(a))
    if a.shape != (count,):
        raise SceneError(name, f"must be a scalar or have shape ({count},), got {a.shape}")
    return a


def _as_pairs(name: str, value) -> np.ndarray:
    try:
        a = np.asarray(value)
    except (TypeError, ValueError):  # ragged nested lists
        raise SceneError(name, "must have shape (n, 2), got a ragged or non-numeric sequence") from None
    if a.ndim == 1 and a.shape[0] == 2:
        a = a[None, :]
    if a.ndim != 2 or a.shape[1] != 2:
        raise SceneError(name, f"must have shape (n, 2), got {a.shape}")
    if a.size and not np.issubdtype(a.dtype, np.integer):
        af = a.astype(np.float64) if a.dtype.kind == "f" else None  # not bool, str, object
        ok = af is not None and np.isfinite(af) & (af == np.round(af))
        if af is None or not np.all(ok):
            bad = 0 if af is None else int(np.flatnonzero(~np.all(ok, axis=1))[0])
            raise SceneError(name, f"particle ids must be integers, got {a[bad].tolist()}")
        a = af
    return a.astype(np.int64)


class ModelBuilder:
    """Collects particles and pairwise terms, then :meth:`finalize` s them into a Model.

    Parameters
    ----------
    gravity
        Acceleration along the up axis [m/s^2]; default -9.81.
    up_axis
        ``"x"``, ``"y"``, ``"z"`` (default) or 0, 1, 2.
    pair_epsilon
        Spring length [m] below which a spring's direction is undefined; see
        :mod:`springsim.forces.spring`. Gravitational pairs have their own softening
        (:meth:`add_gravitational`).

    Examples
    --------
    >>> b = ModelBuilder()
    >>> i = b.add_particle((0, 0, 1), mass=0.1, fixed=True)
    >>> j = b.add_particle((0, 0, 0), mass=0.1)
    >>> b.add_spring(i, j, stiffness=100.0, damping=0.5)
    0
    >>> b.finalize()
    Model(particles=2, fixed=1, springs=1, gravitational=0)
    """

    def __init__(self, *, gravity: float = -9.81, up_axis: int | str = "z", pair_epsilon: float = 1e-9):
        self.gravity = gravity
        self.up_axis = up_axis
        self.pair_epsilon = pair_epsilon
        self._particles: dict[str, list[np.ndarray]] = {k: [] for k in ("q", "qd", "mass", "radius", "fixed")}
        #: (term, array) -> [(first particle, values)] of the per-particle term arrays given
        self._particle_data: dict[tuple[str, str], list[tuple[int, np.ndarray]]] = {}
        #: term -> array name ("indices" the pair list) -> chunks, and term -> pair count
        self._pairs: dict[str, dict[str, list[np.ndarray]]] = {}
        self._pair_counts: dict[str, int] = {}
        #: term -> array name -> per-model value
        self._model_data: dict[str, dict[str, np.ndarray]] = {}
        self._n_particles = 0
        self.metadata: dict = {}
        self._cloth_grids: list[ClothGrid] = []

    # -- counts -----------------------------------------------------------------
    @property
    def particle_count(self) -> int:
        """Number of particles added so far."""
        return self._n_particles

    @property
    def spring_count(self) -> int:
        """Number of springs added so far."""
        return self.pair_count("spring")

    @property
    def gravitational_count(self) -> int:
        """Number of gravitational pairs added so far."""
        return self.pair_count("gravitational")

    def pair_count(self, term: str) -> int:
        """Number of pairs of force term ``term`` added so far.

        Parameters
        ----------
        term : str
            A registered pair term (:data:`springsim.forces.FORCE_TERMS`).

        Returns
        -------
        int
        """
        return self._pair_counts.get(term, 0)

    @staticmethod
    def _term(term: str, per: str):
        """The registered class of ``term``, which must declare ``per`` arrays; ValueError otherwise."""
        terms = dict(data_terms())
        cls = terms.get(term)
        if cls is None or not any(s.per == per for s in cls.data):
            have = [name for name, c in terms.items() if any(s.per == per for s in c.data)]
            raise ValueError(f"{term!r} is not a registered force term with per-{per} data; those are: "
                             f"{', '.join(have) or 'none'}")
        return cls

    # -- particles --------------------------------------------------------------
    def add_particle(self, pos, vel=(0.0, 0.0, 0.0), mass: float = 1.0, *, radius: float | None = None,
                     fixed: bool = False, **arrays) -> int:
        """Add one particle and return its index.

        Parameters
        ----------
        pos, vel
            Position [m] and velocity [m/s], 3-vectors.
        mass
            Mass [kg], > 0.
        radius
            Drawing radius [m] (optional).
        fixed
            A fixed particle never moves (its velocity is forced to zero).
        **arrays
            The per-particle arrays of the force terms (:meth:`add_particles`), e.g. ``drag`` [N s/m].

        Returns
        -------
        int
            Index of the particle.
        """
        start = self.add_particles([pos], [vel], mass, radius=np.nan if radius is None else radius,
                                   fixed=fixed, **arrays)
        return start.start

    def add_particles(self, pos, vel=None, mass=1.0, *, radius=np.nan, fixed=False, **arrays) -> range:
        """Add particles in bulk and return the range of their indices.

        ``pos`` has shape (n, 3); ``vel`` (n, 3) or None; ``mass``, ``radius``,
        ``fixed`` and the term arrays are scalars or arrays of shape (n,) (a vector array: one vector or
        (n, k)).

        Parameters
        ----------
        pos : array_like, shape (n, 3)
            Initial positions [m].
        vel : array_like, shape (n, 3), optional
            Initial velocities [m/s]; None: at rest.
        mass : float or array_like, shape (n,)
            Particle masses [kg], > 0 (fixed particles may have any positive mass).
        radius : float or array_like, shape (n,)
            Radius [m] for drawing and scene files; NaN: none.
        fixed : bool or array_like, shape (n,)
            Particles held at their initial position.
        **arrays
            The per-particle arrays the force terms declare (:attr:`springsim.forces.ForceTerm.data`), by name;
            those not given take their declared defaults. Built in: ``drag``, the linear drag coefficient
            [N s/m] (force ``-drag * qd``), >= 0, default 0.

        Returns
        -------
        range
            Indices of the new particles.

        Raises
        ------
        SceneTypeError, SceneError
            Arrays of the wrong shape or type, or values out of range (naming the item, ``particles.mass``).
        """
        q = _as_rows("particles.pos", pos)
        n = q.shape[0]
        qd = np.zeros((n, 3)) if vel is None else _as_rows("particles.vel", vel, n)
        p = self._particles
        p["q"].append(q.copy())
        p["qd"].append(qd.copy())
        p["mass"].append(_as_column("particles.mass", mass, n))
        p["radius"].append(_as_column("particles.radius", np.nan if radius is None else radius, n))
        p["fixed"].append(_as_flags("particles.fixed", fixed, n))
        specs = {s.name: (term, s) for term, cls in data_terms() for s in cls.data if s.per == "particle"}
        for name in arrays:
            if name not in specs:
                raise TypeError(f"add_particles() got an unexpected keyword argument {name!r} (per-particle arrays "
                                f"of the force terms: {', '.join(specs) or 'none'})")
        start = self._n_particles
        for name, value in arrays.items():
            term, spec = specs[name]
            self._particle_data.setdefault((term, name), []).append(
                (start, spec.as_values(f"particles.{spec.key}", value, n)))
        self._n_particles += n
        return range(start, self._n_particles)

    # -- force-term data -------------------------------------------------------------
    def add_pairs(self, term: str, indices, **arrays) -> range:
        """Add pairs of force term ``term`` in bulk: ``indices`` (n, 2) and its declared per-pair arrays.

        Parameters
        ----------
        term : str
            A registered force term with per-pair data (:data:`springsim.forces.FORCE_TERMS`), e.g.
            ``"spring"``.
        indices : array_like of int, shape (n, 2)
            Particle index pairs ``(i, j)``, ``i != j``.
        **arrays
            The term's per-pair arrays by name (or by an alias the spec declares): scalars (one value for every
            pair) or arrays of shape (n,) (or (n, k) for a vector). Required ones must be given; the others take
            their declared defaults (for a ``computed`` array NaN or None means the value computed by
            :meth:`finalize`).

        Returns
        -------
        range
            Indices of the new pairs in the term's pair list.

        Raises
        ------
        ValueError
            ``term`` is not a registered pair term.
        TypeError
            An array the term does not declare.
        SceneTypeError, SceneError
            A missing required array, both spellings of one, or arrays of the wrong shape or type (naming
            ``springs.stiffness``); values are checked by :meth:`finalize`.
        """
        cls = self._term(term, "pair")
        group = term_group(term, cls)
        specs = [s for s in cls.data if s.per == "pair"]
        names = {a: s for s in specs for a in (s.name,) + tuple(s.aliases)}
        for name in arrays:
            if name not in names:
                raise TypeError(f"add_pairs({term!r}) got an unexpected keyword argument {name!r} (its arrays: "
                                f"{', '.join(s.name for s in specs)})")
        values = {}
        for s in specs:
            given = [(a, arrays[a]) for a in (s.name,) + tuple(s.aliases) if arrays.get(a) is not None]
            if len(given) > 1:
                raise SceneError(group, f"give {s.name} or its alias {given[1][0]}, not both")
            if given:
                values[s.name] = (given[0][1], s.key if given[0][0] == s.name else given[0][0])
            elif s.required:
                alias = f" (or its alias {s.aliases[0]})" if s.aliases else ""
                raise SceneTypeError(f"{group}.{s.key}", f"missing: give {s.key}{alias}")
        ij = _as_pairs(f"{group}.particle_ids", indices)
        n = ij.shape[0]
        chunks = self._pairs.setdefault(term, {})
        cols = {}
        for s in specs:
            v, spelled = values.get(s.name, (s.default, s.key))
            cols[s.name] = s.as_values(f"{group}.{spelled}", v, n)
        chunks.setdefault("indices", []).append(ij)
        for name, col in cols.items():
            chunks.setdefault(name, []).append(col)
        start = self._pair_counts.get(term, 0)
        self._pair_counts[term] = start + n
        return range(start, start + n)

    def set_term_data(self, term: str, **values) -> None:
        """Set per-model arrays of force term ``term`` (those not set keep their declared defaults).

        Parameters
        ----------
        term : str
            A registered force term with per-model data.
        **values
            Its per-model arrays by name, each one value of the declared shape; checked by :meth:`finalize`.

        Raises
        ------
        ValueError
            ``term`` is not a registered term with per-model data.
        TypeError
            An array the term does not declare.
        SceneTypeError, SceneError
            A value of the wrong shape or type.
        """
        cls = self._term(term, "model")
        specs = {s.name: s for s in cls.data if s.per == "model"}
        for name, v in values.items():
            if name not in specs:
                raise TypeError(f"set_term_data({term!r}) got an unexpected keyword argument {name!r} (its "
                                f"per-model arrays: {', '.join(specs)})")
            self._model_data.setdefault(term, {})[name] = specs[name].as_values(
                f"{term_group(term, cls)}.{specs[name].key}", v, None)

    # -- springs ------------------------------------------------------------------
    def add_spring(self, i: int, j: int, stiffness: float | None = None, damping: float | None = None,
                   rest_length: float | None = None, *, ke: float | None = None, kd: float | None = None) -> int:
        """Add a damped spring between particles ``i`` and ``j``; return its index.

        Parameters
        ----------
        i, j
            Particle indices (``i != j``).
        stiffness
            Stiffness [N/m], >= 0; required (``ke`` is its alias).
        damping
            Damping [N s/m] along the spring direction (PA2 eq. 8), >= 0; default 0 (``kd`` is its alias).
        rest_length
            Rest length l0 [m]; ``None`` takes the distance at :meth:`finalize`.
        ke, kd
            Aliases of ``stiffness`` and ``damping`` (not both spellings of one).

        Returns
        -------
        int
            Index of the spring.
        """
        return self.add_springs([[i, j]], stiffness, damping, np.nan if rest_length is None else rest_length,
                                ke=ke, kd=kd).start

    def add_springs(self, indices, stiffness=None, damping=None, rest_length=None, *, ke=None, kd=None) -> range:
        """Add springs in bulk: ``indices`` (n, 2); ``stiffness``, ``damping``, ``rest_length`` scalars or (n,).

        ``stiffness`` is required, ``damping`` defaults to 0; ``ke`` and ``kd`` are their aliases. A NaN
        (or ``None``) rest length means "the initial distance".

        Parameters
        ----------
        indices : array_like of int, shape (n, 2)
            Particle index pairs ``(i, j)``, ``i != j``.
        stiffness : float or array_like, shape (n,)
            Stiffness [N/m], >= 0; required (``ke`` is its alias).
        damping : float or array_like, shape (n,), optional
            Damping along the spring direction [N s/m], >= 0; default 0 (``kd`` is its alias).
        rest_length : float or array_like, shape (n,), optional
            Rest lengths l0 [m]; NaN or None: the distance at :meth:`finalize`.
        ke, kd : float or array_like, optional
            Aliases of ``stiffness`` and ``damping`` (not both spellings of one).

        Returns
        -------
        range
            Indices of the new springs.

        Raises
        ------
        SceneTypeError, SceneError
            A missing stiffness, both spellings of a coefficient, or arrays of the wrong shape or type.
        """
        c = unalias("springs", {"stiffness": stiffness, "ke": ke, "damping": damping, "kd": kd})
        stiffness, damping = c["stiffness"][0], c["damping"][0]
        if stiffness is None:
            raise SceneTypeError("springs.stiffness", "missing: give stiffness (or its alias ke)")
        return self.add_pairs("spring", indices, stiffness=stiffness, damping=damping, rest_length=rest_length)

    # -- gravitational pairs ---------------------------------------------------------
    def add_gravitational(self, i: int, j: int, G: float, softening: float | None = None) -> int:
        """Add pairwise gravitational attraction ``F = -G m_i m_j (q_i - q_j)/|q_i - q_j|^3``; return its index.

        Parameters
        ----------
        i, j
            Particle indices (``i != j``).
        G
            Gravitational constant of the pair [N m^2/kg^2], >= 0.
        softening
            Softening length [m] (a linear core below it, see :mod:`springsim.forces.gravitational`);
            ``None``: :func:`default_softening` of the pair.

        Returns
        -------
        int
            Index of the gravitational pair.
        """
        return self.add_gravitationals([[i, j]], G, np.nan if softening is None else softening).start

    def add_gravitationals(self, indices, G, softening=None) -> range:
        """Add gravitational pairs in bulk: ``indices`` (n, 2); ``G``, ``softening`` scalars or (n,).

        A NaN (or ``None``) softening means :func:`default_softening`.

        Parameters
        ----------
        indices : array_like of int, shape (n, 2)
            Particle index pairs ``(i, j)``, ``i != j``.
        G : float or array_like, shape (n,)
            Gravitational constant of each pair [N m^2/kg^2], >= 0.
        softening : float or array_like, shape (n,), optional
            Softening lengths [m]; NaN or None: :func:`default_softening` of the pair.

        Returns
        -------
        range
            Indices of the new pairs.

        Raises
        ------
        SceneTypeError, SceneError
            Arrays of the wrong shape or type, or values out of range.
        """
        return self.add_pairs("gravitational", indices, G=G, softening=softening)

    # -- generators -----------------------------------------------------------------
    def add_cloth_grid(self, nx: int, ny: int, *, origin=(0.0, 0.0, 0.0), spacing: float | None = None,
                       size: tuple[float, float] | None = None, plane: str = "xy", mass: float | None = None,
                       total_mass: float | None = None, drag: float = 0.0, stiffness: float | None = None,
                       damping: float | None = None, stiffness_y: float | None = None, damping_y: float | None = None,
                       stiffness_shear: float | None = None, damping_shear: float | None = None,
                       bending: bool = True, stiffness_bend: float | None = None, damping_bend: float | None = None,
                       pin="edge", ke: float | None = None, kd: float | None = None, ke_y: float | None = None,
                       kd_y: float | None = None, ke_shear: float | None = None, kd_shear: float | None = None,
                       ke_bend: float | None = None, kd_bend: float | None = None) -> range:
        """Add an ``nx`` x ``ny`` cloth of particles and springs; return the range of its particles.

        Particle ``(i, j)`` is ``start + j*nx + i``; the springs are those of
        :func:`springsim.model.topology.cloth_grid_pairs` (structural along i and j, both shear
        diagonals, bending at distance two). Every argument is validated before anything is
        added; an invalid one raises :class:`~springsim.errors.SceneError` (or ``SceneTypeError``)
        with the path ``cloth.<argument>``. The grid is recorded in :attr:`cloth_grids`; its
        pins can be changed later with :meth:`pin_cloth`, :meth:`set_fixed` or :meth:`fix_box`.

        Parameters
        ----------
        nx, ny
            Particles along the first and second in-plane axis (integers >= 2).
        origin
            Position of particle (0, 0) [m].
        spacing, size
            Grid spacing [m] (> 0), or the cloth's extent (sx, sy) [m] (> 0); default size (1, 1).
        plane
            Two axes spanned by the grid: ``"xy"``, ``"xz"`` or ``"yz"``.
        mass, total_mass
            Mass of each particle [kg], or of the whole cloth shared equally (> 0); default 1 kg in total.
        drag
            Linear drag per particle [N s/m], >= 0.
        stiffness, damping
            Structural springs along i (and along j unless ``stiffness_y``/``damping_y`` are given) [N/m],
            [N s/m], >= 0; default 1e4 and 0.
        stiffness_y, damping_y
            Structural springs along j; default ``stiffness``, ``damping``.
        stiffness_shear, damping_shear
            Diagonal springs; default ``stiffness``, ``damping``.
        bending, stiffness_bend, damping_bend
            Whether to add distance-two springs along i and j, and their stiffness and damping
            (default 100 and 0).
        pin
            Which particles are fixed: a name (``"edge"`` = ``"bottom"``: row j = 0, ``"top"``: j = ny - 1,
            ``"left"``: i = 0, ``"right"``: i = nx - 1, ``"bottom-left"``, ``"bottom-right"``,
            ``"top-left"``, ``"top-right"``, ``"corners"``: the two of row j = 0, ``"all-corners"``,
            ``"ends"``: rows j = 0 and ny - 1, ``"none"``), local indices ``j*nx + i`` (an integer, a
            list or an integer array), a boolean array (nx*ny,), ``{"i": I, "j": J}``,
            ``{"box": [[xmin, ymin, zmin], [xmax, ymax, zmax]]}`` (scene coordinates [m], closed, not
            empty), or a list of these (their union); ``None`` is ``"none"``. See
            :mod:`springsim.model.topology`.
        ke, kd, ke_y, kd_y, ke_shear, kd_shear, ke_bend, kd_bend
            Aliases of ``stiffness``, ``damping``, ``stiffness_y``, ... (:data:`COEFFICIENT_ALIASES`); giving
            both spellings of one coefficient is an error.

        Returns
        -------
        range
            Indices of the grid's particles, ``start`` to ``start + nx*ny``.

        Raises
        ------
        SceneError
            An invalid argument (``SceneTypeError`` for one of the wrong type), with the path
            ``cloth.<argument>``; nothing is added then.
        """
        c = resolve_cloth_grid(nx, ny, origin=origin, spacing=spacing, size=size, plane=plane, mass=mass,
                               total_mass=total_mass, drag=drag, stiffness=stiffness, damping=damping,
                               stiffness_y=stiffness_y, damping_y=damping_y, stiffness_shear=stiffness_shear,
                               damping_shear=damping_shear, bending=bending, stiffness_bend=stiffness_bend,
                               damping_bend=damping_bend, ke=ke, kd=kd, ke_y=ke_y, kd_y=kd_y, ke_shear=ke_shear,
                               kd_shear=kd_shear, ke_bend=ke_bend, kd_bend=kd_bend)
        nx, ny = c["nx"], c["ny"]
        pos = cloth_grid_positions(c, 0, ny)
        fixed = cloth_pin_mask(nx, ny, pin, positions=pos, path="cloth.pin")
        particles = self.add_particles(pos, None, c["mass"], drag=c["drag"], fixed=fixed)
        off = particles.start
        topo = cloth_grid_pairs(nx, ny, bending=c["bending"])
        for family, (ke_, kd_) in c["springs"].items():
            self.add_springs(topo[family] + off, ke_, kd_)
        self._cloth_grids.append(ClothGrid(off, nx, ny))
        return particles

    # -- fixing particles ------------------------------------------------------------
    @property
    def cloth_grids(self) -> tuple[ClothGrid, ...]:
        """The grids added so far by :meth:`add_cloth_grid`, in order (particle ``(i, j)`` is ``start + j*nx + i``)."""
        return tuple(self._cloth_grids)

    @property
    def particle_q(self) -> np.ndarray:
        """Positions (N, 3) [m] of the particles added so far (a read-only array), e.g. to build a mask for
        :meth:`set_fixed`."""
        p = self._particles["q"]
        if len(p) > 1:
            p[:] = [np.concatenate(p)]
        q = p[0].view() if p else np.zeros((0, 3))
        q.setflags(write=False)
        return q

    def set_fixed(self, indices, fixed: bool = True) -> np.ndarray:
        """Fix (or, with ``fixed=False``, free) particles already added; return their indices.

        Parameters
        ----------
        indices
            A particle index, a list, range or integer array of them, or a boolean mask of shape
            (:attr:`particle_count`,).
        fixed
            The new flag of those particles (the others keep theirs).

        Returns
        -------
        ndarray of int64
            The affected particle indices, sorted and unique.

        Raises
        ------
        SceneError
            ``set_fixed.indices[k]: particle index out of range [0, N), got ...``, or a wrong type.
        """
        if not isinstance(fixed, (bool, np.bool_)):
            raise SceneTypeError("set_fixed.fixed", f"must be True or False, got {fixed!r:.60}")
        mask = index_mask("set_fixed.indices", indices, self._n_particles)
        return self._set_fixed_mask(mask, bool(fixed))

    def fix_box(self, lo, hi, fixed: bool = True) -> np.ndarray:
        """Fix (or free) the particles whose current position lies in the closed box ``[lo, hi]``.

        Parameters
        ----------
        lo, hi
            Corners ``(xmin, ymin, zmin)`` and ``(xmax, ymax, zmax)`` [m], finite, ``lo <= hi``.
        fixed
            The new flag of the particles inside.

        Returns
        -------
        ndarray of int64
            Indices of the particles inside (sorted; empty if none).
        """
        if not isinstance(fixed, (bool, np.bool_)):
            raise SceneTypeError("fix_box.fixed", f"must be True or False, got {fixed!r:.60}")
        lo_ = np.array(_vector("fix_box.lo", lo, 3))
        hi_ = np.array(_vector("fix_box.hi", hi, 3))
        if np.any(lo_ > hi_):
            raise SceneError("fix_box", f"needs lo <= hi in every coordinate, got lo {_fmt(lo_)}, hi {_fmt(hi_)}")
        q = self.particle_q
        return self._set_fixed_mask(np.all((q >= lo_) & (q <= hi_), axis=1), bool(fixed))

    def pin_cloth(self, pin, *, grid=-1, fixed: bool = True) -> np.ndarray:
        """Fix (or free) particles of a cloth grid already added, chosen by a ``pin`` specification.

        Parameters
        ----------
        pin
            As for :meth:`add_cloth_grid` (``"top"``, ``["left", "right"]``, local indices, ``{"i": , "j": }``,
            ``{"box": [lo, hi]}``, ...); the other particles keep their flags.
        grid
            Which grid: an index into :attr:`cloth_grids` (default the last one added) or a
            :class:`~springsim.model.model.ClothGrid`.
        fixed
            The new flag of the chosen particles.

        Returns
        -------
        ndarray of int64
            Their (global) particle indices, sorted.
        """
        if not isinstance(fixed, (bool, np.bool_)):
            raise SceneTypeError("pin_cloth.fixed", f"must be True or False, got {fixed!r:.60}")
        if isinstance(grid, ClothGrid):
            if grid not in self._cloth_grids:
                raise SceneError("pin_cloth.grid", f"is not a grid of this builder: {grid}")
            g = grid
        else:
            if isinstance(grid, (bool, np.bool_)) or not isinstance(grid, (int, np.integer)):
                raise SceneTypeError("pin_cloth.grid", f"must be a grid index or a ClothGrid, got {grid!r:.60}")
            n = len(self._cloth_grids)
            if not -n <= grid < n:
                raise SceneError("pin_cloth.grid", f"no cloth grid {grid} (the builder has {n})")
            g = self._cloth_grids[grid]
        count = g.nx * g.ny
        local = cloth_pin_mask(g.nx, g.ny, pin, positions=self.particle_q[g.start:g.start + count],
                               path="pin_cloth.pin")
        mask = np.zeros(self._n_particles, dtype=bool)
        mask[g.start:g.start + count] = local
        return self._set_fixed_mask(mask, bool(fixed))

    def _set_fixed_mask(self, mask: np.ndarray, fixed: bool) -> np.ndarray:
        p = self._particles
        if p["fixed"]:
            flags = np.concatenate(p["fixed"])  # always a new array: never writes into a caller's one
            flags[mask] = fixed
            p["fixed"] = [flags]
        return np.flatnonzero(mask)

    # -- finalize -------------------------------------------------------------------
    @staticmethod
    def _cat(chunks, shape_tail=(), dtype=np.float64):
        if not chunks:
            return np.zeros((0,) + shape_tail, dtype=dtype)
        return np.concatenate(chunks).astype(dtype, copy=False)

    def finalize(self) -> Model:
        """Validate everything and return an immutable :class:`Model`.

        Returns
        -------
        Model
            The model; velocities of fixed particles are set to zero, computed values (rest lengths, softening)
            filled in.

        Raises
        ------
        SceneError
            Naming the first offending item, e.g. ``springs[3].stiffness: must be >= 0, got -1``.
        """
        p = self._particles
        q = self._cat(p["q"], (3,))
        qd = self._cat(p["qd"], (3,))
        mass = self._cat(p["mass"])
        radius = self._cat(p["radius"])
        fixed = self._cat(p["fixed"], dtype=bool)
        n = q.shape[0]

        _check_finite("particles", "pos", q)
        _check_finite("particles", "vel", qd)
        _check_finite("particles", "mass", mass)
        _check_rule("particles", "mass", mass, mass > 0, "must be > 0")
        registered = data_terms()
        terms: dict[str, dict] = {name: {} for name, _ in registered}
        for name, cls in registered:  # the per-particle arrays of every term first: the particles' checks
            for spec in cls.data:
                if spec.per == "particle":
                    a = spec.filled(n)
                    for start, values in self._particle_data.get((name, spec.name), ()):
                        a[start:start + values.shape[0]] = values
                    spec.validate("particles", a)
                    terms[name][spec.name] = a
        bad = np.flatnonzero(~np.isnan(radius) & ~(np.isfinite(radius) & (radius >= 0)))
        if bad.size:
            raise SceneError(f"particles[{bad[0]}].radius", f"must be finite and >= 0, got {radius[bad[0]]:g}")
        qd = np.where(fixed[:, None], 0.0, qd)

        eps = _scalar("pair_epsilon", self.pair_epsilon)
        if eps <= 0:
            raise SceneError("pair_epsilon", f"must be > 0, got {eps:g}")
        for name, cls in registered:
            group = term_group(name, cls)
            d = terms[name]
            chunks = self._pairs.get(name, {})
            if any(spec.per == "pair" for spec in cls.data):
                ij = self._cat(chunks.get("indices", []), (2,), np.int64)
                _check_pairs(group, ij, n)
                d["indices"] = ij
            for spec in cls.data:
                if spec.per == "pair":
                    a = self._cat(chunks.get(spec.name, []), tuple(spec.shape))
                    spec.validate(group, a)
                    d[spec.name] = a
                elif spec.per == "model":
                    v = self._model_data.get(name, {}).get(spec.name)
                    a = np.array(spec.filled(1)[0] if v is None else v, dtype=np.float64)
                    spec.validate(group, a, per_item=False)
                    d[spec.name] = a
            terms[name] = cls.complete_data(d, particle_q=q, particle_mass=mass, pair_epsilon=eps)

        gravity = _scalar("solver.gravity", self.gravity)
        up = self.up_axis
        if isinstance(up, str):
            if up not in AXES:
                raise SceneError("up_axis", f"must be one of {', '.join(AXES)}, got {up!r}")
            up = AXES.index(up)
        if isinstance(up, (bool, np.bool_)) or not isinstance(up, (int, np.integer)) or up not in (0, 1, 2):
            raise SceneError("up_axis", f"must be x, y, z or 0, 1, 2, got {up!r:.60}")

        return Model(
            particle_q=q, particle_qd=qd, particle_mass=mass, particle_radius=radius, particle_fixed=fixed,
            terms=terms, gravity=gravity, up_axis=int(up), pair_epsilon=eps, cloth_grids=tuple(self._cloth_grids),
            metadata=dict(self.metadata),
        )


def resolve_cloth_grid(nx, ny, *, origin=(0.0, 0.0, 0.0), spacing=None, size=None, plane="xy", mass=None,
                       total_mass=None, drag=0.0, stiffness=None, damping=None, stiffness_y=None, damping_y=None,
                       stiffness_shear=None, damping_shear=None, bending=True, stiffness_bend=None,
                       damping_bend=None, ke=None, kd=None, ke_y=None, kd_y=None, ke_shear=None, kd_shear=None,
                       ke_bend=None, kd_bend=None) -> dict:
    """The validated values of a cloth grid (:meth:`ModelBuilder.add_cloth_grid`'s arguments but ``pin``).

    Shared by :meth:`ModelBuilder.add_cloth_grid` and the distributed generator
    (:mod:`springsim.distributed.scene`), which builds a rank's rows of the grid only: both take every value
    from here, so they make the same particles and springs to the last bit.

    Parameters
    ----------
    nx, ny : int
        Particles along the first and second in-plane axis (>= 2).
    origin, spacing, size, plane, mass, total_mass, drag : see :meth:`ModelBuilder.add_cloth_grid`
        The grid's geometry, masses and drag.
    stiffness, damping, stiffness_y, damping_y, stiffness_shear, damping_shear : float, optional
        The structural and shear springs' coefficients (:meth:`ModelBuilder.add_cloth_grid`).
    bending, stiffness_bend, damping_bend : bool, float, float
        The bending springs.
    ke, kd, ke_y, kd_y, ke_shear, kd_shear, ke_bend, kd_bend : float, optional
        Aliases (:data:`COEFFICIENT_ALIASES`).

    Returns
    -------
    dict
        ``nx``, ``ny``, ``origin`` (3 floats), ``dx``, ``dy``, ``axes`` (the plane's two axes), ``mass`` (per
        particle), ``drag``, ``bending`` and ``springs``: family of :func:`~springsim.model.topology.cloth_grid_pairs`
        -> ``(stiffness, damping)``, in the order the springs are added.

    Raises
    ------
    SceneError
        An invalid argument, with the path ``cloth.<argument>``.
    """
    nx = _integer("cloth.nx", nx, 2)
    ny = _integer("cloth.ny", ny, 2)
    if plane not in PLANES:
        raise SceneError("cloth.plane", f"must be one of {', '.join(PLANES)}, got {plane!r:.60}")
    if not isinstance(bending, (bool, np.bool_)):
        raise SceneTypeError("cloth.bending", f"must be True or False, got {bending!r:.60}")
    o = _vector("cloth.origin", origin, 3)
    if spacing is not None and size is not None:
        raise SceneError("cloth", "give spacing or size, not both")
    if mass is not None and total_mass is not None:
        raise SceneError("cloth", "give mass or total_mass, not both")
    if spacing is not None:
        dx = dy = _number("cloth.spacing", spacing, lo=0.0, strict=True)
    else:
        sx, sy = (1.0, 1.0) if size is None else _vector("cloth.size", size, 2, lo=0.0, strict=True)
        dx, dy = sx / (nx - 1), sy / (ny - 1)
    if mass is not None:
        m = _number("cloth.mass", mass, lo=0.0, strict=True)
    else:
        total = 1.0 if total_mass is None else _number("cloth.total_mass", total_mass, lo=0.0, strict=True)
        m = total / (nx * ny)
    drag = _number("cloth.drag", drag, lo=0.0)
    given = unalias("cloth", {
        "stiffness": stiffness, "ke": ke, "damping": damping, "kd": kd, "stiffness_y": stiffness_y,
        "ke_y": ke_y, "damping_y": damping_y, "kd_y": kd_y, "stiffness_shear": stiffness_shear,
        "ke_shear": ke_shear, "damping_shear": damping_shear, "kd_shear": kd_shear,
        "stiffness_bend": stiffness_bend, "ke_bend": ke_bend, "damping_bend": damping_bend, "kd_bend": kd_bend})
    k = {name: None if v is None else _number(f"cloth.{spelled}", v, lo=0.0)
         for name, (v, spelled) in given.items()}
    ke_ = 1e4 if k["stiffness"] is None else k["stiffness"]
    kd_ = 0.0 if k["damping"] is None else k["damping"]

    springs = {"structural_x": (ke_, kd_),
               "structural_y": (ke_ if k["stiffness_y"] is None else k["stiffness_y"],
                                kd_ if k["damping_y"] is None else k["damping_y"]),
               "shear": (ke_ if k["stiffness_shear"] is None else k["stiffness_shear"],
                         kd_ if k["damping_shear"] is None else k["damping_shear"])}
    if bending:
        springs["bending"] = (1e2 if k["stiffness_bend"] is None else k["stiffness_bend"],
                              0.0 if k["damping_bend"] is None else k["damping_bend"])
    return {"nx": nx, "ny": ny, "origin": o, "dx": dx, "dy": dy, "axes": PLANES[plane], "mass": m, "drag": drag,
            "bending": bool(bending), "springs": springs}


def cloth_grid_positions(grid: dict, j0: int, j1: int) -> np.ndarray:
    """Positions [m] of the rows ``j0 .. j1`` (exclusive) of a cloth grid resolved by :func:`resolve_cloth_grid`,
    particle ``(i, j)`` at row ``j - j0``, column ``i``: the same values, to the last bit, for any row range.

    Parameters
    ----------
    grid : dict
        What :func:`resolve_cloth_grid` returned.
    j0, j1 : int
        The rows, ``0 <= j0 <= j1 <= ny``.

    Returns
    -------
    ndarray, shape ((j1 - j0) * nx, 3)
        The positions, row-major.
    """
    nx = grid["nx"]
    ii, jj = np.meshgrid(np.arange(nx, dtype=np.float64), np.arange(j0, j1, dtype=np.float64))
    pos = np.tile(np.asarray(grid["origin"]), (nx * (j1 - j0), 1))
    a, b = grid["axes"]
    pos[:, a] += ii.ravel() * grid["dx"]
    pos[:, b] += jj.ravel() * grid["dy"]
    return pos


def _number(path: str, v, *, lo: float | None = None, strict: bool = False) -> float:
    """``v`` as a finite float (``> lo`` with ``strict``, else ``>= lo``); SceneTypeError for non-numbers."""
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, float, np.integer, np.floating)):
        raise SceneTypeError(path, f"must be a number, got {type(v).__name__} {v!r:.60}")
    try:
        f = float(v)
    except OverflowError:  # an integer beyond float range
        f = float("inf")
    if not np.isfinite(f):
        raise SceneError(path, f"must be finite, got {f}")
    if lo is not None and (f <= lo if strict else f < lo):
        raise SceneError(path, f"must be {'>' if strict else '>='} {lo:g}, got {f:g}")
    return f


def _scalar(path: str, v) -> float:
    return _number(path, v)


def _integer(path: str, v, lo: int) -> int:
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)):
        raise SceneTypeError(path, f"must be an integer, got {type(v).__name__} {v!r:.60}")
    if v < lo:
        raise SceneError(path, f"must be an integer >= {lo}, got {v}")
    return int(v)


def _vector(path: str, v, n: int, **rule) -> tuple:
    if isinstance(v, (str, bytes)) or not hasattr(v, "__len__") or len(v) != n:
        raise SceneTypeError(path, f"must be {n} numbers, got {v!r:.60}")
    return tuple(_number(f"{path}[{k}]", x, **rule) for k, x in enumerate(v))


def _check_finite(group: str, name: str, a: np.ndarray) -> None:
    ok = np.isfinite(a) if a.ndim == 1 else np.isfinite(a).all(axis=1)
    bad = np.flatnonzero(~ok)
    if bad.size:
        raise SceneError(f"{group}[{bad[0]}].{name}", f"must be finite, got {_fmt(a[bad[0]])}")


def _check_pairs(group: str, ij: np.ndarray, n: int) -> None:
    if not ij.shape[0]:
        return
    out = (ij < 0) | (ij >= n)
    bad = np.flatnonzero(out.any(axis=1))
    if bad.size:
        k = bad[0]
        raise SceneError(f"{group}[{k}].particle_ids",
                         f"particle id out of range [0, {n}), got {ij[k].tolist()}")
    bad = np.flatnonzero(ij[:, 0] == ij[:, 1])
    if bad.size:
        k = bad[0]
        raise SceneError(f"{group}[{k}].particle_ids",
                         f"a pair needs two different particles, got {ij[k].tolist()}")
