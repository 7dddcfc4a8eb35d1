#!/usr/bin/env python3
"""Compare the ``linuxcnc`` policy with LinuxCNC 2.9's own planned times (both reference sets:
../shared/reference/linuxcnc/ and ../shared/reference/linuxcnc2/).

``python tools/compare_linuxcnc.py [--quick]`` prints a Markdown table: for every shared program and variant
LinuxCNC was run on (and the validation programs), LinuxCNC's total without its queue-empty idle cycles
(``total_time_noidle_s``; for the second set, which has G4 dwells, ``total_time_noidle_plus_dwell_s``: LinuxCNC
runs a dwell with its motion queue empty, gcodeplan counts it), ours, the relative difference, and the largest
difference of the per-line end times over the lines LinuxCNC saw executing (``how == observed`` in its per-line
CSVs; for the second set plus the dwells programmed before the line), in seconds and as a share of the
program's total. A program gcodeplan refuses is listed with its error. Machine: the reference ``config/mill.ini`` read with ``--linuxcnc-ini``
semantics. ``--quick`` leaves out the whole 169 220-line stellabee file.
"""
from __future__ import annotations

import argparse
import csv
import gzip
import json
import math
import os
import re
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("GCODEPLAN_SHARED", REPO.parent / "shared"))
REF = SHARED / "reference" / "linuxcnc"
REF2 = SHARED / "reference" / "linuxcnc2"
CNC2 = SHARED / "gcode" / "cnc2"

# (label, program path or ("g61", base path) for a G61 variant made as the reference run made it,
#  reference stem, validation?)
CASES = [
    ("plasmatest G64 (power-on mode)", REPO / "gcode_samples" / "linuxcnc_plasmatest.ngc", "linuxcnc_plasmatest_g64", False),
    ("plasmatest G61", REF / "programs" / "variants" / "linuxcnc_plasmatest_g61.ngc", "linuxcnc_plasmatest_g61", False),
    ("plasmatest G61.1", REF / "programs" / "variants" / "linuxcnc_plasmatest_g611.ngc",
     "linuxcnc_plasmatest_g611_speedup8", False),
    ("plasmatest `G64 P0.0254` on line 1", REF / "validation" / "programs" / "linuxcnc_plasmatest_G64P0254_line1.ngc",
     "linuxcnc_plasmatest_G64P0.0254-on-line1_speedup10", True),
    ("plasmatest `G64` (P0) on line 1", REF / "validation" / "programs" / "linuxcnc_plasmatest_G64P0_line1.ngc",
     "linuxcnc_plasmatest_G64P0-on-line1_speedup10", True),
    ("arcspiral G64", REPO / "gcode_samples" / "linuxcnc_arcspiral.ngc", "linuxcnc_arcspiral_g64", False),
    ("arcspiral G61", REF / "programs" / "variants" / "linuxcnc_arcspiral_g61.ngc", "linuxcnc_arcspiral_g61", False),
    ("arcspiral G61.1", REF / "programs" / "variants" / "linuxcnc_arcspiral_g611.ngc",
     "linuxcnc_arcspiral_g611_speedup8", False),
    ("stellabee first 20 000 lines G64", REF / "programs" / "linuxcnc_stellabee1_first20000.ngc",
     "linuxcnc_stellabee1_first20000_g64", False),
    ("stellabee first 20 000 lines G61", ("g61", REF / "programs" / "linuxcnc_stellabee1_first20000.ngc"),
     "linuxcnc_stellabee1_first20000_g61_speedup8", False),
    ("stellabee whole G64", SHARED / "gcode" / "linuxcnc_stellabee1.ngc", "linuxcnc_stellabee1_g64_speedup8", False),
    ("stellabee whole G61", ("g61", SHARED / "gcode" / "linuxcnc_stellabee1.ngc"), "linuxcnc_stellabee1_g61_speedup8",
     False),
]
# the second set (cnc2 programs): (label, program, reference stem)
CASES2 = [
    ("Fusion 360 HEMA-P027 G64", CNC2 / "fusion360_lcnc_HEMA-P027.ngc", "fusion360_lcnc_HEMA-P027_g64"),
    ("Fusion 360 HEMA-P027 G61", REF2 / "programs" / "variants" / "fusion360_lcnc_HEMA-P027_g61.ngc",
     "fusion360_lcnc_HEMA-P027_g61_speedup8"),
    ("Estlcam 2-Spool (O-word) G64", CNC2 / "estlcam10_2-Spool.nc", "estlcam10_2-Spool_g64"),
    ("pcb2gcode milldrill G64", CNC2 / "pcb2gcode_multivibrator_tiles_milldrill.ngc",
     "pcb2gcode_multivibrator_tiles_milldrill_g64"),
    ("pcb2gcode milldrill G61", REF2 / "programs" / "variants" / "pcb2gcode_multivibrator_tiles_milldrill_g61.ngc",
     "pcb2gcode_multivibrator_tiles_milldrill_g61_speedup8"),
]
_DWELL_RE = re.compile(r"^\s*(?:N\d+\s*)?G0*4(?![\d.])[^P]*P\s*([-+]?[\d.]+)", re.I)
VALIDATION = ["val_line_g61", "val_line_g64", "val_square_g611", "val_square_g61", "val_square_g64p001",
              "val_square_g64", "val_z_g61", "val_diag_g61"]


