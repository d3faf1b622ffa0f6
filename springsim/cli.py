"""Command-line interface: ``springsim <command> ...`` (also ``python -m springsim``).

Subcommands live in :data:`COMMANDS`. A command is any object with
``add_arguments(parser)`` and ``run(args) -> int`` (and optionally ``help``), or the
``"module:attribute"`` path of one (imported only when the parser is built), so
adding one is a single line::

    COMMANDS["plot"] = "springsim.cli_extra:plot_command"

Exit status: 0 success, 1 simulation blew up, 2 user error (bad scene, bad option,
missing file; one line ``springsim: error: ...`` on stderr, no traceback), 130
interrupted. Progress goes to stderr, results to stdout.
"""

from __future__ import annotations

import argparse
import importlib
import math
import os
import sys
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from ._argtypes import int_at_least, positive_float
from .errors import SceneError, SimulationError, SimulationInterrupted, SpringsimError, SpringsimWarning
from .options import MAX_STEPS

__all__ = ["COMMANDS", "Command", "main", "build_parser"]


@dataclass(frozen=True)
class Command:
    """A subcommand: ``add_arguments(parser)`` declares its options, ``run(args)`` returns the exit status."""

    add_arguments: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int]
    help: str = ""


class UsageError(SpringsimError):
    """Invalid command-line usage detected after parsing (exit status 2)."""


# -- progress ---------------------------------------------------------------------------
class ProgressBar:
    """A text progress bar on a stream, drawn with carriage returns.

    Appears only after ``delay`` seconds and redraws at most every ``interval``
    seconds, so short runs print nothing. Used only when the stream is a terminal.
    """

    def __init__(self, stream, *, delay: float = 1.0, interval: float = 0.2, width: int = 30):
        self.stream = stream
        self.delay = delay
        self.interval = interval
        self.width = width
        self.t0 = time.perf_counter()
        self._last = -math.inf
        self.drawn = False

    def __call__(self, step: int, steps: int) -> None:
        now = time.perf_counter()
        if now - self.t0 < self.delay or (now - self._last < self.interval and step < steps):
            return
        self._last = now
        frac = step / max(steps, 1)
        fill = int(round(self.width * frac))
        elapsed = now - self.t0
        eta = elapsed * (1 - frac) / frac if frac > 0 else math.nan
        self.stream.write(f"\r[{'#' * fill}{'.' * (self.width - fill)}] {step}/{steps} "
                          f"{elapsed:6.1f} s elapsed, {eta:6.1f} s left ")
        self.stream.flush()
        self.drawn = True

    def close(self) -> None:
        """End the bar's line (if one was drawn)."""
        if self.drawn:
            self.stream.write("\n")
            self.stream.flush()
            self.drawn = False


# -- run ----------------------------------------------------------------------------------
_positive_int = int_at_least(1, MAX_STEPS)
_nonnegative_int = int_at_least(0, MAX_STEPS)


def _run_add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", help="scene file (YAML)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--steps", type=_nonnegative_int, help="number of steps (default: the scene's, else 100)")
    g.add_argument("--duration", type=positive_float, metavar="T", help="simulated time [s] (steps = ceil(T/dt))")
    p.add_argument("--dt", type=positive_float, metavar="H", help="time step [s] (overrides solver.timestep)")
    p.add_argument("--integrator", metavar="NAME", help="integrator (overrides solver.type)")
    p.add_argument("--solver", metavar="NAME", help="linear solver (overrides solver.linear_solver)")
    p.add_argument("--jacobian", metavar="MODE", help="Jacobian mode (overrides solver.jacobian)")
    p.add_argument("--rtol", type=positive_float, metavar="R",
                   help="relative tolerance of iterative linear solvers (overrides solver.linear_rtol)")
    p.add_argument("--newton-tol", type=positive_float, metavar="TOL", help="Newton tolerance on |dv| [m/s]")
    p.add_argument("--newton-maxiter", type=int_at_least(1, 10**6), metavar="N", help="Newton iteration limit")
    p.add_argument("--time-rtol", type=positive_float, metavar="R",
                   help="adaptive time stepping (bdf2, tr_bdf2): relative local error tolerance; --dt is then "
                        "the first step and the frame spacing (overrides solver.time_rtol)")
    p.add_argument("--time-atol", type=positive_float, metavar="A",
                   help="adaptive time stepping: absolute local error tolerance [m, m/s] (overrides solver.time_atol)")
    p.add_argument("--max-step", type=positive_float, metavar="H",
                   help="adaptive time stepping: largest step [s] (overrides solver.max_step; default a tenth "
                        "of the run)")
    p.add_argument("--out", metavar="FILE.npz", help="write frames t (F,), q (F,N,3), qd (F,N,3) to an .npz")
    p.add_argument("--frame-every", type=_positive_int, default=1, metavar="K",
                   help="record every K-th step in --out (first and last always)")
    p.add_argument("--quiet", action="store_true", help="no progress bar and no summary")


def _fmt_s(s: float) -> str:
    if s >= 1:
        return f"{s:.3f} s"
    if s >= 1e-3:
        return f"{s * 1e3:.3f} ms"
    return f"{s * 1e6:.1f} us"


def _summary_lines(scene, cfg, integrator, traj) -> list[tuple[str, str]]:
    m = scene.model
    s = traj.summary()
    rows = [
        ("scene", f"{scene.source} ({scene.name})"),
        ("particles", f"{m.particle_count} ({m.free_count} free, {m.particle_count - m.free_count} fixed)"),
        ("springs", str(m.spring_count)),
        ("gravitational pairs", str(m.gravitational_count)),
        ("dofs", str(m.dof_count)),
    ]
    if integrator.implicit:
        solver = integrator.solver
        chosen = f" -> {solver.last_choice}" if getattr(solver, "last_choice", None) else ""
        rows.append(("integrator", f"{cfg.integrator} (linear solver {solver.name}{chosen}, "
                                   f"jacobian {integrator.jacobian})"))
    else:
        rows.append(("integrator", cfg.integrator))
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
            ("Newton iterations", f"{s['newton_iterations']:.2f} per step"),
            ("linear iterations", f"{s['linear_iterations']:.2f} per step"),
            ("failed steps", f"{s['failed_steps']} (Newton {s['newton_failures']}, linear solves "
                             f"{s['linear_failures']}, ill-conditioned {s['ill_conditioned']})"),
            ("solver fallbacks", str(s["fallbacks"])),
            ("max linear residual", f"{s['max_linear_residual']:.2e}"),
            ("max precision loss", f"{s['max_precision_loss']:.1e}"),
        ]
    return rows


