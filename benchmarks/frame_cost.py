"""Time per 1/60 s frame within 1 cm of the true motion, implicit candidates next to explicit symplectic Euler.

Every error here is measured against a **validated reference of the ODE**, never against the method
itself at a smaller step. For each cloth size ``n`` (default 32 64) on the accuracy cloth
``accuracy_cloth(n)`` = ``benchmark_cloth(n, ke=1e3, ke_shear=1e3, ke_bend=1e2)`` (1 m, 1 kg, edge
y = 0 pinned, released horizontal at rest, undamped), over a window of ``--frames`` frames of 1/60 s
from the release (default 70, i.e. 1.167 s: the fall, the buckling and the folds after it); ``--ke``
sets the structural and shear stiffness instead (``--ke 1e4`` is ``benchmark_cloth(n)`` itself), ``--damping``
gives every spring (structural, shear, bending) a damping [N s/m] (default 0; the reference's Verlet is
then first order in the damping force, which its floor reports):

1. **Reference** (:mod:`benchmarks.reference_cache`). Velocity Verlet (second order, symplectic; only
   the force evaluation is shared with springsim's integrators) at ``S_ref``, ``2 S_ref``, ``4 S_ref``
   substeps per frame (``--ref-levels``, default 3; ``S_ref`` = ``--ref-base`` (2) times the explicit
   substep count of step 2 at the initial state, or ``--ref-substeps``), positions recorded at every
   frame; the finest level is the reference. Its convergence is reported as the largest difference
   between consecutive levels (RMS over particles, max over frames) and the median over frames of the
   ratio of consecutive differences (4 for second order). At sizes up to ``--cross-check-max-n`` the
   finest level is also compared with :func:`springsim.analysis.reference.reference_trajectory` (scipy
   ``solve_ivp``: Radau with the sparse Jacobian up to 600 DOFs, DOP853 above, rtol 1e-10). The
   reference's **floor** is the larger of the two finest levels' difference and that cross-check
   difference: an error below it is not reported as a number but as ``< floor``, and a floor at or
   above ``--target`` makes the size undecidable (no winner). The levels and the cross-check are cached
   in ``results/frame_ref/`` keyed by case, method, substeps, frames and the model's fingerprint.
2. **Explicit limit.** ``omega_max^2`` = largest eigenvalue of ``M^-1 K`` (``K = -dF/dq``, exact
   Jacobian, free DOFs) from a plain Lanczos run on ``M^-1/2 K M^-1/2`` with the sparse matrix
   springsim's :class:`~springsim.assembly.SystemAssembler` assembles, at the initial state and at the
   reference's last frame; the Gershgorin bound is printed beside it. Symplectic Euler is stable for
   ``h < 2 / omega_max``, so a frame needs ``S = ceil(omega_max / (2 * 60))`` substeps. This is
   **verified** by running ``symplectic_euler`` from a state perturbed by 1e-6 m at ``S`` substeps per
   frame (must stay finite with bounded energy) and at ``floor(0.7 S)`` (must blow up or gain energy)
   for ``--explicit-window`` s (at most ``--explicit-max-steps`` substeps); if ``S`` fails it is raised
   by 10 % until a run passes. Then ``symplectic_euler`` at the verified ``S`` runs over the whole
   window from the unperturbed start, and its error and cost per frame are reported.
3. **Candidates** (``--candidates``, ``method:1/h:solver``; ``1/h`` a multiple of 60; explicit methods,
   ``verlet`` included, take the solver ``none``): each is probed for ``--probe-steps`` steps to
   estimate its cost, then run from t = 0 in order of that estimate. Its **error** is the RMS over
   particles of the position error against the reference at every frame, **max over the frames** of
   the window. A run stops early once that error exceeds ``--stop-above`` (default 5 cm; 0: never);
   its error is then a lower bound (``err_lower_bound``). The cheapest candidate (CPU time per frame)
   whose error is below ``--target`` (1 cm) wins. Unless ``--measure-all``, candidates whose probe is
   dearer than the cheapest passing one are not run; candidates whose estimated cost exceeds the
   size's remaining ``--budget`` are skipped (the status says which), and a candidate still running when
   the budget runs out stops at the end of that frame: its error is then a lower bound and its cost per
   frame is reported as the CPU time spent over the whole window's frames, also a lower bound
   (``cost_lower_bound``).
4. Prints a table and writes ``results/frame_cost.csv`` (one row per size), ``results/frame_cost_candidates.csv``
   (the reference levels, the cross-check, symplectic Euler and every candidate) and
   ``results/frame_cost.md`` (``--append`` keeps other sizes' rows).

Costs per frame are measured over the stepping loops only (integrator construction, i.e. the
symbolic assembly, excluded; AMG setups during steps included), as this process's CPU time
(``time.process_time``) and as wall time (``time.perf_counter``). On a shared machine the wall
time depends on the other jobs (the load average is recorded with every size); the single-threaded
CPU time much less, so "cheapest" is decided on CPU time. A run stopped early is costed over the
frames it ran (the early, pre-buckling frames, where Newton methods need fewer iterations).

Forces: ``--force-kernels`` (default ``auto``) chooses the force evaluation of symplectic Euler and the
candidates (:func:`springsim.forces.make_force_terms`: the compiled spring pass of the ``accel`` extra, or
``numpy``); the summary records what it resolved to (``force_kernels``). The reference levels always
use ``auto`` (the two passes give the same forces to round-off).

Usage::

    export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1
    python -m benchmarks frame-cost                                   # n = 32 64, default candidates
    python -m benchmarks frame-cost --sizes 128 --stop-above 0 --candidates linearized_implicit:120:auto
    python -m benchmarks frame-cost --quick                           # n = 6 (tests)
    python -m benchmarks frame-cost --sizes 64 --force-kernels numpy  # the pure force path
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

from springsim.run.energy import total_energy

from . import reference_cache
from .common import RESULTS_DIR, fmt, machine_info, markdown_table, write_csv

__all__ = ["COLUMNS", "CANDIDATE_COLUMNS", "DEFAULT_CANDIDATES", "DEFAULT_FRAMES", "FRAME_DT", "Candidate", "cloth",
           "force_kernels_used", "omega_max", "explicit_substeps", "run_symplectic", "verify_explicit",
           "parse_candidate", "Run", "make_run", "track_errors", "measure_size", "main"]

#: Frame length [s].
FRAME_DT = 1.0 / 60.0
#: Frames in the default window (1.167 s from the release).
DEFAULT_FRAMES = 70

#: Columns of the summary CSV (one row per size).
COLUMNS = ["n", "ke", "damping", "dofs", "frames", "window_s", "target", "ref_method", "ref_substeps", "ref_h", "ref_diffs",
           "ref_median_ratios", "ref_pair_diff", "xcheck_method", "xcheck_diff", "floor", "ref_usable", "ref_cpu_s",
           "config", "method", "solver", "h", "steps_per_frame", "err_rms", "below_floor", "err_frame",
           "wall_per_frame_s", "cpu_per_frame_s", "newton_per_step", "linear_per_step", "newton_failures",
           "se_substeps", "se_h", "se_err_rms", "se_below_floor", "se_err_frame", "se_wall_per_frame_s",
           "se_cpu_per_frame_s", "se_window_finite", "se_stable", "se_window_s", "se_lower_substeps",
           "se_lower_unstable", "se_lower_detected_at_s", "cpu_ratio_to_se", "omega_max", "omega_initial",
           "omega_deformed", "omega_gershgorin", "lanczos_steps", "substeps_computed", "force_kernels", "load_start",
           "load_end", "status"]

#: Columns of the per-run CSV (reference levels, cross-check, symplectic Euler, candidates).
CANDIDATE_COLUMNS = ["n", "role", "config", "method", "solver", "h", "steps_per_frame", "steps", "frames_run",
                     "probe_frame_s", "probe_cpu_frame_s", "wall_s", "cpu_s", "wall_per_frame_s", "cpu_per_frame_s",
                     "cost_lower_bound", "err_rms", "below_floor", "err_lower_bound", "err_frame", "err_final",
                     "err_raw", "floor", "diff_to_next", "newton_per_step", "newton_per_stage", "linear_per_step",
                     "newton_failures", "failed_steps", "retaken_steps", "status"]

#: Default candidates, ``method:1/h:solver``.
DEFAULT_CANDIDATES = ("linearized_implicit:60:auto", "linearized_implicit:120:auto", "linearized_implicit:240:auto",
                      "linearized_implicit:480:auto", "implicit_euler:60:auto", "implicit_euler:240:auto",
                      "bdf2:60:auto", "bdf2:240:auto", "tr_bdf2:60:auto", "tr_bdf2:120:auto", "tr_bdf2:240:auto",
                      "tr_bdf2:480:auto")

#: Candidates of ``--quick``.
QUICK_CANDIDATES = ("linearized_implicit:60:direct", "tr_bdf2:60:direct", "tr_bdf2:240:direct")


def cloth(n: int, ke: float | None = None, damping: float = 0.0):
    """:func:`springsim.scene.gallery.accuracy_cloth` (``ke`` None), else :func:`~springsim.scene.benchmark_cloth`
    with structural and shear springs of ``ke`` N/m (bending 1e2 N/m as in both; ``ke = 1e4`` is the benchmark cloth).
    ``damping`` > 0: every spring (structural, shear, bending) gets that damping [N s/m] (``benchmark_cloth``'s
    ``damping``; with ``ke`` None the accuracy cloth's stiffnesses)."""
    from springsim.scene.gallery import accuracy_cloth, benchmark_cloth

    if ke is None and not damping:
        return accuracy_cloth(n)
    ke = 1e3 if ke is None else ke
    return benchmark_cloth(n, stiffness=ke, stiffness_shear=ke, stiffness_bend=1e2, damping=float(damping))


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


# -- candidates -----------------------------------------------------------------------------------------------------
@dataclass
class Candidate:
    """A configuration: integrator name (or ``verlet``), step ``1/hinv`` [s], linear solver (``none`` if explicit),
    and integrator options (``(name, value)`` pairs, e.g. ``(("forcing", "eisenstat-walker"),)``)."""

    method: str
    hinv: float
    solver: str
    options: tuple = ()

    @property
    def h(self) -> float:
        return 1.0 / self.hinv

    @property
    def steps_per_frame(self) -> int:
        return max(1, int(round(self.hinv * FRAME_DT)))

    @property
    def implicit(self) -> bool:
        from springsim.integrators import INTEGRATORS

        return self.method in INTEGRATORS and INTEGRATORS[self.method].implicit

    @property
    def label(self) -> str:
        return (f"{self.method} h=1/{self.hinv:g}" + (f" {self.solver}" if self.solver != "none" else "")
                + "".join(f" {k}={v}" for k, v in self.options))


def parse_candidate(text: str) -> Candidate:
    """``method:1/h:solver[:name=value,...]`` (e.g. ``tr_bdf2:240:auto``, ``symplectic_euler:2880:none``,
    ``tr_bdf2:120:auto:forcing=eisenstat-walker``) to a :class:`Candidate`.

    ``1/h`` must be a whole multiple of the frame rate (60); implicit methods take a registered linear
    solver, explicit ones (and ``verlet``) ``none``; the optional fourth field gives integrator options
    (``true``/``false`` as booleans, numbers where they parse as numbers, else strings; ``solver_X=v`` is the
    linear solver's option ``X``, e.g. ``solver_reuse_factors=8``). Errors are one line naming the field.
    """
    from springsim.integrators import INTEGRATORS
    from springsim.linsolve import LINEAR_SOLVERS

    parts = text.split(":")
    if len(parts) not in (3, 4):
        raise argparse.ArgumentTypeError(f"--candidates: expected method:1/h:solver[:name=value,...], got {text!r}")
    method, hinv, solver = parts[:3]
    options = []
    for item in (parts[3].split(",") if len(parts) == 4 else []):
        name, eq, value = item.partition("=")
        if not eq or not name.isidentifier():
            raise argparse.ArgumentTypeError(f"--candidates: expected name=value options, got {item!r}")
        if value.lower() in ("true", "false"):
            value = value.lower() == "true"
        else:
            try:
                value = float(value) if any(ch in value for ch in ".eE") else int(value)
            except ValueError:
                pass
        options.append((name, value))
    if method not in INTEGRATORS and method != "verlet":
        raise argparse.ArgumentTypeError(f"--candidates: unknown method {method!r} (an integrator or verlet)")
    try:
        hv = float(hinv)
    except ValueError:
        hv = float("nan")
    if not (np.isfinite(hv) and hv > 0):
        raise argparse.ArgumentTypeError(f"--candidates: 1/h must be a positive number, got {hinv!r}")
    spf = hv * FRAME_DT
    if round(spf) < 1 or abs(spf - round(spf)) > 1e-9 * spf:
        raise argparse.ArgumentTypeError(f"--candidates: 1/h must be a whole multiple of the frame rate 60, "
                                         f"got {hinv!r}")
    implicit = method in INTEGRATORS and INTEGRATORS[method].implicit
    if implicit and solver not in LINEAR_SOLVERS:
        raise argparse.ArgumentTypeError(f"--candidates: unknown linear solver {solver!r}")
    if not implicit and solver != "none":
        raise argparse.ArgumentTypeError(f"--candidates: explicit method {method!r} takes the solver 'none', "
                                         f"got {solver!r}")
    if options and not implicit:
        raise argparse.ArgumentTypeError(f"--candidates: options are for implicit methods, got {text!r}")
    return Candidate(method, hv, solver, tuple(options))


@dataclass
class Run:
    """An implicit integrator's run from the model's initial state, advanced in pieces (probe first, continue later)."""

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

        cls = INTEGRATORS[self.method]
        opts = {k: v for k, v in self.options.items() if k not in cls.unused_options}
        so = dict(opts.pop("solver_options", {}) or {})
        for k in [k for k in opts if k.startswith("solver_")]:  # solver_X=v: the linear solver's option X
            so[k[len("solver_"):]] = opts.pop(k)
        if self.solver in ("direct", "dense"):
            so.pop("rtol", None)
        if "newton_maxiter" in opts and opts["newton_maxiter"] is None:  # the integrator's default, at least 20
            opts["newton_maxiter"] = max(int(getattr(cls, "default_newton_maxiter", 20)), 20)
        self.integ = make_integrator(self.method, self.model, solver=self.solver, solver_options=so,
                                     on_nonconvergence="ignore", **opts)
        self.s0, self.s1 = self.model.state(), self.model.state()

    @property
    def positions(self) -> np.ndarray:
        return self.s0.particle_q

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

    def summary(self) -> dict:
        """Per step: Newton and Krylov iterations; per stage solve (retakes included): Newton iterations;
        steps whose Newton did not converge, steps not ``ok`` after their retakes, steps retaken in substeps."""
        s = self.stats
        k = max(len(s), 1)
        newton = sum(x.newton_iterations for x in s)
        stages = sum(x.extra.get("stages", 0) for x in s)
        return dict(newton_per_step=newton / k, newton_per_stage=newton / stages if stages else float("nan"),
                    linear_per_step=sum(x.linear_iterations for x in s) / k,
                    newton_failures=sum(not x.newton_converged for x in s), failed_steps=sum(not x.ok for x in s),
                    retaken_steps=sum("retaken" in x.extra for x in s))


def force_kernels_used(model, force_kernels: str) -> str:
    """What ``force_kernels`` resolves to on ``model``: ``"numba"`` when its spring forces run compiled, else
    ``"numpy"``. Evaluates the forces once, so that a compiled pass is loaded (or compiled) before any run
    is timed."""
    from springsim.forces import eval_forces, make_force_terms

    terms = make_force_terms(model, kernels=force_kernels)
    eval_forces(terms, model.particle_q, model.particle_qd)
    used = {getattr(t, "kernels", "numpy") for t in terms}
    return "numba" if "numba" in used else "numpy"


def make_run(model, cand: Candidate, options: dict):
    """A fresh run of ``cand`` from the initial state: :class:`Run` if implicit, else
    :func:`benchmarks.reference_cache.explicit_run` (``verlet`` or an explicit integrator)."""
    h = FRAME_DT / cand.steps_per_frame
    if cand.implicit:
        return Run(model, cand.method, h, cand.solver, {**options, **dict(cand.options)})
    return reference_cache.explicit_run(model, cand.method, h, options.get("force_kernels", "auto"))


def per_frame(run, seconds: float, frame_dt: float = FRAME_DT) -> float:
    """``seconds`` spent over ``run.steps`` steps, per frame of ``frame_dt``."""
    return seconds / max(run.steps, 1) * frame_dt / run.h


def rms(a: np.ndarray, b: np.ndarray) -> float:
    """RMS over particles of ``|a - b|`` [m] (inf if not finite)."""
    return float(reference_cache.frame_rms(a, b))


def track_errors(run, steps_per_frame: int, ref_q: np.ndarray, *, stop_above: float = 0.0,
                 deadline: float | None = None) -> dict:
    """Advance ``run`` frame by frame over the frames of ``ref_q`` (frames + 1, N, 3), error at every frame.

    ``deadline``: a ``time.perf_counter`` value; the run stops after the first frame that ends past it.

    Returns
    -------
    dict
        ``errors`` (frames + 1,) [m] (NaN after the last frame run), ``frames_run``, ``finite``, ``stopped``
        (True when the error exceeded ``stop_above`` > 0 and the run stopped there), ``out_of_time`` (True when
        it stopped at the deadline before the last frame), ``err_max`` (max over the frames run), ``err_frame``
        (its frame), ``err_final`` (error at the last frame, NaN unless reached).
    """
    frames = ref_q.shape[0] - 1
    errors = np.full(frames + 1, np.nan)
    errors[0] = rms(run.positions, ref_q[0])
    finite, stopped, out_of_time, k = True, False, False, 0
    for k in range(1, frames + 1):
        finite = run.advance(steps_per_frame)
        errors[k] = rms(run.positions, ref_q[k]) if finite else np.inf
        if not finite:
            break
        if stop_above > 0 and errors[k] > stop_above and k < frames:
            stopped = True
            break
        if deadline is not None and time.perf_counter() > deadline and k < frames:
            out_of_time = True
            break
    f = int(np.nanargmax(errors))
    return dict(errors=errors, frames_run=k, finite=finite, stopped=stopped, out_of_time=out_of_time,
                err_max=float(errors[f]), err_frame=f,
                err_final=float(errors[frames]) if k == frames and finite else float("nan"))


def _load() -> str:
    try:
        return "/".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:
        return "n/a"


def _floor_fields(err: float, floor: float, partial: bool = False) -> dict:
    """The reported error: never below the reference's floor (``err_rms = floor``, ``below_floor`` True then);
    ``partial`` (a run stopped before the end of the window): the error as measured, a lower bound."""
    below = bool(np.isfinite(err) and err < floor and not partial)
    return dict(err_rms=floor if below else err, below_floor=below, err_raw=err)


def _xcheck_method(model, choice: str) -> str:
    if choice != "auto":
        return choice
    return "Radau" if 3 * model.free_particles.size <= 600 else "DOP853"


def measure_size(n: int, a, log=print) -> tuple[dict, list[dict]]:
    """All measurements at one size; returns the summary row and the per-run rows."""
    from springsim.assembly import SystemAssembler
    from springsim.forces import make_force_terms

    load_start = _load()
    t_start = time.perf_counter()
    damping = getattr(a, "damping", 0.0)
    model = cloth(n, a.ke, damping)
    dofs = 3 * int(model.free_particles.size)
    frames = a.frames
    window = frames * FRAME_DT
    kernels = force_kernels_used(model, a.force_kernels)
    log(f"n={n}: {dofs} DOFs, {model.spring_count} springs, window {frames} frames ({window:.4g} s), "
        f"force kernels {kernels}, load {load_start}")
    asm = SystemAssembler(model, make_force_terms(model))
    om0 = omega_max(asm, model.particle_q, model.particle_qd)
    S0 = explicit_substeps(om0["omega"])
    log(f"  omega_max(initial) = {om0['omega']:.6g} rad/s ({om0['steps']} Lanczos steps; Gershgorin bound "
        f"{om0['gershgorin']:.6g}); explicit substeps/frame {S0}")
    rows: list[dict] = []
    cache = None if a.no_cache else a.cache_dir
    case = (f"accuracy_cloth{n}" if a.ke is None else f"cloth{n}_ke{a.ke:g}") + (f"_kd{damping:g}" if damping else "")

    # 1. the reference and its floor
    base = a.ref_substeps or a.ref_base * S0
    ref = reference_cache.refined_reference(model, base, a.ref_levels, frames, case=case, method=a.ref_method,
                                            cache_dir=cache, log=log)
    diffs, med = ref.diffs, ref.median_ratios
    for k, S in enumerate(ref.substeps):
        rows.append(dict(n=n, role="reference", config=f"{a.ref_method} {S} substeps/frame", method=a.ref_method,
                         solver="none", h=FRAME_DT / S, steps_per_frame=S, steps=S * frames, frames_run=frames,
                         cpu_s=ref.cpu_s[k], wall_s=ref.wall_s[k], cpu_per_frame_s=ref.cpu_s[k] / frames,
                         wall_per_frame_s=ref.wall_s[k] / frames,
                         diff_to_next=diffs[k] if k < len(diffs) else "",
                         status=("cached" if ref.cached[k] else "computed") + ("" if ref.finite else ", not finite")))
    log(f"  reference differences between levels (max over frames): {' '.join(f'{d:.3g}' for d in diffs)} m; "
        f"ratios of the maxima {' '.join(f'{r:.2f}' for r in ref.ratios)}; median ratios over frames "
        f"{' '.join(f'{r:.2f}' for r in med)}")
    xmethod, xdiff = "", float("nan")
    if n <= a.cross_check_max_n:
        xmethod = _xcheck_method(model, a.cross_check_method)
        x = reference_cache.cached_frames(model, xmethod, 0, frames, case=case, cache_dir=cache)
        xdiff = float(np.max(reference_cache.frame_rms(x["q"], ref.q))) if x["finite"] else float("inf")
        rows.append(dict(n=n, role="cross-check", config=f"solve_ivp {xmethod} rtol 1e-10", method=xmethod,
                         solver="none", frames_run=frames, cpu_s=x["cpu_s"], wall_s=x["wall_s"],
                         cpu_per_frame_s=x["cpu_s"] / frames, wall_per_frame_s=x["wall_s"] / frames,
                         err_raw=xdiff, status="cached" if x["cached"] else "computed"))
        how = "cached" if x["cached"] else "%.1f CPU s" % x["cpu_s"]
        log(f"  cross-check: solve_ivp {xmethod} vs the finest reference level: {xdiff:.3g} m (max over frames), "
            f"{how}")
        del x
    floor = ref.floor if np.isnan(xdiff) else max(ref.floor, xdiff)
    usable = bool(ref.finite and floor < a.target)
    log(f"  reference floor {floor:.3g} m ({'usable' if usable else 'NOT usable'} for a {a.target:g} m target)")
    summary = dict(n=n, ke=1e3 if a.ke is None else a.ke, damping=damping, dofs=dofs, frames=frames, window_s=window, target=a.target, ref_method=a.ref_method,
                   ref_substeps=ref.substeps[-1], ref_h=FRAME_DT / ref.substeps[-1],
                   ref_diffs=" ".join(f"{d:.3g}" for d in diffs), ref_median_ratios=" ".join(f"{r:.3g}" for r in med),
                   ref_pair_diff=ref.floor, xcheck_method=xmethod, xcheck_diff=xdiff if xmethod else "", floor=floor,
                   ref_usable=usable, ref_cpu_s=sum(ref.cpu_s), omega_initial=om0["omega"],
                   omega_gershgorin=om0["gershgorin"], lanczos_steps=om0["steps"], load_start=load_start,
                   force_kernels=kernels)

    def error_row(run, res, row):
        late = res.get("out_of_time", False)
        r = {**row, "steps": run.steps, "frames_run": res["frames_run"], "wall_s": run.wall, "cpu_s": run.cpu,
             # stopped at the budget: what it spent, spread over the whole window, is a lower bound of its cost
             "wall_per_frame_s": run.wall / frames if late else per_frame(run, run.wall),
             "cpu_per_frame_s": run.cpu / frames if late else per_frame(run, run.cpu), "cost_lower_bound": late,
             **_floor_fields(res["err_max"], floor, late), "err_lower_bound": res["stopped"] or late,
             "err_frame": res["err_frame"], "err_final": res["err_final"], "floor": floor, **run.summary()}
        if not res["finite"]:
            r["status"] = f"blew up at frame {res['frames_run']}"
        elif late:
            r["status"] = (f"stopped at frame {res['frames_run']}: over the budget (more than "
                           f"{r['cpu_per_frame_s']:.3g} CPU s per frame)")
        elif res["stopped"]:
            r["status"] = f"stopped at frame {res['frames_run']}: error above {a.stop_above:g} m"
        else:
            r["status"] = "within target" if r["err_rms"] < a.target else "above target"
        return r

    # 2. the explicit limit, verified, and symplectic Euler over the window
    omd = omega_max(asm, ref.q[-1], np.zeros_like(ref.q[-1])) if ref.finite else None
    if omd is not None:
        log(f"  omega_max(reference at frame {frames}) = {omd['omega']:.6g} rad/s ({omd['steps']} Lanczos steps)")
    om = max(om0["omega"], omd["omega"] if omd else 0.0)
    ex = verify_explicit(model, om, window=a.explicit_window, max_steps=a.explicit_max_steps, lower=a.lower)
    se_cand = Candidate("symplectic_euler", ex["substeps"] / FRAME_DT, "none")
    se_run = make_run(model, se_cand, {"force_kernels": a.force_kernels})
    se = track_errors(se_run, ex["substeps"], ref.q)
    se_row = error_row(se_run, se, dict(n=n, role="explicit", config=se_cand.label, method=se_cand.method,
                                        solver="none", h=se_run.h, steps_per_frame=ex["substeps"]))
    rows.append(se_row)
    log(f"  symplectic Euler: {ex['substeps']} substeps/frame (computed {ex['substeps_computed']}), stable over "
        f"{ex['window_s']:.3g} s from a perturbed start: {ex['stable']}; {ex['lower_substeps']} substeps: "
        f"{'unstable at t=%.3g s' % ex['lower_detected_at_s'] if ex['lower_unstable'] else 'stable'}; over the window: "
        f"error {se['err_max']:.3g} m (frame {se['err_frame']}), {se_row['cpu_per_frame_s']:.3g} CPU s/frame, "
        f"{se_row['wall_per_frame_s']:.3g} wall")
    summary.update(se_substeps=ex["substeps"], se_h=ex["h"], se_err_rms=se_row["err_rms"],
                   se_below_floor=se_row["below_floor"], se_err_frame=se_row["err_frame"],
                   se_wall_per_frame_s=se_row["wall_per_frame_s"], se_cpu_per_frame_s=se_row["cpu_per_frame_s"],
                   se_window_finite=se["finite"], se_stable=ex["stable"], se_window_s=ex["window_s"],
                   se_lower_substeps=ex["lower_substeps"], se_lower_unstable=ex["lower_unstable"],
                   se_lower_detected_at_s=ex["lower_detected_at_s"], omega_max=om,
                   omega_deformed=omd["omega"] if omd else float("nan"), substeps_computed=ex["substeps_computed"])
    del se_run
    gc.collect()

    # 3. candidates: probe, then run in order of the probe's cost
    cand_opts = dict(newton_maxiter=a.newton_maxiter, solver_options={"rtol": a.linear_rtol},
                     force_kernels=a.force_kernels)
    budget_end = t_start + a.budget
    probes = []
    for c in a.candidates:
        run = make_run(model, c, cand_opts)
        ok = run.advance(min(a.probe_steps, c.steps_per_frame * frames))
        probes.append((c, ok, run.wall / max(run.steps, 1), per_frame(run, run.wall), per_frame(run, run.cpu)))
        log(f"  probe {c.label}: ~{probes[-1][3]:.3g} s/frame wall, {probes[-1][4]:.3g} CPU{'' if ok else ' (blew up)'}")
        del run
        gc.collect()
    probes.sort(key=lambda p: (not p[1], p[4]))
    best = None
    for c, ok, step_s, probe_frame_s, probe_cpu in probes:
        row = dict(n=n, role="candidate", config=c.label, method=c.method, solver=c.solver, h=FRAME_DT / c.steps_per_frame,
                   steps_per_frame=c.steps_per_frame, probe_frame_s=probe_frame_s, probe_cpu_frame_s=probe_cpu,
                   floor=floor)
        if not ok:
            rows.append({**row, "status": "blew up in the probe"})
            continue
        if not a.measure_all and best is not None and probe_cpu >= best["cpu_per_frame_s"]:
            rows.append({**row, "status": "not run: probe dearer than the cheapest within target"})
            continue
        est = step_s * c.steps_per_frame * frames
        if time.perf_counter() + est > budget_end:
            rows.append({**row, "status": f"skipped: estimated {est:.0f} s over the budget"})
            log(f"  {c.label}: skipped (estimated {est:.0f} s, over budget)")
            continue
        run = make_run(model, c, cand_opts)
        res = track_errors(run, c.steps_per_frame, ref.q, stop_above=a.stop_above, deadline=budget_end)
        r = error_row(run, res, row)
        rows.append(r)
        cut = res["stopped"] or res["out_of_time"]
        log(f"  {c.label}: error {'>= ' if cut else ''}{res['err_max']:.3g} m (frame {res['err_frame']}"
            f"{', stopped' if res['stopped'] else ''}{', out of budget' if res['out_of_time'] else ''}), "
            f"{'> ' if res['out_of_time'] else ''}{r['cpu_per_frame_s']:.3g} CPU s/frame, "
            f"{r['wall_per_frame_s']:.3g} wall; {r.get('newton_per_step', float('nan')):.3g} Newton/step, "
            f"{r.get('newton_failures', 0)} failures, {r.get('failed_steps', 0)} failed steps, "
            f"{r.get('retaken_steps', 0)} retaken")
        del run
        gc.collect()
        if (usable and r["status"] == "within target"
                and (best is None or r["cpu_per_frame_s"] < best["cpu_per_frame_s"])):
            best = r

    summary["load_end"] = _load()
    if not usable:
        summary.update(config="undecided", status=f"reference floor {floor:.3g} m not below the target")
    elif best is not None:
        summary.update({k: best.get(k, "") for k in ("config", "method", "solver", "h", "steps_per_frame", "err_rms",
                                                     "below_floor", "err_frame", "wall_per_frame_s", "cpu_per_frame_s",
                                                     "newton_per_step", "linear_per_step", "newton_failures")},
                       cpu_ratio_to_se=best["cpu_per_frame_s"] / se_row["cpu_per_frame_s"], status="ok")
    else:
        measured = [r for r in rows if r["role"] == "candidate" and "err_rms" in r]
        closest = min(measured, key=lambda r: r["err_rms"], default=None)
        summary.update(config="none within target",
                       status=("no candidate measured" if closest is None else
                               f"no candidate within the target (smallest error {closest['err_rms']:.3g} m"
                               f"{' or more' if closest['err_lower_bound'] else ''}: {closest['config']})"))
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


def _err_text(r: dict, key: str = "err_rms", below: str = "below_floor", lower: str = "err_lower_bound") -> str:
    """An error for the tables: ``< floor`` when below the reference's floor, ``> x`` when the run stopped."""
    v = r.get(key, "")
    if v == "":
        return ""
    if str(r.get(below, "")) == "True":
        return f"< {fmt(float(v))} (floor)"
    if str(r.get(lower, "")) == "True":
        return f"> {fmt(float(v))}"
    return fmt(float(v))


def markdown(summaries: list[dict], rows: list[dict], target: float) -> str:
    """The summary and per-run tables of ``results/frame_cost.md``."""
    s_rows = [{**r, "err": _err_text(r), "se_err": _err_text(r, "se_err_rms", "se_below_floor", "-")}
              for r in summaries]
    c_rows = [{**r, "err": _err_text(r),
               "cpu_per_frame_s": _err_text(r, "cpu_per_frame_s", "-", "cost_lower_bound")} for r in rows]
    s_cols = ["n", "ke", "dofs", "frames", "floor", "config", "err", "cpu_per_frame_s", "wall_per_frame_s", "se_substeps",
              "se_err", "se_cpu_per_frame_s", "se_wall_per_frame_s", "cpu_ratio_to_se", "load_start", "load_end"]
    c_cols = ["n", "role", "config", "frames_run", "err", "err_frame", "err_final", "err_raw", "diff_to_next",
              "cpu_per_frame_s", "wall_per_frame_s", "probe_cpu_frame_s", "newton_per_step", "linear_per_step",
              "newton_failures", "failed_steps", "retaken_steps", "status"]
    return (f"## Time per 1/60 s frame within {target:g} m RMS of the validated reference\n\n"
            f"error = RMS over particles, max over every frame of the window\n\n"
            + markdown_table(s_rows, s_cols) + "\n\n### Every run\n\n" + markdown_table(c_rows, c_cols) + "\n")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", type=int, nargs="*", default=None, help="cloth sizes n (default 32 64)")
    p.add_argument("--candidates", type=parse_candidate, nargs="*", default=None,
                   help="configurations method:1/h:solver (default: %s)" % " ".join(DEFAULT_CANDIDATES))
    p.add_argument("--frames", type=int, default=DEFAULT_FRAMES,
                   help=f"window: frames of 1/60 s from the release (default {DEFAULT_FRAMES})")
    p.add_argument("--ke", type=float, default=None,
                   help="structural and shear stiffness [N/m] (default: the accuracy cloth's 1e3; 1e4 is benchmark_cloth)")
    p.add_argument("--damping", type=float, default=0.0,
                   help="spring damping [N s/m] of every spring, structural, shear and bending (default 0: undamped)")
    p.add_argument("--target", type=float, default=0.01, help="RMS error target [m] (default 0.01)")
    p.add_argument("--ref-method", default="verlet", choices=("verlet", "symplectic_euler"),
                   help="explicit method of the reference ladder (default verlet)")
    p.add_argument("--ref-base", type=int, default=2,
                   help="coarsest reference level = this times the explicit substeps/frame (default 2)")
    p.add_argument("--ref-substeps", type=int, default=None, help="coarsest reference level [substeps/frame] "
                                                                  "(overrides --ref-base)")
    p.add_argument("--ref-levels", type=int, default=3, help="reference levels, each halving the step (default 3)")
    p.add_argument("--cross-check-max-n", type=int, default=64,
                   help="cross-check the reference with solve_ivp at sizes up to this (default 64; 0: never)")
    p.add_argument("--cross-check-method", default="auto",
                   choices=("auto",) + reference_cache.SOLVE_IVP_METHODS,
                   help="solve_ivp method of the cross-check (default auto: Radau up to 600 DOFs, DOP853 above)")
    p.add_argument("--cache-dir", type=Path, default=reference_cache.CACHE_DIR,
                   help="where references are cached (default results/frame_ref)")
    p.add_argument("--no-cache", action="store_true", help="neither read nor write cached references")
    p.add_argument("--stop-above", type=float, default=0.05,
                   help="stop a candidate once its error exceeds this [m] (default 0.05; 0: never)")
    p.add_argument("--measure-all", action="store_true",
                   help="run every candidate, also those dearer than the cheapest within target")
    p.add_argument("--linear-rtol", type=float, default=1e-6, help="linear rtol of the candidates")
    p.add_argument("--newton-maxiter", type=int, default=None,
                   help="Newton iteration limit of the candidates (default: the integrator's, at least 20)")
    p.add_argument("--probe-steps", type=int, default=2, help="steps of each candidate's cost probe")
    p.add_argument("--budget", type=float, default=1800.0, help="wall-time budget per size [s]")
    p.add_argument("--explicit-window", type=float, default=0.1, help="symplectic Euler verification window [s]")
    p.add_argument("--explicit-max-steps", type=int, default=2000, help="cap on verification substeps")
    p.add_argument("--lower", type=float, default=0.7, help="fraction of the substep count that must fail")
    p.add_argument("--force-kernels", default="auto", choices=("auto", "numba", "numpy"),
                   help="force evaluation of symplectic Euler and the candidates (default auto: the compiled pass "
                        "when numba is installed; the reference always uses auto)")
    p.add_argument("--append", action="store_true",
                   help="keep the rows of other sizes already in the output CSVs (a size run again is replaced)")
    p.add_argument("--quick", action="store_true", help="n = 6, three candidates (tests)")
    p.add_argument("--out", type=Path, default=RESULTS_DIR)
    a = p.parse_args(argv)
    if a.ke is not None and not (np.isfinite(a.ke) and a.ke > 0):
        p.error(f"--ke must be > 0, got {a.ke}")
    if not (np.isfinite(a.damping) and a.damping >= 0):
        p.error(f"--damping must be >= 0, got {a.damping}")
    for name in ("target", "budget", "explicit_window"):
        if not getattr(a, name) > 0:
            p.error(f"--{name.replace('_', '-')} must be > 0, got {getattr(a, name)}")
    for name in ("frames", "ref_base", "probe_steps"):
        if not getattr(a, name) >= 1:
            p.error(f"--{name.replace('_', '-')} must be >= 1, got {getattr(a, name)}")
    if a.ref_levels < 2:
        p.error(f"--ref-levels must be >= 2, got {a.ref_levels}")
    if a.ref_substeps is not None and a.ref_substeps < 1:
        p.error(f"--ref-substeps must be >= 1, got {a.ref_substeps}")
    if not a.stop_above >= 0:
        p.error(f"--stop-above must be >= 0, got {a.stop_above}")
    if not 0 < a.lower < 1:
        p.error(f"--lower must be in (0, 1), got {a.lower}")
    if a.quick:
        a.sizes = a.sizes or [6]
        a.explicit_window = 0.05
        a.candidates = a.candidates or [parse_candidate(x) for x in QUICK_CANDIDATES]
    sizes = a.sizes or [32, 64]
    a.candidates = [parse_candidate(x) for x in DEFAULT_CANDIDATES] if a.candidates is None else a.candidates
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
    md = markdown(summaries, cand_rows, a.target)
    (a.out / "frame_cost.md").write_text(md)
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
