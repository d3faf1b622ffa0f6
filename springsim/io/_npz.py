"""Reading trajectory ``.npz`` files in bounded time and memory: every array's header is checked first.

An ``.npz`` is a zip archive of ``.npy`` members, each a short header (dtype, shape) followed by
the data. :func:`npz_headers` reads only the headers; :func:`read_trajectory_npz` checks them
(numbers, no pickled objects, shapes that fit together, a header that does not claim more data
than its member holds, a total that fits in the available memory) before it reads any array,
so a 7 MB file whose header announces 3e8 particles is refused at once, naming the array.
"""

from __future__ import annotations

import json
import math
import os
import zipfile
import zlib

import numpy as np

from .._runtime import memory
from ..errors import SpringsimError

__all__ = ["MAX_META_BYTES", "NpyHeader", "npz_headers", "read_trajectory_npz"]

#: Largest ``meta`` (JSON text) a trajectory file may hold.
MAX_META_BYTES = 16 * 2**20

_MAX_HEADER = 10_000  # numpy's own default limit for an .npy header


class NpyHeader:
    """The header of one ``.npy`` member: ``shape``, ``dtype``, ``nbytes`` (claimed), ``stored`` (bytes held)."""

    __slots__ = ("name", "shape", "dtype", "nbytes", "stored")

    def __init__(self, name, shape, dtype, nbytes, stored):
        self.name, self.shape, self.dtype, self.nbytes, self.stored = name, shape, dtype, nbytes, stored


