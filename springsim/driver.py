"""Simulation driver: step an integrator, record frames, stop cleanly, report once.

:func:`simulate` runs fixed steps; :func:`springsim.adaptive.simulate_adaptive` chooses
them from an error estimate. Both use :class:`RunRecorder`, which gives them the same
guarantees:

* **Blow-up.** After every step the new state is checked for NaN/inf and against the
  energy bound of :class:`springsim.energy.EnergyBound` (a finite state that holds more
  energy than the forces can supply). On either, :class:`~springsim.errors.SimulationError`
  names the step and carries the frames computed before it (``err.trajectory``).
* **Failed solves.** A :class:`~springsim.errors.SpringsimError` from the integrator
  mid-run (a linear solve with no usable solution, ``on_nonconvergence="raise"``) becomes a
  ``SimulationError`` with the frames so far and the original as ``__cause__``. Steps that
  finished but are not ``ok`` (:class:`~springsim.integrators.StepStats`) are kept and
  reported once per run: a :class:`~springsim.errors.ConvergenceWarning` with the count
  and the first reason, and in :meth:`Trajectory.summary`. Linear-solver fallbacks are
  reported the same way with a :class:`~springsim.errors.FallbackWarning`.
* **Threads.** The stepping loop runs with one BLAS thread
  (:func:`springsim._threads.single_blas_thread`; the optional ``threads`` extra).
* **Interrupts.** Ctrl-C raises :class:`~springsim.errors.SimulationInterrupted` (a
  ``KeyboardInterrupt``) with the frames so far.

:func:`save_npz_atomic` never leaves a partial file at the target path. See
``docs/robustness.md``.
"""

from __future__ import annotations

import json
import os
import stat
import tempfile
import time
import warnings
import zipfile
import zlib
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from .energy import EnergyBound
from .errors import (ConvergenceWarning, FallbackWarning, SimulationError, SimulationInterrupted, SpringsimError)
from .integrators import Integrator, StepStats
from .model import Model, State
from ._threads import single_blas_thread
from .options import MAX_STEPS, describe_int
from .progress import as_progress

__all__ = ["Trajectory", "TRAJECTORY_FORMAT", "TRAJECTORY_FORMAT_VERSION", "run_metadata", "simulate", "SimulationInterrupted", "save_npz_atomic", "check_output_path",
           "RunRecorder", "steps_for_duration", "MAX_STEPS"]

#: ``meta["format"]`` of a saved trajectory, and the layout version this springsim writes.
TRAJECTORY_FORMAT = "springsim-trajectory"
TRAJECTORY_FORMAT_VERSION = 1


def _read_meta(a) -> dict:
    """The JSON object in the 0-d ``meta`` array of a trajectory file."""
    if a.dtype.kind != "U" or a.ndim != 0:
        raise ValueError(f"meta must be a 0-d unicode array, got {a.dtype} {a.shape}")
    meta = json.loads(str(a))
    if not isinstance(meta, dict):
        raise ValueError("meta must hold a JSON object")
    return meta


