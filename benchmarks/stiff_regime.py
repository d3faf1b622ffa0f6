"""The stiff regime, decided: CPU per 1/60 s frame to reach 1 cm and 5 cm at ke = 1e6-1e8, implicit against explicit.

For every size ``n`` of ``--sizes`` (default 32 64) and stiffness ``ke`` of ``--ke`` (default 1e6 1e7 1e8;
structural and shear springs [N/m], bending 1e2 N/m) this runs :mod:`benchmarks.frame_cost` on
``benchmark_cloth(n, stiffness=ke)`` (1 m, 1 kg, edge y = 0 pinned, released horizontal at rest) with its
protocol, every candidate measured (``--measure-all``):

* the **reference**: velocity Verlet at 2, 4 and 8 times the explicit limit's substeps per frame, its floor
  the largest difference of the two finest levels (RMS over particles, max over the frames of the window);
  without the solve_ivp cross-check by default (``--cross-check-max-n 0``: DOP853 at rtol 1e-10 does not
  finish at these stiffnesses in hours), so the floor is the Verlet levels' difference;
* **symplectic Euler at its verified stability limit** (stable from a perturbed start at the count, unstable
  at 0.7 of it);
* the implicit candidates of ``--candidates``, by default ``implicit_euler``, ``bdf2``, ``tr_bdf2`` and
  ``linearized_implicit`` at ``1/h`` = 60, 120, 240 and 480 with the linear solver ``auto``; every error is the
  RMS over particles against the reference, max over the frames of the window; a run stops once it exceeds
  5 cm (``--stop-above``), so it is then more than 5 cm off.

**The window.** The default is the first **30 frames** (0.5 s) from the release, **undamped**
(``--frames``, ``--damping``). On the 70-frame window of frame-cost the buckling's chaotic sensitivity
amplified the reference's own truncation error to more than 1 cm above ke = 1e5, so 1 cm could not be
decided. The fall before the buckling is smooth: at n = 32, ke = 1e6 over 40 frames the differences of
consecutive Verlet levels (1,506 / 3,012 / 6,024 substeps per frame) shrink by 4.0 per halving of the step
(second order, converging) at every frame up to frame 33, where they are below 1e-7 m, and between frames
34 and 37 they jump to 0.5 mm and stop shrinking (ratios 1.5, 1.2, 0.8): the buckling. A window ending at
frame 30 lies before it, so the reference's floor is orders of magnitude below 1 cm with no damping at
all (n = 32: 3.8e-8, 2.9e-7 and 1.9e-4 m at ke = 1e6, 1e7, 1e8; n = 64, ke = 1e6: 9.7e-7 m), and the motion
measured is the undamped one of the issue's cloth; spring damping (``--damping``) would change the ODE
being integrated and is not needed. The stiffer the cloth, the earlier the sensitivity: at n = 32,
ke = 1e8 the levels' differences shrink by 4 per halving up to frame 28 and stop shrinking in frames 29-30,
yet stay at 0.19 mm there, 50x below 1 cm. Each run's floor and the Verlet levels' ratios are in the
outputs: a floor at or above a target marks that target undecidable (``decidable`` False).

For each ``(n, ke)`` and target (1 cm and 5 cm) the report gives, **per method**, its cheapest
configuration within the target (CPU per frame; symplectic Euler has one, at its limit), or, if none
is, its most accurate run (``reached`` False); the ratio of that CPU per frame to symplectic Euler's at its
verified limit; Newton iterations per stage solve (retakes included) and per step; the steps whose Newton
did not converge, the steps still failed after their retakes in 2, 4, ... 32 substeps (``failed_steps``, which
must be 0) and the steps that needed a retake; the reference's floor and the load average before and after
the size. Writes ``results/stiff_regime.csv``, ``results/stiff_regime.md`` and ``results/stiff_regime.png``
(CPU per frame at 1 cm against ke, log-log, one panel per n, one line per method; the explicit trend
``C n^3 sqrt(ke)``: substeps per frame grow as ``n sqrt(ke)`` (``omega_max`` ~ ``n sqrt(ke / m_total)``),
each substep costs ~ ``n^2``; ``C`` fitted to the measured symplectic Euler points; stars where an
implicit method's line crosses the trend, hollow where that crossing is extrapolated beyond the measured
ke, with the implicit cost held at its nearest measured value). The frame-cost runs of every ``(n, ke)``
are kept in ``results/stiff_regime/n<n>_ke<ke>/`` and their references cached as usual; the CSV, table and
plot are derived from every run kept there (``--fresh``: only this invocation's; ``--replot``: nothing run),
so sizes and stiffnesses run apart end up in one table and one plot.

Usage::

    export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 NUMBA_NUM_THREADS=1
    python -m benchmarks stiff-regime --sizes 32                 # ke 1e6 1e7 1e8
    python -m benchmarks stiff-regime --sizes 64 --ke 1e6 1e7
    python -m benchmarks stiff-regime --replot                   # table and plot from the kept runs
    python -m benchmarks stiff-regime --quick                    # n = 6, ke 1e6, 5 frames (tests)
"""

