"""``springsim run --backend petsc`` under ``mpiexec``: the distributed run and its one-message error handling.

Rank 0 reads the scene; the ranks agree on the outcome before any distributed work, so a bad input ends all
ranks with one ``springsim: error:`` line from rank 0 and exit status 2; rank 0 then sends every rank the run
configuration and its part of the model (no rank keeps the whole model), and streams the gathered frames to
``--out`` (:class:`~springsim.io._spool.FrameSpool`) instead of holding them. Errors during the run are
collective (global reductions decide blow-ups and Newton; KSP results are global), so every rank stops at the
same step and rank 0 reports it, saving the frames so far with ``--out``; so do Ctrl-C and SIGTERM, which are only
recorded until the ranks agree on them after a step (:mod:`springsim.run.interrupts`; during the set-up they wait
for the first step's end). The other ranks wait for rank 0's save before they exit. Anything else on one rank (a
bug, memory exhausted) prints one line naming the rank and aborts the MPI job, so no rank waits forever in a
collective call.
"""

from __future__ import annotations

import contextlib
import sys

from ..errors import SimulationError, SimulationInterrupted, SpringsimError
from ..io._spool import FrameSpool
from .runner import (_provenance, execute, print_rows, save_or_rescue, save_stopped_run, summary_lines,
                     warn_failed_steps)
from .session import interrupt_status, signals_deferred

__all__ = ["agree", "run_distributed", "abort_on_error"]


def agree(error: str | None) -> str | None:
    """The first rank's error message (prefixed ``rank r:`` when not every rank had it), or None when every rank
    is fine; collective over MPI's world communicator (a no-op outside ``mpiexec``).

    Parameters
    ----------
    error : str or None
        This rank's error message, None when it is fine.

    Returns
    -------
    str or None
        The message every rank reports, or None.
    """
    from ..distributed import env_size

    if env_size() <= 1:
        return error
    try:
        from ..distributed import import_petsc

        _, MPI = import_petsc()
    except SpringsimError:
        return error
    errors = MPI.COMM_WORLD.allgather(error)
    bad = [(r, e) for r, e in enumerate(errors) if e is not None]
    if not bad:
        return None
    r, e = bad[0]
    return e if len(bad) == len(errors) and len(set(x for _, x in bad)) == 1 else f"rank {r}: {e}"


def abort_on_error(exc: BaseException) -> None:
    """Print one line naming this rank and abort every rank of the job (status 1).

    Parameters
    ----------
    exc : BaseException
        The error this rank cannot recover from; its type and message make the line.
    """
    from ..distributed import env_rank, import_petsc

    print(f"springsim: error: rank {env_rank()}: {type(exc).__name__}: {' '.join(str(exc).split())}",
          file=sys.stderr, flush=True)
    _, MPI = import_petsc()
    MPI.COMM_WORLD.Abort(1)


def run_distributed(args, scene, cfg) -> int:
    """Run ``scene`` with the petsc backend as configured (see the module docstring); the exit status.

    The run is the serial one (:func:`springsim.cli.runner.execute`: the same integrators, adaptive stepping and
    driver) over a :class:`~springsim.distributed.DistributedSystem`; rank 0 prints and saves.

    Parameters
    ----------
    args : argparse.Namespace
        The ``run`` command's arguments (``out``, ``frame_every``, ...).
    scene : Scene
        The loaded scene.
    cfg : SolverConfig
        Its run configuration, with the command line's overrides.

    Returns
    -------
    int
        The exit status: 0 success; 1 a failed step (without ``--keep-going``), a blow-up or an output that could
        not be written (the frames then go to a rescue file); 130 or 143 when interrupted.
    """
    from ..distributed import env_rank, env_size, import_petsc

    import_petsc()  # BackendUnavailable (a SpringsimError): one line with the install hint
    root = env_rank() == 0
    record = args.out is not None
    # on several ranks Ctrl-C and SIGTERM are only recorded until every rank is past the barrier below: the run's
    # drivers act on them at a step boundary, where the ranks agree (springsim.run.interrupts); raised anywhere
    # else on one rank, they would leave the others in a collective call or kill rank 0 in the middle of its save
    with signals_deferred() if env_size() > 1 else contextlib.nullcontext([]) as got:
        spool = FrameSpool(args.out) if record and root else None  # rank 0 streams the frames to --out
        try:
            status = _run(args, scene, cfg, spool, root, record)
        finally:
            if spool is not None:
                spool.discard()
        _wait_for_root()
    return interrupt_status() if got and status == 0 else status


def _wait_for_root() -> None:
    """Every rank waits until rank 0 has saved and reported: ``mpiexec`` ends the whole job as soon as one rank
    exits with a non-zero status, which would kill rank 0 in the middle of saving the frames of a stopped run."""
    from ..distributed import env_size, import_petsc

    if env_size() > 1:
        _, MPI = import_petsc()
        MPI.COMM_WORLD.Barrier()


def _run(args, scene, cfg, spool, root: bool, record: bool) -> int:
    """:func:`run_distributed` once the frame spool is open."""
    try:
        integrator, traj = execute(scene, cfg, record=record, frame_every=args.frame_every, quiet=not root,
                                   frames=spool)
    except (SimulationError, SimulationInterrupted) as e:  # every rank, at the same step
        if e.trajectory is None:  # not the root rank: the root reports and saves
            return interrupt_status() if isinstance(e, SimulationInterrupted) else 1
        return save_stopped_run(e, scene, cfg, args.out)
    if traj is None:  # not the root rank
        return 0
    if args.out is not None:
        _provenance(traj, scene, cfg)
        _, status = save_or_rescue(traj, args.out)
        if status:
            return status
    failed = warn_failed_steps(traj, keep_going=args.keep_going)
    if not args.quiet:
        rows = summary_lines(scene, cfg, integrator, traj)
        if args.out is not None:
            rows.append(("output", f"{args.out} ({traj.frame_count} frames)"))
        print_rows(rows)
    return 1 if failed and not args.keep_going else 0