@dataclass
class Trajectory:
    """Recorded frames of a run.

    Attributes
    ----------
    t : ndarray (F,)
        Frame times [s]; frame 0 is the initial state.
    q, qd : ndarray (F, N, 3)
        Positions [m] and velocities [m/s].
    stats : list of StepStats
        One per step taken (accepted steps in adaptive runs).
    wall_s : float
        Wall time of the stepping loop [s].
    cpu_s : float
        CPU time of the process during the stepping loop [s].
    adaptive_stats : dict or None
        Step-size controller statistics of an adaptive run (see
        :func:`springsim.adaptive.simulate_adaptive`).
    meta : dict
        How the frames were made, JSON-serialisable (saved with them): ``springsim_version``,
        ``model_fingerprint`` (:meth:`springsim.Model.fingerprint`), ``scene`` and ``source``
        (from the model's metadata), ``integrator``, ``linear_solver``, ``jacobian``, and ``dt``,
        ``steps``, ``frame_every`` for fixed steps or ``t_end``, ``time_rtol``, ``time_atol`` for
        adaptive runs; the command line adds ``scene_sha256`` (of the scene file). Empty for
        trajectories made by hand.
    """

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    stats: list = field(default_factory=list)
    wall_s: float = 0.0
    cpu_s: float = 0.0
    adaptive_stats: dict | None = None
    meta: dict = field(default_factory=dict)

    @property
    def frame_count(self) -> int:
        return int(self.t.shape[0])

    def __repr__(self) -> str:
        """One line, whatever the size: frames, particles, time span, steps and failed steps (not the arrays)."""
        t = np.asarray(self.t)
        span = f"[{float(t[0]):g}, {float(t[-1]):g}]" if t.size else "[]"
        particles = int(np.shape(self.q)[1]) if np.ndim(self.q) >= 2 else 0
        failed = sum(not getattr(x, "ok", True) for x in self.stats)
        return (f"Trajectory(frames={int(t.shape[0]) if t.ndim else 0}, particles={particles}, t={span} s, "
                f"steps={len(self.stats)}, failed_steps={failed})")

    def save(self, path) -> None:
        """Write the frames to an ``.npz`` atomically (see :func:`save_npz_atomic`).

        Layout (NumPy ``.npz``, readable with ``np.load(path)`` and no pickling): ``t`` (F,)
        float64 [s], ``q`` and ``qd`` (F, N, 3) float64 [m], [m/s], frame 0 the initial state;
        ``meta`` a 0-d unicode array holding :attr:`meta` as a JSON object, with
        ``"format": "springsim-trajectory"`` and ``"format_version": 1``.
        """
        meta = {"format": TRAJECTORY_FORMAT, "format_version": TRAJECTORY_FORMAT_VERSION, **self.meta}
        save_npz_atomic(path, t=self.t, q=self.q, qd=self.qd, meta=np.array(json.dumps(meta, sort_keys=True)))

    @classmethod
    def load(cls, path) -> "Trajectory":
        """Read a trajectory written by :meth:`save` (arrays ``t``, ``q`` and optionally ``qd``).

        Raises
        ------
        SpringsimError
            One line naming the file when it is missing, not a springsim ``.npz``, truncated
            or corrupt, or its arrays do not fit together.
        """
        path = os.fspath(path)
        if not os.path.exists(path):
            raise SpringsimError(f"{path}: no such file")
        if not os.path.isfile(path):
            raise SpringsimError(f"{path}: not a regular file")
        try:
            with np.load(path, allow_pickle=False) as d:
                t, q = np.asarray(d["t"], dtype=np.float64), np.asarray(d["q"], dtype=np.float64)
                qd = np.asarray(d["qd"], dtype=np.float64) if "qd" in d.files else np.zeros_like(q)
                meta = _read_meta(d["meta"]) if "meta" in d.files else {}
        except (KeyError, ValueError, TypeError, OSError, EOFError, zipfile.BadZipFile, zlib.error) as e:  # JSON too
            msg = " ".join(str(e).split()) or type(e).__name__
            raise SpringsimError(f"{path}: not a readable springsim trajectory (.npz with t, q, qd): {msg}") \
                from None
        if meta.get("format", TRAJECTORY_FORMAT) != TRAJECTORY_FORMAT or \
                meta.get("format_version", 1) > TRAJECTORY_FORMAT_VERSION:
            raise SpringsimError(f"{path}: trajectory format {meta.get('format')!r} version "
                                 f"{meta.get('format_version')!r}; this springsim reads "
                                 f"{TRAJECTORY_FORMAT!r} up to version {TRAJECTORY_FORMAT_VERSION}")
        if q.ndim != 3 or q.shape[2] != 3 or t.ndim != 1 or t.shape[0] != q.shape[0] or qd.shape != q.shape:
            raise SpringsimError(f"{path}: needs t (F,), q and qd (F, N, 3); got t {t.shape}, q {q.shape}, "
                                 f"qd {qd.shape}")
        return cls(t, q, qd, meta=meta)

    def summary(self) -> dict:
        """Aggregate statistics over all steps (per-step means where it says so)."""
        s = self.stats
        n = max(len(s), 1)
        assembly = sum(x.assembly_s for x in s)
        solve = sum(x.solve_s for x in s)
        return {
            "steps": len(s),
            "wall_s": self.wall_s,
            "cpu_s": self.cpu_s,
            "step_s": self.wall_s / n,
            "assembly_s": assembly / n,
            "solve_s": solve / n,
            "other_s": max(self.wall_s - assembly - solve, 0.0) / n,
            "newton_iterations": sum(x.newton_iterations for x in s) / n,
            "linear_iterations": sum(x.linear_iterations for x in s) / n,
            "newton_failures": sum(not x.newton_converged for x in s),
            "linear_failures": sum(x.linear_failures for x in s),
            "ill_conditioned": sum(x.ill_conditioned for x in s),
            "failed_steps": sum(not x.ok for x in s),
            "max_linear_residual": max((x.linear_residual for x in s), default=0.0),
            "max_precision_loss": max((x.precision_loss for x in s), default=0.0),
            "fallbacks": sum(len(x.fallbacks) for x in s),
        }


