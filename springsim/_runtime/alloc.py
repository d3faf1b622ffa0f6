"""Allocator policy of the command line: freed memory is kept for reuse (glibc).

A step of a large scene allocates and frees hundreds of megabytes in large blocks: the AMG setup's
sparse products (whose outputs scipy builds in C++ vectors), assembly and Krylov temporaries. glibc
serves every block above its mmap threshold by a fresh ``mmap`` and returns it with ``munmap``, so the
kernel zero-fills each page again on first touch: on the 256 x 256 benchmark cloth about a fifth of a
linearized implicit Euler step is then system time. :func:`retain_freed_memory` makes glibc's
``malloc`` serve large blocks from its heap and never trim it (``mallopt``: ``M_MMAP_MAX = 0``,
``M_TRIM_THRESHOLD`` and ``M_TOP_PAD`` large), so freed blocks are reused without page faults; the
process keeps its peak memory until it exits (9 % shorter steps, 5 % more peak memory at n = 256:
"Allocator" in the linear-solver notes of BENCHMARKS.md#cloth-grid).

It is a process-wide setting, so only the command line (``springsim`` run as a program) and the
benchmarks apply it; ``SPRINGSIM_RETAIN_MEMORY=0`` turns it off. A program that imports springsim
gets the same effect from glibc's environment variables, set before it starts:
``MALLOC_MMAP_MAX_=0 MALLOC_TRIM_THRESHOLD_=2147483647 MALLOC_TOP_PAD_=268435456``.
Elsewhere than glibc-based Linux it does nothing.
"""

from __future__ import annotations

import ctypes
import os
import platform
import sys

__all__ = ["retain_freed_memory"]

# mallopt parameters (glibc's malloc.h)
_M_TRIM_THRESHOLD, _M_TOP_PAD, _M_MMAP_MAX = -1, -2, -4

_applied = False


def retain_freed_memory() -> bool:
    """Keep freed large blocks in glibc's heap for reuse (module docstring); whether the policy is in force.

    False when ``SPRINGSIM_RETAIN_MEMORY=0``, on other C libraries, or when ``mallopt`` refuses.
    """
    global _applied
    if _applied:
        return True
    if os.environ.get("SPRINGSIM_RETAIN_MEMORY", "1").strip() == "0":
        return False
    if not sys.platform.startswith("linux") or platform.libc_ver()[0] != "glibc":
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):  # pragma: no cover - a glibc without mallopt
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    # mallopt returns 1 on success; the trim threshold and pad are ints (the largest useful values)
    _applied = bool(mallopt(_M_TRIM_THRESHOLD, 2**31 - 1) and mallopt(_M_TOP_PAD, 256 << 20)
                    and mallopt(_M_MMAP_MAX, 0))
    return _applied
