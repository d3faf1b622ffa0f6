"""Cloth-grid topology: vectorised spring index pairs and pin masks of an ``nx`` x ``ny`` grid.

Particle ``(i, j)`` of a grid has the local index ``j*nx + i``; ``i`` runs along the first
in-plane axis, ``j`` along the second. Pure functions of the grid shape (and, for pin boxes,
of the particle positions), shared by :meth:`springsim.ModelBuilder.add_cloth_grid`, the YAML
loader and the exporters.

Pin specifications (:func:`pin_mask`, :func:`cloth_pin_mask`)
--------------------------------------------------------------
A ``pin`` is one of:

- ``None`` or ``"none"``: nothing;
- a name of :data:`PIN_NAMES` (cloth grids only), seen in the grid's plane with ``i`` to the
  right and ``j`` upwards: ``"bottom"`` (row ``j = 0``; ``"edge"`` is the same, its former
  name), ``"top"`` (``j = ny - 1``), ``"left"`` (column ``i = 0``), ``"right"`` (``i = nx - 1``),
  ``"bottom-left"`` ``(0, 0)``, ``"bottom-right"`` ``(nx-1, 0)``, ``"top-left"`` ``(0, ny-1)``,
  ``"top-right"`` ``(nx-1, ny-1)``, ``"corners"`` (the two corners of row ``j = 0``),
  ``"all-corners"`` (all four), ``"ends"`` (rows ``j = 0`` and ``j = ny - 1``);
- a particle index (an integer; local ``j*nx + i`` in a grid), or a list, range or integer array
  of them;
- a boolean array of shape (count,) (Python API only);
- a mapping ``{"box": [[xmin, ymin, zmin], [xmax, ymax, zmax]]}``: the particles whose
  (initial) position lies in the closed box [m], at least one;
- a mapping ``{"i": I, "j": J}`` (cloth grids only): the particle ``(I, J)``;
- a list of names, indices and mappings: their union.

Errors are :class:`~springsim.errors.SceneError` (``SceneTypeError`` for wrong types) with a
one-line message naming the item, e.g. ``cloth.pin[2]: unknown pin name 'topp'; choose one of ...``.
"""

from __future__ import annotations

import reprlib

import numpy as np

from ..errors import SceneError, SceneTypeError

__all__ = [
    "PIN_MODES",
    "PIN_NAMES",
    "PLANES",
    "cloth_grid_pairs",
    "cloth_pin_mask",
    "cloth_quads",
    "index_mask",
    "pin_mask",
    "springs_outside_grids",
]

_S = slice(None)
#: Named pins of a grid: name -> (row j, column i) selectors of the (ny, nx) index array.
_NAMED_PINS = {
    "none": (),
    "edge": ((0, _S),),
    "corners": ((0, 0), (0, -1)),
    "ends": ((0, _S), (-1, _S)),
    "bottom": ((0, _S),),
    "top": ((-1, _S),),
    "left": ((_S, 0),),
    "right": ((_S, -1),),
    "bottom-left": ((0, 0),),
    "bottom-right": ((0, -1),),
    "top-left": ((-1, 0),),
    "top-right": ((-1, -1),),
    "all-corners": ((0, 0), (0, -1), (-1, 0), (-1, -1)),
}

#: Names accepted by a cloth grid's ``pin`` (alone or in a list); see the module docstring.
PIN_NAMES = tuple(_NAMED_PINS)

#: Former name of :data:`PIN_NAMES` (it held ``none``, ``edge``, ``corners``, ``ends``, which keep their meaning).
PIN_MODES = PIN_NAMES

#: Accepted values of ``plane`` and the axes they span.
PLANES = {"xy": (0, 1), "xz": (0, 2), "yz": (1, 2)}

_PIN_FORMS = ("an edge or corner name, a particle index, {box: [[xmin, ymin, zmin], [xmax, ymax, zmax]]} "
              "or {i: I, j: J}")

_REPR = reprlib.Repr()
_REPR.maxlevel, _REPR.maxlist, _REPR.maxdict, _REPR.maxstring, _REPR.maxother = 2, 4, 3, 40, 40


def _show(v) -> str:
    """A short repr for messages, bounded for any value."""
    s = _REPR.repr(v)
    return s if len(s) <= 60 else s[:57] + "..."


def _what(v) -> str:
    return {bool: "a boolean", str: "a string", list: "a list", tuple: "a tuple", dict: "a mapping",
            type(None): "null", int: "an integer", float: "a number"}.get(type(v), type(v).__name__)


