#!/usr/bin/env python3
"""Compare gcodeplan with Klipper's own planned times (../shared/reference/klipper/).

``python tools/compare_klipper.py`` prints a Markdown table: for every corpus file with a Klipper
reference, our total next to Klipper's, the relative difference, and the largest difference of the
per-line end times (Klipper's per_line CSVs, 6 decimals). Machine: the reference config
cartesian_corpus.cfg read with --klipper-config semantics.
"""
from __future__ import annotations

import csv
import gzip
import json
import os
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("GCODEPLAN_SHARED", REPO.parent / "shared"))
REF = SHARED / "reference" / "klipper"


def plan_file(path: Path, machine):
    """(line, end_time_s) of every planned row, through the library's one pipeline."""
    import gcodeplan as gp

    sink = gp.pipeline.Collect(segments=False)
    gp.pipeline.run(str(path), machine, sinks=[sink])
    moves, plan, _ = sink.arrays()
    return moves["line"], plan["t_start"] + plan["duration"]


def per_line_max_diff(line: np.ndarray, end: np.ndarray, csv_path: Path) -> tuple[float, int]:
    """Largest |ours − Klipper| over the reference lines (end time of the last move a line made)."""
    with gzip.open(csv_path, "rt") as f:
        rows = list(csv.reader(f))[1:]
    ref_line = np.array([int(r[0]) for r in rows])
    ref_end = np.array([float(r[1]) for r in rows])
    # last end time per source line (lines are non-decreasing in plan order)
    last = np.r_[line[1:] != line[:-1], True]
    our_line, our_end = line[last], end[last]
    idx = np.searchsorted(our_line, ref_line)
    ok = (idx < our_line.size) & (our_line[np.minimum(idx, our_line.size - 1)] == ref_line)
    missing = int((~ok).sum())
    diff = np.abs(our_end[idx[ok]] - ref_end[ok])
    return float(diff.max()) if diff.size else float("nan"), missing


def main() -> int:
    from gcodeplan.config import load_klipper_config

    if not REF.exists():
        print(f"no reference at {REF}", file=sys.stderr)
        return 2
    machine = load_klipper_config(str(REF / "cartesian_corpus.cfg"))
    times = json.loads((REF / "times.json").read_text())
    print("| file | Klipper total s | gcodeplan total s | relative difference | max per-line diff s | lines missing |")
    print("|---|---:|---:|---:|---:|---:|")
    for name, ref in times.items():
        path = SHARED / "gcode" / name
        if not path.exists():
            continue
        line, end = plan_file(path, machine)
        total = float(end.max()) if end.size else 0.0
        csv_path = REF / ref["per_line_csv"] if "per_line_csv" in ref else None
        diff, missing = per_line_max_diff(line, end, csv_path) if csv_path and csv_path.exists() else (float("nan"), 0)
        k = ref["total_time_s"]
        print(f"| {name} | {k:.6f} | {total:.6f} | {(total - k) / k:+.1e} | {diff:.1e} | {missing} |")
    synth = json.loads((REF / "synthetic" / "times.json").read_text())
    print("\n| synthetic file | Klipper total s | gcodeplan total s | difference s |")
    print("|---|---:|---:|---:|")
    for name, ref in synth.items():
        k = ref["total_time_s"] if isinstance(ref, dict) else float(ref)
        line, end = plan_file(REF / "synthetic" / name, machine)
        total = float(end.max())
        print(f"| {name} | {k:.9f} | {total:.9f} | {total - k:+.1e} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
