"""Refresh tests/data/reference/ (the compact copy of the peer references) from ../shared/reference/.

    python tests/data/reference/vendor.py [--shared DIR]

Two kinds of file, listed below:

* COPY: byte-for-byte copies (configs, JSON figures, programs, per-line CSVs, small step files).
* PREFIX: step files (``*_exact_steps.npz``) cut to the steps before a time ``truncated_at_s``, which is
  stored in the file as one more key (a 0-d float64); QUEUE_PREFIX: Klipper's queue_step commands of such a
  step file, cut to the commands of those steps (same key). The arrays keep their names, dtypes and order and
  the file stays a compressed npz, so the tests read a prefix exactly as they read the original; where a
  ``truncated_at_s`` key is present they compare only the steps before it (``conftest.steps_window``) and
  still check the full-run counts of times.json. The cut is put in the middle of a pause of at least
  ``GAP_S`` between two consecutive steps of all motors, so that a step a few ns off cannot change sides.

``tests/test_planner_klipper.py::test_vendored_copies_are_identical`` checks every file against ../shared.
"""
from __future__ import annotations

import argparse
import io
import shutil
import sys
import zipfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[2]
GAP_S = 20e-6
KEY = "truncated_at_s"

COPY = [
    # Klipper: configs and figures
    "klipper/cartesian_corpus.cfg", "klipper/corexy_corpus.cfg", "klipper/times.json",
    "klipper/per_line/prusaslicer25_cube20_marlin2.per_line_end_time.csv.gz",
    "klipper/synthetic/times.json",
    "klipper/synthetic/a_long_x_cartesian_exact_steps.npz", "klipper/synthetic/a_long_x_corexy_exact_steps.npz",
    "klipper/synthetic/b_square_cartesian_exact_steps.npz", "klipper/synthetic/b_square_corexy_exact_steps.npz",
    "klipper/synthetic/c_circle200_cartesian_exact_steps.npz",
    "klipper/synthetic/c_circle200_corexy_exact_steps.npz",
    # whole: the compression tests replay every command of this file
    "klipper/synthetic/d_slicer_like_corexy_exact_steps.npz",
    "klipper/compression/b_square_corexy_queue_step.npz",
    "klipper/compression/d_slicer_like_corexy_queue_step.npz",
    "klipper/extensions/times.json",
    "klipper/extensions/delta.cfg", "klipper/extensions/delta_wide.cfg", "klipper/extensions/pa_cartesian.cfg",
    "klipper/extensions/shaper_cartesian.cfg", "klipper/extensions/shaper_corexy.cfg",
    "klipper/kinematics/deltesian.cfg", "klipper/kinematics/generic_cartesian.cfg",
    "klipper/kinematics/hybrid_corexy.cfg", "klipper/kinematics/hybrid_corexz.cfg", "klipper/kinematics/polar.cfg",
    "klipper/kinematics/rotary_delta.cfg", "klipper/kinematics/winch.cfg",
] + [f"klipper/extensions/steps/{n}_{c}_exact_steps.npz"
     for n in ("a_long_x", "b_square", "c_circle200")
     for c in ("shaper_cartesian", "shaper_corexy", "pa_cartesian", "delta")] + [
    "klipper/extensions/steps/d_slicer_like_pa_cartesian_exact_steps.npz",
    # LinuxCNC: the mill, its figures, the programs that are not in gcode_samples/, their per-line CSVs
    "linuxcnc/config/mill.ini", "linuxcnc/times.json", "linuxcnc/validation/times.json",
    "linuxcnc/programs/linuxcnc_stellabee1_first20000.ngc",
    "linuxcnc/per_line/linuxcnc_stellabee1_first20000_g64.csv.gz",
    "linuxcnc/validation/per_line/linuxcnc_plasmatest_G64P0.0254-on-line1_speedup10.csv.gz",
] + [f"linuxcnc/validation/programs/{n}.ngc" for n in (
    "val_line_g61", "val_line_g64", "val_square_g611", "val_square_g61", "val_square_g64p001", "val_square_g64",
    "val_z_g61", "val_diag_g61", "linuxcnc_plasmatest_G64P0254_line1")] + [
    f"linuxcnc/programs/variants/linuxcnc_{p}_{m}.ngc" for p in ("plasmatest", "arcspiral") for m in ("g61", "g611")
] + [f"linuxcnc/per_line/linuxcnc_{p}.csv.gz" for p in (
    "plasmatest_g64", "plasmatest_g61", "plasmatest_g611_speedup8", "arcspiral_g64", "arcspiral_g61",
    "arcspiral_g611_speedup8")] + [
    # grbl 1.1h (grbl-sim): settings, figures, the synthetic programs with every step, per-line ends
    "grbl/times.json", "grbl/grbl_settings.txt", "grbl/grbl_settings_as_gcodeplan_machine.toml",
] + [f"grbl/synthetic/{n}.gcode" for n in ("synth_square", "synth_polycircle30", "synth_arcs")] + [
    f"grbl/steps/{n}_steps.npz" for n in ("synth_square", "synth_polycircle30", "synth_arcs")] + [
    f"grbl/per_line/{n}.per_line_end_time.csv.gz" for n in (
        "synth_square", "synth_polycircle30", "synth_arcs", "linuxcnc_plasmatest", "linuxcnc_arcspiral")] + [
    # Marlin 2.1.2.4: the figures (step counts of the whole runs) of the reference and its S-curve and linear
    # advance builds; Marlin bugfix-2.1.x: the cube's every block and per-line ends (times.json has both
    # versions' totals)
    "marlin/times.json", "marlin/variants/scurve/times.json", "marlin/variants/la/times.json",
    "marlin/bugfix-2.1.x/blocks/prusaslicer25_cube20_marlin2.blocks.csv.gz",
    "marlin/bugfix-2.1.x/per_line/prusaslicer25_cube20_marlin2.per_line_end_time.csv.gz"]