def cloth_grid_pairs(nx: int, ny: int, *, bending: bool = True) -> dict[str, np.ndarray]:
    """Spring index pairs of an ``nx`` x ``ny`` grid (local indices ``j*nx + i``).

    Returns a dict with ``structural_x`` (along i), ``structural_y`` (along j),
    ``shear`` (both diagonals) and, when ``bending``, ``bending`` (distance two along
    i and j); each an int64 array of shape (k, 2).

    Parameters
    ----------
    nx, ny : int
        Particles along i and j, each >= 1.
    bending : bool
        Include the bending pairs (distance two along i and j).

    Returns
    -------
    dict of str to ndarray
        Family name -> int64 array of local index pairs, shape (k, 2).
    """
    idx = np.arange(nx * ny, dtype=np.int64).reshape(ny, nx)

    def pairs(a, b):
        return np.stack([a.ravel(), b.ravel()], axis=1)

    out = {
        "structural_x": pairs(idx[:, :-1], idx[:, 1:]),
        "structural_y": pairs(idx[:-1, :], idx[1:, :]),
        "shear": np.concatenate([pairs(idx[:-1, :-1], idx[1:, 1:]), pairs(idx[:-1, 1:], idx[1:, :-1])]),
    }
    if bending:
        out["bending"] = np.concatenate([pairs(idx[:, :-2], idx[:, 2:]), pairs(idx[:-2, :], idx[2:, :])])
    return out


def cloth_pin_mask(nx: int, ny: int, pin="edge", *, positions=None, path: str = "cloth.pin") -> np.ndarray:
    """Boolean mask (nx*ny,) of the pinned particles of an ``nx`` x ``ny`` grid.

    Parameters
    ----------
    nx, ny
        Grid shape; particle ``(i, j)`` is ``j*nx + i``.
    pin
        A pin specification (module docstring): a name of :data:`PIN_NAMES` (``"edge"``: the row
        j = 0; ``"corners"``: its two corners; ``"ends"``: rows j = 0 and j = ny - 1; ``"top"``,
        ``"left"``, ...), local indices, ``{"i": I, "j": J}``, ``{"box": [lo, hi]}`` or a list of these.
    positions
        Particle positions (nx*ny, 3) [m]; needed by boxes only.
    path
        Field path used in error messages.

    Returns
    -------
    ndarray of bool, shape (nx*ny,)

    Raises
    ------
    SceneError
        An invalid specification, naming ``path`` (:func:`pin_mask`).
    """
    return pin_mask(pin, nx * ny, positions=positions, grid=(nx, ny), path=path)


def pin_mask(pin, count: int, *, positions=None, grid: tuple[int, int] | None = None,
             path: str = "pin", rows: tuple[int, int] | None = None) -> np.ndarray:
    """Boolean mask (count,) of the particles a pin specification selects (module docstring).

    Parameters
    ----------
    pin
        The specification.
    count
        Number of particles indices refer to (``nx*ny`` for a grid).
    positions
        Positions (count, 3) [m] the boxes test; None: boxes are an error.
    grid
        ``(nx, ny)`` when the particles are a cloth grid: enables names and ``{i: , j: }``.
    path
        Field path used in error messages (``cloth.pin``, ``pin``).
    rows
        ``(lo, hi)``: the mask of particles ``lo .. hi-1`` only, ``positions`` being theirs (hi - lo, 3): a
        distributed reader's block of a scene (indices still refer to all ``count`` particles; not with ``grid``).
        A box that holds none of these particles is then not an error (:func:`pin_boxes` for the caller's check).

    Returns
    -------
    ndarray of bool, shape (count,), or (hi - lo,) with ``rows``

    Raises
    ------
    SceneError
        One line naming the offending item (``cloth.pin[2]: ...``).
    """
    if rows is not None and grid is not None:
        raise ValueError("pin_mask: rows with a grid")
    lo, hi = (0, count) if rows is None else rows
    mask = np.zeros(hi - lo, dtype=bool)
    if pin is None:
        return mask
    if isinstance(pin, (np.ndarray, range)):
        return mask | index_mask(path, pin, count)[lo:hi]
    if isinstance(pin, (list, tuple)):
        if not pin:
            return mask
        if set(map(type, pin)) <= {int}:  # the common bulk form: no Python loop over the indices
            return mask | index_mask(path, pin, count)[lo:hi]
        for k, item in enumerate(pin):
            if isinstance(item, (list, tuple, np.ndarray, range)):
                raise SceneTypeError(f"{path}[{k}]", f"must be {_PIN_FORMS}, got {_what(item)} {_show(item)}")
            _add_pin(mask, item, f"{path}[{k}]", positions, grid, count, lo)
        return mask
    _add_pin(mask, pin, path, positions, grid, count, lo)
    return mask