from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path

import numpy as np

from . import frame_cost, stiffness_sweep
from .common import RESULTS_DIR, fmt, markdown_table, pyplot, save_figure, write_csv

__all__ = ["COLUMNS", "DEFAULT_CANDIDATES", "DEFAULT_FRAMES", "TARGETS", "method_rows", "derive", "explicit_fit",
           "crossings", "main"]

#: Frames of the default window: the fall before the buckling (module docstring).
DEFAULT_FRAMES = 30
#: Error targets [m]: 1 cm and 5 cm.
TARGETS = (0.01, 0.05)
#: Implicit methods and steps tried at every (n, ke).
IMPLICIT_METHODS = ("implicit_euler", "bdf2", "tr_bdf2", "linearized_implicit")
STEP_RATES = (60, 120, 240, 480)
DEFAULT_CANDIDATES = tuple(f"{m}:{r}:auto" for m in IMPLICIT_METHODS for r in STEP_RATES)
QUICK_CANDIDATES = ("implicit_euler:60:direct", "tr_bdf2:60:direct", "linearized_implicit:120:direct")

COLUMNS = ["n", "ke", "damping", "frames", "target", "method", "config", "reached", "decidable", "err_rms",
           "below_floor", "err_lower_bound", "cpu_per_frame_s", "cost_lower_bound", "ratio_to_se", "se_config",
           "se_err_rms", "se_cpu_per_frame_s", "newton_per_stage", "newton_per_step", "newton_failures",
           "failed_steps", "retaken_steps", "method_failed_steps", "method_retaken_steps", "floor", "ref_diffs", "ref_median_ratios", "se_substeps", "force_kernels",
           "load_start", "load_end"]


def _rows(path: Path) -> list[dict]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def _whole(r: dict) -> bool:
    """A run that covered the whole window (not stopped above the error limit, by the budget or a blow-up)."""
    return r.get("status") in ("within target", "above target")


def method_rows(summary: dict, runs: list[dict], target: float) -> list[dict]:
    """One row per method at ``target``: :func:`benchmarks.stiffness_sweep.best_per_method` on the runs with their
    status judged against ``target`` (a whole-window run is within it when its error, the floor if below it, is
    less), with the run's iteration counts, failed steps and the ratio to symplectic Euler at its limit."""
    judged = [{**r, "status": ("within target" if float(r["err_rms"]) < target else "above target")}
              if _whole(r) and r.get("err_rms", "") != "" else r for r in runs]
    se = next((r for r in runs if r["role"] == "explicit"), None)
    se_cpu = float(se["cpu_per_frame_s"]) if se and se.get("cpu_per_frame_s", "") != "" else float("nan")
    out = []
    for b in stiffness_sweep.best_per_method(summary, judged, target):
        run = next(r for r in runs if r["method"] == b["method"] and r["config"] == b["config"]
                   and r["role"] in ("explicit", "candidate"))
        extra = {k: _num(run.get(k, "")) for k in ("newton_per_stage", "newton_per_step", "newton_failures",
                                                    "failed_steps", "retaken_steps")}
        mine = [r for r in runs if r["method"] == b["method"] and r["role"] == "candidate"]
        counts = {f"method_{k}": sum(int(_num(r.get(k)) or 0) for r in mine) if mine else ""
                  for k in ("failed_steps", "retaken_steps")}
        out.append({**b, **extra, **counts, "below_floor": run.get("below_floor") == "True", "target": target, "damping": float(summary.get("damping") or 0.0),
                    "frames": int(summary["frames"]), "ratio_to_se": b["cpu_per_frame_s"] / se_cpu,
                    "se_config": se["config"] if se else "", "se_err_rms": se.get("err_rms", "") if se else "",
                    "se_cpu_per_frame_s": se_cpu, "ref_diffs": summary.get("ref_diffs", ""),
                    "ref_median_ratios": summary.get("ref_median_ratios", ""),
                    "load_start": summary.get("load_start", ""), "load_end": summary.get("load_end", "")})
    return out


