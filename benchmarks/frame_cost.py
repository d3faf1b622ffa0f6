"""Time per 1/60 s frame at 1 cm RMS, next to explicit symplectic Euler.

Caution: the error here is against the same method at a smaller step (below), which understates the
error against the true motion once the cloth buckles (BENCHMARKS.md, section 8); errors against a
validated reference of the ODE are measured by ``speed-vs-error`` and ``accuracy``.

For each cloth size ``n`` (default 128 256 512) on the accuracy cloth
``benchmark_cloth(n, ke=1e3, ke_shear=1e3, ke_bend=1e2)`` (1 m, 1 kg, edge y = 0 pinned,
released horizontal at rest, undamped):

1. **Explicit limit.** ``omega_max^2`` = largest eigenvalue of ``M^-1 K`` (``K = -dF/dq``,
   exact Jacobian, free DOFs) from a plain Lanczos run on ``M^-1/2 K M^-1/2`` with the sparse
   matrix springsim's :class:`~springsim.assembly.SystemAssembler` assembles (no dense
   matrices), at the initial state and at a deformed one (the end of the finest implicit
   reference run, i.e. the cloth after ``T_w`` of its fall); the Gershgorin bound is printed
   beside it. Symplectic Euler is stable for ``h < 2 / omega_max``, so a 1/60 s frame needs
   ``S = ceil(omega_max / (2 * 60))`` substeps. This is then **verified** by running
   ``symplectic_euler`` at ``S`` substeps per frame (must stay finite with bounded energy) and
   at ``floor(0.7 S)`` (must blow up or gain energy) for a short window (``--explicit-window``,
   capped at ``--explicit-max-steps`` substeps). If ``S`` itself fails, the count is raised by
   10 % until a run passes, and the verified count is the one reported. Wall time per frame =
   ``S`` times the measured time per substep.
2. **Implicit candidates** (``--candidates``, ``method:1/h:solver``): each is first run for
   ``--probe-steps`` steps (a throw-away run) to estimate its cost per frame, then candidates are
   run from t = 0 over the window ``T_w`` (``--window``) in order of that estimate. A candidate's
   error is the RMS over particles of its position error at ``T_w`` against a reference of the
   **same method** with a ``--ref-ratio`` times smaller step (tight Newton and linear tolerances;
   references are cached per method, and a finer one serves every coarser candidate; for a
   first-order method the measured error is ~(1 - 1/ratio) of the true one, for second order
   ~(1 - 1/ratio^2)). The first candidate below ``--target`` (1 cm) is the provisional winner;
   candidates whose probe is cheaper than its measured cost are still run, and the cheapest
   passing one is reported. Candidates or references whose estimated cost exceeds the size's
   remaining ``--budget`` are skipped (status says so); if none could be measured, the row
   reports the cheapest probe with its error left empty.
3. Prints a table (n, DOFs, cheapest config, its h, error, wall s per frame, symplectic Euler
   substeps and wall s per frame) and writes ``results/frame_cost.csv`` (summary),
   ``results/frame_cost_candidates.csv`` (every candidate and reference) and
   ``results/frame_cost.md`` (``--append`` keeps other sizes' rows).

Costs per frame are measured over the stepping loops (integrator construction, i.e. the
symbolic assembly, excluded; AMG setups during steps included), as wall time
(``time.perf_counter``) and as this process's CPU time (``time.process_time``). On the shared
machine the wall time depends on the other jobs (the load average is recorded with every
size); the single-threaded CPU time does much less, so "cheapest" is decided on CPU time.

Usage::

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python -m benchmarks frame-cost            # n = 128 256 512
    python -m benchmarks frame-cost --sizes 128 --window 0.25 --ref-ratio 8
    python -m benchmarks frame-cost --quick                                            # n = 6 (tests)
"""

from __future__ import annotations

import argparse
import csv
import gc
import math
import os
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from springsim.energy import total_energy

from .common import RESULTS_DIR, machine_info, markdown_table, write_csv

__all__ = ["COLUMNS", "CANDIDATE_COLUMNS", "DEFAULT_CANDIDATES", "FRAME_DT", "Candidate", "cloth",
           "reference_solver", "omega_max", "explicit_substeps", "run_symplectic",
           "verify_explicit", "parse_candidate", "main"]

#: Frame length [s].
FRAME_DT = 1.0 / 60.0

