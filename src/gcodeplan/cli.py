"""Command line: ``gcodeplan <command> ...``.

Each command is one module of :mod:`gcodeplan.commands` exposing
``add_arguments(parser)`` and ``run(args) -> int``. Modules are imported only
when their command runs, so ``--help`` stays fast.

Exit codes: 0 success, 2 bad input or usage (one line on stderr, ``file:line:``
where it applies; also an output that cannot be written, standard output included), 1 internal error,
128 + n when stopped by signal n.

Options must be spelt out: no command accepts an abbreviation (``--machin`` is an error, not ``--machine``).
"""
from __future__ import annotations

import argparse
import importlib
import os
import sys

from . import __version__
from .errors import GcodeplanError

# name -> (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "estimate": ("gcodeplan.commands.estimate", "plan a G-code file and print its time (the main job)"),
    "parse": ("gcodeplan.commands.parse", "parse a G-code file and print what it contains"),
    "profile": ("gcodeplan.commands.profile", "solve and print (or plot) one 1-D velocity profile"),
    "steps": ("gcodeplan.commands.steps", "write exact per-stepper step times for a G-code file"),
    "plot": ("gcodeplan.commands.plot", "draw velocity / axes / toolpath / layer plots"),
    "report": ("gcodeplan.commands.report", "write a self-contained HTML report"),
    "view": ("gcodeplan.commands.view", "write an interactive plan viewer: one self-contained HTML page"),
    "post-process": ("gcodeplan.commands.post_process",
                     "rewrite a G-code file with gcodeplan's times (M73 progress, the slicer's time lines)"),
    "dump-moves": ("gcodeplan.commands.dump_moves", "write one CSV row per planned move (klipper_estimator's dump-moves)"),
}


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="gcodeplan",
        description="Motion planner for G-code machines: honest print/cut times, velocity profiles, "
                    "exact step timing and plots. Wherever an output file is named, '-' is standard "
                    "output; a device or pipe is written as a stream and a symbolic link's target is "
                    "replaced (the link stays).",
        allow_abbrev=False,     # a mistyped option is an error, never silently another one
    )
    parser.add_argument("--version", action="version", version=f"gcodeplan {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    argv = sys.argv[1:] if argv is None else argv
    wanted = argv[0] if argv else None
    for name, (module, help_text) in COMMANDS.items():
        sp = sub.add_parser(name, help=help_text, description=help_text, allow_abbrev=False)
        # Import only the module of the command that runs: numba and NumPy cost ~0.5 s to import,
        # and the top-level --help needs none of it.
        if wanted == name:
            mod = importlib.import_module(module)   # a broken command module fails loudly here
            mod.add_arguments(sp)
            sp.set_defaults(_run=mod.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run one command; returns the exit status. SIGINT, SIGTERM and SIGHUP clean up (no temporary file
    stays) and give 128 + the signal number (gcodeplan/signals.py)."""
    from .signals import caught, exit_status, install

    import warnings

    restore = install()
    stdout = sys.stdout
    if stdout is not None:
        sys.stdout = _GuardedStdout(stdout)
    shown = warnings.showwarning

    def one_line(message, category, filename, lineno, file=None, line=None):
        # a machine file's named warnings (grbl $$, Marlin M503, LinuxCNC .ini) as one line, like every message
        print(f"gcodeplan: warning: {message}", file=sys.stderr)

    warnings.showwarning = one_line
    try:
        return _main(argv)
    except KeyboardInterrupt as err:
        caught()
        print(f"gcodeplan: {getattr(err, 'reason', 'interrupted')}", file=sys.stderr)
        return exit_status(err)
    except Exception:
        # raised before _main's own handling (building the parser imports the commands' modules): a signal's
        # exception raised inside an import can come back as another error (Python wraps it when it lands in a
        # class body's __set_name__); after a signal it is the signal's doing
        from .signals import Terminated, taken

        if not taken():
            raise
        caught()
        term = Terminated(taken())
        print(f"gcodeplan: {term.reason}", file=sys.stderr)
        return exit_status(term)
    finally:
        warnings.showwarning = shown
        if isinstance(sys.stdout, _GuardedStdout):
            sys.stdout = stdout
        from . import _jit

        restore(process_ends=_jit.command_process)


def _main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if __name__ == "__main__" or _is_console_script():
        from . import _jit

        _jit.command_process = True     # process-wide start-up shortcuts (gcodeplan/_jit.py)
    parser = build_parser(argv)
    args, extra = parser.parse_known_args(argv)
    if extra:
        # the command's own usage, not the top-level one, for an option the command does not know
        _command_parser(parser, getattr(args, "command", None)).error(
            f"unrecognized arguments: {' '.join(extra)}")
    if not getattr(args, "_run", None):
        parser.print_help(sys.stderr)
        return 2
    from .signals import taken

    try:
        rc = int(args._run(args) or 0)
        _flush_stdout()       # a full or closed standard output is reported here, not at exit
        # The process ends next: skip the collector's last traversal of millions of objects at exit.
        import gc

        gc.freeze()
        return rc
    except GcodeplanError as err:
        _stopped_by_signal(taken())
        if isinstance(err, StdoutError):
            _silence_stdout()   # what could not be written is dropped: the exit's flush must not fail again
        print(f"gcodeplan: {err}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        _silence_stdout()     # the reader left (`| head`): nothing more to say, nor at exit
        return 0
    except MemoryError:
        _stopped_by_signal(taken())
        print("gcodeplan: out of memory", file=sys.stderr)
        return 1
    except Exception as err:  # an internal error: say so, keep the traceback for a bug report
        _stopped_by_signal(taken())
        _internal(err)
        return 1


def _internal(err: BaseException) -> None:
    import traceback

    traceback.print_exception(err)
    print(f"gcodeplan: internal error: {err!r} (please report this with the file)", file=sys.stderr)


def _stopped_by_signal(signum: int | None) -> None:
    """An error raised after a signal arrived is the signal's doing (an exception raised by the handler
    inside a callback from C, e.g. numba's compiler, comes back as a SystemError or a library's error):
    report the signal, as cli.main does for a Terminated, not an internal error."""
    if signum:
        from .signals import Terminated

        raise Terminated(signum) from None


def _command_parser(parser: argparse.ArgumentParser, command: str | None) -> argparse.ArgumentParser:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction) and command in action.choices:
            return action.choices[command]
    return parser


class StdoutError(GcodeplanError):
    """Standard output cannot take what a command prints (a full disk, ``> /dev/full``, an I/O error)."""


class _GuardedStdout:
    """Standard output whose write errors (other than a closed pipe) become one :class:`StdoutError`."""

    def __init__(self, stream):
        self._stream = stream

    def _call(self, name, *a):
        try:
            return getattr(self._stream, name)(*a)
        except BrokenPipeError:
            raise
        except OSError as err:
            raise StdoutError(f"cannot write standard output: {err.strerror or err}") from None

    def write(self, text):
        return self._call("write", text)

    def writelines(self, lines):
        return self._call("writelines", lines)

    def flush(self):
        return self._call("flush")

    def __getattr__(self, name):
        return getattr(self._stream, name)


def _flush_stdout() -> None:
    try:
        sys.stdout.flush()
    except (AttributeError, ValueError):
        pass


def _silence_stdout() -> None:
    """Point standard output at /dev/null so that the interpreter's last flush at exit cannot fail
    again (the recipe of Python's signal docs for SIGPIPE)."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (AttributeError, OSError, ValueError):
        pass


def _is_console_script() -> bool:
    """True when this process is the gcodeplan command itself (not pytest or a program calling main)."""
    return os.path.basename(sys.argv[0]) == "gcodeplan"


if __name__ == "__main__":
    sys.exit(main())
