#!/usr/bin/env python3
"""Compare gcodeplan's Marlin firmware model with Marlin's own planner/stepper (shared/reference/marlin).

For each reference program: gcodeplan's total against the firmware's, the largest per-line end-time error
(in s and as a share of the total, over the lines the reference lists), the first planner block whose
trapezoid (step count, rates, step boundaries, acceleration, directions) or pick-up time differs from the firmware's,
and per stepper the pulses of ``gcodeplan steps`` against the firmware's (count, largest time error and the
share within 1 µs over the steps the reference stores).

    python tools/compare_marlin.py                       # --machine marlin-2.1.2, both programs
    python tools/compare_marlin.py --machine marlin      # the generic classic-jerk policy, for contrast
    python tools/compare_marlin.py --files cura413_ender3_cylinder30
    python tools/compare_marlin.py --reference variants/jd --policy junction-deviation
    python tools/compare_marlin.py --machine marlin-bugfix --reference bugfix-2.1.x   # the bugfix-2.1.x model
    python tools/compare_marlin.py --reference variants/la      # the marlin-2.1.2 machine with K 0.05

The estimate runs through the same pipeline as ``gcodeplan estimate`` (per-line end times from its
PLAN rows); the block check runs the model itself (planner.marlin.run_marlin) on the parsed rows.
"""
from __future__ import annotations

import argparse
import csv
import gzip
import json
import os
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "src"))

REF = os.path.join(HERE, "..", "..", "shared", "reference", "marlin")
GCODE = os.path.join(HERE, "..", "..", "shared", "gcode")
FILES = ("prusaslicer25_cube20_marlin2", "cura413_ender3_cylinder30")
#: Hz, the reference build's stepper timer
MARLIN_HZ = 25_000_000
#: the linear-advance build's K factor (variants/la: ADVANCE_K), used when --machine is left at its default
LA_K = 0.05
#: (reference column, model output column) of the block check
BLOCK_COLUMNS = (("step_event_count", "OI_SEC"), ("nominal_rate", "OI_NOMINAL_RATE"),
                 ("acceleration_steps_per_s2", "OI_ACCEL_STEPS"), ("initial_rate", "OI_INITIAL_RATE"),
                 ("final_rate", "OI_FINAL_RATE"), ("accelerate_end", "OI_ACCEL_UNTIL"),
                 ("decelerate_start", "OI_DECEL_AFTER"), ("direction_bits", "OI_DIR_BITS"))


def read_csv_gz(path: str) -> dict[str, np.ndarray]:
    with gzip.open(path, "rt", newline="") as fh:
        rows = list(csv.reader(fh))
    head, body = rows[0], rows[1:]
    return {name: np.array([float(r[i]) for r in body]) for i, name in enumerate(head)}


def per_line_check(name: str, machine_spec: str, ref_dir: str, policy: str | None):
    import gcodeplan as gp

    est = gp.estimate(os.path.join(GCODE, name + ".gcode"), gp.load_machine(machine_spec), policy)
    lines, ends = est.line_times()
    ref = read_csv_gz(os.path.join(ref_dir, "per_line", name + ".per_line_end_time.csv.gz"))
    ref_line, ref_end = ref["source_line"].astype(np.int64), ref["end_time_s"]
    idx = np.searchsorted(lines, ref_line)
    idx = np.minimum(idx, len(lines) - 1)
    found = lines[idx] == ref_line
    err = np.where(found, ends[idx] - ref_end, np.nan)
    return est.total_time_s, err, int((~found).sum()), ref_line


