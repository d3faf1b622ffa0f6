"""Shared helpers of the benchmark scripts: cases, reference cache, errors, energy, writers.

Every benchmark reports speed *and* error. Errors are position errors at the final
time, RMS and max over particles, divided by the scene's size ``L`` (the largest
extent of the initial positions, 1 m for the benchmark cloth). Energies are kinetic
plus every potential (:func:`springsim.run.energy.total_energy`), reported relative to ``E_scale = max(|E0|,
m_total |g| L, KE0)``. Results go to ``benchmarks/results/`` (git-ignored); plots
need matplotlib (``pip install 'springsim[plot]'``), tables do not.
"""

from __future__ import annotations

import csv
import hashlib
import os
import platform
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["RESULTS_DIR", "Case", "benchmark_case", "scene_case", "scene_cases", "SCENE_NAMES",
           "reference_final", "position_errors", "write_csv", "markdown_table",
           "have_matplotlib", "pyplot", "machine_info", "timed", "fit_order", "fmt"]

#: Output directory (git-ignored).
RESULTS_DIR = Path(__file__).resolve().parent / "results"

#: Shipped scenes the trajectory benchmark runs (besides the benchmark cloths).
SCENE_NAMES = ("spring", "stiff_chain", "three_body")


@dataclass
class Case:
    """One benchmark scene.

    Attributes
    ----------
    name : str
    model : Model
    size : float
        Scene size ``L`` [m] (largest extent of the initial positions).
    horizon : float
        Simulated time [s].
    state : State or None
        Initial state (None: ``model.state()``).
    """

    name: str
    model: object
    size: float
    horizon: float
    state: object = None


def _size(q) -> float:
    ext = float(np.max(np.ptp(np.asarray(q), axis=0))) if len(q) > 1 else 0.0
    return ext if ext > 0 else 1.0


def benchmark_case(n: int, horizon: float = 0.5) -> Case:
    """The ``n`` x ``n`` benchmark cloth (:func:`springsim.scene.benchmark_cloth`) falling for ``horizon`` s."""
    from springsim.scene import benchmark_cloth

    m = benchmark_cloth(n)
    return Case(f"cloth{n}", m, _size(m.particle_q), horizon)


def scene_case(name: str, horizon: float = 0.5) -> Case:
    """A shipped scene, ``scenes/<name>.yaml``."""
    from springsim.scene import load_scene

    model = load_scene(Path(__file__).resolve().parent.parent / "scenes" / f"{name}.yaml").model
    return Case(name, model, _size(model.particle_q), horizon)


def scene_cases(horizon: float = 0.5) -> list[Case]:
    """All :data:`SCENE_NAMES` as cases."""
    return [scene_case(n, horizon) for n in SCENE_NAMES]


def _model_key(model, t_end: float, method: str, rtol: float) -> str:
    h = hashlib.sha1()
    for name in ("particle_q", "particle_qd", "particle_mass", "particle_fixed", "particle_drag", "spring_indices",
                 "spring_stiffness", "spring_damping", "spring_rest_length", "gravitational_indices",
                 "gravitational_G"):
        h.update(np.ascontiguousarray(getattr(model, name)).tobytes())
    for name, a in model.data_beyond_v1():  # the data of other force terms (none for the built-in ones)
        h.update(name.encode())
        h.update(np.ascontiguousarray(a).tobytes())
    h.update(repr((float(model.gravity), model.up_axis, t_end, method, rtol)).encode())
    return h.hexdigest()[:16]


def reference_final(case: Case, *, method: str = "auto", rtol: float = 1e-10, cache: bool = True):
    """Reference state at ``case.horizon`` from :func:`springsim.analysis.reference.reference_trajectory`.

    ``method="auto"`` uses Radau (implicit, sparse Jacobian) up to 600 DOFs and DOP853
    above (the benchmark cloths are only mildly stiff; the two agree to ~1e-14 m on the
    8 x 8 cloth, see benchmarks/notes/2026-12-05-speed-vs-error.md). Results are cached in ``benchmarks/results/ref/``.

    Returns
    -------
    q, qd : ndarray (N, 3)
        Positions [m] and velocities [m/s] at the final time.
    seconds : float
        Wall time of the reference solve (0 when cached).
    method : str
    """
    from springsim.analysis.reference import reference_trajectory

    if method == "auto":
        method = "Radau" if 3 * case.model.free_particles.size <= 600 else "DOP853"
    key = _model_key(case.model, case.horizon, method, rtol)
    path = RESULTS_DIR / "ref" / f"{case.name}_{key}.npz"
    if cache and path.exists():
        d = np.load(path)
        return d["q"], d["qd"], 0.0, method
    atol = 1e-12 * max(case.size, 1e-3)
    ref = reference_trajectory(case.model, [0.0, case.horizon], state=case.state, method=method, rtol=rtol,
                               atol=atol)
    if cache:
        path.parent.mkdir(parents=True, exist_ok=True)
        from springsim.run.driver import save_npz_atomic

        save_npz_atomic(path, q=ref.q[-1], qd=ref.qd[-1])
    return ref.q[-1], ref.qd[-1], ref.wall_s, method


