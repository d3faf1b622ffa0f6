"""The distributed fixed-step driver: :func:`simulate_distributed`.

Call it on every rank of the communicator with the same model and options (``mpiexec -n 4 python
script.py``, or ``mpiexec -n 4 springsim run scene.yaml --backend petsc``). Frames are gathered on the root
rank, which returns the :class:`~springsim.driver.Trajectory`; the other ranks return None. Blow-ups are
detected as in the serial driver (a non-finite state, or more kinetic plus gravitational energy than the
forces can supply, :class:`springsim.energy.EnergyBound`) from global reductions, so every rank stops at
the same step with the same :class:`~springsim.errors.SimulationError`; the root's carries the frames so far.
"""

from __future__ import annotations

import time

import numpy as np

from ..driver import Trajectory, _count, _positive_time, report
from ..energy import EnergyBound
from ..errors import SimulationError, SpringsimError
from ..progress import as_progress
from .integrators import make_distributed_integrator
from .system import DistributedSystem

__all__ = ["simulate_distributed", "DistributedRun"]


class DistributedRun:
    """A distributed run's system, integrator, owned state and recorded frames (on ``root``)."""

    def __init__(self, model, integrator: str, *, comm=None, linear_rtol: float = 1e-6, linear_maxiter: int = 1000,
                 petsc_options=None, check_energy: bool = True, root: int = 0, partitioner: str = "contiguous",
                 **options):
        self.model = model
        self.system = DistributedSystem(model, comm, rtol=linear_rtol, maxiter=linear_maxiter,
                                        petsc_options=petsc_options, partitioner=partitioner)
        self.integrator = make_distributed_integrator(integrator, self.system, **options)
        s, p = self.system, self.system.part
        own = p.local_particles[:p.n_own]
        self.q = np.array(model.particle_q[own])
        self.v = np.array(model.particle_qd[own])
        self.root = root
        self.is_root = s.rank == root
        self.bound = None
        if check_energy:
            self.bound = EnergyBound(model, model.particle_q, model.particle_qd)
            fixed = model.particle_fixed
            q_fixed = np.where(fixed[:, None], model.particle_q, 0.0)
            self._w_fixed = self.bound.work(q_fixed, np.zeros_like(q_fixed))  # gravity on the fixed particles
            self._unbounded = [t for t in s.particle_terms if not np.isfinite(t.potential_floor())]
        self.t, self.frames_q, self.frames_qd, self.stats = [], [], [], []
        self.time = 0.0
        self.recorded = False
        self.steps = 0
        self.record()

    def record(self) -> None:
        q, v = self.system.gather_full(self.q, self.v, root=self.root)
        if self.is_root:
            self.t.append(self.time)
            self.frames_q.append(q)
            self.frames_qd.append(v)
        self.recorded = True

    def work(self, q, v) -> float:
        """``W = T + V_gravity`` of the global state (as :meth:`springsim.energy.EnergyBound.work`)."""
        s = self.system
        with np.errstate(over="ignore", invalid="ignore"):
            local = 0.5 * float(np.einsum("i,ij,ij->", s.mass, v, v))
            local += sum(float(t.potential_energy(q)) for t in self._unbounded)
        return float(s.mpi.allreduce(local)) + self._w_fixed

    def problem(self, q, v) -> str | None:
        """Why ``(q, v)`` is a blow-up, or None; the same answer on every rank."""
        if not self.system.all_finite(q, v):
            return "a particle has a non-finite position or velocity"
        if self.bound is not None:
            w = self.work(q, v)
            if not w <= self.bound.limit:
                return (f"kinetic plus gravitational energy reached {w:.3g} J, more than the forces can supply "
                        f"from the start ({self.bound.w_max:.3g} J)")
        return None

    def trajectory(self, wall: float, cpu: float, meta: dict):
        if not self.is_root:
            return None
        return Trajectory(np.array(self.t), np.array(self.frames_q), np.array(self.frames_qd), self.stats, wall, cpu,
                          None, dict(meta))