# -- output files ------------------------------------------------------------------------------
def _target(path) -> str:
    """The file a write to ``path`` replaces (symbolic links followed), checked to be a regular file or absent."""
    path = os.fspath(path)
    target = os.path.realpath(path)
    if os.path.exists(target):
        mode = os.stat(target).st_mode
        if stat.S_ISDIR(mode):
            raise SpringsimError(f"{path}: is a directory; give a file name")
        if not stat.S_ISREG(mode):
            raise SpringsimError(f"{path}: not a regular file (a device, FIFO or socket); give a file name")
    d = os.path.dirname(target)
    if not os.path.isdir(d):
        raise SpringsimError(f"{path}: directory {d} does not exist")
    return target


def check_output_path(path) -> str:
    """Check before a run that ``path`` can take an atomic write; return the file to write.

    A symbolic link is followed (its target is replaced, the link stays). The target must be
    a regular file or not exist, and its directory must exist and accept a new file (probed
    by creating and removing a temporary file).

    Raises
    ------
    SpringsimError
        One line naming the path and the problem.
    """
    target = _target(path)
    d = os.path.dirname(target)
    try:
        fd, probe = tempfile.mkstemp(prefix=".springsim-probe-", dir=d)
    except OSError as e:
        raise SpringsimError(f"{os.fspath(path)}: cannot write in {d}: {e.strerror or e}") from None
    os.close(fd)
    os.unlink(probe)
    return target


def _new_file_mode(existing: str) -> int:
    """Mode for a file replacing ``existing``: its mode if it exists, else 0o666 less the umask."""
    try:
        return stat.S_IMODE(os.stat(existing).st_mode)
    except OSError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask


def save_npz_atomic(path, **arrays) -> None:
    """Write ``arrays`` to the ``.npz`` file ``path`` atomically.

    ``np.savez`` writes to a temporary file in the target's directory, which is flushed,
    fsync'ed, given the mode of the file it replaces (or ``0o666`` less the umask for a new
    one) and renamed over the target (``os.replace``, atomic on POSIX and Windows). A symbolic
    link is followed: its target is replaced and the link kept. On any failure (including
    KeyboardInterrupt) the temporary file is removed and the target is left as it was.

    Parameters
    ----------
    path : str or PathLike
        Target file, used exactly as given (no ``.npz`` is appended); it must be a regular
        file or not exist (:func:`check_output_path`).
    **arrays : ndarray
        Named arrays, as for ``np.savez``.

    Raises
    ------
    SpringsimError
        When the target is not a regular file or its directory is missing.
    OSError
        When writing fails (full disk, permissions); the target is unchanged.
    """
    target = _target(path)
    d = os.path.dirname(target)
    mode = _new_file_mode(target)
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=".npz", dir=d)
    try:
        with os.fdopen(fd, "wb") as fh:
            np.savez(fh, **arrays)
            fh.flush()
            os.fchmod(fh.fileno(), mode)
            os.fsync(fh.fileno())
        os.replace(tmp, target)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


