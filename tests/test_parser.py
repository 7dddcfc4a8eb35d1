"""The G-code parser, command by command, against hand-worked expectations.

Every case runs twice, through the numba scanner and with every line forced through the Python
interpreter, and the two MOVE arrays must be identical (``_parse``).
"""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from gcodeplan import cli
from gcodeplan.errors import GcodeError
from gcodeplan.gcode import GcodeReader, read_moves
from gcodeplan.machine import Machine
from conftest import same_rows  # noqa: E402
from gcodeplan.schema import (FLAG_ARC, FLAG_CANNED, FLAG_FIRMWARE_RETRACT, FLAG_HOMING, FLAG_RAPID, FLAG_RETRACT,
                              KIND_DWELL, KIND_EXTRUDE_ONLY, KIND_PRINT, KIND_TRAVEL, KIND_WAIT, MOVE_DTYPE)


def _write(tmp_path, text, name="t.gcode"):
    p = tmp_path / name
    if isinstance(text, bytes):
        p.write_bytes(text)
    else:
        p.write_text(text)
    return str(p)


def _parse(tmp_path, text, machine=None, **kw):
    """Rows and reader; checks that the kernel and the pure-Python path agree."""
    path = _write(tmp_path, text)
    machine = machine or Machine(flavor="marlin")
    a, r = read_moves(path, machine, **kw)
    b, rb = read_moves(path, machine, force_python=True, **kw)
    assert same_rows(a, b), "numba scanner and Python interpreter disagree"
    assert r.summary.to_json() == rb.summary.to_json()
    assert r.layer_z == rb.layer_z or np.allclose(r.layer_z, rb.layer_z, equal_nan=True)
    return a, r


def _err(tmp_path, text, machine=None, **kw) -> GcodeError:
    path = _write(tmp_path, text)
    for force in (False, True):
        with pytest.raises(GcodeError) as ei:
            read_moves(path, machine or Machine(flavor="marlin"), force_python=force, **kw)
    return ei.value


# ------------------------------------------------------------------ G0/G1 basics
def test_g1_absolute_345_triangle_feed_and_kinds(tmp_path):
    m, r = _parse(tmp_path, "G90\nM82\nG1 X3 Y4 F1200\nG1 X6 Y8 E2\nG1 E1.5\nG1 X6 Y8\n")
    assert list(m["kind"]) == [KIND_TRAVEL, KIND_PRINT, KIND_EXTRUDE_ONLY]
    assert list(m["line"]) == [3, 4, 5]
    assert m["move_d"][0] == 5.0 and m["move_d"][1] == 5.0      # 3-4-5
    assert m["move_d"][2] == 0.5                                   # |dE| for extrude-only
    assert np.all(m["feed_v"] == 20.0)                             # F1200 mm/min
    assert m["flags"][2] & FLAG_RETRACT
    assert (m["x1"][1], m["y1"][1], m["e1"][1]) == (6.0, 8.0, 2.0)
    assert r.summary.moves == 3 and r.summary.lines == 6
    assert r.summary.travel_mm == 5.0 and r.summary.print_mm == 5.0
    assert r.summary.filament_mm == 1.5
    # naive time: 5/20 + 5/20 + 0.5/20
    assert r.summary.naive_time_s == pytest.approx(0.525)


def test_initial_feed_is_25_mm_s_and_zero_length_lines_only_set_state(tmp_path):
    m, r = _parse(tmp_path, "G1 X10\nG1 F600\nG1 X10\nG1 X20\n")
    assert m["feed_v"][0] == 25.0          # 1500 mm/min default
    assert len(m) == 2 and m["feed_v"][1] == 10.0


def test_compact_lowercase_and_leading_zero_words(tmp_path):
    m, _ = _parse(tmp_path, "G1X10Y-2.5E.4\ng0 x1.724638 y-1.012731\nG01 X2\nG00 Y0\n")
    assert (m["x1"][0], m["y1"][0], m["e1"][0]) == (10.0, -2.5, 0.4)
    assert (m["x1"][1], m["y1"][1]) == (1.724638, -1.012731)
    assert m["flags"][1] & FLAG_RAPID
    assert m["x1"][2] == 2.0 and m["y1"][3] == 0.0
    assert m["flags"][3] & FLAG_RAPID and not m["flags"][2] & FLAG_RAPID


