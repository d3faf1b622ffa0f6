"""Running a scene for a command: the path ``run``, ``plot`` and ``render`` share.

:func:`add_run_options` declares the options of a run (the fields of :class:`springsim.run.options.SolverConfig`,
one flag each, derived from its declarations, plus ``-v/--verbose`` and ``-q/--quiet``);
:func:`load_and_configure` loads the scene with them applied; :func:`configured_integrator` builds the
integrator on the configured backend; :func:`execute` runs it. The summary (:func:`summary_lines`), the report
of steps that missed their criteria (:func:`warn_failed_steps`) and the saving of the frames
(:func:`save_or_rescue`, :func:`save_stopped_run`) are shared with the distributed run
(:mod:`springsim.cli.distributed`).
"""

from __future__ import annotations

import argparse
import os
import sys
import warnings
from pathlib import Path

from ..errors import EnergyGrowthWarning, SceneError, SimulationInterrupted, SpringsimError, SpringsimWarning
from ..forces._data import data_terms, term_group
from ..run.options import SolverConfig
from .session import _stopped_by, interrupt_status, signals_deferred

__all__ = ["add_run_options", "load_and_configure", "configured_integrator", "execute", "warn_failed_steps",
           "print_rows", "summary_lines", "save_or_rescue", "save_stopped_run", "load_trajectory_for"]


def add_run_options(p: argparse.ArgumentParser) -> None:
    """Add the flags of every command that runs a scene: one per :class:`SolverConfig` field that declares one,
    and ``-v/--verbose`` or ``-q/--quiet``.

    Parameters
    ----------
    p : argparse.ArgumentParser
        The command's parser.
    """
    SolverConfig.add_arguments(p)
    g = p.add_mutually_exclusive_group()
    g.add_argument("-v", "--verbose", action="count", default=0,
                   help="also log every set-up phase with its time (default: progress every few seconds and "
                        "set-up phases that take over a second)")
    g.add_argument("-q", "--quiet", action="store_true", help="warnings and errors only: no progress, no summary")


def load_and_configure(args: argparse.Namespace, *, build: bool = True):
    """The scene of ``args.scene`` (a file, or the name of a shipped scene) with the command-line overrides applied.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed arguments with ``scene`` and the flags of :func:`add_run_options`.
    build : bool
        False: a scene of one generator block is not built (:func:`springsim.scene.load_scene`).

    Returns
    -------
    scene : Scene
    config : SolverConfig
        The scene's ``solver:`` block with the flags given applied (validated).
    """
    from ..progress import phase
    from ..scene import load_scene
    from ..scene.shipped import resolve_scene

    args.scene = str(resolve_scene(args.scene))  # a bare name (cloth_64) is a shipped scene
    with phase(f"loading {args.scene}"):
        scene = load_scene(Path(args.scene), build=build)  # always a path on the command line, never YAML text
    names = [name for name in SolverConfig.declarations() if hasattr(args, name)]
    cfg = scene.config.with_overrides(**{name: getattr(args, name) for name in names})
    return scene, cfg


def configured_integrator(cfg: SolverConfig, model):
    """The integrator ``cfg`` configures for ``model``, on the configured backend.

    The serial backend builds it with :func:`springsim.integrators.make_integrator`; the petsc one builds a
    :class:`~springsim.distributed.DistributedSystem` (:func:`springsim.distributed.make_distributed`,
    collective). This sits above both the run configuration and the distributed driver, so neither imports
    the other.

    Parameters
    ----------
    cfg : SolverConfig
        The run configuration.
    model : Model
        The model to integrate.

    Returns
    -------
    Integrator

    Raises
    ------
    SceneError
        An invalid combination, naming its ``solver.<key>``.
    """
    from ..integrators import make_integrator

    by_kwarg = {SolverConfig.keyword(name): name for name in SolverConfig.declarations()}
    opts = cfg.integrator_options()
    try:
        if cfg.backend == "petsc":
            from ..distributed import make_distributed

            if opts.pop("solver", "auto") != "auto":
                raise SceneError("solver", "the petsc backend solves with PETSc's KSP; choose its method with "
                                           "petsc_options (-ksp_type, -pc_type)")
            return make_distributed(model, cfg.integrator, petsc_options=cfg.petsc_options,
                                    partitioner=cfg.partitioner or cfg.default("partitioner"), **opts)
        return make_integrator(cfg.integrator, model, **opts)
    except SceneError as e:
        name = by_kwarg.get(e.path)
        raise (SceneError(f"solver.{cfg.yaml_key(name)}", e.message) if name else e) from None


