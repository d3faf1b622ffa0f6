"""Optional compiled kernels (numba, the ``accel`` extra): availability and the ``kernels`` option.

Every compiled kernel in springsim has a pure numpy/scipy twin that stays the reference path; the
tests check each compiled kernel against its twin. The option value ``"auto"`` picks the compiled
kernel when numba is installed.
"""

from __future__ import annotations

import importlib.util

__all__ = ["numba_available", "resolve"]


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