def _save_or_rescue(traj, out: str) -> None:
    """Write ``traj`` to ``out``; if that fails, to a rescue file in the temporary directory (named on stderr)."""
    try:
        traj.save(out)
        return
    except (OSError, SpringsimError) as e:
        why = getattr(e, "strerror", None) or str(e)
    import tempfile

    fd, rescue = tempfile.mkstemp(prefix="springsim-rescue-", suffix=".npz")
    os.close(fd)
    try:
        traj.save(rescue)
    except (OSError, SpringsimError) as e2:
        raise SpringsimError(f"--out {out}: cannot write ({why}); the rescue copy failed too "
                             f"({getattr(e2, 'strerror', None) or e2}); the frames are lost") from None
    print(f"springsim: error: --out {out}: cannot write ({why}); saved {traj.frame_count} frame(s) to {rescue} "
          f"instead", file=sys.stderr)
    raise _Exit(1)


class _Exit(Exception):
    """Leave :func:`main` with this exit status (the message was printed already)."""

    def __init__(self, status: int):
        super().__init__(status)
        self.status = status


def _run(args: argparse.Namespace) -> int:
    from .adaptive import simulate_adaptive
    from .driver import check_output_path, simulate, steps_for_duration
    from .integrators import make_integrator
    from .scene import DEFAULT_STEPS, load_scene

    scene = load_scene(Path(args.scene))  # always a path on the command line, never YAML text
    if args.out is not None:
        check_output_path(args.out)  # before the run: a run is never lost to an unwritable --out
    cfg = scene.config.with_overrides(dt=args.dt, integrator=args.integrator, linear_solver=args.solver,
                                      jacobian=args.jacobian, linear_rtol=args.rtol, newton_tol=args.newton_tol,
                                      newton_maxiter=args.newton_maxiter, time_rtol=args.time_rtol,
                                      time_atol=args.time_atol, max_step=args.max_step)
    if args.steps is not None:
        steps = args.steps
    elif args.duration is not None:
        try:
            steps = steps_for_duration(args.duration, cfg.dt)
        except ValueError as e:
            raise UsageError(f"--duration {args.duration:g}: {e}") from None
    else:
        steps = cfg.steps if cfg.steps is not None else DEFAULT_STEPS
    integrator = make_integrator(cfg.integrator, scene.model, **cfg.integrator_options())

    progress = None
    if not args.quiet and sys.stderr.isatty():
        progress = ProgressBar(sys.stderr)
    record = args.out is not None
    adaptive = cfg.time_rtol is not None or cfg.time_atol is not None
    try:
        with warnings.catch_warnings():
            # the CLI reports failed steps and fallbacks in its own lines below
            warnings.simplefilter("ignore", SpringsimWarning)
            if adaptive:  # frames every dt
                rtol = cfg.time_rtol if cfg.time_rtol is not None else cfg.time_atol
                atol = cfg.time_atol if cfg.time_atol is not None else cfg.time_rtol
                traj = simulate_adaptive(scene.model, integrator, steps * cfg.dt, time_rtol=rtol, time_atol=atol,
                                         frame_dt=cfg.dt * args.frame_every if record else None,
                                         h0=cfg.dt, h_max=cfg.max_step,  # the driver clips h0 to h_max
                                         progress=None if progress is None else
                                         (lambda t, t_end: progress(int(round(t / cfg.dt)), steps)))
            else:
                traj = simulate(scene.model, integrator, cfg.dt, steps, frame_every=args.frame_every,
                                record=record, progress=progress)
    except (SimulationError, SimulationInterrupted) as e:
        if progress is not None:
            progress.close()
        interrupted = isinstance(e, SimulationInterrupted)
        print(f"springsim: {'interrupted' if interrupted else 'error'}: {e}", file=sys.stderr)
        if args.out is not None and e.trajectory is not None and e.trajectory.frame_count:
            _save_or_rescue(e.trajectory, args.out)
            print(f"springsim: saved {e.trajectory.frame_count} finite frame(s) up to "
                  f"t={e.trajectory.t[-1]:g} s to {args.out}", file=sys.stderr)
        return 130 if interrupted else 1
    if progress is not None:
        progress.close()
    if args.out is not None:
        _save_or_rescue(traj, args.out)
    s = traj.summary()
    if s["failed_steps"]:
        first = next(x for x in traj.stats if not x.ok)
        print(f"springsim: warning: {s['failed_steps']} of {s['steps']} step(s) did not meet their criteria "
              f"(first: {'; '.join(first.failures)})", file=sys.stderr)
    if not args.quiet:
        rows = _summary_lines(scene, cfg, integrator, traj)
        if adaptive:
            rows.append(("time tolerances", f"time_rtol {rtol:g}, time_atol {atol:g}"))
        if args.out is not None:
            rows.append(("output", f"{args.out} ({traj.frame_count} frames)"))
        w = max(len(k) for k, _ in rows)
        for k, v in rows:
            print(f"{k + ':':<{w + 1}} {v}")
    return 0


