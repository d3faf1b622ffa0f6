"""``springsim run``: run a scene and print a summary (serially, or with the petsc backend under ``mpiexec``).

The options of a run are those of :func:`springsim.cli.runner.add_run_options` (the fields of
:class:`springsim.run.options.SolverConfig`) plus ``--out``, ``--frame-every`` and ``--keep-going``. Progress and
set-up phases are logged (:mod:`springsim.progress`) to stderr.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys

from ..errors import SceneError, SimulationError, SimulationInterrupted, SpringsimError
from ..run.options import MAX_STEPS
from .argtypes import int_at_least
from .distributed import abort_on_error, agree, run_distributed
from .runner import (_provenance, add_run_options, execute, load_and_configure, load_trajectory_for,  # noqa: F401
                     print_rows, save_or_rescue, save_stopped_run, summary_lines, warn_failed_steps)
from .session import _Exit, _stopped_by, configure_logging, error_text  # noqa: F401

__all__ = ["run_command", "add_run_options", "load_and_configure", "execute", "configure_logging", "error_text",
           "load_trajectory_for"]


def _add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", help="scene file (YAML), or the name of a shipped scene (`springsim scenes`)")
    add_run_options(p)
    p.add_argument("--out", metavar="FILE.npz", help="write frames t (F,), q (F,N,3), qd (F,N,3) to an .npz")
    p.add_argument("--frame-every", type=int_at_least(1, MAX_STEPS), default=1, metavar="K",
                   help="record every K-th step in --out (first and last always; default 1)")
    p.add_argument("--keep-going", action="store_true",
                   help="exit with status 0 even when steps did not meet their criteria after their retakes "
                        "(default: status 1; the frames are kept either way)")


def _load_agreed(args):
    """:func:`load_and_configure` under ``mpiexec``: rank 0 reads the scene, the ranks agree on the outcome (one
    message from rank 0, every rank exits 2), rank 0 sends the others the run configuration and, with the petsc
    backend, every rank its part of the model (:func:`springsim.distributed.scatter_model`), or, for a scene of one
    generator block, its description, from which every rank generates its part
    (:func:`springsim.distributed.generated_part`); no rank keeps the whole model, and with a generator block no
    rank builds it."""
    from ..distributed import env_rank, env_size
    from ..run.driver import check_output_path

    err, scene, cfg, mine = None, None, None, None
    root, many = env_rank() == 0, env_size() > 1
    if root:  # the other ranks wait for rank 0's verdict (agree) instead of reading the file too
        try:
            # a scene of one generator block is not built: every rank generates its part (_scene_parts); rank 0
            # generates its own here, which checks the block's values before the verdict
            scene, cfg = load_and_configure(args, build=False)
            if scene.model is None and cfg.backend == "petsc":  # (the serial backend here is refused below)
                from ..distributed import generated_part
                from ..scene.yaml_io import check_generated_memory

                grid = scene.generator["grid"]
                check_generated_memory(scene.generator["paths"]["cloth"], grid["nx"] * grid["ny"], env_size())
                mine = generated_part(scene.generator, env_size(), 0)
            if args.out is not None:
                check_output_path(args.out, suffixes=(".npz",), inputs=(args.scene,))
        except (SpringsimError, OSError) as e:
            err = error_text(e, args.scene)
        except Exception as e:  # a bug while reading: end every rank now, they wait in agree()
            if many:
                abort_on_error(e)
            raise
    err = _verdict(err) if many else err
    if err is not None:
        if root:
            print(f"springsim: error: {err}", file=sys.stderr)
        raise _Exit(2)
    try:
        if many:
            from ..distributed import import_petsc

            _, MPI = import_petsc()
            got = MPI.COMM_WORLD.bcast((dataclasses.replace(scene, model=None), cfg) if root else None, root=0)
            if not root:
                scene, cfg = got  # the scene without its model; the part comes below
            del got
        if cfg.backend == "petsc":
            scene = _scene_parts(scene, mine, args.scene)
    except (SpringsimError, _Exit):
        raise
    except Exception as e:  # one rank's own failure: end every rank now rather than leave them waiting
        if many:
            abort_on_error(e)
        raise
    return scene, cfg


def _verdict(err):
    """Rank 0's error (None: fine), on every rank (collective; without MPI's Python module, this rank's own)."""
    from ..distributed import import_petsc

    try:
        _, MPI = import_petsc()
    except SpringsimError:
        return agree(err)
    return MPI.COMM_WORLD.bcast(err, root=0)


