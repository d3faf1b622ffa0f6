"""The backends of the integrators: :class:`System` (the interface) and :class:`SerialSystem`.

The distributed backend, :class:`springsim.distributed.DistributedSystem`, implements the same interface
on PETSc and MPI (optional: it needs petsc4py and mpi4py).
"""

from ._base import System
from .serial import SerialSystem

__all__ = ["System", "SerialSystem"]
