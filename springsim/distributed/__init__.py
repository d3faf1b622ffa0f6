"""Distributed runs on PETSc and MPI: springsim's assembly design on PETSc's distributed matrices and solvers.

Optional: it needs petsc4py and mpi4py (no PyPI wheels; docs/distributed.md gives the install), which
only this package imports; the rest of springsim works without them.

* :mod:`~springsim.distributed.partition`: owned particles (contiguous blocks of the free particles in the
  serial system's order), owned pairs (by the owner of the first particle), ghosts, the local models;
  plain numpy.
* :mod:`~springsim.distributed.system`: ghost exchange, forces, the distributed assembly into a PETSc AIJ
  matrix of block size 3, the KSP solve (CG + GAMG with the rigid-body near-null space by default).
* :mod:`~springsim.distributed.integrators`: explicit Euler, symplectic Euler, midpoint, linearized
  implicit Euler and implicit Euler (Newton) on the owned state.
* :mod:`~springsim.distributed.driver`: :func:`simulate_distributed`, frames gathered on the root rank.

From the command line: ``mpiexec -n 4 springsim run scene.yaml --backend petsc``.
"""

from ._petsc import BackendUnavailable, env_rank, env_size, import_petsc, petsc_available
from .integrators import DISTRIBUTED_INTEGRATORS, make_distributed_integrator
from .partition import LocalPart, contiguous_offsets, partition

__all__ = ["BackendUnavailable", "import_petsc", "petsc_available", "env_rank", "env_size", "DISTRIBUTED_INTEGRATORS",
           "make_distributed_integrator", "LocalPart", "contiguous_offsets", "partition", "simulate_distributed",
           "DistributedSystem"]


def __getattr__(name):  # the PETSc-backed parts import petsc4py only when used
    if name == "simulate_distributed":
        from .driver import simulate_distributed

        return simulate_distributed
    if name == "DistributedSystem":
        from .system import DistributedSystem

        return DistributedSystem
    raise AttributeError(name)
