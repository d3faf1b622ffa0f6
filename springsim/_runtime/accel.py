"""Optional compiled kernels (numba, the ``accel`` extra): availability, the ``kernels`` option, the cache.

Every compiled kernel in springsim has a pure NumPy/SciPy twin that stays the reference path; the
tests check each compiled kernel against its twin.

The ``kernels`` option, documented here once: every switch between the two paths takes the same values,
:data:`KERNELS`, checked by one function (:func:`check_kernels`): the forces' ``force_kernels`` (and
``kernels`` of :func:`springsim.forces.make_force_terms`) and the AMG preconditioner's ``kernels``
(:class:`springsim.linsolve.amg.AMGPreconditioner`, also through ``solver_options`` of the iterative solvers).

``"auto"``
    The compiled kernels where numba is installed (and, for the spring forces, the term is large enough to
    gain), else the pure path.
``"numba"``
    The compiled kernels; an error when numba is not installed or does not import.
``"numpy"``
    The pure NumPy/SciPy path (for the AMG preconditioner: scipy's sparse products and pyamg's cycle). The
    AMG preconditioner's former spelling ``"scipy"`` is accepted with a :class:`DeprecationWarning`
    (:data:`KERNEL_ALIASES`).

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

__all__ = ["KERNELS", "KERNEL_ALIASES", "check_kernels", "numba_available", "resolve", "default_numba_cache_dir",
           "use_user_numba_cache"]

#: The values of every ``kernels`` option (module docstring).
KERNELS = ("auto", "numba", "numpy")
#: Former spellings of :data:`KERNELS` values, accepted with a :class:`DeprecationWarning`.
KERNEL_ALIASES = {"scipy": "numpy"}


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


def check_kernels(kernels: str) -> str:
    """The value of a ``kernels`` option, checked: one of :data:`KERNELS` (module docstring); a former spelling
    (:data:`KERNEL_ALIASES`) is mapped to its value with a :class:`DeprecationWarning`.

    Parameters
    ----------
    kernels : str
        The option value given.

    Returns
    -------
    str
        One of :data:`KERNELS`.

    Raises
    ------
    ValueError
        For any other value.
    """
    if isinstance(kernels, str) and kernels in KERNEL_ALIASES:
        import warnings

        new = KERNEL_ALIASES[kernels]
        warnings.warn(f"kernels={kernels!r} is deprecated; use {new!r} (the pure NumPy/SciPy path)", DeprecationWarning,
                      stacklevel=3)
        return new
    if not isinstance(kernels, str) or kernels not in KERNELS:
        raise ValueError(f"kernels must be one of {', '.join(map(repr, KERNELS))}, got {kernels!r}")
    return kernels


def resolve(kernels: str, available=None) -> str:
    """``"numba"`` or ``"numpy"`` for the option value ``kernels`` (checked by :func:`check_kernels`;
    ``"auto"``: numba when ``available()``, by default :func:`numba_available`).

    Parameters
    ----------
    kernels : str
        The option value.
    available : callable, optional
        Whether numba can be used.

    Returns
    -------
    str
        ``"numba"`` or ``"numpy"``.

    Raises
    ------
    ValueError
        For a value not in :data:`KERNELS` (nor a former spelling), or ``"numba"`` without numba installed.
    """
    kernels = check_kernels(kernels)
    if kernels == "numpy":
        return kernels
    if (available or numba_available)():
        return "numba"
    if kernels == "numba":
        raise ValueError("kernels='numba' needs numba, which is not installed (pip install 'springsim[accel]')")
    return "numpy"