# -- arguments at the boundary -------------------------------------------------------------------
def _positive_time(name: str, value) -> float:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name} must be a number, got {type(value).__name__} {value!r}")
    v = float(value)
    if not (np.isfinite(v) and v > 0):
        raise ValueError(f"{name} must be finite and > 0, got {value!r}")
    return v


def _count(name: str, value, lo: int) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"{name} must be an integer, got {type(value).__name__} {value!r}")
    if not lo <= value <= MAX_STEPS:
        raise ValueError(f"{name} must be in [{lo}, {MAX_STEPS}], got {describe_int(int(value))}")
    return int(value)


def steps_for_duration(duration: float, dt: float) -> int:
    """Steps of size ``dt`` that cover ``duration`` [s]: ``ceil(duration / dt)`` (a relative 1e-9
    slack absorbs rounding, so 1.0 / 0.01 is 100 steps), at least 1 for a positive duration.

    Raises
    ------
    ValueError
        When that exceeds :data:`MAX_STEPS` (or overflows).
    """
    with np.errstate(over="ignore"):
        ratio = float(duration) / float(dt)
    if not ratio <= MAX_STEPS:
        raise ValueError(f"a duration of {duration:g} s in steps of {dt:g} s needs more than {MAX_STEPS:.0e} steps")
    return max(int(np.ceil(ratio - 1e-9 * max(ratio, 1.0))), 1 if duration > 0 else 0)


