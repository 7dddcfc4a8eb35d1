"""Review of the G-code front end: dialect cases worked by hand, and hostile input.

Each test pins a bug found in review (the wrong answer is named in the test's docstring). Every case runs
through both paths, the numba scanner and the pure-Python interpreter, and they must agree.
"""
from __future__ import annotations

import io
import random
from contextlib import redirect_stderr, redirect_stdout

import numpy as np
import pytest

from gcodeplan.schema import KIND_WAIT

from gcodeplan import cli
from gcodeplan.errors import GcodeError
from gcodeplan.gcode import read_moves
from gcodeplan.machine import Machine
from gcodeplan.schema import MOVE_DTYPE


def _same_rows(a: np.ndarray, b: np.ndarray) -> bool:
    if a.shape != b.shape:
        return False
    return all(np.array_equal(a[f], b[f], equal_nan=a[f].dtype.kind == "f") for f in MOVE_DTYPE.names)


def _write(tmp_path, text, name="t.gcode") -> str:
    p = tmp_path / name
    p.write_bytes(text if isinstance(text, bytes) else text.encode())
    return str(p)


def _parse(tmp_path, text, flavor="marlin", **machine_kw):
    """MOVE rows and reader; the scanner and the Python interpreter must give the same rows and summary."""
    path = _write(tmp_path, text)
    machine = Machine(flavor=flavor, **machine_kw)
    a, r = read_moves(path, machine)
    b, rb = read_moves(path, machine, force_python=True)
    assert _same_rows(a, b), "numba scanner and Python interpreter disagree"
    assert r.summary.to_json() == rb.summary.to_json()
    return a, r


def _err(tmp_path, text, flavor="marlin") -> GcodeError:
    path = _write(tmp_path, text)
    errors = []
    for force in (False, True):
        with pytest.raises(GcodeError) as ei:
            read_moves(path, Machine(flavor=flavor), force_python=force)
        errors.append(str(ei.value))
    assert errors[0] == errors[1], "the two paths report different errors"
    return ei.value


# ------------------------------------------------------------------ F on a line with an M code
def test_f_on_a_printer_m_code_line_is_a_parameter_not_the_feed(tmp_path):
    """Was: `M106 S255 F100` set the modal feed to 100 mm/min in the Python interpreter while the scanner
    ignored it (the paths disagreed, 10 vs 1.667 mm/s for the next move), and `M106 F-5` was an error in one
    path only. Marlin and Klipper read F only on moves: the feed stays F600 = 10 mm/s."""
    m, _ = _parse(tmp_path, "G1 X10 F600\nM106 S255 F100\nM104 S200 F-5\nG1 X20\n")
    assert list(m["feed_v"]) == [10.0, 10.0]


@pytest.mark.parametrize("flavor", ["linuxcnc", "grbl"])
def test_f_is_modal_on_any_cnc_line(tmp_path, flavor):
    """On CNC controls F is a modal word wherever it stands (`M3 S1000 F120` sets 120 mm/min = 2 mm/s). grbl
    rejects a line with an M code it does not have whole (gcode.c: error:20 before any word runs), so the F60
    beside M106 is not read there."""
    m, r = _parse(tmp_path, "G1 X1 F600\nM3 S1000 F120\nG1 X2\nM106 F60\nG1 X3\n", flavor)
    m = m[m["kind"] != KIND_WAIT]      # LinuxCNC's M3 also waits for the queue to empty (a wait row)
    assert list(m["feed_v"]) == ([10.0, 2.0, 1.0] if flavor == "linuxcnc" else [10.0, 2.0, 2.0])
    if flavor == "linuxcnc":
        e = _err(tmp_path, "G1 X1 F600\nM106 F-5\n", flavor)
        assert e.line == 2 and "feed rate" in str(e)
    else:
        assert any("t.gcode:4: M106: grbl rejects it (error:20" in w for w in r.summary.warnings)
        # a negative F is grbl's error:4: the line is rejected whole and the program goes on
        m2, r2 = _parse(tmp_path, "G1 X1 F600\nG1 X2 F-5\n", flavor)
        assert [float(x) for x in m2[m2["kind"] != KIND_WAIT]["x1"]] == [1.0]
        assert any("t.gcode:2: F-5: grbl rejects it (error:4, negative value)" in w for w in r2.summary.warnings)


