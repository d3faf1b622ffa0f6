"""Speed against error of every integrator, time step, Newton tolerance, linear solver and adaptive tolerance.

For each case (benchmark cloths n = 8, 16, 32 and the shipped scenes spring,
stiff damped chain, three-body; ``scenes/*.yaml``) the final state after ``horizon`` seconds is compared
with an independent ``solve_ivp`` reference (:func:`springsim.analysis.reference.reference_trajectory`,
rtol 1e-10). Four sweeps:

``dt``
    every integrator in :data:`springsim.integrators.INTEGRATORS` (default options)
    at a ladder of time steps 1/30 ... 1/3840 s;
``newton``
    implicit Euler at several Newton tolerances (``newton_maxiter`` 20) at the first half
    of the dt ladder (at least two steps);
``solver``
    every implicit integrator with every solver in :data:`springsim.linsolve.LINEAR_SOLVERS`
    at a ladder of relative tolerances (direct solvers once), at ``h = 1/60`` s;
``adaptive``
    :func:`springsim.run.adaptive.simulate_adaptive` with ``bdf2``, ``tr_bdf2`` and ``energy_momentum`` (every
    integrator with an error estimate) over a ladder of
    time tolerances ``time_rtol`` 1e-2 ... 1e-6 (``time_atol = time_rtol * L``); the row's ``dt``
    is the mean accepted step, ``steps``/``rejected`` the accepted/rejected steps, ``h_min``/``h_max``
    the extreme accepted steps, and Newton/linear iterations count every attempt per accepted step.

The default run is bounded (:data:`DEFAULT_BOUNDS`): the scenes get the whole dt ladder down to
1/1920 s and the time_rtol ladder 1e-2 ... 1e-6; the 8 x 8 cloth steps down to 1/960 s and
time_rtol down to 1e-5; 16 x 16 down to 1/480 s, time_rtol down to 1e-4 and solver rtols 1e-2 and
1e-6; 32 x 32 runs the dt ladder 1/30 ... 1/120 s and the adaptive sweep at time_rtol 1e-3 only
(no Newton or solver sweep). The solver sweep uses implicit Euler only, with rtols 1e-2, 1e-4, 1e-6,
1e-10 on the scenes and 8 x 8. Measured (443 runs, ``OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1``):
303 s of CPU (255 s user + 47 s system) in 396 s wall, with other agents' benchmarks running on
the 2 cores (load average 2.3-3.1); scenes 70 s, 8 x 8 32 s, 16 x 16 104 s, 32 x 32 178 s wall.
Re-run after the BDF2/TR-BDF2 Newton limit went to 20: 269 s of CPU (225 s user + 44 s system)
in 507 s wall at load 3.1-4.4.
(The previous default, without the adaptive sweep but with dt down to 1/960 s on 16 x 16 and
1/480 s on 32 x 32 and the full solver sweep on 32 x 32, took 533 s wall at load ~1 and ~19 min at
load 4.) ``--full`` lifts all bounds (dt down to 1/3840 s, every rtol and time_rtol, every implicit
integrator in the solver sweep, every sweep on every case): not measured, two hours or more by
extrapolation of the per-run times.

Per run: wall time per simulated second, RMS/max position error relative to the
scene size, stability, energy drift, Newton and linear iterations. Observed orders
of convergence are fitted on the dt ladder. Writes ``results/speed_vs_error.csv``,
``.md`` and Pareto plots ``results/pareto_<case>.png``.

Usage::

    python -m benchmarks speed-vs-error            # default: bounded, ~4.5-5 min of CPU
    python -m benchmarks speed-vs-error --quick    # seconds (used by the tests)
    python -m benchmarks speed-vs-error --full     # every ladder on every case; hours (not measured)
    python -m benchmarks speed-vs-error --sweeps adaptive --cloth 16 --scenes   # one sweep, one case
    python -m benchmarks speed-vs-error --from-csv benchmarks/results/speed_vs_error.csv  # re-plot only
"""

from __future__ import annotations

import argparse
import csv
import time
import warnings
from pathlib import Path

import numpy as np

