"""CPU time per 1/60 s frame to stay within 1 cm of the true motion, against the cloth's stiffness, per method.

For every stiffness ``ke`` of ``--ke`` (structural and shear springs [N/m]; bending 1e2 N/m) and every size
of ``--sizes``, this runs :mod:`benchmarks.frame_cost` on ``benchmark_cloth(n, stiffness=ke)`` (its
protocol: error = RMS over particles, max over the frames of the window, against a validated Verlet
reference with its floor; symplectic Euler at its verified stability limit; the implicit candidates of
``--candidates``), then reports for each **method** the cheapest of its configurations whose error is
within ``--target``: symplectic Euler (at its limit), and each implicit integrator over the steps tried.
A method none of whose configurations gets within the target is shown as not reaching it, with its
smallest error. Where the reference's floor is not below the target, ``decidable`` is False: the
comparison with the target means nothing there. Writes ``results/stiffness_sweep.csv``, ``.md`` and, with matplotlib,
``results/stiffness_sweep.png`` (CPU per frame against ke, one line per method, log-log; hollow markers
where the method did not reach the target). The frame-cost runs of every ``(n, ke)`` are kept in
``results/stiffness_sweep/ke<ke>/`` and their references cached as usual. ``--merge`` joins the rows of
earlier sweeps (their ``stiffness_sweep.csv``, e.g. ``docs/stiffness_sweep.csv``, the data of the plot in
BENCHMARKS.md#stiffness-sweep) with this run's, which replace those of the same ``(n, ke, method, force_kernels)``, so that
sizes run apart end up in one table and one plot. ``--force-kernels`` is frame-cost's (default ``auto``:
the compiled spring force pass when numba is installed); each row records what its forces ran on, and
rows with compiled forces are their own lines in the plot ("(compiled forces)").

Usage::

    export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1
    python -m benchmarks stiffness-sweep --sizes 32 --ke 1e3 1e4 1e5 1e6
    python -m benchmarks stiffness-sweep --sizes 128 --ke 1e4 --merge docs/stiffness_sweep.csv
    python -m benchmarks stiffness-sweep --quick                 # n = 6, two stiffnesses (tests)
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

from . import frame_cost
from .common import RESULTS_DIR, fmt, markdown_table, pyplot, save_figure, write_csv

__all__ = ["COLUMNS", "DEFAULT_CANDIDATES", "best_per_method", "main"]

COLUMNS = ["n", "ke", "method", "config", "reached", "decidable", "err_rms", "cpu_per_frame_s", "floor", "se_substeps",
           "force_kernels", "err_lower_bound", "cost_lower_bound"]

#: Implicit configurations tried at every stiffness (``method:1/h:solver``).
DEFAULT_CANDIDATES = ("linearized_implicit:60:auto", "linearized_implicit:240:auto", "tr_bdf2:60:auto",
                      "tr_bdf2:120:auto", "tr_bdf2:240:auto")


def _rows(path: Path) -> list[dict]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def load(path: Path, target: float) -> list[dict]:
    """The rows of a ``stiffness_sweep.csv``, typed as :func:`best_per_method` gives them (rows written before
    the compiled force pass existed have ``force_kernels`` ``"numpy"``)."""
    return [{**r, "n": int(r["n"]), "ke": float(r["ke"]), "reached": r["reached"] == "True",
             "force_kernels": _kernels(r),
             "err_lower_bound": r.get("err_lower_bound") == "True",
             "cost_lower_bound": r.get("cost_lower_bound") == "True",
             "decidable": r["decidable"] == "True" if "decidable" in r else float(r["floor"]) < target,
             "err_rms": float(r["err_rms"]), "cpu_per_frame_s": float(r["cpu_per_frame_s"]),
             "floor": float(r["floor"])} for r in _rows(path)]


def _kernels(r: dict) -> str:
    """A row's force kernels; rows from before the column existed ran on numpy."""
    return r.get("force_kernels") or "numpy"


def _key(r: dict) -> tuple:
    return r["n"], r["ke"], r["method"], _kernels(r)


