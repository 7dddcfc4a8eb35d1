"""The 'linuxcnc' policy against real LinuxCNC 2.9 runs (../shared/reference/linuxcnc) and closed forms."""
from __future__ import annotations

import csv
import gzip
import json
import math

import numpy as np
import pytest

from conftest import shared_path
from gcodeplan.errors import ConfigError
from gcodeplan.gcode.reader import read_moves
from gcodeplan.linuxcnc_ini import load_linuxcnc_ini
from gcodeplan.planner import plan_moves
from gcodeplan.planner.linuxcnc import run_linuxcnc

REF = ("reference", "linuxcnc")


def _mill():
    return load_linuxcnc_ini(str(shared_path(*REF, "config", "mill.ini")))


def _noidle(stem: str, validation: bool = False) -> float:
    parts = REF + (("validation",) if validation else ()) + ("times.json",)
    return json.loads(shared_path(*parts).read_text())[stem]["total_time_noidle_s"]


def _run(path, machine=None):
    m = machine or _mill()
    moves, reader = read_moves(str(path), m)
    return run_linuxcnc(moves, reader.limits, m), moves, reader, m


# ------------------------------------------------------------------ closed forms (README validation table)
@pytest.mark.parametrize("stem", ["val_line_g61", "val_line_g64", "val_square_g611", "val_square_g61",
                                  "val_square_g64p001", "val_square_g64", "val_z_g61", "val_diag_g61"])
def test_validation_programs_within_one_cycle(stem):
    run, *_ = _run(shared_path(*REF, "validation", "programs", stem + ".ngc"))
    assert abs(run.total_time - _noidle(stem, validation=True)) <= 0.001 + 1e-9


def test_closed_forms_without_reference_files(tmp_path):
    """t = L/v + v/a: full acceleration in G61 / G61.1, half in G64 (the last move ends a parabolic blend)."""
    m = load_linuxcnc_ini(_write_ini(tmp_path))
    for mode, expect in (("G61.1", 1.100), ("G64", 1.200)):
        f = tmp_path / f"l{mode}.ngc"
        f.write_text(f"G21 G90 {mode}\nG1 X100 F6000\nM2\n")
        run, *_ = _run(f, m)
        assert run.total_time == pytest.approx(expect, abs=1e-9)
    # a diagonal move: the per-axis projection allows √2·1000 mm/s² along the path, speed capped by [TRAJ]
    f = tmp_path / "diag.ngc"
    f.write_text("G21 G90 G61\nG1 X100 Y100 F6000\nM2\n")
    run, *_ = _run(f, m)
    assert run.total_time == pytest.approx(100 * math.sqrt(2) / 100 + 100 / (1000 * math.sqrt(2)), abs=0.0011)


def test_zero_length_move_dropped_and_m5_is_a_full_stop(tmp_path):
    m = load_linuxcnc_ini(_write_ini(tmp_path))
    f = tmp_path / "p.ngc"
    f.write_text("G21 G90 G64\nG1 X50 F6000\nG1 X50\nM5\nG1 X100\nM2\n")
    run, moves, *_ = _run(f, m)
    # two separate G64 moves from rest to rest (the queue drains at M5), each at half acceleration: L/v + v/(a/2)
    one = 50 / 100 + 100 / 500
    assert run.total_time == pytest.approx(2 * one, abs=0.0011)
    assert len(run.queue) == 2


# ------------------------------------------------------------------ shared programs
PROGRAMS = [
    ("linuxcnc_plasmatest_g64", ("gcode_samples", "linuxcnc_plasmatest.ngc"), 0.005),
    ("linuxcnc_plasmatest_g61", REF + ("programs", "variants", "linuxcnc_plasmatest_g61.ngc"), 0.005),
    ("linuxcnc_plasmatest_g611_speedup8", REF + ("programs", "variants", "linuxcnc_plasmatest_g611.ngc"), 0.005),
    ("linuxcnc_arcspiral_g64", ("gcode_samples", "linuxcnc_arcspiral.ngc"), 0.005),
    ("linuxcnc_arcspiral_g61", REF + ("programs", "variants", "linuxcnc_arcspiral_g61.ngc"), 0.005),
    ("linuxcnc_arcspiral_g611_speedup8", REF + ("programs", "variants", "linuxcnc_arcspiral_g611.ngc"), 0.005),
]


