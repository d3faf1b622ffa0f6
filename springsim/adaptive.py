"""Error-controlled adaptive time stepping with output frames at requested times.

The integrator (``bdf2`` or ``tr_bdf2``, or any integrator exposing ``error_estimate``
after each step, a pair ``(err_q, err_v)`` of (N, 3) arrays) takes a step of size ``h``;
the driver measures the local error in the weighted RMS norm over free DOFs::

    err = sqrt(mean((e_i / (atol + rtol max(|y_i^n|, |y_i^{n+1}|)))^2))

over positions and velocities (``error_on="qv"``, the default: the global position error
then scales with the tolerance) or position components only (``error_on="q"``; cheaper, but
the position error alone under-reports the velocity error that later becomes position error). A step is accepted when ``err <= 1`` and the
next step is::

    h_new = h min(grow, max(shrink, safety err^(-1/(p+1))))        p = integrator order (2)

with ``safety = 0.9``, ``grow = 4`` (2 for BDF2, whose variable-step form is zero-stable
only for step ratios below 1 + sqrt(2); 1 right after a rejection), ``shrink = 0.2``,
clipped to ``[h_min, h_max]``. A rejected step is retried from the same state (the
multistep history is reused, see :class:`~springsim.integrators.bdf2.StepHistory`);
a Newton failure (``newton_converged`` False or a non-finite state) counts as a rejection
and retries with ``h/4``. Failing at ``h_min`` raises :class:`SimulationError`.

Output frames at the requested times come from cubic Hermite interpolation of ``q`` between
the two step ends (values ``q``, slopes ``qd``); velocities are the derivative of that cubic.
A frame time that coincides with a step end (within ``1e-12`` relative) takes that state
exactly; the last step is shortened to land on ``t_end``.
"""

from __future__ import annotations

import time
import warnings

import numpy as np

from .driver import SimulationInterrupted, Trajectory
from .errors import SceneError, SimulationError
from .integrators import Integrator, NewtonConvergenceWarning, StepStats, make_integrator

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


