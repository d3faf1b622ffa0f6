"""Linear-solve error against speed on matrices from real steps of the benchmark cloth.

The cloth (n x n, :func:`springsim.scene.benchmark_cloth`) falls for a few implicit
Euler steps at ``h = 1/60`` s; at that state the Newton system of the next step,
``A = M - h^2 dF/dq - h dF/dqd`` with right-hand side ``R(v0)``, is assembled in every
Jacobian mode. Each solver in :data:`springsim.linsolve.LINEAR_SOLVERS` solves it at a
ladder of relative tolerances (direct solvers once) from a fresh instance (setup
included) and once more with the setup reused; the error is
``|x - x_direct| / |x_direct|`` against the direct solve of the same matrix.
Writes ``results/linear_solve_error.csv``, ``.md`` and ``.png``.

Usage::

    python -m benchmarks linear-solve-error              # n = 64, 128
    python -m benchmarks linear-solve-error --large      # also n = 256
    python -m benchmarks linear-solve-error --quick      # n = 8 (tests)
    python -m benchmarks linear-solve-error --append --sizes 256 --modes spd   # add rows to the last run's
"""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

import numpy as np

from .common import RESULTS_DIR, markdown_table, pyplot, save_figure, write_csv

__all__ = ["COLUMNS", "step_systems", "run", "main"]

#: Columns of the CSV / markdown table.
COLUMNS = ["n", "dofs", "jacobian", "symmetric", "solver", "rtol", "status", "method", "first_s", "setup_s",
           "repeat_s", "iterations", "residual", "rel_error"]
RTOLS = [1e-2, 1e-4, 1e-6, 1e-8, 1e-10]


def step_systems(n: int, *, warm_steps: int = 5, dt: float = 1 / 60):
    """Newton systems at a state reached by ``warm_steps`` implicit Euler steps of the n x n cloth.

    Returns
    -------
    dict of str -> callable() -> (SystemMatrix, ndarray)
        Jacobian mode -> a function assembling the matrix over free DOFs (the assembler's
        persistent matrix, so call it again before every use) and the right-hand side [N s].
    """
    from springsim.forces import JACOBIAN_MODES, eval_forces
    from springsim.integrators import make_integrator
    from springsim.run.driver import simulate
    from springsim.scene import benchmark_cloth

    model = benchmark_cloth(n)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        # the state only has to be a realistic one: auto (AMG above 4000 DOFs) reaches it fast at n = 256
        integ = make_integrator("implicit_euler", model, solver="auto")
        tr = simulate(model, integ, dt, warm_steps, record=False)
    q, v = tr.q[-1], tr.qd[-1]
    f = np.zeros_like(q)
    eval_forces(integ.terms, q + dt * v, v, out=f)
    # residual of implicit Euler at v0 = qd^n: R = h F(q + h v0, v0) - M (v0 - qd^n)
    b = integ.assembler.gather(dt * f)

    def make(mode):
        def system():
            integ.assembler.linearize_at(q + dt * v)  # mixed: the same matrix every time (continued from here)
            return integ.assembler.assemble(q + dt * v, v, dt * dt, dt, mode), b
        return system

    return {mode: make(mode) for mode in JACOBIAN_MODES}


def _solve(name: str, A, b, rtol):
    from springsim.linsolve import make_linear_solver

    opts = {} if rtol is None else {"rtol": rtol, "maxiter": 10000}
    s = make_linear_solver(name, **opts)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r1 = s.solve(A, b)
        r2 = s.solve(A, b)
    return r1, r2