def test_modal_bare_coordinates_continue_last_motion(tmp_path):
    # the reprap flavor repeats the modal G0/G1 (Marlin and Klipper do not: tests/test_printer_axis_lines.py)
    m, _ = _parse(tmp_path, "G0 X1\nX2 Y2\nG1 X3 F600\nY5\n", Machine(flavor="reprap"))
    assert [bool(f & FLAG_RAPID) for f in m["flags"]] == [True, True, False, False]
    assert m["y1"][3] == 5.0 and m["feed_v"][3] == 10.0


def test_relative_g91_and_m83_klipper_rule(tmp_path):
    # G91: XYZ and E relative. G90 after M83 keeps E relative (Klipper's rule).
    m, _ = _parse(tmp_path, "G91\nG1 X1 E1\nG1 X1 E1\nG90\nM83\nG1 X5 E1\nM82\nG1 X6 E4\n")
    assert list(m["x1"]) == [1.0, 2.0, 5.0, 6.0]
    assert list(m["e1"]) == [1.0, 2.0, 3.0, 4.0]


def test_g92_e0_resets_logical_e_not_machine_e(tmp_path):
    m, _ = _parse(tmp_path, "G1 X10 E5\nG92 E0\nG1 X20 E2\n")
    assert (m["e0"][1], m["e1"][1]) == (5.0, 7.0)     # running machine E, +2 commanded


def test_m221_flow_scales_e_and_m220_scales_feed(tmp_path):
    m, r = _parse(tmp_path, "M221 S50\nG1 X10 E4 F600\nM220 S200\nG1 X20 E8\n")
    assert m["e1"][0] - m["e0"][0] == 2.0
    assert m["e1"][1] - m["e0"][1] == 2.0
    assert m["feed_v"][0] == 10.0 and m["feed_v"][1] == 20.0
    assert r.summary.filament_mm == 4.0


def test_g20_inches_scale_coordinates_and_feed(tmp_path):
    # reprap: Marlin's default build has no G20 (no INCH_MODE_SUPPORT) and Klipper refuses it (test_printer_cnc_words)
    m, _ = _parse(tmp_path, "G20\nG1 X1 Y2 F60\nG21\nG1 X30\n", Machine(flavor="reprap"))
    assert (m["x1"][0], m["y1"][0]) == (25.4, 50.8)
    assert m["feed_v"][0] == pytest.approx(25.4)    # 60 in/min = 1 in/s
    assert m["x1"][1] == 30.0


def test_g0_is_rapid_inf_on_cnc_and_f_based_on_printers(tmp_path):
    cnc, r = _parse(tmp_path, "G0 X10\nG1 X20 F600\n", Machine(flavor="grbl", max_velocity=100.0))
    assert cnc["feed_v"][0] == math.inf and cnc["flags"][0] & FLAG_RAPID
    assert r.summary.naive_time_s == pytest.approx(10 / 100.0 + 10 / 10.0)   # rapid at max_velocity
    pr, _ = _parse(tmp_path, "G0 X10 F6000\n", Machine(flavor="marlin"))
    assert pr["feed_v"][0] == 100.0 and pr["flags"][0] & FLAG_RAPID


# ------------------------------------------------------------------ M204 by dialect
def test_m204_klipper_rule(tmp_path):
    text = "M204 P800\nG1 X1 E1\nM204 P900 T700\nG1 X2 E2\nM204 S1500\nG1 X3\nG1 E1\n"
    m, r = _parse(tmp_path, text, Machine(flavor="klipper", max_accel=3000.0))
    # P alone is ignored, min(P, T) when both, S sets; one accel for every kind of move
    assert list(m["accel"]) == [3000.0, 700.0, 1500.0, 1500.0]
    assert r.summary.ignored_commands["M204 without S or P+T"] == 1