def simulate_adaptive(model, integrator, t_end: float, *, frame_dt: float | None = None, t_frames=None,
                      time_rtol: float = 1e-3, time_atol: float = 1e-4, h0: float | None = None,
                      h_min: float = 1e-7, h_max: float | None = None, error_on: str = "qv", state=None,
                      safety: float = 0.9, grow: float = 4.0, shrink: float = 0.2, max_steps: int = 1_000_000,
                      progress=None, **integrator_options) -> Trajectory:
    """Integrate to ``t_end`` with step sizes chosen from a local error estimate.

    Parameters
    ----------
    model : Model
    integrator : str or Integrator
        ``"bdf2"``, ``"tr_bdf2"`` or an instance exposing ``error_estimate``.
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
    progress : callable(t, t_end), optional
        Called after each accepted step.
    **integrator_options
        Passed to :func:`~springsim.integrators.make_integrator` when ``integrator`` is a name
        (``solver``, ``jacobian``, ``newton_tol``, ...).

    Returns
    -------
    Trajectory
        Frames at ``0`` and the requested times; ``stats`` holds the accepted steps' StepStats;
        ``adaptive_stats`` (attribute) a dict: ``accepted``, ``rejected``, ``newton_failures``,
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
        raise SceneError("simulation.duration", f"must be finite and > 0, got {t_end}")
    if not time_rtol >= 0 or not time_atol >= 0 or (time_rtol == 0 and time_atol == 0):
        raise SceneError("solver.time_rtol", f"time_rtol and time_atol must be >= 0 and not both 0, got "
                                             f"{time_rtol}, {time_atol}")
    if error_on not in ("q", "qv"):
        raise ValueError(f"error_on must be 'q' or 'qv', got {error_on!r}")
    if t_frames is not None:
        t_frames = np.asarray(t_frames, dtype=np.float64).ravel()
        if t_frames.size and (np.any(np.diff(t_frames) <= 0) or t_frames[0] <= 0 or t_frames[-1] > t_end):
            raise SceneError("simulation.t_frames", "must be increasing and in (0, t_end]")
    elif frame_dt is not None:
        if not frame_dt > 0:
            raise SceneError("simulation.frame_dt", f"must be > 0, got {frame_dt}")
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
        raise SceneError("solver.h_min", f"need 0 < h_min <= h_max, got {h_min}, {h_max}")
    h = min(h_max, 1e-3) if h0 is None else float(h0)
    h = min(max(h, h_min), h_max)

    if isinstance(integrator, str):
        integrator_options.setdefault("on_nonconvergence", "ignore")
        integrator = make_integrator(integrator, model, **integrator_options)
    if not isinstance(integrator, Integrator) or not hasattr(integrator, "error_estimate"):
        raise SceneError("solver.type", f"adaptive stepping needs an integrator with an error estimate "
                                        f"(bdf2, tr_bdf2), got {getattr(integrator, 'name', integrator)!r}")
    integrator.reset()
    order = getattr(integrator, "order", 2)
    grow = min(grow, getattr(integrator, "max_step_ratio", grow))
    expo = -1.0 / (order + 1)
    free = model.free_particles

    s0 = model.state() if state is None else state.copy()
    s1 = s0.copy()
    t = 0.0
    ts, qs, qds = [0.0], [s0.particle_q.copy()], [s0.particle_qd.copy()]
    stats: list[StepStats] = []
    info = dict(accepted=0, rejected=0, newton_failures=0, newton_iterations=0, linear_iterations=0,
                h_min=np.inf, h_max=0.0, h_mean=0.0)
    fi = 0
    wall0 = time.perf_counter()
    just_rejected = False
    attempts = 0

    def trajectory():
        tr = Trajectory(np.array(ts), np.array(qs), np.array(qds), stats, time.perf_counter() - wall0)
        info["h_mean"] = float(t / max(info["accepted"], 1))
        tr.adaptive_stats = dict(info)
        return tr

    try:
        while fi < t_frames.size:
            attempts += 1
            if attempts > max_steps:
                raise SimulationError(f"adaptive stepping exceeded max_steps={max_steps} at t={t:g} s",
                                      trajectory(), step=info["accepted"])
            last = t + h >= t_end * (1 - 1e-12) or t_end - (t + h) < h_min
            if last:
                h = t_end - t
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", NewtonConvergenceWarning)
                st = integrator.step(s0, s1, h)
            info["newton_iterations"] += st.newton_iterations
            info["linear_iterations"] += st.linear_iterations
            finite = s1.is_finite()
            if not finite or not st.newton_converged:
                info["rejected"] += 1
                info["newton_failures"] += 1
                if h <= h_min * (1 + 1e-12):
                    why = "non-finite state" if not finite else "Newton did not converge"
                    raise SimulationError(f"adaptive stepping failed at t={t:g} s with h=h_min={h_min:g} s "
                                          f"({why}); kept {len(ts)} finite frame(s)", trajectory(),
                                          step=info["accepted"])
                h = max(h_min, 0.25 * h)
                just_rejected = True
                continue
            eq, ev = integrator.error_estimate
            err = _error_norm(eq, s0.particle_q, s1.particle_q, free, time_rtol, time_atol)
            if error_on == "qv":
                err = np.sqrt(0.5 * (err**2 + _error_norm(ev, s0.particle_qd, s1.particle_qd, free,
                                                          time_rtol, time_atol)**2))
            fac = safety * err**expo if err > 0 else grow
            if err > 1.0 and h > h_min * (1 + 1e-12):
                info["rejected"] += 1
                h = max(h_min, h * min(0.9, max(shrink, fac)))
                just_rejected = True
                continue
            # accepted
            t1 = t + h
            info["accepted"] += 1
            info["h_min"] = float(min(info["h_min"], h))
            info["h_max"] = float(max(info["h_max"], h))
            stats.append(st)
            while fi < t_frames.size and t_frames[fi] <= t1 * (1 + 1e-12):
                tf = t_frames[fi]
                if abs(tf - t1) <= 1e-12 * max(t1, 1.0):
                    qf, vf = s1.particle_q.copy(), s1.particle_qd.copy()
                else:
                    qf, vf = hermite_frame(t, s0.particle_q, s0.particle_qd, t1, s1.particle_q, s1.particle_qd,
                                           tf)
                    qf[model.particle_fixed] = s1.particle_q[model.particle_fixed]
                    vf[model.particle_fixed] = 0.0
                ts.append(float(tf))
                qs.append(qf)
                qds.append(vf)
                fi += 1
            s0, s1 = s1, s0
            t = t1
            if progress is not None:
                progress(t, t_end)
            h = h * min(1.0 if just_rejected else grow, max(shrink, fac))
            h = min(max(h, h_min), h_max)
            just_rejected = False
    except KeyboardInterrupt:
        raise SimulationInterrupted(f"interrupted at t={t:g} s; kept {len(ts)} frame(s)", trajectory(),
                                    step=info["accepted"]) from None
    return trajectory()


def _error_norm(e, y0, y1, free, rtol, atol):
    """Weighted RMS norm of the error estimate ``e`` over free particles."""
    sc = atol + rtol * np.maximum(np.abs(y0[free]), np.abs(y1[free]))
    return float(np.sqrt(np.mean((e[free] / sc) ** 2))) if free.size else 0.0