def g61_variant(base: Path, out_dir: str) -> Path:
    """The reference's G61 variant: every ``G64 [P..] [Q..]`` word replaced in place by ``G61``, and ``G61`` put
    on line 1 unless line 1 already holds a G61/G64 word (line numbers unchanged)."""
    with open(base, newline="") as fh:
        lines = fh.read().split("\n")
    lines = [re.sub(r"G64(\s*P[-\d.]+)?(\s*Q[-\d.]+)?", "G61", s, flags=re.I) for s in lines]
    if not re.search(r"G6[14]", lines[0], re.I):
        lines[0] = "G61 " + lines[0]
    path = Path(out_dir) / (base.stem + "_g61.ngc")
    with open(path, "w", newline="") as fh:
        fh.write("\n".join(lines))
    return path


def line_times(path: Path, machine) -> tuple[np.ndarray, np.ndarray]:
    """(line, end_time_s) of every line that made motion, through the library's one pipeline."""
    import gcodeplan as gp

    sink = gp.pipeline.LineTimes()
    gp.pipeline.run(str(path), machine, policy="linuxcnc", sinks=[sink])
    return sink.arrays()


def dwell_before(program: Path) -> np.ndarray:
    """Seconds of G4 dwell programmed on lines 1..n-1, indexed by line n (LinuxCNC: P in seconds)."""
    with open(program, "rb") as fh:
        lines = fh.read().decode("utf-8", "replace").split("\n")
    per = np.zeros(len(lines) + 2)
    for i, s in enumerate(lines, 1):
        m = _DWELL_RE.match(s)
        if m:
            per[i] = float(m.group(1))
    return np.concatenate([[0.0], np.cumsum(per)])[:-1]