def block_check(name: str, machine_spec: str, ref_dir: str, policy: str | None) -> str:
    from gcodeplan.config import load_machine
    from gcodeplan.gcode.reader import read_moves
    from gcodeplan.planner import marlin_kernels as mk
    from gcodeplan.planner.marlin import run_marlin

    machine = load_machine(machine_spec)
    if machine.firmware == "generic":
        return "(no firmware model: no blocks)"
    moves, reader = read_moves(os.path.join(GCODE, name + ".gcode"), machine)
    _, model = run_marlin(moves, reader.limits, machine, keep_blocks=True,
                          e_position_sets=reader.interp.e_position_sets, junction=policy)
    oi = np.concatenate([b[0] for b in model.blocks])
    lines = np.concatenate([b[2] for b in model.blocks])
    has = oi[:, mk.OI_HAS_BLOCK] == 1
    oi, lines = oi[has], lines[has]
    path = os.path.join(ref_dir, "blocks", name + ".blocks.csv.gz")
    if not os.path.exists(path):
        return "(the reference has no blocks)"
    ref = read_csv_gz(path)
    moving = ref["sync"] == 0
    ref = {k: v[moving] for k, v in ref.items()}
    if machine.firmware == "marlin-bugfix":
        # bugfix-2.1.x stores a bit per axis that moves forward (AxisBits); 2.1.2 and the model a bit per axis
        # that moves backward: the same directions, read in the model's convention
        back = np.zeros(len(ref["seq"]), np.int64)
        for bit, col in enumerate(("steps_x", "steps_y", "steps_z", "steps_e")):
            forward = (ref["direction_bits"].astype(np.int64) >> bit) & 1
            back |= np.where((ref[col] > 0) & (forward == 0), 1 << bit, 0)
        ref["direction_bits"] = back
    n = min(len(oi), len(ref["seq"]))
    first = None
    what = ""
    checks = [("source_line", lines)] + [(c, oi[:, getattr(mk, o)]) for c, o in BLOCK_COLUMNS]
    checks.append(("t_pick_s", oi[:, mk.OI_T_PICK] / model.timer_hz))
    for col, mine in checks:
        if col == "t_pick_s":
            bad = np.flatnonzero(np.abs(mine[:n] - ref[col][:n]) > 0.5e-8)
        else:
            bad = np.flatnonzero(mine[:n] != ref[col][:n])
        if bad.size and (first is None or bad[0] < first):
            first, what = int(bad[0]), col
    counts = f"{len(oi)} blocks (reference {len(ref['seq'])})"
    if first is None and len(oi) == len(ref["seq"]):
        return counts + ", every block identical"
    if first is None:
        return counts
    return (f"{counts}, first difference: block {first} (line {int(ref['source_line'][first])}) "
            f"in {what}")


#: (reference npz key, axis letter of gcodeplan's cartesian stepper names)
STEPPERS = (("stepper_x", "x"), ("stepper_y", "y"), ("stepper_z", "z"), ("extruder", "e"))


def run_entry(entry: dict, key: str) -> dict:
    """The reference run's entry of one program: ``key`` (marlin-2.1.2.4, bugfix-2.1.x) or a variant's own."""
    if key in entry:
        return entry[key]
    own = [v for k, v in entry.items() if isinstance(v, dict) and k.startswith("marlin-2.1.2.4-")]
    return own[0] if own else {}


