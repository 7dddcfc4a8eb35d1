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

A signal the process inherited as ignored stays ignored: ``nohup gcodeplan …`` survives the terminal's
SIGHUP, and a background job of a script (started with SIGINT ignored) survives Ctrl-C, as every Unix
program does (POSIX: a shell starts asynchronous commands with SIGINT and SIGQUIT ignored). Any error
raised after a signal arrived (the exception raised inside a callback from C comes back as a
``SystemError``, or as a library's own error) is reported as the signal: one line, 128 + n
(``cli.main``, :func:`taken`).
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
_inherited: dict[int, object] = {}   # signal -> disposition found at the first install() (SIG_IGN stays)
_owner: list[int] = []      # pid of the process that installed the handlers
_caught = threading.Event()  # set once cli.main has the exception in hand (no more raising)
RERAISE_S = 1.0             # s: a Terminated swallowed on its way (see _watch) is raised again this late
_sweeps: list = []          # clean-ups run when the handlers are restored (at_restore)
_deferred = threading.Event()  # set while a signal waits for the main thread to leave the JIT (_in_jit)
DEFER_POLL_S = 0.02         # s: how often a held-back signal is tried again
_JIT_PACKAGES = ("numba", "llvmlite")


def _watch(signum: int) -> None:
    """Raise the signal again in the main thread until cli.main has caught it.

    An exception raised by a signal handler is lost when the main thread happens to be in Python code
    called back from C (numba's compiler calls llvmlite's ctypes callbacks, whose exceptions are
    printed and ignored), and the command would run on. Raising it again, once a second, makes sure it
    arrives; a clean-up cut short by it is finished by the registry sweep (report/output.py). A signal
    the handler held back (the main thread was inside the JIT: :func:`_in_jit`) is raised again at once,
    as soon as the main thread has left it."""
    import _thread
    import time

    again_t = time.monotonic() + RERAISE_S
    while not _caught.wait(DEFER_POLL_S):
        if _deferred.is_set() or time.monotonic() >= again_t:
            _deferred.clear()
            again_t = time.monotonic() + RERAISE_S
            _thread.interrupt_main(signum)


def _in_jit(frame) -> bool:
    """True when the main thread is inside numba or llvmlite (compiling, or loading a cached kernel): an
    exception raised there leaves the JIT half-built, and the process can crash on its way out (a
    segmentation fault seen once in CI on a Ctrl-C). The signal then waits until the thread is back in
    gcodeplan's code (:func:`_watch` raises it again every DEFER_POLL_S)."""
    while frame is not None:
        if frame.f_globals.get("__name__", "").partition(".")[0] in _JIT_PACKAGES:
            return True
        frame = frame.f_back
    return False


def _handler(signum, frame) -> None:
    if _owner and os.getpid() != _owner[0]:
        # a forked worker (estimate --jobs) keeps the default: its parent cleans up
        signal.signal(signum, signal.SIG_DFL)
        os.kill(os.getpid(), signum)
        return
    if _caught.is_set():
        return
    _taken.append(signum)
    held_back = _in_jit(frame)
    if held_back:
        _deferred.set()
    if len(_taken) == 1:
        threading.Thread(target=_watch, args=(signum,), name="gcodeplan-signal", daemon=True).start()
    if not held_back:
        raise Terminated(_taken[0])


def taken() -> int | None:
    """The first signal received since :func:`install` (None if none): an error raised after it is the
    signal's doing and is reported as the signal."""
    return _taken[0] if _taken else None


def inherited_ignored(signum: int) -> bool:
    """True when the process started with ``signum`` ignored (nohup, a background job): it stays so."""
    return _inherited.get(signum) == signal.SIG_IGN


def child_defaults() -> None:
    """In a forked worker (estimate --jobs): SIGINT / SIGTERM / SIGHUP back to what the process inherited,
    ignored where it was ignored (nohup), else the default (the worker dies; its parent reports and cleans up)."""
    for sig in HANDLED:
        try:
            signal.signal(sig, signal.SIG_IGN if inherited_ignored(sig) else signal.SIG_DFL)
        except (ValueError, OSError):
            pass


def _unraisable(hook):
    """sys.unraisablehook that drops a Terminated raised where Python can only print it (inside a ctypes
    callback: numba's compiler): it is raised again in the main thread (:func:`_watch`), so the
    multi-line 'Exception ignored' print is noise."""

    def quiet(info) -> None:
        if isinstance(info.exc_value, KeyboardInterrupt) and _taken:
            return
        hook(info)

    quiet.gcodeplan = True
    return quiet


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
    _deferred.clear()
    _owner[:] = [os.getpid()]
    previous = {}
    for sig in HANDLED:
        try:
            now = signal.getsignal(sig)
            _inherited[sig] = now
            if now == signal.SIG_IGN:       # nohup, a background job: ignored it stays
                continue
            previous[sig] = signal.signal(sig, _handler)
        except (ValueError, OSError):      # not settable here (embedded interpreter)
            pass
    import sys

    old_hook = sys.unraisablehook
    if not getattr(old_hook, "gcodeplan", False):
        sys.unraisablehook = _unraisable(old_hook)

    def restore(process_ends: bool = False) -> None:
        """Back to the previous handlers; ``process_ends``: the command's process exits next (the gcodeplan
        command, not a library call): the handlers stay, ignoring what comes now, so a signal that arrives
        after the work is done and written does not kill the process on its way out (its status stays 0)."""
        _caught.set()              # stops the re-raising thread; later signals are ignored until reset
        for sweep in list(_sweeps):
            sweep()                # the last safety net (report/output.py: no registered temporary survives)
        if process_ends:
            return
        for sig, old in previous.items():
            try:
                signal.signal(sig, old if old is not None else signal.SIG_DFL)
            except (ValueError, OSError):
                pass
        if getattr(sys.unraisablehook, "gcodeplan", False):
            sys.unraisablehook = old_hook
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


def at_restore(sweep) -> None:
    """Run ``sweep()`` (no arguments) each time the function returned by :func:`install` restores the
    handlers, after later signals are ignored: a module that keeps something to clean up on the way out
    registers its sweep here (``report/output.py`` its temporary files), so this module needs none of them."""
    if sweep not in _sweeps:
        _sweeps.append(sweep)


def exit_status(err: BaseException) -> int:
    """128 + the signal number for a :class:`Terminated` (or 130 for a plain KeyboardInterrupt)."""
    return 128 + getattr(err, "signum", signal.SIGINT)


__all__ = ["Terminated", "install", "held", "caught", "taken", "child_defaults", "inherited_ignored", "at_restore",
           "exit_status", "HANDLED"]