def execute(scene, cfg, *, record: bool = True, frame_every: int = 1, progress=True, quiet: bool = False,
            frames=None):
    """Run ``scene`` as configured by ``cfg``, with fixed or adaptive steps.

    Steps that did not meet their criteria and fallbacks are reported by the caller (from the trajectory), not
    as Python warnings; options the integrator does not use and energy growth are one line each on stderr.

    Parameters
    ----------
    scene : Scene
    cfg : SolverConfig
    record : bool
        Keep frames (else only the last state).
    frame_every : int
        Record every ``frame_every``-th step (adaptive runs: a frame every ``frame_every * dt``).
    progress : callable, bool or None
        As for :func:`springsim.simulate` (default: log lines, :class:`springsim.progress.ProgressLog`).
    quiet : bool
        No warning lines (the ranks other than the root of a distributed run).
    frames : object, optional
        A sink for the root's frames (:func:`springsim.simulate`; the distributed run streams them to ``--out``).

    Returns
    -------
    integrator : Integrator
    trajectory : Trajectory or None
        None on the ranks other than the root of a distributed run.

    Raises
    ------
    SceneError
        ``cfg`` has no time step, or an invalid combination of options.
    SimulationError
        The run failed; ``trajectory`` holds the frames so far.
    """
    from ..progress import as_progress, logger, phase
    from ..run.adaptive import simulate_adaptive
    from ..run.driver import simulate

    if cfg.dt is None:  # a config built in Python without a step (the YAML loader requires one)
        raise SceneError("solver.timestep", "missing: give solver.timestep or --dt")
    steps = cfg.run_steps()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("ignore", SpringsimWarning)  # reported in the CLI's own lines
        warnings.simplefilter("always", EnergyGrowthWarning)  # ... this one by the line below
        with phase(f"setting up {cfg.integrator}"):
            integrator = configured_integrator(cfg, scene.model)
        unused = cfg.unused(integrator)
        if unused and not quiet:
            print(f"springsim: warning: {cfg.integrator} does not use {', '.join(unused)}"
                  f"{' (max_step needs time_rtol or time_atol)' if 'max_step' in unused else ''}; ignored",
                  file=sys.stderr)
        progress = as_progress(progress)
        logger.debug("running %s", f"{cfg.integrator} to t = {steps * cfg.dt:g} s (adaptive, frames every "
                                   f"{cfg.dt * frame_every:g} s)" if cfg.adaptive else
                     f"{steps} step(s) of {cfg.dt:g} s with {cfg.integrator}")
        if cfg.adaptive:  # frames every dt
            rtol, atol = cfg.time.tolerances()
            traj = simulate_adaptive(scene.model, integrator, steps * cfg.dt, time_rtol=rtol, time_atol=atol,
                                     frame_dt=cfg.dt * frame_every if record else None,
                                     h0=cfg.dt, h_max=cfg.max_step,  # the driver clips h0 to h_max
                                     progress=progress, frames=frames)
        else:
            traj = simulate(scene.model, integrator, cfg.dt, steps, frame_every=frame_every, record=record,
                            progress=progress, frames=frames)
    for w in caught:
        if issubclass(w.category, EnergyGrowthWarning) and not quiet:
            print(f"springsim: warning: {w.message}", file=sys.stderr)
    return integrator, traj


