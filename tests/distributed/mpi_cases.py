"""Programs the distributed tests start under ``mpiexec`` (``python -m tests.distributed.mpi_cases CASE ...``)."""

from __future__ import annotations

import sys

import numpy as np


#: Minimize stages converge to their force tolerance and solve no tighter than it needs: a tight one, so that the
#: distributed run (KSP) and the serial reference (direct) agree to the linear tolerance.
STAGE_TOLERANCE = {name: {"force_rtol": 1e-9} for name in ("implicit_euler", "bdf2", "tr_bdf2")}


def _state(model, seed=7):
    """A perturbed state: free particles moved by ~1 cm and given velocities (fixed ones stay)."""
    rng = np.random.default_rng(seed)
    free = ~model.particle_fixed[:, None]
    q = model.particle_q + 0.01 * rng.standard_normal(model.particle_q.shape) * free
    v = 0.1 * rng.standard_normal(model.particle_q.shape) * free
    return q, v


def trajectory(scene, integrator, dt, steps, out, partitioner="contiguous"):
    from springsim.distributed import simulate_distributed

    from .scenes import scene as make

    opts = {} if integrator in ("explicit_euler", "symplectic_euler", "midpoint") else dict(jacobian="spd")
    opts.update(STAGE_TOLERANCE.get(integrator, {}))
    traj = simulate_distributed(make(scene), integrator, float(dt), int(steps), linear_rtol=1e-10,
                                on_nonconvergence="ignore", partitioner=partitioner, **opts)
    if traj is not None:
        np.savez(out, q=traj.q, qd=traj.qd, newton=[s.newton_iterations for s in traj.stats],
                 ok=[s.ok for s in traj.stats])
    return 0


def adaptive(scene, integrator, out):
    """Adaptive stepping over the distributed system (the serial controller), to t = 0.2 s."""
    from springsim import simulate_adaptive
    from springsim.distributed import make_distributed

    from .scenes import scene as make

    model = make(scene)
    integ = make_distributed(model, integrator, linear_rtol=1e-10, jacobian="spd", on_nonconvergence="ignore")
    traj = simulate_adaptive(model, integ, 0.2, frame_dt=0.05, time_rtol=1e-3, time_atol=1e-4, h0=1e-2)
    if traj is not None:
        a = traj.adaptive_stats
        np.savez(out, q=traj.q, accepted=a["accepted"], rejected=a["rejected"])
    integ.system.destroy()
    return 0


def trajectory_forcing(scene, dt, steps, out):
    """Implicit Euler with Eisenstat-Walker forcing (Newton to 1e-9 m/s), for comparison with a serial run."""
    from springsim.distributed import simulate_distributed

    from .scenes import scene as make

    traj = simulate_distributed(make(scene), "implicit_euler", float(dt), int(steps), linear_rtol=1e-10,
                                jacobian="spd", stage_solver="residual", newton_tol=1e-9, newton_maxiter=20,
                                forcing="eisenstat-walker",
                                on_nonconvergence="ignore")
    if traj is not None:
        np.savez(out, q=traj.q, ok=[s.ok for s in traj.stats], linres=[s.linear_residual for s in traj.stats])
    return 0


def matrix(scene, out, partitioner="contiguous"):
    """The distributed matrix (gathered) and forces at a perturbed state, with their serial counterparts' inputs."""
    from springsim.distributed import DistributedSystem

    from .scenes import scene as make

    model = make(scene)
    q, v = _state(model)
    ds = DistributedSystem(model, partitioner=partitioner)
    own = ds.part.local_particles[:ds.part.n_own]
    f = ds.forces(q[own], v[own])
    f_full, _ = ds.gather_full(f, f)
    q2, _ = _state(model, seed=11)
    curv = ds.curvature_forces(q[own], q2[own], np.empty((ds.part.n_own, 3)))
    curv_full = None if curv is None else ds.gather_full(curv, curv)[0]
    mats = {}
    # the first assembly inserts by PETSc's MatSetValuesBlockedLocal, the second directly into the AIJ arrays
    # ("-springsim_insertion direct", the default)
    for mode in ("exact", "spd"):
        ds.assemble(q[own], v[own], 2.5e-4, 1.6e-2, mode)
        A = ds.gather_matrix()
        if A is not None:
            A.sort_indices()
            mats[mode] = A
    ghosts = ds.mpi.gather(ds.part.n_ghost)  # collective: every rank
    direct = ds.all(ds._direct is not None)
    if ds.rank == 0:
        extra = {} if curv_full is None else {"curvature": curv_full[model.free_particles]}
        np.savez(out, f=f_full[model.free_particles], size=ds.size, **extra, system_particles=ds.system_particles,
                 ghosts=np.array(ghosts), direct=direct,
                 **{f"{m}_{k}": getattr(A, k) for m, A in mats.items() for k in ("data", "indices", "indptr")})
    return 0