from springsim.integrators import INTEGRATORS
from springsim.run.energy import total_energy

from .common import (RESULTS_DIR, SCENE_NAMES, benchmark_case, fit_order, markdown_table, position_errors,
                     pyplot, reference_final, save_figure, scene_case, write_csv)

__all__ = ["COLUMNS", "ORDER_COLUMNS", "ALL_SWEEPS", "ADAPTIVE_INTEGRATORS", "TIME_RTOLS", "DEFAULT_BOUNDS",
           "run_case", "classify", "orders", "pareto_plot", "default_bounds", "read_csv", "main"]

#: Columns of the CSV / markdown table.
COLUMNS = ["case", "sweep", "method", "integrator", "solver", "jacobian", "rtol", "newton_tol", "time_rtol", "dt",
           "steps", "rejected", "h_min", "h_max", "status", "wall_per_sim_s", "err_rms", "err_max", "energy_drift",
           "energy_drift_ref", "newton_per_step", "linear_per_step", "newton_failures", "fallbacks"]
#: Integer-valued columns (counts).
INT_COLUMNS = {"steps", "rejected", "newton_failures", "fallbacks"}
#: Columns of the observed-order table.
ORDER_COLUMNS = ["case", "integrator", "order", "formal_order", "dts_used"]

DT_LADDER = [1 / 30, 1 / 60, 1 / 120, 1 / 240, 1 / 480, 1 / 960, 1 / 1920, 1 / 3840]
NEWTON_TOLS = [1e-1, 1e-2, 1e-3, 1e-5, 1e-8]
SOLVER_RTOLS = [1e-2, 1e-4, 1e-6, 1e-8, 1e-10]
TIME_RTOLS = [1e-2, 1e-3, 1e-4, 1e-5, 1e-6]
#: Integrators of the adaptive sweep: every registered one with a local error estimate.
ADAPTIVE_INTEGRATORS = tuple(name for name, cls in INTEGRATORS.items() if cls.has_error_estimate)
ALL_SWEEPS = ("dt", "newton", "solver", "adaptive")

#: Bounds of the default run (``--full`` lifts them): smallest time step of the dt ladder
#: (the Newton sweep takes the first half of that ladder, at least two steps), the solver
#: sweep's rtols (implicit Euler only), the adaptive sweep's time tolerances, and the sweeps.
DEFAULT_BOUNDS = {
    "scene": dict(min_dt=1 / 1920, solver_rtols=[1e-2, 1e-4, 1e-6, 1e-10], time_rtols=TIME_RTOLS,
                  sweeps=ALL_SWEEPS),
    "cloth8": dict(min_dt=1 / 960, solver_rtols=[1e-2, 1e-4, 1e-6, 1e-10], time_rtols=TIME_RTOLS[:4],
                   sweeps=ALL_SWEEPS),
    "cloth16": dict(min_dt=1 / 480, solver_rtols=[1e-2, 1e-6], time_rtols=TIME_RTOLS[:3], sweeps=ALL_SWEEPS),
    "cloth32": dict(min_dt=1 / 120, solver_rtols=[], time_rtols=[1e-3], sweeps=("dt", "adaptive")),
}


def _print(msg: str) -> None:
    print(msg, flush=True)


def _is_iterative(solver_cls) -> bool:
    """Iterative solvers honour ``rtol``; direct/dense ones (and their wrappers) do not."""
    name = getattr(solver_cls, "name", "")
    return name not in ("dense", "direct")


def _energy_scale(case, terms, s0) -> tuple[float, float]:
    """``(E0, E_scale)`` of a case: initial energy and ``max(|E0|, m_total |g| L, KE0)``."""
    model = case.model
    e0 = total_energy(model, s0.particle_q, s0.particle_qd, terms)
    g = abs(float(model.gravity))
    e_scale = max(abs(e0), float(np.sum(model.particle_mass)) * g * case.size,
                  0.5 * float(np.sum(model.particle_mass[:, None] * s0.particle_qd**2)), 1e-12)
    return e0, e_scale