def _num(v):
    """A CSV field as a number (int where it is one), ``""`` if empty."""
    if v in ("", None):
        return ""
    f = float(v)
    return int(f) if f.is_integer() and "." not in str(v) else f


def derive(run_dirs) -> list[dict]:
    """The rows of :func:`method_rows` at both targets for the frame-cost runs kept in ``run_dirs`` (those with
    both CSVs), sorted by n, ke, target, method."""
    rows = []
    for d in run_dirs:
        if not ((d / "frame_cost.csv").exists() and (d / "frame_cost_candidates.csv").exists()):
            continue
        runs = _rows(d / "frame_cost_candidates.csv")
        rows += [r for s in _rows(d / "frame_cost.csv") for t in TARGETS
                 for r in method_rows(s, [x for x in runs if x["n"] == s["n"]], t)]
    return sorted(rows, key=lambda r: (r["n"], r["ke"], r["damping"], r["target"], r["method"]))


def explicit_fit(rows: list[dict]) -> float:
    """``C`` of ``cpu_per_frame = C n^3 sqrt(ke)``, the geometric mean over symplectic Euler's rows (NaN if none)."""
    se = {(r["n"], r["ke"]): r["cpu_per_frame_s"] for r in rows if r["method"] == "symplectic_euler"}
    logs = [math.log(c / (n ** 3 * math.sqrt(ke))) for (n, ke), c in se.items() if c > 0 and math.isfinite(c)]
    return math.exp(sum(logs) / len(logs)) if logs else float("nan")


def crossings(rows: list[dict], C: float, target: float = TARGETS[0]) -> list[dict]:
    """Where each implicit method's CPU per frame within ``target`` equals the explicit trend ``C n^3 sqrt(ke)``.

    Per ``(n, method)``, over the stiffnesses where the method reached the target: between two consecutive ones
    where the sign of ``log(implicit) - log(trend)`` changes, log-log interpolated (``extrapolated`` False);
    else beyond the measured range, the implicit cost held at the nearest measured value (``extrapolated``
    True): ``ke = (cost / (C n^3))^2``. Returns dicts ``n``, ``method``, ``ke``, ``cpu_per_frame_s``,
    ``extrapolated``.
    """
    out = []
    if not (C > 0 and math.isfinite(C)):
        return out
    for n in sorted({r["n"] for r in rows}):
        for m in sorted({r["method"] for r in rows if r["n"] == n and r["method"] != "symplectic_euler"}):
            pts = sorted((r["ke"], r["cpu_per_frame_s"]) for r in rows
                         if r["n"] == n and r["method"] == m and r["target"] == target and r["reached"]
                         and r["decidable"] and not r.get("cost_lower_bound"))
            if not pts:
                continue
            trend = [C * n ** 3 * math.sqrt(k) for k, _ in pts]
            g = [math.log(c) - math.log(t) for (_, c), t in zip(pts, trend)]
            found = False
            for (k0, c0), (k1, c1), g0, g1 in zip(pts, pts[1:], g, g[1:]):
                if g0 == 0 or g0 * g1 < 0:
                    w = g0 / (g0 - g1)
                    lk = math.log(k0) + w * (math.log(k1) - math.log(k0))
                    lc = math.log(c0) + w * (math.log(c1) - math.log(c0))
                    out.append(dict(n=n, method=m, ke=math.exp(lk), cpu_per_frame_s=math.exp(lc), extrapolated=False))
                    found = True
                    break
            if not found:
                c = pts[0][1] if g[0] < 0 else pts[-1][1]  # implicit cheaper everywhere: the crossing is below
                out.append(dict(n=n, method=m, ke=(c / (C * n ** 3)) ** 2, cpu_per_frame_s=c, extrapolated=True))
    return out


