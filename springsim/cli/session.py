"""What every command shares: exit statuses, signals, logging to stderr and one-line error messages.

Exit statuses are listed in :mod:`springsim.cli`; a command leaves with a given status by raising
:class:`_Exit` (its message printed already). SIGTERM is handled like Ctrl-C
(:func:`signals_as_interrupts`); a save in progress defers both (:func:`signals_deferred`).
"""

from __future__ import annotations

import contextlib
import logging
import signal
import sys
import threading

from ..errors import SceneError

__all__ = ["interrupt_status", "signals_as_interrupts", "signals_deferred", "configure_logging", "error_text"]


class _Exit(Exception):
    """Leave :func:`springsim.cli.main` with this exit status (the message was printed already)."""

    def __init__(self, status: int):
        super().__init__(status)
        self.status = status


# -- signals ---------------------------------------------------------------------------------------
#: The signals received by the current command (SIGINT, SIGTERM), in order.
_received: list[int] = []


def interrupt_status() -> int:
    """Exit status of an interrupted command: 128 + the signal (130 for Ctrl-C, 143 for SIGTERM).

    Returns
    -------
    int
    """
    return 128 + (_received[-1] if _received else signal.SIGINT)


def _stopped_by() -> str:
    """``"terminated"`` (SIGTERM) or ``"interrupted"`` (Ctrl-C): how the current command was stopped."""
    return "terminated" if interrupt_status() == signal.SIGTERM + 128 else "interrupted"


@contextlib.contextmanager
def _handlers(handlers: dict):
    """Install signal ``handlers`` while the block runs (only in the main thread, where Python runs them)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    saved = {}
    try:
        for signum, handler in handlers.items():
            saved[signum] = signal.getsignal(signum)
            signal.signal(signum, handler)
        yield
    finally:
        for signum, handler in saved.items():
            signal.signal(signum, handler if handler is not None else signal.SIG_DFL)


@contextlib.contextmanager
def signals_as_interrupts():
    """While the block runs, SIGTERM stops it like Ctrl-C: a ``KeyboardInterrupt`` (a run keeps its frames and
    saves them, temporary files are removed); :func:`interrupt_status` tells which signal it was.

    Yields
    ------
    None
    """
    del _received[:]

    def interrupt(signum, frame):
        _received.append(signum)
        raise KeyboardInterrupt

    with _handlers({signal.SIGINT: interrupt, signal.SIGTERM: interrupt}):
        yield


@contextlib.contextmanager
def signals_deferred():
    """While the block runs, SIGINT and SIGTERM are recorded instead of raised, so a save in progress finishes;
    the caller then ends with :func:`interrupt_status`.

    Yields
    ------
    list of int
        The signals received during the block.
    """
    got: list[int] = []

    def record(signum, frame):
        got.append(signum)
        _received.append(signum)

    with _handlers({signal.SIGINT: record, signal.SIGTERM: record}):
        yield got


# -- messages ----------------------------------------------------------------------------------------
@contextlib.contextmanager
def configure_logging(verbose: int = 0, quiet: bool = False):
    """Send the ``springsim`` logger to stderr as ``springsim: <message>`` lines while the block runs.

    Level INFO (progress, slow set-up phases), DEBUG with ``verbose``, WARNING with ``quiet``.
    The handler is removed afterwards, so the library's logging is left as it was.

    Parameters
    ----------
    verbose : int
        ``-v`` given (any count): DEBUG.
    quiet : bool
        ``-q`` given: WARNING.

    Yields
    ------
    None
    """
    from ..progress import logger

    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("springsim: %(message)s"))
    saved = logger.level, logger.propagate
    logger.setLevel(logging.WARNING if quiet else logging.DEBUG if verbose else logging.INFO)
    logger.propagate = False  # one line per message, whatever the application's root logger does
    logger.addHandler(handler)
    try:
        yield
    finally:
        logger.removeHandler(handler)
        logger.setLevel(saved[0])
        logger.propagate = saved[1]


def error_text(e: Exception, scene_path=None) -> str:
    """The one-line message of a user error (a scene error names the scene file, an OS error its file).

    Parameters
    ----------
    e : Exception
        A :class:`~springsim.errors.SpringsimError` or an ``OSError``.
    scene_path : str, optional
        The scene file, prefixed to a scene error's message.

    Returns
    -------
    str
    """
    if isinstance(e, OSError):
        msg = f"{e.filename + ': ' if getattr(e, 'filename', None) else ''}{e.strerror or e}"
    else:
        msg = str(e)
        if isinstance(e, SceneError) and scene_path and not msg.startswith(str(scene_path)):
            msg = f"{scene_path}: {msg}"
    return " ".join(msg.split())