# step file -> keep the steps before about this time (s); the cut moves to the next pause of GAP_S
PREFIX = {
    "klipper/synthetic/d_slicer_like_cartesian_exact_steps.npz": 8.0,
    "klipper/synthetic/e_spiral20k_cartesian_exact_steps.npz": 2.0,
    "klipper/synthetic/e_spiral20k_corexy_exact_steps.npz": 2.0,
    "klipper/steps/prusaslicer25_cube20_marlin2_corexy_exact_steps.npz": 8.0,
    "klipper/extensions/steps/d_slicer_like_shaper_cartesian_exact_steps.npz": 8.0,
    "klipper/extensions/steps/d_slicer_like_shaper_corexy_exact_steps.npz": 8.0,
    "klipper/extensions/steps/d_slicer_like_delta_exact_steps.npz": 5.0,
    "klipper/extensions/steps/e_spiral20k_shaper_cartesian_exact_steps.npz": 2.0,
    "klipper/extensions/steps/e_spiral20k_shaper_corexy_exact_steps.npz": 2.0,
    "klipper/extensions/steps/e_spiral20k_pa_cartesian_exact_steps.npz": 2.0,
    "klipper/extensions/steps/e_spiral20k_delta_wide_exact_steps.npz": 2.0,
    "klipper/extensions/steps/prusaslicer25_cube20_marlin2_shaper_cartesian_exact_steps.npz": 8.0,
    "klipper/extensions/steps/prusaslicer25_cube20_marlin2_shaper_corexy_exact_steps.npz": 8.0,
    "klipper/extensions/steps/prusaslicer25_cube20_marlin2_pa_cartesian_exact_steps.npz": 8.0,
    "klipper/extensions/steps/prusaslicer25_cube20_marlin2_delta_exact_steps.npz": 5.0,
    # Marlin 2.1.2.4's pulses of the cube (its stepper interrupt), and of its S_CURVE_ACCELERATION build
    "marlin/steps/prusaslicer25_cube20_marlin2_steps.npz": 8.0,
    "marlin/variants/scurve/steps/prusaslicer25_cube20_marlin2_steps.npz": 3.0,
    # its LIN_ADVANCE build's extruder pulses (advance pulses both ways): 45 s, about 24,500 pulses
    "marlin/variants/la/steps/prusaslicer25_cube20_marlin2_steps.npz": 45.0,
}

