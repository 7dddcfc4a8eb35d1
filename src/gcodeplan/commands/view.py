"""``gcodeplan view``: the interactive plan viewer, one self-contained HTML page (offline, no server)."""
from __future__ import annotations

import argparse

from ..errors import GcodeplanError
from .common import (add_machine_arguments, add_plan_arguments, check_plan_arguments, machine_from_args,
                     progress_bar)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", metavar="FILE", help="G-code file ('-' reads standard input)")
    add_machine_arguments(p)
    add_plan_arguments(p)
    p.add_argument("-o", "--output", metavar="VIEW.html",
                   help="page to write ('-': standard output); default FILE.view.html beside the input, "
                        "stdin.view.html in the current directory when FILE is standard input")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bar")


def _default_output(path: str) -> str:
    from ..report.output import default_output

    return default_output(path, ".view.html")


def _spool_error(name: str, err: OSError) -> GcodeplanError:
    """A one-line error for an OSError out of the viewer: standard input is kept in $TMPDIR while the page
    is built (report/viewer.py), and that place may be full."""
    import errno
    import tempfile

    if err.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS):
        return GcodeplanError(f"cannot keep a copy of {'standard input' if name == '-' else name} in "
                              f"{tempfile.gettempdir()}: {err.strerror} (point TMPDIR at a place with room)")
    return GcodeplanError(f"{name}: {err.strerror or err}")


def run(args) -> int:
    from ..report.output import atomic_write_text, resolve_output
    from ..report.viewer import build_viewer

    check_plan_arguments(args)
    machine = machine_from_args(args)
    out = args.output or _default_output(args.file)
    target = resolve_output(out)    # refuse an unwritable place before planning, not after
    bar, progress = progress_bar(args.file, args.quiet)
    try:
        page = build_viewer(args.file, machine, args.policy, args.jerk, args.strict, progress)
    except OSError as err:
        raise _spool_error(args.file, err) from None
    finally:
        if bar is not None:
            bar.close()
    atomic_write_text(out, page)
    if target.kind != "stdout":     # the page itself went to standard output
        print(out)
    return 0
