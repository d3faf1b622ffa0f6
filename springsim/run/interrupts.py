"""Interrupts that stop every process of a distributed run at the same step.

Serially, Ctrl-C (or SIGTERM in the command line) raises ``KeyboardInterrupt`` wherever the step is, and the
driver turns it into :class:`~springsim.errors.SimulationInterrupted` with the frames so far. Over several MPI
processes that is not safe: the processes receive the signal at different points, one may raise inside its step
while another waits in a collective operation for it (a hang until the launcher kills both), and the frames so far
are gathered collectively. :func:`collective_interrupts` therefore defers SIGINT and SIGTERM during each step
(their Python handlers only record the signal) and, after each step, the processes agree whether any of them was
signalled (one reduction of a flag); if one was, every process raises ``KeyboardInterrupt`` at that step
boundary, the signalled ones through the handler they had (the command line's records which signal it was, for the
exit status), so the driver stops all of them at the same step with the same frames.

Signals whose handler is not a Python function (``SIG_DFL``, ``SIG_IGN``) are left alone: a library user's
process still dies of SIGTERM by default. Launchers give the processes a grace period after forwarding a signal
(Open MPI's ``mpiexec`` 1 s before SIGKILL, its ``odls_base_sigkill_timeout``; Slurm's ``KillWait``, 30 s by
default); the frames are saved only if the grace period covers the save (docs/distributed.md).
"""

from __future__ import annotations

import signal
import threading
from contextlib import contextmanager
from typing import Callable, Iterator

__all__ = ["collective_interrupts"]

_SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextmanager
def collective_interrupts(system) -> Iterator[Callable[[], None]]:
    """Defer SIGINT and SIGTERM while the block runs; yield the check to call at each step boundary.

    Parameters
    ----------
    system : System
        The run's system; with one process (``system.size`` 1), or outside the main thread, nothing is deferred
        and the check does nothing.

    Yields
    ------
    callable
        ``check()``: collective over the system's processes; raises ``KeyboardInterrupt`` on every process when any
        of them received a deferred signal since the block began.

    Notes
    -----
    When the block ends, the handlers it replaced are restored; a signal recorded after the last check is then
    delivered to its handler (a ``KeyboardInterrupt`` outside the step loop, as serially).
    """
    if getattr(system, "size", 1) <= 1 or threading.current_thread() is not threading.main_thread():
        yield lambda: None
        return
    pending: list[int] = []
    previous = {}

    def record(signum, frame):
        pending.append(signum)

    for sig in _SIGNALS:
        handler = signal.getsignal(sig)
        if callable(handler):
            previous[sig] = handler
            signal.signal(sig, record)

    def deliver():
        sig = pending[0]
        del pending[:]
        previous[sig](sig, None)  # the handler it had: normally raises KeyboardInterrupt

    def check():
        if system.max(1.0 if pending else 0.0) > 0.0:
            if pending:
                deliver()
            raise KeyboardInterrupt

    try:
        yield check
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        if pending:
            deliver()
