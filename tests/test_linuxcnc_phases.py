"""PLAN rows of LinuxCNC plans tell the truth about their phases (issue 19): accelerating, cruising and
decelerating times and the accelerations reached, read off the servo-cycle trace; totals untouched."""
from __future__ import annotations

import numpy as np
import pytest

from gcodeplan import pipeline
from gcodeplan.config.linuxcnc import load_linuxcnc_ini
from gcodeplan.report.summary import TimeSummary
from gcodeplan.schema import KIND_DWELL


def _mill(tmp_path):
    p = tmp_path / "mill.ini"
    p.write_text("[EMCMOT]\nSERVO_PERIOD = 1000000\n[TRAJ]\nCOORDINATES = X Y Z\nLINEAR_UNITS = mm\n"
                 "MAX_LINEAR_VELOCITY = 100\n"
                 "[AXIS_X]\nMAX_VELOCITY = 100\nMAX_ACCELERATION = 1000\n"
                 "[AXIS_Y]\nMAX_VELOCITY = 100\nMAX_ACCELERATION = 1000\n"
                 "[AXIS_Z]\nMAX_VELOCITY = 20\nMAX_ACCELERATION = 500\n")
    return load_linuxcnc_ini(str(p))


def _plan(tmp_path, text):
    f = tmp_path / "p.ngc"
    f.write_text(text)
    keep = pipeline.Collect()
    pipeline.run(str(f), _mill(tmp_path), sinks=[keep])
    return keep.arrays()


def test_one_line_is_a_trapezoid_of_the_closed_form(tmp_path):
    """G61.1, 100 mm at F6000 (100 mm/s), a = 1000 mm/s²: 0.1 s up, 0.9 s at 100 mm/s, 0.1 s down
    (t = L/v + v/a = 1.1 s; LinuxCNC's trace in 1 ms cycles: within two cycles)."""
    moves, plan, _ = _plan(tmp_path, "G21 G90 G61.1\nG1 X100 F6000\nM2\n")
    row = plan[np.flatnonzero(moves["move_d"] > 0)[0]]
    assert row["duration"] == pytest.approx(1.1, abs=1e-9)
    assert row["accel_t"] == pytest.approx(0.1, abs=0.002)
    assert row["decel_t"] == pytest.approx(0.1, abs=0.002)
    assert row["cruise_t"] == pytest.approx(0.9, abs=0.004)
    assert row["accel_t"] + row["cruise_t"] + row["decel_t"] == pytest.approx(row["duration"], abs=1e-12)
    assert row["accel"] == pytest.approx(1000.0, rel=0.02)
    assert row["decel"] == pytest.approx(1000.0, rel=0.02)
    assert row["cruise_v"] == pytest.approx(100.0, rel=1e-6)
    s = TimeSummary()
    s.add(moves, plan)
    motion = s.accel_t + s.cruise_t + s.decel_t
    assert s.accel_t / motion == pytest.approx(0.1 / 1.1, abs=0.002)
    assert s.cruise_t / motion == pytest.approx(0.9 / 1.1, abs=0.004)


def test_short_segments_accelerate_as_the_segments_say(tmp_path):
    """Short G64 zig-zag segments never reach the feed: the rows' accelerations are what the plan's own
    pieces (SEGMENT rows: what plan.sample evaluates) reach in them, and most of the time is ramps."""
    pts = "".join(f"G1 X{2.0 * (k + 1):.1f} Y{(k % 2) * 0.5:.1f}\n" for k in range(40))
    moves, plan, segs = _plan(tmp_path, "G21 G90 G64\nG1 F6000\n" + pts + "M2\n")
    motion = (moves["kind"] <= 1) & (plan["duration"] > 0)
    a_seg = np.sqrt(segs["ax"] ** 2 + segs["ay"] ** 2 + segs["az"] ** 2)
    peak = float(np.max(a_seg))
    # the rows' accelerations never exceed the pieces' and the largest is theirs within 10 %
    top = max(float(plan["accel"].max()), float(plan["decel"].max()))
    assert top == pytest.approx(peak, rel=0.1)
    # a row with a piece accelerating at ≥ 100 mm/s² has a nonzero accel_t and accel (and so for decel)
    seg_row = segs["move"] - 0
    tan = (segs["vx"] * segs["ax"] + segs["vy"] * segs["ay"]) / np.maximum(np.hypot(segs["vx"], segs["vy"]), 1e-9)
    for rows, field in ((seg_row[(tan > 100) & (segs["dt"] >= 0.002)], "accel"),
                        (seg_row[(tan < -100) & (segs["dt"] >= 0.002)], "decel")):
        assert rows.size
        assert np.all(plan[field][rows] > 100), field
        assert np.all(plan[field + "_t"][rows] > 0), field
    s = plan["accel_t"] + plan["cruise_t"] + plan["decel_t"]
    np.testing.assert_allclose(s[motion], plan["duration"][motion], rtol=0, atol=1e-12)


def test_dwells_have_no_phases_and_totals_are_the_runs(tmp_path):
    moves, plan, _ = _plan(tmp_path, "G21 G90 G61\nG1 X10 F600\nG4 P0.5\nG1 X20\nM2\n")
    dw = moves["kind"] == KIND_DWELL
    assert dw.any()
    assert np.all(plan["accel_t"][dw] == 0) and np.all(plan["cruise_t"][dw] == 0) and np.all(plan["accel"][dw] == 0)
    assert plan["duration"][dw].sum() == pytest.approx(0.5, abs=1e-9)