def _as_state(model, state) -> State:
    """A float64 copy of ``state`` (default ``model.state()``), checked against ``model``."""
    if state is None:
        return model.state()
    arrays = []
    for name in ("particle_q", "particle_qd"):
        if not hasattr(state, name):
            raise TypeError(f"state must be a springsim State, got {type(state).__name__}")
        a = getattr(state, name)
        try:
            a = np.array(a, dtype=np.float64)  # a copy; integer input is converted, never truncated later
        except (TypeError, ValueError):
            raise TypeError(f"state.{name} must be numeric, got {type(getattr(state, name)).__name__}") from None
        if a.shape != (model.particle_count, 3):
            raise ValueError(f"state.{name} must have shape ({model.particle_count}, 3) for this model, got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"state.{name} holds NaN or inf")
        arrays.append(a)
    return State(*arrays)


def _check_integrator(model, integrator) -> None:
    if not isinstance(integrator, Integrator):
        raise TypeError(f"integrator must be a springsim Integrator (see make_integrator), got "
                        f"{type(integrator).__name__}")
    if integrator.model is not model:
        raise ValueError(f"integrator was built for another model ({integrator.model!r}); build it with "
                         f"make_integrator(name, model) for this one ({model!r})")


# -- the shared run machinery --------------------------------------------------------------------
def run_metadata(model, integrator) -> dict:
    """The part of :attr:`Trajectory.meta` that the model and the integrator determine."""
    from . import __version__

    solver = getattr(integrator, "solver", None)
    name, source = (model.metadata.get(k) for k in ("name", "source"))
    return {"springsim_version": __version__, "model_fingerprint": model.fingerprint(),
            "scene": None if name is None else str(name), "source": None if source is None else str(source),
            "integrator": integrator.name, "linear_solver": getattr(solver, "name", None),
            "jacobian": getattr(integrator, "jacobian", None)}


class RunRecorder:
    """Frames, statistics, checks and reports of one run (used by both drivers).

    Parameters
    ----------
    model : Model
    integrator : Integrator
        Built for ``model``.
    state : State or None
        Initial state (copied and converted to float64), default ``model.state()``.
    check_energy : bool
        Apply the energy bound of :class:`springsim.energy.EnergyBound` after every step.
    """

    def __init__(self, model, integrator, state=None, *, check_energy: bool = True):
        _check_integrator(model, integrator)
        self.model = model
        self.integrator = integrator
        self.state = _as_state(model, state)  # the state after the last completed step
        self.scratch = self.state.copy()      # the integrator writes the next state here
        self.bound = EnergyBound(model, self.state.particle_q, self.state.particle_qd) if check_energy else None
        self.t = [0.0]
        self.q = [self.state.particle_q.copy()]
        self.qd = [self.state.particle_qd.copy()]
        self.stats: list[StepStats] = []
        self.time = 0.0        # simulated time of ``state``
        self.recorded = True   # whether ``state`` is the last frame
        self.steps = 0         # completed steps
        self._wall0 = time.perf_counter()
        self._cpu0 = time.process_time()
        self.adaptive_stats: dict | None = None
        self.meta = run_metadata(model, integrator)

    def add_frame(self, t: float, q: np.ndarray, qd: np.ndarray) -> None:
        """Record a frame (copied)."""
        self.t.append(float(t))
        self.q.append(np.array(q, copy=True))
        self.qd.append(np.array(qd, copy=True))

    def trajectory(self, keep_last: bool = False) -> Trajectory:
        """The frames so far; ``keep_last`` adds the last completed state if it was not recorded."""
        if keep_last and not self.recorded:
            self.add_frame(self.time, self.state.particle_q, self.state.particle_qd)
            self.recorded = True
        return Trajectory(np.array(self.t), np.array(self.q), np.array(self.qd), self.stats,
                          time.perf_counter() - self._wall0, time.process_time() - self._cpu0,
                          None if self.adaptive_stats is None else dict(self.adaptive_stats), dict(self.meta))

    def kept(self) -> str:
        n = len(self.t) + (not self.recorded)
        return f"kept {n} finite frame(s) up to t={self.time:g} s"

    def step(self, dt: float) -> StepStats:
        """Take one step of ``dt`` from :attr:`state` into :attr:`scratch` (not yet accepted)."""
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):  # judged by check()
            return self.integrator.step(self.state, self.scratch, dt)

    def problem(self) -> str | None:
        """Why the state in :attr:`scratch` is a blow-up (NaN/inf, energy bound), or None."""
        s = self.scratch
        if not s.is_finite():
            bad = ~(np.isfinite(s.particle_q).all(axis=1) & np.isfinite(s.particle_qd).all(axis=1))
            p = int(np.flatnonzero(bad)[0])
            return (f"particle {p} has a non-finite position or velocity ({int(bad.sum())} particle(s) "
                    f"affected)")
        if self.bound is not None:
            w = self.bound.exceeded(s.particle_q, s.particle_qd)
            if w is not None:
                return (f"kinetic plus gravitational energy reached {w:.3g} J, more than the forces can supply "
                        f"from the start ({self.bound.w_max:.3g} J)")
        return None

    def check(self, step: int, t_new: float) -> None:
        """Raise :class:`SimulationError` if the state in :attr:`scratch` blew up (:meth:`problem`)."""
        why = self.problem()
        if why is not None:
            raise SimulationError(f"simulation blew up at step {step} (t={t_new:g} s): {why}; {self.kept()}; "
                                  f"{self.integrator.blowup_hint()}", self.trajectory(keep_last=True), step=step)

    def accept(self, stats: StepStats, t_new: float) -> None:
        """Make :attr:`scratch` the current state (swap buffers)."""
        self.stats.append(stats)
        self.state, self.scratch = self.scratch, self.state
        self.time = t_new
        self.steps += 1
        self.recorded = False

    def record_current(self) -> None:
        self.add_frame(self.time, self.state.particle_q, self.state.particle_qd)
        self.recorded = True

    def interrupted(self, total: str) -> SimulationInterrupted:
        return SimulationInterrupted(f"interrupted after {total}; {self.kept()}", self.trajectory(keep_last=True),
                                     step=self.steps)

    def stopped(self, err: SpringsimError, step: int, t_new: float) -> SimulationError:
        return SimulationError(f"simulation stopped at step {step} (t={t_new:g} s): {type(err).__name__}: {err}; "
                               f"{self.kept()}", self.trajectory(keep_last=True), step=step)

    def finish(self) -> Trajectory:
        """The trajectory, after reporting failed steps and fallbacks once (warnings)."""
        traj = self.trajectory()
        report(traj, self.integrator, stacklevel=4)
        return traj