def rank_error(scene_path, rank):
    """``springsim run --backend petsc`` where rank ``rank``'s force evaluation raises at its third call."""
    from springsim.cli import main
    from springsim.distributed import env_rank
    from springsim.distributed.system import DistributedSystem

    calls = {"n": 0}
    original = DistributedSystem.forces

    def forces(self, *a, **k):
        calls["n"] += 1
        if env_rank() == int(rank) and calls["n"] == 3:
            raise RuntimeError("injected failure")
        return original(self, *a, **k)

    DistributedSystem.forces = forces
    return main(["run", scene_path, "--backend", "petsc", "--steps", "5", "-q"])


def solver_failure(scene):
    """A KSP limited to one iteration with ``on_nonconvergence="raise"``: every rank stops at step 1."""
    from springsim.distributed import env_rank, simulate_distributed
    from springsim.errors import SimulationError

    from .scenes import scene as make

    try:
        simulate_distributed(make(scene), "linearized_implicit", 1 / 60, 3, linear_rtol=1e-12,
                             petsc_options="-ksp_max_it 1", on_nonconvergence="raise")
    except SimulationError as e:
        if env_rank() == 0:
            print(f"springsim: error: {e}", file=sys.stderr)
        return 1
    return 0


def pc_reuse(scene, out):
    """The preconditioner options of ``DistributedSystem`` on ``scene`` (every rank; rank 0 writes ``out``, a JSON):
    bad values are refused; the finest GAMG level gets SOR unless the user chose smoothers; a kept preconditioner
    serves the same matrix, and on a much stiffer one it goes stale and a fresh one (CG, not the GMRES escalation)
    gives the answer to the tolerance."""
    import json

    from petsc4py import PETSc

    from springsim.distributed import env_rank
    from springsim.distributed.system import DistributedSystem
    from springsim.errors import SceneError

    from .scenes import scene as make

    opts = PETSc.Options()

    def clear():
        for name in ("springsim_pc_reuse", "springsim_fine_smoother", "mg_levels_pc_type", "springsim_pc",
                     "springsim_insertion", "springsim_sa_smoother"):
            if opts.hasName(name):
                opts.delValue(name)

    model = make(scene)
    report = {}
    for bad in ("-springsim_pc_reuse 0", "-springsim_pc_reuse x", "-springsim_fine_smoother ilu", "-springsim_pc ml",
                "-springsim_insertion csr", "-springsim_sa_smoother ilu"):
        try:
            DistributedSystem(model, petsc_options=bad)
            report[bad] = "accepted"
        except SceneError as e:
            report[bad] = str(e)
        clear()

    def fine_smoother(options):
        s = DistributedSystem(model, rtol=1e-8, petsc_options=options + " -springsim_pc gamg -springsim_pc_reuse 2")
        q, v = s.local_state(model.particle_q, model.particle_qd)
        A = s.assemble(q, v, 1e-4, 1e-2, "spd")
        assert s.solve(A, np.ones(3 * s.part.n_own)).converged
        pc = s._kept[0].getPC()
        fine = pc.getMGSmoother(pc.getMGLevels() - 1)
        kind = f"{fine.getType()}+{fine.getPC().getType()}"
        s.destroy()
        clear()
        return kind

    report["fine_default"] = fine_smoother("")
    report["fine_gamg"] = fine_smoother("-springsim_fine_smoother gamg")
    report["fine_user"] = fine_smoother("-mg_levels_pc_type jacobi")

    def sa_smoothers(options):
        """The finest SA level's smoothers before and after the coarse correction, and the CG iterations."""
        s = DistributedSystem(model, rtol=1e-8, petsc_options=options)
        q, v = s.local_state(model.particle_q, model.particle_qd)
        A = s.assemble(q, v, 1e-2, 1e-1, "spd")
        res = s.solve(A, np.ones(3 * s.part.n_own))
        pc = s._kept[0].getPC()
        L = pc.getMGLevels()
        kinds = [f"{k.getType()}+{k.getPC().getType()}" for k in (pc.getMGSmoother(L - 1), pc.getMGSmoother(L - 2))]
        s.destroy()
        clear()
        return dict(kinds=kinds, ok=res.converged, its=res.iterations)

    report["sa_default"] = sa_smoothers("")
    report["sa_gs"] = sa_smoothers("-springsim_sa_smoother gs")
    report["sa_user"] = sa_smoothers("-springsim_sa_smoother gs -mg_levels_pc_type bjacobi")

    rtol = 1e-8
    for pc in ("gamg", "sa"):
        s = DistributedSystem(model, rtol=rtol, petsc_options=f"-springsim_pc_reuse 3 -springsim_pc {pc}")
        clear()
        q, v = s.local_state(model.particle_q, model.particle_qd)
        rhs = np.ones(3 * s.part.n_own)

        def true_residual(A, x):
            r = rhs - A @ x
            return np.sqrt(s.sum(r @ r)) / np.sqrt(s.sum(rhs @ rhs))

        stats = []
        A = s.assemble(q, v, 1e-8, 1e-4, "spd")  # nearly the mass matrix: a few iterations
        for _ in range(2):  # built, then kept for the same matrix
            res = s.solve(A, rhs)
            stats.append(dict(s.pc_stats, ok=res.converged, its=res.iterations, method=res.method,
                              residual=true_residual(A, res.x)))
        A = s.assemble(q, v, 0.1 ** 2, 0.1, "spd")  # much stiffer: a kept GAMG goes stale
        res = s.solve(A, rhs)
        stats.append(dict(s.pc_stats, ok=res.converged, its=res.iterations, method=res.method,
                          residual=true_residual(A, res.x), fallback=res.fallback))
        s.destroy()
        report[f"solves_{pc}"] = stats
    # springsim's levels kept whole for the same coefficients until that goes stale: the cloth stretched by 1.6 (the
    # finest level swept by springsim's kernels, whose copy of it must follow the matrix)
    s = DistributedSystem(model, rtol=rtol, petsc_options="-springsim_pc_reuse 3 -springsim_sa_smoother gs")
    q, v = s.local_state(model.particle_q, model.particle_qd)
    rhs = np.ones(3 * s.part.n_own)
    switch = []
    for scale in (1.0, 1.0, 1.6):
        A = s.assemble(scale * q, v, 0.01, 0.1, "spd")
        res = s.solve(A, rhs)
        r = rhs - A @ res.x
        switch.append(dict(s.pc_stats, ok=res.converged, whole=s._sa_whole, sweep_refreshes=s._sa.sweep_refreshes,
                           residual=float(np.sqrt(s.sum(r @ r) / s.sum(rhs @ rhs)))))
    s.destroy()
    report["sa_switch"] = switch
    if env_rank() == 0:
        with open(out, "w") as fh:
            json.dump(report, fh)
    return 0



