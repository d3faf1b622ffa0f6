"""Validated references of the ODE at every frame, by explicit integration refined until converged; cached on disk.

The frame benchmarks measure a method's error against the motion the model's ODE ``M q'' = F(q, q')``
prescribes, never against the method itself at a smaller step. That motion is computed here by
**velocity Verlet** (kick-drift-kick leapfrog; second order and symplectic for position-only forces,
stable for ``h omega_max < 2``, one force evaluation per substep) at ``S_0``, ``2 S_0``, ``4 S_0``, ...
substeps per frame, sharing only the force evaluation (:func:`springsim.forces.eval_forces`, compiled
when numba is installed: the same forces to round-off) with springsim's integrators. Its positions are
recorded at every frame. The finest level is the reference; the largest difference between the two
finest levels (RMS over particles, max over the recorded frames) is its **floor**: errors below it
cannot be told from the reference's own uncertainty. A refinement ladder converges when those
differences shrink level by level (about 4x per halving for a second-order method while the motion
is smooth; on a buckling cloth they can stall at the amplified round-off and
truncation noise, which is exactly what the floor reports).

:func:`reference_frames` also runs :func:`springsim.analysis.reference.reference_trajectory` (scipy ``solve_ivp``:
Radau with the sparse Jacobian, or DOP853, at rtol 1e-10), a code with no stepping in common, to
cross-check the Verlet reference where that is affordable.

Every level is cached in ``benchmarks/results/frame_ref/`` (git-ignored) under a key of the case name,
the model's :meth:`~springsim.Model.fingerprint`, the method, the substeps per frame, the frame length,
the number of frames and :data:`CACHE_VERSION` (bumped with any change of the stepping or the tolerances), so reruns cost nothing; a key mismatch recomputes.
"""

from __future__ import annotations

import hashlib
import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .common import RESULTS_DIR

__all__ = ["CACHE_DIR", "CACHE_VERSION", "FRAME_DT", "SOLVE_IVP_METHODS", "frame_rms", "VerletRun", "ExplicitRun",
           "explicit_run", "reference_frames", "verlet_frames", "cached_frames", "Reference", "refined_reference"]

#: Cache folder (git-ignored with ``benchmarks/results/``).
CACHE_DIR = RESULTS_DIR / "frame_ref"
#: Bumped whenever the stepping or the file layout changes (old files are then ignored).
CACHE_VERSION = 1
#: Frame length [s].
FRAME_DT = 1.0 / 60.0


def frame_rms(qa: np.ndarray, qb: np.ndarray) -> np.ndarray:
    """RMS over particles of ``|qa - qb|`` per frame [m]; arrays (F, N, 3) or (N, 3); inf where not finite."""
    with np.errstate(over="ignore", invalid="ignore"):
        e = np.sqrt(np.mean(np.sum((np.asarray(qa) - np.asarray(qb)) ** 2, axis=-1), axis=-1))
    return np.where(np.isfinite(e), e, np.inf)


class VerletRun:
    """Velocity Verlet (kick-drift-kick) from ``model``'s initial state at step ``h``, advanced in pieces.

    ``v_half = v + h/2 a(q, v)``, ``q1 = q + h v_half``, ``v1 = v_half + h/2 a(q1, v_half)``; fixed
    particles have zero acceleration; one force evaluation per step (the end-of-step acceleration is
    the next step's start). Second order and symplectic when the forces do not depend on the velocity
    (the undamped cloth); a velocity-dependent force (damping, drag) is evaluated at ``v_half``, first
    order in that term. Stable for ``h omega_max < 2``.

    Attributes
    ----------
    q, v : ndarray (N, 3)
        Current positions [m] and velocities [m/s].
    steps : int
    cpu, wall : float
        ``time.process_time`` and ``time.perf_counter`` seconds spent stepping.
    """

    method = "verlet"

    def __init__(self, model, h: float, state=None, force_kernels: str = "auto"):
        from springsim.forces import make_force_terms

        self.terms = make_force_terms(model, kernels=force_kernels)
        s = model.state() if state is None else state
        self.q, self.v = s.particle_q.copy(), s.particle_qd.copy()
        self.fixed = np.flatnonzero(model.particle_fixed)
        self.inv_mass = np.where(model.particle_fixed, 0.0, 1.0 / model.particle_mass)[:, None]
        self.f, self.a, self.tmp = np.zeros_like(self.q), np.zeros_like(self.q), np.zeros_like(self.q)
        self.h = float(h)
        self.steps, self.cpu, self.wall = 0, 0.0, 0.0
        self._accel()

    def _accel(self):
        from springsim.forces import eval_forces

        eval_forces(self.terms, self.q, self.v, out=self.f)
        np.multiply(self.f, self.inv_mass, out=self.a)
        self.a[self.fixed] = 0.0

    @property
    def positions(self) -> np.ndarray:
        return self.q

    def advance(self, k: int) -> bool:
        """Take ``k`` more steps; False if the state is no longer finite."""
        h, half, q, v, a, tmp = self.h, 0.5 * self.h, self.q, self.v, self.a, self.tmp
        c0, w0 = time.process_time(), time.perf_counter()
        with np.errstate(over="ignore", invalid="ignore"):
            for _ in range(k):
                v += np.multiply(a, half, out=tmp)
                q += np.multiply(v, h, out=tmp)
                self._accel()
                v += np.multiply(a, half, out=tmp)
            self.steps += k
        self.cpu += time.process_time() - c0
        self.wall += time.perf_counter() - w0
        return bool(np.all(np.isfinite(q)) and np.all(np.isfinite(v)))

    def summary(self) -> dict:
        return {}