def test_m204_marlin_print_travel_retract(tmp_path):
    text = "M204 P800 T1500 R400\nG1 X1 E1\nG1 X2\nG1 E0.5\nM204 S1000\nG1 X3 E2\nG1 X4\n"
    m, _ = _parse(tmp_path, text, Machine(flavor="marlin"))
    assert list(m["accel"]) == [800.0, 1500.0, 400.0, 1000.0, 1000.0]


def test_marlin_initial_accels_from_machine(tmp_path):
    m, _ = _parse(tmp_path, "G1 X1 E1\nG1 X2\nG1 E0\n",
                  Machine(flavor="marlin", max_accel=2000, accel_print=500, accel_travel=None, accel_retract=300))
    assert list(m["accel"]) == [500.0, 2000.0, 300.0]


# ------------------------------------------------------------------ dwell, waits
def test_g4_units_by_flavor(tmp_path):
    m, r = _parse(tmp_path, "G4 P500\nG4 S2\n", Machine(flavor="marlin"))
    assert list(m["kind"]) == [KIND_DWELL, KIND_DWELL] and list(m["dwell_t"]) == [0.5, 2.0]
    assert r.summary.dwell_s == 2.5 and r.summary.moves == 0
    m, _ = _parse(tmp_path, "G4 P0.5\n", Machine(flavor="grbl"))
    assert m["dwell_t"][0] == 0.5       # seconds on grbl/linuxcnc
    m, r = _parse(tmp_path, "G4 P0.5\nG4 S3\n", Machine(flavor="klipper"))
    assert list(m["dwell_t"]) == [0.0005, 0.0]   # Klipper: ms, and S is not supported
    assert r.summary.warning_count == 1


def test_waits_homing_tool_change(tmp_path):
    mach = Machine(flavor="marlin", heat_wait_time=30.0, homing_time=5.0)
    mach.axes["x"].home = -2.0
    text = "G1 X10 Y10\nM109 S215\nM190 S60\nG28 X\nM400\nT1\nM104 S200\nM106 S255\nM107\nM140 S0\n"
    m, r = _parse(tmp_path, text, mach)
    assert list(m["kind"]) == [KIND_TRAVEL] + [KIND_WAIT] * 5
    assert list(m["dwell_t"][1:]) == [30.0, 30.0, 5.0, 0.0, 0.0]
    assert m["flags"][3] & FLAG_HOMING
    assert (m["x0"][3], m["x1"][3], m["y1"][3]) == (10.0, -2.0, 10.0)   # only X homed
    assert r.summary.waits == {"M109": 1, "M190": 1, "G28": 1, "M400": 1, "tool_change": 1}
    assert r.summary.wait_s == 65.0 and r.summary.unknown_commands == {}
    assert r.summary.tool_changes == 1 and any("T1" in e for _, e in r.summary.events)


def test_set_kinematic_position_is_a_full_stop_without_motion(tmp_path):
    m, _ = _parse(tmp_path, "G1 X5\nSET_KINEMATIC_POSITION X=0 Y=0 Z=0\nG1 X1\n", Machine(flavor="klipper"))
    assert list(m["kind"]) == [KIND_TRAVEL, KIND_WAIT, KIND_TRAVEL]
    assert m["x0"][2] == 0.0 and m["move_d"][2] == 1.0


# ------------------------------------------------------------------ limits
def test_set_velocity_limit_rows_and_accel(tmp_path):
    text = ("G1 X1\nSET_VELOCITY_LIMIT VELOCITY=100 ACCEL=2000\nG1 X2\n"
            "SET_VELOCITY_LIMIT VELOCITY=100\nG1 X3\nSET_VELOCITY_LIMIT ACCEL_TO_DECEL=500 SQUARE_CORNER_VELOCITY=8\n"
            "G1 X4\n")
    m, r = _parse(tmp_path, text, Machine(flavor="klipper", max_velocity=300, max_accel=3000))
    assert list(m["limits"]) == [0, 1, 1, 2]             # a no-change line adds no row
    lim = r.limits
    assert len(lim) == 3 and lim["max_v"][0] == 300 and lim["max_v"][1] == 100 and lim["max_a"][1] == 2000
    assert lim["mcr"][2] == pytest.approx(1 - 500 / 2000) and lim["scv"][2] == 8
    assert m["accel"][1] == 2000.0