def sa_levels(out):
    """springsim's smoothed aggregation over PETSc matrices (``springsim.distributed.sa``), rank 0 writes ``out``
    (a JSON): on one rank its levels are the serial set-up's; on any number, the coarse operators of a build and of
    ``galerkin`` are ``P^T A P`` of the gathered matrices, the values go straight into and out of PETSc's arrays (and
    through PETSc's calls when that path is refused, with the same hierarchy), CG with it solves the benchmark cloth
    and a straight rope (whose aggregates cannot carry the rotation about the rope: zero prolongator columns) to the
    tolerance, and a matrix that is not positive definite falls back to GAMG."""
    import json

    from springsim import ModelBuilder
    from springsim.distributed import env_rank
    from springsim.distributed.system import DistributedSystem
    from springsim.linsolve._sa import smoothed_aggregation_levels
    from springsim.linsolve.amg import rigid_body_modes
    from springsim.scene.gallery import BENCHMARK_DT, benchmark_cloth

    h = BENCHMARK_DT
    report = {}

    def whole_dense(M):
        """The whole PETSc matrix on every rank, dense (small matrices only)."""
        from petsc4py import PETSc as P
        rows, cols = (P.IS().createStride(n, 0, 1, comm=P.COMM_SELF) for n in M.getSize())
        if M.getType().endswith("baij"):  # (PETSc 3.18's MatCreateSubMatrices on MPIBAIJ refuses these index sets)
            M = M.convert("aij", P.Mat())  # (a new matrix: without one, convert works in place)
        whole = M.createSubMatrices(rows, cols)[0]
        dense = whole.convert("dense").getDenseArray().copy()
        for obj in (whole, rows, cols):
            obj.destroy()
        return dense

    # the benchmark cloth, perturbed from the plane
    model = benchmark_cloth(16)
    q0, v0 = _state(model)
    s = DistributedSystem(model, rtol=1e-8)
    q, v = s.local_state(q0, v0)
    A = s.assemble(q, v, h * h, h, "spd")
    rhs = np.linspace(-1.0, 1.0, 3 * s.part.n_own) + s.rank
    res = s.solve(A, rhs)
    r = rhs - A @ res.x
    report["cloth"] = dict(ok=res.converged, its=res.iterations, method=res.method,
                           residual=float(np.sqrt(s.sum(r @ r) / s.sum(rhs @ rhs))))
    levels = s._sa.levels
    report["cloth_levels"] = [lv.A.getSize()[0] for lv in levels]

    def galerkin_error(levels):
        """Largest relative difference between a coarse operator and ``P^T A P`` of the level above."""
        worst = 0.0
        for fine, coarse in zip(levels[:-1], levels[1:]):
            P, Af = whole_dense(fine.P), whole_dense(fine.A)
            ref = P.T @ Af @ P
            worst = max(worst, float(np.abs(whole_dense(coarse.A) - ref).max() / np.abs(ref).max()))
        return worst

    report["build_diff"] = galerkin_error(levels)
    report["direct"] = dict(read=levels[0].extract.reader is not None,
                            write=[lv.csrP.writer is not None for lv in levels[:-1]]
                            + [lv.csrA.writer is not None for lv in levels[1:]])
    fresh = [whole_dense(lv.A) for lv in levels[1:]]
    if s.size == 1:  # the serial set-up of the same matrix
        import scipy.sparse as sp
        bsr = sp.csr_matrix(whole_dense(s.A)).tobsr(blocksize=(3, 3))
        ref, _ = smoothed_aggregation_levels(bsr, rigid_body_modes(q))
        report["serial_levels"] = [lv.A.shape[0] for lv in ref]
        report["coarse_diff"] = float(np.abs(whole_dense(levels[1].A) - ref[1].A.toarray()).max()
                                      / np.abs(ref[1].A.toarray()).max())
    # a BAIJ copy of the matrix: its arrays hold 3 x 3 blocks, not scalar rows; read through getValuesCSR, the same
    # hierarchy
    from springsim.distributed.sa import SmoothedAggregation
    from petsc4py import PETSc as P

    B = s.A.convert("baij", P.Mat())
    sab = SmoothedAggregation(P, s.comm)
    sab.build(B, rigid_body_modes(np.asarray(s._positions)))
    report["baij"] = dict(read=sab.levels[0].extract.reader is not None,
                          diff=max(float(np.abs(whole_dense(m.A) - f).max() / np.abs(f).max())
                                   for m, f in zip(sab.levels[1:], fresh)))
    sab.destroy()
    B.destroy()
    # galerkin() with new values equals a build with the same prolongators
    A = s.assemble(q, v, 4 * h * h, 2 * h, "spd")
    s._sa.galerkin()
    kept = whole_dense(levels[-1].A)
    Ps = [whole_dense(lv.P) for lv in levels[:-1]]
    Af = whole_dense(s.A)
    for P in Ps:
        Af = P.T @ Af @ P
    report["galerkin_diff"] = float(np.abs(kept - Af).max() / np.abs(Af).max())
    # indefinite: springsim's set-up breaks down, GAMG with CG or GMRES still answers (or the failure is reported)
    A = s.assemble(q, v, -4.0, 0.0, "spd")
    res = s.solve(A, rhs)
    r = rhs - A @ res.x
    report["indefinite"] = dict(ok=res.converged, method=res.method, failure=res.failure,
                                residual=float(np.sqrt(s.sum(r @ r) / s.sum(rhs @ rhs))))
    s.destroy()
    # without the direct access to PETSc's arrays (refused, as for a matrix type it does not handle): the values go
    # through getValuesCSR and MatSetValuesCSR, the hierarchy and the iterations are the same
    import springsim.distributed._aij as aij

    class Refused(aij.AIJValues):
        def __init__(self, *args, **kwargs):
            raise ValueError("refused")

    kept, aij.AIJValues = aij.AIJValues, Refused
    try:
        s = DistributedSystem(model, rtol=1e-8)
        q, v = s.local_state(q0, v0)
        A = s.assemble(q, v, h * h, h, "spd")
        res = s.solve(A, rhs)
        lv = s._sa.levels
        report["petsc_calls"] = dict(ok=res.converged, its=res.iterations, levels=[m.A.getSize()[0] for m in lv],
                                     read=lv[0].extract.reader is not None,
                                     write=any(m.csrA.writer is not None for m in lv[1:]),
                                     diff=max(float(np.abs(whole_dense(m.A) - f).max() / np.abs(f).max())
                                              for m, f in zip(lv[1:], fresh)),
                                     build_diff=galerkin_error(lv))
        A = s.assemble(q, v, 4 * h * h, 2 * h, "spd")
        s._sa.galerkin()
        report["petsc_calls"]["galerkin_diff"] = galerkin_error(s._sa.levels)
        s.destroy()
    finally:
        aij.AIJValues = kept

    # a rank without aggregates: a cloth on the first rows, unconnected free particles after it (their rank's
    # diagonal block is the mass matrix: nothing to aggregate), solved after a build and after a Galerkin update
    b = ModelBuilder(gravity=-9.81)
    b.add_cloth_grid(nx=12, ny=12, size=(1.0, 1.0), total_mass=1.0, stiffness=1e4, pin="top")
    b.add_particles(np.column_stack([np.linspace(2.0, 3.0, 150), np.zeros(150), np.zeros(150)]), mass=0.01)
    mixed = b.finalize()
    s = DistributedSystem(mixed, rtol=1e-8)
    q, v = s.local_state(mixed.particle_q + 0.001, mixed.particle_qd)
    rhs = np.cos(np.arange(3 * s.part.n_own) + s.rank)
    runs = []
    for a in (h * h, 4 * h * h):  # other coefficients: the kept levels' coarse operators are recomputed
        A = s.assemble(q, v, a, np.sqrt(a), "spd")
        res = s.solve(A, rhs)
        r = rhs - A @ res.x
        runs.append(dict(ok=res.converged, method=res.method, its=res.iterations,
                         residual=float(np.sqrt(s.sum(r @ r) / s.sum(rhs @ rhs)))))
    report["empty_rank"] = dict(runs=runs, coarse_updates=s.pc_stats["coarse_updates"],
                                fewest_aggregates=int(s.mpi.allreduce(s._sa.levels[0].aggregates.shape[1],
                                                                      op=s.MPI.MIN)),
                                levels=len(s._sa.levels))
    s.destroy()

    # a straight rope: every aggregate collinear, the rotation about the rope is not representable
    b = ModelBuilder(gravity=-9.81)
    n = 300
    ids = np.asarray(b.add_particles(np.column_stack([np.linspace(0.0, 3.0, n), np.zeros(n), np.zeros(n)]),
                                     mass=0.01, fixed=np.arange(n) == 0))
    b.add_springs(np.column_stack([ids[:-1], ids[1:]]), stiffness=1e4, damping=0.0)
    rope = b.finalize()
    s = DistributedSystem(rope, rtol=1e-8)
    q, v = s.local_state(rope.particle_q, rope.particle_qd)
    A = s.assemble(q, v, h * h, h, "spd")
    rhs = np.cos(np.arange(3 * s.part.n_own) + s.rank)
    res = s.solve(A, rhs)
    r = rhs - A @ res.x
    report["rope"] = dict(ok=res.converged, its=res.iterations, method=res.method,
                          residual=float(np.sqrt(s.sum(r @ r) / s.sum(rhs @ rhs))),
                          levels=[lv.A.getSize()[0] for lv in s._sa.levels],
                          dead=int(s.sum(sum(0 if lv.dead is None else lv.dead.size for lv in s._sa.levels))))
    s.destroy()
    if env_rank() == 0:
        with open(out, "w") as fh:
            json.dump(report, fh)
    return 0