def _scene_parts(scene, mine=None, path=None):
    """``scene`` with its model replaced by this rank's part (collective): for a scene of one generator block,
    generated on every rank (``mine``: this rank's, generated already), the ranks agreeing on errors (a value only
    some ranks' rows reach, such as an overflowing position: rank 0 prints the lowest rank's, with ``path`` the
    scene file, and every rank exits 2); else sent from rank 0, which holds the model, and the model dropped."""
    from ..distributed import generated_part, import_petsc, scatter_model

    _, MPI = import_petsc()
    comm = MPI.COMM_WORLD
    if scene.generator is None:
        return dataclasses.replace(scene, model=scatter_model(scene.model if comm.Get_rank() == 0 else None, comm))
    err, part = None, mine
    if part is None:
        try:
            part = generated_part(scene.generator, comm.Get_size(), comm.Get_rank())
        except SceneError as e:
            err = error_text(e, path)
    err = next((e for e in comm.allgather(err) if e is not None), None)  # the lowest rank's
    if err is not None:
        if comm.Get_rank() == 0:
            print(f"springsim: error: {err}", file=sys.stderr)
        raise _Exit(2)
    return dataclasses.replace(scene, model=part)


def _run_petsc(args, scene, cfg) -> int:
    """The petsc backend; a collective error is printed by rank 0 only, anything else aborts the job."""
    from ..distributed import env_rank

    try:
        return run_distributed(args, scene, cfg)
    except _Exit:
        raise
    except SpringsimError as e:  # collective: the same on every rank
        if env_rank() == 0:
            print(f"springsim: error: {error_text(e, args.scene)}", file=sys.stderr)
        raise _Exit(2) from None
    except Exception as e:  # one rank's own failure: end every rank now rather than leave them waiting
        from ..distributed import env_size

        if env_size() > 1:
            abort_on_error(e)
        raise


def _run(args: argparse.Namespace) -> int:
    from ..distributed import env_rank, env_size
    from ..run.driver import check_output_path

    if env_size() > 1 or getattr(args, "backend", None) == "petsc":
        scene, cfg = _load_agreed(args)
        if cfg.backend == "petsc":
            return _run_petsc(args, scene, cfg)
        if env_rank() == 0:
            print(f"springsim: error: {env_size()} MPI processes need --backend petsc (solver.backend: petsc)",
                  file=sys.stderr)
        return 2
    scene, cfg = load_and_configure(args)
    if cfg.backend == "petsc":  # one process: its part is the whole model, which is then dropped
        scene = _scene_parts(scene, path=args.scene)
        return _run_petsc(args, scene, cfg)
    if args.out is not None:  # before the run: a run is never lost to an unwritable --out
        check_output_path(args.out, suffixes=(".npz",), inputs=(args.scene,))
    record = args.out is not None
    try:
        integrator, traj = execute(scene, cfg, record=record, frame_every=args.frame_every)
    except (SimulationError, SimulationInterrupted) as e:
        return save_stopped_run(e, scene, cfg, args.out)
    if args.out is not None:
        _provenance(traj, scene, cfg)
        where, status = save_or_rescue(traj, args.out)
        if status:
            if where == args.out:
                print(f"springsim: {_stopped_by()}; the run had finished and its {traj.frame_count} frame(s) are "
                      f"saved to {where}", file=sys.stderr)
            return status
    failed = warn_failed_steps(traj, keep_going=args.keep_going)
    if not args.quiet:
        rows = summary_lines(scene, cfg, integrator, traj)
        if args.out is not None:
            rows.append(("output", f"{args.out} ({traj.frame_count} frames)"))
        print_rows(rows)
    return 1 if failed and not args.keep_going else 0


class _RunCommand:
    help = "run a scene and print a summary"

    add_arguments = staticmethod(_add_arguments)
    run = staticmethod(_run)


#: ``springsim run``.
run_command = _RunCommand()