def test_m201_m203_m205_marlin_rows_klipper_ignored(tmp_path):
    text = "M203 X200 Y150 Z12 E120\nM201 X1000 E5000\nM205 X8 Y8 Z0.4 E4.5 J0.02 S1 T2\nG1 X1\n"
    m, r = _parse(tmp_path, text, Machine(flavor="marlin"))
    lim = r.limits[m["limits"][0]]
    assert (lim["axis_v_x"], lim["axis_v_y"], lim["axis_v_z"], lim["axis_v_e"]) == (200, 150, 12, 120)
    assert (lim["axis_a_x"], lim["axis_a_e"]) == (1000, 5000)
    assert (lim["jerk_x"], lim["jerk_z"], lim["junction_dev"], lim["min_feed_v"], lim["min_travel_v"]) == \
        (8, 0.4, 0.02, 1, 2)
    m, r = _parse(tmp_path, text, Machine(flavor="klipper"))
    assert len(r.limits) == 1 and r.summary.ignored_commands == {"M203": 1, "M201": 1, "M205": 1}


def test_g61_g64_blend_and_exact_stop(tmp_path):
    text = "G21\nG64 P0.05 Q0.01\nG1 X1\nG61\nG1 X2\nG64\nG1 X3\nG20\nG64 P0.001\nG1 X1\n"
    m, r = _parse(tmp_path, text, Machine(flavor="linuxcnc"))
    # LinuxCNC's G61 is exact *path* (2: tangent joins pass, corners stop), not exact stop (1)
    assert list(m["exact_stop"]) == [0, 2, 0, 0]
    assert m["blend_p"][0] == 0.05 and math.isnan(m["blend_p"][2]) and m["blend_p"][3] == pytest.approx(0.0254)
    # G64 Q is LinuxCNC's naive-CAM tolerance (used by the linuxcnc policy); P alone sets Q = P
    assert m["blend_q"][0] == 0.01 and m["blend_q"][3] == pytest.approx(0.0254)
    assert "G64 Q" not in r.summary.ignored_commands
    m2, r2 = _parse(tmp_path, "G64 P0.05 Q0.01\nG1 X1\n", Machine(flavor="reprap"))
    assert r2.summary.ignored_commands["G64 Q"] == 1
    # Marlin has no G64 (gcode.cpp): "Unknown command", nothing blends
    m3, r3 = _parse(tmp_path, "G64 P0.05 Q0.01\nG1 X1\n", Machine(flavor="marlin"))
    assert r3.summary.unknown_commands == {"G64": 1} and math.isnan(m3["blend_p"][0])


# ------------------------------------------------------------------ layers, features
def test_prusaslicer_layers_and_features(tmp_path):
    text = (";TYPE:Custom\nG1 X1 Y1 Z0.2 E1\n;LAYER_CHANGE\n;Z:0.2\n;HEIGHT:0.2\n;TYPE:External perimeter\n"
            "G1 X2 E2\n;TYPE:Solid infill\nG1 X3 E3\n;LAYER_CHANGE\n;Z:0.4\nG1 Z0.4\n;TYPE:External perimeter\n"
            "G1 X4 E4\n")
    m, r = _parse(tmp_path, text)
    assert r.features == ["custom", "external perimeter", "solid infill"]
    assert list(m["feature"]) == [0, 1, 2, 2, 1]
    assert list(m["layer"]) == [-1, 0, 0, 1, 1]     # the purge line comes before the first ;LAYER_CHANGE
    assert r.layer_z == [0.2, 0.4] and r.summary.layer_count == 2


def test_cura_layers_with_raft_and_layer_count(tmp_path):
    text = (";LAYER_COUNT:3\n;LAYER:-1\nG0 Z0.3\nG1 X1 E1\n;LAYER:0\nG0 Z0.5\n;TYPE:WALL-OUTER\nG1 X2 E2\n"
            ";LAYER:1\nG0 Z0.7\nG1 X3 E3\n")
    m, r = _parse(tmp_path, text)
    assert r.summary.layer_count == 3 and r.summary.header_layer_count == 3
    assert r.layer_z == [0.3, 0.5, 0.7]             # Z of each layer's first printing move
    assert r.features == ["wall-outer"]


