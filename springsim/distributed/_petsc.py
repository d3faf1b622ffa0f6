"""Importing petsc4py and mpi4py, and the MPI rank of a process before MPI is started."""

from __future__ import annotations

import glob
import os
import sys

from ..errors import SpringsimError

__all__ = ["BackendUnavailable", "import_petsc", "petsc_available", "env_rank", "env_size", "INSTALL_HINT"]

#: How to get the backend's dependencies (docs/distributed.md has the details).
INSTALL_HINT = ("the petsc backend needs petsc4py and mpi4py; on Debian/Ubuntu: apt-get install python3-petsc4py "
                "python3-mpi4py, then a venv made with --system-site-packages from /usr/bin/python3 and numpy pinned "
                "to the system's (docs/distributed.md)")


class BackendUnavailable(SpringsimError):
    """petsc4py or mpi4py cannot be imported."""


def _debian_petsc_dirs() -> list[str]:
    """Debian's real-number PETSc builds (``/usr/lib/petscdir/<version>/<arch>-real``), newest first."""
    return sorted(glob.glob("/usr/lib/petscdir/petsc*/*-real"), reverse=True)


def import_petsc():
    """``(PETSc, MPI)``: petsc4py's PETSc module and mpi4py's MPI.

    Debian's ``python3-petsc4py`` finds its build through the ``/usr/lib/petsc`` link that only PETSc's
    development package creates; without it (and without ``PETSC_DIR``) the newest real-number build under
    ``/usr/lib/petscdir`` is used. Sets ``OMP_NUM_THREADS=1`` unless it is set.

    Returns
    -------
    PETSc : module
        ``petsc4py.PETSc``.
    MPI : module
        ``mpi4py.MPI``.

    Raises
    ------
    BackendUnavailable
        With :data:`INSTALL_HINT` when either cannot be imported.
    """
    os.environ.setdefault("OMP_NUM_THREADS", "1")  # some PETSc builds link OpenMP; one thread per rank
    try:
        from petsc4py import PETSc
    except Exception as first:  # ImportError, or ValueError from a numpy it was not built for
        if os.environ.get("PETSC_DIR") or not _debian_petsc_dirs():
            raise BackendUnavailable(f"{INSTALL_HINT} ({first})") from None
        os.environ["PETSC_DIR"] = _debian_petsc_dirs()[0]
        path = os.path.join(os.environ["PETSC_DIR"], "lib", "python3", "dist-packages")
        if path not in sys.path:
            sys.path.append(path)
        try:
            from petsc4py import PETSc
        except Exception as e:  # ImportError, or ValueError from a numpy it was not built for
            sys.path.remove(path)
            del os.environ["PETSC_DIR"]
            raise BackendUnavailable(f"{INSTALL_HINT} ({type(e).__name__}: {e})") from None
    try:
        from mpi4py import MPI
    except ImportError as e:
        raise BackendUnavailable(f"{INSTALL_HINT} ({e})") from None
    return PETSc, MPI


def petsc_available() -> bool:
    """Whether :func:`import_petsc` succeeds.

    Returns
    -------
    bool
    """
    try:
        import_petsc()
    except BackendUnavailable:
        return False
    return True


_RANK_VARS = ("OMPI_COMM_WORLD_RANK", "PMIX_RANK", "PMI_RANK", "MV2_COMM_WORLD_RANK")
_SIZE_VARS = ("OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "MV2_COMM_WORLD_SIZE")


def _env_int(names, default: int) -> int:
    for name in names:
        v = os.environ.get(name)
        if v is not None and v.isdigit():
            return int(v)
    return default


def env_rank() -> int:
    """This process's rank as the MPI launcher announced it (0 when not launched by ``mpiexec``); read from
    the environment, so it is known before (and without) starting MPI.

    Returns
    -------
    int
        From ``OMPI_COMM_WORLD_RANK``, ``PMIX_RANK``, ``PMI_RANK`` or ``MV2_COMM_WORLD_RANK``, the first set.
    """
    return _env_int(_RANK_VARS, 0)


def env_size() -> int:
    """The number of processes ``mpiexec`` started (1 when not launched by it); see :func:`env_rank`.

    Returns
    -------
    int
        From ``OMPI_COMM_WORLD_SIZE``, ``PMI_SIZE`` or ``MV2_COMM_WORLD_SIZE``, the first set.
    """
    return _env_int(_SIZE_VARS, 1)