def _program_path(parts):
    if parts[0] == "gcode_samples":
        from pathlib import Path

        return Path(__file__).resolve().parent.parent.joinpath(*parts)
    return shared_path(*parts)


@pytest.mark.parametrize("stem,parts,rel", PROGRAMS)
def test_program_totals(stem, parts, rel):
    run, *_ = _run(_program_path(parts))
    ref = _noidle(stem)
    assert abs(run.total_time - ref) <= rel * ref, (run.total_time, ref)


@pytest.mark.parametrize("stem,parts", [
    ("linuxcnc_plasmatest_g611_speedup8", REF + ("programs", "variants", "linuxcnc_plasmatest_g611.ngc")),
    ("linuxcnc_plasmatest_g61", REF + ("programs", "variants", "linuxcnc_plasmatest_g61.ngc")),
    ("linuxcnc_arcspiral_g64", ("gcode_samples", "linuxcnc_arcspiral.ngc")),
])
def test_per_line_end_times(stem, parts):
    """Every line LinuxCNC saw executing ends within 0.5 % of the program's total of LinuxCNC's time."""
    run, *_ = _run(_program_path(parts))
    ours = run.line_end_times()
    rows = list(csv.DictReader(gzip.open(shared_path(*REF, "per_line", stem + ".csv.gz"), "rt")))
    total = _noidle(stem)
    worst = 0.0
    for r in rows:
        if r["how"] != "observed":
            continue
        worst = max(worst, abs(ours[int(r["source_line"])] - float(r["end_time_noidle_s"])))
    assert worst <= 0.005 * total, worst


@pytest.mark.xfail(strict=True, reason="known gap: G64 P0.0254 blends are +1.1 % (arc blends approximated)")
def test_plasmatest_with_tolerance_total():
    run, *_ = _run(shared_path(*REF, "validation", "programs", "linuxcnc_plasmatest_G64P0254_line1.ngc"))
    ref = _noidle("linuxcnc_plasmatest_G64P0.0254-on-line1_speedup10", validation=True)
    assert abs(run.total_time - ref) <= 0.005 * ref


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="known gap: stellabee G64 is +4 % (short 3-D segments, blend details)")
def test_stellabee_first20000_total():
    run, *_ = _run(shared_path(*REF, "programs", "linuxcnc_stellabee1_first20000.ngc"))
    ref = _noidle("linuxcnc_stellabee1_first20000_g64")
    assert abs(run.total_time - ref) <= 0.005 * ref


# ------------------------------------------------------------------ plumbing
def test_plan_rows_sum_to_the_run(tmp_path):
    m = load_linuxcnc_ini(_write_ini(tmp_path))
    f = tmp_path / "sq.ngc"
    f.write_text("G21 G90 G64 P0.01\nG1 X50 F6000\nY50\nX0\nY0\nG2 X0 Y0 I5 J0\nM2\n")
    moves, reader = read_moves(str(f), m)
    plan = plan_moves(moves, reader.limits, m, "linuxcnc")
    assert len(plan) == len(moves)
    end = float((plan["t_start"] + plan["duration"]).max())
    run = run_linuxcnc(moves, reader.limits, m)
    assert end == pytest.approx(run.total_time, abs=1e-9)
    assert np.all(np.diff(plan["t_start"]) >= -1e-12)


def test_interp_g64_q_and_g61_modes(tmp_path):
    m = load_linuxcnc_ini(_write_ini(tmp_path))
    f = tmp_path / "m.ngc"
    f.write_text("G21 G90 G64 P0.5\nG1 X1 F600\nG64 P0.5 Q0.1\nX2\nG61\nX3\nG61.1\nX4\n")
    moves, _ = read_moves(str(f), m)
    assert list(moves["blend_q"]) == [0.5, 0.1, 0.1, 0.1]
    assert list(moves["exact_stop"]) == [0, 0, 2, 1]