def linear_group(scene, out):
    """``make_distributed`` with a ``LinearSolveOptions`` group: its tolerance reaches the KSP; a solver name or a
    tolerance given twice with another value is refused (rank 0 writes ``out``, a JSON)."""
    import json

    from springsim.distributed import env_rank, make_distributed
    from springsim.errors import SceneError
    from springsim.integrators import LinearSolveOptions

    from .scenes import scene as make

    model = make(scene)
    report = {}
    integ = make_distributed(model, "implicit_euler", linear=LinearSolveOptions(linear_rtol=1e-9))
    report["rtol"] = integ.system.linear_rtol
    integ.system.destroy()
    for name, kwargs in (("solver", dict(linear=LinearSolveOptions(linear_solver="direct"))),
                         ("twice", dict(linear_rtol=1e-7, linear=LinearSolveOptions(linear_rtol=1e-9)))):
        try:
            make_distributed(model, "implicit_euler", **kwargs).system.destroy()
            report[name] = "accepted"
        except SceneError as e:
            report[name] = str(e)
    if env_rank() == 0:
        with open(out, "w") as fh:
            json.dump(report, fh)
    return 0


def built_per_rank(kind, integrator, steps, out, partitioner="contiguous"):
    """A scene no rank holds whole (``cloth``: the benchmark cloth generated per rank; ``scattered``: the irregular
    scene read on rank 0 and scattered), run and streamed to ``out`` by the root; also the replicated model's run
    (``out`` + ``.ref.npz``) for comparison."""
    from springsim.distributed import (benchmark_cloth_part, import_petsc, scatter_model, simulate_distributed)
    from springsim.scene import benchmark_cloth

    from .scenes import scene as make

    _, MPI = import_petsc()
    comm = MPI.COMM_WORLD
    opts = dict(linear_rtol=1e-10, on_nonconvergence="ignore")
    explicit = integrator in ("explicit_euler", "symplectic_euler", "midpoint")
    if not explicit:
        opts.update(jacobian="spd", **STAGE_TOLERANCE.get(integrator, {}))
    if kind == "cloth":
        whole, part = benchmark_cloth(10, kd=0.1), benchmark_cloth_part(10, comm.size, comm.rank, kd=0.1)
    else:
        whole = make("irregular")
        part = scatter_model(whole if comm.rank == 0 else None, comm)
    dt = 1e-3 if explicit else 1 / 60 if kind == "cloth" else 0.01
    traj = simulate_distributed(part, integrator, dt, int(steps), partitioner=partitioner, out=out, **opts)
    ref = simulate_distributed(whole, integrator, dt, int(steps), **opts)
    if comm.rank == 0:
        assert traj.q is None and traj.meta["out"] == out, traj.meta.get("out")
        np.savez(out + ".ref.npz", q=ref.q, qd=ref.qd, newton=[s.newton_iterations for s in ref.stats],
                 fingerprint=str(ref.meta["model_fingerprint"]), ranks=comm.size,
                 part_fingerprint=str(traj.meta["model_fingerprint"]))
    return 0


