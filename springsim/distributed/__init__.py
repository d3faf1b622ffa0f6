"""Distributed runs on PETSc and MPI: springsim's assembly design on PETSc's distributed matrices and solvers.

Optional: it needs petsc4py and mpi4py (no PyPI wheels; docs/distributed.md gives the install), which
only this package imports; the rest of springsim works without them.

* :mod:`~springsim.distributed.partition`: owned particles (contiguous blocks of the free particles in the
  serial system's order), owned pairs (by the owner of the first particle), ghosts, the local models;
  plain numpy.
* :mod:`~springsim.distributed.scene`: a rank's share of a scene built without the whole model (a cloth grid
  generated per rank, a model scattered from the root); plain numpy but the scatter.
* :mod:`~springsim.distributed.scene_stream`: a rank's share of a scene file read in pieces on the root
  (:func:`streamed_part`): no rank holds the whole model.
* :mod:`~springsim.distributed.system`: ghost exchange, forces, the distributed assembly into a PETSc AIJ
  matrix of block size 3, the KSP solve (CG + GAMG with the rigid-body near-null space by default).
* :mod:`~springsim.distributed.driver`: :func:`make_distributed` (an integrator of
  :mod:`springsim.integrators` over the distributed system: every integrator, adaptive stepping included, runs
  on it unchanged) and :func:`simulate_distributed`, frames gathered on the root rank.

From the command line: ``mpiexec -n 4 springsim run scene.yaml --backend petsc``.
"""

from ._petsc import BackendUnavailable, env_rank, env_size, import_petsc, petsc_available
from .partition import LocalPart, contiguous_offsets, partition
from .scene import ScenePart, benchmark_cloth_part, cloth_grid_part, generated_part, model_part, scatter_model
from .scene_stream import streamed_part

__all__ = ["BackendUnavailable", "import_petsc", "petsc_available", "env_rank", "env_size", "LocalPart",
           "contiguous_offsets", "partition", "simulate_distributed", "make_distributed", "DistributedSystem",
           "ScenePart", "benchmark_cloth_part", "cloth_grid_part", "generated_part", "model_part", "scatter_model",
           "streamed_part"]


def __getattr__(name):  # the PETSc-backed parts import petsc4py only when used
    if name in ("simulate_distributed", "make_distributed"):
        from . import driver

        return getattr(driver, name)
    if name == "DistributedSystem":
        from .system import DistributedSystem

        return DistributedSystem
    raise AttributeError(name)
