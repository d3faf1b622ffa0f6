"""Simulation driver: step an integrator, record frames, stop cleanly, report once.

:func:`simulate` runs fixed steps; :func:`springsim.run.adaptive.simulate_adaptive` chooses
them from an error estimate. Both use :class:`RunRecorder`, which gives them the same
guarantees:

* **Blow-up.** After every step the new state is checked for NaN/inf and against the
  energy bound of :class:`springsim.run.energy.EnergyBound` (a finite state that holds more
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
  (:func:`springsim._runtime.threads.single_blas_thread`; the optional ``threads`` extra).
* **Interrupts.** Ctrl-C raises :class:`~springsim.errors.SimulationInterrupted` (a
  ``KeyboardInterrupt``) with the frames so far.

:func:`save_npz_atomic` never leaves a partial file at the target path. See
``docs/robustness.md``.
"""

from __future__ import annotations

import json
import time
import warnings
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from .._runtime.threads import single_blas_thread
from ..errors import (ConvergenceWarning, EnergyGrowthWarning, FallbackWarning, SimulationError,
                      SimulationInterrupted, SpringsimError)
from ..integrators import Integrator, StepStats
from ..io._atomic import _new_file_mode, _target, check_output_path, save_npz_atomic  # noqa: F401 (re-exported)
from ..io._npz import read_trajectory_npz
from ..model import Model, State
from ..progress import as_progress
from .energy import EnergyBound
from .interrupts import collective_interrupts
from .options import MAX_STEPS, describe_int

__all__ = ["Trajectory", "TRAJECTORY_FORMAT", "TRAJECTORY_FORMAT_VERSION", "run_metadata", "simulate", "SimulationInterrupted", "save_npz_atomic", "check_output_path",
           "RunRecorder", "steps_for_duration", "MAX_STEPS"]

#: Energy rise over a run, in units of the start's energy scale (:class:`springsim.run.energy.EnergyBound`), above
#: which a conservative or damped scene is reported as unstable (:meth:`RunRecorder.check_energy_growth`).
ENERGY_GROWTH = 1e-2