#: Columns of the summary CSV (one row per size).
COLUMNS = ["n", "dofs", "config", "method", "solver", "h", "steps_per_frame", "err_rms", "ref_h", "window_s",
           "wall_per_frame_s", "cpu_per_frame_s", "newton_per_step", "linear_per_step", "newton_failures",
           "se_substeps", "se_h", "se_wall_per_frame_s", "se_cpu_per_frame_s", "se_wall_per_substep_s", "se_stable",
           "se_window_s", "se_lower_substeps", "se_lower_unstable", "se_lower_detected_at_s", "omega_max",
           "omega_initial", "omega_deformed", "omega_gershgorin", "lanczos_steps", "substeps_computed", "load_start",
           "load_end", "status"]

#: Columns of the per-candidate CSV (candidates and references).
CANDIDATE_COLUMNS = ["n", "role", "config", "method", "solver", "h", "steps", "probe_frame_s",
                     "probe_cpu_frame_s", "wall_s", "wall_per_frame_s", "cpu_per_frame_s", "err_rms", "ref_h",
                     "newton_per_step", "linear_per_step", "newton_failures", "status"]

#: Default candidates, ``method:1/h:solver``.
DEFAULT_CANDIDATES = ("linearized_implicit:60:auto", "linearized_implicit:120:auto",
                      "linearized_implicit:240:auto", "implicit_euler:60:auto",
                      "bdf2:60:auto", "bdf2:120:auto", "tr_bdf2:60:auto", "tr_bdf2:120:auto", "tr_bdf2:240:auto",
                      "tr_bdf2:240:cg")


def cloth(n: int):
    """:func:`springsim.scene.gallery.accuracy_cloth`."""
    from springsim.scene.gallery import accuracy_cloth

    return accuracy_cloth(n)


# -- explicit stability limit -----------------------------------------------------------------------------------
def omega_max(assembler, q, qd=None, **kw) -> dict:
    """:func:`springsim.analysis.max_frequency` (the largest natural angular frequency at ``(q, qd)``)."""
    from springsim.analysis import max_frequency

    return max_frequency(assembler, q, qd, **kw)


def explicit_substeps(omega: float, frame_dt: float = FRAME_DT) -> int:
    """:func:`springsim.analysis.explicit_substeps` at the frame rate of this benchmark."""
    from springsim.analysis import explicit_substeps as substeps

    return substeps(omega, frame_dt)


def run_symplectic(model, substeps: int, *, window: float, max_steps: int | None = None,
                   frame_dt: float = FRAME_DT, check_every: int = 10, growth_tol: float = 0.1,
                   perturb: float = 1e-6, seed: int = 0) -> dict:
    """Run ``symplectic_euler`` at ``substeps`` per frame for ``window`` seconds (at most ``max_steps`` steps).

    The free particles start displaced by Gaussian noise of ``perturb`` metres (seeded), so every
    mode, the stiffest included, starts excited well above round-off: an unstable step then shows
    within a few dozen steps instead of after the hundreds a round-off seed needs.

    Stability check every ``check_every`` steps and at the end: the state must be finite and
    the total energy (kinetic + spring + gravity) must not exceed its initial value by more
    than ``growth_tol * m_total |g| L`` (L = 1 m, the cloth size; 0.98 J for the 1 kg cloth).
    Stops at the first failed check.

    Returns
    -------
    dict
        ``stable``, ``steps`` (run), ``h``, ``window_s`` (simulated), ``wall_per_substep_s``,
        ``energy_gain`` [J] (largest ``E - E0`` seen), ``detected_at_s`` (time of the failed check,
        NaN if stable).
    """
    from springsim.forces import make_force_terms
    from springsim.integrators import make_integrator

    h = frame_dt / substeps
    steps = max(1, int(round(window / h)))
    if max_steps is not None:
        steps = max(1, min(steps, int(max_steps)))
    integ = make_integrator("symplectic_euler", model)
    terms = make_force_terms(model, skip_fixed=False)
    s0, s1 = model.state(), model.state()
    free = model.free_particles
    s0.particle_q[free] += perturb * np.random.default_rng(seed).standard_normal((free.size, 3))
    e0 = total_energy(model, s0.particle_q, s0.particle_qd, terms)
    scale = float(np.sum(model.particle_mass)) * abs(float(model.gravity)) * 1.0
    gain, detected, k = 0.0, float("nan"), 0
    wall = cpu = 0.0
    with np.errstate(over="ignore", invalid="ignore"):
        for k in range(1, steps + 1):
            t0, c0 = time.perf_counter(), time.process_time()
            integ.step(s0, s1, h)
            wall += time.perf_counter() - t0
            cpu += time.process_time() - c0
            s0, s1 = s1, s0
            if k % check_every == 0 or k == steps:
                e = total_energy(model, s0.particle_q, s0.particle_qd, terms) if s0.is_finite() else float("inf")
                gain = max(gain, e - e0) if np.isfinite(e) else float("inf")
                if not gain <= growth_tol * scale:
                    detected = k * h
                    break
    return dict(stable=bool(np.isnan(detected)), steps=k, h=h, window_s=k * h, wall_per_substep_s=wall / max(k, 1),
                cpu_per_substep_s=cpu / max(k, 1), energy_gain=gain, detected_at_s=detected)


