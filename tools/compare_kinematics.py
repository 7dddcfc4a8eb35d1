#!/usr/bin/env python3
"""Compare gcodeplan's plug-in kinematics with real Klipper (../shared/reference/klipper/kinematics/).

``python tools/compare_kinematics.py [--cube] [--per-motor] [--regular | --schedule] [--exact]`` prints a Markdown table: for
each of Klipper's polar, rotary_delta, winch, deltesian, hybrid_corexy, hybrid_corexz and generic_cartesian and each
reference file (b_square, c_circle200, d_slicer_like; with ``--cube`` also the PrusaSlicer cube's first 2032 lines),
our total next to Klipper's, the relative difference, whether every motor has Klipper's step count and net steps, and
the worst step-time difference (``--per-motor``: each motor's too, on stderr).

Step generation runs in the windows Klipper's batch mode made for that input (:func:`batch_windows`, from the
input's bytes and the plan: gcodeplan.stepper.klipper_batch), since the reference was made with ``klippy -i -o``
and Klipper's search restarts at every window; ``--regular``: every 0.25 s instead (a printer that keeps up);
``--schedule``: the windows recorded by the compression reference (its corexy run of the same file, where it has
one, :func:`batch_schedule`), and whether the model's windows for that run are the recorded ones. ``--exact``: the
plug-in motors stepped by the step engine's guarded search (``ik_search="exact"``) instead of Klipper's.

The inputs are prepared as the reference README says (:func:`source_lines`, byte for byte, since the windows
depend on where Klipper's 4096-byte reads end): heater, fan and motor-off lines become
``; [dropped for Klipper] <line>``, G28 becomes ``SET_KINEMATIC_POSITION X=0 Y=0 Z=0``; for polar every X/Y
coordinate is shifted by (+30, +30) mm (decimal arithmetic) so that no move passes the polar centre, and G28 becomes
``SET_KINEMATIC_POSITION X=30 Y=30 Z=0``. The tests (tests/test_kinematics_plugins.py, tests/test_klipper_batch.py)
use the same functions.
"""
from __future__ import annotations

import json
import os
import re
import sys
from decimal import Decimal
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("GCODEPLAN_SHARED", REPO.parent / "shared"))
KIN = SHARED / "reference" / "klipper" / "kinematics"
CONFIGS = ("polar", "rotary_delta", "winch", "deltesian", "hybrid_corexy", "hybrid_corexz", "generic_cartesian")
FILES = ("b_square", "c_circle200", "d_slicer_like")
CUBE = "prusaslicer25_cube20_marlin2"
CUBE_KEY = "prusaslicer25_cube20_marlin2_lines1-2032"
CUBE_LINES = 2032
POLAR_SHIFT = Decimal(30)
# the reference's preprocessing: these commands' lines become comments (line numbers kept)
KLIPPER_DROPPED = frozenset(("M104", "M109", "M140", "M190", "M106", "M107", "M84", "M3", "M5", "M18", "M73"))
DROPPED_PREFIX = "; [dropped for Klipper] "
KLIPPER_SDS_FILTER_T = 750e-6   # s, Klipper's step+dir+step filter (stepcompress.c)

_MOVE = re.compile(r"^\s*G0*[0-3](?![0-9.])", re.I)
_SKP = re.compile(r"^\s*SET_KINEMATIC_POSITION\b", re.I)
_XY_WORD = re.compile(r"(?<![A-Za-z_])([XY])(\s*)([-+]?(?:\d+\.?\d*|\.\d+))", re.I)
_XY_PARAM = re.compile(r"\b([XY])=([-+]?(?:\d+\.?\d*|\.\d+))", re.I)


def _shift_line(line: str) -> str:
    """One line with its X/Y coordinates moved by POLAR_SHIFT (comments untouched)."""
    code, sep, comment = line.partition(";")
    if _MOVE.match(code):
        head = re.match(r"^\s*G0*[0-3]", code, re.I).group(0)
        rest = _XY_WORD.sub(lambda m: f"{m.group(1)}{m.group(2)}{Decimal(m.group(3)) + POLAR_SHIFT}", code[len(head):])
        code = head + rest
    elif _SKP.match(code):
        code = _XY_PARAM.sub(lambda m: f"{m.group(1)}={Decimal(m.group(2)) + POLAR_SHIFT}", code)
    return code + sep + comment


def _klipper_line(line: str, config: str) -> str:
    """One line as the reference's preprocessing left it for ``config``."""
    words = line.partition(";")[0].split()
    if words and words[0].upper() in KLIPPER_DROPPED:
        return DROPPED_PREFIX + line
    if words and words[0].upper() == "G28":
        return "SET_KINEMATIC_POSITION X=30 Y=30 Z=0" if config == "polar" else "SET_KINEMATIC_POSITION X=0 Y=0 Z=0"
    return _shift_line(line) if config == "polar" else line


def source_lines(name: str, config: str) -> list[str]:
    """The G-code as Klipper ran it for ``config`` (module docstring), line numbers kept: joined with newlines (and
    one at the end) these are the bytes Klipper read."""
    if name in (CUBE, CUBE_KEY):
        lines = (SHARED / "gcode" / f"{CUBE}.gcode").read_text().splitlines()[:CUBE_LINES]
    else:
        lines = (SHARED / "reference" / "klipper" / "synthetic" / f"{name}.gcode").read_text().splitlines()
    return [_klipper_line(ln, config) for ln in lines]


def batch_windows(lines, m) -> np.ndarray:
    """The step-generation windows of Klipper's batch mode for ``lines`` (:func:`source_lines`) on machine ``m``
    (s from the first move's start; gcodeplan.stepper.klipper_batch.klipper_batch_flush_times)."""
    from gcodeplan.stepper.klipper_batch import klipper_batch_flush_times

    return klipper_batch_flush_times(("\n".join(lines) + "\n").encode(), m)


