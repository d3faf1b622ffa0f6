"""Distributed runs with the one driver: :func:`simulate_distributed` builds the PETSc system and runs
:func:`springsim.simulate` (or :func:`springsim.simulate_adaptive`) on it.

Call it on every rank of the communicator with the same model and options (``mpiexec -n 4 python
script.py``, or ``mpiexec -n 4 springsim run scene.yaml --backend petsc``). The integrators are the serial ones
(:mod:`springsim.integrators`) over a :class:`~springsim.distributed.DistributedSystem`; frames are gathered on
the root rank, which returns the :class:`~springsim.run.driver.Trajectory`; the other ranks return None. Blow-ups
and stage failures are decided from global reductions, so every rank stops at the same step with the same
:class:`~springsim.errors.SimulationError`; the root's carries the frames so far. Ctrl-C and SIGTERM are deferred
during a step and agreed on after it (:mod:`springsim.run.interrupts`): every rank raises
:class:`~springsim.errors.SimulationInterrupted` at the same step.
"""

from __future__ import annotations

import os
import time

from ..errors import SceneError, SimulationError, SimulationInterrupted
from ..integrators import LinearSolveOptions, make_integrator
from ..linsolve import DEFAULT_RTOL
from ..io._spool import FrameSpool
from ..run.driver import simulate
from .system import DistributedSystem

__all__ = ["simulate_distributed", "make_distributed"]


def make_distributed(model, integrator: str, *, comm=None, linear_rtol: float = DEFAULT_RTOL,
                     linear_maxiter: int = 1000, petsc_options=None, partitioner: str = "contiguous",
                     force_kernels: str = "auto", linear: LinearSolveOptions | None = None, **options):
    """The integrator ``integrator`` over a new :class:`DistributedSystem` of ``model`` (collective).

    Parameters
    ----------
    model : Model or ScenePart
        The same model on every rank, or this rank's part of a scene built per rank.
    integrator : str
        A name of :data:`springsim.integrators.INTEGRATORS`.
    comm : petsc4py Comm, optional
        Default ``PETSc.COMM_WORLD``.
    linear_rtol, linear_maxiter : float, int
        Tolerance on the true relative residual (default :data:`~springsim.linsolve._base.DEFAULT_RTOL`) and
        iteration limit of the KSP solves.
    petsc_options : str or dict, optional
        PETSc options (``"-pc_gamg_threshold 0.02 -ksp_type gmres"``); the command line's and ``PETSC_OPTIONS``'
        apply too.
    partitioner : str
        ``contiguous`` (default) or a graph partitioner of PETSc (``ptscotch``, ``parmetis``).
    force_kernels : {"auto", "numba", "numpy"}
        Compiled force passes or the pure numpy path.
    linear : LinearSolveOptions, optional
        The linear-solve group: its ``linear_rtol`` replaces the default of ``linear_rtol`` (a ``linear_rtol`` set
        to another value as well is refused); its ``linear_solver`` must be unset (the system solves with PETSc's
        KSP).
    **options
        The integrator's options (:func:`springsim.integrators.make_integrator`), except ``solver`` and
        ``solver_options``: the system solves with PETSc's KSP.

    Returns
    -------
    Integrator
        Its :attr:`~springsim.integrators.Integrator.system` is the distributed system.

    Raises
    ------
    SceneError
        For a ``linear`` group that names a solver, or a tolerance given twice with different values.
    """
    if linear is not None:
        given = linear.given()
        if "linear_solver" in given:
            raise SceneError("linear_solver", "the petsc backend solves with PETSc's KSP (choose it with "
                                              "petsc_options); leave linear_solver unset")
        if "linear_rtol" in given:
            if linear_rtol != DEFAULT_RTOL and linear_rtol != given["linear_rtol"]:
                raise SceneError("linear_rtol", f"given twice: linear_rtol={linear_rtol!r:.60} and "
                                                f"LinearSolveOptions(linear_rtol={given['linear_rtol']!r:.60})")
            linear_rtol = given["linear_rtol"]
    system = DistributedSystem(model, comm, rtol=linear_rtol,
                               maxiter=linear_maxiter, petsc_options=petsc_options, partitioner=partitioner,
                               force_kernels=force_kernels)
    return make_integrator(integrator, model, system=system, **options)


