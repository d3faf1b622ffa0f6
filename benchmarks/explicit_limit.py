"""Explicit stability limit of the benchmark cloth and the cost per frame of symplectic Euler at it, over a window.

The cost side of :mod:`benchmarks.frame_cost` for cloths whose validated reference is out of reach (e.g.
n = 256 at ke = 1e6: Verlet at two or three times the explicit limit for 70 frames is several CPU hours).
For each size of ``--sizes`` and stiffness of ``--ke`` (``benchmark_cloth(n, stiffness=ke)``, bending 1e2 N/m):

1. ``omega_max`` at the initial state (Lanczos on the assembled ``M^-1/2 K M^-1/2``) and the substep
   count ``S = ceil(omega_max / 120)`` per 1/60 s frame, **verified** as in frame-cost: symplectic Euler
   from a state perturbed by 1e-6 m must stay stable at ``S`` (raised by 10 % until it does) and blow up
   at ``0.7 S`` (:func:`benchmarks.frame_cost.verify_explicit`).
2. Symplectic Euler at the verified ``S`` over ``--frames`` frames from rest, with ``--force-kernels``
   (default ``auto``): CPU per substep and per frame, and whether every frame stayed finite.

Error: the window is not compared with a trajectory reference (there is none at these sizes). Its error
figure is the ODE's own invariant: the cloth is undamped, so its total energy (kinetic, springs, gravity)
is conserved, and ``energy_drift`` is the largest ``|E - E0|`` over the frames relative to ``m g L``
(L = 1 m, the cloth size). ``omega_final`` at the last frame, with the substep count it would give,
shows whether the limit moved during the window. The cost of symplectic Euler at its limit is a lower
bound of the explicit path's cost at any error target.

Usage::

    export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 NUMBA_NUM_THREADS=1
    python -m benchmarks explicit-limit --sizes 256 --ke 1e6
    python -m benchmarks explicit-limit --quick          # n = 6, 3 frames (tests)
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from . import frame_cost
from .common import RESULTS_DIR, markdown_table, write_csv

__all__ = ["COLUMNS", "measure", "main"]

COLUMNS = ["n", "ke", "force_kernels", "omega_initial", "substeps_computed", "substeps", "lower_substeps",
           "lower_unstable", "frames", "finite", "energy_drift", "cpu_per_substep_ms", "cpu_per_frame_s",
           "omega_final", "substeps_for_final_omega"]


def measure(n: int, ke: float, *, frames: int, force_kernels: str = "auto", window: float = 0.1,
            max_steps: int = 2000, log=print) -> dict:
    """One row of :data:`COLUMNS` for ``benchmark_cloth(n, stiffness=ke)`` (module docstring)."""
    from springsim.assembly import SystemAssembler
    from springsim.forces import make_force_terms
    from springsim.run.energy import total_energy

    model = frame_cost.cloth(n, ke)
    terms = make_force_terms(model)  # for the assembler and the energies
    asm = SystemAssembler(model, terms)
    om0 = frame_cost.omega_max(asm, model.particle_q, model.particle_qd)
    ex = frame_cost.verify_explicit(model, om0["omega"], window=window, max_steps=max_steps)
    S = ex["substeps"]
    log(f"n = {n}, ke = {ke:g}: omega_max {om0['omega']:.6g} rad/s, {ex['substeps_computed']} substeps computed, "
        f"{S} verified; {ex['lower_substeps']} unstable: {ex['lower_unstable']}")
    kernels = frame_cost.force_kernels_used(model, force_kernels)
    run = frame_cost.make_run(model, frame_cost.Candidate("symplectic_euler", S / frame_cost.FRAME_DT, "none"),
                              {"force_kernels": force_kernels})
    e0 = total_energy(model, model.particle_q, model.particle_qd, terms)
    scale = float(np.sum(model.particle_mass)) * abs(float(model.gravity)) * 1.0
    drift, finite, k, t0 = 0.0, True, 0, time.perf_counter()
    for k in range(1, frames + 1):
        finite = run.advance(S)
        if not finite:
            drift = float("inf")
            break
        drift = max(drift, abs(total_energy(model, run.positions, run.v, terms) - e0) / scale)
        if time.perf_counter() - t0 > 60 or k == frames:
            log(f"  frame {k}: energy drift {drift:.3g} (m g L), {run.cpu / k:.4g} CPU s per frame")
            t0 = time.perf_counter()
    omf = frame_cost.omega_max(asm, run.positions, np.zeros_like(run.positions)) if finite else {"omega": np.nan}
    return dict(n=n, ke=ke, force_kernels=kernels, omega_initial=om0["omega"],
                substeps_computed=ex["substeps_computed"], substeps=S, lower_substeps=ex["lower_substeps"],
                lower_unstable=ex["lower_unstable"], frames=k, finite=finite, energy_drift=drift,
                cpu_per_substep_ms=run.cpu / (k * S) * 1e3, cpu_per_frame_s=run.cpu / k, omega_final=omf["omega"],
                substeps_for_final_omega=(frame_cost.explicit_substeps(omf["omega"]) if finite else ""))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks explicit-limit", description=__doc__.splitlines()[0])
    p.add_argument("--sizes", type=int, nargs="*", default=[256], help="cloth sizes n (default 256)")
    p.add_argument("--ke", type=float, nargs="*", default=[1e6], help="structural and shear stiffness [N/m]")
    p.add_argument("--frames", type=int, default=70, help="frames of the window (default 70)")
    p.add_argument("--force-kernels", default="auto", choices=("auto", "numba", "numpy"),
                   help="force evaluation of symplectic Euler (default auto: compiled where numba is installed)")
    p.add_argument("--quick", action="store_true", help="n = 6, ke 1e4, 3 frames (tests)")
    p.add_argument("--out", type=Path, default=RESULTS_DIR)
    a = p.parse_args(argv)
    if a.quick:
        a.sizes, a.ke, a.frames = [6], [1e4], 3
    if not a.sizes or any(n < 2 for n in a.sizes):
        p.error("--sizes: every size must be >= 2")
    if not a.ke or any(not k > 0 for k in a.ke):
        p.error("--ke: every stiffness must be > 0")
    if a.frames < 1:
        p.error("--frames must be >= 1")
    rows = [measure(n, ke, frames=a.frames, force_kernels=a.force_kernels) for n in a.sizes for ke in a.ke]
    a.out.mkdir(parents=True, exist_ok=True)
    write_csv(a.out / "explicit_limit.csv", rows, COLUMNS)
    print(markdown_table(rows, COLUMNS))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