def stopped_streamed(out):
    """A run that blows up (explicit Euler, a step far too large) with its frames streamed: the frames so far are in
    ``out`` and every rank raises the same SimulationError."""
    from springsim.distributed import benchmark_cloth_part, import_petsc, simulate_distributed
    from springsim.errors import SimulationError

    _, MPI = import_petsc()
    comm = MPI.COMM_WORLD
    try:
        simulate_distributed(benchmark_cloth_part(8, comm.size, comm.rank), "explicit_euler", 0.05, 50, out=out)
    except SimulationError as e:
        print(f"rank {comm.rank}: stopped at step {e.step}", flush=True)
        return 0
    return 1


def signalled_cli(rank, signame, scene_path, out):
    """``springsim run --backend petsc --out`` where only ``rank`` receives ``signame`` (SIGTERM or SIGINT), from
    itself during step 3: every rank must stop after that step, rank 0 save the frames so far, and every rank exit
    with 128 + the signal (the ranks not signalled 130)."""
    import os
    import signal

    from springsim.cli import main
    from springsim.distributed import env_rank
    from springsim.run.driver import RunRecorder

    accept = RunRecorder.accept

    def accept_and_signal(self, stats, t_new):
        accept(self, stats, t_new)
        if self.steps == 3 and env_rank() == int(rank):
            os.kill(os.getpid(), getattr(signal, signame))

    RunRecorder.accept = accept_and_signal
    status = main(["run", scene_path, "--backend", "petsc", "--out", out])
    print(f"rank {env_rank()}: status {status}", flush=True)
    return 0