def warn_failed_steps(traj, *, keep_going: bool = True) -> int:
    """One ``springsim: error:`` line (``warning:`` with ``keep_going``) when steps did not meet their criteria
    after their retakes.

    Parameters
    ----------
    traj : Trajectory
    keep_going : bool
        The run's status stays 0 (a warning, not an error).

    Returns
    -------
    int
        The number of such steps.
    """
    s = traj.summary()
    if s["failed_steps"]:
        first = next(x for x in traj.stats if not x.ok)
        kind = "warning" if keep_going else "error"
        print(f"springsim: {kind}: {s['failed_steps']} of {s['steps']} step(s) did not meet their criteria "
              f"(first: {'; '.join(first.failures)}); their results are kept"
              f"{'' if keep_going else ' (--keep-going: exit status 0)'}", file=sys.stderr)
    return s["failed_steps"]


def _fmt_s(s: float) -> str:
    if s >= 1:
        return f"{s:.3f} s"
    if s >= 1e-3:
        return f"{s * 1e3:.3f} ms"
    return f"{s * 1e6:.1f} us"


def _model_rows(scene) -> list[tuple[str, str]]:
    m = scene.model
    return [
        ("scene", f"{scene.source} ({scene.name})"),
        ("particles", f"{m.particle_count} ({m.free_count} free, {m.particle_count - m.free_count} fixed)"),
        *((cls.pair_label or term_group(name, cls), str(getattr(m, f"{name}_count")))
          for name, cls in data_terms() if any(spec.per == "pair" for spec in cls.data)),
        ("dofs", str(m.dof_count)),
    ]


def _newton_rows(s: dict) -> list[tuple[str, str]]:
    """Summary rows of an implicit run's iterations and failures (``s``: :meth:`Trajectory.summary`)."""
    return [
        ("Newton iterations", f"{s['newton_iterations']:.2f} per step"),
        ("linear iterations", f"{s['linear_iterations']:.2f} per step"),
        ("failed steps", f"{s['failed_steps']} (Newton {s['newton_failures']}, linear solves "
                         f"{s['linear_failures']}, ill-conditioned {s['ill_conditioned']})"),
        ("solver fallbacks", str(s["fallbacks"])),
        ("max linear residual", f"{s['max_linear_residual']:.2e}"),
        ("max precision loss", f"{s['max_precision_loss']:.1e}"),
    ]


def print_rows(rows: list[tuple[str, str]]) -> None:
    """Print the summary on stdout, one ``name: value`` row per line, values aligned.

    Parameters
    ----------
    rows : list of (str, str)
        The rows (:func:`summary_lines`).
    """
    w = max(len(k) for k, _ in rows)
    for k, v in rows:
        print(f"{k + ':':<{w + 1}} {v}")