def test_layers_by_z_when_no_layer_comments(tmp_path):
    text = "G1 Z0.2\nG1 X1 E1\nG1 X2 E2\nG1 Z0.4\nG1 X3\nG1 X4 E3\nG1 Z5\nG1 X0\nG1 Z0.6\nG1 X1 E4\n"
    m, r = _parse(tmp_path, text)
    assert r.layer_z == [0.2, 0.4, 0.6]          # travel at Z5 prints nothing: no layer
    assert list(m["layer"]) == [-1, 0, 0, 0, 0, 1, 1, 1, 1, 2]


def test_simplify3d_layers_and_features(tmp_path):
    text = "; layer 1, Z = 0.300\n; feature outer perimeter\nG1 X1 E1\n; layer 2, Z = 0.500\nG1 X2 E2\n"
    m, r = _parse(tmp_path, text)
    assert r.layer_z == [0.3, 0.5] and r.features == ["outer perimeter"]
    assert list(m["layer"]) == [0, 1] and list(m["feature"]) == [0, 0]


# ------------------------------------------------------------------ syntax
def test_comments_n_numbers_checksums_crlf_bom_tabs(tmp_path):
    def cs(s):
        x = 0
        for ch in s.encode():
            x ^= ch
        return f"{s}*{x}"

    text = ("\ufeffG1 X1 ; go\r\n(MSG, hello)\r\nG1 (inline) X2\r\nN10 G1 X3\r\n" + cs("N11 G1 X4") + "\r\n"
            "\tG1\tX5\r\n%\r\n\r\n")
    m, r = _parse(tmp_path, text.encode("utf-8"))
    assert list(m["x1"]) == [1.0, 2.0, 3.0, 4.0, 5.0]
    assert list(m["line"]) == [1, 3, 4, 5, 6]
    assert any("hello" in e for _, e in r.summary.events)
    e = _err(tmp_path, "N11 G1 X4*1\n")
    assert e.line == 1 and "checksum" in str(e)


@pytest.mark.parametrize("bad", ["G1 X1.2.3", "G1 X", "G1 Xabc", "G1 X--1", "G1 X nan", "G1 X1" + "0" * 400,
                                 "G1 X1 X2", "G1 X(1", "G1 F0", "G1 F-5", "M204 S0", "G1 X1 ) "])
def test_malformed_numbers_are_errors_with_file_and_line(tmp_path, bad):
    e = _err(tmp_path, "G1 X0\n" + bad + "\n")
    assert e.line == 2 and e.file.endswith("t.gcode")
    assert str(e).startswith(e.file + ":2: ")


def test_x1e999_reads_as_x_and_e_words(tmp_path):
    # G-code has no exponent notation: E is a word letter (G1X10E.4), so X1e999 is X1 E999
    m, _ = _parse(tmp_path, "G1 X1e999\n")
    assert m["x1"][0] == 1.0 and m["e1"][0] == 999.0


def test_placeholder_line_is_skipped_with_warning_or_error_when_strict(tmp_path):
    m, r = _parse(tmp_path, "G1 X1\nG1 X0 Y{machine_depth}\nG1 X2\n")
    assert list(m["x1"]) == [1.0, 2.0] and r.summary.skipped_lines == 1
    assert "2: unexpanded slicer placeholder '{machine_depth}': line skipped" in r.summary.warnings[0]
    e = _err(tmp_path, "G1 X1\nG1 X0 Y{machine_depth}\n", strict=True)
    assert e.line == 2


def test_unknown_commands_counted_or_strict_error(tmp_path):
    text = ("M117 Hello 1.2.3 world\nM117 Hello all\nM999\nPRINT_START BED=60\nEXCLUDE_OBJECT_START NAME=a\n"
            "G1 X1\nM999\n")
    m, r = _parse(tmp_path, text)
    assert r.summary.unknown_commands == {"M999": 2, "PRINT_START": 1}
    e = _err(tmp_path, text, strict=True)
    assert e.line == 3 and "M999" in str(e)