def verify_explicit(model, omega: float, *, window: float, max_steps: int | None, lower: float = 0.7,
                    frame_dt: float = FRAME_DT, max_raise: int = 5) -> dict:
    """Substeps from ``omega``, verified: stable at the count, unstable at ``floor(lower * count)``.

    If the computed count is unstable, it is raised by 10 % (up to ``max_raise`` times) until
    a run passes; ``substeps`` is the verified count, ``substeps_computed`` the one from omega.
    """
    computed = explicit_substeps(omega, frame_dt)
    S = computed
    for _ in range(max_raise + 1):
        run = run_symplectic(model, S, window=window, max_steps=max_steps, frame_dt=frame_dt)
        if run["stable"]:
            break
        S = max(S + 1, math.ceil(1.1 * S))
    low = max(1, math.floor(lower * S))
    low_run = run_symplectic(model, low, window=window, max_steps=max_steps, frame_dt=frame_dt) if low < S else None
    return dict(substeps=S, substeps_computed=computed, h=frame_dt / S, stable=run["stable"],
                window_s=run["window_s"], wall_per_substep_s=run["wall_per_substep_s"],
                wall_per_frame_s=S * run["wall_per_substep_s"], cpu_per_frame_s=S * run["cpu_per_substep_s"],
                energy_gain=run["energy_gain"],
                lower_substeps=low, lower_unstable=(None if low_run is None else not low_run["stable"]),
                lower_detected_at_s=(float("nan") if low_run is None else low_run["detected_at_s"]))


# -- implicit candidates ------------------------------------------------------------------------------------------
@dataclass
class Candidate:
    """An implicit configuration: integrator name, step ``1/hinv`` [s], linear solver."""

    method: str
    hinv: float
    solver: str

    @property
    def h(self) -> float:
        return 1.0 / self.hinv

    @property
    def label(self) -> str:
        return f"{self.method} h=1/{self.hinv:g} {self.solver}"


def parse_candidate(text: str) -> Candidate:
    """``method:1/h:solver`` (e.g. ``tr_bdf2:240:auto``) to a :class:`Candidate`; one-line errors name the field."""
    from springsim.integrators import INTEGRATORS
    from springsim.linsolve import LINEAR_SOLVERS

    parts = text.split(":")
    if len(parts) != 3:
        raise argparse.ArgumentTypeError(f"--candidates: expected method:1/h:solver, got {text!r}")
    method, hinv, solver = parts
    if method not in INTEGRATORS or not INTEGRATORS[method].implicit:
        raise argparse.ArgumentTypeError(f"--candidates: method must be an implicit integrator, got {method!r}")
    try:
        hv = float(hinv)
    except ValueError:
        hv = float("nan")
    if not (np.isfinite(hv) and hv > 0):
        raise argparse.ArgumentTypeError(f"--candidates: 1/h must be a positive number, got {hinv!r}")
    if solver not in LINEAR_SOLVERS:
        raise argparse.ArgumentTypeError(f"--candidates: unknown linear solver {solver!r}")
    return Candidate(method, hv, solver)


