"""Sparse direct versus dense path: time per linearized implicit Euler step, and agreement.

For benchmark cloths (:func:`springsim.scene.benchmark_cloth`, n x n particles, edge
pinned, h = 1/60 s, from rest) this times each step of linearized implicit Euler
(PA2 eq. 3) split into

* assembly: force evaluation + Jacobians + system matrix,
* solve: the linear solve,

for the **sparse** path (the library's :class:`IntegratorLinearizedImplicit` with the
two-phase BSR assembler over free DOFs and ``direct`` = SuperLU, MMD on A^T + A) and
the **dense** reference path (``dense_system``: all 3N DOFs, seed identity rows for
fixed DOFs, then ``np.linalg.solve``; only for n <= ``--dense-max``). Both paths
start every step from the same state (the sparse trajectory), and the relative
difference of their velocity updates ``|dv_sparse - dv_dense| / |dv_dense|`` is
reported (max over steps).

Usage::

    python -m benchmarks sparse-vs-dense [--sizes 16 32 64 128] [--steps 5] [--dense-max 32]

Prints a Markdown table and writes ``benchmarks/results/sparse_vs_dense.csv``.
Times are medians over the steps after one warm-up step (the symbolic phase,
``symbolic_s`` in the CSV, is reported separately).
"""

from __future__ import annotations

import argparse
import platform
import time
from pathlib import Path

import numpy as np

from springsim.assembly import dense_system
from springsim.forces import eval_forces, make_force_terms
from springsim.integrators import make_integrator
from springsim.scene import BENCHMARK_DT, benchmark_cloth

from .common import RESULTS_DIR, markdown_table, write_csv


COLUMNS = ["n", "particles", "dofs_free", "springs", "nnzb", "symbolic_s", "sparse_assembly_s",
           "sparse_solve_s", "sparse_step_s", "nnz_LU", "dense_assembly_s", "dense_solve_s", "dense_step_s",
           "rel_diff_dv", "speedup"]


def dense_step(model, terms, q, v, h):
    """PA2 eq. (3) on the dense identity-row system; returns ``(dv (N, 3), assembly_s, solve_s)``."""
    t0 = time.perf_counter()
    qs = q + h * v
    rhs = h * eval_forces(terms, qs, v).reshape(-1)
    A, r = dense_system(model, qs, v, h * h, h, rhs=rhs, mode="exact", terms=terms)
    t1 = time.perf_counter()
    dv = np.linalg.solve(A, r)
    t2 = time.perf_counter()
    return dv.reshape(-1, 3), t1 - t0, t2 - t1


def run_size(n: int, steps: int, dense_max: int, h: float = BENCHMARK_DT) -> dict:
    """Benchmark one cloth size; returns a row of :data:`COLUMNS`."""
    model = benchmark_cloth(n)
    t0 = time.perf_counter()
    integ = make_integrator("linearized_implicit", model, solver="direct", jacobian="exact")
    symbolic = time.perf_counter() - t0
    dense_terms = make_force_terms(model, skip_fixed=False) if n <= dense_max else None
    s0, s1 = model.state(), model.state()
    sa, ss, sstep, da, ds, dstep, diffs, nnz = [], [], [], [], [], [], [], 0
    for k in range(steps + 1):  # step 0 warms up (BLAS/LAPACK first calls); its times are dropped
        q, v = s0.particle_q.copy(), s0.particle_qd.copy()
        w0 = time.perf_counter()
        st = integ.step(s0, s1, h)
        sstep.append(time.perf_counter() - w0)
        sa.append(st.assembly_s + st.force_s)
        ss.append(st.solve_s)
        if dense_terms is not None:
            w0 = time.perf_counter()
            dv, a_s, s_s = dense_step(model, dense_terms, q, v, h)
            dstep.append(time.perf_counter() - w0)
            da.append(a_s)
            ds.append(s_s)
            dv_sparse = s1.particle_qd - v
            diffs.append(np.linalg.norm(dv_sparse - dv) / np.linalg.norm(dv))
        s0, s1 = s1, s0
        if k == 0:
            for xs in (sa, ss, sstep, da, ds, dstep):
                xs.clear()
    A = integ.assembler.matrix
    nnz = integ.solver.solve(A, np.ones(A.shape[0])).info.get("nnz_LU", 0)
    med = lambda xs: float(np.median(xs)) if xs else float("nan")  # noqa: E731
    row = dict(n=n, particles=model.particle_count, dofs_free=model.dof_count, springs=model.spring_count,
               nnzb=integ.assembler.pattern.nnzb, symbolic_s=symbolic, sparse_assembly_s=med(sa),
               sparse_solve_s=med(ss), sparse_step_s=med(sstep), nnz_LU=nnz, dense_assembly_s=med(da),
               dense_solve_s=med(ds), dense_step_s=med(dstep), rel_diff_dv=max(diffs) if diffs else float("nan"))
    row["speedup"] = row["dense_step_s"] / row["sparse_step_s"]
    return row


def markdown(rows) -> str:
    """The result rows as a Markdown table (times in seconds)."""
    cols = ["n", "dofs_free", "nnzb", "sparse_assembly_s", "sparse_solve_s", "sparse_step_s",
            "dense_assembly_s", "dense_solve_s", "dense_step_s", "rel_diff_dv", "speedup"]
    return markdown_table(rows, cols)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[16, 32, 64, 128], help="cloth sizes n (n x n)")
    p.add_argument("--steps", type=int, default=5, help="timed steps per size, after one warm-up (median reported)")
    p.add_argument("--dense-max", type=int, default=32, help="largest n run on the dense path")
    p.add_argument("--out", type=Path, default=RESULTS_DIR / "sparse_vs_dense.csv", help="CSV output")
    args = p.parse_args(argv)
    rows = []
    for n in args.sizes:
        rows.append(run_size(n, args.steps, args.dense_max))
        print(f"n={n}: done", flush=True)
    print(f"\nlinearized implicit Euler, benchmark cloth, h = 1/60 s, {args.steps} steps, median per step [s]; "
          f"{platform.processor() or platform.machine()}, numpy {np.__version__}\n")
    print(markdown(rows))
    write_csv(args.out, rows, COLUMNS)
    print(f"\nwrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