def load_klipper_config(path: str):
    from gcodeplan.config import load_klipper_config as load

    return load(path)


def machine(config: str):
    """The reference config read as a Klipper printer.cfg."""
    return load_klipper_config(str(KIN / f"{config}.cfg"))


def batch_schedule(name: str) -> np.ndarray | None:
    """Klipper's batch-mode step-generation windows recorded for ``name`` by the compression reference (its
    corexy run of the same file; s from the first move's start, the final flush left out), or None. Batch mode
    makes 0.25 s windows but after 100 of them in one timer call jumps ahead by how the file's reads fall
    (motion_queuing.py _flush_handler_debug); the search restarts at every window."""
    key = CUBE if name in (CUBE, CUBE_KEY) else name
    path = SHARED / "reference" / "klipper" / "compression" / f"{key}_corexy_queue_step.npz"
    if not path.exists():
        return None     # (the cube's is of the whole file: its first 2032 lines read alike, the plan may differ)
    z = np.load(path)
    return (z["step_gen_time_s"] - z["first_move_print_time_s"])[:-2]


def klipper_steps(lines, m, flush_times=None, ik_search="klipper") -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """{stepper: (times s, dirs)} through the pipeline and the step sink, Klipper's names and filter;
    ``flush_times``: the step-generation windows (:func:`batch_schedule`; default every 0.25 s); ``ik_search``:
    the plug-in motors' search (StepGenerator.IK_SEARCHES)."""
    from gcodeplan import pipeline
    from gcodeplan.kinematics import rails_for
    from gcodeplan.stepper.source import StepSink

    rails = rails_for(m, klipper_names=True)
    parts: dict[int, list] = {}

    def sink(si, t, d):
        parts.setdefault(si, []).append((t.copy(), d.copy()))

    step_sink = StepSink(rails, sink, sds_filter_t=KLIPPER_SDS_FILTER_T, machine=m, ik_search=ik_search)
    if flush_times is not None:
        step_sink.generator.flush_times = np.asarray(flush_times, np.float64)
    pipeline.run(lines, m, sinks=[step_sink])
    return {r.name: (np.concatenate([c[0] for c in parts[i]]) if parts.get(i) else np.empty(0),
                     np.concatenate([c[1] for c in parts[i]]) if parts.get(i) else np.empty(0, np.int8))
            for i, r in enumerate(rails)}


def total(lines, m) -> float:
    import gcodeplan.api as gp

    return gp.estimate(lines, m).total_time_s


def reference(name: str, config: str):
    """(times.json entry of the run, its npz)."""
    key = CUBE_KEY if name in (CUBE, CUBE_KEY) else name
    info = json.loads((KIN / "times.json").read_text())[key]["configs"][config]
    return info, np.load(KIN / "steps" / f"{key}_{config}_exact_steps.npz")


def compare_steps(ours, ref, figures):
    """(counts equal, worst |Δt| s) per the README: full counts and net steps against times.json, the times
    pairwise over the npz prefix (the cube's are the first n_steps_in_npz steps)."""
    counts_ok = True
    worst = 0.0
    per_motor = {}
    for name, (t, d) in ours.items():
        full = figures[name]
        if len(t) != full["n_steps"] or int(d.sum(dtype=np.int64)) != full["net_steps"]:
            counts_ok = False
            continue
        rt, rd = ref[name], ref[name + "_dir"]
        k = len(rt)
        if not np.array_equal(d[:k], rd):
            counts_ok = False
            continue
        if k:
            per_motor[name] = float(np.max(np.abs(t[:k] - rt)))
            worst = max(worst, per_motor[name])
    if figures is not None and "--per-motor" in sys.argv:
        print("    " + ", ".join(f"{n} {w * 1e9:.1f} ns" for n, w in per_motor.items()), file=sys.stderr)
    return counts_ok, worst


def main() -> int:
    if not KIN.exists():
        print(f"no reference at {KIN}", file=sys.stderr)
        return 2
    files = FILES + ((CUBE,) if "--cube" in sys.argv else ())
    print("| file | kinematics | Klipper total s | gcodeplan total s | rel. diff | counts | worst step ns |")
    print("|---|---|---:|---:|---:|---|---:|")
    for name in files:
        for config in CONFIGS:
            info, ref = reference(name, config)
            m = machine(config)
            lines = source_lines(name, config)
            ours = total(lines, m)
            if "--regular" in sys.argv:
                sched = None
            else:
                sched = batch_windows(lines, m)
                if "--schedule" in sys.argv:
                    rec = batch_schedule(name)
                    if rec is not None:
                        if name != CUBE:     # the recorded run is corexy's; the cube's is of the whole file
                            corexy = load_klipper_config(str(KIN.parent / "corexy_corpus.cfg"))
                            same = np.array_equal(batch_windows(source_lines(name, "corexy"), corexy), rec)
                            print(f"    model windows {'=' if same else '!='} recorded ({name}, corexy)",
                                  file=sys.stderr)
                        sched = rec
            search = "exact" if "--exact" in sys.argv else "klipper"
            ok, worst = compare_steps(klipper_steps(lines, m, sched, search), ref, info["steps"]["steppers"])
            rel = (ours - info["total_time_s"]) / info["total_time_s"]
            print(f"| {name} | {config} | {info['total_time_s']:.9f} | {ours:.9f} | {rel:.1e} | "
                  f"{'equal' if ok else 'DIFFER'} | {worst * 1e9:.1f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(REPO / "src"))
    raise SystemExit(main())
