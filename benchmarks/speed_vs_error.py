"""Speed against error of every integrator, time step, Newton tolerance and linear solver.

For each case (benchmark cloths n = 8, 16, 32 and the shipped scenes spring,
stiff damped chain, three-body; ``scenes/*.yaml``) the final state after ``horizon`` seconds is compared
with an independent ``solve_ivp`` reference (:func:`springsim.reference.reference_trajectory`,
rtol 1e-10). Three sweeps:

``dt``
    every integrator in :data:`springsim.integrators.INTEGRATORS` (default options)
    at a ladder of time steps 1/30 ... 1/3840 s;
``newton``
    implicit Euler at several Newton tolerances (``newton_maxiter`` 20);
``solver``
    every implicit integrator with every solver in :data:`springsim.linsolve.LINEAR_SOLVERS`
    at a ladder of relative tolerances (direct solvers once), at ``h = 1/60`` s.

The default run is bounded to a few minutes: time steps down to 1/1920 s on the
8 x 8 cloth and the scenes, 1/960 s on 16 x 16 and 1/480 s on 32 x 32, rtol ladder
1e-2, 1e-4, 1e-6, 1e-10, the solver sweep with implicit Euler only, no Newton sweep
on 32 x 32. ``--full`` lifts all of these (much longer).

Per run: wall time per simulated second, RMS/max position error relative to the
scene size, stability, energy drift, Newton and linear iterations. Observed orders
of convergence are fitted on the dt ladder. Writes ``results/speed_vs_error.csv``,
``.md`` and Pareto plots ``results/pareto_<case>.png``.

Usage::

    python benchmarks/speed_vs_error.py            # default: a few minutes on 2 cores
    python benchmarks/speed_vs_error.py --quick    # seconds (used by the tests)
    python benchmarks/speed_vs_error.py --full     # the whole ladder (1/30 ... 1/3840 s) everywhere; long
"""

from __future__ import annotations

import argparse
import csv
import sys
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import (RESULTS_DIR, SCENE_NAMES, benchmark_case, fit_order, markdown_table, position_errors,  # noqa: E402
                     pyplot, reference_final, save_figure, scene_case, total_energy, write_csv)

__all__ = ["COLUMNS", "ORDER_COLUMNS", "run_case", "classify", "orders", "pareto_plot", "read_csv", "main"]

#: Columns of the CSV / markdown table.
COLUMNS = ["case", "sweep", "method", "integrator", "solver", "jacobian", "rtol", "newton_tol", "dt", "steps",
           "status", "wall_per_sim_s", "err_rms", "err_max", "energy_drift", "energy_drift_ref",
           "newton_per_step", "linear_per_step", "newton_failures", "fallbacks"]
#: Columns of the observed-order table.
ORDER_COLUMNS = ["case", "integrator", "order", "formal_order", "dts_used"]

DT_LADDER = [1 / 30, 1 / 60, 1 / 120, 1 / 240, 1 / 480, 1 / 960, 1 / 1920, 1 / 3840]
NEWTON_TOLS = [1e-1, 1e-2, 1e-3, 1e-5, 1e-8]
SOLVER_RTOLS = [1e-2, 1e-4, 1e-6, 1e-8, 1e-10]


def _is_iterative(solver_cls) -> bool:
    """Iterative solvers honour ``rtol``; direct/dense ones (and their wrappers) do not."""
    name = getattr(solver_cls, "name", "")
    return name not in ("dense", "direct")


