"""Scaling of the time per implicit step with the number of DOFs (benchmark cloth, h = 1/60 s).

For n = 16 ... 512 (optionally 1024) the n x n benchmark cloth
(:func:`springsim.scene.benchmark_cloth`) takes ``--warmup`` untimed steps, then
``--steps`` timed steps of linearized implicit Euler (the cloth-grid benchmark's setting; any
integrator with ``--integrator``) with the chosen linear solver (default ``auto`` if
registered, else ``direct``) at relative tolerance 1e-6. Reports median time per step
(total, assembly, linear solve), Newton and linear iterations per step and the largest
relative residual, then fits ``time ~ DOFs^p`` on the sizes >= 64 (DOFs >= 10^4) and
writes a log-log plot. Writes ``results/scaling.csv``, ``.md`` and ``.png``.

Usage::

    python -m benchmarks scaling                       # n = 16 32 64 128 256 512
    python -m benchmarks scaling --sizes 16 32 64 128 256 512 1024 --solver amg-cg
    python -m benchmarks scaling --quick               # n = 8 16 (tests)
"""

from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

import numpy as np

from .common import RESULTS_DIR, markdown_table, pyplot, save_figure, write_csv

__all__ = ["COLUMNS", "default_solver", "time_steps", "fit_exponent", "main"]

#: Columns of the CSV / markdown table.
COLUMNS = ["n", "dofs", "solver", "integrator", "rtol", "steps", "setup_s", "step_s", "assembly_s", "solve_s",
           "newton_per_step", "linear_per_step", "max_relres", "fallbacks"]


def default_solver() -> str:
    """``auto`` if registered, else ``direct``."""
    from springsim.linsolve import LINEAR_SOLVERS

    return "auto" if "auto" in LINEAR_SOLVERS else "direct"


def time_steps(n: int, *, solver: str, integrator: str = "linearized_implicit", steps: int = 5,
               warmup: int = 3, rtol: float = 1e-6, dt: float = 1 / 60) -> dict:
    """Median times of ``steps`` steps of the n x n benchmark cloth after ``warmup`` untimed ones.

    Returns a result row: ``setup_s`` covers the integrator construction and the warm-up
    steps; ``step_s``, ``assembly_s``, ``solve_s`` are medians over the timed steps [s].
    """
    from springsim.integrators import make_integrator
    from springsim.run.driver import simulate
    from springsim.scene import benchmark_cloth

    model = benchmark_cloth(n)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        t0 = time.perf_counter()
        integ = make_integrator(integrator, model, solver=solver, solver_options={"rtol": rtol})
        warm = simulate(model, integ, dt, warmup, record=False)
        setup = time.perf_counter() - t0
        state = model.state()
        state.particle_q[:] = warm.q[-1]
        state.particle_qd[:] = warm.qd[-1]
        stamps = [time.perf_counter()]
        tr = simulate(model, integ, dt, steps, state=state, record=False,
                      progress=lambda k, total: stamps.append(time.perf_counter()))
    st = tr.stats
    return dict(n=n, dofs=3 * model.free_particles.size, solver=solver, integrator=integrator, rtol=rtol,
                steps=steps, setup_s=setup, step_s=float(np.median(np.diff(stamps))),
                assembly_s=float(np.median([x.assembly_s for x in st])),
                solve_s=float(np.median([x.solve_s for x in st])),
                newton_per_step=float(np.mean([x.newton_iterations for x in st])),
                linear_per_step=float(np.mean([x.linear_iterations for x in st])),
                max_relres=float(max(x.linear_residual for x in st)),
                fallbacks=sum(len(x.fallbacks) for x in st))


def fit_exponent(rows: list[dict], *, min_dofs: int = 10_000) -> float:
    """Exponent ``p`` of ``step_s ~ DOFs^p`` fitted over rows with at least ``min_dofs`` DOFs (all if < 2)."""
    rr = [r for r in rows if r["dofs"] >= min_dofs]
    if len(rr) < 2:
        rr = rows
    if len(rr) < 2:
        return float("nan")
    x = np.log([r["dofs"] for r in rr])
    y = np.log([r["step_s"] for r in rr])
    return float(np.polyfit(x, y, 1)[0])


def plot(rows, p: float, out_png, *, dpi: int = 80) -> bool:
    """Log-log time per step against DOFs with the fitted slope."""
    plt = pyplot()
    if plt is None:
        return False
    d = np.array([r["dofs"] for r in rows], dtype=float)
    fig, ax = plt.subplots(figsize=(5.6, 4.0))
    ax.loglog(d, [r["step_s"] for r in rows], "o-", label="step (total)")
    ax.loglog(d, [r["solve_s"] for r in rows], "s--", ms=4, label="linear solves")
    ax.loglog(d, [r["assembly_s"] for r in rows], "^--", ms=4, label="assembly")
    if np.isfinite(p):
        ref = rows[-1]
        ax.loglog(d, ref["step_s"] * (d / ref["dofs"]) ** p, ":", color="0.4", label=f"fit: DOFs^{p:.2f}")
    ax.set_xlabel("DOFs")
    ax.set_ylabel("wall time per step [s]")
    ax.set_title(f"{rows[0]['integrator']}, {rows[0]['solver']}, h = 1/60 s")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    save_figure(fig, out_png, dpi)
    return True


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", type=int, nargs="*", default=None, help="cloth sizes n (default 16 ... 512)")
    p.add_argument("--solver", default=None, help="linear solver (default auto if registered, else direct)")
    p.add_argument("--integrator", default="linearized_implicit", help="integrator (default linearized_implicit)")
    p.add_argument("--rtol", type=float, default=1e-6, help="relative tolerance of iterative solvers")
    p.add_argument("--steps", type=int, default=5, help="timed steps per size")
    p.add_argument("--warmup", type=int, default=3, help="untimed steps before them (setup, first AMG hierarchy)")
    p.add_argument("--quick", action="store_true", help="n = 8 16, one step (tests)")
    p.add_argument("--out", type=Path, default=RESULTS_DIR)
    p.add_argument("--plot-dir", type=Path, default=None, help="also write the PNG here (e.g. docs/)")
    a = p.parse_args(argv)
    a.out.mkdir(parents=True, exist_ok=True)
    sizes = a.sizes or ([8, 16] if a.quick else [16, 32, 64, 128, 256, 512])
    steps, warmup = (1, 1) if a.quick else (a.steps, a.warmup)
    solver = a.solver or default_solver()
    rows = []
    for n in sizes:
        r = time_steps(n, solver=solver, integrator=a.integrator, steps=steps, warmup=warmup, rtol=a.rtol)
        rows.append(r)
        write_csv(a.out / "scaling.csv", rows, COLUMNS)  # after every size: a long run keeps its finished part
        print(f"  n={n:5d} dofs={r['dofs']:8d} step={r['step_s']:.4g}s solve={r['solve_s']:.4g}s "
              f"newton/step={r['newton_per_step']:.2f} linear/step={r['linear_per_step']:.1f}", flush=True)
    pexp = fit_exponent(rows)
    a.out.mkdir(parents=True, exist_ok=True)
    write_csv(a.out / "scaling.csv", rows, COLUMNS)
    md = markdown_table(rows, COLUMNS) + f"\n\nFitted exponent (DOFs >= 10000): time per step ~ DOFs^{pexp:.2f}\n"
    (a.out / "scaling.md").write_text("## Scaling\n\n" + md)
    print(md)
    for d in [a.out] + ([a.plot_dir] if a.plot_dir else []):
        plot(rows, pexp, d / "scaling.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