def plot(rows: list[dict], out_png: Path, target: float = TARGETS[0]) -> bool:
    """CPU per frame within ``target`` against ke, one panel per n (module docstring)."""
    plt = pyplot()
    if plt is None:
        return False
    rows = [r for r in rows if r["target"] == target]
    if not rows:
        return False
    sizes = sorted({r["n"] for r in rows})
    methods = sorted({r["method"] for r in rows})
    colors = {m: f"C{k}" for k, m in enumerate(methods)}
    C = explicit_fit(rows)
    cross = crossings(rows, C, target)
    fig, axes = plt.subplots(1, len(sizes), figsize=(6.0 * len(sizes), 4.6), squeeze=False)
    for ax, n in zip(axes[0], sizes):
        here = [r for r in rows if r["n"] == n]
        kes = [r["ke"] for r in here] + [c["ke"] for c in cross if c["n"] == n]
        lo, hi = min(kes) / 2, max(kes) * 2
        for m in methods:
            rs = sorted((r for r in here if r["method"] == m), key=lambda r: r["ke"])
            if not rs:
                continue
            reached = [r for r in rs if r["reached"]]  # the line joins the configurations within the target
            ax.plot([r["ke"] for r in reached], [r["cpu_per_frame_s"] for r in reached], "-", color=colors[m], label=m)
            for r in rs:  # filled: within the target; hollow: the most accurate run, not within; x: undecidable
                marker = "^" if r.get("cost_lower_bound") else "o" if r["decidable"] else "x"
                ax.plot(r["ke"], r["cpu_per_frame_s"], marker, color=colors[m],
                        markerfacecolor=colors[m] if r["reached"] else "none")
        if math.isfinite(C):
            k = np.geomspace(lo, hi, 50)
            ax.plot(k, C * n ** 3 * np.sqrt(k), "k--", lw=1, label=f"explicit trend {C:.2g} n^3 sqrt(ke)")
        for c in (c for c in cross if c["n"] == n):
            ax.plot(c["ke"], c["cpu_per_frame_s"], "*", ms=13, color=colors[c["method"]],
                    markeredgecolor=colors[c["method"]] if c["extrapolated"] else "k",
                    markerfacecolor="none" if c["extrapolated"] else colors[c["method"]])
            ax.annotate(f"{c['ke']:.2g}", (c["ke"], c["cpu_per_frame_s"]), textcoords="offset points", xytext=(4, -11),
                        fontsize=7)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlim(lo, hi)
        ax.set_xlabel("structural and shear stiffness ke [N/m]")
        ax.set_ylabel("CPU s per 1/60 s frame")
        fr = sorted({r["frames"] for r in here})
        ax.set_title(f"cloth {n} x {n}, {'/'.join(map(str, fr))} frames: cheapest config within {target * 100:g} cm\n"
                     f"(filled; hollow: none within, the most accurate; x: floor above the target)\n"
                     f"star: crossing with the explicit trend (hollow: extrapolated)", fontsize=8)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7, loc="upper left")
    save_figure(fig, out_png, dpi=110)
    return True


def _err(r: dict) -> str:
    v = float(r["err_rms"])
    if str(r.get("below_floor")) == "True":
        return f"< {fmt(v)} (floor)"
    return ("> " if r.get("err_lower_bound") else "") + fmt(v)


