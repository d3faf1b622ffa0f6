"""Distributed backend against the serial path: time per step split into its parts, memory per rank, agreement.

For each cloth size ``n`` (default 256 512; ``benchmark_cloth(n)``, linearized implicit Euler at h = 1/60 s,
``spd`` Jacobian, linear rtol 1e-6) this runs, one configuration at a time, each in its own processes:

* **serial**: springsim's own path (``auto`` -> AMG-CG with the pyamg hierarchy), ``springsim.simulate``;
* **petsc, r ranks** for every ``r`` of ``--ranks`` (default 1 2): ``mpiexec -n r`` running
  :func:`springsim.distributed.simulate_distributed` (KSP CG with springsim's smoothed aggregation, PETSc
  options from ``--petsc-options``) on the cloth each rank generates for itself (:func:`springsim.distributed.benchmark_cloth_part`; ``--build replicated``:
  every rank builds the whole model, as before).

``--steps`` steps each (default 3; the first includes no extra set-up beyond the preconditioner's first build).
Reported per step (rank 0's wall time, averaged over the steps): total, its ratio to the serial row's
(``ratio_to_serial``), rank 0's CPU time (``cpu_step_s``: less sensitive than wall time to other processes on a
shared machine), force evaluation, assembly (the local COO scatter), insertion into the PETSc matrix
(communication of ghost rows included), ghost exchange, preconditioner set-up, Krylov solve; linear solves and
iterations per step, iterations per solve and their ratio to the serial path's; preconditioner builds, re-set-ups
with a kept interpolation, stale kept ones (``-springsim_pc_reuse``) and kept springsim levels whose coarse
operators were recomputed (``pc_coarse_updates``); peak resident memory of every rank
(``ru_maxrss``); set-up before the first step (partition, pattern, preallocation); the 1-minute load average
before the configuration ran (``load``: state it with every figure; on a machine with c cores, a load near c
before the run means the ranks shared their cores). **Error**: the largest
distance [m] between the configuration's final positions and the serial path's, which both solve to the
same linear tolerance (so it measures the agreement of the two solvers' 1e-6 answers, not an error
against the ODE: that is the same for both, and ``benchmarks/frame_cost.py`` measures it).

**Weak scaling** (``--weak P``, no serial run): one petsc run per rank count ``r`` of ``--ranks`` on the cloth of
side ``round(P sqrt(r))`` (P = 256: 256, 362, 512 on 1, 2, 4 ranks; P = 724 on 2 ranks: 1024), so every rank owns
about P^2 particles (contiguous row bands; ``--partitioner ptscotch``: a graph partition of the distributed
graph). Per step: wall and CPU time of rank 0 and the largest over ranks, the efficiency (1-rank wall time over
this one's), Newton and CG iterations (per step and per solve), GAMG set-up, peak RSS per rank (largest and mean,
and KB per owned particle), and the communication: bytes the ghost scatters move (counted: ghost rows x scatters,
:meth:`springsim.distributed.DistributedSystem.communication`) and the 3x3 blocks of ghost rows sent to their
owners per assembly (counted, 72 bytes each), then the bytes PETSc's log measured in its vector scatters (ghost
exchanges and the Krylov and GAMG products' halos), matrix assemblies (ours and GAMG's), preconditioner set-ups
and Krylov solves (:data:`MESSAGE_EVENTS`; the last two inclusive). Writes ``distributed_weak.csv``, ``.json``
(with the machine) and ``.md``.

Usage::

    python -m benchmarks distributed                         # n = 256 512, serial and 1, 2 ranks
    python -m benchmarks distributed --sizes 64 --steps 2    # quick
    python -m benchmarks distributed --sizes 256 --ranks 1 --petsc-options "-pc_gamg_threshold 0.02"
    python -m benchmarks distributed --weak 256 --ranks 1 2 4 --steps 2    # weak scaling, 256^2 particles per rank
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from .common import RESULTS_DIR, fmt, machine_info, markdown_table, write_csv

__all__ = ["COLUMNS", "WEAK_COLUMNS", "main", "weak_row", "weak_side", "worker"]

COLUMNS = ["n", "dofs", "config", "ranks", "steps", "step_s", "ratio_to_serial", "cpu_step_s", "force_s", "assembly_s",
           "insert_s", "exchange_s", "setup_s", "solve_s", "linear_solves", "linear_its", "its_per_solve",
           "its_ratio_to_serial", "pc_builds", "pc_reuses", "pc_stale", "pc_coarse_updates", "init_s", "max_rss_mb",
           "diff_to_serial_m", "max_linear_residual", "failed_steps", "load", "petsc_options"]

#: PETSc events whose message lengths the petsc runs report (``PETSc.Log``): vector scatters (the ghost exchanges and
#: the matrix-vector products' halo exchanges), matrix assembly (off-process entries, GAMG's own matrices included),
#: preconditioner set-up (PETSc's, and springsim's levels built outside it: ``springsim.distributed.sa.LOG_EVENT``)
#: and Krylov solves (inclusive: they contain scatters and assemblies of their own)
MESSAGE_EVENTS = {"scatter": ("VecScatterBegin", "VecScatterEnd"), "assembly": ("MatAssemblyBegin", "MatAssemblyEnd"),
                  "pc_setup": ("PCSetUp", "SpringsimSASetUp"), "ksp_solve": ("KSPSolve",)}


#: Columns of ``--weak``: per step unless named otherwise; ``*_max`` the largest over ranks, ``efficiency`` the 1-rank
#: wall time per step over this one's; ``ghost_mb`` and ``offproc_mb`` counted from the ghost scatter's size and the
#: 3x3 blocks in ghost rows (72 bytes each), the ``*_mb`` after them measured by PETSc's log (MESSAGE_EVENTS)
WEAK_COLUMNS = ["ranks", "side", "particles", "particles_per_rank", "dofs", "steps", "step_s", "step_s_max",
                "efficiency", "cpu_step_s", "cpu_step_s_max", "newton_its", "linear_solves", "linear_its",
                "its_per_solve", "setup_s", "solve_s", "pc_builds", "init_s", "max_rss_mb", "mean_rss_mb", "kb_per_particle",
                "ghosts", "ghost_mb", "offproc_blocks", "offproc_mb", "scatter_mb", "assembly_mb", "pc_setup_mb",
                "ksp_mb", "failed_steps", "load", "partitioner", "petsc_options"]


def worker(argv) -> int:
    """One configuration (``serial`` in one process, or ``petsc`` on every rank of mpiexec); rank 0 writes JSON."""
    p = argparse.ArgumentParser()
    p.add_argument("mode", choices=("serial", "petsc"))
    p.add_argument("n", type=int)
    p.add_argument("steps", type=int)
    p.add_argument("out")
    p.add_argument("--petsc-options", default="")
    p.add_argument("--build", choices=("per-rank", "replicated"), default="per-rank")
    p.add_argument("--partitioner", default="contiguous")
    a = p.parse_args(argv)
    from springsim.scene import benchmark_cloth

    model = benchmark_cloth(a.n) if a.mode == "serial" or a.build == "replicated" else None
    dt = 1.0 / 60.0
    t0 = time.perf_counter()
    pc = dict(pc_builds=float("nan"), pc_reuses=float("nan"), pc_stale=float("nan"), pc_coarse_updates=float("nan"))
    extra = {}
    if a.mode == "serial":
        from springsim import simulate
        from springsim.integrators import make_integrator

        integ = make_integrator("linearized_implicit", model, solver="auto", solver_options={"rtol": 1e-6})
        init = time.perf_counter() - t0
        c0 = time.process_time()
        traj = simulate(model, integ, dt, a.steps, record=False)
        cpu = time.process_time() - c0
        rank, rss = 0, [resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024]
        st = traj.stats
        parts = dict(force_s=sum(s.force_s for s in st), assembly_s=sum(s.assembly_s for s in st), insert_s=0.0,
                     exchange_s=0.0, setup_s=float("nan"), solve_s=sum(s.solve_s for s in st))
        ranks = 1
        solver = f"serial ({getattr(integ.solver, 'last_choice', None) or integ.solver.name})"
    else:
        from mpi4py import MPI

        from springsim.distributed import simulate_distributed

        from petsc4py import PETSc

        comm = MPI.COMM_WORLD
        rank, ranks = comm.Get_rank(), comm.Get_size()
        PETSc.Log.begin()  # the message counts of PETSc's events (MESSAGE_EVENTS)
        c0 = time.process_time()
        if model is None:  # each rank builds its own rows of the cloth
            from springsim.distributed import benchmark_cloth_part

            model = benchmark_cloth_part(a.n, ranks, rank)
        traj = simulate_distributed(model, "linearized_implicit", dt, a.steps, record=False, linear_rtol=1e-6,
                                    petsc_options=a.petsc_options or None, partitioner=a.partitioner)
        cpu = time.process_time() - c0
        rss = comm.gather(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, root=0)
        # bytes sent plus received by this rank inside each event (PETSc counts both ends: halve the sum)
        msg = comm.gather({k: sum(PETSc.Log.Event(e).getPerfInfo()["messageLength"] for e in events)
                           for k, events in MESSAGE_EVENTS.items()}, root=0)
        init, solver = float("nan"), f"petsc, {ranks} rank(s)"
        if rank == 0:
            st = traj.stats
            parts = dict(traj.meta["timings"])
            init = traj.meta.get("init_s", float("nan"))
            cpu -= traj.meta.get("init_cpu_s", 0.0)  # as the serial row: the steps only
            pc = {f"pc_{k}": v for k, v in traj.meta.get("pc_stats", {}).items()}
            extra = dict(per_rank=traj.meta["per_rank"], msg_bytes={k: sum(m[k] for m in msg) / 2 for k in msg[0]},
                         newton_its=sum(s.newton_iterations for s in st) / max(len(st), 1))
            pc_name = {"springsim-sa": "SA"}.get(traj.meta.get("preconditioner"), "GAMG")
            solver = f"petsc CG+{pc_name}, {ranks} rank(s)"
    if rank == 0:
        steps = max(len(st), 1)
        solves = sum(s.linear_solves for s in st)
        out = dict(step_s=traj.wall_s / steps, cpu_step_s=cpu / steps, **{k: v / steps for k, v in parts.items()},
                   linear_its=sum(s.linear_iterations for s in st) / steps, linear_solves=solves / steps,
                   its_per_solve=sum(s.linear_iterations for s in st) / max(solves, 1), **pc,
                   init_s=init, max_rss_mb=max(rss),
                   rss_mb=rss, ranks=ranks, max_linear_residual=max(s.linear_residual for s in st),
                   failed_steps=sum(not s.ok for s in st), config=solver, **extra)
        np.save(a.out + ".npy", traj.q[-1])
        Path(a.out).write_text(json.dumps(out))
    return 0


def _mpiexec(ranks: int) -> list[str]:
    cmd = ["mpiexec", "--oversubscribe", "--quiet", "-n", str(ranks)]
    if hasattr(os, "geteuid") and os.geteuid() == 0:
        cmd.insert(1, "--allow-run-as-root")
    return cmd


def run_config(mode: str, n: int, steps: int, ranks: int, petsc_options: str, tmp: Path,
               build: str = "per-rank", partitioner: str = "contiguous") -> dict:
    out = tmp / f"{mode}_{n}_{ranks}.json"
    cmd = [sys.executable, "-m", "benchmarks.distributed", "--worker", mode, str(n), str(steps), str(out),
           "--petsc-options=" + petsc_options, "--build", build, "--partitioner", partitioner]
    if mode == "petsc":
        cmd = _mpiexec(ranks) + cmd
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    subprocess.run(cmd, check=True, env=env, cwd=Path(__file__).resolve().parents[1])
    r = json.loads(out.read_text())
    r["q"] = np.load(str(out) + ".npy")
    return r


def weak_side(per_rank: int, ranks: int) -> int:
    """Cloth side of the weak-scaling run on ``ranks`` ranks: ``round(per_rank sqrt(ranks))``."""
    return int(round(per_rank * np.sqrt(ranks)))


def weak_row(r: dict, side: int, steps: int) -> dict:
    """A weak-scaling table row from a petsc worker's JSON ``r`` (every figure per step unless named otherwise)."""
    per = r["per_rank"]
    ranks = len(per)
    msg = r["msg_bytes"]
    mb = 1e6 * steps
    rss = np.asarray(r["rss_mb"])
    particles = side * side
    return dict(ranks=ranks, side=side, particles=particles, particles_per_rank=particles / ranks,
                dofs=3 * (particles - side), steps=steps, step_s=r["step_s"],
                step_s_max=max(q["steps_s"] for q in per) / steps, cpu_step_s=r["cpu_step_s"],
                cpu_step_s_max=max(q["steps_cpu_s"] for q in per) / steps, newton_its=r["newton_its"],
                linear_solves=r["linear_solves"], linear_its=r["linear_its"], its_per_solve=r["its_per_solve"],
                setup_s=r["setup_s"], solve_s=r["solve_s"], pc_builds=r["pc_builds"], init_s=max(q["init_s"] for q in per),
                max_rss_mb=float(rss.max()), mean_rss_mb=float(rss.mean()),
                kb_per_particle=1024 * float(rss.max()) / (particles / ranks),
                ghosts=sum(q["ghosts"] for q in per),
                ghost_mb=sum(q["ghost_bytes"] for q in per) / mb, offproc_blocks=sum(q["offproc_blocks"] for q in per),
                offproc_mb=sum(q["offproc_bytes"] for q in per) / mb, scatter_mb=msg["scatter"] / mb,
                assembly_mb=msg["assembly"] / mb, pc_setup_mb=msg["pc_setup"] / mb, ksp_mb=msg["ksp_solve"] / mb,
                failed_steps=r["failed_steps"])


