"""Progress and set-up timing through the standard :mod:`logging` module.

springsim logs to the logger ``"springsim"`` (and its children), which has a
:class:`logging.NullHandler`: set-up phases are printed only when the application configures
logging, e.g. ``logging.basicConfig(level=logging.INFO)``. The CLI does that itself
(``-v/--verbose`` for DEBUG, ``--quiet`` for warnings only).

Progress asked for with ``progress=True`` shows on its own, as tqdm's or pip's does: while
logging is not configured (no handler on the ``springsim`` logger or, through propagation, on
the root logger) its lines go to stderr as ``springsim: step 40/200 ...``; once an application
configures logging they go through it instead (its handlers, levels and format decide), never both.

Levels
------
INFO
    Set-up phases that took at least :data:`SLOW_PHASE_S` (loading a scene, building an
    integrator's sparsity pattern, an AMG hierarchy), and run progress at most every
    ``interval`` seconds with an estimate of the time left (:class:`ProgressLog`). A run that
    is fast logs nothing at INFO.
DEBUG
    Every phase with its time, whatever it took.

Progress callbacks
------------------
:func:`springsim.simulate` and :func:`springsim.simulate_adaptive` take ``progress``: a
callable ``progress(done, total)`` (steps, or simulated time in seconds for adaptive runs),
or ``True`` for a :class:`ProgressLog`. Any progress bar library plugs in the same way::

    from tqdm import tqdm
    bar = tqdm(total=steps)
    simulate(model, integrator, dt, steps, progress=lambda k, n: bar.update(k - bar.n))
"""

from __future__ import annotations

import logging
import sys
import time
from contextlib import contextmanager

__all__ = ["logger", "phase", "ProgressLog", "SLOW_PHASE_S", "PROGRESS_INTERVAL_S", "as_progress", "format_seconds",
           "logging_configured"]

#: The package logger; modules log to children such as ``springsim.linsolve``.
logger = logging.getLogger("springsim")
logger.addHandler(logging.NullHandler())

#: A set-up phase that takes at least this long [s] is logged at INFO (else at DEBUG).
SLOW_PHASE_S = 1.0

#: Seconds between the progress lines of ``progress=True`` (and before the first); read at call time.
PROGRESS_INTERVAL_S = 5.0


def logging_configured(log: logging.Logger | None = None) -> bool:
    """Whether records of ``log`` (default: the ``springsim`` logger) reach a handler that an application
    configured: one other than a :class:`logging.NullHandler` on it or, through propagation, an ancestor
    (the root logger included).

    Parameters
    ----------
    log : logging.Logger, optional
        The logger; default the ``springsim`` logger.

    Returns
    -------
    bool
    """
    c = log or logger
    while c is not None:
        if any(not isinstance(h, logging.NullHandler) for h in c.handlers):
            return True
        if not c.propagate:
            return False
        c = c.parent
    return False


def format_seconds(s: float) -> str:
    """``"4.2 s"``, ``"42 s"``, ``"3 min 05 s"``, ``"2 h 03 min"``.

    Parameters
    ----------
    s : float
        A duration [s]; negative values count as 0.

    Returns
    -------
    str
        Tenths of a second below 10 s, whole seconds below a minute, then minutes and seconds, then hours and
        minutes.
    """
    s = max(float(s), 0.0)
    if s < 60:
        return f"{s:.1f} s" if s < 10 else f"{s:.0f} s"
    m, sec = divmod(round(s), 60)
    if m < 60:
        return f"{m} min {sec:02d} s"
    h, m = divmod(m, 60)
    return f"{h} h {m:02d} min"


@contextmanager
def phase(what: str, log: logging.Logger | None = None, slow: float = SLOW_PHASE_S, announce: bool = True):
    """Time the block as the set-up phase ``what``.

    Logs ``"<what> ..."`` at DEBUG when it starts (if ``announce``) and ``"<what>: <time>"`` when it
    ends, at INFO if it took at least ``slow`` seconds, else at DEBUG.

    Parameters
    ----------
    what : str
        The phase, as the log lines name it (``"sparsity pattern of 3000 DOFs"``).
    log : logging.Logger, optional
        Where to log; default the ``springsim`` logger.
    slow : float
        Duration [s] from which the end is logged at INFO; default :data:`SLOW_PHASE_S`.
    announce : bool
        Log the start too (at DEBUG).

    Yields
    ------
    None
        Nothing; a block that raises is not logged as ended.
    """
    log = log or logger
    if announce:
        log.debug("%s ...", what)
    t0 = time.perf_counter()
    yield
    dt = time.perf_counter() - t0
    log.log(logging.INFO if dt >= slow else logging.DEBUG, "%s: %s", what, format_seconds(dt))