def simulate_distributed(model, integrator: str, dt: float, steps: int, *, comm=None, frame_every: int = 1,
                         record: bool = True, progress=None, check_energy: bool = True,
                         linear_rtol: float = DEFAULT_RTOL, linear_maxiter: int = 1000, petsc_options=None,
                         partitioner: str = "contiguous", out=None, **options):
    """Run ``steps`` steps of ``integrator`` on every rank of ``comm`` (default ``PETSc.COMM_WORLD``).

    :func:`make_distributed` then :func:`springsim.simulate`; the arguments are theirs. On the root rank the
    trajectory's ``meta`` records ``backend: petsc``, the rank count and the set-up time (wall ``init_s``, CPU
    ``init_cpu_s``), ``meta["timings"]`` the system's time in exchange, forces, assembly, insertion, preconditioner
    set-up and solves, and ``meta["pc_stats"]`` the preconditioner builds, re-set-ups with a kept interpolation and
    kept ones found stale (:attr:`DistributedSystem.pc_stats`), and ``meta["per_rank"]`` every rank's set-up and
    step times (wall and CPU) and communication (:meth:`DistributedSystem.communication`); the other ranks return
    None. The distributed system is destroyed at the end, whatever happens.

    With ``out``, the root writes every frame to that file as it is gathered (:class:`springsim.io._spool.FrameSpool`)
    instead of holding them: the file is written atomically at the end, also when the run stops with a
    :class:`~springsim.errors.SimulationError` or is interrupted (the frames so far), and the trajectory returned
    has ``q`` and ``qd`` None (``meta["out"]`` names the file).

    Parameters
    ----------
    model : Model or ScenePart
        The same model on every rank, or this rank's part of a scene built per rank
        (:mod:`springsim.distributed.scene`: no rank holds the whole model).
    integrator : str
        A name of :data:`springsim.integrators.INTEGRATORS`.
    dt : float
        Time step [s], finite and > 0.
    steps : int
        Number of steps, >= 0.
    comm : petsc4py Comm, optional
        Default ``PETSc.COMM_WORLD``.
    frame_every : int
        Record every k-th step (:func:`springsim.simulate`).
    record : bool
        If False, keep only the initial and final frames.
    progress : callable(step, steps) or True, optional
        Progress callback (:func:`springsim.simulate`).
    check_energy : bool
        Apply the energy bound after every step.
    linear_rtol, linear_maxiter : float, int
        Tolerance on the true relative residual and iteration limit of the KSP solves (:func:`make_distributed`).
    petsc_options : str or dict, optional
        PETSc options (:func:`make_distributed`).
    partitioner : str
        ``contiguous`` (default) or a graph partitioner of PETSc (``ptscotch``, ``parmetis``).
    out : str or PathLike, optional
        Stream the frames to this ``.npz`` (see above); default: the root's trajectory holds them.
    **options
        ``force_kernels`` and the integrator's options (:func:`make_distributed`).

    Returns
    -------
    Trajectory or None
        The frames on the root rank; None on the others.

    Raises
    ------
    SimulationError
        On every rank, at the same step, for a blow-up or a solver error; on the root it carries the frames so far.
    ~springsim.errors.SimulationInterrupted
        On every rank, at the same step, when any rank received SIGINT (or SIGTERM handled by Python); on the root
        it carries the frames so far.
    """
    t0, c0 = time.perf_counter(), time.process_time()
    integ = make_distributed(model, integrator, comm=comm, linear_rtol=linear_rtol, linear_maxiter=linear_maxiter,
                             petsc_options=petsc_options, partitioner=partitioner, **options)
    init_s, init_cpu_s = time.perf_counter() - t0, time.process_time() - c0
    system = integ.system
    spool = FrameSpool(out) if out is not None and system.is_root else None
    try:
        try:
            t1, c1 = time.perf_counter(), time.process_time()
            traj = simulate(model, integ, dt, steps, frame_every=frame_every, record=record, progress=progress,
                            check_energy=check_energy, frames=spool)
            mine = dict(init_s=init_s, init_cpu_s=init_cpu_s, steps_s=time.perf_counter() - t1,
                        steps_cpu_s=time.process_time() - c1, **system.communication())
            per_rank = system.mpi.gather(mine, root=system.root)
        except (SimulationError, SimulationInterrupted) as e:  # the frames so far go to ``out`` too
            if spool is not None and e.trajectory is not None:
                e.trajectory.meta["out"] = os.fspath(out)
                e.trajectory.save(out)
            raise
        finally:
            timings = {k: float(v) for k, v in system.timings.items()}
            pc_stats = dict(system.pc_stats)
            system.destroy()
        if traj is not None:
            traj.meta["init_s"] = init_s
            traj.meta["init_cpu_s"] = init_cpu_s
            traj.meta["timings"] = timings
            traj.meta["pc_stats"] = pc_stats
            traj.meta["per_rank"] = per_rank
            if spool is not None:
                traj.meta["out"] = os.fspath(out)
                traj.save(out)
                traj.frames = None  # the spool goes below; the file holds the frames
        return traj
    finally:
        if spool is not None:
            spool.discard()
