"""Simulation driver: step an integrator, record frames, stop cleanly on blow-up.

After every step the new state is checked for NaN/inf; on blow-up
:func:`simulate` raises :class:`~springsim.errors.SimulationError` naming the step
and the first offending particle, carrying the finite frames computed before it
(``err.trajectory``). Ctrl-C does the same with :class:`SimulationInterrupted`.
"""

from __future__ import annotations

import os
import tempfile
import time
from dataclasses import dataclass, field

import numpy as np

from .errors import SimulationError
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
    """``np.savez`` to a temporary file in the target directory, then ``os.replace``."""
    path = os.fspath(path)
    d = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(suffix=".npz", dir=d)
    try:
        with os.fdopen(fd, "wb") as fh:
            np.savez(fh, **arrays)
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
    SimulationInterrupted
        On KeyboardInterrupt, with the frames so far.
    """
    if not (dt > 0 and np.isfinite(dt)):
        raise ValueError(f"dt must be finite and > 0, got {dt}")
    if steps < 0:
        raise ValueError(f"steps must be >= 0, got {steps}")
    s0 = model.state() if state is None else state.copy()
    s1 = s0.copy()
    ts, qs, qds = [0.0], [s0.particle_q.copy()], [s0.particle_qd.copy()]
    stats: list[StepStats] = []
    t0 = time.perf_counter()

    def trajectory():
        return Trajectory(np.array(ts), np.array(qs), np.array(qds), stats, time.perf_counter() - t0)

    k = 0
    try:
        for k in range(1, steps + 1):
            st = integrator.step(s0, s1, dt)
            stats.append(st)
            if not s1.is_finite():
                bad = ~(np.isfinite(s1.particle_q).all(axis=1) & np.isfinite(s1.particle_qd).all(axis=1))
                p = int(np.flatnonzero(bad)[0])
                raise SimulationError(
                    f"simulation blew up at step {k} (t={k * dt:g} s): particle {p} has a non-finite "
                    f"position or velocity; kept {len(ts)} finite frame(s) up to t={ts[-1]:g} s",
                    trajectory(), step=k)
            s0, s1 = s1, s0
            if record and (k % frame_every == 0 or k == steps) or (not record and k == steps):
                ts.append(k * dt)
                qs.append(s0.particle_q.copy())
                qds.append(s0.particle_qd.copy())
            if progress is not None:
                progress(k, steps)
    except KeyboardInterrupt:
        raise SimulationInterrupted(f"interrupted at step {k}; kept {len(ts)} frame(s) up to t={ts[-1]:g} s",
                                    trajectory(), step=k) from None
    except SimulationError as e:
        if e.trajectory is None:
            e.trajectory = trajectory()
            e.step = k
        raise
    return trajectory()