# ------------------------------------------------------------------ E mode: G90/G91 against M82/M83
def test_marlin2_g90_after_m83_makes_e_absolute(tmp_path):
    """Marlin 2 (PR #15218): G90/G91 set every axis, E included, overriding an earlier M82/M83, and a later
    M82/M83 overrides them for E. Was: Klipper's rule everywhere (E relative while G91 or M83), so this
    program extruded 5 + 6 mm on Marlin instead of 5 + 1."""
    prog = "M83\nG90\nG1 X10 E5 F600\nG1 X20 E6\n"
    m, _ = _parse(tmp_path, prog, "marlin")
    assert list(m["e1"] - m["e0"]) == [5.0, 1.0]
    m, _ = _parse(tmp_path, prog, "klipper")         # Klipper: M83 stays in force after G90
    assert list(m["e1"] - m["e0"]) == [5.0, 6.0]


def test_marlin2_m82_after_g91_makes_e_absolute_with_xyz_relative(tmp_path):
    prog = "G91\nM82\nG1 X10 E5 F600\nG1 X10 E6\n"
    m, _ = _parse(tmp_path, prog, "marlin")
    assert list(m["x1"]) == [10.0, 20.0]              # XYZ relative
    assert list(m["e1"] - m["e0"]) == [5.0, 1.0]      # E absolute (M82 overrides G91 for E)
    m, _ = _parse(tmp_path, prog, "klipper")         # Klipper: E relative while G91 is in force
    assert list(m["e1"] - m["e0"]) == [5.0, 6.0]


def test_marlin2_g91_after_m82_makes_e_relative_and_g90_back(tmp_path):
    # the usual end G-code: G91, retract and lift, G90; then an absolute E move again
    prog = "M82\nG1 X10 E5 F600\nG91\nG1 E-2 Z1\nG90\nG1 X20 E7\n"
    m, _ = _parse(tmp_path, prog, "marlin")
    assert list(m["e1"] - m["e0"]) == [5.0, -2.0, 4.0]  # logical E 5 -> 3 -> 7


# ------------------------------------------------------------------ M203 units by flavor
def test_reprap_m203_is_in_mm_per_minute(tmp_path):
    """RepRapFirmware's M203 takes mm/min (config.g: `M203 X6000 Y6000 Z180 E1200`); Marlin's takes mm/s.
    Was: the RRF values were read as mm/s, a 60× too loose per-axis speed limit."""
    _, r = _parse(tmp_path, "M203 X6000 Y6000 Z180 E1200\nG1 X1 F600\n", "reprap")
    row = r.limits[-1]
    assert (row["axis_v_x"], row["axis_v_y"], row["axis_v_z"], row["axis_v_e"]) == (100.0, 100.0, 3.0, 20.0)
    _, r = _parse(tmp_path, "M203 X100 Z3\nG1 X1 F600\n", "marlin")
    assert (r.limits[-1]["axis_v_x"], r.limits[-1]["axis_v_z"]) == (100.0, 3.0)


# ------------------------------------------------------------------ G28 and G92
@pytest.mark.parametrize("flavor", ["marlin", "klipper"])
def test_g28_clears_the_g92_offset_of_the_homed_axes(tmp_path, flavor):
    """Marlin (set_axis_is_at_home: position_shift = 0) and Klipper (base_position = homing_position) drop
    the G92 offset of every axis they home. Was: kept, so `G1 X5` after `G92 X0` + `G28 X` went to
    machine X15 instead of X5."""
    m, _ = _parse(tmp_path, "G1 X10 Y10 F600\nG92 X0 Y0\nG28 X\nG1 X5 Y5\n", flavor)
    assert (m["x1"][-1], m["y1"][-1]) == (5.0, 15.0)   # X offset gone, Y offset (10) kept


def test_linuxcnc_g28_keeps_g92_offsets(tmp_path):
    m, _ = _parse(tmp_path, "G1 X10 F600\nG92 X0\nG28\nG1 X5\n", "linuxcnc")
    assert m["x1"][-1] == 15.0


# ------------------------------------------------------------------ Klipper extended commands
@pytest.mark.parametrize("line", ["SET_VELOCITY_LIMIT ACCEL 500", "SET_KINEMATIC_POSITION X0 Y0",
                                  "SET_VELOCITY_LIMIT VELOCITY=100 ACCEL"])
def test_malformed_klipper_parameters_are_errors_not_ignored(tmp_path, line):
    """Klipper refuses `NAME value` without '=' ("Malformed command"). Was: the parameters were silently
    dropped, so the limit or position change never happened."""
    e = _err(tmp_path, f"G1 X1 F600\n{line}\nG1 X2\n", "klipper")
    assert e.line == 2 and "malformed" in str(e)


