"""``gcodeplan post-process``: put gcodeplan's times into a G-code file (M73 progress, the slicer's time lines).

Meant to be entered as a slicer post-processing script (PrusaSlicer, SuperSlicer, OrcaSlicer call it with the
G-code path as the last argument); the library function is :func:`gcodeplan.report.postprocess.post_process`.
"""
from __future__ import annotations

import argparse
import os
import sys

from ..report.summary import hms
from .common import add_machine_arguments, add_plan_arguments, check_plan_arguments, machine_from_args, progress_bar


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", metavar="FILE",
                   help="G-code file, rewritten in place (atomically: temporary file + rename, permissions kept); "
                        "'-' (standard input) or a pipe is read once and needs -o")
    p.add_argument("-o", "--output", metavar="OUT",
                   help="write the result here instead of in place ('-': standard output); a symbolic "
                        "link's target is replaced, a device or pipe is written as a stream")
    add_machine_arguments(p)
    add_plan_arguments(p)
    p.add_argument("--no-m73", action="store_true",
                   help="insert no M73 progress lines (and leave the file's own M73 lines alone)")
    p.add_argument("--layer-info", action="store_true",
                   help="also insert Klipper's SET_PRINT_STATS_INFO TOTAL_LAYER= / CURRENT_LAYER= (replacing "
                        "the file's own)")
    p.add_argument("--exclude-object", action="append", default=[], metavar="NAME",
                   help="plan the print with this object cancelled (repeatable)")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bar and no summary line")


def run(args) -> int:
    from ..report.postprocess import post_process

    from ..report.output import resolve_output

    check_plan_arguments(args)
    machine = machine_from_args(args)
    resolve_output(args.output if args.output is not None else args.file)   # refuse before planning
    # PrusaSlicer >= 2.6 tells the final name of the file it is writing (the path it gives is a temporary one)
    from ..gcode.sources import source_name

    shown = os.environ.get("SLIC3R_PP_OUTPUT_NAME") or source_name(args.file)
    bar, progress = progress_bar(args.file, args.quiet)
    try:
        res = post_process(args.file, args.output, machine, args.policy, args.jerk, strict=args.strict,
                           m73=not args.no_m73, layer_info=args.layer_info, progress=progress,
                           exclude_objects=args.exclude_object)
    finally:
        if bar is not None:
            bar.close()
    if not args.quiet:
        print(f"{shown}: {hms(res.total_time_s)} ({res.total_time_s:.3f} s; {res.machine}, {res.policy}); "
              f"{res.counts_text()}", file=sys.stderr)
    return 0
