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
clipped to ``[h_min, h_max]``. A rejected step is retried from the same state (the
multistep history is reused, see :class:`~springsim.integrators.bdf2.StepHistory`).
A failed attempt (a step that is not ``StepStats.ok``: Newton missed its limit, a linear
solve failed, the matrix lost the masses; a :class:`~springsim.errors.SolverError`; a
blow-up by NaN/inf or the energy bound of :mod:`springsim.energy`) is retried with ``h/4``.
Failing at ``h_min``, or missing the tolerance there, raises :class:`~springsim.errors.SimulationError`
with the frames so far, as a fixed-step run does (:mod:`springsim.driver`): a step is never accepted
with an error above the tolerance.

Output frames at the requested times come from cubic Hermite interpolation of ``q`` between
the two step ends (values ``q``, slopes ``qd``); velocities are the derivative of that cubic.
A frame time that coincides with a step end (within ``1e-12`` relative) takes that state
exactly; the last step is shortened to land on ``t_end`` (where less than ``h_min`` would remain after a
step, the remainder is split into two equal steps, never one step longer than the controller proposed).
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

from ._threads import single_blas_thread
from .driver import RunRecorder, Trajectory
from .errors import SceneError, SimulationError, SpringsimError
from .integrators import INTEGRATORS, Integrator, StepStats, make_integrator
from .model import Model, State
from .progress import as_progress

__all__ = ["simulate_adaptive", "hermite_frame"]


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