def position_errors(q: np.ndarray, q_ref: np.ndarray, size: float) -> tuple[float, float]:
    """RMS and max over particles of ``|q - q_ref|``, divided by ``size``; inf if not finite.

    Parameters
    ----------
    q, q_ref : ndarray (N, 3)
        Positions [m].
    size : float
        Scene size [m].
    """
    with np.errstate(over="ignore", invalid="ignore"):
        d = np.linalg.norm(np.asarray(q, dtype=np.float64) - q_ref, axis=1)
        if not np.all(np.isfinite(d)):
            return float("inf"), float("inf")
        return float(np.sqrt(np.mean(d**2)) / size), float(np.max(d) / size)


def timed(fn, *args, **kwargs):
    """Call ``fn`` and return ``(result, seconds)``."""
    t0 = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - t0


def fit_order(dts, errs, points: int = 3) -> float:
    """Observed order: slope of log(err) against log(dt) over the ``points`` smallest steps.

    Only finite errors above 1e-12 count; NaN if fewer than two remain.
    """
    dts = np.asarray(dts, dtype=np.float64)
    errs = np.asarray(errs, dtype=np.float64)
    ok = np.isfinite(errs) & (errs > 1e-12) & (errs < 0.5)
    dts, errs = dts[ok], errs[ok]
    if dts.size < 2:
        return float("nan")
    order = np.argsort(dts)[:points]
    return float(np.polyfit(np.log(dts[order]), np.log(errs[order]), 1)[0])


def fmt(v) -> str:
    """Compact string for tables (floats in 3 significant digits)."""
    if isinstance(v, (float, np.floating)):
        if not np.isfinite(v):
            return str(v)
        if v == 0:
            return "0"
        return f"{v:.3g}" if 1e-3 <= abs(v) < 1e4 else f"{v:.2e}"
    return str(v)


def _as_dicts(rows, columns) -> list[dict]:
    return [r if isinstance(r, dict) else dict(zip(columns, r)) for r in rows]


def write_csv(path, rows: list, columns: list[str]) -> None:
    """Write ``rows`` (dicts, or sequences in ``columns`` order) to ``path`` with the given column order."""
    rows = _as_dicts(rows, columns)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=columns, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({c: r.get(c, "") for c in columns})


def markdown_table(rows: list, columns: list[str]) -> str:
    """A GitHub markdown table of ``rows`` (dicts, or sequences in ``columns`` order) restricted to ``columns``."""
    rows = _as_dicts(rows, columns)
    lines = ["| " + " | ".join(columns) + " |", "|" + "|".join("---" for _ in columns) + "|"]
    for r in rows:
        lines.append("| " + " | ".join(fmt(r.get(c, "")) for c in columns) + " |")
    return "\n".join(lines)


def have_matplotlib() -> bool:
    """Whether matplotlib can be imported."""
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        return False
    return True


def pyplot():
    """matplotlib.pyplot with the non-interactive Agg backend, or None without matplotlib."""
    if not have_matplotlib():
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, out_png, dpi: int) -> None:
    """Lay out ``fig``, write it to ``out_png`` (creating the folder) and close it."""
    fig.tight_layout()
    Path(out_png).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_png, dpi=dpi)
    pyplot().close(fig)


def machine_info() -> dict:
    """CPU model, core count, RAM and library versions of this machine."""
    import numpy
    import scipy

    cpu = platform.processor() or "unknown"
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    ram = "unknown"
    try:
        with open("/proc/meminfo") as fh:
            kb = int(fh.readline().split()[1])
            ram = f"{kb / 2**20:.1f} GiB"
    except (OSError, ValueError, IndexError):
        pass
    info = {"cpu": cpu, "nproc": os.cpu_count(), "ram": ram, "python": platform.python_version(),
            "numpy": numpy.__version__, "scipy": scipy.__version__}
    try:
        import pyamg

        info["pyamg"] = pyamg.__version__
    except ImportError:
        info["pyamg"] = "not installed"
    return info