def _size(n: float) -> str:
    for unit, scale in (("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if n >= scale:
            return f"{n / scale:.1f} {unit}"
    return f"{int(n)} bytes"


def _bad(path: str, msg: str) -> SpringsimError:
    return SpringsimError(f"{path}: not a readable springsim trajectory (.npz with t, q, qd): {msg}")


def _read_header(zf: zipfile.ZipFile, info: zipfile.ZipInfo, path: str, name: str) -> NpyHeader:
    fmt = np.lib.format
    with zf.open(info) as fh:
        try:
            version = fmt.read_magic(fh)
            if version == (1, 0):
                shape, _, dtype = fmt.read_array_header_1_0(fh, max_header_size=_MAX_HEADER)
            elif version == (2, 0):
                shape, _, dtype = fmt.read_array_header_2_0(fh, max_header_size=_MAX_HEADER)
            else:
                raise ValueError(f"unsupported .npy format version {version}")
        except (ValueError, TypeError, SyntaxError, OSError, EOFError, zipfile.BadZipFile, zlib.error) as e:
            raise _bad(path, f"array {name}: bad header ({' '.join(str(e).split())[:200]})") from None
        start = fh.tell()
    if any(not isinstance(n, int) or n < 0 for n in shape):
        raise _bad(path, f"array {name}: bad shape {shape}")
    nbytes = math.prod(shape) * dtype.itemsize
    return NpyHeader(name, tuple(shape), dtype, nbytes, info.file_size - start)


def npz_headers(path) -> dict[str, NpyHeader]:
    """The headers of the arrays in the ``.npz`` ``path`` (name without ``.npy`` -> :class:`NpyHeader`).

    Reads only the zip directory and each member's header.

    Raises
    ------
    SpringsimError
        One line naming the file: missing, not a regular file, not a zip archive, a bad header.
    """
    path = os.fspath(path)
    if not os.path.exists(path):
        raise SpringsimError(f"{path}: no such file")
    if not os.path.isfile(path):
        raise SpringsimError(f"{path}: not a regular file")
    try:
        with zipfile.ZipFile(path) as zf:
            return {info.filename[:-4]: _read_header(zf, info, path, info.filename[:-4])
                    for info in zf.infolist() if info.filename.endswith(".npy")}
    except zipfile.BadZipFile:
        raise _bad(path, "not an .npz (zip) archive") from None
    except (OSError, EOFError, zlib.error, ValueError) as e:
        raise _bad(path, " ".join(str(e).split()) or type(e).__name__) from None


def _check_headers(path: str, h: dict[str, NpyHeader]) -> None:
    for name in ("t", "q"):
        if name not in h:
            raise _bad(path, f"no array {name!r}")
    for a in h.values():
        if a.dtype.hasobject:
            raise _bad(path, f"array {a.name} holds Python objects (pickled data), which springsim does not load")
    for name in ("t", "q", "qd"):
        if name in h and h[name].dtype.kind not in "iuf":
            raise _bad(path, f"array {name} has dtype {h[name].dtype}; expected numbers")
    t, q, qd = h["t"].shape, h["q"].shape, h["qd"].shape if "qd" in h else h["q"].shape
    if len(q) != 3 or q[2] != 3 or len(t) != 1 or t[0] != q[0] or qd != q:
        raise SpringsimError(f"{path}: needs t (F,), q and qd (F, N, 3); got t {t}, q {q}, qd {qd}")
    if "meta" in h:
        m = h["meta"]
        if m.dtype.kind != "U" or m.shape != ():
            raise _bad(path, f"meta must be a 0-d unicode array, got {m.dtype} {m.shape}")
        if m.nbytes > MAX_META_BYTES:
            raise _bad(path, f"meta is {_size(m.nbytes)}, more than the limit of {_size(MAX_META_BYTES)}")
    for a in h.values():
        if a.nbytes > a.stored:
            raise _bad(path, f"the header of array {a.name} claims {a.dtype} {a.shape} ({_size(a.nbytes)}) but "
                             f"the file holds {_size(max(a.stored, 0))} of it (truncated or corrupt)")


def _check_memory(path: str, h: dict[str, NpyHeader]) -> None:
    # t, q and qd as float64, plus the array being read before its conversion
    need = sum(math.prod(h[n].shape) * 8 for n in ("t", "q")) + math.prod(h["q"].shape) * 8
    need += max((a.nbytes for a in h.values()), default=0)
    have = memory.available_memory()
    if have is not None and need > have:
        q = h["q"]
        raise SpringsimError(f"{path}: array q {q.shape} ({q.shape[1]} particles, {q.shape[0]} frames) needs about "
                             f"{_size(need)} of memory to load; {_size(have)} are available")


def _read_meta(path: str, text: str) -> dict:
    try:
        meta = json.loads(text)
    except ValueError as e:
        raise _bad(path, f"meta is not JSON: {' '.join(str(e).split())[:200]}") from None
    except RecursionError:
        raise _bad(path, "meta is nested too deeply") from None
    if not isinstance(meta, dict):
        raise _bad(path, "meta must hold a JSON object")
    return meta


def read_trajectory_npz(path, *, format_name: str, format_version: int):
    """``(t, q, qd, meta)`` of a trajectory file, float64 arrays, in bounded time and memory.

    ``format_name`` and ``format_version`` are the format this springsim reads: a file whose
    ``meta["format"]`` differs or whose ``meta["format_version"]`` is newer is refused.

    Raises
    ------
    SpringsimError
        One line naming the file (and the array or meta field) for every problem.
    """
    path = os.fspath(path)
    h = npz_headers(path)
    _check_headers(path, h)
    _check_memory(path, h)
    arrays = {}
    try:
        with zipfile.ZipFile(path) as zf:
            for name in ("t", "q", "qd", "meta"):
                if name in h:
                    with zf.open(f"{name}.npy") as fh:
                        a = np.lib.format.read_array(fh, allow_pickle=False)
                    if a.shape != h[name].shape or a.dtype != h[name].dtype:  # the file changed meanwhile
                        raise ValueError(f"array {name} changed while it was read")
                    arrays[name] = a
    except (ValueError, OSError, EOFError, zipfile.BadZipFile, zlib.error, KeyError) as e:
        raise _bad(path, " ".join(str(e).split())[:200] or type(e).__name__) from None
    t = np.asarray(arrays["t"], dtype=np.float64)
    q = np.asarray(arrays["q"], dtype=np.float64)
    qd = np.asarray(arrays["qd"], dtype=np.float64) if "qd" in arrays else np.zeros_like(q)
    meta = _read_meta(path, str(arrays["meta"])) if "meta" in arrays else {}
    fmt, version = meta.get("format", format_name), meta.get("format_version", 1)
    if not isinstance(fmt, str):
        raise _bad(path, f"meta.format must be a string, got {type(fmt).__name__} {fmt!r:.60}")
    if isinstance(version, bool) or not isinstance(version, int):
        raise _bad(path, f"meta.format_version must be an integer, got {type(version).__name__} {version!r:.60}")
    if fmt != format_name or version > format_version:
        raise SpringsimError(f"{path}: trajectory format {fmt!r:.60} version {version}; this springsim reads "
                             f"{format_name!r} up to version {format_version}")
    return t, q, qd, meta