class ExplicitRun(VerletRun):
    """A registered explicit springsim integrator (``symplectic_euler``, ...) with the interface of :class:`VerletRun`."""

    def __init__(self, model, method: str, h: float, state=None, force_kernels: str = "auto"):
        from springsim.integrators import make_integrator

        self.method = method
        self.integ = make_integrator(method, model, force_kernels=force_kernels)
        self.s0 = model.state() if state is None else state
        self.s1 = model.state()
        self.h = float(h)
        self.steps, self.cpu, self.wall = 0, 0.0, 0.0

    @property
    def positions(self) -> np.ndarray:
        return self.s0.particle_q

    @property
    def v(self) -> np.ndarray:
        return self.s0.particle_qd

    def advance(self, k: int) -> bool:
        c0, w0 = time.process_time(), time.perf_counter()
        with np.errstate(over="ignore", invalid="ignore"):
            for _ in range(k):
                self.integ.step(self.s0, self.s1, self.h)
                self.s0, self.s1 = self.s1, self.s0
            self.steps += k
        self.cpu += time.process_time() - c0
        self.wall += time.perf_counter() - w0
        return self.s0.is_finite()


#: ``solve_ivp`` methods :func:`reference_frames` accepts (through
#: :func:`springsim.analysis.reference.reference_trajectory`).
SOLVE_IVP_METHODS = ("Radau", "BDF", "LSODA", "DOP853", "RK45")


def explicit_run(model, method: str, h: float, force_kernels: str = "auto"):
    """:class:`VerletRun` for ``verlet``, else :class:`ExplicitRun` (``force_kernels``: see
    :func:`springsim.forces.make_force_terms`)."""
    if method == "verlet":
        return VerletRun(model, h, force_kernels=force_kernels)
    return ExplicitRun(model, method, h, force_kernels=force_kernels)


def reference_frames(model, method: str, substeps: int, frames: int, *, frame_dt: float = FRAME_DT,
                     rtol: float = 1e-10, atol: float = 1e-12) -> dict:
    """Positions at every frame of ``method`` at ``substeps`` per frame.

    ``method``: ``verlet`` (:class:`VerletRun`), a registered explicit springsim integrator, or one of
    :data:`SOLVE_IVP_METHODS` (``substeps`` is then ignored: :func:`springsim.analysis.reference.reference_trajectory`
    at ``rtol``, ``atol``).

    Returns
    -------
    dict
        ``q`` (frames + 1, N, 3) [m] (frame 0 is the initial state; inf after a blow-up), ``qd`` (N, 3)
        at the last frame, ``finite``, ``cpu_s`` and ``wall_s`` of the stepping.
    """
    if method in SOLVE_IVP_METHODS:
        from springsim.analysis.reference import reference_trajectory

        c0, w0 = time.process_time(), time.perf_counter()
        tr = reference_trajectory(model, np.arange(frames + 1) * frame_dt, method=method, rtol=rtol, atol=atol)
        return dict(q=tr.q, qd=tr.qd[-1], finite=bool(np.all(np.isfinite(tr.q))), cpu_s=time.process_time() - c0,
                    wall_s=time.perf_counter() - w0)
    run = explicit_run(model, method, frame_dt / substeps)
    out = np.full((frames + 1,) + run.positions.shape, np.inf)
    out[0] = run.positions
    finite = True
    for k in range(1, frames + 1):
        if not run.advance(substeps):
            finite = False
            break
        out[k] = run.positions
    return dict(q=out, qd=run.v.copy(), finite=finite, cpu_s=run.cpu, wall_s=run.wall)


def verlet_frames(model, substeps: int, frames: int, *, frame_dt: float = FRAME_DT) -> dict:
    """:func:`reference_frames` with ``verlet``."""
    return reference_frames(model, "verlet", substeps, frames, frame_dt=frame_dt)