def markdown(rows: list[dict]) -> str:
    """The tables of ``stiff_regime.md``: one per target, and where each implicit line crosses the explicit trend."""
    cols = ["n", "ke", "method", "config", "reached", "err", "cpu_per_frame_s", "ratio_to_se", "newton_per_stage",
            "newton_per_step", "failed_steps", "retaken_steps", "method_failed_steps", "method_retaken_steps", "floor",
            "load_start", "load_end"]
    parts = []
    for t in TARGETS:
        rs = sorted((r for r in rows if r["target"] == t), key=lambda r: (r["n"], r["ke"], r["method"]))
        if not rs:
            continue
        parts.append(f"### Within {t * 100:g} cm (RMS over particles, max over the window, against the reference)\n\n"
                     + markdown_table([{**r, "err": _err(r), "ke": f"{r['ke']:g}",
                                        "cpu_per_frame_s": ("> " if r.get("cost_lower_bound") else "")
                                        + fmt(r["cpu_per_frame_s"])} for r in rs], cols))
    C = explicit_fit(rows)
    cross = crossings(rows, C)
    if cross:
        parts.append(f"### Crossings with the explicit trend {C:.3g} n^3 sqrt(ke) CPU s per frame (1 cm)\n\n"
                     + markdown_table([{**c, "ke": f"{c['ke']:.3g}"} for c in cross],
                                      ["n", "method", "ke", "cpu_per_frame_s", "extrapolated"]))
    return "\n\n".join(parts) + "\n"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", type=int, nargs="*", default=[32, 64], help="cloth sizes n (default 32 64)")
    p.add_argument("--ke", type=float, nargs="*", default=[1e6, 1e7, 1e8],
                   help="structural and shear stiffnesses [N/m] (default 1e6 1e7 1e8)")
    p.add_argument("--frames", type=int, default=DEFAULT_FRAMES,
                   help=f"window: frames of 1/60 s from the release (default {DEFAULT_FRAMES}, before the buckling)")
    p.add_argument("--damping", type=float, default=0.0, help="spring damping [N s/m] (default 0: undamped)")
    p.add_argument("--candidates", nargs="*", default=list(DEFAULT_CANDIDATES),
                   help="implicit configurations method:1/h:solver (default: %s)" % " ".join(DEFAULT_CANDIDATES))
    p.add_argument("--budget", type=float, default=3600.0, help="wall-time budget per (n, ke) [s] (default 3600)")
    p.add_argument("--cross-check-max-n", type=int, default=0,
                   help="cross-check the reference with solve_ivp up to this size (default 0: never)")
    p.add_argument("--force-kernels", default="auto", choices=("auto", "numba", "numpy"),
                   help="force evaluation of the measured runs (frame-cost's option; default auto)")
    p.add_argument("--fresh", action="store_true",
                   help="tabulate only this run's (n, ke), not every frame-cost run kept in results/stiff_regime/")
    p.add_argument("--replot", action="store_true",
                   help="run nothing: CSV, table and plot again from the frame-cost runs kept in results/stiff_regime/")
    p.add_argument("--quick", action="store_true", help="n = 6, ke 1e6, 5 frames, three candidates (tests)")
    p.add_argument("--out", type=Path, default=RESULTS_DIR)
    a = p.parse_args(argv)
    if a.quick:
        a.sizes, a.ke, a.frames = [6], [1e6], 5
        a.candidates = list(QUICK_CANDIDATES)
    if not a.sizes or not a.ke or any(not k > 0 for k in a.ke):
        p.error("--sizes and --ke: at least one each, stiffnesses > 0")
    kept = a.out / "stiff_regime"
    ran = []
    if not a.replot:
        for n in a.sizes:
            for ke in a.ke:
                d = kept / (f"n{n}_ke{ke:g}" + (f"_kd{a.damping:g}" if a.damping else ""))
                args = ["--ke", f"{ke:g}", "--sizes", str(n), "--measure-all", "--frames", str(a.frames),
                        "--damping", str(a.damping), "--target", str(TARGETS[0]), "--stop-above", str(TARGETS[-1]),
                        "--budget", str(a.budget), "--out", str(d), "--force-kernels", a.force_kernels,
                        "--cross-check-max-n", str(a.cross_check_max_n), "--candidates", *a.candidates]
                if a.quick:
                    args += ["--explicit-window", "0.05"]
                frame_cost.main(args)
                ran.append(d)
                rows = derive(ran if a.fresh else sorted(kept.iterdir()))
                write_csv(a.out / "stiff_regime.csv", rows, COLUMNS)  # a long run keeps its finished (n, ke)
    rows = derive(ran if a.fresh else sorted(kept.iterdir()) if kept.is_dir() else [])
    write_csv(a.out / "stiff_regime.csv", rows, COLUMNS)
    if not rows:
        p.error(f"no frame-cost runs in {kept}")
    md = markdown(rows)
    (a.out / "stiff_regime.md").write_text(md)
    print(md)
    if plot(rows, a.out / "stiff_regime.png"):
        print(f"plot: {a.out / 'stiff_regime.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