def test_set_velocity_limit_accel_forms(tmp_path):
    _, r = _parse(tmp_path, "SET_VELOCITY_LIMIT ACCEL = 1000 ACCEL_TO_DECEL=800\nG1 X1\n", "klipper")
    assert r.limits[-1]["mcr"] == pytest.approx(0.2)       # 1 − 800/1000
    # Klipper uses MINIMUM_CRUISE_RATIO when both are given. Was: ACCEL_TO_DECEL won (0.2)
    _, r = _parse(tmp_path, "SET_VELOCITY_LIMIT ACCEL=1000 ACCEL_TO_DECEL=800 MINIMUM_CRUISE_RATIO=0.25\n"
                            "G1 X1\n", "klipper")
    assert r.limits[-1]["mcr"] == 0.25


def test_klipper_m220_m221_without_s_reset_to_100_percent(tmp_path):
    """Klipper's M220/M221 default S to 100; Marlin's without S change nothing. Was: unchanged on both."""
    prog = "M220 S50\nM221 S50\nG1 X10 E1 F600\nM220\nM221\nG1 X20 E2\n"
    m, _ = _parse(tmp_path, prog, "klipper")
    assert list(m["feed_v"]) == [5.0, 10.0] and list(m["e1"] - m["e0"]) == [0.5, 1.0]
    m, _ = _parse(tmp_path, prog, "marlin")
    assert list(m["feed_v"]) == [5.0, 5.0] and list(m["e1"] - m["e0"]) == [0.5, 0.5]


# ------------------------------------------------------------------ hostile input
def test_nul_byte_error_names_the_line(tmp_path):
    """Was: `file: not a text file (NUL bytes)` without the line, for a NUL in the first 64 KiB."""
    e = _err(tmp_path, "G1 X1 F600\nG1 X2\nG1 X\x003\nG1 X4\n")
    assert e.line == 3 and "NUL" in str(e)
    e = _err(tmp_path, b"\xef\xbb\xbfG1 X1\n\x00\x00\x00\n")    # after a BOM
    assert e.line == 2


HOSTILE = {
    "X1e300 (X1 E300)": "G1 X1e300 F600\n",
    "400-digit number": "G1 X" + "9" * 400 + " F600\n",
    "1 MB line": "G1 X1 ;" + "x" * (1 << 20) + "\nG1 X2\n",
    "NUL": "G1 X1 F600\nG1 X\x002\n",
    "unterminated (": "G1 X1 (oops\n",
    "X without number": "G1 X\n",
    "repeated word": "G1 X1 X2\n",
    "F-0": "G1 X1 F-0\n",
    "bad utf-8 in code": b"G1 X\xff2\n",
    "R arc impossible": "G1 X10\nG2 X0 Y0 R1\n",
}


# the hostile inputs that have a correct reading, and the clean program that reading is: accepting them is fine
# when the output is that program's
HOSTILE_MEANING = {"1 MB line": "G1 X1\nG1 X2\n"}


def _cli(cmd, path):
    err, out = io.StringIO(), io.StringIO()
    with redirect_stderr(err), redirect_stdout(out):
        rc = cli.main([cmd, path, "--flavor", "marlin"])
    return rc, out.getvalue(), err.getvalue()


@pytest.mark.parametrize("name", list(HOSTILE))
def test_hostile_input_exits_2_with_one_line(tmp_path, name):
    path = _write(tmp_path, HOSTILE[name])
    for cmd in ("parse", "estimate"):
        rc, out, err = _cli(cmd, path)
        if rc == 0:
            # accepted: only where the input has a meaning, and then the output is that meaning's
            assert name in HOSTILE_MEANING, (cmd, "accepted", out)
            (tmp_path / "clean").mkdir(exist_ok=True)
            clean = _write(tmp_path / "clean", HOSTILE_MEANING[name])
            rc2, out2, _ = _cli(cmd, clean)
            assert rc2 == 0 and out.replace(path, "FILE") == out2.replace(clean, "FILE"), cmd
            continue
        lines = err.strip().splitlines()
        assert rc == 2 and len(lines) == 1 and lines[0].startswith("gcodeplan: "), (cmd, err)


def test_hostile_text_without_newline_lowercase_and_no_spaces(tmp_path):
    m, _ = _parse(tmp_path, b"\xef\xbb\xbfg1x10y-2.5e.4f600\r\n;\xff\xfe\r\nG1\tX-.5")
    assert [(r["x1"], r["y1"], r["e1"]) for r in m] == [(10.0, -2.5, 0.4), (-0.5, -2.5, 0.4)]
    assert m["feed_v"][0] == 10.0 and list(m["line"]) == [1, 3]