def _run(case, ref_q, e_ref_drift, integrator: str, dt: float | None, *, sweep: str, method: str,
         time_rtol: float | None = None, **options) -> dict:
    """One simulation; returns a result row (never raises on blow-up or solver failure).

    With ``time_rtol`` the run is adaptive (:func:`springsim.run.adaptive.simulate_adaptive`,
    ``time_atol = time_rtol * L``) and ``dt`` is ignored: the row's ``dt`` is then the mean
    accepted step, ``steps`` the accepted and ``rejected`` the rejected steps, and the Newton and
    linear iterations per step count every attempt (rejected ones too) per accepted step.
    """
    from springsim.errors import SimulationError, SolverError
    from springsim.forces import make_force_terms
    from springsim.integrators import make_integrator
    from springsim.run.adaptive import simulate_adaptive
    from springsim.run.driver import simulate

    model = case.model
    adaptive = time_rtol is not None
    if adaptive:
        options.setdefault("on_nonconvergence", "ignore")
    else:
        steps = max(1, int(round(case.horizon / dt)))
        dt = case.horizon / steps
    terms = make_force_terms(model)
    s0 = model.state() if case.state is None else case.state
    e0, e_scale = _energy_scale(case, terms, s0)
    row = dict(case=case.name, sweep=sweep, method=method, integrator=integrator,
               solver=options.get("solver", "") if INTEGRATORS[integrator].implicit else "",
               jacobian=options.get("jacobian", ""), rtol=(options.get("solver_options") or {}).get("rtol", ""),
               newton_tol=options.get("newton_tol", ""), energy_drift_ref=e_ref_drift)
    if adaptive:
        row.update(time_rtol=time_rtol)
    else:
        row.update(dt=dt, steps=steps)

    def adaptive_stats(tr):
        a = getattr(tr, "adaptive_stats", None) if tr is not None else None
        if not a:
            return
        n = max(a["accepted"], 1)
        row.update(dt=a["h_mean"], steps=a["accepted"], rejected=a["rejected"], h_min=a["h_min"],
                   h_max=a["h_max"], newton_per_step=a["newton_iterations"] / n,
                   linear_per_step=a["linear_iterations"] / n, newton_failures=a["newton_failures"])

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            integ = make_integrator(integrator, model, **options)
            if getattr(integ, "jacobian", None) and not row["jacobian"]:
                row["jacobian"] = integ.jacobian
            if adaptive:
                tr = simulate_adaptive(model, integ, case.horizon, time_rtol=time_rtol,
                                       time_atol=time_rtol * case.size, state=case.state)
            else:
                tr = simulate(model, integ, dt, steps, state=case.state, record=False)
        except SimulationError as e:
            tr = e.trajectory
            s = tr.summary() if tr is not None else {}
            blew_up = not adaptive or "non-finite" in str(e)
            row.update(status="unstable (blew up)" if blew_up else f"failed: {str(e)[:60]}",
                       err_rms=float("inf"), err_max=float("inf"),
                       energy_drift=float("nan"), wall_per_sim_s=s.get("wall_s", float("nan")) / case.horizon,
                       newton_per_step=s.get("newton_iterations", 0), linear_per_step=s.get("linear_iterations", 0))
            adaptive_stats(tr)
            return row
        except SolverError as e:
            row.update(status=f"solver error: {str(e)[:60]}", err_rms=float("nan"), err_max=float("nan"))
            return row
    s = tr.summary()
    rms, mx = position_errors(tr.q[-1], ref_q, case.size)
    e1 = total_energy(model, tr.q[-1], tr.qd[-1], terms)
    row.update(wall_per_sim_s=s["wall_s"] / case.horizon, err_rms=rms, err_max=mx,
               energy_drift=(e1 - e0) / e_scale if np.isfinite(e1) else float("inf"),
               newton_per_step=s["newton_iterations"], linear_per_step=s["linear_iterations"],
               newton_failures=s["newton_failures"], fallbacks=s["fallbacks"])
    adaptive_stats(tr)
    row["status"] = classify(row)
    return row