def merge(earlier: list[dict], rows: list[dict]) -> list[dict]:
    """``earlier`` and ``rows`` in one list, a row of ``rows`` replacing one of ``earlier`` with its
    ``(n, ke, method, force_kernels)``; sorted by n, method, force kernels, ke."""
    out = {_key(r): r for r in earlier}
    out.update({_key(r): r for r in rows})
    return sorted(out.values(), key=lambda r: (r["n"], r["method"], _kernels(r), r["ke"]))


def label(r: dict) -> str:
    """The plot's name of a row's line: the method, marked when its forces ran compiled."""
    return r["method"] + (" (compiled forces)" if _kernels(r) == "numba" else "")


def best_per_method(summary: dict, runs: list[dict], target: float) -> list[dict]:
    """One row per method: its cheapest configuration within ``target`` (or, if none, its smallest error among
    the runs that finished the window or stopped above the error limit; a run stopped by the budget, whose
    error covers only its first frames, only when the method has no other)."""
    out = []
    n, ke, floor = summary["n"], summary["ke"], summary["floor"]
    explicit = [r for r in runs if r["role"] == "explicit"]
    by_method: dict[str, list[dict]] = {}
    for r in explicit + [r for r in runs if r["role"] == "candidate" and r.get("err_rms")]:
        by_method.setdefault(r["method"], []).append(r)
    for method, rs in by_method.items():
        within = [r for r in rs if r["status"] == "within target"]
        if within:
            best, reached = min(within, key=lambda r: float(r["cpu_per_frame_s"])), True
        else:
            whole = [r for r in rs if r.get("cost_lower_bound") != "True"] or rs
            best, reached = min(whole, key=lambda r: float(r["err_rms"])), False
        out.append(dict(n=int(n), ke=float(ke), method=method, config=best["config"], reached=reached,
                        decidable=float(floor) < target,
                        err_rms=float(best["err_rms"]), cpu_per_frame_s=float(best["cpu_per_frame_s"]),
                        floor=float(floor), se_substeps=summary.get("se_substeps", ""),
                        force_kernels=_kernels(summary),
                        err_lower_bound=best.get("err_lower_bound") == "True",
                        cost_lower_bound=best.get("cost_lower_bound") == "True"))
    return out


