"""Side by side with NVIDIA Newton: symplectic Euler on the identical cloth, at equal substeps, in one process.

The peer is `NVIDIA Newton <https://github.com/newton-physics/newton>`_'s ``SolverSemiImplicit`` (warp-lang
CPU kernels, float32), run live beside springsim's ``symplectic_euler`` (float64, ``force_kernels``
default ``auto``: the compiled spring pass of the ``accel`` extra from 2,048 springs on). It needs the
``peer`` extra (``pip install 'springsim[peer]'``: warp-lang and newton); without it the benchmark exits
with status 2 and one line saying so. No peer figure is ever taken from an earlier run.

For each cloth size ``n`` of ``--sizes`` (``benchmark_cloth(n, stiffness=ke, damping=kd)``, ``--ke``
default 1e4, ``--kd`` default 0):

1. **The identical model** (:func:`newton_model`): the same particles, positions, velocities and masses
   (a fixed particle gets mass 0, Newton's kinematic particle: its inverse mass and gravity term are 0,
   so it stays where it is, as springsim's fixed particles do), the same springs with their stiffness,
   damping and springsim's rest lengths (cast to float32), the same gravity vector. Both spring kernels
   compute ``F_i = -(k (l - l0) + b (n . v)) n`` (springsim ``forces/spring.py``, Newton
   ``eval_spring``): the damping coefficient means the same. Both updates are ``v1 = v0 + h (F / m + g)``,
   ``x1 = x0 + h v1``. What Newton would add is switched off: particle radius 0 (no particle-particle
   contact grid), no shapes, triangles or edges, and its velocity clamp (``particle_max_velocity``,
   1e5 m/s by default) raised to 1e30. A model with drag or gravitational pairs is refused
   (``ValueError``): Newton's particles have neither.
2. **Identity check**: both engines run one 1/60 s frame from rest at the equal substep count of step 4;
   ``diff_1frame_m`` is the largest distance between their particles after it (float32 round-off of the
   peer; the cloth is 1 m).
3. **Each engine's stability limit**, by bisection on the substeps per 1/60 s frame with one criterion
   for both (:func:`stable`), the one of springsim's verified limit
   (:func:`benchmarks.frame_cost.run_symplectic`): the free particles start displaced by 1e-6 m of seeded
   Gaussian noise, the engine runs ``--window`` s (at most ``--max-steps`` substeps), and every 10
   substeps its state must be finite with a total energy (kinetic, springs, gravity, computed by
   :func:`springsim.run.energy.total_energy` from the engine's state in float64) no more than 0.1 m g L
   above the initial one. The bracket starts at ``springsim.analysis.explicit_substeps`` of the
   largest natural frequency; ``substeps_springsim`` and ``substeps_newton`` are the smallest stable
   counts.
4. **Timing at equal substeps**: ``substeps_equal`` = the larger of the two limits (both stable there).
   Both engines restart from rest and advance one frame at a time, alternately (ABBA order), for
   ``--repeats`` frames each, and with them springsim's public path (:class:`SimulateEngine`: one
   ``springsim.simulate`` call per frame, driver checks included; ``*_simulate`` columns, its ratio to
   the adjacent Newton frame likewise); every frame is timed with ``time.process_time`` (one thread each: warp's CPU
   kernels are serial; set ``OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 NUMBA_NUM_THREADS=1``). The table
   gives the median ms per substep of each engine, ``ratio`` = the median over the frames of
   springsim's frame time over Newton's adjacent one (robust to the load of a shared machine), the CPU
   seconds per frame of each at its own limit (``ms_per_substep * substeps / 1000``), and
   ``diff_final_m``, the largest particle distance between the two trajectories after the timed frames.
   The load average (``os.getloadavg``) is printed with the table and recorded per size.
5. **Error against the validated reference** (``--reference-frames F``, sizes up to ``--reference-max-n``):
   frame-cost's reference (:func:`benchmarks.reference_cache.refined_reference`: velocity Verlet at 2, 4
   and 8 times the explicit substep count, positions at every frame, cached under the same keys as
   ``frame-cost --ke``), and both engines from rest for ``F`` frames at the equal count; ``err_*_m`` is the
   RMS over particles of the position error, max over the frames (frame-cost's error), ``ref_floor_m``
   the reference's floor (the two finest levels' difference): an error below it is not resolved.

Usage::

    export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 NUMBA_NUM_THREADS=1
    python -m benchmarks peer-newton --sizes 32 64 128 256 --repeats 20 --reference-frames 70
    python -m benchmarks peer-newton --quick           # n = 6, 3 frames (tests)
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

from .common import RESULTS_DIR, machine_info, markdown_table, write_csv

__all__ = ["COLUMNS", "FRAME_DT", "PeerUnavailable", "import_peer", "newton_model", "SpringsimEngine",
           "SimulateEngine", "NewtonEngine",
           "stable", "smallest_stable", "reference_errors", "measure", "main"]

#: Frame length [s].
FRAME_DT = 1.0 / 60.0

COLUMNS = ["n", "springs", "force_kernels", "substeps_springsim", "substeps_newton", "substeps_equal",
           "ms_per_substep_springsim", "ms_per_substep_newton", "ratio", "ratio_min", "ratio_max",
           "ms_per_substep_simulate", "ratio_simulate",
           "cpu_s_per_frame_springsim", "cpu_s_per_frame_newton", "diff_1frame_m", "diff_final_m", "frames",
           "ref_frames", "err_springsim_m", "err_newton_m", "ref_floor_m", "load_start", "load_end"]


class PeerUnavailable(RuntimeError):
    """warp-lang or newton (the ``peer`` extra) does not import."""


def import_peer():
    """Import warp (on its CPU device) and newton.

    Returns
    -------
    wp, newton : module
        ``warp`` and ``newton``.

    Raises
    ------
    PeerUnavailable
        Either package is missing or fails to import.
    """
    try:
        import warp as wp

        wp.config.quiet = True  # no banner
        wp.config.log_level = wp.LOG_WARNING  # no line per kernel module loaded
        import newton
    except Exception as exc:  # ImportError, or a broken install's own error
        raise PeerUnavailable(f"NVIDIA Newton is not importable ({type(exc).__name__}: {exc}); "
                              "install the peer extra: pip install 'springsim[peer]'") from exc
    wp.init()
    wp.set_device("cpu")
    return wp, newton


def newton_model(model, *, max_velocity: float = 1e30):
    """NVIDIA Newton's model of the springsim ``model``, on warp's CPU device (float32).

    Parameters
    ----------
    model : springsim.Model
        Particles and springs only: no drag, no gravitational pairs.
    max_velocity : float
        Newton's velocity clamp [m/s] (its default 1e5 would change a diverging run).

    Returns
    -------
    newton.Model

    Raises
    ------
    ValueError
        The model has drag or gravitational pairs, which Newton's particles do not have.

    Notes
    -----
    A fixed particle gets mass 0, Newton's kinematic particle (no force and no gravity move it); the rest
    lengths are springsim's, cast to float32 (Newton's ``add_spring`` would recompute them from the
    positions); every particle has radius 0, so Newton builds no contact grid.
    """
    wp, newton = import_peer()
    if np.any(model.particle_drag != 0.0):
        raise ValueError("the model has particle drag; NVIDIA Newton's particles have none")
    if model.gravitational_count:
        raise ValueError("the model has gravitational pairs; NVIDIA Newton has none")
    axis = ("x", "y", "z")[model.up_axis]
    b = newton.ModelBuilder(up_axis=axis, gravity=tuple(float(g) for g in model.gravity_vector))
    mass = np.where(model.particle_fixed, 0.0, model.particle_mass)
    b.add_particles(pos=[tuple(p) for p in model.particle_q.tolist()],
                    vel=[tuple(v) for v in model.particle_qd.tolist()], mass=mass.tolist(),
                    radius=[0.0] * model.particle_count)
    for (i, j), ke, kd in zip(model.spring_indices.tolist(), model.spring_stiffness.tolist(),
                              model.spring_damping.tolist()):
        b.add_spring(i, j, ke, kd, 0.0)
    b.particle_max_velocity = float(max_velocity)
    m = b.finalize(device="cpu")
    m.spring_rest_length.assign(np.asarray(model.spring_rest_length, dtype=np.float32))
    if m.particle_grid is not None:  # radius 0 should give none; make sure no contact pass runs
        m.particle_grid = None
    return m


class SpringsimEngine:
    """springsim's ``symplectic_euler`` stepping its own two states (the raw stepping loop, no driver).

    Parameters
    ----------
    model : springsim.Model
    force_kernels : str
        ``auto``, ``numba`` or ``numpy`` (:func:`springsim.make_integrator`).
    """

    name = "springsim"

    def __init__(self, model, force_kernels: str = "auto"):
        from springsim import make_integrator

        self.model = model
        self.integ = make_integrator("symplectic_euler", model, force_kernels=force_kernels)
        self.force_kernels = "numba" if any(getattr(t, "kernels", None) == "numba" for t in self.integ.terms) \
            else "numpy"
        self.s0, self.s1 = model.state(), model.state()

    def set_state(self, q: np.ndarray, qd: np.ndarray) -> None:
        """Set positions and velocities [m, m/s], (N, 3)."""
        self.s0.particle_q[:], self.s0.particle_qd[:] = q, qd

    def advance(self, steps: int, h: float) -> None:
        """``steps`` substeps of ``h`` seconds."""
        for _ in range(steps):
            self.integ.step(self.s0, self.s1, h)
            self.s0, self.s1 = self.s1, self.s0

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """Positions and velocities, float64 copies."""
        return self.s0.particle_q.copy(), self.s0.particle_qd.copy()


class SimulateEngine:
    """springsim's public path: each :meth:`advance` is one ``springsim.simulate`` call (driver checks included).

    Parameters
    ----------
    model : springsim.Model
    force_kernels : str
        ``auto``, ``numba`` or ``numpy`` (:func:`springsim.make_integrator`).
    """

    name = "simulate"

    def __init__(self, model, force_kernels: str = "auto"):
        from springsim import make_integrator

        self.model = model
        self.integ = make_integrator("symplectic_euler", model, force_kernels=force_kernels)
        self.q, self.qd = model.particle_q.copy(), model.particle_qd.copy()

    def set_state(self, q: np.ndarray, qd: np.ndarray) -> None:
        """Set positions and velocities [m, m/s], (N, 3)."""
        self.q, self.qd = np.array(q, dtype=np.float64), np.array(qd, dtype=np.float64)

    def advance(self, steps: int, h: float) -> None:
        """``steps`` substeps of ``h`` seconds, one ``simulate`` call (only the last state kept)."""
        from springsim import State, simulate

        traj = simulate(self.model, self.integ, h, steps, state=State(self.q, self.qd), record=False)
        self.q, self.qd = traj.q[-1], traj.qd[-1]

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """Positions and velocities, float64 copies."""
        return self.q.copy(), self.qd.copy()


class NewtonEngine:
    """NVIDIA Newton's ``SolverSemiImplicit`` on :func:`newton_model` of ``model`` (warp CPU, float32).

    Each substep is what Newton's examples do: clear the forces, ``solver.step``, swap the states.

    Parameters
    ----------
    model : springsim.Model
    """

    name = "newton"

    def __init__(self, model):
        wp, newton = import_peer()
        self._wp = wp
        self.model = newton_model(model)
        self.solver = newton.solvers.SolverSemiImplicit(self.model)
        self.s0, self.s1 = self.model.state(), self.model.state()
        self.control = self.model.control()

    def set_state(self, q: np.ndarray, qd: np.ndarray) -> None:
        """Set positions and velocities [m, m/s], (N, 3), cast to float32."""
        for s in (self.s0, self.s1):
            s.particle_q.assign(np.asarray(q, dtype=np.float32))
            s.particle_qd.assign(np.asarray(qd, dtype=np.float32))

    def advance(self, steps: int, h: float) -> None:
        """``steps`` substeps of ``h`` seconds."""
        for _ in range(steps):
            self.s0.clear_forces()
            self.solver.step(self.s0, self.s1, self.control, None, h)
            self.s0, self.s1 = self.s1, self.s0
        self._wp.synchronize_device("cpu")

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """Positions and velocities as float64 arrays."""
        return (self.s0.particle_q.numpy().astype(np.float64), self.s0.particle_qd.numpy().astype(np.float64))


def stable(engine, model, substeps: int, *, window: float, max_steps: int | None = None, check_every: int = 10,
           growth_tol: float = 0.1, perturb: float = 1e-6, seed: int = 0, frame_dt: float = FRAME_DT) -> bool:
    """Whether ``engine`` is stable at ``substeps`` per frame: springsim's verified-limit criterion.

    The criterion of :func:`benchmarks.frame_cost.run_symplectic`, applied to any engine: from the
    initial state with the free particles displaced by ``perturb`` m of Gaussian noise (``seed``), run
    ``window`` s (at most ``max_steps`` substeps); every ``check_every`` substeps and at the end the
    state must be finite and its total energy (float64, :func:`springsim.run.energy.total_energy`) at most
    ``growth_tol * m_total |g| L`` (L = 1 m) above the initial one.

    Parameters
    ----------
    engine : SpringsimEngine or NewtonEngine
    model : springsim.Model
    substeps : int
        Substeps per frame of ``frame_dt``.
    window, max_steps, check_every, growth_tol, perturb, seed, frame_dt
        As above.

    Returns
    -------
    bool
    """
    from springsim.forces import make_force_terms
    from springsim.run.energy import total_energy

    h = frame_dt / substeps
    steps = max(1, int(round(window / h)))
    if max_steps is not None:
        steps = max(1, min(steps, int(max_steps)))
    terms = make_force_terms(model, skip_fixed=False)
    q0 = model.particle_q.copy()
    free = model.free_particles
    q0[free] += perturb * np.random.default_rng(seed).standard_normal((free.size, 3))
    engine.set_state(q0, model.particle_qd)
    q, qd = engine.state()  # as the engine holds it (float32 for Newton)
    e0 = total_energy(model, q, qd, terms)
    limit = growth_tol * float(np.sum(model.particle_mass)) * abs(float(model.gravity)) * 1.0
    done = 0
    with np.errstate(over="ignore", invalid="ignore"):
        while done < steps:
            k = min(check_every, steps - done)
            engine.advance(k, h)
            done += k
            q, qd = engine.state()
            if not (np.isfinite(q).all() and np.isfinite(qd).all()):
                return False
            if not total_energy(model, q, qd, terms) - e0 <= limit:
                return False
    return True


def smallest_stable(engine, model, start: int, **criterion) -> int:
    """The smallest substep count per frame at which :func:`stable` holds, by bisection.

    Parameters
    ----------
    engine : SpringsimEngine or NewtonEngine
    model : springsim.Model
    start : int
        First guess (e.g. from the largest natural frequency); the bracket is widened from it.
    **criterion
        Keyword arguments of :func:`stable`.

    Returns
    -------
    int
        ``S`` with ``stable(S)`` and not ``stable(S - 1)`` (stability assumed monotone in ``S``).
    """
    hi = max(1, int(start))
    while not stable(engine, model, hi, **criterion):
        hi *= 2
    lo = max(1, (7 * hi) // 10)
    while lo > 1 and stable(engine, model, lo, **criterion):
        hi, lo = lo, max(1, lo // 2)
    if lo == 1 and stable(engine, model, 1, **criterion):
        return 1
    while hi - lo > 1:  # stable at hi, unstable at lo
        mid = (lo + hi) // 2
        if stable(engine, model, mid, **criterion):
            hi = mid
        else:
            lo = mid
    return hi


def _diff(a, b) -> float:
    with np.errstate(invalid="ignore"):
        d = float(np.max(np.linalg.norm(a.state()[0] - b.state()[0], axis=1)))
    return d if np.isfinite(d) else float("inf")


def reference_errors(model, engines, substeps: int, frames: int, *, case: str, base_substeps: int, cache_dir=None,
                     log=print) -> dict:
    """Each engine's error against frame-cost's validated reference over ``frames`` frames from rest.

    Parameters
    ----------
    model : springsim.Model
    engines : sequence of SpringsimEngine or NewtonEngine
    substeps : int
        Substeps per frame of the engines.
    frames : int
        Frames of 1/60 s.
    case : str
        Cache name of the reference (frame-cost's, e.g. ``cloth32_ke10000``).
    base_substeps : int
        Substeps per frame of the reference's coarsest level (three levels, doubling).
    cache_dir : path-like, optional
        Cache of the reference levels (default frame-cost's, ``benchmarks/results/frame_ref``).
    log : callable
        Progress printer.

    Returns
    -------
    dict
        ``err_<engine name>_m`` (RMS over particles, max over the frames [m]) and ``ref_floor_m``.
    """
    from . import reference_cache

    cache = reference_cache.CACHE_DIR if cache_dir is None else Path(cache_dir)
    ref = reference_cache.refined_reference(model, base_substeps, 3, frames, case=case, cache_dir=cache, log=log)
    out = {"ref_floor_m": ref.floor}
    for eng in engines:
        eng.set_state(model.particle_q, model.particle_qd)
        err = 0.0
        for f in range(1, frames + 1):
            eng.advance(substeps, FRAME_DT / substeps)
            err = max(err, float(reference_cache.frame_rms(eng.state()[0], ref.q[f])))
        out[f"err_{eng.name}_m"] = err
    log(f"  over {frames} frames against the reference (floor {ref.floor:.3g} m): "
        + ", ".join(f"{e.name} {out[f'err_{e.name}_m']:.3g} m" for e in engines))
    return out


def measure(n: int, *, repeats: int, ke: float = 1e4, kd: float = 0.0, force_kernels: str = "auto",
            window: float = 0.1, max_steps: int | None = 2000, reference_frames: int = 0, cache_dir=None,
            log=print) -> dict:
    """One row of :data:`COLUMNS` for ``benchmark_cloth(n, stiffness=ke, damping=kd)`` (module docstring).

    Parameters
    ----------
    n : int
        Particles per side.
    repeats : int
        Timed frames per engine.
    ke, kd : float
        Stiffness [N/m] and damping [N s/m] of the benchmark cloth's structural and shear springs (``kd``
        of every spring).
    force_kernels : str
        springsim's force kernels (``auto``, ``numba``, ``numpy``).
    window, max_steps : float, int
        Window [s] and substep cap of the stability criterion (:func:`stable`).
    reference_frames : int
        Frames of the error against the validated reference (0: not measured).
    cache_dir : path-like, optional
        Cache of the reference (:func:`reference_errors`).
    log : callable
        Progress printer.

    Returns
    -------
    dict
    """
    from springsim.analysis import explicit_substeps, max_frequency
    from springsim.assembly import SystemAssembler
    from springsim.forces import make_force_terms
    from springsim.scene import benchmark_cloth

    load_start = os.getloadavg()[0]
    model = benchmark_cloth(n, stiffness=ke, damping=kd)
    sp, nt, sd = SpringsimEngine(model, force_kernels), NewtonEngine(model), SimulateEngine(model, force_kernels)
    asm = SystemAssembler(model, make_force_terms(model))
    omega = max_frequency(asm, model.particle_q, model.particle_qd)["omega"]
    start = explicit_substeps(omega, FRAME_DT)
    crit = dict(window=window, max_steps=max_steps)
    limits = {}
    for eng in (sp, nt):
        t0 = time.perf_counter()
        limits[eng.name] = smallest_stable(eng, model, start, **crit)
        log(f"n = {n}: {eng.name} smallest stable substep count {limits[eng.name]} "
            f"(omega_max gives {start}; {time.perf_counter() - t0:.1f} s)")
    S = max(limits.values())
    h = FRAME_DT / S
    for eng in (sp, nt):  # identity: one frame from rest at the equal count (also the warm-up)
        eng.set_state(model.particle_q, model.particle_qd)
        eng.advance(S, h)
    diff1 = _diff(sp, nt)
    log(f"n = {n}: one frame from rest at {S} substeps: largest particle distance springsim - newton {diff1:.3g} m")
    sd.advance(S, h)  # warm-up of the public path
    for eng in (sp, nt, sd):
        eng.set_state(model.particle_q, model.particle_qd)
    cpu = {"springsim": [], "newton": [], "simulate": []}
    for r in range(repeats):
        for eng in ((sp, nt, sd) if r % 2 == 0 else (sd, nt, sp)):
            c = time.process_time()
            eng.advance(S, h)
            cpu[eng.name].append(time.process_time() - c)
    ratios = np.array(cpu["springsim"]) / np.array(cpu["newton"])
    ratios_sd = np.array(cpu["simulate"]) / np.array(cpu["newton"])
    ms = {k: 1e3 * float(np.median(v)) / S for k, v in cpu.items()}
    row = dict(n=n, springs=model.spring_count, force_kernels=sp.force_kernels, substeps_springsim=limits["springsim"],
               substeps_newton=limits["newton"], substeps_equal=S, ms_per_substep_springsim=ms["springsim"],
               ms_per_substep_newton=ms["newton"], ratio=float(np.median(ratios)), ratio_min=float(ratios.min()),
               ratio_max=float(ratios.max()), ms_per_substep_simulate=ms["simulate"],
               ratio_simulate=float(np.median(ratios_sd)),
               cpu_s_per_frame_springsim=ms["springsim"] * limits["springsim"] / 1e3,
               cpu_s_per_frame_newton=ms["newton"] * limits["newton"] / 1e3, diff_1frame_m=diff1,
               diff_final_m=_diff(sp, nt), frames=repeats, load_start=load_start, load_end=os.getloadavg()[0])
    if reference_frames:
        case = f"cloth{n}_ke{ke:g}" + (f"_kd{kd:g}" if kd else "")
        row.update(ref_frames=reference_frames, **reference_errors(model, (sp, nt), S, reference_frames, case=case,
                                                                   base_substeps=2 * start, cache_dir=cache_dir,
                                                                   log=log))
    log(f"n = {n}: {ms['springsim']:.4g} ms / substep springsim, {ms['newton']:.4g} ms newton, ratio "
        f"{row['ratio']:.3g} ({row['ratio_min']:.3g}-{row['ratio_max']:.3g}); through simulate {ms['simulate']:.4g} "
        f"ms, ratio {row['ratio_simulate']:.3g}; load {load_start:.2f} -> {row['load_end']:.2f}")
    return row


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks peer-newton", description=__doc__.splitlines()[0])
    p.add_argument("--sizes", type=int, nargs="*", default=[32, 64, 128], help="cloth sizes n (default 32 64 128)")
    p.add_argument("--repeats", type=int, default=20, help="timed frames per engine, alternating (default 20)")
    p.add_argument("--ke", type=float, default=1e4, help="structural and shear stiffness [N/m] (default 1e4)")
    p.add_argument("--kd", type=float, default=0.0, help="damping of every spring [N s/m] (default 0)")
    p.add_argument("--force-kernels", default="auto", choices=("auto", "numba", "numpy"),
                   help="springsim's force evaluation (default auto)")
    p.add_argument("--window", type=float, default=0.1, help="window of the stability criterion [s] (default 0.1)")
    p.add_argument("--max-steps", type=int, default=2000, help="substep cap of the stability window (default 2000)")
    p.add_argument("--reference-frames", type=int, default=0,
                   help="frames of the error against frame-cost's validated reference (default 0: not measured)")
    p.add_argument("--reference-max-n", type=int, default=128,
                   help="largest size whose reference is computed (default 128)")
    p.add_argument("--cache-dir", type=Path, default=None,
                   help="cache of the references (default frame-cost's, benchmarks/results/frame_ref)")
    p.add_argument("--quick", action="store_true", help="n = 6, 3 timed frames, 5 reference frames (tests)")
    p.add_argument("--out", type=Path, default=RESULTS_DIR, help="output directory of peer_newton.csv")
    p.add_argument("--json", default=None, help="also write the rows, machine and load to this JSON file")
    a = p.parse_args(argv)
    if a.quick:
        a.sizes, a.repeats, a.reference_frames = [6], 3, 5
    if not a.sizes or any(n < 2 for n in a.sizes):
        p.error("--sizes: every size must be >= 2")
    if a.repeats < 1:
        p.error("--repeats must be >= 1")
    if a.reference_frames < 0:
        p.error("--reference-frames must be >= 0")
    try:
        wp, newton = import_peer()
    except PeerUnavailable as exc:
        print(f"python -m benchmarks peer-newton: {exc}", file=sys.stderr)
        return 2
    threads = {k: os.environ.get(k, "unset") for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMBA_NUM_THREADS")}
    print(f"newton {newton.__version__}, warp-lang {wp.__version__} (CPU, float32); threads: "
          + ", ".join(f"{k}={v}" for k, v in threads.items()))
    rows = [measure(n, repeats=a.repeats, ke=a.ke, kd=a.kd, force_kernels=a.force_kernels, window=a.window,
                    max_steps=a.max_steps, reference_frames=a.reference_frames if n <= a.reference_max_n else 0,
                    cache_dir=a.cache_dir) for n in a.sizes]
    a.out.mkdir(parents=True, exist_ok=True)
    write_csv(a.out / "peer_newton.csv", rows, COLUMNS)
    print(markdown_table(rows, COLUMNS))
    load = os.getloadavg()
    print(f"load average (1, 5, 15 min) at the end: {load[0]:.2f}, {load[1]:.2f}, {load[2]:.2f} on "
          f"{os.cpu_count()} cores")
    if a.json:
        Path(a.json).parent.mkdir(parents=True, exist_ok=True)
        Path(a.json).write_text(json.dumps(dict(rows=rows, machine=machine_info(), newton=newton.__version__,
                                                warp=wp.__version__, threads=threads, ke=a.ke, kd=a.kd,
                                                load_end=list(load)), indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
