"""``gcodeplan dump-moves FILE -o moves.csv``: one CSV row per planned move (klipper_estimator's dump-moves).

Streaming: each planned piece is formatted and written as it leaves the planner, into a temporary file
that replaces ``-o`` when the whole file is done (nothing half-written on an error).
"""
from __future__ import annotations

import argparse

import numpy as np

from ..schema import KIND_NAMES, LIMIT_NAMES
from .common import add_machine_arguments, add_plan_arguments, check_plan_arguments, machine_from_args, progress_bar

# (column, unit) in order; docs: README "Per object, per line, per move"
COLUMNS = (
    ("line", ""), ("kind", ""),
    ("x0", "mm"), ("y0", "mm"), ("z0", "mm"), ("e0", "mm"),
    ("x1", "mm"), ("y1", "mm"), ("z1", "mm"), ("e1", "mm"),
    ("length_mm", "mm"), ("start_v", "mm/s"), ("cruise_v", "mm/s"), ("end_v", "mm/s"),
    ("accel", "mm/s²"), ("decel", "mm/s²"), ("accel_t", "s"), ("cruise_t", "s"), ("decel_t", "s"),
    ("t_start", "s"), ("duration", "s"), ("limited_by", ""), ("feature", ""), ("layer", ""), ("object", ""),
)
HEADER = ",".join(c for c, _ in COLUMNS) + "\n"
_ROW = ("%d,%s," + "%.5f," * 8 + "%.5f,%.4f,%.4f,%.4f,%.1f,%.1f,%.7f,%.7f,%.7f,%.7f,%.7f,%s,%s,%d,%s\n")


def _csv_text(name: str) -> str:
    """A name as one CSV field (quoted when it holds a comma, quote or line break)."""
    if any(c in name for c in ',"\n\r'):
        return '"' + name.replace('"', '""') + '"'
    return name


def format_rows(moves: np.ndarray, plan: np.ndarray, features: list[str], objects: list[str]) -> str:
    """CSV rows of one piece (MOVE and PLAN rows aligned). ``features`` / ``objects``: the names the
    indices refer to (-1 = none: an empty field)."""
    feat = np.array([_csv_text(f) for f in features] + [""], dtype=object)
    obj = np.array([_csv_text(o) for o in objects] + [""], dtype=object)
    fi = np.where(moves["feature"] >= 0, moves["feature"], len(features))
    oi = np.where(moves["object"] >= 0, moves["object"], len(objects))
    kinds = np.array(KIND_NAMES, dtype=object)[moves["kind"]]
    limits = np.array(LIMIT_NAMES, dtype=object)[plan["limit"]]
    cols = (moves["line"].tolist(), kinds.tolist(),
            moves["x0"].tolist(), moves["y0"].tolist(), moves["z0"].tolist(), moves["e0"].tolist(),
            moves["x1"].tolist(), moves["y1"].tolist(), moves["z1"].tolist(), moves["e1"].tolist(),
            moves["move_d"].tolist(), plan["start_v"].tolist(), plan["cruise_v"].tolist(), plan["end_v"].tolist(),
            plan["accel"].tolist(), plan["decel"].tolist(), plan["accel_t"].tolist(), plan["cruise_t"].tolist(),
            plan["decel_t"].tolist(), plan["t_start"].tolist(), plan["duration"].tolist(), limits.tolist(),
            feat[fi].tolist(), moves["layer"].tolist(), obj[oi].tolist())
    return "".join(map(_ROW.__mod__, zip(*cols)))


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", metavar="FILE", help="G-code file")
    p.add_argument("-o", "--output", required=True, metavar="moves.csv",
                   help="CSV file to write ('-': standard output)")
    add_machine_arguments(p)
    add_plan_arguments(p)
    p.add_argument("--exclude-object", action="append", default=[], metavar="NAME",
                   help="plan the print with this object cancelled (repeatable)")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bar")


def dump_moves(source, out_path: str, machine, policy=None, jerk=None, *, strict=False, progress=None,
               exclude_objects=()) -> int:
    """Write the CSV of every planned row of ``source`` to ``out_path`` (atomically); returns the rows."""
    from ..pipeline import Run
    from ..report.output import atomic_output

    drive = Run(source, machine, policy=policy, jerk=jerk, strict=strict, progress=progress,
                exclude_objects=exclude_objects)
    reader = drive.reader
    rows = 0
    with atomic_output(out_path, "w", newline="") as fh:
        fh.write(HEADER)
        for piece in drive:
            # names are appended as the file is read; a piece only refers to names already read
            fh.write(format_rows(piece.moves, piece.plan, reader.features, reader.interp.objects.names))
            rows += len(piece.moves)
    return rows


def run(args) -> int:
    from ..report.output import resolve_output

    check_plan_arguments(args)
    machine = machine_from_args(args)
    resolve_output(args.output)       # refuse an unwritable place before planning
    bar, progress = progress_bar(args.file, args.quiet)
    try:
        dump_moves(args.file, args.output, machine, args.policy, args.jerk, strict=args.strict, progress=progress,
                   exclude_objects=args.exclude_object)
    finally:
        if bar is not None:
            bar.close()
    return 0