def _key(case: str, model, method: str, substeps: int, frames: int, frame_dt: float) -> str:
    text = json.dumps(dict(case=case, model=model.fingerprint(), method=method, substeps=int(substeps),
                           frames=int(frames), frame_dt=float(frame_dt).hex(), version=CACHE_VERSION), sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def cached_frames(model, method: str, substeps: int, frames: int, *, case: str, frame_dt: float = FRAME_DT,
                  cache_dir: Path | None = CACHE_DIR) -> dict:
    """:func:`reference_frames`, loaded from / saved to ``cache_dir`` (None: no cache).

    The result has ``cached`` (True when loaded; ``cpu_s`` and ``wall_s`` are then those of the run that
    made the file) and ``path``. A run that stopped being finite is not cached.
    """
    path = None
    if cache_dir is not None:
        path = Path(cache_dir) / f"{case}_{method}_S{int(substeps)}_F{int(frames)}_{_key(case, model, method, substeps, frames, frame_dt)}.npz"
        if path.exists():
            try:
                with np.load(path, allow_pickle=False) as d:
                    return dict(q=d["q"], qd=d["qd"], finite=bool(d["finite"]), cpu_s=float(d["cpu_s"]),
                                wall_s=float(d["wall_s"]), cached=True, path=path)
            except (OSError, KeyError, ValueError):
                pass  # unreadable: recompute
    r = reference_frames(model, method, substeps, frames, frame_dt=frame_dt)
    r.update(cached=False, path=path)
    if path is not None and r["finite"]:
        from springsim.run.driver import save_npz_atomic

        path.parent.mkdir(parents=True, exist_ok=True)
        save_npz_atomic(path, q=r["q"], qd=r["qd"], finite=np.bool_(r["finite"]), cpu_s=np.float64(r["cpu_s"]),
                        wall_s=np.float64(r["wall_s"]))
    return r


@dataclass
class Reference:
    """A refinement ladder of explicit runs and the reference it validates.

    Attributes
    ----------
    q : ndarray (frames + 1, N, 3)
        Positions of the finest level at every frame [m].
    substeps : list of int
        Substeps per frame of every level, coarse to fine.
    diff_frames : list of ndarray
        RMS over particles of ``level k - level k+1`` at every frame (frames + 1,) [m], one per
        consecutive pair.
    finite : bool
        Every level stayed finite.
    cpu_s, wall_s : list of float
        Stepping time of every level (of the run that made a cached file).
    cached : list of bool
    method : str
    """

    q: np.ndarray
    substeps: list
    diff_frames: list
    finite: bool
    cpu_s: list = field(default_factory=list)
    wall_s: list = field(default_factory=list)
    cached: list = field(default_factory=list)
    method: str = "verlet"

    @property
    def diffs(self) -> list:
        """``max over frames of RMS(level k - level k+1)`` [m], one per consecutive pair."""
        return [float(np.max(d)) for d in self.diff_frames]

    @property
    def floor(self) -> float:
        """``diffs[-1]``: the two finest levels' difference, max over frames, the reference's own uncertainty [m]."""
        return self.diffs[-1] if self.finite else float("inf")

    @property
    def ratios(self) -> list:
        """``diffs[k] / diffs[k+1]``: how much each refinement shrank the largest difference."""
        d = self.diffs
        return [a / b if b > 0 else float("inf") for a, b in zip(d, d[1:])]

    @property
    def median_ratios(self) -> list:
        """Median over frames of ``diff_frames[k] / diff_frames[k+1]`` (frames where both exceed 1e-13 m).

        About 4 per halving of the step for a second-order method, 2 for a first-order one; the
        largest differences (late frames of a buckling cloth) can shrink less, see :attr:`ratios`.
        """
        out = []
        for a, b in zip(self.diff_frames, self.diff_frames[1:]):
            ok = (a > 1e-13) & (b > 1e-13) & np.isfinite(a) & np.isfinite(b)
            out.append(float(np.median(a[ok] / b[ok])) if np.any(ok) else float("nan"))
        return out

    @property
    def shrinking(self) -> bool:
        """Every level finite and the largest differences shrink strictly, level by level."""
        d = self.diffs
        return bool(self.finite and all(np.isfinite(d)) and all(b < a for a, b in zip(d, d[1:])))


def refined_reference(model, base_substeps: int, levels: int, frames: int, *, case: str, method: str = "verlet",
                      frame_dt: float = FRAME_DT, cache_dir: Path | None = CACHE_DIR, log=None) -> Reference:
    """Run ``method`` at ``base_substeps * 2**k`` substeps per frame, ``k = 0 .. levels-1`` (``levels >= 2``),
    each from the model's initial state, positions recorded at every frame (cached, :func:`cached_frames`)."""
    if levels < 2:
        raise ValueError(f"levels must be >= 2, got {levels}")
    runs, subs = [], []
    for k in range(levels):
        S = int(base_substeps) * 2 ** k
        r = cached_frames(model, method, S, frames, case=case, frame_dt=frame_dt, cache_dir=cache_dir)
        runs.append(r)
        subs.append(S)
        if log is not None:
            log(f"  reference level: {method} at {S} substeps/frame, {'cached' if r['cached'] else 'computed'} "
                f"({r['cpu_s']:.1f} CPU s){'' if r['finite'] else ', NOT FINITE'}")
    return Reference(q=runs[-1]["q"], substeps=subs, diff_frames=[frame_rms(a["q"], b["q"]) for a, b in
                                                                   zip(runs, runs[1:])],
                     finite=all(r["finite"] for r in runs), cpu_s=[r["cpu_s"] for r in runs],
                     wall_s=[r["wall_s"] for r in runs], cached=[r["cached"] for r in runs], method=method)