def steps_check(name: str, machine_spec: str, ref_dir: str, policy: str | None, run: dict) -> list[str]:
    """Per stepper: pulses issued against the firmware's count, and over the steps the reference stores (its
    first 200,000 per axis) the largest time error and the shares within 1 µs and at the tick, directions
    compared too. A linear-advance run also compares the extruder's forward and backward pulses, and its
    counts even where no step file is stored."""
    from gcodeplan import pipeline
    from gcodeplan.config import load_machine
    from gcodeplan.stepper.source import StepSink, rails_from

    path = os.path.join(ref_dir, "steps", name + "_steps.npz")
    la = run.get("linear_advance")
    if not os.path.exists(path) and not la:
        return ["(the reference has no step file)"]
    ref = np.load(path) if os.path.exists(path) else None
    stored = set(ref.files) if ref is not None else set()
    keep = {a: max((len(ref[k]) for k, b in STEPPERS if b == a and k in stored), default=0) for _, a in STEPPERS}
    machine = load_machine(machine_spec)
    rails = rails_from(machine)
    names = [r.name for r in rails]
    got = {n: [] for n in names}
    held = dict.fromkeys(names, 0)
    count = dict.fromkeys(names, 0)
    fwd = dict.fromkeys(names, 0)
    back = dict.fromkeys(names, 0)

    def sink(si, t, d):
        n = names[si]
        count[n] += len(t)
        fwd[n] += int(np.count_nonzero(d > 0))
        back[n] += int(np.count_nonzero(d < 0))
        room = keep.get(n, 0) - held[n]
        if room > 0:
            got[n].append((t[:room].copy(), d[:room].copy()))
            held[n] += min(room, len(t))

    from gcodeplan.errors import GcodeplanError

    try:
        pipeline.run(os.path.join(GCODE, name + ".gcode"), machine, policy=policy,
                     sinks=[StepSink(rails, sink, machine=machine)])
    except GcodeplanError as err:
        return [f"(no pulses: {err})"]
    totals = run.get("steps", {})
    out = []
    for key, a in STEPPERS:
        if a not in got or (key not in stored and not (la and key == "extruder")):
            continue
        total = totals.get(key, {}).get("steps_total")
        if key not in stored:
            out.append(f"{key:10s} {count[a]:>9d} steps (firmware {total}: "
                       f"{'equal' if count[a] == total else 'DIFFERENT'}); no stored pulses")
        else:
            rt, rd = ref[key], ref[key + "_dir"]
            mt = np.concatenate([c[0] for c in got[a]]) if got[a] else np.zeros(0)
            md = np.concatenate([c[1] for c in got[a]]) if got[a] else np.zeros(0, np.int8)
            n = min(len(rt), len(mt))
            err = np.abs(mt[:n] - rt[:n])
            tick = np.round(mt[:n] * MARLIN_HZ) == np.round(rt[:n] * MARLIN_HZ)
            same = len(mt) == len(rt) if total is None else count[a] == total
            out.append(f"{key:10s} {count[a]:>9d} steps (firmware {total if total is not None else '?'}: "
                       f"{'equal' if same else 'DIFFERENT'}); first {n}: max |dt| {err.max() * 1e6 if n else 0:.3f} "
                       f"us, {100 * np.mean(err <= 1e-6) if n else 100:.4f} % within 1 us, "
                       f"{100 * np.mean(tick) if n else 100:.4f} % at the tick, "
                       f"directions {'equal' if np.array_equal(md[:n], rd[:n]) else 'DIFFERENT'}")
        if la and key == "extruder":
            # linear advance: the advance pulses go both ways (a stored prefix holds only the first pulses)
            want = (la["extruder_pulses_forward"], la["extruder_pulses_backward"])
            out.append(f"{'':10s} linear advance: {fwd[a]} forward / {back[a]} back, net {fwd[a] - back[a]} "
                       f"(firmware {want[0]} / {want[1]}, net {la['extruder_pulses_net']}: "
                       f"{'equal' if (fwd[a], back[a]) == want else 'DIFFERENT'})")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--machine", default="marlin-2.1.2", help="preset or machine TOML (default marlin-2.1.2)")
    ap.add_argument("--reference", default="",
                    help="reference sub-folder (bugfix-2.1.x, variants/jd, variants/la, ...); default 2.1.2.4")
    ap.add_argument("--policy", default=None, help="junction policy (junction-deviation for variants/jd)")
    ap.add_argument("--files", nargs="*", default=list(FILES))
    ap.add_argument("--no-blocks", action="store_true", help="skip the per-block check")
    ap.add_argument("--no-steps", action="store_true", help="skip the step-pulse check")
    args = ap.parse_args(argv)
    ref_dir = os.path.join(REF, args.reference) if args.reference else REF
    shown = args.machine
    if args.reference.strip("/") == "variants/la" and args.machine == "marlin-2.1.2":
        # the LIN_ADVANCE build: the reference machine with its ADVANCE_K
        args.machine = os.path.join(tempfile.mkdtemp(), "marlin_la.toml")
        with open(args.machine, "w") as fh:
            fh.write(f'base = "marlin-2.1.2"\n[extruder]\npressure_advance = {LA_K}\n')
        shown = f"marlin-2.1.2 with pressure_advance {LA_K}"
    with open(os.path.join(REF, "times.json")) as fh:
        times = json.load(fh)
    if os.path.exists(os.path.join(ref_dir, "times.json")) and ref_dir != REF:
        with open(os.path.join(ref_dir, "times.json")) as fh:
            times = json.load(fh)
    key = "bugfix-2.1.x" if "bugfix" in args.reference else "marlin-2.1.2.4"
    print(f"machine {shown}, policy {args.policy or 'default'}, reference {args.reference or key}")
    print(f"{'file':34s} {'gcodeplan s':>13s} {'reference s':>13s} {'total err':>10s} {'max line err':>13s}"
          f" {'% of total':>10s}  time")
    for name in args.files:
        t0 = time.perf_counter()
        total, err, missing, _ = per_line_check(name, args.machine, ref_dir, args.policy)
        dt = time.perf_counter() - t0
        entry = times[name + ".gcode"]
        ref_total = entry[key]["total_time_s"] if key in entry else entry["total_time_s"]
        worst = float(np.nanmax(np.abs(err))) if np.any(np.isfinite(err)) else float("nan")
        print(f"{name:34s} {total:13.6f} {ref_total:13.6f} {100 * (total - ref_total) / ref_total:+9.5f}% "
              f"{worst:12.6f}s {100 * worst / ref_total:9.5f}%  {dt:.1f}s"
              + (f"  ({missing} reference lines without a time)" if missing else ""))
        if not args.no_blocks:
            print("    blocks:", block_check(name, args.machine, ref_dir, args.policy))
        if not args.no_steps:
            for row in steps_check(name, args.machine, ref_dir, args.policy, run_entry(entry, key)):
                print("    steps:", row)
    return 0


if __name__ == "__main__":
    sys.exit(main())