@dataclass
class Run:
    """A stepping run that can be advanced in pieces (probe first, continue later)."""

    model: object
    method: str
    h: float
    solver: str
    options: dict
    integ: object = None
    s0: object = None
    s1: object = None
    steps: int = 0
    wall: float = 0.0
    cpu: float = 0.0
    stats: list = field(default_factory=list)

    def __post_init__(self):
        from springsim.integrators import INTEGRATORS, make_integrator

        opts = {k: v for k, v in self.options.items() if k not in INTEGRATORS[self.method].unused_options}
        so = dict(opts.pop("solver_options", {}) or {})
        if self.solver in ("direct", "dense"):
            so.pop("rtol", None)
        self.integ = make_integrator(self.method, self.model, solver=self.solver, solver_options=so,
                                     on_nonconvergence="ignore", **opts)
        self.s0, self.s1 = self.model.state(), self.model.state()

    def advance(self, k: int) -> bool:
        """Take ``k`` more steps; False if the state became non-finite."""
        with np.errstate(over="ignore", invalid="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for _ in range(k):
                t0, c0 = time.perf_counter(), time.process_time()
                st = self.integ.step(self.s0, self.s1, self.h)
                self.wall += time.perf_counter() - t0
                self.cpu += time.process_time() - c0
                self.stats.append(st)
                self.s0, self.s1 = self.s1, self.s0
                self.steps += 1
                if not self.s0.is_finite():
                    return False
        return True

    @property
    def step_s(self) -> float:
        return self.wall / max(self.steps, 1)

    def frame_s(self, frame_dt: float = FRAME_DT) -> float:
        """Wall time per frame [s]."""
        return self.step_s * frame_dt / self.h

    def frame_cpu(self, frame_dt: float = FRAME_DT) -> float:
        """CPU time (this process) per frame [s]."""
        return self.cpu / max(self.steps, 1) * frame_dt / self.h

    def summary(self) -> dict:
        s = self.stats
        k = max(len(s), 1)
        return dict(newton_per_step=sum(x.newton_iterations for x in s) / k,
                    linear_per_step=sum(x.linear_iterations for x in s) / k,
                    newton_failures=sum(not x.newton_converged for x in s))


#: Newton stage coefficient c / h of each implicit method (matrix M - c^2 dF/dq - c dF/dqd).
STAGE_COEFFICIENT = {"linearized_implicit": 1.0, "implicit_euler": 1.0, "bdf2": 2.0 / 3.0,
                     "tr_bdf2": 1.0 - 1.0 / math.sqrt(2.0)}


def reference_solver(choice: str, method: str, h: float, omega: float) -> str:
    """``choice``, or for ``pick``: ``cg`` (block Jacobi) when ``c omega <= 10`` (CG needs ~``c omega``
    iterations, fewer than an AMG setup costs), else ``auto``."""
    if choice != "pick":
        return choice
    return "cg" if STAGE_COEFFICIENT.get(method, 1.0) * h * omega <= 10.0 else "auto"


def _steps(window: float, h: float) -> int:
    return max(1, int(round(window / h)))


def rms(a: np.ndarray, b: np.ndarray) -> float:
    """RMS over particles of ``|a - b|`` [m] (inf if not finite)."""
    with np.errstate(over="ignore", invalid="ignore"):
        e = float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=-1))))
    return e if np.isfinite(e) else float("inf")


def _load() -> str:
    try:
        return "/".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:
        return "n/a"


