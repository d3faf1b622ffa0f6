"""The data of force terms: each term declares its arrays as :class:`ArraySpec` s (:attr:`ForceTerm.data
<springsim.forces.ForceTerm.data>`), and everything that handles model data iterates the declarations.

A spec says what one array is: per particle (one value per particle, ``model.particle_<name>``), per pair
(one value per item of the term's pair list ``model.<term>_indices``, ``model.<term>_<name>``) or per model
(one value, ``model.<term>_<name>``); its shape per item, unit, bounds, YAML key and default. From the specs
of the registered terms (:data:`springsim.forces.FORCE_TERMS`):

* the :class:`~springsim.model.model.Model` holds each term's arrays in :attr:`~springsim.model.model.Model.terms` and
  exposes them under the names above;
* :class:`~springsim.model.builder.ModelBuilder` takes them (:meth:`~springsim.model.builder.ModelBuilder.add_pairs`,
  keywords of :meth:`~springsim.model.builder.ModelBuilder.add_particles`,
  :meth:`~springsim.model.builder.ModelBuilder.set_term_data`) and validates them with one-line messages naming
  the item (``springs[12].stiffness: must be >= 0, got -3``);
* the YAML loader reads a pair term's list under the term's :attr:`~springsim.forces.ForceTerm.yaml_key`,
  per-particle arrays as keys of ``particles[k]`` and per-model arrays as keys of a mapping under the term's
  YAML key;
* the partitioner slices per-particle arrays by particle and per-pair arrays by pair
  (:mod:`springsim.distributed.partition`), and :meth:`~springsim.model.model.Model.fingerprint` hashes them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import SceneError, check_numeric

__all__ = ["ArraySpec", "PER", "term_attributes", "data_terms", "term_group", "check_rule", "format_value"]

#: Where an array has one value: per particle, per pair of the term's pair list, or once per model.
PER = ("particle", "pair", "model")


def _g(x: float) -> str:
    return f"{x:g}"


@dataclass(frozen=True)
class ArraySpec:
    """One array of a force term's data.

    Parameters
    ----------
    name : str
        Name of the array within its term (an identifier). The model exposes it as ``particle_<name>``
        (per particle) or ``<term>_<name>`` (per pair, per model).
    per : {"particle", "pair", "model"}
        One value per particle, per pair of the term's pair list, or one per model.
    shape : tuple of int
        Shape of one value: ``()`` for a scalar, ``(3,)`` for a vector.
    unit : str
        Unit of the values (documentation), e.g. ``"N/m"``.
    lo, hi : float, optional
        Bounds of the values (every component), None: unbounded.
    lo_strict, hi_strict : bool
        Whether the bound itself is excluded (``> lo`` instead of ``>= lo``).
    default : float
        The value where none is given (also the value a term's data has where it does nothing: a model whose
        values all equal the default has no data of the term).
    required : bool
        Every pair (YAML item, builder call) must give it.
    computed : bool
        A missing value (NaN in the builder, null or absent in YAML) is computed when the model is built, by
        the term's :meth:`~springsim.forces.ForceTerm.complete_data`; ``default`` is then NaN.
    yaml_key : str, optional
        Key in the YAML scene; default ``name``.
    aliases : tuple of str
        Other YAML keys (and builder keywords) accepted for it; giving two spellings is an error.
    sample : tuple of float, optional
        A typical range of values ``(lo, hi)``, for random test scenes; default from the bounds.
    dissipative : bool
        The array is a dissipation coefficient (a damping, a drag): a model whose values are not all zero
        dissipates energy (:meth:`springsim.model.model.Model.dissipates`).
    doc : str
        One line of documentation.
    """

    name: str
    per: str
    shape: tuple = ()
    unit: str = ""
    lo: float | None = None
    hi: float | None = None
    lo_strict: bool = False
    hi_strict: bool = False
    default: float = 0.0
    required: bool = False
    computed: bool = False
    yaml_key: str | None = None
    aliases: tuple = ()
    sample: tuple | None = None
    dissipative: bool = False
    doc: str = ""

    def __post_init__(self):
        if self.per not in PER:
            raise ValueError(f"ArraySpec {self.name!r}: per must be one of {', '.join(PER)}, got {self.per!r}")
        if not self.name.isidentifier():
            raise ValueError(f"ArraySpec name must be an identifier, got {self.name!r}")
        if self.computed and self.default == self.default:
            object.__setattr__(self, "default", float("nan"))

    @property
    def key(self) -> str:
        """The YAML key (``yaml_key`` or ``name``)."""
        return self.yaml_key or self.name

    @property
    def rule(self) -> str:
        """The bounds as the error messages state them (``"must be >= 0"``), or ``""`` when unbounded."""
        parts = []
        if self.lo is not None:
            parts.append(f"{'>' if self.lo_strict else '>='} {_g(self.lo)}")
        if self.hi is not None:
            parts.append(f"{'<' if self.hi_strict else '<='} {_g(self.hi)}")
        if not parts:
            return ""
        return "must be " + ("finite and " if self.computed else "") + " and ".join(parts)

    def filled(self, count: int) -> np.ndarray:
        """``count`` values equal to the default.

        Parameters
        ----------
        count : int
            Number of items.

        Returns
        -------
        ndarray, shape ``(count,) + shape``
        """
        return np.full((count,) + tuple(self.shape), self.default, dtype=np.float64)

    def in_bounds(self, a: np.ndarray) -> np.ndarray:
        """Which values of ``a`` are within the bounds (every component; NaN is not).

        Parameters
        ----------
        a : ndarray, shape ``(k,) + shape``
            Values, one per leading index.

        Returns
        -------
        ndarray of bool, shape (k,)
        """
        ok = np.ones(a.shape, dtype=bool)
        with np.errstate(invalid="ignore"):
            if self.lo is not None:
                ok &= (a > self.lo) if self.lo_strict else (a >= self.lo)
            if self.hi is not None:
                ok &= (a < self.hi) if self.hi_strict else (a <= self.hi)
        return ok.reshape(a.shape[0], int(np.prod(a.shape[1:], dtype=np.int64))).all(axis=1) if a.ndim > 1 else ok

    def sample_range(self) -> tuple[float, float]:
        """A typical range of values, for random test scenes.

        Returns
        -------
        tuple of float
            ``sample``, or a range inside the bounds (from ``lo`` and ``hi`` where given, else from -1 or
            ``lo`` to 1 above it).
        """
        if self.sample is not None:
            return tuple(self.sample)
        lo = -1.0 if self.lo is None else float(self.lo)
        hi = lo + 1.0 if self.hi is None else float(self.hi)
        return (lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo))

    def as_values(self, path: str, value, count: int | None) -> np.ndarray:
        """``value`` as the float array of ``count`` items (the shapes only; :meth:`validate` checks the values).

        Parameters
        ----------
        path : str
            Path of the value in error messages (``springs.stiffness``).
        value : float or array_like
            One value (broadcast to every item) or ``count`` of them.
        count : int or None
            Number of items; None: a per-model value (one of ``shape``).

        Returns
        -------
        ndarray, shape ``(count,) + shape`` (``shape`` when ``count`` is None)

        Raises
        ------
        SceneTypeError, SceneError
            Not numbers, or the wrong shape.
        """
        a = check_numeric(path, value)
        tail = tuple(self.shape)
        if count is None:
            if a.shape != tail:
                raise SceneError(path, f"must have shape {tail}, got {a.shape}")
            return a
        if a.shape == tail:
            return np.broadcast_to(a, (count,) + tail).copy()
        if a.shape != (count,) + tail:
            want = "a scalar" if not tail else f"shape {tail}"
            raise SceneError(path, f"must be {want} or have shape {(count,) + tail}, got {a.shape}")
        return a

    def validate(self, group: str, a: np.ndarray, *, per_item: bool = True) -> None:
        """Check the values of ``a`` against the bounds; NaN passes where ``computed`` (it marks a computed value).

        Parameters
        ----------
        group : str
            Path of the items in error messages (``springs``, ``particles``).
        a : ndarray
            The values, ``(k,) + shape`` (``shape`` when not ``per_item``).
        per_item : bool
            One value per item (False: one per-model value).

        Raises
        ------
        SceneError
            At the first invalid value: ``group[k].key: must be finite, got nan`` or
            ``group[k].key: must be >= 0, got -3`` (``group.key`` for a per-model value).
        """

        values = a.reshape((1,) + a.shape) if not per_item else a
        rows = values.reshape(values.shape[0], int(np.prod(values.shape[1:], dtype=np.int64)))

        def where(k):
            return f"{group}[{k}].{self.key}" if per_item else f"{group}.{self.key}"

        def show(k):
            v = rows[k]
            return _g(float(v[0])) if np.ndim(values[k]) == 0 else "[" + ", ".join(_g(float(x)) for x in v) + "]"

        if self.computed:
            given = ~np.isnan(rows).any(axis=1)
            ok = ~given | (np.isfinite(rows).all(axis=1) & self.in_bounds(values))
            bad = np.flatnonzero(~ok)
            if bad.size:
                raise SceneError(where(bad[0]), f"{self.rule or 'must be finite'}, got {show(bad[0])}")
            return
        bad = np.flatnonzero(~np.isfinite(rows).all(axis=1))
        if bad.size:
            raise SceneError(where(bad[0]), f"must be finite, got {show(bad[0])}")
        if self.rule:
            bad = np.flatnonzero(~self.in_bounds(values))
            if bad.size:
                raise SceneError(where(bad[0]), f"{self.rule}, got {show(bad[0])}")


def _registry() -> dict:
    from . import FORCE_TERMS

    return FORCE_TERMS


def data_terms(registry: dict | None = None) -> list[tuple[str, type]]:
    """The registered terms that declare data.

    Parameters
    ----------
    registry : dict, optional
        Name -> term class; default :data:`springsim.forces.FORCE_TERMS`.

    Returns
    -------
    list of (str, type)
        ``(name, class)`` in registry order.
    """
    reg = _registry() if registry is None else registry
    return [(name, cls) for name, cls in reg.items() if cls.data]


def term_group(name: str, cls) -> str:
    """The path of a term's items in error messages and YAML.

    Parameters
    ----------
    name : str
        The term's registry name.
    cls : type
        Its class.

    Returns
    -------
    str
        Its :attr:`~springsim.forces.ForceTerm.yaml_key`, or ``name``.
    """
    return cls.yaml_key or name


_TABLE: dict = {"key": None, "table": None}


def term_attributes(registry: dict | None = None, *, reserved=frozenset()) -> dict[str, tuple[str, str]]:
    """Model attribute name -> ``(term, array)`` for every array of the registered terms: ``particle_<array>``
    (per particle), ``<term>_<array>`` (per pair and per model), ``<term>_indices`` (a pair list) and
    ``<term>_count`` (its length, array ``"count"``).

    Parameters
    ----------
    registry : dict, optional
        Name -> term class; default :data:`springsim.forces.FORCE_TERMS` (then the table is cached until the
        registry or ``reserved`` changes).
    reserved : set of str
        Names no term may claim (the :class:`~springsim.model.model.Model`'s own fields, properties and methods).

    Returns
    -------
    dict
        Attribute name -> ``(term, array)``.

    Raises
    ------
    ValueError
        Two terms (or a term and the model) claiming one name, or a spec inconsistent with its term.
    """
    reg = _registry() if registry is None else registry
    reserved = frozenset(reserved)
    key = (tuple((name, id(cls), cls.data) for name, cls in reg.items()), reserved)
    if registry is None and _TABLE["key"] == key:
        return _TABLE["table"]
    table: dict[str, tuple[str, str]] = {}
    base = reserved

    def claim(attr, term, array):
        if attr in table or attr in base:
            other = table[attr][0] if attr in table else "the model"
            raise ValueError(f"force term {term!r}: its data name {attr!r} is already taken by {other}")
        table[attr] = (term, array)

    for name, cls in reg.items():
        names = [s.name for s in cls.data]
        if len(set(names)) != len(names) or {"indices", "count"} & set(names):
            raise ValueError(f"force term {name!r}: array names must be distinct and not 'indices' or 'count'")
        pers = {s.per for s in cls.data}
        if {"pair", "model"} <= pers:
            raise ValueError(f"force term {name!r}: per-pair and per-model arrays share the YAML key "
                             f"{term_group(name, cls)!r}; declare one kind")
        if "pair" in pers:
            claim(f"{name}_indices", name, "indices")
            claim(f"{name}_count", name, "count")
        for s in cls.data:
            claim(f"particle_{s.name}" if s.per == "particle" else f"{name}_{s.name}", name, s.name)
    if registry is None:
        _TABLE.update(key=key, table=table)
    return table


def format_value(v) -> str:
    """A value for an error message: ``%g`` of a number, ``[a, b, c]`` of an array."""
    if np.ndim(v) == 0:
        return f"{float(v):g}"
    return "[" + ", ".join(f"{float(x):g}" for x in np.ravel(v)) + "]"


def check_rule(group: str, name: str, a: np.ndarray, ok: np.ndarray, rule: str) -> None:
    """A :class:`~springsim.errors.SceneError` naming the first item of ``group`` whose ``name`` breaks ``rule``
    (``ok`` False there): ``group[k].name: rule, got value``."""
    bad = np.flatnonzero(~ok)
    if bad.size:
        raise SceneError(f"{group}[{bad[0]}].{name}", f"{rule}, got {format_value(a[bad[0]])}")