class ProgressLog:
    """A progress callback that logs one line at most every ``interval`` seconds.

    While logging is not configured (:func:`logging_configured` is false) the lines go to stderr
    as ``springsim: <line>`` instead, unless ``log`` was given a level above ``level``.

    ``progress(done, total)`` with integers (steps) logs ``step 40/200 (20%), 12 s elapsed,
    about 48 s left``; with floats (simulated time of an adaptive run) ``t = 0.4 s of 2 s``.
    The first line comes after ``interval`` seconds, so short runs log nothing. The time left
    is extrapolated from the rate since the first call (so the set-up and the first step,
    which builds factorisations and hierarchies, do not distort it).

    Parameters
    ----------
    interval : float
        Seconds between lines (and before the first).
    log : logging.Logger, optional
        Default: the ``springsim`` logger.
    level : int
        Logging level of the lines (default INFO).
    """

    def __init__(self, interval: float = 5.0, log: logging.Logger | None = None, level: int = logging.INFO):
        self.interval = float(interval)
        self.log = log or logger
        self.level = level
        self.t_start = time.perf_counter()
        self._first: tuple[float, float] | None = None  # (time, done) of the first call
        self._last = self.t_start
        self.lines = 0

    def __call__(self, done, total) -> None:
        now = time.perf_counter()
        if self._first is None:
            self._first = (now, float(done))
        if now - self._last < self.interval:
            return
        self._last = now
        self.lines += 1
        line = self.line(done, total, now)
        if logging_configured(self.log):
            self.log.log(self.level, "%s", line)
        elif self.log.level <= self.level:  # NOTSET, or a level the caller set that lets the line through
            print(f"springsim: {line}", file=sys.stderr, flush=True)

    def line(self, done, total, now: float | None = None) -> str:
        """The progress line for ``done`` of ``total``.

        Parameters
        ----------
        done, total : int or float
            Steps done and in all (integers), or simulated time reached and the end time [s] (floats).
        now : float, optional
            :func:`time.perf_counter` time of the line; default now.

        Returns
        -------
        str
            ``step 40/200 (20%), 12 s elapsed, about 48 s left`` (the time left once it can be extrapolated).
        """
        now = time.perf_counter() if now is None else now
        frac = float(done) / float(total) if total else 1.0
        if isinstance(done, float) or isinstance(total, float):
            where = f"t = {float(done):.4g} s of {float(total):.4g} s ({100 * frac:.0f}%)"
        else:
            where = f"step {done}/{total} ({100 * frac:.0f}%)"
        text = f"{where}, {format_seconds(now - self.t_start)} elapsed"
        t1, d1 = self._first if self._first is not None else (self.t_start, 0.0)
        if d1 < float(done) < float(total) and now > t1:
            rate = (float(done) - d1) / (now - t1)
            text += f", about {format_seconds((float(total) - float(done)) / rate)} left"
        return text


def as_progress(progress):
    """The callback for a ``progress`` argument: None, a callable, or True for a :class:`ProgressLog`.

    Parameters
    ----------
    progress : callable, bool or None
        ``progress(done, total)``, True (a :class:`ProgressLog` every :data:`PROGRESS_INTERVAL_S`), or None or
        False (no progress).

    Returns
    -------
    callable or None
        The callback, or None.

    Raises
    ------
    TypeError
        ``progress`` is none of these.
    """
    if progress is True:
        return ProgressLog(interval=PROGRESS_INTERVAL_S)
    if progress is None or progress is False:
        return None
    if not callable(progress):
        raise TypeError(f"progress must be a callable, True or None, got {type(progress).__name__}")
    return progress