def test_g93_inverse_time_is_refused(tmp_path):
    e = _err(tmp_path, "G1 X1\nG93\n", Machine(flavor="linuxcnc"))
    assert e.line == 2 and "G93" in str(e)


def test_bad_files(tmp_path):
    with pytest.raises(GcodeError, match="no such file"):
        GcodeReader(str(tmp_path / "nope.gcode"), Machine())
    with pytest.raises(GcodeError, match="directory"):
        GcodeReader(str(tmp_path), Machine())
    e = _err(tmp_path, b"\x7fELF\x02\x01\x01\x00\x00\x00" * 50)
    assert "binary" in str(e) or "text" in str(e)
    m, r = _parse(tmp_path, b"")
    assert len(m) == 0 and r.summary.lines == 0 and r.summary.moves == 0


# ------------------------------------------------------------------ arcs
def test_g2_full_circle_chords_end_and_e_spread(tmp_path):
    m, r = _parse(tmp_path, "G1 X10 Y0 F600\nG2 X10 Y0 I-10 J0 E6.2832\n",
                  Machine(flavor="marlin", arc_tolerance=0.01))
    arc = m[1:]
    n = len(arc)
    # tolerance 0.01 mm on r = 10: chord angle ≤ 2·acos(1 − 0.01/10) → at least 2π / that chords
    assert n >= math.ceil(2 * math.pi / (2 * math.acos(1 - 0.01 / 10)))
    assert np.all(arc["flags"] & FLAG_ARC) and np.all(arc["line"] == 2)
    assert (arc["x1"][-1], arc["y1"][-1]) == (10.0, 0.0)
    assert np.allclose(np.hypot(arc["x1"], arc["y1"]), 10.0)
    assert arc["e1"][-1] == pytest.approx(6.2832)
    assert np.allclose(arc["e1"] - arc["e0"], 6.2832 / n)
    assert r.summary.arcs == 1 and r.summary.arc_chords == n
    assert arc["move_d"].sum() == pytest.approx(2 * math.pi * 10, rel=1e-3)
    assert np.all(arc["y1"][: n // 4] <= 1e-12)   # clockwise from (10, 0): y goes negative first


def test_modal_r_format_arcs_and_absolute_centre(tmp_path):
    # half circle by R, then a modal second half (no G word on the line)
    m, _ = _parse(tmp_path, "G21 G17\nG0 X0 Y0\nG3 X10 Y0 R5 F100\nX0 Y0 R5\n", Machine(flavor="linuxcnc"))
    assert np.all(m["flags"][1:] & FLAG_ARC)
    line3 = m[m["line"] == 3]
    assert line3["y1"].min() < -4.99                 # G3 from (0,0) to (10,0) with centre (5,0) goes below
    assert (m["x1"][-1], m["y1"][-1]) == (0.0, 0.0)
    m2, _ = _parse(tmp_path, "G90.1\nG0 X10 Y0\nG2 X0 Y10 I0 J0 F100\n", Machine(flavor="linuxcnc"))
    assert np.allclose(np.hypot(m2["x1"][1:], m2["y1"][1:]), 10.0)


def test_arc_error_names_the_line(tmp_path):
    e = _err(tmp_path, "G0 X0 Y0\nG2 X10 Y0 I1 J0\n", Machine(flavor="linuxcnc"))
    assert e.line == 2


# ------------------------------------------------------------------ offsets
def test_work_offsets_g10_g54_g55_g92_g53(tmp_path):
    text = ("G10 L2 P2 X100 Y50\nG55\nG0 X1 Y1\nG92 X0 Y0\nG0 X2\nG92.1\nG0 X4\nG53 G0 X7\n"
            "G10 L20 P1 X0\nG54\nG0 X1\n")
    m, _ = _parse(tmp_path, text, Machine(flavor="linuxcnc"))
    assert (m["x1"][0], m["y1"][0]) == (101.0, 51.0)   # G55 origin at (100, 50)
    assert m["x1"][1] == 103.0          # G92 made (101, 51) read (0, 0)
    assert m["x1"][2] == 104.0          # G92.1 cleared it
    assert m["x1"][3] == 7.0            # G53: machine coordinates for that line only
    assert m["x1"][4] == 8.0            # G10 L20 P1 X0 at machine 7: G54 origin at 7


def test_tool_length_offset(tmp_path):
    m, _ = _parse(tmp_path, "G43.1 Z2\nG0 Z10\nG49\nG0 Z10\n", Machine(flavor="linuxcnc"))
    m = m[m["kind"] != KIND_WAIT]       # LinuxCNC waits for its queue at G43.1 and G49
    assert list(m["z1"]) == [12.0, 10.0]


def test_g92_xyz_on_printer_and_bare_g92_by_flavor(tmp_path):
    m, _ = _parse(tmp_path, "G1 X10 E2\nG92 X0 E0\nG1 X5 E1\n")
    assert (m["x1"][1], m["e1"][1]) == (15.0, 3.0)
    m, _ = _parse(tmp_path, "G1 X10 E2\nG92\nG1 X5 E1\n", Machine(flavor="klipper"))
    assert (m["x1"][1], m["e1"][1]) == (15.0, 3.0)    # Klipper: bare G92 zeroes every axis
    m, _ = _parse(tmp_path, "G1 X10 E2\nG92\nG1 X5 E3\n", Machine(flavor="marlin"))
    assert (m["x1"][1], m["e1"][1]) == (5.0, 3.0)     # Marlin: nothing


def test_firmware_retraction_g10_g11(tmp_path):
    mach = Machine(flavor="marlin", retract_length=0.8, retract_speed=35, unretract_extra_length=0.1,
                   unretract_speed=20)
    m, _ = _parse(tmp_path, "G1 X1 E1\nG10\nG10\nG1 X5\nG11\n", mach)
    fw = m[(m["flags"] & FLAG_FIRMWARE_RETRACT) != 0]
    assert list(fw["kind"]) == [KIND_EXTRUDE_ONLY] * 2
    assert list(fw["move_d"]) == [0.8, pytest.approx(0.9)] and list(fw["feed_v"]) == [35.0, 20.0]
    assert fw["flags"][0] & FLAG_RETRACT and not fw["flags"][1] & FLAG_RETRACT
    assert m["e1"][-1] == pytest.approx(1.1)


# ------------------------------------------------------------------ canned cycles, program end
def test_g81_drill_cycle_modal_repeat_and_cancel(tmp_path):
    text = "G90 G0 X0 Y0 Z10\nG98 G81 X1 Y1 Z-2 R1 F60\nX2\nG80\nG0 X0\n"
    m, r = _parse(tmp_path, text, Machine(flavor="linuxcnc"))
    cyc = m[(m["flags"] & FLAG_CANNED) != 0]
    assert set(cyc["line"]) == {2, 3} and r.summary.canned_cycles == 2
    first = cyc[cyc["line"] == 2]
    # rapid XY at 10, rapid down to R=1, feed to -2, rapid back to the initial level 10 (G98)
    assert list(zip(first["x1"], first["y1"], first["z1"])) == [(1, 1, 10), (1, 1, 1), (1, 1, -2), (1, 1, 10)]
    assert [bool(f & FLAG_RAPID) for f in first["flags"]] == [True, True, False, True]
    assert first["feed_v"][2] == 1.0
    assert m["x1"][-1] == 0.0 and not m["flags"][-1] & FLAG_CANNED


def test_initial_modal_motion_by_flavor(tmp_path):
    m, _ = _parse(tmp_path, "X10\n", Machine(flavor="grbl"))
    assert m["flags"][0] & FLAG_RAPID and m["feed_v"][0] == math.inf      # grbl starts in G0
    m, _ = _parse(tmp_path, "X10\n", Machine(flavor="reprap"))      # Marlin, Klipper: no modal G1 at all
    assert not m["flags"][0] & FLAG_RAPID and m["feed_v"][0] == 25.0
    e = _err(tmp_path, "X10\n", Machine(flavor="linuxcnc"))
    assert e.line == 1 and "motion" in str(e)


def test_m2_ends_program_on_cnc_only(tmp_path):
    m, r = _parse(tmp_path, "G0 X1\nM2\nG0 X5\n", Machine(flavor="linuxcnc"))
    assert len(m) == 1 and r.summary.lines == 3
    m, r = _parse(tmp_path, "G0 X1\nM2\nG0 X5\n", Machine(flavor="klipper"))
    assert len(m) == 2 and r.summary.ignored_commands == {"M2": 1}


# ------------------------------------------------------------------ streaming
def test_batches_and_chunk_boundaries_do_not_change_the_result(tmp_path):
    lines = ["G90", "M83", ";TYPE:Infill", "; " + "x" * 5000]   # a line longer than a chunk
    lines += [f"G1 X{i % 97}.5 Y{i % 13} E0.01{i % 7}" for i in range(3000)]
    path = _write(tmp_path, "\n".join(lines))       # no final newline
    whole, r1 = read_moves(path, Machine())
    r2 = GcodeReader(path, Machine(), batch_moves=100, chunk_bytes=1000)
    parts = list(r2.batches())
    assert all(len(p) <= 100 for p in parts) and len(parts) == math.ceil(len(whole) / 100)
    assert same_rows(np.concatenate(parts), whole)
    assert r1.summary.to_json() == r2.summary.to_json() and r2.summary.lines == 3004


def test_slicer_estimates(tmp_path):
    _, r = _parse(tmp_path, "; estimated printing time (normal mode) = 1h 2m 3s\n"
                            "; estimated printing time (silent mode) = 1h 5m 3s\n")
    assert r.summary.slicer_estimate_s == 3723.0
    _, r = _parse(tmp_path, ";FLAVOR:Marlin\n;TIME:3231\n")
    assert r.summary.slicer_estimate_s == 3231.0
    _, r = _parse(tmp_path, "; estimated printing time (normal mode) = 2d 1h 0m 1s\n")
    assert r.summary.slicer_estimate_s == 2 * 86400 + 3600 + 1


# ------------------------------------------------------------------ the command
def test_parse_command_text_and_json(tmp_path, capsys):
    path = _write(tmp_path, ";TIME:100\nG1 X3 Y4 F600 E1\nG0 X0 Y0\nM999\n")
    assert cli.main(["parse", path, "--flavor", "marlin", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    for key in ("moves", "layer_count", "travel_mm", "print_mm", "filament_mm", "unknown_commands",
                "naive_time_s"):
        assert key in d
    assert d["moves"] == 2 and d["print_mm"] == 5.0 and d["travel_mm"] == 5.0 and d["filament_mm"] == 1.0
    assert d["unknown_commands"] == {"M999": 1} and d["slicer_estimate_s"] == 100
    assert d["naive_time_s"] == pytest.approx(5 / 10 + 5 / 10)
    assert cli.main(["parse", path, "--flavor", "marlin"]) == 0
    out = capsys.readouterr().out
    assert "moves" in out and "M999" in out


def test_parse_command_errors_exit_2(tmp_path, capsys):
    path = _write(tmp_path, "G1 X1\nG1 X1.2.3\n")
    assert cli.main(["parse", path, "--flavor", "marlin"]) == 2
    assert f"{path}:2:" in capsys.readouterr().err
    path = _write(tmp_path, "M999\n", "u.gcode")
    assert cli.main(["parse", path, "--flavor", "marlin", "--strict"]) == 2
    assert cli.main(["parse", str(tmp_path / "missing.gcode")]) == 2


def test_m30_ends_the_program_on_cnc_flavors_but_is_a_file_command_on_printers(tmp_path):
    text = "G21 G90\nG1 X1 F600\nM30\nG1 X5\n"
    mv, r = _parse(tmp_path, text, Machine(flavor="linuxcnc"))
    assert list(mv["x1"]) == [1.0] and (3, "M30 program end") in r.summary.events
    mv, r = _parse(tmp_path, text, Machine(flavor="marlin"))   # Marlin M30 = delete an SD file
    assert list(mv["x1"]) == [1.0, 5.0]
