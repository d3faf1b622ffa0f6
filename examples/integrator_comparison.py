"""Speed against error of every integrator at one animation time step, on a falling cloth.

Each integrator of ``springsim.INTEGRATORS`` runs the accuracy benchmark's cloth (a 1 m square
pinned along one edge, soft enough to buckle while it falls) for 0.5 s at h = 1/60 s. Its final
positions are compared with an independent reference of the same ODE, ``scipy.integrate.solve_ivp``
(Radau, rtol 1e-10), not with springsim at a smaller step. Explicit methods are unstable at this
step on this cloth; that is reported, not hidden.

    python examples/integrator_comparison.py       # 12 x 12 cloth: ~11 s on 1 core
    python examples/integrator_comparison.py --tiny   # 4 x 4 cloth (what the tests run)

Prints a table and writes ``integrator_comparison.png`` (CPU time against error) to ``--out-dir``.
For every step size, tolerance and solver, see ``python -m benchmarks speed-vs-error``.
"""

import argparse
import logging
import time
import warnings
from pathlib import Path

import numpy as np

import springsim as ss
from springsim.analysis.reference import reference_trajectory
from springsim.scene.gallery import accuracy_cloth


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tiny", action="store_true", help="4 x 4 cloth")
    p.add_argument("--out-dir", type=Path, default=Path("."), help="where the picture goes")
    a = p.parse_args(argv)
    n = 4 if a.tiny else 12
    model = accuracy_cloth(n)
    dt, steps = 1 / 60, 30
    ref = reference_trajectory(model, [0.0, dt * steps])
    size = 1.0  # the cloth's extent [m]: errors are relative to it
    rows = []
    for name in ss.INTEGRATORS:
        integrator = ss.make_integrator(name, model)
        cpu = time.process_time()
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", ss.ConvergenceWarning)  # counted in the table instead
                traj = ss.simulate(model, integrator, dt, steps)
        except ss.SimulationError as e:
            rows.append((name, np.nan, time.process_time() - cpu, f"unstable (step {e.step})"))
            continue
        err = float(np.sqrt(np.mean(np.sum((traj.q[-1] - ref.q[-1]) ** 2, axis=1)))) / size
        failed = traj.summary()["failed_steps"]
        rows.append((name, err, time.process_time() - cpu, f"{failed} failed steps" if failed else "ok"))

    print(f"{n} x {n} cloth, {steps} steps of 1/60 s; error = RMS final position error / cloth size")
    print(f"{'integrator':<20} {'error':>10} {'CPU [s]':>9}  status")
    for name, err, cpu, status in rows:
        print(f"{name:<20} {err:10.3g} {cpu:9.3f}  {status}")

    from springsim.io.viz import require_matplotlib

    Figure = require_matplotlib()
    fig = Figure(figsize=(7.0, 4.5))
    ax = fig.subplots()
    for k, (name, err, cpu, _) in enumerate(rows):
        if np.isfinite(err):
            ax.loglog(err, cpu, "o", ms=8, color=f"C{k}", label=name)
    ax.set_xlabel("RMS final position error / cloth size (against solve_ivp)")
    ax.set_ylabel("CPU time for 0.5 s of motion [s]")
    unstable = [name for name, err, _, _ in rows if not np.isfinite(err)]
    ax.set_title(f"{n} x {n} cloth, h = 1/60 s (lower left is better)", fontsize=10)
    if unstable:
        ax.text(0.02, 0.03, f"unstable: {', '.join(unstable)}", transform=ax.transAxes, fontsize=8)
    from matplotlib.ticker import NullFormatter

    ax.xaxis.set_minor_formatter(NullFormatter())  # decade labels only: the minor ones overlap
    ax.yaxis.set_minor_formatter(NullFormatter())
    ax.margins(0.15)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="center left", bbox_to_anchor=(1.02, 0.5), frameon=False)
    fig.tight_layout()
    a.out_dir.mkdir(parents=True, exist_ok=True)
    fig.savefig(a.out_dir / "integrator_comparison.png", dpi=100)
    print(f"wrote {a.out_dir / 'integrator_comparison.png'}")


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(message)s")  # springsim logs progress and slow set-up
    main()