def cli_generated(scene_path, out):
    """``springsim run --backend petsc`` on a scene of one generator block with the builder's whole-grid method
    disabled: no rank may build the whole model (each generates its part)."""
    from springsim.cli import main
    from springsim.model.builder import ModelBuilder

    def refuse(self, *a, **k):
        raise AssertionError("the whole cloth was built")

    ModelBuilder.add_cloth_grid = refuse
    return main(["run", scene_path, "--backend", "petsc", "--out", out, "-q"])


def weighted_partition(out):
    """PT-Scotch on the distributed graph of a cloth whose upper half has 20 extra springs per particle, with and
    without weighing the particles by their pairs: particles and pair ends per part (rank 0 writes JSON)."""
    import json

    from springsim import ModelBuilder
    from springsim.distributed import import_petsc, scatter_model
    from springsim.distributed.system import graph_parts, part_pattern

    PETSc, MPI = import_petsc()
    comm = MPI.COMM_WORLD
    model = None
    if comm.rank == 0:
        b = ModelBuilder()
        b.add_cloth_grid(20, 20, pin="none")
        i = np.repeat(np.arange(200, 400), 20)
        j = np.clip(i + np.random.default_rng(0).integers(-40, 40, i.size), 200, 399)
        b.add_springs(np.stack([i[i != j], j[i != j]], axis=1), 10.0, 0.0)
        model = b.finalize()
    part = scatter_model(model, comm)
    report = {}
    for weights in (False, True):
        parts = graph_parts(part.part, part.free_count, PETSc.COMM_WORLD, "ptscotch", weights=weights)
        pairs = part_pattern(part.part, part.free_count, comm)[2]
        report[str(weights)] = [comm.allreduce(np.bincount(parts, minlength=comm.size)).tolist(),
                                comm.allreduce(np.bincount(parts, weights=pairs, minlength=comm.size)).tolist()]
    if comm.rank == 0:
        with open(out, "w") as fh:
            json.dump(report, fh)
    return 0