def _run(case, ref_q, e_ref_drift, integrator: str, dt: float, *, sweep: str, method: str, **options) -> dict:
    """One simulation; returns a result row (never raises on blow-up or solver failure)."""
    from springsim.driver import simulate
    from springsim.errors import SimulationError, SolverError
    from springsim.forces import make_force_terms
    from springsim.integrators import INTEGRATORS, make_integrator

    model = case.model
    steps = max(1, int(round(case.horizon / dt)))
    dt = case.horizon / steps
    terms = make_force_terms(model)
    s0 = model.state() if case.state is None else case.state
    e0 = total_energy(model, terms, s0.particle_q, s0.particle_qd)
    g = abs(float(model.gravity))
    e_scale = max(abs(e0), float(np.sum(model.particle_mass)) * g * case.size,
                  0.5 * float(np.sum(model.particle_mass[:, None] * s0.particle_qd**2)), 1e-12)
    row = dict(case=case.name, sweep=sweep, method=method, integrator=integrator, dt=dt, steps=steps,
               solver=options.get("solver", "") if INTEGRATORS[integrator].implicit else "",
               jacobian=options.get("jacobian", ""), rtol=(options.get("solver_options") or {}).get("rtol", ""),
               newton_tol=options.get("newton_tol", ""), energy_drift_ref=e_ref_drift)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            integ = make_integrator(integrator, model, **options)
            if getattr(integ, "jacobian", None) and not row["jacobian"]:
                row["jacobian"] = integ.jacobian
            tr = simulate(model, integ, dt, steps, state=case.state, record=False)
        except SimulationError as e:
            tr = e.trajectory
            s = tr.summary() if tr is not None else {}
            row.update(status="unstable (blew up)", err_rms=float("inf"), err_max=float("inf"),
                       energy_drift=float("nan"), wall_per_sim_s=s.get("wall_s", float("nan")) / case.horizon,
                       newton_per_step=s.get("newton_iterations", 0), linear_per_step=s.get("linear_iterations", 0))
            return row
        except SolverError as e:
            row.update(status=f"solver error: {str(e)[:60]}", err_rms=float("nan"), err_max=float("nan"))
            return row
    s = tr.summary()
    rms, mx = position_errors(tr.q[-1], ref_q, case.size)
    e1 = total_energy(model, terms, tr.q[-1], tr.qd[-1])
    row.update(wall_per_sim_s=s["wall_s"] / case.horizon, err_rms=rms, err_max=mx,
               energy_drift=(e1 - e0) / e_scale if np.isfinite(e1) else float("inf"),
               newton_per_step=s["newton_iterations"], linear_per_step=s["linear_iterations"],
               newton_failures=s["newton_failures"], fallbacks=s["fallbacks"])
    row["status"] = classify(row)
    return row


def classify(row: dict) -> str:
    """Status of a finished run: ``ok``, ``ok (k Newton limit)`` or ``unstable (...)``.

    Unstable: RMS error above the scene size, or an energy gain above ``E_scale`` beyond
    the reference's (no scene here gains energy; a stiff cloth whose Newton iterations
    stall at a large step can blow up in energy while its positions stay bounded).
    """
    rms, drift = float(row["err_rms"]), float(row["energy_drift"])
    ref = float(row.get("energy_drift_ref") or 0.0)
    if not rms < 1.0:
        return "unstable (diverged)"
    if not drift - ref < 1.0:
        return f"unstable (energy +{drift:.3g} E_scale)"
    k = int(float(row.get("newton_failures") or 0))
    return f"ok ({k} Newton limit)" if k else "ok"