def report(traj: Trajectory, integrator, stacklevel: int = 2) -> None:
    """Warn once about the run's steps that are not ``ok`` and once about linear-solver fallbacks.

    Honours the integrator's ``on_nonconvergence`` (``"ignore"``: no warning).
    """
    if getattr(integrator, "on_nonconvergence", "warn") == "ignore":
        return
    stats = traj.stats
    bad = [k for k, s in enumerate(stats) if not s.ok]
    if bad:
        first = stats[bad[0]]
        warnings.warn(f"{integrator.name}: {len(bad)} of {len(stats)} step(s) did not meet their criteria (first: step "
                      f"{bad[0] + 1}, {'; '.join(first.failures) or 'failed'}); their results are kept, see "
                      f"StepStats.ok and .failures", ConvergenceWarning, stacklevel=stacklevel)
    fallbacks = [f for s in stats for f in s.fallbacks]
    if fallbacks:
        warnings.warn(f"{integrator.name}: {len(fallbacks)} linear solve(s) fell back to another solver (first: "
                      f"{fallbacks[0]})", FallbackWarning, stacklevel=stacklevel)


def simulate(model: Model, integrator: Integrator, dt: float, steps: int, *, state: State | None = None,
             frame_every: int = 1, record: bool = True, progress: Callable[[int, int], None] | bool | None = None,
             check_energy: bool = True) -> Trajectory:
    """Run ``steps`` steps of size ``dt`` [s] and return the :class:`Trajectory`.

    Parameters
    ----------
    model : Model
    integrator : Integrator
        Built for ``model`` (:func:`~springsim.integrators.make_integrator`).
    dt : float
        Time step [s], finite and > 0.
    steps : int
        Number of steps, >= 0.
    state : State, optional
        Initial state (default ``model.state()``); copied, and converted to float64.
    frame_every : int
        Record every k-th step (the initial and the final state are always recorded).
    record : bool
        If False, keep only the initial and final frames (large scenes).
    progress : callable(step, steps) or True, optional
        Called after every step; True logs a line every few seconds with the time left
        (:class:`springsim.progress.ProgressLog`, logger ``springsim``).
    check_energy : bool
        Stop when a finite state holds more energy than the forces can supply (module docstring).

    Raises
    ------
    TypeError, ValueError
        On invalid arguments (naming the parameter).
    SimulationError
        On a blow-up (NaN/inf or the energy bound); ``err.trajectory`` has the finite frames before
        it. Also wraps any other :class:`~springsim.errors.SpringsimError` the integrator raises
        mid-run (e.g. ``SolverError``), kept as ``__cause__``.
    SimulationInterrupted
        On KeyboardInterrupt (also from ``progress``), with the frames so far.
    """
    dt = _positive_time("dt", dt)
    steps = _count("steps", steps, 0)
    frame_every = _count("frame_every", frame_every, 1)
    progress = as_progress(progress)
    run = RunRecorder(model, integrator, state, check_energy=check_energy)
    run.meta.update(dt=dt, steps=steps, frame_every=frame_every)
    k = 0
    try:
        with single_blas_thread():
            for k in range(1, steps + 1):
                t_new = k * dt
                st = run.step(dt)
                run.check(k, t_new)
                run.accept(st, t_new)
                if (k == steps) or (record and k % frame_every == 0):
                    run.record_current()
                if progress is not None:
                    progress(k, steps)
    except KeyboardInterrupt:
        raise run.interrupted(f"step {run.steps} of {steps}") from None
    except SimulationError:
        raise
    except SpringsimError as e:
        raise run.stopped(e, k, k * dt) from e
    return run.finish()