def summary_lines(scene, cfg, integrator, traj) -> list[tuple[str, str]]:
    """The rows of the run summary: the model, the integrator and its solvers, steps, times and iterations.

    Parameters
    ----------
    scene : Scene
    cfg : SolverConfig
    integrator : Integrator
    traj : Trajectory

    Returns
    -------
    list of (str, str)
        ``(name, value)`` rows for :func:`print_rows`.
    """
    s = traj.summary()
    rows = _model_rows(scene)
    if integrator.implicit:
        solver = integrator.solver
        if solver is None:
            linear = "PETSc KSP"
        else:
            chosen = f" -> {solver.last_choice}: {solver.last_reason}" if getattr(solver, "last_choice", None) else ""
            linear = f"linear solver {solver.name}{chosen}"
        stages = f"{integrator.stage_solver} stages" if integrator.converges else "one Newton step per step"
        rows.append(("integrator", f"{cfg.integrator} ({linear}, {stages}, jacobian {integrator.jacobian})"))
    else:
        rows.append(("integrator", cfg.integrator))
    meta = traj.meta
    if meta.get("backend") == "petsc":
        pc = f", preconditioner {meta['preconditioner']}" if meta.get("preconditioner") else ""
        rows.insert(len(rows) - 1, ("backend", f"petsc, {meta['ranks']} MPI rank(s){pc}"))
    a = traj.adaptive_stats
    if a:
        rows.append(("steps", f"{a['accepted']} adaptive (mean h {a['h_mean']:.3g} s, h in [{a['h_min']:.3g}, "
                              f"{a['h_max']:.3g}] s), {a['rejected']} rejected"))
    else:
        rows.append(("steps", f"{s['steps']} x dt = {cfg.dt:g} s"))
    rows += [
        ("simulated time", f"{traj.t[-1]:g} s"),
        ("wall time", f"{_fmt_s(s['wall_s'])} (CPU {_fmt_s(s['cpu_s'])})"),
        ("time per step", _fmt_s(s["step_s"])),
    ]
    if integrator.implicit and s["steps"]:
        rows += [
            ("assembly per step", _fmt_s(s["assembly_s"])),
            ("linear solve per step", _fmt_s(s["solve_s"])),
            ("other per step", _fmt_s(s["other_s"])),
        ] + _newton_rows(s)
    tm = meta.get("timings", {})
    if tm and s["steps"]:
        rows.append(("per step (rank 0)", ", ".join(f"{k[:-2]} {_fmt_s(v / s['steps'])}" for k, v in tm.items()
                                                    if v)))
    if cfg.adaptive:
        rtol, atol = cfg.time.tolerances()
        rows.append(("time tolerances", f"time_rtol {rtol:g}, "
                                        f"time_atol {atol:g}"))
    return rows


def _rescue_path() -> str:
    """A name for a rescue file in the temporary directory that no file has (the file appears only once written)."""
    import secrets
    import tempfile

    d = tempfile.gettempdir()
    while True:
        path = os.path.join(d, f"springsim-rescue-{secrets.token_hex(6)}.npz")
        if not os.path.lexists(path):
            return path


def _why(e: BaseException) -> str:
    if isinstance(e, KeyboardInterrupt):
        return "interrupted"
    return " ".join(str(getattr(e, "strerror", None) or e).split())


def save_or_rescue(traj, out: str, *, interrupted: bool = False) -> tuple[str | None, int]:
    """Write ``traj`` to ``out``, else to a rescue file in the temporary directory: ``(file written or None, status)``.

    Ctrl-C and SIGTERM wait until the write is finished (:func:`signals_deferred`): the frames are
    never lost to an interrupt during the save. When ``out`` cannot be written (full disk, or a
    ``KeyboardInterrupt`` inside the write), the frames go to ``springsim-rescue-*.npz`` in the
    temporary directory, written atomically like ``out`` (no empty or partial rescue file), and
    one line names it; when that fails too, one line says the frames are lost.

    Parameters
    ----------
    traj : Trajectory
    out : str
        The ``--out`` file.
    interrupted : bool
        The run was interrupted (its frames are saved, the status says so).

    Returns
    -------
    written : str or None
        The file written (``out`` or the rescue file), None when both failed.
    status : int
        :func:`~springsim.cli.session.interrupt_status` (130, 143) when the run was ``interrupted`` or a
        signal arrived during the save, else 0 when ``out`` was written, else 1.
    """
    why = where = None
    with signals_deferred() as got:
        try:
            traj.save(out)
            where = out
        except (OSError, SpringsimError, KeyboardInterrupt) as e:
            why = _why(e)
            interrupted = interrupted or isinstance(e, KeyboardInterrupt)
            rescue = _rescue_path()
            try:
                traj.save(rescue)
                where = rescue
            except (OSError, SpringsimError, KeyboardInterrupt) as e2:
                print(f"springsim: error: --out {out}: cannot write ({why}); the rescue copy in "
                      f"{os.path.dirname(rescue)} failed too ({_why(e2)}); the frames are lost", file=sys.stderr)
            else:
                print(f"springsim: error: --out {out}: cannot write ({why}); saved {traj.frame_count} frame(s) to "
                      f"{rescue} instead", file=sys.stderr)
    if interrupted or got:
        return where, interrupt_status()
    return where, 0 if why is None else 1