# Klipper's queue_step commands (klipper/compression/) -> the step file they compress: the commands are cut where
# that step file's vendored prefix is cut (every command whose steps all lie in the prefix); the batch
# windows (flush_time_s, step_gen_time_s) are kept whole
QUEUE_PREFIX = {
    "klipper/compression/prusaslicer25_cube20_marlin2_corexy_queue_step.npz":
        "klipper/steps/prusaslicer25_cube20_marlin2_corexy_exact_steps.npz",
}
STEPPERS = ("stepper_x", "stepper_y", "stepper_z", "extruder")
COMMAND_FIELDS = ("interval", "count", "add", "dir", "clock", "end_reason")


def step_arrays(z) -> list[str]:
    """The step-time arrays of a step file (each has a ``<name>_dir`` twin)."""
    return [k for k in z.files if k + "_dir" in z.files]


def cut_time(z, about_s: float) -> float:
    """The middle of the first pause of ≥ GAP_S between consecutive steps (all motors) after ``about_s``."""
    t = np.sort(np.concatenate([z[k] for k in step_arrays(z)]))
    t = t[t >= about_s]
    gaps = np.flatnonzero(np.diff(t) >= GAP_S)
    if len(gaps) == 0:
        raise SystemExit(f"no pause of {GAP_S} s after {about_s} s")
    i = gaps[0]
    return float((t[i] + t[i + 1]) / 2)


def write_prefix(src: Path, dst: Path, about_s: float) -> float:
    z = np.load(src)
    if KEY in z.files:
        raise SystemExit(f"{src}: already has {KEY}")
    cut = cut_time(z, about_s)
    out = {}
    for k in z.files:
        out[k] = z[k]
    for k in step_arrays(z):
        keep = z[k] < cut
        out[k], out[k + "_dir"] = z[k][keep], z[k + "_dir"][keep]
    out[KEY] = np.float64(cut)
    write_npz(dst, out)
    return cut


def write_queue_prefix(src: Path, dst: Path, exact_src: Path, cut: float) -> None:
    z, exact = np.load(src), np.load(exact_src)
    if KEY in z.files:
        raise SystemExit(f"{src}: already has {KEY}")
    out = {k: z[k] for k in z.files}
    for s in STEPPERS:
        n_steps = int(np.count_nonzero(exact[s] < cut))
        keep = int(np.searchsorted(np.cumsum(z[s + "_count"]), n_steps, side="right"))
        for f in COMMAND_FIELDS:
            out[f"{s}_{f}"] = z[f"{s}_{f}"][:keep]
    out[KEY] = np.float64(cut)
    write_npz(dst, out)


def write_npz(dst: Path, out: dict) -> None:
    # np.savez_compressed's layout (one deflated ``<key>.npy`` per array) with a fixed date, so that a refresh
    # from the same ../shared gives the same bytes
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        for k, v in out.items():
            info = zipfile.ZipInfo(k + ".npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            with zf.open(info, "w", force_zip64=True) as fh:
                np.lib.format.write_array(fh, np.asanyarray(v), allow_pickle=False)
    dst.write_bytes(buf.getvalue())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shared", type=Path, default=REPO.parent / "shared", help="the shared folder (../shared)")
    a = ap.parse_args(argv)
    ref = a.shared / "reference"
    if not ref.is_dir():
        print(f"vendor: {ref} not found", file=sys.stderr)
        return 1
    for rel in COPY:
        dst = HERE / rel
        dst.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(ref / rel, dst)
    for rel, about in PREFIX.items():
        dst = HERE / rel
        dst.parent.mkdir(parents=True, exist_ok=True)
        cut = write_prefix(ref / rel, dst, about)
        print(f"{rel}: steps before {cut:.6f} s, {dst.stat().st_size // 1024} KB")
    for rel, steps in QUEUE_PREFIX.items():
        dst = HERE / rel
        cut = float(np.load(HERE / steps)[KEY])
        write_queue_prefix(ref / rel, dst, ref / steps, cut)
        print(f"{rel}: commands of the steps before {cut:.6f} s, {dst.stat().st_size // 1024} KB")
    known = {HERE / r for r in COPY} | {HERE / r for r in PREFIX} | {HERE / r for r in QUEUE_PREFIX}
    extra = [p for p in HERE.rglob("*") if p.is_file() and p.suffix not in (".md", ".py") and p not in known]
    for p in extra:
        print(f"vendor: not listed here, left alone: {p.relative_to(HERE)}", file=sys.stderr)
    total = sum(p.stat().st_size for p in HERE.rglob("*") if p.is_file())
    print(f"total {total / 1e6:.2f} MB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
