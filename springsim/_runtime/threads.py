"""Thread policy of springsim's numerical kernels: one BLAS thread inside a solve.

springsim's dense kernels are small: 3x3 block inverses, the AMG coarse-level
pseudo-inverse (a few hundred unknowns), the dense reference solver on small scenes.
Multithreaded OpenBLAS gains nothing on them and, when the cores are busy, its
spinning worker threads slow them down several times (BENCHMARKS.md#blas-threads).
Sparse kernels (scipy, pyamg, SuperLU) are single-threaded anyway.

So every linear solve runs inside :func:`single_blas_thread`, which limits the BLAS
libraries loaded in the process to one thread and restores their setting afterwards
(about 10 us per call). It uses `threadpoolctl <https://github.com/joblib/threadpoolctl>`_,
an optional extra (``pip install 'springsim[threads]'``); without it this is a no-op
and the environment (``OPENBLAS_NUM_THREADS=1``) is the way to get the same effect.
"""

from __future__ import annotations

import contextlib

__all__ = ["single_blas_thread", "have_threadpoolctl"]

_controller = None  # a threadpoolctl.ThreadpoolController, created at the first solve (after scipy loaded BLAS)


def have_threadpoolctl() -> bool:
    """Whether the optional threadpoolctl is importable."""
    try:
        import threadpoolctl  # noqa: F401
    except ImportError:
        return False
    return True


def single_blas_thread():
    """A context manager limiting every loaded BLAS to one thread (no-op without threadpoolctl)."""
    global _controller
    if _controller is None:
        try:
            from threadpoolctl import ThreadpoolController
        except ImportError:
            _controller = False
        else:
            _controller = ThreadpoolController()
    if _controller is False:
        return contextlib.nullcontext()
    return _controller.limit(limits=1, user_api="blas")
