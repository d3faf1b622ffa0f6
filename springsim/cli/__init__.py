"""Command-line interface: ``springsim <command> ...`` (also ``python -m springsim``).

Subcommands live in :data:`COMMANDS`. A command is any object with
``add_arguments(parser)`` and ``run(args) -> int`` (and optionally ``help``), or the
``"module:attribute"`` path of one (imported only when the parser is built), so
adding one is a single line::

    COMMANDS["plot"] = "springsim.cli.pictures:plot_command"

Exit status: 0 success, 1 simulation blew up, 2 user error (bad scene, bad option,
missing file; one line ``springsim: error: ...`` on stderr, no traceback), 130
interrupted. Progress goes to stderr, results to stdout.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from dataclasses import dataclass
from typing import Callable

from ..errors import SpringsimError
from .run import _Exit, configure_logging, error_text

__all__ = ["COMMANDS", "Command", "main", "build_parser"]


@dataclass(frozen=True)
class Command:
    """A subcommand: ``add_arguments(parser)`` declares its options, ``run(args)`` returns the exit status."""

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
    """argparse with one-line usage errors (``springsim run: error: argument --steps: ...; see --help``)."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {' '.join(message.split())}; see '{self.prog} --help'\n")


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with one subparser per entry of :data:`COMMANDS`."""
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
    :func:`springsim._alloc.retain_freed_memory` (off with ``SPRINGSIM_RETAIN_MEMORY=0``).
    """
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
    except SystemExit as e:  # argparse: --help/--version (0) or usage error (2)
        return int(e.code) if isinstance(e.code, int) else 2
    except KeyboardInterrupt:  # during start-up (the commands' imports)
        print("springsim: interrupted", file=sys.stderr)
        return 130
    if argv is None:  # the command line owns the process: keep freed memory for reuse (springsim._alloc)
        from .._alloc import retain_freed_memory

        retain_freed_memory()
    scene = getattr(args, "scene", None)
    try:
        with configure_logging(getattr(args, "verbose", 0), getattr(args, "quiet", False)):
            return int(args._command.run(args))
    except SpringsimError as e:
        return _error(error_text(e, scene))
    except _Exit as e:
        return e.status
    except KeyboardInterrupt:
        print("springsim: interrupted", file=sys.stderr)
        return 130
    except MemoryError:
        return _error("out of memory: the scene is too large for this machine")
    except OSError as e:
        return _error(error_text(e))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