def plot(rows: list[dict], out_png: Path, target: float) -> bool:
    plt = pyplot()
    if plt is None:
        return False
    sizes = sorted({r["n"] for r in rows})
    # one colour per method in every panel
    colors = {m: f"C{k}" for k, m in enumerate(sorted({label(r) for r in rows}))}
    fig, axes = plt.subplots(1, len(sizes), figsize=(5.5 * len(sizes), 4.2), squeeze=False)
    for ax, n in zip(axes[0], sizes):
        for method in sorted({label(r) for r in rows if r["n"] == n}):
            rs = sorted((r for r in rows if r["n"] == n and label(r) == method), key=lambda r: r["ke"])
            line, = ax.plot([r["ke"] for r in rs], [r["cpu_per_frame_s"] for r in rs], "-", label=method,
                            color=colors[method])
            for r in rs:  # ^: a cost that is a lower bound (the run stopped at the budget)
                marker = "^" if r.get("cost_lower_bound") else "o" if r["decidable"] else "x"
                ax.plot(r["ke"], r["cpu_per_frame_s"], marker, color=line.get_color(),
                        markerfacecolor=line.get_color() if r["reached"] else "none")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("structural and shear stiffness ke [N/m]")
        ax.set_ylabel("CPU s per 1/60 s frame")
        ax.set_title(f"cloth {n} x {n}: cheapest config within {target * 100:g} cm (filled); hollow: none\n"
                     f"within, the most accurate tried; x: reference floor above {target * 100:g} cm; ^: at least",
                     fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    save_figure(fig, out_png, dpi=110)
    return True


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", type=int, nargs="*", default=[32], help="cloth sizes n (default 32)")
    p.add_argument("--ke", type=float, nargs="*", default=[1e3, 1e4, 1e5, 1e6],
                   help="stiffnesses [N/m] (default 1e3 1e4 1e5 1e6)")
    p.add_argument("--candidates", nargs="*", default=list(DEFAULT_CANDIDATES),
                   help="implicit configurations method:1/h:solver (default: %s)" % " ".join(DEFAULT_CANDIDATES))
    p.add_argument("--target", type=float, default=0.01, help="RMS error target [m] (default 0.01)")
    p.add_argument("--frames", type=int, default=frame_cost.DEFAULT_FRAMES, help="frames of the window")
    p.add_argument("--budget", type=float, default=14400.0,
                   help="wall-time budget per size and stiffness [s] (default 14400: a sweep runs every candidate)")
    p.add_argument("--cross-check-max-n", type=int, default=None,
                   help="cross-check the references with solve_ivp at sizes up to this (default: frame-cost's; "
                        "0: never, the floor is then the Verlet levels' difference alone)")
    p.add_argument("--ref-levels", type=int, default=None,
                   help="reference levels, each halving the step (default: frame-cost's, 3; with 2, as used for the "
                        "largest cloths, the floor is the two levels' difference)")
    p.add_argument("--force-kernels", default="auto", choices=("auto", "numba", "numpy"),
                   help="force evaluation of the measured runs (frame-cost's option; default auto)")
    p.add_argument("--quick", action="store_true", help="n = 6, ke 1e3 1e4, two candidates, 20 frames (tests)")
    p.add_argument("--replot", action="store_true", help="only redraw the plot from the CSV of an earlier run")
    p.add_argument("--merge", type=Path, nargs="*", default=[], metavar="CSV",
                   help="join the rows of earlier sweeps' CSVs (this run's replace the same n, ke, method and "
                        "force kernels)")
    p.add_argument("--out", type=Path, default=RESULTS_DIR)
    a = p.parse_args(argv)
    if a.quick:
        a.sizes, a.ke, a.frames = [6], [1e3, 1e4], 20
        a.candidates = ["linearized_implicit:60:direct", "tr_bdf2:240:direct"]
    if not a.ke or any(not k > 0 for k in a.ke):
        p.error("--ke: every stiffness must be > 0")
    for path in a.merge:
        if not path.is_file():
            p.error(f"--merge: no such file: {path}")
    earlier = [r for path in a.merge for r in load(path, a.target)]
    if a.replot:
        rows = merge(earlier, load(a.out / "stiffness_sweep.csv", a.target))
        return 0 if plot(rows, a.out / "stiffness_sweep.png", a.target) else 1
    rows = []
    for ke in a.ke:
        d = a.out / "stiffness_sweep" / f"ke{ke:g}"
        args = ["--ke", f"{ke:g}", "--sizes", *map(str, a.sizes), "--measure-all", "--frames", str(a.frames),
                "--target", str(a.target), "--budget", str(a.budget), "--out", str(d), "--force-kernels",
                a.force_kernels, "--candidates", *a.candidates]
        if a.cross_check_max_n is not None:
            args += ["--cross-check-max-n", str(a.cross_check_max_n)]
        if a.ref_levels is not None:
            args += ["--ref-levels", str(a.ref_levels)]
        if a.quick:
            args += ["--explicit-window", "0.05"]
        frame_cost.main(args)
        runs = _rows(d / "frame_cost_candidates.csv")
        for s in _rows(d / "frame_cost.csv"):
            rows += best_per_method(s, [r for r in runs if r["n"] == s["n"]], a.target)
    rows = merge(earlier, rows)
    write_csv(a.out / "stiffness_sweep.csv", rows, COLUMNS)
    md = markdown_table([{**r, "err_rms": fmt(r["err_rms"]), "cpu_per_frame_s": fmt(r["cpu_per_frame_s"])}
                         for r in rows], COLUMNS)
    (a.out / "stiffness_sweep.md").write_text(md + "\n")
    print(md)
    if plot(rows, a.out / "stiffness_sweep.png", a.target):
        print(f"plot: {a.out / 'stiffness_sweep.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