#: Registry of subcommands: name -> Command, or the dotted path ``"module:attribute"`` of one
#: (imported only when the parser is built).
COMMANDS: dict[str, object] = {
    "run": Command(_run_add_arguments, _run, "run a scene and print a summary"),
    "plot": "springsim.cli_extra:plot_command",
    "render": "springsim.cli_extra:render_command",
    "export": "springsim.cli_extra:export_command",
}


def _resolve(cmd):
    if isinstance(cmd, str):
        module, _, attr = cmd.partition(":")
        cmd = importlib.import_module(module)
        if attr:
            cmd = getattr(cmd, attr)
    return cmd


class _Parser(argparse.ArgumentParser):
    """argparse with one-line usage errors (``springsim run: error: argument --steps: ...; see --help``)."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {' '.join(message.split())}; see '{self.prog} --help'\n")


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with one subparser per entry of :data:`COMMANDS`."""
    from . import __version__

    parser = _Parser(prog="springsim", description="Large mass-spring systems, implicitly integrated.")
    parser.add_argument("--version", action="version", version=f"springsim {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True
    for name, cmd in COMMANDS.items():
        cmd = _resolve(cmd)
        doc = (getattr(cmd, "__doc__", None) or "").strip().splitlines()
        help_ = getattr(cmd, "help", None) or getattr(cmd, "HELP", None) or (doc[0] if doc else "")
        p = sub.add_parser(name, help=help_, description=help_)
        cmd.add_arguments(p)
        p.set_defaults(_command=cmd)
    return parser


def _error(message: str) -> int:
    print(f"springsim: error: {' '.join(str(message).split())}", file=sys.stderr)
    return 2


def main(argv: list[str] | None = None) -> int:
    """Parse ``argv`` (default ``sys.argv[1:]``), run the command, return the exit status."""
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
    except SystemExit as e:  # argparse: --help/--version (0) or usage error (2)
        return int(e.code) if isinstance(e.code, int) else 2
    except KeyboardInterrupt:  # during start-up (the commands' imports)
        print("springsim: interrupted", file=sys.stderr)
        return 130
    scene = getattr(args, "scene", None)
    try:
        return int(args._command.run(args))
    except SceneError as e:
        msg = str(e)
        if scene and not msg.startswith(str(scene)):
            msg = f"{scene}: {msg}"
        return _error(msg)
    except SpringsimError as e:
        return _error(str(e))
    except _Exit as e:
        return e.status
    except KeyboardInterrupt:
        print("springsim: interrupted", file=sys.stderr)
        return 130
    except MemoryError:
        return _error("out of memory: the scene is too large for this machine")
    except OSError as e:
        return _error(f"{e.filename + ': ' if getattr(e, 'filename', None) else ''}{e.strerror or e}")


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
