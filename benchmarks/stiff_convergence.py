"""Implicit stages on stiff cloth at the defaults: convergence, Newton iterations per stage, stretch, energy.

For every size of ``--sizes``, stiffness of ``--ke`` (structural and shear springs [N/m]), spring damping of
``--damping`` [N s/m] and step of ``--inv-h`` (1/h, multiples of 60), each integrator of ``--integrators`` runs
``benchmark_cloth(n, stiffness=ke, damping=kd)`` from release for ``--frames`` frames of 1/60 s with its default
options (minimize stages, the ``mixed`` Hessian, substep retakes). Per run: steps still failed after their
retakes, steps retaken, steps taken in substeps (retaken, or started so by the substep memory), Newton iterations
per stage (mean and largest per step; TR-BDF2 has two stages a step), the largest structural stretch (spring
length over rest length, over the frames), the largest rise of the total energy above its start (the undamped ODE
conserves it, the damped one loses it) and CPU per frame. Writes
``results/stiff_convergence.csv`` and ``.md``.

Usage::

    export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 NUMBA_NUM_THREADS=1
    python -m benchmarks stiff-convergence --sizes 32 --ke 1e3 1e4 1e6 1e8 --damping 0 1
    python -m benchmarks stiff-convergence --sizes 16 --ke 1e6 1e8 --frames 40 --jacobian spd   # against mixed
    python -m benchmarks stiff-convergence --quick          # n = 6, two stiffnesses, a few frames (tests)
"""

from __future__ import annotations

import argparse
import os
import time
import warnings

import numpy as np

from .common import RESULTS_DIR, markdown_table, write_csv

__all__ = ["COLUMNS", "STAGES", "run", "main"]

COLUMNS = ["n", "ke", "kd", "inv_h", "integrator", "failed_steps", "retaken_steps", "substep_steps", "newton_per_stage",
           "max_newton_per_stage", "max_stretch", "max_energy_rise_J", "cpu_per_frame_s", "load"]
#: Stage solves per step of each integrator (for "per stage")
STAGES = {"tr_bdf2": 2}


def run(n: int, ke: float, kd: float, inv_h: int, name: str, frames: int, **options) -> dict:
    """One run (module docstring): its table row; ``options`` go to the integrator."""
    import springsim as ss
    from springsim.run.energy import total_energy
    from springsim.scene import benchmark_cloth

    model = benchmark_cloth(n, stiffness=ke, damping=kd)
    i, j = model.spring_indices.T
    sub = inv_h // 60
    integ = ss.make_integrator(name, model, on_nonconvergence="ignore", **options)
    t0 = time.process_time()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # counted from the StepStats below
        traj = ss.simulate(model, integ, 1.0 / inv_h, frames * sub, frame_every=sub)
    cpu = (time.process_time() - t0) / frames
    its = np.array([s.newton_iterations for s in traj.stats]) / STAGES.get(name, 1)
    stretch = max(float(np.max(np.linalg.norm(q[i] - q[j], axis=1) / model.spring_rest_length)) for q in traj.q)
    energy = total_energy(model, traj.q, traj.qd)
    return dict(n=n, ke=ke, kd=kd, inv_h=inv_h, integrator=name, failed_steps=sum(not s.ok for s in traj.stats),
                retaken_steps=sum("retaken" in s.extra for s in traj.stats),
                substep_steps=sum("substeps" in s.extra for s in traj.stats), newton_per_stage=float(its.mean()),
                max_newton_per_stage=float(its.max()), max_stretch=stretch,
                max_energy_rise_J=float(energy.max() - energy[0]), cpu_per_frame_s=cpu,
                load=round(os.getloadavg()[0], 2))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[32])
    p.add_argument("--ke", type=float, nargs="+", default=[1e3, 1e4, 1e6, 1e8])
    p.add_argument("--damping", type=float, nargs="+", default=[0.0])
    p.add_argument("--inv-h", type=int, nargs="+", default=[60], help="1/h, multiples of 60")
    p.add_argument("--integrators", nargs="+", default=["implicit_euler", "bdf2", "tr_bdf2"])
    p.add_argument("--frames", type=int, default=30)
    p.add_argument("--jacobian", default=None, help="Jacobian mode (default: the integrator's, mixed)")
    p.add_argument("--quick", action="store_true", help="n = 6, ke 1e4 and 1e8, 3 frames (tests)")
    p.add_argument("--out", default=str(RESULTS_DIR))
    a = p.parse_args(argv)
    if a.quick:
        a.sizes, a.ke, a.frames = [6], [1e4, 1e8], 3
    if any(x % 60 for x in a.inv_h):
        p.error("--inv-h: multiples of 60 (frames of 1/60 s)")
    rows = []
    for n in a.sizes:
        for kd in a.damping:
            for ke in a.ke:
                for inv_h in a.inv_h:
                    for name in a.integrators:
                        options = {} if a.jacobian is None else {"jacobian": a.jacobian}
                        rows.append(run(n, ke, kd, inv_h, name, a.frames, **options))
                        print(markdown_table([rows[-1]], COLUMNS).splitlines()[-1], flush=True)
    write_csv(os.path.join(a.out, "stiff_convergence.csv"), rows, COLUMNS)
    with open(os.path.join(a.out, "stiff_convergence.md"), "w") as fh:
        fh.write(markdown_table(rows, COLUMNS) + "\n")
    return 0
