"""Error-controlled adaptive time stepping with output frames at requested times.

The integrator (``bdf2``, ``tr_bdf2`` or ``energy_momentum``: any with ``has_error_estimate``,
which sets ``error_estimate``, a pair ``(err_q, err_v)`` of (N, 3) arrays, after each step while
its ``estimating`` flag is set, as it is during the run) takes a step of size ``h``;
the driver measures the local error in the weighted RMS norm over free DOFs::

    err = sqrt(mean((e_i / (atol + rtol max(|y_i^n|, |y_i^{n+1}|)))^2))

over positions and velocities (``error_on="qv"``, the default: the global position error
then scales with the tolerance) or position components only (``error_on="q"``; cheaper, but
the position error alone under-reports the velocity error that later becomes position error).
A step is accepted when ``err <= 1`` and the
next step is::

    h_new = h min(grow, max(shrink, safety err^(-1/(p+1))))        p = integrator order (2)

with ``safety = 0.9``, ``grow = 4`` (2 for BDF2, whose variable-step form is zero-stable
only for step ratios below 1 + sqrt(2); 1 right after a rejection), ``shrink = 0.2``,
clipped to ``[h_min, h_max]`` (:class:`StepSizeController`; :func:`simulate_adaptive` is the
loop that uses it). A rejected step is retried from the same state (the
multistep history is reused, see :class:`~springsim.integrators.bdf2.StepHistory`).
A failed attempt (a step that is not ``StepStats.ok``: Newton missed its limit, a linear
solve failed, the matrix lost the masses; a :class:`~springsim.errors.SolverError`; a
blow-up by NaN/inf or the energy bound of :mod:`springsim.run.energy`) is retried with ``h/4``.
Failing at ``h_min``, or missing the tolerance there, raises :class:`~springsim.errors.SimulationError`
with the frames so far, as a fixed-step run does (:mod:`springsim.run.driver`): a step is never accepted
with an error above the tolerance.

The stages of implicit integrators stop at their ``force_rtol`` capped at ``NEWTON_SHARE`` (0.1) times
``time_rtol`` (``time_atol`` when ``time_rtol`` is 0; never below ``NEWTON_FLOOR``, 1e-10;
:attr:`~springsim.integrators._stage.StageSolver.force_rtol_cap`) for the run, so that the Newton error stays a
fraction of the error the test accepts, as stiff ODE codes do (CVODE stops Newton at 0.1 of its error test,
Hindmarsh et al. 2005): a step is judged on its truncation error, not on an unfinished solve.

Output frames at the requested times come from cubic Hermite interpolation of ``q`` between
the two step ends (values ``q``, slopes ``qd``); velocities are the derivative of that cubic.
A frame time that coincides with a step end (within ``1e-12`` relative) takes that state
exactly; the last step is shortened to land on ``t_end`` (where less than ``h_min`` would remain after a
step, the remainder is split into two equal steps, never one step longer than the controller proposed).
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

from .._runtime.threads import single_blas_thread
from ..errors import SceneError, SimulationError, SpringsimError
from ..integrators import INTEGRATORS, Integrator, StepStats, make_integrator
from ..model import Model, State
from ..progress import as_progress
from .driver import RunRecorder, Trajectory
from .interrupts import collective_interrupts
from .options import ADAPTIVE_H_MIN

__all__ = ["simulate_adaptive", "StepSizeController", "hermite_frame", "NEWTON_SHARE", "NEWTON_FLOOR"]

#: The implicit stages of an adaptive run stop at ``force_rtol`` capped at this share of ``time_rtol`` (of
#: ``time_atol`` when ``time_rtol`` is 0): the Newton error below the error test (module docstring).
NEWTON_SHARE = 0.1
#: ... but never below this: a tighter force balance is round-off (the error test then fails on its own).
NEWTON_FLOOR = 1e-10


def hermite_frame(t0, q0, v0, t1, q1, v1, t):
    """Cubic Hermite interpolation at ``t`` in ``[t0, t1]``.

    Parameters
    ----------
    t0, t1, t : float
        Interval ends and evaluation time [s].
    q0, v0, q1, v1 : ndarray (N, 3)
        Positions [m] and velocities [m/s] at both ends.

    Returns
    -------
    q, v : ndarray (N, 3)
        Interpolated position [m] and its time derivative [m/s].
    """
    h = t1 - t0
    s = (t - t0) / h
    h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
    d00, d10, d01, d11 = 6 * s**2 - 6 * s, 3 * s**2 - 4 * s + 1, -6 * s**2 + 6 * s, 3 * s**2 - 2 * s
    q = h00 * q0 + (h10 * h) * v0 + h01 * q1 + (h11 * h) * v1
    v = (d00 * q0 + d01 * q1) / h + d10 * v0 + d11 * v1
    return q, v


def _check_step_bounds(h_min: float, h_max: float) -> None:
    if not (0 < h_min <= h_max):
        raise SceneError("h_min", f"need 0 < h_min <= h_max, got {h_min}, {h_max}")


class StepSizeController:
    """The step-size controller of adaptive stepping: accept or reject a step by its error, and the next step.

    For a method of order ``p`` whose local error estimate, in the weighted RMS norm scaled by the
    tolerances, is ``err``, a step is accepted when ``err <= 1``, and the next step size is the
    elementary controller of Hairer, Nørsett and Wanner (*Solving Ordinary Differential Equations I*,
    2nd ed., Springer 1993, section II.4, eqs. 4.12-4.13)::

        fac   = safety err^(-1/(p+1))            (grow when err = 0)
        h_new = h min(grow, max(shrink, fac))    after an accepted step (grow = 1 right after a rejection)
        h_new = h min(0.9, max(shrink, fac))     after a rejected one (at least 10 % smaller)
        h_new = h / 4                            after a failed attempt (no usable step)

    always clipped to ``[h_min, h_max]`` (a rejection or failure only from below). The factor
    ``err^(-1/(p+1))`` is the step that would have given ``err = 1`` if the error behaved as
    ``C h^(p+1)``; ``safety`` keeps the next step below it so that it is likely accepted, ``grow`` and
    ``shrink`` bound the change from one step to the next, and no growth right after a rejection
    avoids alternating rejections (Hairer, Nørsett and Wanner I, II.4).

    Parameters
    ----------
    order : int
        Order ``p`` of the integrator (its local error is ``O(h^(p+1))``).
    h_min, h_max : float
        Step size bounds [s], ``0 < h_min <= h_max``.
    safety : float
        Safety factor (default :attr:`SAFETY`, 0.9).
    grow : float
        Largest ratio of consecutive steps (default :attr:`GROW`, 4; an integrator whose variable-step form is
        zero-stable only below some ratio passes the smaller of the two).
    shrink : float
        Smallest ratio of consecutive steps (default :attr:`SHRINK`, 0.2).

    Raises
    ------
    SceneError
        When the step bounds are not ``0 < h_min <= h_max`` (naming ``h_min``).
    """

    #: Default safety factor.
    SAFETY = 0.9
    #: Default largest ratio of consecutive steps.
    GROW = 4.0
    #: Default smallest ratio of consecutive steps.
    SHRINK = 0.2
    #: Largest factor of a rejected step: it shrinks by at least 10 %, whatever its error.
    REJECT_FACTOR = 0.9
    #: Factor of a failed attempt (the step gave no usable result: Newton or a linear solve failed, a blow-up).
    FAILURE_FACTOR = 0.25

    def __init__(self, order: int, *, h_min: float, h_max: float, safety: float = SAFETY, grow: float = GROW,
                 shrink: float = SHRINK):
        _check_step_bounds(h_min, h_max)
        self.order = order
        self.h_min, self.h_max = h_min, h_max
        self.safety, self.grow, self.shrink = safety, grow, shrink
        self.exponent = -1.0 / (order + 1)
        #: Whether the last step was rejected or failed (the next accepted step does not grow).
        self.just_rejected = False

    def first_step(self, h0: float | None = None) -> float:
        """The first step: ``h0`` (default ``min(1e-3, h_max)``) clipped to ``[h_min, h_max]``.

        Parameters
        ----------
        h0 : float, optional
            Requested first step [s].

        Returns
        -------
        float
        """
        h = min(self.h_max, 1e-3) if h0 is None else float(h0)
        return min(max(h, self.h_min), self.h_max)

    def fit(self, h: float, remaining: float) -> float:
        """The step to take when ``remaining`` [s] are left: ``h``, or the rest when ``h`` reaches (or nearly
        reaches) it, or half of the rest when less than ``h_min`` would remain after ``h`` (two steps to the end,
        never one longer than proposed).

        Parameters
        ----------
        h : float
            Proposed step [s].
        remaining : float
            Time left to the end of the run [s].

        Returns
        -------
        float
        """
        if h >= remaining * (1 - 1e-12):
            return remaining
        if remaining - h < self.h_min:
            return 0.5 * remaining
        return h

    def accepts(self, err: float) -> bool:
        """Whether a step with the scaled error ``err`` is accepted (``err <= 1``).

        Parameters
        ----------
        err : float
            The local error estimate in the tolerance-weighted norm.

        Returns
        -------
        bool
        """
        return err <= 1.0

    def at_h_min(self, h: float) -> bool:
        """Whether ``h`` is the smallest step (within a relative ``1e-12``): a rejection there ends the run.

        Parameters
        ----------
        h : float
            Step [s].

        Returns
        -------
        bool
        """
        return h <= self.h_min * (1 + 1e-12)

    def factor(self, err: float) -> float:
        """``safety err^(-1/(p+1))``, the unbounded ratio of the next step to this one (``grow`` for ``err = 0``).

        Parameters
        ----------
        err : float
            The local error estimate in the tolerance-weighted norm.

        Returns
        -------
        float
        """
        return self.safety * err ** self.exponent if err > 0 else self.grow

    def accepted(self, h: float, err: float) -> float:
        """The step after an accepted step ``h`` with error ``err``.

        Parameters
        ----------
        h : float
            The accepted step [s].
        err : float
            Its scaled error (``<= 1``).

        Returns
        -------
        float
            ``h min(grow, max(shrink, fac))`` (``grow`` 1 right after a rejection) in ``[h_min, h_max]``.
        """
        h = h * min(1.0 if self.just_rejected else self.grow, max(self.shrink, self.factor(err)))
        self.just_rejected = False
        return min(max(h, self.h_min), self.h_max)

    def rejected(self, h: float, err: float) -> float:
        """The retry after rejecting step ``h`` for its error ``err``.

        Parameters
        ----------
        h : float
            The rejected step [s].
        err : float
            Its scaled error (``> 1``).

        Returns
        -------
        float
            ``h min(0.9, max(shrink, fac))``, at least ``h_min``.
        """
        self.just_rejected = True
        return max(self.h_min, h * min(self.REJECT_FACTOR, max(self.shrink, self.factor(err))))

    def failed(self, h: float) -> float:
        """The retry after a failed attempt of step ``h`` (no usable step to measure).

        Parameters
        ----------
        h : float
            The failed step [s].

        Returns
        -------
        float
            ``h / 4``, at least ``h_min``.
        """
        self.just_rejected = True
        return max(self.h_min, self.FAILURE_FACTOR * h)


def _frame_times(t_end: float, frame_dt: float | None, t_frames) -> np.ndarray:
    """The output times in ``(0, t_end]``: ``t_frames``, else every ``frame_dt`` and ``t_end``, else ``t_end``."""
    if t_frames is not None:
        t_frames = np.asarray(t_frames, dtype=np.float64).ravel()
        if t_frames.size and (np.any(np.diff(t_frames) <= 0) or t_frames[0] <= 0 or t_frames[-1] > t_end):
            raise SceneError("t_frames", "must be increasing and in (0, t_end]")
        return t_frames
    if frame_dt is not None:
        if not frame_dt > 0:
            raise SceneError("frame_dt", f"must be > 0, got {frame_dt}")
        k = int(np.floor(t_end / frame_dt + 1e-9))
        t_frames = frame_dt * np.arange(1, k + 1)
        if t_frames.size == 0 or t_end - t_frames[-1] > 1e-12 * t_end:
            t_frames = np.append(t_frames, t_end)
        t_frames[-1] = min(t_frames[-1], t_end)
        return t_frames
    return np.array([t_end])


def _adaptive_integrator(model: Model, integrator: str | Integrator, options: dict) -> Integrator:
    """``integrator`` (built for ``model`` from its name and ``options``), checked to have an error estimate."""
    if isinstance(integrator, str):
        integrator = make_integrator(integrator, model, **options)
    elif options:
        raise TypeError(f"integrator options ({', '.join(options)}) need an integrator name, not an instance")
    if not isinstance(integrator, Integrator) or not integrator.has_error_estimate:
        raise SceneError("integrator", f"adaptive stepping needs an integrator with an error estimate "
                                        f"({', '.join(k for k, c in INTEGRATORS.items() if c.has_error_estimate)}), "
                                        f"got {getattr(integrator, 'name', integrator)!r}")
    return integrator


def simulate_adaptive(model: Model, integrator: str | Integrator, t_end: float, *, frame_dt: float | None = None,
                      t_frames=None, time_rtol: float = 1e-3, time_atol: float = 1e-4, h0: float | None = None,
                      h_min: float = ADAPTIVE_H_MIN, h_max: float | None = None, error_on: str = "qv",
                      state: State | None = None, safety: float = StepSizeController.SAFETY,
                      grow: float = StepSizeController.GROW, shrink: float = StepSizeController.SHRINK,
                      max_steps: int = 1_000_000, progress: Callable[[float, float], None] | bool | None = None,
                      frames=None, **integrator_options) -> Trajectory:
    """Integrate to ``t_end`` with step sizes chosen from a local error estimate.

    The loop: take a step, measure its error, let a :class:`StepSizeController` accept or
    reject it and choose the next step, interpolate the frames an accepted step covers.

    Parameters
    ----------
    model : Model
    integrator : str or Integrator
        ``"bdf2"``, ``"tr_bdf2"``, ``"energy_momentum"`` or an instance of an integrator with ``has_error_estimate``,
        built for ``model``.
    t_end : float
        Final time [s], > 0.
    frame_dt : float, optional
        Output every ``frame_dt`` [s] (the last frame is ``t_end``).
    t_frames : array_like, optional
        Increasing output times in ``(0, t_end]`` [s]; frame 0 (t = 0) is always recorded.
        Default: only ``t_end``.
    time_rtol, time_atol : float
        Local error tolerances of the time integration (``atol`` in m, and m/s for velocities);
        distinct from the linear solver's tolerance.
    h0 : float, optional
        First step [s] (default ``min(1e-3, h_max)``).
    h_min, h_max : float
        Step size bounds [s] (default ``h_max = t_end / 10``; steps may span several frames,
        which are interpolated).
    error_on : {"q", "qv"}
        Components the error norm covers.
    state : State, optional
        Initial state (default ``model.state()``).
    safety, grow, shrink : float
        Controller constants (:class:`StepSizeController`; ``grow`` is capped by the integrator's
        ``max_step_ratio``).
    max_steps : int
        Limit on attempted steps.
    progress : callable(t, t_end) or True, optional
        Called after each accepted step; True logs a line every few seconds with the time left
        (:class:`springsim.progress.ProgressLog`, logger ``springsim``).
    frames : object, optional
        A sink for the root's frames (:func:`springsim.simulate`): the trajectory then holds none.
    **integrator_options
        Passed to :func:`~springsim.integrators.make_integrator` when ``integrator`` is a name
        (``solver``, ``jacobian``, ``newton_tol``, ...).

    Returns
    -------
    Trajectory
        Frames at ``0`` and the requested times; ``stats`` holds the accepted steps' StepStats;
        ``adaptive_stats`` a dict: ``accepted``, ``rejected`` (all rejections), ``failed_attempts``
        (those that failed rather than missed the tolerance), ``newton_failures``,
        ``newton_iterations``, ``linear_iterations``, ``h_min``, ``h_max``, ``h_mean``.

    Raises
    ------
    SceneError
        On invalid tolerances, step bounds or frame times (one-line message naming the field).
    SimulationError
        On blow-up or when the step falls below ``h_min``; ``err.trajectory`` has the finite frames.
    ~springsim.errors.SimulationInterrupted
        On Ctrl-C (a ``KeyboardInterrupt``); ``err.trajectory`` has the frames so far. Over several processes every
        process raises it after the same attempt (:mod:`springsim.run.interrupts`).
    """
    t_end = float(t_end)
    if not (np.isfinite(t_end) and t_end > 0):
        raise SceneError("t_end", f"must be finite and > 0, got {t_end}")
    if not time_rtol >= 0 or not time_atol >= 0 or (time_rtol == 0 and time_atol == 0):
        raise SceneError("time_rtol", f"time_rtol and time_atol must be >= 0 and not both 0, got "
                                             f"{time_rtol}, {time_atol}")
    if error_on not in ("q", "qv"):
        raise ValueError(f"error_on must be 'q' or 'qv', got {error_on!r}")
    t_frames = _frame_times(t_end, frame_dt, t_frames)
    if h_max is None:
        h_max = t_end / 10
    _check_step_bounds(h_min, h_max)
    progress = as_progress(progress)
    integrator = _adaptive_integrator(model, integrator, integrator_options)
    integrator.reset()
    control = StepSizeController(integrator.order, h_min=h_min, h_max=h_max, safety=safety,
                                 grow=min(grow, integrator.max_step_ratio), shrink=shrink)
    h = control.first_step(h0)
    system = integrator.system
    fixed = system.fixed

    run = RunRecorder(model, integrator, state, frames=frames)
    if not run.is_root:
        progress = None
    run.meta.update(t_end=t_end, time_rtol=float(time_rtol), time_atol=float(time_atol))
    info: dict[str, Any] = dict(accepted=0, rejected=0, newton_failures=0, failed_attempts=0, newton_iterations=0,
                                linear_iterations=0, h_min=np.inf, h_max=0.0, h_mean=0.0)
    run.adaptive_stats = info
    fi = 0
    t = 0.0
    attempts = 0
    guard = integrator.exclusive()  # one thread at a time: an integrator keeps state between steps
    guard.__enter__()
    estimating, retake = integrator.estimating, getattr(integrator, "retake", False)
    integrator.estimating = True  # restored when the run ends
    if retake:
        integrator.retake = False  # a failed step is retried smaller here, not retaken in substeps
    stage = getattr(integrator, "stage", None)  # the stage solver of an implicit integrator
    cap = None if stage is None else stage.force_rtol_cap
    if stage is not None:  # the Newton error below the error test (restored when the run ends)
        share = max(NEWTON_SHARE * float(time_rtol if time_rtol > 0 else time_atol), NEWTON_FLOOR)
        stage.force_rtol_cap = share if cap is None else min(cap, share)
    # over several processes, signals are held until the processes agree after an attempt, and until the frames
    # of an interrupted run are gathered (springsim.run.interrupts)
    with collective_interrupts(system) as interrupted:
        try:
            with single_blas_thread():
                while fi < t_frames.size:
                    interrupted()  # every process stops at the same attempt (springsim.run.interrupts)
                    attempts += 1
                    if attempts > max_steps:
                        raise SimulationError(f"adaptive stepping exceeded max_steps={max_steps} at t={t:g} s; "
                                              f"{run.kept()}",
                                              run.trajectory(keep_last=True), step=info["accepted"])
                    h = control.fit(h, t_end - t)
                    st, why = _attempt(run, integrator, h, info)
                    if why is not None:  # no usable step: retry smaller
                        info["rejected"] += 1
                        info["failed_attempts"] += 1
                        info["newton_failures"] += st is not None and not st.newton_converged
                        if control.at_h_min(h):
                            raise SimulationError(f"adaptive stepping failed at t={t:g} s with h = h_min = "
                                                  f"{h_min:g} s: {why}; {run.kept()}",
                                                  run.trajectory(keep_last=True), step=info["accepted"])
                        h = control.failed(h)
                        continue
                    assert integrator.error_estimate is not None  # checked by _attempt
                    eq, ev = integrator.error_estimate
                    q0, v0 = run.state.particle_q, run.state.particle_qd
                    q1, v1 = run.scratch.particle_q, run.scratch.particle_qd
                    err = _error_norm(system, eq, q0, q1, time_rtol, time_atol)
                    if error_on == "qv":
                        err = np.sqrt(0.5 * (err**2 + _error_norm(system, ev, v0, v1, time_rtol, time_atol)**2))
                    if not control.accepts(err):
                        info["rejected"] += 1
                        if control.at_h_min(h):  # never accepted as if it had met the tolerance
                            raise SimulationError(f"adaptive stepping cannot meet the tolerance at t={t:g} s: the "
                                                  f"local error is {err:.3g} times time_rtol/time_atol at h = h_min = "
                                                  f"{h_min:g} s; loosen the tolerance or lower h_min; {run.kept()}",
                                                  run.trajectory(keep_last=True), step=info["accepted"])
                        h = control.rejected(h, err)
                        continue
                    # accepted: frames in (t, t1] by Hermite interpolation (exactly the state at t1)
                    t1 = t + h
                    info["accepted"] += 1
                    info["h_min"] = float(min(info["h_min"], h))
                    info["h_max"] = float(max(info["h_max"], h))
                    frames: list[tuple | None] = []
                    while fi < t_frames.size and t_frames[fi] <= t1 * (1 + 1e-12):
                        tf = t_frames[fi]
                        if abs(tf - t1) <= 1e-12 * max(t1, 1.0):
                            frames.append(None)
                        else:
                            qf, vf = hermite_frame(t, q0, v0, t1, q1, v1, tf)
                            qf[fixed] = q1[fixed]
                            vf[fixed] = 0.0
                            frames.append((tf, qf, vf))
                        fi += 1
                    run.accept(st, t1)
                    for fr in frames:
                        if fr is None:
                            run.record_current()
                        else:
                            run.add_frame(*fr)
                    t = t1
                    info["h_mean"] = float(t / info["accepted"])
                    if progress is not None:
                        progress(t, t_end)
                    h = control.accepted(h, err)
                interrupted()  # a signal during the last attempt
        except KeyboardInterrupt:
            raise run.interrupted(f"t={t:g} s of {t_end:g} s") from None
        finally:
            integrator.estimating = estimating
            if retake:
                integrator.retake = True
            if stage is not None:
                stage.force_rtol_cap = cap
            guard.__exit__(None, None, None)
        return run.finish()


def _attempt(run: RunRecorder, integrator: Integrator, h: float, info: dict) -> tuple[StepStats | None, str | None]:
    """Take a step of ``h``: ``(its StepStats or None, why it gave no usable step or None)``; counts its iterations
    in ``info``. A solver error (a solve with no usable solution) is such a failure, like a failed Newton."""
    try:
        st = run.step(h)
    except SimulationError:
        raise
    except SpringsimError as e:
        return None, f"{type(e).__name__}: {e}"
    info["newton_iterations"] += st.newton_iterations
    info["linear_iterations"] += st.linear_iterations
    why = run.problem() or (None if st.ok else "; ".join(st.failures))
    if why is None and integrator.error_estimate is None:
        why = f"{integrator.name} gave no error estimate for the step"
    return st, why


def _error_norm(system, e, y0, y1, rtol, atol):
    """Weighted RMS norm of the error estimate ``e`` over the free particles of every process."""
    count = system.free_dof_count
    if not count:
        return 0.0
    rows = system.free_rows
    sc = atol + rtol * np.maximum(np.abs(rows(y0)), np.abs(rows(y1)))
    return float(np.sqrt(system.sum(float(np.sum((rows(e) / sc) ** 2))) / count))