def per_line_error(line: np.ndarray, end: np.ndarray, csv_path: Path,
                   dwell: np.ndarray | None = None) -> tuple[float, int, int]:
    """(largest |ours − LinuxCNC| over the observed lines, lines compared, observed lines we lack).
    ``dwell[n]``: dwell programmed before line n, added to LinuxCNC's queue-busy times."""
    with gzip.open(csv_path, "rt") as fh:
        rows = [r for r in csv.DictReader(fh) if r["how"] == "observed"]
    ref_line = np.array([int(r["source_line"]) for r in rows], dtype=np.int64)
    ref_end = np.array([float(r["end_time_noidle_s"]) for r in rows])
    if dwell is not None:
        ref_end = ref_end + dwell[ref_line]
    idx = np.searchsorted(line, ref_line)
    ok = (idx < line.size) & (line[np.minimum(idx, max(line.size - 1, 0))] == ref_line)
    diff = np.abs(end[idx[ok]] - ref_end[ok])
    return (float(diff.max()) if diff.size else float("nan")), int(ok.sum()), int((~ok).sum())


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="compare_linuxcnc.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="leave out the whole stellabee file")
    args = ap.parse_args(argv)
    if not REF.exists():
        print(f"no reference at {REF}", file=sys.stderr)
        return 2
    from gcodeplan.config.linuxcnc import load_linuxcnc_ini

    machine = load_linuxcnc_ini(str(REF / "config" / "mill.ini"))
    times = json.loads((REF / "times.json").read_text())
    vtimes = json.loads((REF / "validation" / "times.json").read_text())
    print("| program / variant | LinuxCNC s | gcodeplan s | diff | max per-line error s | of total | lines |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    worst_total = 0.0
    worst_line = 0.0
    with tempfile.TemporaryDirectory() as tmp:
        for label, program, stem, validation in CASES:
            if args.quick and "whole" in label:
                continue
            if isinstance(program, tuple):
                if not program[1].exists():
                    continue
                program = g61_variant(program[1], tmp)
            if not program.exists():
                continue
            ref = (vtimes if validation else times)[stem]["total_time_noidle_s"]
            line, end = line_times(program, machine)
            total = float(end.max()) if end.size else 0.0
            csv_path = REF / ("validation/per_line" if validation else "per_line") / f"{stem}.csv.gz"
            err, n, missing = per_line_error(line, end, csv_path)
            rel = (total - ref) / ref
            worst_total = max(worst_total, abs(rel))
            worst_line = max(worst_line, err / ref)
            miss = f" ({missing} missing)" if missing else ""
            print(f"| {label} | {ref:.3f} | {total:.3f} | {rel * 100:+.3f} % | {err:.3f} | {err / ref * 100:.3f} % "
                  f"| {n}{miss} |")
        times2 = json.loads((REF2 / "times.json").read_text()) if REF2.exists() else {}
        machine2 = load_linuxcnc_ini(str(REF2 / "config" / "mill.ini")) if REF2.exists() else None
        for label, program, stem in CASES2:
            if stem not in times2 or not program.exists():
                continue
            ref = times2[stem]["total_time_noidle_plus_dwell_s"]
            try:
                line, end = line_times(program, machine2)
            except Exception as err:      # a refused program is a row of the table, not the end of the run
                worst_total = math.inf
                print(f"| {label} | {ref:.3f} | refused: {str(err)[:60]} | | | | |")
                continue
            total = float(end.max()) if end.size else 0.0
            csv_path = REF2 / "per_line" / f"{stem}.csv.gz"
            err, n, missing = per_line_error(line, end, csv_path, dwell_before(program))
            rel = (total - ref) / ref
            worst_total = max(worst_total, abs(rel))
            worst_line = max(worst_line, err / ref)
            miss = f" ({missing} missing)" if missing else ""
            print(f"| {label} | {ref:.3f} | {total:.3f} | {rel * 100:+.3f} % | {err:.3f} | {err / ref * 100:.3f} % "
                  f"| {n}{miss} |")
    print("\n| validation program | LinuxCNC s | gcodeplan s | diff s |")
    print("|---|---:|---:|---:|")
    worst_val = 0.0
    for stem in VALIDATION:
        ref = vtimes[stem]["total_time_noidle_s"]
        line, end = line_times(REF / "validation" / "programs" / f"{stem}.ngc", machine)
        total = float(end.max())
        worst_val = max(worst_val, abs(total - ref))
        print(f"| {stem} | {ref:.3f} | {total:.3f} | {total - ref:+.3f} |")
    print(f"\nworst total {worst_total * 100:.3f} % (target 0.1 %), worst per-line error {worst_line * 100:.3f} % of "
          f"the program's total (target 0.1 %), worst validation {worst_val * 1000:.1f} ms (target 1 servo cycle)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
