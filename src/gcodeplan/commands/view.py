"""``gcodeplan view``: the interactive plan viewer, one self-contained HTML page (offline, no server)."""
from __future__ import annotations

import argparse
import os

from ..errors import GcodeplanError
from .common import (add_machine_arguments, add_plan_arguments, check_plan_arguments, machine_from_args,
                     progress_bar)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", metavar="FILE", help="G-code file ('-' reads standard input)")
    add_machine_arguments(p)
    add_plan_arguments(p)
    p.add_argument("-o", "--output", metavar="VIEW.html",
                   help="page to write; default FILE.view.html beside the input")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bar")


def _default_output(path: str) -> str:
    if path == "-":
        return "view.html"
    return os.path.splitext(path)[0] + ".view.html"


def run(args) -> int:
    from ..report.output import atomic_write_text
    from ..report.viewer import build_viewer

    check_plan_arguments(args)
    machine = machine_from_args(args)
    out = args.output or _default_output(args.file)
    parent = os.path.dirname(os.path.abspath(out))
    if not os.path.isdir(parent):   # refuse before planning, not after
        raise GcodeplanError(f"cannot write {out}: no such directory {parent}")
    bar, progress = progress_bar(args.file, args.quiet)
    try:
        page = build_viewer(args.file, machine, args.policy, args.jerk, args.strict, progress)
    finally:
        if bar is not None:
            bar.close()
    atomic_write_text(out, page)
    print(out)
    return 0