def save_stopped_run(e, scene, cfg, out) -> int:
    """Report a run stopped by ``e`` and save its frames to ``out`` (if given; :func:`save_or_rescue`).

    Parameters
    ----------
    e : SimulationError or SimulationInterrupted
        What stopped the run (its ``trajectory`` holds the frames so far).
    scene : Scene
    cfg : SolverConfig
    out : str or None
        The ``--out`` file.

    Returns
    -------
    int
        The exit status: 1, or 130/143 when interrupted.
    """
    interrupted = isinstance(e, SimulationInterrupted)
    print(f"springsim: {_stopped_by() if interrupted else 'error'}: {e}", file=sys.stderr)
    status = interrupt_status() if interrupted else 1
    if out is not None and e.trajectory is not None and e.trajectory.frame_count:
        _provenance(e.trajectory, scene, cfg)
        where, saved = save_or_rescue(e.trajectory, out, interrupted=interrupted)
        if where is not None:
            print(f"springsim: saved {e.trajectory.frame_count} finite frame(s) up to t={e.trajectory.t[-1]:g} s "
                  f"to {where}", file=sys.stderr)
        status = saved or status
    return status


def load_trajectory_for(path, scene, scene_path):
    """The trajectory ``.npz`` at ``path``, checked against the scene it is drawn or exported with.

    A different particle count is an error, found from the array headers before any data is read
    (a 7 MB compressed file announcing 3e8 particles costs nothing); so is a file without frames.
    A different model fingerprint (the file records the model it was computed from) is a one-line
    warning on stderr; a file without one (a distributed run of a generated scene before such runs hashed the model
    in bands) is compared by the SHA-256 of the scene file it was run from instead.

    Parameters
    ----------
    path : str or Path
        The trajectory file.
    scene : Scene
        The scene it is drawn or exported with.
    scene_path : str
        That scene's file, for the messages.

    Returns
    -------
    Trajectory

    Raises
    ------
    SpringsimError
        Another particle count, or no frames.
    """
    from ..io._npz import npz_headers
    from ..run.driver import Trajectory

    q = npz_headers(path).get("q")
    n = scene.model.particle_count
    if q is not None and len(q.shape) == 3 and q.shape[1] != n:
        raise SpringsimError(f"{path} has {q.shape[1]} particles (array q {q.shape}), {scene_path} has {n}")
    traj = Trajectory.load(path)
    if traj.q.shape[1] != n:
        raise SpringsimError(f"{path} has {traj.q.shape[1]} particles, {scene_path} has {n}")
    if traj.frame_count == 0:
        raise SpringsimError(f"{path}: the trajectory has no frames")
    recorded = traj.meta.get("model_fingerprint")
    if recorded is not None and recorded != scene.model.fingerprint():
        print(f"springsim: warning: {path} was computed from another model than {scene_path} "
              f"(the model fingerprints differ)", file=sys.stderr)
    elif recorded is None and traj.meta.get("scene_sha256") not in (None, "", scene.sha256) and scene.sha256:
        print(f"springsim: warning: {path} was computed from another scene file than {scene_path} "
              f"(it records no model fingerprint, and the files' SHA-256 differ)", file=sys.stderr)
    return traj


def _provenance(traj, scene, cfg, scene_path=None) -> None:
    """Add the scene's SHA-256 (of the bytes loaded, :attr:`Scene.sha256`: the file is not read again, so a scene
    moved, deleted or edited during the run changes nothing) and the run options to ``traj.meta``."""
    if scene.sha256:
        traj.meta["scene_sha256"] = scene.sha256
    traj.meta["run_options"] = {k: v for k, v in cfg.flat().items() if v is not None}
