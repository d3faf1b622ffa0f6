"""Interrupts that stop every process of a distributed run at the same step.

Serially, Ctrl-C (or SIGTERM in the command line) raises ``KeyboardInterrupt`` wherever the step is, and the
driver turns it into :class:`~springsim.errors.SimulationInterrupted` with the frames so far. Over several MPI
processes that is not safe: the processes receive the signal at different points, one may raise inside its step
while another waits in a collective operation for it (a hang until the launcher kills both), and the frames so far
are gathered collectively. :func:`collective_interrupts` therefore holds SIGINT and SIGTERM while its block runs
(their Python handlers only record the signal), and the driver calls its check after each step: the processes
agree on the largest signal number any of them received (one reduction), and if there is one, every process
passes it to the handler it had (the command line's records it, for the exit status and the message) and raises
``KeyboardInterrupt`` at that step boundary. The driver keeps the block open while it builds the interrupted
run's frames (a collective gather), so no process raises in the middle of it.

A signal that arrives after the last check is only recorded (passed to the handler it had, a
``KeyboardInterrupt`` from it swallowed): the processes have finished their steps by then, and raising on one
process alone would leave the others in the collective operations that follow. Signals whose handler is not a
Python function (``SIG_DFL``, ``SIG_IGN``) are left alone: a library user's process still dies of SIGTERM by
default. Launchers give the processes a grace period after forwarding a signal (Open MPI's ``mpiexec`` 1 s before
SIGKILL, its ``odls_base_sigkill_timeout``; Slurm's ``KillWait``, 30 s by default); the frames are saved only if
the grace period covers the save (docs/distributed.md).
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
    """Hold SIGINT and SIGTERM while the block runs; yield the check to call at each step boundary.

    Parameters
    ----------
    system : System
        The run's system; with one process (``system.size`` 1), or outside the main thread, nothing is held and
        the check does nothing.

    Yields
    ------
    callable
        ``check()``: collective over the system's processes; when any of them received a held signal since the
        last check, passes the largest such signal number to this process's previous handler for it (a
        ``KeyboardInterrupt`` it raises is swallowed) and raises ``KeyboardInterrupt``, on every process.
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

    def notify(sig: int) -> None:
        """Pass ``sig`` to the handler it had here (it records it); a ``KeyboardInterrupt`` from it is ours to
        raise, not its."""
        handler = previous.get(sig)
        if handler is not None:
            try:
                handler(sig, None)
            except KeyboardInterrupt:
                pass

    def check():
        sig = int(system.max(float(max(pending, default=0))))
        if sig > 0:
            del pending[:]
            notify(sig)
            raise KeyboardInterrupt

    def restore(items):
        if items:
            (sig, handler), rest = items[0], items[1:]
            try:
                signal.signal(sig, handler)
            finally:
                restore(rest)  # every handler comes back, whatever a signal on the way raises

    try:
        yield check
    finally:
        late = sorted(set(pending))
        del pending[:]
        restore(list(previous.items()))
        for sig in late:
            notify(sig)
