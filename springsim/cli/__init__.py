"""Command-line interface: ``springsim <command> ...`` (also ``python -m springsim``).

Subcommands live in :data:`COMMANDS`. A command is any object with
``add_arguments(parser)`` and ``run(args) -> int`` (and optionally ``help``), or the
``"module:attribute"`` path of one (imported only when the parser is built), so
adding one is a single line::

    COMMANDS["plot"] = "springsim.cli.pictures:plot_command"

Exit status: 0 success, 1 simulation blew up (or its frames could not be written to
``--out``), 2 user error (bad scene, bad option, missing file; one line
``springsim: error: ...`` on stderr, no traceback), 130 interrupted (Ctrl-C), 143 terminated
(SIGTERM; handled like Ctrl-C: the frames so far are saved), 141 stdout closed early
(``springsim ... | head``; nothing is printed about it). Progress goes to stderr, results to stdout;
Python warnings are shown as one ``springsim: warning: ...`` line each; numpy's floating-point
warnings (overflow, invalid value) are not shown, the run's own checks report their consequences.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import warnings
from dataclasses import dataclass
from typing import Callable

from ..errors import SpringsimError
from .session import _Exit, configure_logging, error_text, interrupt_status, signals_as_interrupts

__all__ = ["COMMANDS", "Command", "main", "build_parser"]


@dataclass(frozen=True)
class Command:
    """A subcommand: ``add_arguments(parser)`` declares its options, ``run(args)`` returns the exit status.

    Parameters
    ----------
    add_arguments : callable
        ``add_arguments(parser)`` adds the subcommand's options to its ``argparse`` parser.
    run : callable
        ``run(args)`` runs it on the parsed namespace and returns the exit status (0 ok, 1 a failed run, 2 bad
        input).
    help : str
        One line for ``springsim --help`` (default: the first line of the command's docstring).
    """

    add_arguments: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int]
    help: str = ""


#: Registry of subcommands: name -> Command, or the dotted path ``"module:attribute"`` of one
#: (imported only when the parser is built).
COMMANDS: dict[str, object] = {
    "run": "springsim.cli.run:run_command",
    "plot": "springsim.cli.pictures:plot_command",
    "render": "springsim.cli.pictures:render_command",
    "export": "springsim.cli.export:export_command",
    "scenes": "springsim.cli.scenes:scenes_command",
}


def _resolve(cmd):
    if isinstance(cmd, str):
        module, _, attr = cmd.partition(":")
        cmd = importlib.import_module(module)
        if attr:
            cmd = getattr(cmd, attr)
    return cmd


class _Parser(argparse.ArgumentParser):
    """argparse with one-line usage errors (``springsim: error: argument --steps: ...; see 'springsim run --help'``)."""

    def error(self, message):
        self.exit(2, f"springsim: error: {' '.join(message.split())}; see '{self.prog} --help'\n")


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with one subparser per entry of :data:`COMMANDS`.

    Returns
    -------
    argparse.ArgumentParser
        ``springsim``'s parser; its usage errors are one line and exit 2.
    """
    from .. import __version__

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
    """Parse ``argv`` (default ``sys.argv[1:]``), run the command, return the exit status.

    Run as the program (``argv`` None), it first applies the allocator policy of
    :func:`springsim._runtime.alloc.retain_freed_memory` (off with ``SPRINGSIM_RETAIN_MEMORY=0``).

    Parameters
    ----------
    argv : list of str, optional
        The arguments after the program name.

    Returns
    -------
    int
        The exit status: 0 success, 1 a run that ended with a failed step or blew up, 2 bad input or usage, 130
        interrupted.
    """
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
    except SystemExit as e:  # argparse: --help/--version (0) or usage error (2)
        return int(e.code) if isinstance(e.code, int) else 2
    except KeyboardInterrupt:  # during start-up (the commands' imports)
        print("springsim: interrupted", file=sys.stderr)
        return 130
    if argv is None:  # the command line owns the process: keep freed memory for reuse (springsim._runtime.alloc)
        from .._runtime.alloc import retain_freed_memory

        retain_freed_memory()
    scene = getattr(args, "scene", None)
    try:
        with signals_as_interrupts(), warnings.catch_warnings():
            warnings.showwarning = _show_warning
            # numpy's floating-point warnings on extreme inputs: the run's own checks (non-finite states, the
            # energy bound, failed solves) report what they lead to, naming the step and the particle
            warnings.filterwarnings("ignore", r"(overflow|invalid value|divide by zero|underflow) encountered",
                                    RuntimeWarning)
            with configure_logging(getattr(args, "verbose", 0), getattr(args, "quiet", False)):
                status = int(args._command.run(args))
            sys.stdout.flush()  # a closed pipe shows here, not at exit
            return status
    except BrokenPipeError:
        return _stdout_closed()
    except SpringsimError as e:
        return _error(error_text(e, scene))
    except _Exit as e:
        return e.status
    except KeyboardInterrupt:
        print(f"springsim: {'terminated' if interrupt_status() == 143 else 'interrupted'}", file=sys.stderr)
        return interrupt_status()
    except MemoryError:
        return _error("out of memory: the scene is too large for this machine")
    except OSError as e:
        return _error(error_text(e))


def _show_warning(message, category, filename, lineno, file=None, line=None):
    """A Python warning (numpy, matplotlib, springsim) as one ``springsim: warning:`` line, without source paths."""
    try:
        print(f"springsim: warning: {' '.join(str(message).split())[:300]}", file=sys.stderr)
    except (OSError, ValueError):
        pass


def _stdout_closed() -> int:
    """stdout was closed by its reader (``| head``): stop quietly, exit 141 (128 + SIGPIPE), as other tools do."""
    import os

    try:  # later writes, and the interpreter's flush at exit, go nowhere instead of raising again
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError, AttributeError):
        pass
    return 141


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