def classify(row: dict) -> str:
    """Status of a finished run: ``ok``, ``ok (k Newton limit)``, ``ok (k Newton retries)`` or ``unstable (...)``.

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
    if not k:
        return "ok"
    # fixed steps: k steps kept Newton's last iterate; adaptive: k steps were rejected and retried with h/4
    return f"ok ({k} Newton retries)" if row.get("sweep") == "adaptive" else f"ok ({k} Newton limit)"


def run_case(case, *, dts, newton_tols, solver_rtols, time_rtols=(), solver_dt: float = 1 / 60,
             ref_method: str = "auto", sweeps=ALL_SWEEPS, solver_integrators=None, filter_variants: bool = False,
             log=None) -> list[dict]:
    """All sweeps for one case; returns the result rows.

    ``solver_integrators`` limits the solver sweep to these integrators (default: every implicit one);
    ``time_rtols`` is the tolerance ladder of the ``adaptive`` sweep (every integrator of
    :data:`ADAPTIVE_INTEGRATORS`; ``filter_variants``: also, for those that can filter their estimate, the
    variant that is not their default, as ``NAME adaptive filtered`` or ``NAME adaptive unfiltered``).
    """
    from springsim.forces import make_force_terms
    from springsim.linsolve import LINEAR_SOLVERS

    log = log or _print
    unknown = set(sweeps) - set(ALL_SWEEPS)
    if unknown:
        raise ValueError(f"sweeps: unknown {sorted(unknown)}; choose from {', '.join(ALL_SWEEPS)}")
    ref_q, ref_qd, ref_s, ref_m = reference_final(case, method=ref_method)
    terms = make_force_terms(case.model)
    s0 = case.model.state() if case.state is None else case.state
    e0, e_scale = _energy_scale(case, terms, s0)
    e1 = total_energy(case.model, ref_q, ref_qd, terms)
    e_ref_drift = (e1 - e0) / e_scale
    log(f"# {case.name}: {case.model.particle_count} particles, reference {ref_m} ({ref_s:.1f} s)")
    rows = []
    t0 = time.perf_counter()

    def done(r):
        rows.append(r)
        rt = f"time_rtol={r['time_rtol']:.0e}" if r.get("time_rtol", "") != "" else f"rtol={r['rtol']!s:6s}"
        log(f"  {r['sweep']:8s} {r['method']:28s} dt={r.get('dt', float('nan')):.2e} {rt:15s} "
            f"{r['status'][:24]:24s} err={r.get('err_rms', float('nan')):.2e} "
            f"t/sim_s={r.get('wall_per_sim_s', float('nan')):.3g}  [{time.perf_counter() - t0:.0f} s]")

    if "dt" in sweeps:
        for name in INTEGRATORS:
            for dt in dts:
                done(_run(case, ref_q, e_ref_drift, name, dt, sweep="dt", method=name))
    if "newton" in sweeps and "implicit_euler" in INTEGRATORS:
        for tol in newton_tols:
            for dt in dts[: max(2, len(dts) // 2)]:
                done(_run(case, ref_q, e_ref_drift, "implicit_euler", dt, sweep="newton",
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
                    done(_run(case, ref_q, e_ref_drift, name, solver_dt, sweep="solver", method=f"{name}/{sname}",
                              **opts))
    if "adaptive" in sweeps:
        for name in ADAPTIVE_INTEGRATORS:
            for tol in time_rtols:
                done(_run(case, ref_q, e_ref_drift, name, None, sweep="adaptive", method=f"{name} adaptive",
                          time_rtol=tol))
            cls = INTEGRATORS[name]
            if filter_variants and "filter_estimates" not in cls.unused_options:
                other = not cls.default_filter_estimates
                for tol in time_rtols:
                    done(_run(case, ref_q, e_ref_drift, name, None, sweep="adaptive", time_rtol=tol,
                              method=f"{name} adaptive {'filtered' if other else 'unfiltered'}",
                              filter_estimates=other))
    log(f"# {case.name}: {len(rows)} runs in {time.perf_counter() - t0:.1f} s")
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
                    if k in INT_COLUMNS and r[k].is_integer():
                        r[k] = int(r[k])
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


def pareto_plot(rows: list[dict], case: str, out_png, *, dpi: int = 100) -> bool:
    """Log-log plot of wall time per simulated second against RMS error, one curve per method.

    Solid lines with dots: the dt ladder per integrator; dashed: implicit Euler per Newton
    tolerance; crosses: the solver/rtol sweep at h = 1/60 s; thick dash-dotted lines with
    squares (same colour as the integrator's dt ladder): the adaptive integrators over their
    time-tolerance ladder, whose range the legend gives (no labels on the points, so nothing
    overlaps the curves); the other setting of the estimate's stiff filter (``--filter-variants``)
    dotted with hollow squares.
    """

    plt = pyplot()
    if plt is None:
        return False
    fig, ax = plt.subplots(figsize=(10.0, 5.6))
    base = plt.get_cmap("tab10").colors  # one per integrator: its dt ladder and its adaptive curve
    others = plt.get_cmap("tab20b").colors  # Newton and solver sweeps
    names = list(INTEGRATORS)
    styles = {"dt": dict(marker="o", ls="-", lw=1.4, ms=3), "newton": dict(marker="d", ls="--", lw=0.8, ms=3),
              "solver": dict(marker="x", ls=":", lw=0.8, ms=6), "adaptive": dict(marker="s", ls="-.", lw=2.2, ms=5)}
    k = 0
    for sweep in ALL_SWEEPS:
        rr_s = [r for r in rows if r["case"] == case and r["sweep"] == sweep and r["status"].startswith("ok")]
        for m in dict.fromkeys(r["method"] for r in rr_s):
            key = ((lambda r: -float(r["time_rtol"])) if sweep == "adaptive"
                   else (lambda r: (-r["dt"], str(r["rtol"]))))
            rr = sorted((r for r in rr_s if r["method"] == m), key=key)
            if sweep == "adaptive":
                lo, hi = float(rr[-1]["time_rtol"]), float(rr[0]["time_rtol"])
                label = f"{m} (time_rtol {hi:.0e} to {lo:.0e})"
            else:
                label = {"solver": f"{m} (rtol ladder, h=1/60)"}.get(sweep, m)
            if sweep in ("dt", "adaptive"):
                integ = rr[0]["integrator"]
                color = base[(names.index(integ) if integ in names else len(names)) % 10]
            else:
                color = others[(4 * k + k // 5) % 20]
                k += 1
            style = dict(styles[sweep])
            if m.endswith(("filtered", "unfiltered")):  # --filter-variants: the integrator's colour, hollow, dotted
                style.update(ls=":", mfc="none")
            ax.loglog([r["err_rms"] for r in rr], [r["wall_per_sim_s"] for r in rr], color=color,
                      label=label, **style)
    ax.set_xlabel("final position error, RMS / scene size")
    ax.set_ylabel("wall time per simulated second [s]")
    ax.set_title(f"speed vs error: {case} (lower left is better)")
    ax.grid(True, which="major", alpha=0.3)
    ax.legend(fontsize=7.5, loc="center left", bbox_to_anchor=(1.01, 0.5), frameon=False)
    save_figure(fig, out_png, dpi)
    return True


def default_bounds(case) -> dict:
    """Per-case bounds of the default run (see the module docstring and :data:`DEFAULT_BOUNDS`)."""
    if not case.name.startswith("cloth"):
        return DEFAULT_BOUNDS["scene"]
    n = int(case.name[5:])
    return DEFAULT_BOUNDS["cloth8" if n <= 8 else "cloth16" if n <= 16 else "cloth32"]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true",
                   help="tiny run (4x4 cloth, spring scene, 0.05 s, 2 time steps, 2 time tolerances)")
    p.add_argument("--full", action="store_true",
                   help="unbounded run: dt down to 1/3840 s, every rtol and time_rtol, every implicit integrator "
                        "in the solver sweep, on every case (long)")
    p.add_argument("--cloth", type=int, nargs="*", default=None, help="cloth sizes n (default 8 16 32)")
    p.add_argument("--scenes", nargs="*", default=None, help="shipped scenes (default spring stiff_chain three_body)")
    p.add_argument("--sweeps", nargs="*", default=list(ALL_SWEEPS), choices=ALL_SWEEPS,
                   help="sweeps to run (default all)")
    p.add_argument("--horizon", type=float, default=0.5, help="simulated time [s]")
    p.add_argument("--ref-method", default="auto", help="solve_ivp method of the reference (auto|Radau|BDF|DOP853)")
    p.add_argument("--out", type=Path, default=RESULTS_DIR, help="output directory")
    p.add_argument("--plot-dir", type=Path, default=None, help="also write the Pareto PNGs here (e.g. docs/)")
    p.add_argument("--filter-variants", action="store_true",
                   help="adaptive sweep: also run BDF2 and TR-BDF2 with the stiff filter of their error estimate "
                        "switched the other way from their default")
    p.add_argument("--from-csv", type=Path, default=None,
                   help="skip the runs: rebuild tables and plots from an earlier speed_vs_error.csv")
    a = p.parse_args(argv)
    t_start = time.perf_counter()
    if a.quick:
        cloths = [4] if a.cloth is None else a.cloth
        scenes = ["spring"] if a.scenes is None else a.scenes
        horizon = min(a.horizon, 0.05)
    else:
        cloths = [8, 16, 32] if a.cloth is None else a.cloth
        scenes = list(SCENE_NAMES) if a.scenes is None else a.scenes
        horizon = a.horizon
    cases = [scene_case(s, horizon) for s in scenes] + [benchmark_case(n, horizon) for n in cloths]
    if a.from_csv:
        cases = []
    rows = read_csv(a.from_csv) if a.from_csv else []
    for case in cases:
        if a.quick:
            plan = dict(dts=[1 / 60, 1 / 120], newton_tols=[1e-2], solver_rtols=[1e-2, 1e-8],
                        time_rtols=[1e-2, 1e-5], sweeps=ALL_SWEEPS, solver_integrators=None)
        elif a.full:
            plan = dict(dts=DT_LADDER, newton_tols=NEWTON_TOLS, solver_rtols=SOLVER_RTOLS, time_rtols=TIME_RTOLS,
                        sweeps=ALL_SWEEPS, solver_integrators=None)
        else:
            b = default_bounds(case)
            plan = dict(dts=[d for d in DT_LADDER if d >= b["min_dt"] * (1 - 1e-9)], newton_tols=NEWTON_TOLS,
                        solver_rtols=b["solver_rtols"], time_rtols=b["time_rtols"], sweeps=b["sweeps"],
                        solver_integrators=("implicit_euler",))
        plan["sweeps"] = tuple(sw for sw in plan["sweeps"] if sw in a.sweeps)
        rows += run_case(case, ref_method=a.ref_method, filter_variants=a.filter_variants, **plan)
    ords = orders(rows)
    a.out.mkdir(parents=True, exist_ok=True)
    write_csv(a.out / "speed_vs_error.csv", rows, COLUMNS)
    write_csv(a.out / "convergence_orders.csv", ords, ORDER_COLUMNS)
    short = ["case", "sweep", "method", "rtol", "time_rtol", "dt", "steps", "rejected", "status", "wall_per_sim_s",
             "err_rms", "err_max", "energy_drift", "newton_per_step", "linear_per_step"]
    md = ("## Speed against error\n\n" + markdown_table(rows, short) + "\n\n## Observed orders\n\n"
          + markdown_table(ords, ORDER_COLUMNS) + "\n")
    (a.out / "speed_vs_error.md").write_text(md)
    print(markdown_table(ords, ORDER_COLUMNS))
    for name in dict.fromkeys(r["case"] for r in rows):
        for d in [a.out] + ([a.plot_dir] if a.plot_dir else []):
            pareto_plot(rows, name, d / f"pareto_{name}.png")
    print(f"wrote {a.out / 'speed_vs_error.csv'}, {a.out / 'speed_vs_error.md'} "
          f"({len(rows)} rows; wall {time.perf_counter() - t_start:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