def pin_boxes(pin, path: str = "pin") -> list[tuple[str, np.ndarray]]:
    """The boxes of a valid pin specification (:func:`pin_mask` checked it): ``(path, corners (2, 3))`` each.

    Parameters
    ----------
    pin
        The specification.
    path
        Its field path.

    Returns
    -------
    list of (str, ndarray)
        The box items' paths (``pin[2].box``) and corners ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]``.
    """
    items = list(enumerate(pin)) if isinstance(pin, (list, tuple)) else [(None, pin)]
    return [(f"{path}{'' if k is None else f'[{k}]'}.box", np.array(item["box"], dtype=np.float64))
            for k, item in items if isinstance(item, dict) and set(item) == {"box"}]


def index_mask(path: str, indices, count: int) -> np.ndarray:
    """Boolean mask (count,) of particle ``indices``: an integer, a list, range or integer array of them,
    or a boolean array of shape (count,) (returned as a copy); vectorised. Booleans mixed with integers,
    floats and strings are refused; an out-of-range index is a SceneError naming its item (``path[k]``).

    Parameters
    ----------
    path : str
        Item path for error messages.
    indices : int, sequence of int, range, ndarray of int, or ndarray of bool, shape (count,)
        The particles to mark.
    count : int
        Number of particles.

    Returns
    -------
    ndarray of bool, shape (count,)
        True at the given particles.

    Raises
    ------
    SceneTypeError
        Booleans mixed with integers, floats or strings, or an array of the wrong shape.
    SceneError
        An index out of ``[0, count)``.
    """
    mask = np.zeros(count, dtype=bool)
    if isinstance(indices, (bool, np.bool_)):
        raise SceneTypeError(path, f"must be particle indices or a boolean mask, got a boolean {indices!r}")
    if isinstance(indices, (int, np.integer)):
        if not 0 <= indices < count:
            raise SceneError(path, f"particle index out of range [0, {count}), got {_show(int(indices))}")
        mask[int(indices)] = True
        return mask
    if isinstance(indices, (list, tuple)):
        if not indices:
            return mask
        types = set(map(type, indices))
        if types <= {bool, np.bool_}:
            indices = np.asarray(indices, dtype=bool)
        elif not all(t is int or issubclass(t, np.integer) for t in types):
            k = next(k for k, x in enumerate(indices)
                     if isinstance(x, (bool, np.bool_)) or not isinstance(x, (int, np.integer)))
            raise SceneTypeError(f"{path}[{k}]", f"must be a particle index (an integer), got "
                                                 f"{_what(indices[k])} {_show(indices[k])}")
        else:
            lo, hi = min(indices), max(indices)
            if lo < 0 or hi >= count:
                bad = lo if lo < 0 else hi
                raise SceneError(f"{path}[{indices.index(bad)}]",
                                 f"particle index out of range [0, {count}), got {_show(int(bad))}")
            indices = np.asarray(indices, dtype=np.int64)
    try:
        a = np.asarray(indices)
    except (TypeError, ValueError):
        raise SceneTypeError(path, "must be particle indices or a boolean mask, got a ragged or non-numeric "
                                   "sequence") from None
    if a.dtype.kind == "b":
        if a.shape != (count,):
            raise SceneError(path, f"a boolean mask must have shape ({count},), got {a.shape}")
        return a.copy()
    if a.size == 0 and a.dtype.kind in "iuf":
        return mask
    if a.dtype.kind not in "iu" or a.ndim > 1:
        raise SceneTypeError(path, f"must be particle indices (integers, 1-D) or a boolean mask of shape "
                                   f"({count},), got {a.dtype} values of shape {a.shape}")
    idx = a.reshape(-1)
    bad = np.flatnonzero((idx < 0) | (idx >= count))
    if bad.size:
        raise SceneError(f"{path}[{bad[0]}]",
                         f"particle index out of range [0, {count}), got {_show(int(idx[bad[0]]))}")
    mask[idx] = True
    return mask


def _add_pin(mask: np.ndarray, item, path: str, positions, grid, count: int, lo: int = 0) -> None:
    """Set in ``mask`` (particles ``lo ..`` of ``count``) the particles of one pin item: a name, an index or a
    mapping."""
    if isinstance(item, str):
        if grid is None:
            raise SceneError(path, f"edge and corner names such as {_show(item)} apply to a cloth block; "
                                   f"here give particle indices or a {{box: ...}}")
        sel = _NAMED_PINS.get(item)
        if sel is None:
            raise SceneError(path, f"unknown pin name {_show(item)}; choose one of {', '.join(PIN_NAMES)}")
        nx, ny = grid
        m = mask.reshape(ny, nx)
        for rows, cols in sel:
            m[rows, cols] = True
    elif isinstance(item, (int, np.integer)) and not isinstance(item, (bool, np.bool_)):
        mask |= index_mask(path, item, count)[lo:lo + mask.size]
    elif isinstance(item, dict):
        keys = set(item)
        if keys == {"box"}:
            mask |= _box_mask(f"{path}.box", item["box"], positions, required=lo == 0 and mask.size == count)
        elif keys == {"i", "j"}:
            if grid is None:
                raise SceneError(path, "{i: , j: } applies to a cloth block; here give particle indices or a "
                                       "{box: ...}")
            nx, ny = grid
            i = _grid_coordinate(f"{path}.i", item["i"], nx)
            j = _grid_coordinate(f"{path}.j", item["j"], ny)
            mask[j * nx + i] = True
        else:
            raise SceneError(path, f"a pin mapping is {{box: [[xmin, ymin, zmin], [xmax, ymax, zmax]]}} or "
                                   f"{{i: I, j: J}}, got the keys {_show(sorted(map(str, keys)))}")
    else:
        raise SceneTypeError(path, f"must be {_PIN_FORMS}, got {_what(item)} {_show(item)}")