def simulate_adaptive(model: Model, integrator: str | Integrator, t_end: float, *, frame_dt: float | None = None,
                      t_frames=None, time_rtol: float = 1e-3, time_atol: float = 1e-4, h0: float | None = None,
                      h_min: float = 1e-7, h_max: float | None = None, error_on: str = "qv",
                      state: State | None = None, safety: float = 0.9, grow: float = 4.0, shrink: float = 0.2,
                      max_steps: int = 1_000_000, progress: Callable[[float, float], None] | bool | None = None,
                      **integrator_options) -> Trajectory:
    """Integrate to ``t_end`` with step sizes chosen from a local error estimate.

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
        Controller constants (see module docstring).
    max_steps : int
        Limit on attempted steps.
    progress : callable(t, t_end) or True, optional
        Called after each accepted step; True logs a line every few seconds with the time left
        (:class:`springsim.progress.ProgressLog`, logger ``springsim``).
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
    """
    t_end = float(t_end)
    if not (np.isfinite(t_end) and t_end > 0):
        raise SceneError("t_end", f"must be finite and > 0, got {t_end}")
    if not time_rtol >= 0 or not time_atol >= 0 or (time_rtol == 0 and time_atol == 0):
        raise SceneError("time_rtol", f"time_rtol and time_atol must be >= 0 and not both 0, got "
                                             f"{time_rtol}, {time_atol}")
    if error_on not in ("q", "qv"):
        raise ValueError(f"error_on must be 'q' or 'qv', got {error_on!r}")
    if t_frames is not None:
        t_frames = np.asarray(t_frames, dtype=np.float64).ravel()
        if t_frames.size and (np.any(np.diff(t_frames) <= 0) or t_frames[0] <= 0 or t_frames[-1] > t_end):
            raise SceneError("t_frames", "must be increasing and in (0, t_end]")
    elif frame_dt is not None:
        if not frame_dt > 0:
            raise SceneError("frame_dt", f"must be > 0, got {frame_dt}")
        k = int(np.floor(t_end / frame_dt + 1e-9))
        t_frames = frame_dt * np.arange(1, k + 1)
        if t_frames.size == 0 or t_end - t_frames[-1] > 1e-12 * t_end:
            t_frames = np.append(t_frames, t_end)
        t_frames[-1] = min(t_frames[-1], t_end)
    else:
        t_frames = np.array([t_end])
    if h_max is None:
        h_max = t_end / 10
    if not (0 < h_min <= h_max):
        raise SceneError("h_min", f"need 0 < h_min <= h_max, got {h_min}, {h_max}")
    h = min(h_max, 1e-3) if h0 is None else float(h0)
    h = min(max(h, h_min), h_max)
    progress = as_progress(progress)

    if isinstance(integrator, str):
        integrator = make_integrator(integrator, model, **integrator_options)
    elif integrator_options:
        raise TypeError(f"integrator options ({', '.join(integrator_options)}) need an integrator name, not an "
                        f"instance")
    if not isinstance(integrator, Integrator) or not integrator.has_error_estimate:
        raise SceneError("integrator", f"adaptive stepping needs an integrator with an error estimate "
                                        f"({', '.join(k for k, c in INTEGRATORS.items() if c.has_error_estimate)}), "
                                        f"got {getattr(integrator, 'name', integrator)!r}")
    integrator.reset()
    grow = min(grow, integrator.max_step_ratio)
    expo = -1.0 / (integrator.order + 1)
    system = integrator.system
    fixed = system.fixed

    run = RunRecorder(model, integrator, state)
    if not run.is_root:
        progress = None
    run.meta.update(t_end=t_end, time_rtol=float(time_rtol), time_atol=float(time_atol))
    info: dict[str, Any] = dict(accepted=0, rejected=0, newton_failures=0, failed_attempts=0, newton_iterations=0,
                                linear_iterations=0, h_min=np.inf, h_max=0.0, h_mean=0.0)
    run.adaptive_stats = info
    fi = 0
    t = 0.0
    just_rejected = False
    attempts = 0
    guard = integrator.exclusive()  # one thread at a time: an integrator keeps state between steps
    guard.__enter__()
    estimating, retake = integrator.estimating, getattr(integrator, "retake", False)
    integrator.estimating = True  # restored when the run ends
    if retake:
        integrator.retake = False  # a failed step is retried smaller here, not retaken in substeps
    try:
        with single_blas_thread():
            while fi < t_frames.size:
                attempts += 1
                if attempts > max_steps:
                    raise SimulationError(f"adaptive stepping exceeded max_steps={max_steps} at t={t:g} s; "
                                          f"{run.kept()}",
                                          run.trajectory(keep_last=True), step=info["accepted"])
                remaining = t_end - t
                if h >= remaining * (1 - 1e-12):
                    h = remaining  # the last step lands on t_end
                elif remaining - h < h_min:
                    h = 0.5 * remaining  # two steps to t_end, not one stretched beyond the proposed size
                st: StepStats | None = None
                why: str | None
                try:
                    st = run.step(h)
                except SimulationError:
                    raise
                except SpringsimError as e:  # a solve with no usable solution: retry smaller, like a failed Newton
                    why = f"{type(e).__name__}: {e}"
                else:
                    info["newton_iterations"] += st.newton_iterations
                    info["linear_iterations"] += st.linear_iterations
                    why = run.problem() or (None if st.ok else "; ".join(st.failures))
                    if why is None and integrator.error_estimate is None:
                        why = f"{integrator.name} gave no error estimate for the step"
                if why is not None:
                    info["rejected"] += 1
                    info["failed_attempts"] += 1
                    info["newton_failures"] += st is not None and not st.newton_converged
                    if h <= h_min * (1 + 1e-12):
                        raise SimulationError(f"adaptive stepping failed at t={t:g} s with h = h_min = {h_min:g} s: "
                                              f"{why}; {run.kept()}", run.trajectory(keep_last=True),
                                              step=info["accepted"])
                    h = max(h_min, 0.25 * h)
                    just_rejected = True
                    continue
                assert integrator.error_estimate is not None  # checked above
                eq, ev = integrator.error_estimate
                q0, v0 = run.state.particle_q, run.state.particle_qd
                q1, v1 = run.scratch.particle_q, run.scratch.particle_qd
                err = _error_norm(system, eq, q0, q1, time_rtol, time_atol)
                if error_on == "qv":
                    err = np.sqrt(0.5 * (err**2 + _error_norm(system, ev, v0, v1, time_rtol, time_atol)**2))
                fac = safety * err**expo if err > 0 else grow
                if err > 1.0:
                    info["rejected"] += 1
                    if h <= h_min * (1 + 1e-12):  # never accepted as if it had met the tolerance
                        raise SimulationError(f"adaptive stepping cannot meet the tolerance at t={t:g} s: the local "
                                              f"error is {err:.3g} times time_rtol/time_atol at h = h_min = "
                                              f"{h_min:g} s; loosen the tolerance or lower h_min; {run.kept()}",
                                              run.trajectory(keep_last=True), step=info["accepted"])
                    h = max(h_min, h * min(0.9, max(shrink, fac)))
                    just_rejected = True
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
                h = h * min(1.0 if just_rejected else grow, max(shrink, fac))
                h = min(max(h, h_min), h_max)
                just_rejected = False
    except KeyboardInterrupt:
        raise run.interrupted(f"t={t:g} s of {t_end:g} s") from None
    finally:
        integrator.estimating = estimating
        if retake:
            integrator.retake = True
        guard.__exit__(None, None, None)
    return run.finish()


def _error_norm(system, e, y0, y1, rtol, atol):
    """Weighted RMS norm of the error estimate ``e`` over the free particles of every process."""
    count = system.free_dof_count
    if not count:
        return 0.0
    rows = system.free_rows
    sc = atol + rtol * np.maximum(np.abs(rows(y0)), np.abs(rows(y1)))
    return float(np.sqrt(system.sum(float(np.sum((rows(e) / sc) ** 2))) / count))
