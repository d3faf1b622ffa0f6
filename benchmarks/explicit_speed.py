"""Explicit path: time per symplectic Euler substep on the benchmark cloth, against the naive force loop
and against compiled kernels, with the difference between the two paths' states (speed and error).

For each cloth size ``n`` the benchmark cloth (``benchmark_cloth(n)``, released at rest) runs one
1/60 s frame of ``symplectic_euler`` through the public path (``springsim.simulate``, driver checks
included) at ``4 n`` substeps (128 at n = 32, doubling with n: about 1.7 times the verified stability
limit, 76 substeps at n = 32, 151 at n = 64, 302 at n = 128). The same model is stepped ``--naive-steps``
times by a plain loop over :func:`springsim.forces.naive.naive_forces` (fancy-index gathers, ``np.add.at``
scatters: the straightforward numpy implementation), and the two states after those substeps are compared
(round-off only). Each size runs once per force kernel of ``--kernels``: ``numpy`` (the pure path) and
``numba`` (the compiled force pass of the ``accel`` extra, :mod:`springsim.forces.spring`); by default both
when numba is installed. The comparison with NVIDIA Newton's CPU solver, run live at equal substeps, is
:mod:`benchmarks.peer_newton` (``python -m benchmarks peer-newton``).

    python -m benchmarks explicit-speed                 # n = 64 128 256
    python -m benchmarks explicit-speed --sizes 32 --naive-steps 20 --kernels numpy
    python -m benchmarks explicit-speed --quick         # n = 8 (tests)
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import springsim
from springsim._runtime.accel import numba_available
from springsim._runtime.threads import single_blas_thread
from springsim.forces.naive import naive_forces
from springsim.scene import benchmark_cloth

from .common import RESULTS_DIR, markdown_table, write_csv

COLUMNS = ["n", "springs", "kernels", "substeps_per_frame", "ms_per_substep_wall", "ms_per_substep_cpu", "naive_ms_cpu",
           "speedup_vs_naive", "cpu_s_per_frame", "max_state_diff_m"]


def substeps_per_frame(n: int) -> int:
    """The substeps of the timed frame: ``4 n`` (128 at n = 32; at least 32), above the explicit limit."""
    return max(32, 128 * n // 32)


def _naive(model, dt: float, steps: int):
    q, qd = model.particle_q.copy(), model.particle_qd.copy()
    inv_m = np.where(model.particle_fixed, 0.0, 1.0 / model.particle_mass)[:, None]
    c = time.process_time()
    for _ in range(steps):
        qd = qd + dt * naive_forces(model, q, qd) * inv_m
        q = q + dt * qd
    return q, (time.process_time() - c) / steps


def run_size(n: int, naive_steps: int, kernels: str = "numpy") -> dict:
    model = benchmark_cloth(n)
    S = substeps_per_frame(n)
    dt = 1.0 / 60 / S
    integ = springsim.make_integrator("symplectic_euler", model, force_kernels=kernels)
    springsim.simulate(model, integ, dt, 3, record=False)  # warm-up (imports, incidence matrices)
    w, c = time.perf_counter(), time.process_time()
    springsim.simulate(model, integ, dt, S, record=False)
    wall, cpu = (time.perf_counter() - w) / S, (time.process_time() - c) / S
    k = min(naive_steps, S)
    fast = springsim.simulate(model, integ, dt, k, record=False).q[-1]
    with single_blas_thread():
        slow, naive_cpu = _naive(model, dt, k)
    return dict(n=n, springs=model.spring_count, kernels=kernels, substeps_per_frame=S, ms_per_substep_wall=1e3 * wall,
                ms_per_substep_cpu=1e3 * cpu, naive_ms_cpu=1e3 * naive_cpu, speedup_vs_naive=naive_cpu / cpu,
                cpu_s_per_frame=cpu * S,
                max_state_diff_m=float(np.abs(fast - slow).max()))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", type=int, nargs="*", default=[64, 128, 256], help="cloth sizes n")
    p.add_argument("--naive-steps", type=int, default=50, help="substeps of the naive loop (and of the comparison)")
    p.add_argument("--kernels", nargs="*", choices=["numpy", "numba"], default=None,
                   help="force kernels to time (default: numpy, and numba when installed)")
    p.add_argument("--quick", action="store_true", help="n = 8, 10 naive substeps")
    p.add_argument("--out", default=str(RESULTS_DIR), help="output directory")
    a = p.parse_args(argv)
    sizes, naive = ([8], 10) if a.quick else (a.sizes, a.naive_steps)
    kernels = a.kernels or (["numpy", "numba"] if numba_available() else ["numpy"])
    rows = [run_size(n, naive, k) for n in sizes for k in kernels]
    from pathlib import Path

    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    write_csv(out / "explicit_speed.csv", rows, COLUMNS)
    print(markdown_table(rows, COLUMNS))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