def left_alive(scene):
    """A program that solves with the finest SA level swept by springsim's kernels (a Python PC) and exits without
    destroying its system: it must exit cleanly (the PC's Python context released before PETSc finalises)."""
    from springsim.distributed.system import DistributedSystem

    from .scenes import scene as make

    model = make(scene)
    s = DistributedSystem(model, rtol=1e-8, petsc_options="-springsim_sa_smoother gs")
    q, v = s.local_state(model.particle_q, model.particle_qd)
    A = s.assemble(q, v, 1e-2, 1e-1, "spd")
    assert s.solve(A, np.ones(3 * s.part.n_own)).converged
    print("solved", flush=True)
    return 0  # s is not destroyed


def read_in_pieces(path, chunk):
    """A scene file read in chunks of ``chunk`` items on rank 0 and built in parts
    (springsim.distributed.streamed_part): every rank's part, its fixed particles and the whole model's fingerprint
    are those of the model a whole load builds (model_part), to the last bit."""
    import springsim.scene.yaml_stream as ys
    from springsim.distributed import import_petsc, model_part, streamed_part
    from tests.helpers import assert_same_part
    from springsim.scene import load_scene

    _, MPI = import_petsc()
    comm = MPI.COMM_WORLD
    ys.CHUNK_ITEMS = int(chunk)
    got = streamed_part(comm.bcast(load_scene(path, build=False) if comm.rank == 0 else None, root=0), comm)
    whole = load_scene(path).model
    ref = model_part(whole, comm.size, comm.rank)
    assert got.model_fingerprint == whole.fingerprint()
    assert_same_part(got, ref)
    return 0


if __name__ == "__main__":
    case, *args = sys.argv[1:]
    sys.exit(globals()[case](*args))
