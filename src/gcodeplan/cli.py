"""Command line: ``gcodeplan <command> ...``.

Each command is one module of :mod:`gcodeplan.commands` exposing
``add_arguments(parser)`` and ``run(args) -> int``. Modules are imported only
when their command runs, so ``--help`` stays fast.

Exit codes: 0 success, 2 bad input or usage (one line on stderr, ``file:line:``
where it applies), 1 internal error.
"""
from __future__ import annotations

import argparse
import importlib
import os
import sys

from . import __version__

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
                    "exact step timing and plots.",
    )
    parser.add_argument("--version", action="version", version=f"gcodeplan {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    argv = sys.argv[1:] if argv is None else argv
    wanted = argv[0] if argv else None
    for name, (module, help_text) in COMMANDS.items():
        sp = sub.add_parser(name, help=help_text, description=help_text)
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

    restore = install()
    try:
        return _main(argv)
    except KeyboardInterrupt as err:
        caught()
        print(f"gcodeplan: {getattr(err, 'reason', 'interrupted')}", file=sys.stderr)
        return exit_status(err)
    finally:
        restore()


def _main(argv: list[str] | None = None) -> int:
    from .errors import GcodeplanError

    argv = sys.argv[1:] if argv is None else list(argv)
    if __name__ == "__main__" or _is_console_script():
        from . import _jit

        _jit.command_process = True     # process-wide start-up shortcuts (gcodeplan/_jit.py)
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    if not getattr(args, "_run", None):
        parser.print_help(sys.stderr)
        return 2
    try:
        rc = int(args._run(args) or 0)
        # The process ends next: skip the collector's last traversal of millions of objects at exit.
        import gc

        gc.freeze()
        return rc
    except GcodeplanError as err:
        print(f"gcodeplan: {err}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        return 0
    except MemoryError:
        print("gcodeplan: out of memory", file=sys.stderr)
        return 1
    except Exception as err:  # an internal error: say so, keep the traceback for a bug report
        import traceback

        traceback.print_exc()
        print(f"gcodeplan: internal error: {err!r} (please report this with the file)", file=sys.stderr)
        return 1


def _is_console_script() -> bool:
    """True when this process is the gcodeplan command itself (not pytest or a program calling main)."""
    return os.path.basename(sys.argv[0]) == "gcodeplan"


if __name__ == "__main__":
    sys.exit(main())
