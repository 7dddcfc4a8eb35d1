"""SIGTERM and SIGHUP end gcodeplan the way Ctrl-C does: cleanly, with exit status 128 + signal.

A service manager, a slicer cancelling its post-processing script or a CI timeout sends SIGTERM (a
closed terminal sends SIGHUP). Python's default for them is to die at once, skipping every
``finally``: the temporary files of a half-written output (``report/output.py``, the step
writers of ``stepper/export.py``) stay behind. :func:`install` makes SIGINT, SIGTERM and SIGHUP
raise :class:`Terminated` (a ``KeyboardInterrupt``, so every clean-up written for Ctrl-C runs for
them too) in the main thread; ``cli.main`` turns it into one line on stderr and the exit status
128 + signal number, the shell's convention (130 for Ctrl-C, 143 for SIGTERM, 129 for SIGHUP).

The exception is raised again every second until ``cli.main`` has caught it (an exception raised
in Python code called back from C, as numba's compiler does, would otherwise be lost); whatever a
clean-up cut short by it leaves, the registry sweep run on the way out removes. Only kill -9
(SIGKILL) escapes, and the temporary names it leaves (``.<name>.gcodeplan-<pid>-*``) are never
taken for output and are removed by the next write to the same target (:mod:`gcodeplan.report.output`).
"""
from __future__ import annotations

import contextlib
import os
import signal
import threading

HANDLED = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))


class Terminated(KeyboardInterrupt):
    """Raised in the main thread when SIGINT, SIGTERM or SIGHUP arrives; ``signum`` is the signal."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = int(signum)

    @property
    def reason(self) -> str:
        """``interrupted`` (SIGINT) or ``terminated by SIGTERM`` / ``SIGHUP``: for the one-line message."""
        if self.signum == signal.SIGINT:
            return "interrupted"
        return f"terminated by {signal.Signals(self.signum).name}"


_taken: list[int] = []      # signals received since install(); the first one gives the exit status
_owner: list[int] = []      # pid of the process that installed the handlers
_caught = threading.Event()  # set once cli.main has the exception in hand (no more raising)
RERAISE_S = 1.0             # s: a Terminated swallowed on its way (see _watch) is raised again this late


def _watch(signum: int) -> None:
    """Raise the signal again in the main thread until cli.main has caught it.

    An exception raised by a signal handler is lost when the main thread happens to be in Python code
    called back from C (numba's compiler calls llvmlite's ctypes callbacks, whose exceptions are
    printed and ignored), and the command would run on. Raising it again, once a second, makes sure it
    arrives; a clean-up cut short by it is finished by the registry sweep (report/output.py)."""
    import _thread

    while not _caught.wait(RERAISE_S):
        _thread.interrupt_main(signum)


def _handler(signum, frame) -> None:
    if _owner and os.getpid() != _owner[0]:
        # a forked worker (estimate --jobs) keeps the default: its parent cleans up
        signal.signal(signum, signal.SIG_DFL)
        os.kill(os.getpid(), signum)
        return
    if _caught.is_set():
        return
    _taken.append(signum)
    if len(_taken) == 1:
        threading.Thread(target=_watch, args=(signum,), name="gcodeplan-signal", daemon=True).start()
    raise Terminated(_taken[0])


def caught() -> None:
    """cli.main has the Terminated in hand: later signals are ignored while it reports and cleans up."""
    _caught.set()


def install():
    """Route SIGINT, SIGTERM and SIGHUP to :class:`Terminated`; returns a function restoring the previous
    handlers. Does nothing (and returns a no-op) outside the main thread, where Python cannot set handlers."""
    if threading.current_thread() is not threading.main_thread():
        return lambda: None
    del _taken[:]
    _caught.clear()
    _owner[:] = [os.getpid()]
    previous = {}
    for sig in HANDLED:
        try:
            previous[sig] = signal.signal(sig, _handler)
        except (ValueError, OSError):      # not settable here (embedded interpreter)
            pass

    def restore() -> None:
        from .report.output import discard_temporaries

        _caught.set()              # stops the re-raising thread; later signals are ignored until reset
        discard_temporaries()      # the last safety net: nothing registered survives the command
        for sig, old in previous.items():
            try:
                signal.signal(sig, old if old is not None else signal.SIG_DFL)
            except (ValueError, OSError):
                pass
        del _taken[:]

    return restore


@contextlib.contextmanager
def held():
    """Hold SIGINT, SIGTERM and SIGHUP back inside the block (delivered when it ends): for the few
    statements that create a temporary file and register it, so no interruption falls between them."""
    if not hasattr(signal, "pthread_sigmask"):
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, HANDLED)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def exit_status(err: BaseException) -> int:
    """128 + the signal number for a :class:`Terminated` (or 130 for a plain KeyboardInterrupt)."""
    return 128 + getattr(err, "signum", signal.SIGINT)


__all__ = ["Terminated", "install", "held", "caught", "exit_status", "HANDLED"]