def weak(a) -> int:
    """``--weak P``: a petsc run per rank count at P^2 particles per rank; table, CSV and JSON."""
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for ranks in a.ranks:
            side = weak_side(a.weak, ranks)
            load = os.getloadavg()[0]
            r = run_config("petsc", side, a.steps, ranks, a.petsc_options, Path(tmp), a.build, a.partitioner)
            row = dict(weak_row(r, side, a.steps), load=load, partitioner=a.partitioner,
                       petsc_options=a.petsc_options)
            base = row if ranks == 1 else next((q for q in rows if q["ranks"] == 1), None)
            row["efficiency"] = base["step_s"] / row["step_s"] if base else float("nan")
            rows.append(row)
            print("  " + ", ".join(f"{k} {fmt(row[k])}" for k in WEAK_COLUMNS if row[k] != ""), flush=True)
            write_csv(a.out / "distributed_weak.csv", rows, WEAK_COLUMNS)
    (a.out / "distributed_weak.json").write_text(json.dumps(dict(machine=machine_info(), rows=rows), indent=1))
    md = markdown_table(rows, WEAK_COLUMNS)
    (a.out / "distributed_weak.md").write_text(md + "\n")
    print(md)
    return 0


def main(argv=None) -> int:
    if argv is None:
        argv = sys.argv[1:]
    if argv and argv[0] == "--worker":
        return worker(argv[1:])
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", type=int, nargs="*", default=[256, 512], help="cloth sizes n (default 256 512)")
    p.add_argument("--ranks", type=int, nargs="*", default=[1, 2], help="MPI rank counts (default 1 2)")
    p.add_argument("--steps", type=int, default=3, help="steps per configuration (default 3)")
    p.add_argument("--petsc-options", default="", help="PETSc options of the petsc runs")
    p.add_argument("--no-serial", action="store_true", help="skip the serial path (no agreement column then)")
    p.add_argument("--build", choices=("per-rank", "replicated"), default="per-rank",
                   help="petsc runs: every rank generates its rows of the cloth (default), or builds the whole model")
    p.add_argument("--weak", type=int, metavar="P",
                   help="weak scaling: P^2 particles per rank, side round(P sqrt(ranks)) (no serial run)")
    p.add_argument("--partitioner", default="contiguous",
                   help="petsc runs: contiguous row bands (default) or a PETSc graph partitioner (ptscotch)")
    p.add_argument("--out", type=Path, default=RESULTS_DIR)
    a = p.parse_args(argv)
    from springsim.distributed import petsc_available

    if not petsc_available() or shutil.which("mpiexec") is None:
        p.error("needs petsc4py, mpi4py and mpiexec (docs/distributed.md)")
    if a.steps < 1 or any(r < 1 for r in a.ranks) or any(n < 2 for n in a.sizes):
        p.error("--steps and --ranks must be >= 1, --sizes >= 2")
    if a.weak is not None and a.weak < 2:
        p.error("--weak must be >= 2")
    a.out.mkdir(parents=True, exist_ok=True)
    print(f"machine: {machine_info()}", flush=True)
    if a.weak is not None:
        return weak(a)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in a.sizes:
            serial = serial_row = None
            configs = ([] if a.no_serial else [("serial", 1)]) + [("petsc", r) for r in a.ranks]
            for mode, ranks in configs:
                load = os.getloadavg()[0]  # 1-minute load average before the run (other processes' share)
                r = run_config(mode, n, a.steps, ranks, a.petsc_options, Path(tmp), a.build, a.partitioner)
                if mode == "serial":
                    serial, serial_row = r["q"], r
                diff = float(np.abs(r["q"] - serial).max()) if serial is not None else float("nan")
                ratio = its_ratio = float("nan")
                if serial_row is not None:
                    ratio = r["step_s"] / serial_row["step_s"]
                    if serial_row["its_per_solve"] > 0:  # 0 where the serial path solved directly
                        its_ratio = r["its_per_solve"] / serial_row["its_per_solve"]
                row = dict(n=n, dofs=3 * (n * n - n), steps=a.steps, diff_to_serial_m=diff, ratio_to_serial=ratio,
                           its_ratio_to_serial=its_ratio, load=load,
                           petsc_options=a.petsc_options if mode == "petsc" else "",
                           **{k: r[k] for k in COLUMNS if k in r})
                rows.append(row)
                print("  " + ", ".join(f"{k} {fmt(row[k])}" for k in COLUMNS if k in row and row[k] != ""),
                      flush=True)
                write_csv(a.out / "distributed.csv", rows, COLUMNS)
    md = markdown_table(rows, COLUMNS)
    (a.out / "distributed.md").write_text(md + "\n")
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