def measure_size(n: int, a, log=print) -> tuple[dict, list[dict]]:
    """All measurements at one size; returns the summary row and the candidate rows."""
    from springsim.assembly import SystemAssembler
    from springsim.forces import make_force_terms

    load_start = _load()
    t_start = time.perf_counter()
    model = cloth(n)
    dofs = 3 * int(model.free_particles.size)
    log(f"n={n}: {dofs} DOFs, {model.spring_count} springs, load {load_start}")
    asm = SystemAssembler(model, make_force_terms(model))
    om0 = omega_max(asm, model.particle_q, model.particle_qd)
    log(f"  omega_max(initial) = {om0['omega']:.6g} rad/s ({om0['steps']} Lanczos steps; Gershgorin bound "
        f"{om0['gershgorin']:.6g}); substeps/frame {explicit_substeps(om0['omega'])}")

    window = a.window
    budget_end = t_start + a.budget
    cand_opts = dict(newton_maxiter=a.newton_maxiter, solver_options={"rtol": a.linear_rtol})
    ref_opts = dict(newton_maxiter=max(a.newton_maxiter, 20), newton_tol=a.ref_newton_tol,
                    solver_options={"rtol": a.ref_rtol})
    rows: list[dict] = []
    refs: dict[str, list] = {}  # method -> [(h_ref, final q)]

    def reference(method: str, h_need: float):
        """Final positions of the cached reference with h_ref <= h_need (finest), or a new one at h_need."""
        have = [r for r in refs.get(method, []) if r[0] <= h_need * (1 + 1e-9)]
        if have:
            return min(have, key=lambda r: r[0])
        if a.ref_h is not None and a.ref_h <= h_need:  # one finer reference serving several candidates
            h_need = a.ref_h
        steps = _steps(window, h_need)
        h_ref = window / steps
        solver = reference_solver(a.ref_solver, method, h_ref, om0["omega"])
        run = Run(model, method, h_ref, solver, ref_opts)
        ok = run.advance(min(a.probe_steps, steps))
        est = run.step_s * (steps - run.steps)
        row = dict(n=n, role="reference", config=f"{method} h={h_ref:.4g} {solver}", method=method,
                   solver=solver, h=h_ref, probe_frame_s=run.frame_s(), probe_cpu_frame_s=run.frame_cpu())
        if ok and time.perf_counter() + est > budget_end:
            rows.append({**row, "steps": run.steps, "wall_s": run.wall,
                         "status": f"skipped: estimated {est:.0f} s over the budget"})
            log(f"  reference {row['config']}: skipped (estimated {est:.0f} s, over budget)")
            return None
        ok = ok and run.advance(steps - run.steps)
        rows.append({**row, "steps": run.steps, "wall_s": run.wall, "wall_per_frame_s": run.frame_s(),
                     "cpu_per_frame_s": run.frame_cpu(), **run.summary(), "status": "ok" if ok else "blew up"})
        log(f"  reference {row['config']}: {run.steps} steps in {run.wall:.1f} s, {run.summary()}")
        if not ok:
            return None
        refs.setdefault(method, []).append((h_ref, run.s0.particle_q.copy()))
        del run
        gc.collect()
        return refs[method][-1]

    # probe every candidate (a throw-away run, so only one integrator, AMG hierarchy included, is alive)
    probes = []
    for c in a.candidates:
        steps = _steps(window, c.h)
        run = Run(model, c.method, window / steps, c.solver, cand_opts)
        ok = run.advance(min(a.probe_steps, steps))
        probes.append((c, steps, ok, run.step_s, run.frame_s(), run.frame_cpu()))
        log(f"  probe {c.label}: {run.step_s:.3g} s/step -> ~{run.frame_s():.3g} s/frame wall, "
            f"{run.frame_cpu():.3g} s/frame CPU{'' if ok else ' (blew up)'}")
        del run
        gc.collect()
    probes.sort(key=lambda x: (not x[2], x[5]))
    best = None
    for c, steps, ok, probe_step_s, probe_frame_s, probe_cpu in probes:
        row = dict(n=n, role="candidate", config=c.label, method=c.method, solver=c.solver, h=window / steps,
                   probe_frame_s=probe_frame_s, probe_cpu_frame_s=probe_cpu)
        if not ok:
            rows.append({**row, "status": "blew up in the probe"})
            continue
        if best is not None and probe_cpu >= best["cpu_per_frame_s"]:
            rows.append({**row, "status": "not run: probe slower than the cheapest passing"})
            continue
        est = probe_step_s * steps
        if time.perf_counter() + est > budget_end:
            rows.append({**row, "status": f"skipped: estimated {est:.0f} s over the budget"})
            log(f"  {c.label}: skipped (estimated {est:.0f} s, over budget)")
            continue
        run = Run(model, c.method, window / steps, c.solver, cand_opts)  # the measured run, from t = 0
        ok = run.advance(steps)
        r = {**row, "steps": run.steps, "wall_s": run.wall, "wall_per_frame_s": run.frame_s(),
             "cpu_per_frame_s": run.frame_cpu(), **run.summary()}
        if not ok:
            rows.append({**r, "status": "blew up"})
            continue
        ref = reference(c.method, run.h / a.ref_ratio)
        if ref is None:
            rows.append({**r, "status": "no reference (budget or blow-up)"})
            continue
        r.update(err_rms=rms(run.s0.particle_q, ref[1]), ref_h=ref[0])
        r["status"] = "ok, below target" if r["err_rms"] < a.target else "ok, above target"
        rows.append(r)
        del run
        gc.collect()
        log(f"  {c.label}: err {r['err_rms']:.3g} m, {r['wall_per_frame_s']:.3g} s/frame wall, "
            f"{r['cpu_per_frame_s']:.3g} CPU, Newton/step {r['newton_per_step']:.2f}, failures {r['newton_failures']}")
        if r["err_rms"] < a.target and (best is None or r["cpu_per_frame_s"] < best["cpu_per_frame_s"]):
            best = r

    # deformed state: end of the finest reference (the cloth after the window)
    finest = min((x for v in refs.values() for x in v), key=lambda x: x[0], default=None)
    omd = omega_max(asm, finest[1], np.zeros_like(finest[1])) if finest is not None else None
    if omd is not None:
        log(f"  omega_max(deformed, t={window:g} s) = {omd['omega']:.6g} rad/s ({omd['steps']} Lanczos steps)")
    om = max(om0["omega"], omd["omega"] if omd else 0.0)
    ex = verify_explicit(model, om, window=a.explicit_window, max_steps=a.explicit_max_steps, lower=a.lower)
    log(f"  symplectic Euler: {ex['substeps']} substeps/frame (computed {ex['substeps_computed']}), stable over "
        f"{ex['window_s']:.3g} s: {ex['stable']}; {ex['lower_substeps']} substeps: "
        f"{'unstable at t=%.3g s' % ex['lower_detected_at_s'] if ex['lower_unstable'] else 'stable'}; "
        f"{ex['wall_per_frame_s']:.3g} s/frame wall, {ex['cpu_per_frame_s']:.3g} CPU")
    summary = dict(n=n, dofs=dofs, window_s=window, se_substeps=ex["substeps"], se_h=ex["h"],
                   se_wall_per_frame_s=ex["wall_per_frame_s"], se_cpu_per_frame_s=ex["cpu_per_frame_s"],
                   se_wall_per_substep_s=ex["wall_per_substep_s"],
                   se_stable=ex["stable"], se_window_s=ex["window_s"], se_lower_substeps=ex["lower_substeps"],
                   se_lower_unstable=ex["lower_unstable"], se_lower_detected_at_s=ex["lower_detected_at_s"],
                   omega_max=om, omega_initial=om0["omega"], omega_deformed=omd["omega"] if omd else float("nan"),
                   omega_gershgorin=om0["gershgorin"], lanczos_steps=om0["steps"],
                   substeps_computed=ex["substeps_computed"], load_start=load_start, load_end=_load())
    if best is not None:
        summary.update({k: best[k] for k in ("config", "method", "solver", "h", "err_rms", "ref_h",
                                             "wall_per_frame_s", "cpu_per_frame_s", "newton_per_step",
                                             "linear_per_step",
                                             "newton_failures")},
                       steps_per_frame=FRAME_DT / best["h"], status="ok")
    else:
        measured = [r for r in rows if r["role"] == "candidate" and "err_rms" in r]
        closest = min(measured, key=lambda r: r["err_rms"], default=None)
        if closest is not None:
            summary.update(config="none below target", status=f"no candidate below the target (smallest error "
                                                               f"{closest['err_rms']:.3g} m: {closest['config']})")
        else:  # nothing fit the budget: report the cheapest probe, error not measured
            p0 = next((x for x in probes if x[2]), None)
            summary.update(config="none measured", status="no candidate fit the budget")
            if p0 is not None:
                c = p0[0]
                summary.update(config=f"probe only: {c.label}", method=c.method, solver=c.solver,
                               h=window / p0[1], steps_per_frame=FRAME_DT * p0[1] / window,
                               wall_per_frame_s=p0[4], cpu_per_frame_s=p0[5],
                               status=f"error not measured (budget); cost from a {min(a.probe_steps, p0[1])}-step "
                                      f"probe")
    return summary, rows