#: ``meta["format"]`` of a saved trajectory, and the layout version this springsim writes.
TRAJECTORY_FORMAT = "springsim-trajectory"
TRAJECTORY_FORMAT_VERSION = 1


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
        :func:`springsim.run.adaptive.simulate_adaptive`).
    meta : dict
        How the frames were made, JSON-serialisable (saved with them): ``springsim_version``,
        ``model_fingerprint`` (:meth:`springsim.Model.fingerprint`), ``scene`` and ``source``
        (from the model's metadata), ``integrator``, ``linear_solver``, ``jacobian``, and ``dt``,
        ``steps``, ``frame_every`` for fixed steps or ``t_end``, ``time_rtol``, ``time_atol`` for
        adaptive runs; the command line adds ``scene_sha256`` (of the scene file). Empty for
        trajectories made by hand.
    frames : object or None
        Where the frames are when ``q`` and ``qd`` are None: the sink they were streamed to
        (:class:`springsim.io._spool.FrameSpool`), which :meth:`save` writes out.
    """

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    stats: list = field(default_factory=list)
    wall_s: float = 0.0
    cpu_s: float = 0.0
    adaptive_stats: dict | None = None
    meta: dict = field(default_factory=dict)
    frames: object = None

    @property
    def frame_count(self) -> int:
        """Number of frames F, the initial state included."""
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
        ``"format": "springsim-trajectory"`` and ``"format_version": 1`` (these two keys are always the
        format's own: a ``meta`` entry of the same name does not replace them).

        Parameters
        ----------
        path : str or PathLike
            Target file, used exactly as given (no ``.npz`` is appended).

        Raises
        ------
        SpringsimError
            The target is not a regular file or its directory is missing.
        OSError
            Writing failed (full disk, permissions); the target is unchanged.
        """
        meta = {**self.meta, "format": TRAJECTORY_FORMAT, "format_version": TRAJECTORY_FORMAT_VERSION}
        if self.q is None and self.frames is not None:  # streamed: written from the sink, a frame at a time
            self.frames.finish(self.t, meta, path)
            return
        save_npz_atomic(path, t=self.t, q=self.q, qd=self.qd, meta=np.array(json.dumps(meta, sort_keys=True)))

    @classmethod
    def load(cls, path) -> "Trajectory":
        """Read a trajectory written by :meth:`save` (arrays ``t``, ``q`` and optionally ``qd``).

        Parameters
        ----------
        path : str or PathLike
            The ``.npz`` file.

        Returns
        -------
        Trajectory
            The frames and :attr:`meta` as saved (``format`` and ``format_version`` included); no step
            statistics.

        Raises
        ------
        SpringsimError
            One line naming the file when it is missing, not a springsim ``.npz``, truncated
            or corrupt, its arrays do not fit together or would not fit in memory, or its ``meta``
            is not a JSON object of this format. The array headers are checked before any data
            is read (:mod:`springsim.io._npz`), so this takes bounded time and memory.
        """
        t, q, qd, meta = read_trajectory_npz(path, format_name=TRAJECTORY_FORMAT,
                                             format_version=TRAJECTORY_FORMAT_VERSION)
        return cls(t, q, qd, meta=meta)

    def summary(self) -> dict:
        """Aggregate statistics over all steps (per-step means where it says so).

        Returns
        -------
        dict
            ``steps``; ``wall_s``, ``cpu_s`` [s] of the run; per-step means ``step_s``, ``assembly_s``,
            ``solve_s``, ``other_s`` [s], ``newton_iterations``, ``linear_iterations``; counts
            ``newton_failures``, ``linear_failures``, ``ill_conditioned``, ``failed_steps``, ``fallbacks``;
            maxima ``max_linear_residual``, ``max_precision_loss``.
        """
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

    Parameters
    ----------
    duration : float
        Simulated time [s], >= 0.
    dt : float
        Step size [s], > 0.

    Returns
    -------
    int
        The number of steps (0 for a zero duration).

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
    """The part of :attr:`Trajectory.meta` that the model and the integrator determine.

    Parameters
    ----------
    model : Model
        The model run.
    integrator : Integrator
        The integrator that runs it.

    Returns
    -------
    dict
        ``springsim_version``, ``model_fingerprint``, ``scene``, ``source``, ``integrator``, ``linear_solver``,
        ``jacobian`` (None where they do not apply), and the system's :meth:`~springsim.system.System.metadata`
        (``backend``, ...).
    """
    from .. import __version__

    solver = getattr(integrator, "solver", None)
    backend = integrator.system.metadata()
    name, source = (model.metadata.get(k) for k in ("name", "source"))
    linear = getattr(solver, "name", None) or ("petsc" if integrator.implicit and backend["backend"] == "petsc"
                                               else None)
    return {"springsim_version": __version__, "model_fingerprint": model.fingerprint(),
            "scene": None if name is None else str(name), "source": None if source is None else str(source),
            "integrator": integrator.name, "linear_solver": linear,
            "jacobian": getattr(integrator, "jacobian", None), **backend}


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
        Apply the energy bound of :class:`springsim.run.energy.EnergyBound` after every step.
    frames : object, optional
        The root's frame sink (:func:`simulate`); default: the frames are kept in memory.
    """

    def __init__(self, model, integrator, state=None, *, check_energy: bool = True, frames=None):
        _check_integrator(model, integrator)
        self.model = model
        self.integrator = integrator
        self.system = system = integrator.system
        self.is_root = system.is_root
        #: where the root's frames go: None keeps them in :attr:`q` and :attr:`qd`; else an object whose
        #: ``append(q, qd)`` takes each gathered frame (:class:`springsim.io._spool.FrameSpool` streams them to a file)
        self.frames = frames if self.is_root else None
        #: the total energy of every frame, computed as it is recorded when the system holds no whole model
        self.energies = None if system.whole_model else []
        self.t = [0.0]
        self.q, self.qd = [], []
        if system.whole_model:
            full = _as_state(model, state)
            # the state after the last completed step, as the system's state arrays (every particle serially)
            self.state = State(*system.local_state(full.particle_q, full.particle_qd))
            self.bound = EnergyBound(model, full.particle_q, full.particle_qd, system=system) if check_energy else None
            first = (full.particle_q.copy(), full.particle_qd.copy()) if self.is_root else (None, None)
            del full
        else:  # a scene built per rank: the start is the system's own; the root gathers the first frame
            if state is not None:
                raise ValueError("state must be None for a distributed scene built per rank (its parts hold the "
                                 "initial state)")
            self.state = State(*system.initial_state())
            self.bound = (EnergyBound(model, self.state.particle_q, self.state.particle_qd, system=system)
                          if check_energy else None)
            first = system.gather_state(self.state.particle_q, self.state.particle_qd)
            self.energies.append(system.frame_energy(self.state.particle_q, self.state.particle_qd))
        self.scratch = self.state.copy()      # the integrator writes the next state here
        if self.is_root:
            self._keep(*first)
        del first
        self.stats: list[StepStats] = []
        self.time = 0.0        # simulated time of ``state``
        self.recorded = True   # whether ``state`` is the last frame
        self.steps = 0         # completed steps
        self._wall0 = time.perf_counter()
        self._cpu0 = time.process_time()
        self.adaptive_stats: dict | None = None
        self.meta = run_metadata(model, integrator)

    def _keep(self, q, qd) -> None:
        """A gathered frame on the root: into the frame sink, or kept."""
        if self.frames is not None:
            self.frames.append(q, qd)
        else:
            self.q.append(q)
            self.qd.append(qd)

    def add_frame(self, t: float, q: np.ndarray, qd: np.ndarray) -> None:
        """Record a frame of state arrays (gathered on the root process, copied). Collective.

        Parameters
        ----------
        t : float
            Simulated time of the frame [s].
        q, qd : ndarray, shape (n, 3)
            Positions [m] and velocities [m/s] (state arrays of the system).
        """
        if self.energies is not None:
            self.energies.append(self.system.frame_energy(q, qd))
        q, qd = self.system.gather_state(q, qd)
        self.t.append(float(t))
        if self.is_root:
            self._keep(q, qd)

    def trajectory(self, keep_last: bool = False) -> Trajectory | None:
        """The frames so far (None on processes other than the root); ``keep_last`` adds the last completed state
        if it was not recorded (collective then).

        Parameters
        ----------
        keep_last : bool
            Record the last completed state first if it is not the last frame.

        Returns
        -------
        Trajectory or None
            The frames, statistics and timings so far, on the root process.
        """
        if keep_last and not self.recorded:
            self.add_frame(self.time, self.state.particle_q, self.state.particle_qd)
            self.recorded = True
        if not self.is_root:
            return None
        meta = dict(self.meta)
        timings = getattr(self.system, "timings", None)  # a distributed system's time per phase [s]
        if timings:
            meta["timings"] = {k: float(v) for k, v in timings.items()}
        streamed = self.frames is not None  # the frames are in the sink: the trajectory has none
        return Trajectory(np.array(self.t), None if streamed else np.array(self.q),
                          None if streamed else np.array(self.qd), self.stats,
                          time.perf_counter() - self._wall0, time.process_time() - self._cpu0,
                          None if self.adaptive_stats is None else dict(self.adaptive_stats), meta,
                          self.frames if streamed else None)

    def kept(self) -> str:
        """What a failed run keeps, for its error message: ``"kept 12 finite frame(s) up to t=0.5 s"``.

        Returns
        -------
        str
        """
        n = len(self.t) + (not self.recorded)
        return f"kept {n} finite frame(s) up to t={self.time:g} s"

    def step(self, dt: float) -> StepStats:
        """Take one step of ``dt`` from :attr:`state` into :attr:`scratch` (not yet accepted).

        numpy's overflow and invalid-value warnings are silenced: :meth:`check` judges the result.

        Parameters
        ----------
        dt : float
            Step size [s].

        Returns
        -------
        StepStats
            The integrator's statistics of the step.
        """
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):  # judged by check()
            return self.integrator.step(self.state, self.scratch, dt)

    def problem(self) -> str | None:
        """Why the state in :attr:`scratch` is a blow-up (NaN/inf, energy bound), or None; the same on every
        process.

        Returns
        -------
        str or None
            One clause for the error message, or None when the state is fine.
        """
        s = self.scratch
        if not self.system.all_finite(s.particle_q, s.particle_qd):
            bad = ~(np.isfinite(s.particle_q).all(axis=1) & np.isfinite(s.particle_qd).all(axis=1))
            count = int(self.system.sum(int(bad.sum())))
            where = f"particle {int(np.flatnonzero(bad)[0])}" if self.system.holds_fixed else "a particle"
            return f"{where} has a non-finite position or velocity ({count} particle(s) affected)"
        if self.bound is not None:
            w = self.bound.exceeded(s.particle_q, s.particle_qd)
            if w is not None:
                return (f"kinetic plus gravitational energy reached {w:.3g} J, more than the forces can supply "
                        f"from the start ({self.bound.w_max:.3g} J)")
        return None

    def check(self, step: int, t_new: float) -> None:
        """Raise :class:`SimulationError` if the state in :attr:`scratch` blew up (:meth:`problem`).

        Parameters
        ----------
        step : int
            Number of the step that made it (from 1), for the message.
        t_new : float
            Simulated time [s] it reached.

        Raises
        ------
        SimulationError
            The state blew up; the error carries the frames so far (the last completed state included) and
            the step.
        """
        why = self.problem()
        if why is not None:
            raise SimulationError(f"simulation blew up at step {step} (t={t_new:g} s): {why}; {self.kept()}; "
                                  f"{self.integrator.blowup_hint()}", self.trajectory(keep_last=True), step=step)

    def accept(self, stats: StepStats, t_new: float) -> None:
        """Make :attr:`scratch` the current state (swap buffers).

        Parameters
        ----------
        stats : StepStats
            The step's statistics, appended to the run's.
        t_new : float
            Simulated time [s] of the new state.
        """
        self.stats.append(stats)
        self.state, self.scratch = self.scratch, self.state
        self.time = t_new
        self.steps += 1
        self.recorded = False

    def record_current(self) -> None:
        """Record the current state as a frame (collective)."""
        self.add_frame(self.time, self.state.particle_q, self.state.particle_qd)
        self.recorded = True

    def interrupted(self, total: str) -> SimulationInterrupted:
        """The error a driver raises when the run is interrupted (Ctrl-C), with the frames so far.

        Parameters
        ----------
        total : str
            How far the run got, for the message (``"step 40 of 100"``).

        Returns
        -------
        SimulationInterrupted
            Carrying the trajectory (the last completed state included) and the number of completed steps.
        """
        return SimulationInterrupted(f"interrupted after {total}; {self.kept()}", self.trajectory(keep_last=True),
                                     step=self.steps)

    def stopped(self, err: SpringsimError, step: int, t_new: float) -> SimulationError:
        """The error a driver raises when a step raised ``err`` (a solver error), with the frames so far.

        Parameters
        ----------
        err : SpringsimError
            What the step raised.
        step : int
            Number of that step (from 1).
        t_new : float
            Simulated time [s] the step was to reach.

        Returns
        -------
        SimulationError
            Naming the step and ``err``, carrying the trajectory (the last completed state included).
        """
        return SimulationError(f"simulation stopped at step {step} (t={t_new:g} s): {type(err).__name__}: {err}; "
                               f"{self.kept()}", self.trajectory(keep_last=True), step=step)

    def finish(self) -> Trajectory | None:
        """The trajectory (None on processes other than the root), after reporting energy growth, failed steps and
        fallbacks once (warnings, on the root).

        Returns
        -------
        Trajectory or None
        """
        traj = self.trajectory()
        if traj is not None:
            self.check_energy_growth(traj)
            report(traj, self.integrator, stacklevel=4)
        return traj

    def check_energy_growth(self, traj: Trajectory) -> None:
        """Warn once (:class:`~springsim.errors.EnergyGrowthWarning`) when the recorded frames of a scene whose
        forces all conserve or dissipate energy rise above the first frame's energy by more than
        :data:`ENERGY_GROWTH` of the start's energy scale, and in a damped scene fail the step of that frame.

        Only the recorded frames are checked (no cost per step); the energy bound catches the larger blow-ups on
        every step. Bounded oscillations of a symplectic method stay below the threshold.

        Parameters
        ----------
        traj : Trajectory
            The run's frames and step statistics (a failed step is marked in them).
        """
        terms = self.system.terms
        if self.bound is None or traj.frame_count < 2 or not all(t.conservative or t.dissipative for t in terms):
            return
        from .energy import total_energy

        energy = np.array(self.energies) if self.energies is not None else total_energy(self.model, traj.q, traj.qd)
        rise = energy - energy[0]
        k = int(np.argmax(rise))
        if not rise[k] > ENERGY_GROWTH * self.bound.scale:
            return
        damped = self.model.dissipates()
        msg = (f"{self.integrator.name}: the energy rose from {energy[0]:.4g} J to {energy[k]:.4g} J (t={traj.t[k]:g} "
               f"s) in a scene whose forces {'dissipate' if damped else 'conserve'} it: an instability; try a "
               f"smaller time step{' or an implicit integrator' if not self.integrator.implicit else ''}")
        if damped and traj.stats:
            step = min(max(int(round(traj.t[k] / max(self.time, 1e-300) * len(traj.stats))), 1), len(traj.stats))
            traj.stats[step - 1].fail(msg)
        if getattr(self.integrator, "on_nonconvergence", "warn") != "ignore":
            warnings.warn(msg, EnergyGrowthWarning, stacklevel=5)


def report(traj: Trajectory, integrator, stacklevel: int = 2) -> None:
    """Warn once about the run's steps that are not ``ok`` and once about linear-solver fallbacks.

    Honours the integrator's ``on_nonconvergence`` (``"ignore"``: no warning).

    Parameters
    ----------
    traj : Trajectory
        The run.
    integrator : Integrator
        The integrator that made it (its name goes in the messages).
    stacklevel : int
        ``stacklevel`` of the warnings.
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
             check_energy: bool = True, frames=None) -> Trajectory:
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
    frames : object, optional
        A sink for the frames on the root process: its ``append(q, qd)`` takes each one as it is recorded
        (:class:`springsim.io._spool.FrameSpool` streams them to a file), and the trajectory then holds none (``q`` and
        ``qd`` None). Default: the trajectory holds them.

    Returns
    -------
    Trajectory or None
        The frames; None on the processes other than the root of a distributed system (the root gathers them).

    Raises
    ------
    TypeError, ValueError
        On invalid arguments (naming the parameter).
    SimulationError
        On a blow-up (NaN/inf or the energy bound); ``err.trajectory`` has the finite frames before
        it (None on processes other than the root of a distributed system). Also wraps any other :class:`~springsim.errors.SpringsimError` the integrator raises
        mid-run (e.g. ``SolverError``), kept as ``__cause__``.
    SimulationInterrupted
        On KeyboardInterrupt (also from ``progress``), with the frames so far. Over several processes every
        process raises it after the same step (:mod:`springsim.run.interrupts`).
    """
    dt = _positive_time("dt", dt)
    steps = _count("steps", steps, 0)
    frame_every = _count("frame_every", frame_every, 1)
    _check_integrator(model, integrator)
    with integrator.exclusive():  # one thread at a time: an integrator keeps state between steps
        return _simulate(model, integrator, dt, steps, state, frame_every, record, progress, check_energy, frames)


def _simulate(model, integrator, dt, steps, state, frame_every, record, progress, check_energy, frames=None):
    """:func:`simulate` once its arguments are checked and the integrator is held."""
    run = RunRecorder(model, integrator, state, check_energy=check_energy, frames=frames)
    progress = as_progress(progress) if run.is_root else None
    run.meta.update(dt=dt, steps=steps, frame_every=frame_every)
    k = 0
    # over several processes, signals are held until the processes agree after a step, and until the frames of
    # an interrupted run are gathered (springsim.run.interrupts)
    with collective_interrupts(run.system) as interrupted:
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
                    interrupted()
        except KeyboardInterrupt:
            raise run.interrupted(f"step {run.steps} of {steps}") from None
        except SimulationError:
            raise
        except SpringsimError as e:
            raise run.stopped(e, k, k * dt) from e
        return run.finish()
