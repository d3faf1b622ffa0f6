"""Optional compiled kernels (numba, the ``accel`` extra): availability, the ``kernels`` option, the cache.

Every compiled kernel in springsim has a pure numpy/scipy twin that stays the reference path; the
tests check each compiled kernel against its twin. The option value ``"auto"`` picks the compiled
kernel when numba is installed.

The kernels are compiled with ``cache=True`` (machine code kept on disk between processes). numba
would write that cache into ``__pycache__`` next to the source files, that is into a source checkout
or an installed package; importing springsim (this module, before numba is imported) sets
``NUMBA_CACHE_DIR`` to a per-user cache directory instead, when it is not set already
(:func:`default_numba_cache_dir`: ``$XDG_CACHE_HOME/springsim/numba``, by default
``~/.cache/springsim/numba``; ``~/Library/Caches/springsim/numba`` on macOS,
``%LOCALAPPDATA%\\springsim\\numba`` on Windows). The variable applies to the whole process, as numba
reads it once: set it yourself to choose another directory.
"""

from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path

__all__ = ["numba_available", "resolve", "default_numba_cache_dir", "use_user_numba_cache"]


def default_numba_cache_dir() -> Path | None:
    """The per-user directory for numba's cache of springsim's kernels (None when there is no home directory)."""
    if sys.platform == "win32":
        base = os.environ.get("LOCALAPPDATA")
        return Path(base) / "springsim" / "numba" if base else None
    if sys.platform == "darwin":
        base = Path.home() / "Library" / "Caches"
    else:
        xdg = os.environ.get("XDG_CACHE_HOME")
        base = Path(xdg) if xdg and os.path.isabs(xdg) else Path.home() / ".cache"
    return base / "springsim" / "numba"


def use_user_numba_cache() -> None:
    """Set ``NUMBA_CACHE_DIR`` to :func:`default_numba_cache_dir` unless it is set (also in numba's config when
    numba was imported first), so that compiled kernels are never cached inside the source tree."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return
    try:
        d = default_numba_cache_dir()
    except (RuntimeError, KeyError, OSError):  # Path.home() without a home directory
        return
    if d is None:
        return
    os.environ["NUMBA_CACHE_DIR"] = str(d)
    config = sys.modules.get("numba.core.config")
    if config is not None:
        config.CACHE_DIR = str(d)


use_user_numba_cache()


def numba_available() -> bool:
    """Whether numba can be imported (without importing it)."""
    return importlib.util.find_spec("numba") is not None


def resolve(kernels: str, pure: str, accepted: tuple[str, ...], available=None) -> str:
    """``"numba"`` or ``pure`` for the option value ``kernels`` (``"auto"``: numba when ``available()``,
    by default :func:`numba_available`).

    Raises
    ------
    ValueError
        For a value not in ``accepted``, or ``"numba"`` without numba installed.
    """
    if kernels not in accepted:
        raise ValueError(f"kernels must be one of {', '.join(map(repr, accepted))}, got {kernels!r}")
    if kernels == pure:
        return pure
    if (available or numba_available)():
        return "numba"
    if kernels == "numba":
        raise ValueError("kernels='numba' needs numba, which is not installed (pip install 'springsim[accel]')")
    return pure