def run(sizes, *, rtols=RTOLS, modes=None, log=print) -> list[dict]:
    """All (n, Jacobian mode, solver, rtol) combinations (``modes``: a subset of the Jacobian
    modes, default all); returns result rows."""
    from springsim.linsolve import LINEAR_SOLVERS

    rows = []
    for n in sizes:
        systems = step_systems(n)
        for mode, system in systems.items():
            if modes is not None and mode not in modes:
                continue
            A, b = system()
            x_ref = _solve("direct", A, b, None)[0].x
            xn = float(np.linalg.norm(x_ref))
            for name, cls in LINEAR_SOLVERS.items():
                if name == "dense" and A.shape[0] > 4000:
                    continue
                iterative = name not in ("dense", "direct")
                for tol in (rtols if iterative else [None]):
                    A, b = system()
                    row = dict(n=n, dofs=A.shape[0], jacobian=mode, symmetric=A.symmetric, solver=name,
                               rtol="" if tol is None else tol)
                    note = " (SPD solver, non-SPD mode)" if getattr(cls, "needs_spd", False) and mode != "spd" else ""
                    try:
                        r1, r2 = _solve(name, A, b, tol)
                        err = float(np.linalg.norm(r1.x - x_ref) / xn) if np.all(np.isfinite(r1.x)) else np.inf
                        row.update(status=("ok" if r1.converged else "not converged") + note,
                                   method=r1.method, first_s=r1.time_s, setup_s=r1.setup_s, repeat_s=r2.time_s,
                                   iterations=r1.iterations, residual=r1.residual, rel_error=err)
                    except Exception as e:  # noqa: BLE001 - a solver failure is a result here
                        row.update(status=f"error: {type(e).__name__}: {str(e)[:50]}")
                    rows.append(row)
                    log(f"  n={n:4d} {mode:9s} {name:10s} rtol={row['rtol']!s:6s} {row['status'][:24]:24s} "
                        f"t={row.get('first_s', float('nan')):.3g}s err={row.get('rel_error', float('nan')):.2e}")
    return rows


NUMERIC = ("n", "dofs", "rtol", "first_s", "setup_s", "repeat_s", "iterations", "residual", "rel_error")


def read_rows(path) -> list[dict]:
    """Rows of an earlier run's CSV, numbers converted back (for ``--append``)."""
    import csv

    with open(path) as fh:
        rows = list(csv.DictReader(fh))
    for r in rows:
        for k in NUMERIC:
            if r.get(k, "") != "":
                r[k] = int(float(r[k])) if k in ("n", "dofs", "iterations") else float(r[k])
        r["symmetric"] = r.get("symmetric") == "True"
    return rows


def plot(rows, out_png, *, dpi: int = 80) -> bool:
    """Log-log solve time (first solve, setup included) against relative error; one curve per solver/mode."""
    plt = pyplot()
    if plt is None:
        return False
    sizes = sorted(dict.fromkeys(r["n"] for r in rows))
    fig, axes = plt.subplots(1, len(sizes), figsize=(max(6.4, 4.2 * len(sizes)), 4.2), squeeze=False)
    for ax, n in zip(axes[0], sizes):
        rr = [r for r in rows if r["n"] == n and np.isfinite(r.get("rel_error", np.nan))]
        for key in dict.fromkeys((r["solver"], r["jacobian"]) for r in rr):
            pts = [r for r in rr if (r["solver"], r["jacobian"]) == key]
            err = np.maximum([r["rel_error"] for r in pts], 1e-17)
            ax.loglog(err, [r["first_s"] for r in pts], "o-" if len(pts) > 1 else "s", ms=3, lw=1,
                      label=f"{key[0]} / {key[1]}")
        ax.set_title(f"n = {n} ({rr[0]['dofs'] if rr else 0} DOFs)")
        ax.set_xlabel("|x - x_direct| / |x_direct|")
        ax.set_ylabel("solve time incl. setup [s]")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=6)
    save_figure(fig, out_png, dpi)
    return True


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="n = 8 only, two tolerances")
    p.add_argument("--sizes", type=int, nargs="*", default=None, help="cloth sizes (default 64 128)")
    p.add_argument("--large", action="store_true", help="add n = 256")
    p.add_argument("--out", type=Path, default=RESULTS_DIR)
    p.add_argument("--plot-dir", type=Path, default=None, help="also write the PNG here (e.g. docs/)")
    p.add_argument("--modes", nargs="+", choices=("exact", "symmetric", "spd"), default=None,
                   help="Jacobian modes to run (default all)")
    p.add_argument("--append", action="store_true",
                   help="keep the rows of OUT/linear_solve_error.csv and add this run's (table and plot show both)")
    a = p.parse_args(argv)
    sizes = a.sizes or ([8] if a.quick else [64, 128] + ([256] if a.large else []))
    a.out.mkdir(parents=True, exist_ok=True)
    old = a.out / "linear_solve_error.csv"
    rows = read_rows(old) if a.append and old.exists() else []
    for n in sizes:  # write after every size, so a long run leaves its finished part
        rows += run([n], rtols=[1e-2, 1e-8] if a.quick else RTOLS, modes=a.modes)
        write_csv(a.out / "linear_solve_error.csv", rows, COLUMNS)
    md = markdown_table(rows, COLUMNS)
    (a.out / "linear_solve_error.md").write_text("## Linear-solve error against speed\n\n" + md + "\n")
    print(md)
    for d in [a.out] + ([a.plot_dir] if a.plot_dir else []):
        plot(rows, d / "linear_solve_error.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
