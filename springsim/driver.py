"""Simulation driver: step an integrator, record frames, stop cleanly on blow-up.

After every step the new state is checked for NaN/inf; on blow-up
:func:`simulate` raises :class:`~springsim.errors.SimulationError` naming the step
and the first offending particle, carrying the finite frames computed before it
(``err.trajectory``). Any other :class:`~springsim.errors.SpringsimError` raised by
the integrator mid-run (a failed linear solve, Newton with ``on_nonconvergence="raise"``)
becomes a ``SimulationError`` with the frames so far and the original as ``__cause__``.
Ctrl-C does the same with :class:`SimulationInterrupted`. :func:`save_npz_atomic`
never leaves a partial file at the target path. See ``docs/robustness.md``.
"""

from __future__ import annotations

import os
import tempfile
import time
from dataclasses import dataclass, field

import numpy as np

from .errors import SimulationError, SpringsimError
from .integrators import Integrator, StepStats

__all__ = ["Trajectory", "simulate", "SimulationInterrupted", "save_npz_atomic"]


class SimulationInterrupted(SimulationError):
    """The run was interrupted (KeyboardInterrupt); ``trajectory`` holds the frames so far."""


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
        One per step taken.
    wall_s : float
        Wall time of the stepping loop [s].
    """

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    stats: list = field(default_factory=list)
    wall_s: float = 0.0

    @property
    def frame_count(self) -> int:
        return int(self.t.shape[0])

    def save(self, path) -> None:
        """Write ``t``, ``q``, ``qd`` to an ``.npz`` atomically (temporary file, then rename)."""
        save_npz_atomic(path, t=self.t, q=self.q, qd=self.qd)

    def summary(self) -> dict:
        """Aggregate statistics over all steps."""
        s = self.stats
        n = max(len(s), 1)
        return {
            "steps": len(s),
            "wall_s": self.wall_s,
            "step_s": self.wall_s / n,
            "assembly_s": sum(x.assembly_s for x in s) / n,
            "solve_s": sum(x.solve_s for x in s) / n,
            "newton_iterations": sum(x.newton_iterations for x in s) / n,
            "linear_iterations": sum(x.linear_iterations for x in s) / n,
            "newton_failures": sum(not x.newton_converged for x in s),
            "max_linear_residual": max((x.linear_residual for x in s), default=0.0),
            "fallbacks": sum(len(x.fallbacks) for x in s),
        }


def save_npz_atomic(path, **arrays) -> None:
    """Write ``arrays`` to the ``.npz`` file ``path`` atomically.

    ``np.savez`` writes to a temporary file in the target directory, which is
    flushed, fsync'ed and then renamed over ``path`` (``os.replace``, atomic on POSIX
    and Windows). On any failure (including KeyboardInterrupt) the temporary file is
    removed and ``path`` is left as it was: never a partial file.

    Parameters
    ----------
    path : str or PathLike
        Target file, used exactly as given (no ``.npz`` is appended).
    **arrays : ndarray
        Named arrays, as for ``np.savez``.
    """
    path = os.fspath(path)
    d = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=".npz", dir=d)
    try:
        with os.fdopen(fd, "wb") as fh:
            np.savez(fh, **arrays)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def simulate(model, integrator: Integrator, dt: float, steps: int, *, state=None, frame_every: int = 1,
             record: bool = True, progress=None) -> Trajectory:
    """Run ``steps`` steps of size ``dt`` [s] and return the :class:`Trajectory`.

    Parameters
    ----------
    model : Model
    integrator : Integrator
    dt : float
        Time step [s], > 0.
    steps : int
        Number of steps, >= 0.
    state : State, optional
        Initial state (default ``model.state()``).
    frame_every : int
        Record every k-th step (the initial and the final state are always recorded).
    record : bool
        If False, keep only the initial and final frames (large scenes).
    progress : callable(step, steps), optional
        Called after every step.

    Raises
    ------
    SimulationError
        On NaN/inf (blow-up); ``err.trajectory`` has the finite frames before it.
        Also wraps any other :class:`~springsim.errors.SpringsimError` the integrator
        raises mid-run (e.g. ``SolverError``), kept as ``__cause__``.
    SimulationInterrupted
        On KeyboardInterrupt (also from ``progress``), with the frames so far.
    """
    if not (dt > 0 and np.isfinite(dt)):
        raise ValueError(f"dt must be finite and > 0, got {dt}")
    if steps < 0:
        raise ValueError(f"steps must be >= 0, got {steps}")
    if int(frame_every) != frame_every or frame_every < 1:
        raise ValueError(f"frame_every must be an integer >= 1, got {frame_every}")
    s0 = model.state() if state is None else state.copy()
    if not s0.is_finite():
        raise ValueError("the initial state holds NaN or inf")
    s1 = s0.copy()
    ts, qs, qds = [0.0], [s0.particle_q.copy()], [s0.particle_qd.copy()]
    stats: list[StepStats] = []
    t0 = time.perf_counter()
    done = 0  # steps completed; s0 holds the (finite) state after them
    recorded = 0  # step of the last recorded frame

    def trajectory():
        return Trajectory(np.array(ts), np.array(qs), np.array(qds), stats, time.perf_counter() - t0)

    def keep_last():
        # on an early stop, also keep the last finite state when frame_every/record skipped it
        if recorded != done:
            ts.append(done * dt)
            qs.append(s0.particle_q.copy())
            qds.append(s0.particle_qd.copy())
        return trajectory()

    def kept():
        return f"kept {len(ts) + (recorded != done)} finite frame(s) up to t={done * dt:g} s"

    k = 0
    try:
        for k in range(1, steps + 1):
            with np.errstate(over="ignore", invalid="ignore"):  # a blow-up is reported below, once
                st = integrator.step(s0, s1, dt)
            stats.append(st)
            if not s1.is_finite():
                bad = ~(np.isfinite(s1.particle_q).all(axis=1) & np.isfinite(s1.particle_qd).all(axis=1))
                p = int(np.flatnonzero(bad)[0])
                msg = (f"simulation blew up at step {k} (t={k * dt:g} s): particle {p} has a non-finite "
                       f"position or velocity ({int(bad.sum())} particle(s) affected); {kept()}; "
                       f"try a smaller time step or an implicit integrator")
                raise SimulationError(msg, keep_last(), step=k)
            s0, s1 = s1, s0
            done = k
            if record and (k % frame_every == 0 or k == steps) or (not record and k == steps):
                ts.append(k * dt)
                qs.append(s0.particle_q.copy())
                qds.append(s0.particle_qd.copy())
                recorded = k
            if progress is not None:
                progress(k, steps)
    except KeyboardInterrupt:
        msg = f"interrupted after step {done} of {steps}; {kept()}"
        raise SimulationInterrupted(msg, keep_last(), step=done) from None
    except SimulationError as e:
        if e.trajectory is None:
            e.trajectory = keep_last()
            e.step = k
        raise
    except SpringsimError as e:
        msg = f"simulation stopped at step {k} (t={k * dt:g} s): {type(e).__name__}: {e}; {kept()}"
        raise SimulationError(msg, keep_last(), step=k) from e
    return trajectory()