# ------------------------------------------------------------------ both paths agree on random programs
_CMDS = ["G0", "G1", "G1", "G1", "g1", "G2", "G3", "G4", "G90", "G91", "G92", "G20", "G21", "M82", "M83",
         "M204", "M220", "M221", "M104", "M106", "M140", "G28", "M400", "G10", "G11", "T0", "M201", "M203",
         "M205", "G17", "G18", "G61", "G64", "G54", ""]


def _random_program(rnd: random.Random) -> str:
    def num():
        c = rnd.random()
        if c < 0.5:
            return f"{rnd.uniform(-50, 50):.{rnd.randint(0, 5)}f}"
        if c < 0.6:
            return rnd.choice(["0", "-0", ".5", "5.", "+3", "-.25", "1e3", "00012", "0.0000001"])
        return str(rnd.randint(-5, 200))

    lines = []
    for _ in range(rnd.randint(1, 25)):
        if rnd.random() < 0.06:
            lines.append(rnd.choice([";TYPE:Perimeter", ";LAYER_CHANGE", ";Z:0.4", ";LAYER:3", "(paren)",
                                     "SET_VELOCITY_LIMIT ACCEL=1000", "M117 hi 1.2", "N5 G1 X3", ""]))
            continue
        c = rnd.choice(_CMDS)
        words = [(L if rnd.random() < 0.8 else L.lower()) + rnd.choice(["", "", " "]) + num()
                 for L in rnd.sample("XYZEFSPTRIJ", rnd.randint(0, 4)) if c in ("G2", "G3") or L not in "IJ"]
        sep = rnd.choice([" ", "", "  "])
        lines.append(c + (sep if c else "") + sep.join(words) + (" ; c" if rnd.random() < 0.1 else ""))
    return "\n".join(lines) + ("\n" if rnd.random() < 0.8 else "")


def test_scanner_and_interpreter_agree_on_random_programs(tmp_path):
    """Random lines of every common command, every flavor: identical rows, summary, or the same error."""
    rnd = random.Random(20240611)
    path = str(tmp_path / "r.gcode")
    for _ in range(150):
        text = _random_program(rnd)
        with open(path, "w") as fh:
            fh.write(text)
        machine = Machine(flavor=rnd.choice(["marlin", "klipper", "reprap", "grbl", "linuxcnc"]),
                          retract_length=1.0, arc_tolerance=0.05)
        got = []
        for force in (False, True):
            try:
                a, r = read_moves(path, machine, force_python=force)
                got.append((a, r.summary.to_json()))
            except GcodeError as err:
                got.append(str(err))
        if isinstance(got[0], str) or isinstance(got[1], str):
            assert got[0] == got[1], text
        else:
            assert _same_rows(got[0][0], got[1][0]) and got[0][1] == got[1][1], text


# ------------------------------------------------------------------ arc P by flavor
def test_arc_p_counts_extra_circles_on_marlin_and_turns_on_linuxcnc(tmp_path):
    """Marlin's G2/G3 P (ARC_P_CIRCLES) adds P complete circles to the arc (P0 = none); LinuxCNC's P is the
    number of turns (P1 = none extra). Was: P read as turns everywhere, so Marlin's `P1` drew one circle
    instead of two and `P0` was an error."""
    arc = "G1 X10 Y0 F600\nG2 X10 Y0 I-10 J0 Z4 P{}\n"
    kw = dict(arc_tolerance=0.5)
    marlin_p1, _ = _parse(tmp_path, arc.format(1), "marlin", **kw)
    cnc_p2, _ = _parse(tmp_path, arc.format(2), "linuxcnc", **kw)
    marlin_p0, _ = _parse(tmp_path, arc.format(0), "marlin", **kw)
    cnc_p1, _ = _parse(tmp_path, arc.format(1), "linuxcnc", **kw)
    for a, b in ((marlin_p1, cnc_p2), (marlin_p0, cnc_p1)):
        assert np.array_equal(a[["x1", "y1", "z1"]][1:], b[["x1", "y1", "z1"]][1:])
    # two full circles (4π) of radius 10 rising 4 mm in n equal chords: each hypot(2·10·sin(2π/n), 4/n)
    chords = marlin_p1[1:]
    n = len(chords)
    assert n % 2 == 0 and np.allclose(chords["move_d"], np.hypot(20 * np.sin(2 * np.pi / n), 4 / n))
    assert chords["z1"][-1] == 4.0
    e = _err(tmp_path, arc.format(0), "linuxcnc")
    assert e.line == 2 and "P" in str(e)