def _grid_coordinate(path: str, v, n: int) -> int:
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)):
        raise SceneTypeError(path, f"must be an integer in [0, {n}), got {_what(v)} {_show(v)}")
    if not 0 <= v < n:
        raise SceneError(path, f"must be an integer in [0, {n}), got {_show(int(v))}")
    return int(v)


def _is_number(x) -> bool:
    return isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, (bool, np.bool_))


def _box_mask(path: str, box, positions, required: bool = True) -> np.ndarray:
    """Particles whose position lies in the closed box ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]``; an error if
    there is none, when ``required`` (a box over all the particles)."""
    form = "must be [[xmin, ymin, zmin], [xmax, ymax, zmax]]"
    if isinstance(box, np.ndarray):
        if box.dtype.kind not in "iuf" or box.shape != (2, 3):
            raise SceneTypeError(path, f"{form}, got an array of {box.dtype} with shape {box.shape}")
        corners = box.astype(np.float64)
    else:
        if not isinstance(box, (list, tuple)) or len(box) != 2:
            raise SceneTypeError(path, f"{form}, got {_what(box)} {_show(box)}")
        for k, corner in enumerate(box):
            if isinstance(corner, np.ndarray):
                corner = corner.tolist()
            if not isinstance(corner, (list, tuple)) or len(corner) != 3:
                raise SceneTypeError(f"{path}[{k}]", f"must be 3 numbers [x, y, z], got {_what(corner)} "
                                                     f"{_show(corner)}")
            for c, x in enumerate(corner):
                if not _is_number(x):
                    raise SceneTypeError(f"{path}[{k}][{c}]", f"must be a number, got {_what(x)} {_show(x)}")
        try:
            corners = np.array(box, dtype=np.float64)
        except OverflowError:
            corners = np.full((2, 3), np.inf)
    bad = np.argwhere(~np.isfinite(corners))
    if bad.size:
        k, c = bad[0]
        raise SceneError(f"{path}[{k}][{c}]", f"must be finite, got {corners[k, c]}")
    lo, hi = corners
    if np.any(lo > hi):
        raise SceneError(path, f"needs min <= max in every coordinate, got {_show(corners.tolist())}")
    if positions is None:
        raise SceneError(path, "a box needs the particle positions")
    q = np.asarray(positions, dtype=np.float64)
    inside = np.all((q >= lo) & (q <= hi), axis=1)
    if required and not inside.any():
        span = "" if not q.shape[0] else (f" (the particles span [{', '.join(f'{x:g}' for x in q.min(axis=0))}] "
                                          f"to [{', '.join(f'{x:g}' for x in q.max(axis=0))}])")
        raise SceneError(path, f"contains no particle{span}")
    return inside


def cloth_quads(start: int, nx: int, ny: int) -> np.ndarray:
    """The (nx-1)(ny-1) quads (Q, 4) of a grid whose particle (0, 0) has index ``start``, counter-clockwise.

    Parameters
    ----------
    start : int
        Index of the grid's particle (0, 0).
    nx, ny : int
        Particles along i and j.

    Returns
    -------
    ndarray of int64, shape ((nx-1)(ny-1), 4)
        Particle indices of each quad.
    """
    idx = start + np.arange(nx * ny, dtype=np.int64).reshape(ny, nx)
    return np.stack([idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()], axis=1)


def springs_outside_grids(model) -> np.ndarray:
    """Indices of the springs that do not join two particles of the same cloth grid (drawn as lines
    when the grids are drawn as surfaces, e.g. a weight hung from a cloth).

    Parameters
    ----------
    model : Model
        A model whose ``cloth_grids`` records its grids ``(start, nx, ny)``.

    Returns
    -------
    ndarray of int64, shape (k,)
        Spring indices.
    """
    inside = np.zeros(model.spring_count, dtype=bool)
    ij = model.spring_indices
    for start, nx, ny in model.cloth_grids:
        end = start + nx * ny
        inside |= (ij >= start).all(axis=1) & (ij < end).all(axis=1)
    return np.flatnonzero(~inside)