def run_case(case, *, dts, newton_tols, solver_rtols, solver_dt: float = 1 / 60, ref_method: str = "auto",
             sweeps=("dt", "newton", "solver"), solver_integrators=None, log=print) -> list[dict]:
    """All sweeps for one case; returns the result rows.

    ``solver_integrators`` limits the solver sweep to these integrators (default: every implicit one).
    """
    from springsim.forces import make_force_terms
    from springsim.integrators import INTEGRATORS
    from springsim.linsolve import LINEAR_SOLVERS

    ref_q, ref_qd, ref_s, ref_m = reference_final(case, method=ref_method)
    terms = make_force_terms(case.model)
    s0 = case.model.state() if case.state is None else case.state
    e0 = total_energy(case.model, terms, s0.particle_q, s0.particle_qd)
    e1 = total_energy(case.model, terms, ref_q, ref_qd)
    g = abs(float(case.model.gravity))
    e_scale = max(abs(e0), float(np.sum(case.model.particle_mass)) * g * case.size,
                  0.5 * float(np.sum(case.model.particle_mass[:, None] * s0.particle_qd**2)), 1e-12)
    e_ref_drift = (e1 - e0) / e_scale
    log(f"# {case.name}: {case.model.particle_count} particles, reference {ref_m} ({ref_s:.1f} s)")
    rows = []
    if "dt" in sweeps:
        for name in INTEGRATORS:
            for dt in dts:
                rows.append(_run(case, ref_q, e_ref_drift, name, dt, sweep="dt", method=name))
    if "newton" in sweeps and "implicit_euler" in INTEGRATORS:
        for tol in newton_tols:
            for dt in dts[: max(2, len(dts) // 2)]:
                rows.append(_run(case, ref_q, e_ref_drift, "implicit_euler", dt, sweep="newton",
                                 method=f"implicit_euler tol={tol:g}", newton_tol=tol, newton_maxiter=20))
    if "solver" in sweeps:
        for name, cls in INTEGRATORS.items():
            if not cls.implicit or (solver_integrators is not None and name not in solver_integrators):
                continue
            for sname, scls in LINEAR_SOLVERS.items():
                if sname == "dense" and case.model.particle_count > 300:
                    continue
                tols = solver_rtols if _is_iterative(scls) else [None]
                for tol in tols:
                    opts = dict(solver=sname)
                    if tol is not None:
                        opts["solver_options"] = {"rtol": tol}
                    rows.append(_run(case, ref_q, e_ref_drift, name, solver_dt, sweep="solver",
                                     method=f"{name}/{sname}", **opts))
    for r in rows:
        log(f"  {r['sweep']:6s} {r['method']:34s} dt={r['dt']:.2e} rtol={r['rtol']!s:6s} "
            f"{r['status']:22s} err={r.get('err_rms', float('nan')):.2e} "
            f"t/sim_s={r.get('wall_per_sim_s', float('nan')):.3g}")
    return rows


def read_csv(path) -> list[dict]:
    """Rows of a ``speed_vs_error.csv`` with numbers parsed and the status re-derived by :func:`classify`."""
    text = {"case", "sweep", "method", "integrator", "solver", "jacobian", "status"}
    rows = []
    with open(path) as fh:
        for r in csv.DictReader(fh):
            for k, v in r.items():
                if k not in text and v != "":
                    r[k] = float(v)
            if r["status"].startswith(("ok", "unstable (diverged)", "unstable (energy")) and r["err_rms"] != "":
                r["status"] = classify(r)
            rows.append(r)
    return rows


def orders(rows: list[dict]) -> list[dict]:
    """Observed convergence order per (case, integrator) from the dt sweep."""
    from springsim.integrators import INTEGRATORS

    out = []
    for case in dict.fromkeys(r["case"] for r in rows):
        for name, cls in INTEGRATORS.items():
            rr = [r for r in rows if r["case"] == case and r["sweep"] == "dt" and r["integrator"] == name]
            if not rr:
                continue
            dts = [r["dt"] for r in rr]
            errs = [r.get("err_rms", np.nan) if r["status"].startswith("ok") else np.nan for r in rr]
            ok = [d for d, e in zip(dts, errs) if np.isfinite(e) and 1e-12 < e < 0.5]
            used = sorted(ok)[:3]
            out.append(dict(case=case, integrator=name, order=fit_order(dts, errs),
                            formal_order=getattr(cls, "order", ""),
                            dts_used=" ".join(f"1/{round(1 / d)}" for d in used)))
    return out


def pareto_plot(rows: list[dict], case: str, out_png, *, dpi: int = 80) -> bool:
    """Log-log plot of wall time per simulated second against RMS error, one curve per method.

    Solid lines with dots: the dt ladder per integrator; dashed: implicit Euler per Newton
    tolerance; crosses: the solver/rtol sweep at h = 1/60 s.
    """
    plt = pyplot()
    if plt is None:
        return False
    fig, ax = plt.subplots(figsize=(8.4, 4.6))
    colors = plt.get_cmap("tab20").colors
    styles = {"dt": dict(marker="o", ls="-", lw=1.4, ms=3), "newton": dict(marker="d", ls="--", lw=0.8, ms=3),
              "solver": dict(marker="x", ls=":", lw=0.8, ms=6)}
    k = 0
    for sweep in ("dt", "newton", "solver"):
        rr_s = [r for r in rows if r["case"] == case and r["sweep"] == sweep and r["status"].startswith("ok")]
        for m in dict.fromkeys(r["method"] for r in rr_s):
            rr = sorted((r for r in rr_s if r["method"] == m), key=lambda r: (-r["dt"], str(r["rtol"])))
            label = m if sweep != "solver" else f"{m} (rtol ladder, h=1/60)"
            ax.loglog([r["err_rms"] for r in rr], [r["wall_per_sim_s"] for r in rr], color=colors[k % 20],
                      label=label, **styles[sweep])
            k += 1
    ax.set_xlabel("final position error, RMS / scene size")
    ax.set_ylabel("wall time per simulated second [s]")
    ax.set_title(f"speed vs error: {case} (lower left is better)")
    ax.grid(True, which="major", alpha=0.3)
    ax.legend(fontsize=6.5, loc="center left", bbox_to_anchor=(1.01, 0.5), frameon=False)
    save_figure(fig, out_png, dpi)
    return True


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="tiny run (4x4 cloth, spring scene, 2 time steps)")
    p.add_argument("--full", action="store_true",
                   help="unbounded run: dt down to 1/3840 s everywhere, every implicit integrator in the solver sweep")
    p.add_argument("--cloth", type=int, nargs="*", default=None, help="cloth sizes n (default 8 16 32)")
    p.add_argument("--scenes", nargs="*", default=None, help="shipped scenes (default spring stiff_chain three_body)")
    p.add_argument("--horizon", type=float, default=0.5, help="simulated time [s]")
    p.add_argument("--ref-method", default="auto", help="solve_ivp method of the reference (auto|Radau|BDF|DOP853)")
    p.add_argument("--out", type=Path, default=RESULTS_DIR, help="output directory")
    p.add_argument("--plot-dir", type=Path, default=None, help="also write the Pareto PNGs here (e.g. docs/)")
    p.add_argument("--from-csv", type=Path, default=None,
                   help="skip the runs: rebuild tables and plots from an earlier speed_vs_error.csv")
    a = p.parse_args(argv)
    if a.quick:
        cloths = [4] if a.cloth is None else a.cloth
        scenes = ["spring"] if a.scenes is None else a.scenes
        dts, ntols, rtols = [1 / 60, 1 / 120], [1e-2], [1e-2, 1e-8]
        horizon = min(a.horizon, 0.05)
    else:
        cloths = [8, 16, 32] if a.cloth is None else a.cloth
        scenes = list(SCENE_NAMES) if a.scenes is None else a.scenes
        dts, ntols, rtols, horizon = DT_LADDER, NEWTON_TOLS, SOLVER_RTOLS, a.horizon
        if not a.full:
            dts, rtols = [d for d in dts if d > 1 / 3000], [1e-2, 1e-4, 1e-6, 1e-10]
    cases = [scene_case(s, horizon) for s in scenes] + [benchmark_case(n, horizon) for n in cloths]
    rows = read_csv(a.from_csv) if a.from_csv else []
    for case in (cases if a.from_csv is None else []):
        ladder = dts
        if case.name.startswith("cloth") and not (a.quick or a.full):
            # bound the default run: the finest steps only on the small cloths
            n = int(case.name[5:])
            ladder = [d for d in dts if d >= {8: 0, 16: 1 / 960}.get(n, 1 / 480) - 1e-15]
        rows += run_case(case, dts=ladder, newton_tols=ntols, solver_rtols=rtols, ref_method=a.ref_method,
                         solver_integrators=None if (a.full or a.quick) else ("implicit_euler",),
                         sweeps=("dt", "newton", "solver") if not case.name.startswith("cloth") or
                         case.name in ("cloth4", "cloth8", "cloth16") else ("dt", "solver"))
    ords = orders(rows)
    a.out.mkdir(parents=True, exist_ok=True)
    write_csv(a.out / "speed_vs_error.csv", rows, COLUMNS)
    write_csv(a.out / "convergence_orders.csv", ords, ORDER_COLUMNS)
    short = ["case", "sweep", "method", "rtol", "dt", "status", "wall_per_sim_s", "err_rms", "err_max",
             "energy_drift", "newton_per_step", "linear_per_step"]
    md = ("## Speed against error\n\n" + markdown_table(rows, short) + "\n\n## Observed orders\n\n"
          + markdown_table(ords, ORDER_COLUMNS) + "\n")
    (a.out / "speed_vs_error.md").write_text(md)
    print(markdown_table(ords, ORDER_COLUMNS))
    for name in dict.fromkeys(r["case"] for r in rows):
        for d in [a.out] + ([a.plot_dir] if a.plot_dir else []):
            pareto_plot(rows, name, d / f"pareto_{name}.png")
    print(f"wrote {a.out / 'speed_vs_error.csv'}, {a.out / 'speed_vs_error.md'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
