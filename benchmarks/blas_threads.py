"""BLAS thread policy: time per step with springsim's one-thread policy against the BLAS default, and the
difference between the two trajectories (the error of the comparison: round-off only).

Runs the benchmark cloth with one linear solver, first with the policy of :mod:`springsim._runtime.threads`
(one BLAS thread in the stepping loop; needs the ``threads`` extra), then with it switched off (the
BLAS library's default threads), optionally with ``--busy`` processes spinning on the other cores as
on a shared machine. Prints wall and CPU time per step and the largest position difference [m].

    python -m benchmarks blas-threads --n 16 --solver amg-cg --steps 30 --busy 1
"""

from __future__ import annotations

import argparse
import contextlib
import multiprocessing as mp
import time

import numpy as np

import springsim
from springsim._runtime import threads as _threads
from springsim.scene import BENCHMARK_DT, benchmark_cloth


def _spin():
    while True:
        pass


def _run(n: int, solver: str, steps: int):
    model = benchmark_cloth(n)
    integ = springsim.make_integrator("linearized_implicit", model, solver=solver)
    t0, c0 = time.perf_counter(), time.process_time()
    tr = springsim.simulate(model, integ, BENCHMARK_DT, steps)
    return (time.perf_counter() - t0) / steps, (time.process_time() - c0) / steps, tr.q


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--n", type=int, default=16, help="cloth size (n x n particles)")
    p.add_argument("--solver", default="amg-cg", help="linear solver")
    p.add_argument("--steps", type=int, default=30)
    p.add_argument("--busy", type=int, default=0, help="busy-looping processes beside the run")
    a = p.parse_args(argv)
    if not _threads.have_threadpoolctl():
        p.error("needs threadpoolctl: pip install 'springsim[threads]'")
    busy = [mp.Process(target=_spin, daemon=True) for _ in range(a.busy)]
    for b in busy:
        b.start()
    try:
        _run(a.n, a.solver, 2)  # warm-up (imports, first hierarchy)
        wall1, cpu1, q1 = _run(a.n, a.solver, a.steps)
        policy = _threads.single_blas_thread
        _threads.single_blas_thread = contextlib.nullcontext
        springsim.run.driver.single_blas_thread = contextlib.nullcontext
        springsim.linsolve._base.single_blas_thread = contextlib.nullcontext
        try:
            wall2, cpu2, q2 = _run(a.n, a.solver, a.steps)
        finally:
            _threads.single_blas_thread = springsim.run.driver.single_blas_thread = policy
            springsim.linsolve._base.single_blas_thread = policy
    finally:
        for b in busy:
            b.terminate()
    diff = float(np.abs(q1 - q2).max())
    print("| n | solver | busy | one thread: wall / CPU per step | BLAS default: wall / CPU per step | ratio | "
          "max position difference [m] |")
    print("|---|---|---|---|---|---|---|")
    print(f"| {a.n} | {a.solver} | {a.busy} | {wall1 * 1e3:.2f} / {cpu1 * 1e3:.2f} ms | {wall2 * 1e3:.2f} / "
          f"{cpu2 * 1e3:.2f} ms | {wall2 / wall1:.2f}x | {diff:.1e} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