def _read_csv(path) -> list[dict]:
    """Rows of an earlier run's CSV (numbers parsed, empty fields dropped), [] if absent."""
    def parse(v: str):
        for kind in (int, float):
            try:
                return kind(v)
            except ValueError:
                pass
        return v

    if not Path(path).exists():
        return []
    with open(path, newline="") as fh:
        return [{k: parse(v) for k, v in r.items() if v != ""} for r in csv.DictReader(fh)]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", type=int, nargs="*", default=None, help="cloth sizes n (default 128 256 512)")
    p.add_argument("--candidates", type=parse_candidate, nargs="*", default=None,
                   help="implicit configurations method:1/h:solver (default: %s)" % " ".join(DEFAULT_CANDIDATES))
    p.add_argument("--window", type=float, default=0.25, help="simulated window T_w [s] (default 0.25)")
    p.add_argument("--target", type=float, default=0.01, help="RMS error target [m] (default 0.01)")
    p.add_argument("--ref-ratio", type=float, default=8.0, help="reference step = candidate step / this (default 8)")
    p.add_argument("--ref-h", type=float, default=None,
                   help="reference step [s] when it is at most candidate step / ratio (one reference then serves "
                        "several candidates; default: candidate step / ratio)")
    p.add_argument("--ref-solver", default="pick",
                   help="linear solver of the references (default pick: cg if c*omega_max <= 10, else auto)")
    p.add_argument("--ref-rtol", type=float, default=1e-10, help="linear rtol of the references")
    p.add_argument("--ref-newton-tol", type=float, default=1e-7, help="Newton tolerance of the references [m/s]")
    p.add_argument("--linear-rtol", type=float, default=1e-6, help="linear rtol of the candidates")
    p.add_argument("--newton-maxiter", type=int, default=20, help="Newton iteration limit of the candidates")
    p.add_argument("--probe-steps", type=int, default=2, help="steps of each candidate's cost probe")
    p.add_argument("--budget", type=float, default=1800.0, help="wall-time budget per size for the implicit part [s]")
    p.add_argument("--explicit-window", type=float, default=0.1, help="symplectic Euler verification window [s]")
    p.add_argument("--explicit-max-steps", type=int, default=2000, help="cap on verification substeps")
    p.add_argument("--lower", type=float, default=0.7, help="fraction of the substep count that must fail")
    p.add_argument("--append", action="store_true",
                   help="keep the rows of other sizes already in the output CSVs (a size run again is replaced)")
    p.add_argument("--quick", action="store_true", help="n = 6, short window, three candidates (tests)")
    p.add_argument("--out", type=Path, default=RESULTS_DIR)
    a = p.parse_args(argv)
    for name in ("window", "target", "ref_ratio", "budget", "explicit_window", "ref_h"):
        if name == "ref_h" and a.ref_h is None:
            continue
        if not getattr(a, name) > 0:
            p.error(f"--{name.replace('_', '-')} must be > 0, got {getattr(a, name)}")
    if not 0 < a.lower < 1:
        p.error(f"--lower must be in (0, 1), got {a.lower}")
    if a.quick:
        a.sizes = a.sizes or [6]
        a.window = 2 * FRAME_DT
        a.ref_ratio = 4.0
        a.explicit_window = 0.05
        a.candidates = a.candidates or [parse_candidate(x) for x in
                                        ("linearized_implicit:60:direct", "tr_bdf2:60:direct", "tr_bdf2:120:direct")]
        a.ref_solver = "direct"
    sizes = a.sizes or [128, 256, 512]
    a.candidates = a.candidates or [parse_candidate(x) for x in DEFAULT_CANDIDATES]
    a.out.mkdir(parents=True, exist_ok=True)
    info = machine_info()
    print(f"machine: {info}; threads: OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', 'unset')}, "
          f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}", flush=True)
    summaries, cand_rows = [], []
    if a.append:
        summaries = [r for r in _read_csv(a.out / "frame_cost.csv") if int(r["n"]) not in sizes]
        cand_rows = [r for r in _read_csv(a.out / "frame_cost_candidates.csv") if int(r["n"]) not in sizes]
    for n in sizes:
        s, rows = measure_size(n, a, log=lambda *x: print(*x, flush=True))
        summaries = sorted(summaries + [s], key=lambda r: r["n"])
        cand_rows = sorted(cand_rows + rows, key=lambda r: r["n"])
        write_csv(a.out / "frame_cost.csv", summaries, COLUMNS)  # a long run keeps its finished sizes
        write_csv(a.out / "frame_cost_candidates.csv", cand_rows, CANDIDATE_COLUMNS)
    table_cols = ["n", "dofs", "config", "h", "err_rms", "wall_per_frame_s", "cpu_per_frame_s", "se_substeps",
                  "se_wall_per_frame_s", "se_cpu_per_frame_s", "se_stable", "se_lower_substeps", "se_lower_unstable",
                  "load_start", "load_end"]
    md = (f"## Time per 1/60 s frame at {a.target:g} m RMS\n\nwindow {a.window:g} s, reference step = "
          f"h / {a.ref_ratio:g}\n\n" + markdown_table(summaries, table_cols) + "\n\n### Candidates\n\n"
          + markdown_table(cand_rows, CANDIDATE_COLUMNS) + "\n")
    (a.out / "frame_cost.md").write_text(md)
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