def test_naive_cam_merges_collinear_runs(tmp_path):
    m = load_linuxcnc_ini(_write_ini(tmp_path))
    f = tmp_path / "n.ngc"
    f.write_text("G21 G90 G64 P0.01\nG1 X1 Y0.001 F6000\nX2 Y0\nX3 Y0.001\nX4 Y0\nY10\nM2\n")
    run, *_ = _run(f, m)
    lines = list(run.queue["line"])
    assert 5 in lines and 2 not in lines and 3 not in lines     # the run X1..X4 is one segment tagged line 5


def test_ini_errors_name_file_line_and_key(tmp_path):
    p = tmp_path / "bad.ini"
    p.write_text("[TRAJ]\nMAX_LINEAR_VELOCITY = fast\n")
    with pytest.raises(ConfigError, match=r"bad.ini:2: \[TRAJ\]MAX_LINEAR_VELOCITY"):
        load_linuxcnc_ini(str(p))
    p.write_text("[TRAJ]\nLINEAR_UNITS = furlong\n")
    with pytest.raises(ConfigError, match=r"bad.ini:2: \[TRAJ\]LINEAR_UNITS"):
        load_linuxcnc_ini(str(p))
    p.write_text("[TRAJ]\nCOORDINATES = X Y Z\n[AXIS_X]\nMAX_VELOCITY = 10\n")
    with pytest.raises(ConfigError, match=r"AXIS_X\]MAX_ACCELERATION"):
        load_linuxcnc_ini(str(p))


def test_ini_inch_units_and_defaults(tmp_path):
    p = tmp_path / "in.ini"
    p.write_text("[TRAJ]\nLINEAR_UNITS = inch\nCOORDINATES = XYZ\n"
                 "[AXIS_X]\nMAX_VELOCITY = 1\nMAX_ACCELERATION = 10\n"
                 "[JOINT_1]\nMAX_VELOCITY = 2\nMAX_ACCELERATION = 20\n"
                 "[AXIS_Z]\nMAX_VELOCITY = 0.5\nMAX_ACCELERATION = 5\n")
    m = load_linuxcnc_ini(str(p))
    assert m.axes["x"].max_velocity == pytest.approx(25.4)
    assert m.axes["y"].max_accel == pytest.approx(508.0)      # from [JOINT_1]
    assert m.junction_policy == "linuxcnc" and m.flavor == "linuxcnc"
    assert m.linuxcnc.optimization_depth == 50 and m.linuxcnc.cycle == pytest.approx(0.001)


def _write_ini(tmp_path) -> str:
    p = tmp_path / "mill.ini"
    p.write_text("[EMCMOT]\nSERVO_PERIOD = 1000000\n[TRAJ]\nCOORDINATES = X Y Z\nLINEAR_UNITS = mm\n"
                 "MAX_LINEAR_VELOCITY = 100\n"
                 "[AXIS_X]\nMAX_VELOCITY = 100\nMAX_ACCELERATION = 1000\n"
                 "[AXIS_Y]\nMAX_VELOCITY = 100\nMAX_ACCELERATION = 1000\n"
                 "[AXIS_Z]\nMAX_VELOCITY = 20\nMAX_ACCELERATION = 500\n")
    return str(p)


@pytest.mark.slow
def test_stellabee_first20000_exact_path_total(tmp_path):
    """The G61 variant as the reference run made it: every G64 word replaced by G61, G61 on line 1."""
    import re

    with open(shared_path(*REF, "programs", "linuxcnc_stellabee1_first20000.ngc"), newline="") as fh:
        src = fh.read().split("\n")
    lines = [re.sub(r"G64(\s*P[-\d.]+)?(\s*Q[-\d.]+)?", "G61", s, flags=re.I) for s in src]
    if not re.search(r"G6[14]", lines[0], re.I):
        lines[0] = "G61 " + lines[0]
    f = tmp_path / "sb_g61.ngc"
    with open(f, "w", newline="") as fh:
        fh.write("\n".join(lines))
    run, *_ = _run(f)
    ref = _noidle("linuxcnc_stellabee1_first20000_g61_speedup8")
    assert abs(run.total_time - ref) <= 0.001 * ref