def simulate_distributed(model, integrator: str, dt: float, steps: int, *, comm=None, frame_every: int = 1,
                         record: bool = True, progress=None, check_energy: bool = True, linear_rtol: float = 1e-6,
                         linear_maxiter: int = 1000, petsc_options=None, root: int = 0,
                         partitioner: str = "contiguous", **options):
    """Run ``steps`` steps of ``integrator`` on every rank of ``comm`` (default ``PETSc.COMM_WORLD``).

    Parameters
    ----------
    model : Model
        The same model on every rank.
    integrator : str
        A name of :data:`springsim.distributed.DISTRIBUTED_INTEGRATORS`.
    dt, steps, frame_every, record, progress, check_energy
        As :func:`springsim.simulate` (``progress`` is called on the root rank only).
    linear_rtol, linear_maxiter : float, int
        Tolerance on the true relative residual and iteration limit of the KSP solves.
    petsc_options : str or dict, optional
        PETSc options (``"-pc_gamg_threshold 0.02 -ksp_type gmres"``); the command line's and
        ``PETSC_OPTIONS``' apply too.
    root : int
        The rank that gathers the frames.
    partitioner : str
        ``contiguous`` (default) or a graph partitioner of PETSc (``ptscotch``, ``parmetis``), see
        :class:`~springsim.distributed.system.DistributedSystem`.
    **options
        Options of the implicit integrators: ``jacobian`` (default ``spd``), ``newton_tol``, ``newton_maxiter``,
        ``residual_rtol``, ``line_search``, ``min_step``, ``on_nonconvergence``, ``forcing``, ``forcing_max``.

    Returns
    -------
    Trajectory or None
        On ``root`` the trajectory (``meta`` records ``backend: petsc`` and the rank count), None elsewhere.

    Raises
    ------
    SimulationError
        On every rank, at the same step, for a blow-up or a solver error; on ``root`` it carries the frames so far.
    """
    dt = _positive_time("dt", dt)
    steps = _count("steps", steps, 0)
    frame_every = _count("frame_every", frame_every, 1)
    t_init = time.perf_counter()
    run = DistributedRun(model, integrator, comm=comm, linear_rtol=linear_rtol, linear_maxiter=linear_maxiter,
                         petsc_options=petsc_options, check_energy=check_energy, root=root,
                         partitioner=partitioner, **options)
    progress = as_progress(progress) if run.is_root else None
    from .. import __version__

    integ = run.integrator
    meta = {"springsim_version": __version__, "model_fingerprint": model.fingerprint(),
            "scene": model.metadata.get("name"), "source": model.metadata.get("source"), "integrator": integ.name,
            "linear_solver": "petsc" if integ.implicit else None, "jacobian": getattr(integ, "jacobian", None),
            "backend": "petsc", "ranks": run.system.size, "partitioner": partitioner, "dt": dt, "steps": steps,
            "frame_every": frame_every,
            "init_s": time.perf_counter() - t_init}
    wall0, cpu0 = time.perf_counter(), time.process_time()
    k = 0
    try:
        for k in range(1, steps + 1):
            with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                q1, v1, st = integ.step(run.q, run.v, dt)
            why = run.problem(q1, v1)
            if why is not None:
                if not run.recorded:
                    run.record()
                raise SimulationError(
                    f"simulation blew up at step {k} (t={k * dt:g} s): {why}; kept {len(run.t)} finite frame(s) up "
                    f"to t={run.time:g} s; try a smaller time step",
                    run.trajectory(time.perf_counter() - wall0, time.process_time() - cpu0, meta), step=k)
            run.q, run.v = q1, v1
            run.stats.append(st)
            run.time, run.steps, run.recorded = k * dt, k, False
            if k == steps or (record and k % frame_every == 0):
                run.record()
            if progress is not None:
                progress(k, steps)
    except SimulationError:
        raise
    except SpringsimError as e:
        if not run.recorded:
            run.record()
        raise SimulationError(f"simulation stopped at step {k} (t={k * dt:g} s): {type(e).__name__}: {e}; kept "
                              f"{len(run.t)} finite frame(s) up to t={run.time:g} s",
                              run.trajectory(time.perf_counter() - wall0, time.process_time() - cpu0, meta),
                              step=k) from e
    traj = run.trajectory(time.perf_counter() - wall0, time.process_time() - cpu0, meta)
    if traj is not None:
        traj.meta["timings"] = {k: float(v) for k, v in run.system.timings.items()}
        report(traj, integ, stacklevel=2)
    run.system.destroy()
    return traj
