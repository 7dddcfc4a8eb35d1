"""RS274NGC semantics, second part: one parameter table, G10 L1/L2/L10/L11/L20, G43/G43.1/G43.2/G49, probe
moves (G38.n), spindle-synchronised motion (G33, G33.1) and the G76 threading cycle.

Truth: hand-worked one-line programs against LinuxCNC's G-code manual ("G10 L1" … "G76 Threading Cycle",
"Numbered Parameters") and its interpreter (interp_convert.cc convert_setup, convert_setup_tool,
convert_axis_offsets, convert_savehome, convert_home, convert_tool_length_offset, convert_probe,
convert_threading_cycle): parameters are stored in the machine's ("user") units, G92 writes #5210-5213,
G10 L2 writes #5201 + 20·P …, G28.1 the machine position into #5161-5163. Both interpreter paths (numba
scanner and Python) must give the same rows.
"""
from __future__ import annotations

import math

import pytest

from conftest import same_rows
from gcodeplan.config.linuxcnc import load_linuxcnc_ini
from gcodeplan.errors import GcodeError
from gcodeplan.gcode.cycles import THREAD_CUT, THREAD_CUT_FROM_INDEX, THREAD_RAPID, threading_passes
from gcodeplan.gcode.reader import read_moves
from gcodeplan.machine import Machine
from gcodeplan.schema import FLAG_RAPID, KIND_DWELL, KIND_WAIT

INI = ("[EMCMOT]\nSERVO_PERIOD = 1000000\n[TRAJ]\nCOORDINATES = X Y Z\nLINEAR_UNITS = {units}\n"
       "MAX_LINEAR_VELOCITY = 100\n"
       "[AXIS_X]\nMAX_VELOCITY = 100\nMAX_ACCELERATION = 1000\n"
       "[AXIS_Y]\nMAX_VELOCITY = 100\nMAX_ACCELERATION = 1000\n"
       "[AXIS_Z]\nMAX_VELOCITY = 20\nMAX_ACCELERATION = 500\n"
       "[RS274NGC]\nPARAMETER_FILE = mill.var\n[EMCIO]\nTOOL_TABLE = tool.tbl\n")


def mill(tmp_path, units="mm", var="", tools="T1 P1 Z0 ;zero\nT2 P2 Z10.5 ;long tool\n"):
    (tmp_path / "tool.tbl").write_text(tools)
    (tmp_path / "mill.var").write_text(var)
    p = tmp_path / "mill.ini"
    p.write_text(INI.format(units=units))
    return load_linuxcnc_ini(str(p))


def run(tmp_path, text, machine, name="p.ngc"):
    """(rows, reader) of a program; the scanner and the Python interpreter must agree."""
    path = tmp_path / name
    path.write_text(text)
    a, r = read_moves(str(path), machine)
    b, _ = read_moves(str(path), machine, force_python=True)
    assert same_rows(a, b), "numba scanner and Python interpreter disagree"
    return a, r


def ends(rows, line=None):
    """(x, y, z) of each motion row (of ``line``), rounded to 1e-9 mm."""
    keep = rows[(rows["kind"] != KIND_WAIT) & (rows["kind"] != KIND_DWELL)]
    if line is not None:
        keep = keep[keep["line"] == line]
    return [(round(float(m["x1"]), 9), round(float(m["y1"]), 9), round(float(m["z1"]), 9)) for m in keep]


def moving(rows, line):
    keep = rows[(rows["kind"] != KIND_WAIT) & (rows["kind"] != KIND_DWELL)]
    return keep[keep["line"] == line]


PRE = "G21 G90 G64 F600\nG0 X10 Y10 Z5\n"          # line 2: the start point


# ------------------------------------------------------------------ the parameter table
def test_g28_1_is_read_back_by_the_same_program(tmp_path):
    """G28.1 stores the machine position into #5161-5163; a later #5161 on the same program reads it; G28
    goes there."""
    a, _ = run(tmp_path, PRE + "G28.1\nG0 X50\nG1 X#5161 Y[#5162 + 1] Z#5163\nG0 X70\nG28\nM2\n",
               mill(tmp_path))
    assert ends(a, 5) == [(10.0, 11.0, 5.0)]
    assert ends(a, 7) == [(10.0, 10.0, 5.0)]


def test_g30_1_in_an_inch_machine_stores_user_units(tmp_path):
    """Parameters are in the machine's units (PROGRAM_TO_USER_LEN): on an inch machine a G21 program's G30.1
    at X 50.8 mm stores 2.0, which #5181 then reads as 2.0 (mm in that program); the .var's 1.0 is 1 inch."""
    m = mill(tmp_path, units="inch", var="5181 1.0\n5182 0\n5183 0\n")
    a, _ = run(tmp_path, "G21 G90 F600\nG0 X10 Y0 Z0\nG30\nG0 X50.8\nG30.1\nG1 X#5181\nM2\n", m)
    assert ends(a, 3) == [(25.4, 0.0, 0.0)]
    assert ends(a, 6) == [(2.0, 0.0, 0.0)]


def test_g92_and_g10_land_in_their_numbered_parameters(tmp_path):
    """G10 L2 P2 → #5241-5243; G92 → #5210 = 1 and #5211-5213 (the offsets); G92.1 zeroes them, G92.2 only
    the offsets in force, G92.3 restores the offsets from #5211-5213."""
    prog = (PRE + "G10 L2 P2 X1 Y2 Z3\n"                 # 3
            "G55 G0 X0 Y0 Z0\n"                          # 4: machine (1, 2, 3)
            "G1 X#5241 Y#5242 Z#5243\n"                  # 5: program (1, 2, 3) -> machine (2, 4, 6)
            "G92 X0 Y0 Z0\n"                             # 6: G92 offsets (1, 2, 3)
            "G0 X#5211 Y#5212 Z#5213\n"                  # 7: program (1, 2, 3) -> machine (3, 6, 9)
            "G92.2\n"                                    # 8: offsets off, #5211.. kept
            "G0 X#5211 Y#5210 Z0\n"                      # 9: program (1, 0, 0) -> machine (2, 2, 3)
            "G92.3\n"                                    # 10: offsets back from #5211..
            "G0 X0 Y0 Z0\n"                              # 11: machine (2, 4, 6)
            "G92.1\n"                                    # 12: all zero
            "G0 X[#5211 + 5] Y#5210 Z0\nM2\n")           # 13: program (5, 0, 0) -> machine (6, 2, 3)
    a, _ = run(tmp_path, prog, mill(tmp_path))
    assert [ends(a, k) for k in (4, 5, 7, 9, 11, 13)] == [
        [(1.0, 2.0, 3.0)], [(2.0, 4.0, 6.0)], [(3.0, 6.0, 9.0)], [(2.0, 2.0, 3.0)], [(2.0, 4.0, 6.0)],
        [(6.0, 2.0, 3.0)]]


def test_var_file_coordinate_system_and_g92_at_start(tmp_path):
    """LinuxCNC's start-up: #5220 = 2 selects G55 with its origin #5241.., #5210 = 1 applies #5211.. (in the
    machine's units: 0.5 inch = 12.7 mm on an inch machine)."""
    m = mill(tmp_path, units="inch", var="5220 2\n5241 1\n5242 0\n5243 0\n5210 1\n5211 0.5\n")
    a, _ = run(tmp_path, "G21 G90\nG0 X0 Y0 Z0\nG54 G0 X0\nM2\n", m)
    assert ends(a, 2) == [(pytest.approx(25.4 + 12.7), 0.0, 0.0)]
    assert ends(a, 3) == [(pytest.approx(12.7), 0.0, 0.0)]      # G54's origin is 0, G92 stays


def test_g10_l20_and_the_active_system(tmp_path):
    """G10 L20 P0 X0: the active system's origin makes the current X read 0 (machine 10 → origin 10); P2 of
    an inactive system is stored and takes effect when G55 is selected."""
    a, _ = run(tmp_path, PRE + "G10 L20 P0 X0\nG0 X5\nG10 L20 P2 Y1\nG55 G0 Y0\nM2\n", mill(tmp_path))
    assert ends(a, 4) == [(15.0, 10.0, 5.0)]
    assert ends(a, 6) == [(15.0, 9.0, 5.0)]      # G55 Y origin = 10 - 1; X origin of G55 = 0: X stays 15


def test_g10_l2_r_and_bad_p_are_errors(tmp_path):
    with pytest.raises(GcodeError, match="rotated coordinate system is not modelled"):
        run(tmp_path, PRE + "G10 L2 P1 R30\nM2\n", mill(tmp_path))
    with pytest.raises(GcodeError, match=r"p.ngc:3: G10 L2 P must be 0..9"):
        run(tmp_path, PRE + "G10 L2 P10 X0\nM2\n", mill(tmp_path))


# ------------------------------------------------------------------ tool table and tool length offsets
def test_g10_l1_l10_l11_and_g43_family(tmp_path):
    """Hand-worked: T2 (10.5 long) loaded; G10 L1 P2 Z4 changes the table, not the offset in force (G43
    must be issued again); G10 L10 P2 Z2 at machine Z 7 (no G92) makes the length 7 − 2 = 5; G43.2 Z1 adds 1;
    G43.2 H1 adds T1's length; G10 L11 P1 Z2 at machine Z 11 with a G59.3 Z origin of 3 gives T1 6; G49
    cancels."""
    prog = (PRE + "T2 M6 G43\n"                   # 3: offset 10.5
            "G0 Z0\n"                              # 4: machine 10.5
            "G10 L1 P2 Z4\n"                       # 5
            "G0 Z1\n"                              # 6: machine 11.5 (still 10.5)
            "G43\nG0 Z3\n"                         # 7, 8: machine 7
            "G10 L10 P2 Z2\nG43\nG0 Z2\n"          # 9-11: length 5: Z2 is machine 7 (no move)
            "G43.2 Z1\nG0 Z2\n"                    # 12: offset 6, its Z1 (modal G0) is machine 7: no move; 13: 8
            "G10 L2 P9 Z3\nG0 Z5\n"                # 14, 15: G59.3 Z origin 3; machine 11
            "G10 L11 P1 Z2\nG43.2 H1\nG0 Z0\n"     # 16-18: T1 = 11 - 3 - 2 = 6; offset 6 + 6 = 12
            "G49\nG0 Z0\nM2\n")                    # 19, 20: machine 0
    a, r = run(tmp_path, prog, mill(tmp_path))
    got = {k: ends(a, k) for k in (4, 6, 8, 11, 12, 13, 15, 18, 20)}
    assert got == {4: [(10.0, 10.0, 10.5)], 6: [(10.0, 10.0, 11.5)], 8: [(10.0, 10.0, 7.0)], 11: [],
                   12: [], 13: [(10.0, 10.0, 8.0)], 15: [(10.0, 10.0, 11.0)], 18: [(10.0, 10.0, 12.0)],
                   20: [(10.0, 10.0, 0.0)]}
    assert r.interp.tool_table == {1: 6.0, 2: 5.0}
    assert r.interp.waits["G43.2"] == 2 and r.interp.waits["G49"] == 1      # queue drains, as G43


def test_g43_2_axis_words_move_except_under_g80(tmp_path):
    """G43.2 Z1 in G0 mode: offset +1, then the modal G0 to Z1 (machine 2); under G80 only the offset."""
    a, _ = run(tmp_path, PRE + "G43.2 Z1\nG80\nG43.2 Z1\nG0 Z1\nM2\n", mill(tmp_path))
    assert ends(a, 3) == [(10.0, 10.0, 2.0)]
    assert ends(a, 5) == [] and ends(a, 6) == [(10.0, 10.0, 3.0)]      # offset 2


def test_g43_h0_is_the_loaded_tool(tmp_path):
    """On a nonrandom tool changer G43 H0 applies the tool in the spindle (LinuxCNC manual, G43 note)."""
    a, _ = run(tmp_path, PRE + "T2 M6\nG43 H0\nG0 Z0\nM2\n", mill(tmp_path))
    assert ends(a, 5) == [(10.0, 10.0, 10.5)]


def test_tool_parameters(tmp_path):
    """#5403: the loaded tool's stored length (user units), #5083: the offset in force."""
    a, _ = run(tmp_path, PRE + "T2 M6\nG43.1 Z1\nG1 X#5403 Y#5083 Z0\nM2\n", mill(tmp_path))
    assert ends(a, 5) == [(10.5, 1.0, 1.0)]


@pytest.mark.parametrize("line,match", [
    ("G43.2 H2 Z1", "G43.2: Can not have both H and axis words"),
    ("G43.2", "G43.2: No axes specified and H word missing"),
    ("G43.2 H7", "G43.2 H7: tool 7 is not in the tool table"),
    ("G43.1 X1", "tool offsets in X and Y are not modelled"),
    ("G10 L1 P7 Z1", "tool 7 is not in the tool table"),
    ("G10 L1 P0 Z1", "P must be a tool number > 0"),
    ("G10 L10 P1", "without offsets has no effect"),
    ("G10 L3 P1 Z1", "G10 L3 is not supported"),
])
def test_tool_offset_errors(tmp_path, line, match):
    with pytest.raises(GcodeError, match=match):
        run(tmp_path, PRE + line + "\nM2\n", mill(tmp_path))


# ------------------------------------------------------------------ probe
def test_probe_moves_run_to_their_target_from_rest_to_rest(tmp_path):
    """G38.2 Z-10 at F600 and a modal G38.3 continuation: each a feed move (10 mm/s, 5 mm/s after F300) to
    its target, the queue drained before and after it, an exact stop at its end; one named warning per
    file."""
    a, r = run(tmp_path, PRE + "G38.2 Z-10\nG38.3 Z-20 F300\nZ-30\nM2\n", mill(tmp_path))
    for line, z, v in ((3, -10.0, 10.0), (4, -20.0, 5.0), (5, -30.0, 5.0)):
        rows = a[a["line"] == line]
        assert list(rows["kind"]) == [KIND_WAIT, rows["kind"][1], KIND_WAIT]     # drain, move, drain
        mv = rows[1]
        assert (float(mv["z1"]), float(mv["feed_v"]), int(mv["exact_stop"])) == (z, v, 1)
        assert not mv["flags"] & FLAG_RAPID
    probe = [w for w in r.summary.warnings if "probe moves are timed to their target" in w]
    assert len(probe) == 1 and "Probe move finished without making contact" in probe[0]


def test_probe_errors(tmp_path):
    with pytest.raises(GcodeError, match="p.ngc:3: G38.2: start point too close to probe point"):
        run(tmp_path, PRE + "G38.2 Z5\nM2\n", mill(tmp_path))
    with pytest.raises(GcodeError, match="G38.4 needs at least one axis word"):
        run(tmp_path, PRE + "G38.4\nM2\n", mill(tmp_path))
    a, _ = run(tmp_path, PRE + "G38.3 Z5\nM2\n", mill(tmp_path))      # G38.3 may start at its target
    assert ends(a, 3) == []


def test_grbl_probe_and_its_errors(tmp_path):
    g = Machine(flavor="grbl", max_velocity=100.0)
    a, r = run(tmp_path, "G21 G90 G1 F600 X1\nG38.2 Z-5\nG10 L1 P1 Z3\nG43.1 Z2\nG0 Z0\nM2\n", g, "p.nc")
    assert ends(a, 2) == [(1.0, 0.0, -5.0)] and int(moving(a, 2)["exact_stop"][0]) == 1
    assert any("ALARM:5" in w for w in r.summary.warnings)
    assert any("G10 L1: grbl rejects it (error:20" in w for w in r.summary.warnings)
    assert ends(a, 5) == [(1.0, 0.0, 2.0)]                              # G43.1 Z2 in force
    _, r = run(tmp_path, "G0 X1\nG33 Z-5 K1\n", g, "q.nc")
    assert any("G33: grbl rejects it (error:20" in w for w in r.summary.warnings)


# ------------------------------------------------------------------ spindle-synchronised motion
def test_g33_moves_at_k_times_spindle_speed(tmp_path):
    """G33 Z-10 K1.5 at S600: 1.5 mm/rev × 10 rev/s = 15 mm/s, from rest to rest; in G20 K is inches/rev."""
    a, r = run(tmp_path, PRE + "M3 S600\nG33 Z-10 K1.5\nG20 G33 Z-1 K0.05\nM2\n", mill(tmp_path))
    mv = moving(a, 4)
    assert (ends(a, 4), float(mv["feed_v"][0]), int(mv["exact_stop"][0])) == ([(10.0, 10.0, -10.0)], 15.0, 1)
    assert float(moving(a, 5)["feed_v"][0]) == pytest.approx(0.05 * 25.4 * 10.0)
    assert r.interp.waits["G33"] == 2


def test_g33_is_held_to_the_axis_limit_by_the_planner(tmp_path):
    """K10 at S600 asks 100 mm/s of Z; Z's limit is 20 mm/s: the 100 mm move takes at least 5 s."""
    from gcodeplan.api import estimate

    path = tmp_path / "t.ngc"
    path.write_text("G21 G90\nG0 X0 Y0 Z0\nM3 S600\nG33 Z-100 K10\nM2\n")
    est = estimate(str(path), mill(tmp_path))
    assert est.time.total_time_s >= 100.0 / 20.0


@pytest.mark.parametrize("line,match", [
    ("G33 Z-10 K1", "G33: spindle not turning"),
    ("M3 S600 G33 Z-10", "G33: K word missing"),
    ("M3 S600 G33 Z-10 K1 F100", "F word used with a G33"),
    ("M3 S600 G33.1 Z-10", "G33.1: K word missing"),
    ("M3 S600 G33 K1", "G33 needs at least one axis word"),
])
def test_g33_errors(tmp_path, line, match):
    with pytest.raises(GcodeError, match=match):
        run(tmp_path, PRE + line + "\nM2\n", mill(tmp_path))


def test_g33_1_rigid_tap_in_and_out(tmp_path):
    """G33.1 Z-20 K1 I2 at S600: in at 10 mm/s, out to the start at 20 mm/s (I = 2); I0.5 counts as 1."""
    a, r = run(tmp_path, PRE + "M3 S600\nG33.1 Z-20 K1 I2\nG33.1 Z-20 K1 I0.5\nM2\n", mill(tmp_path))
    for line, back_v in ((4, 20.0), (5, 10.0)):
        mv = moving(a, line)
        assert ends(a, line) == [(10.0, 10.0, -20.0), (10.0, 10.0, 5.0)]
        assert list(mv["feed_v"]) == [10.0, back_v] and list(mv["exact_stop"]) == [1, 1]
    assert any("reversal overrun" in w for w in r.summary.warnings)


# ------------------------------------------------------------------ G76
def test_g76_passes_hand_worked(tmp_path):
    """G76 P1.5 Z-10 I-1 J0.2 K0.9 H1 from X10 Z5 (external thread, constant depth): depths 1.2, 1.4, 1.6,
    1.8 (1 + 0.2·pass while below 1.9), then 1.9 twice (H1); each pass: rapid back to X 10 − d + 1.9,
    rapid in to X 10 − d, the cut to Z-10 at 1.5 mm/rev × 10 rev/s = 15 mm/s from the spindle index, rapid
    out; the tool ends at X10 Z-10 (the last out move)."""
    a, r = run(tmp_path, "G21 G90 G18\nG0 X10 Y0 Z5\nM3 S600\nG76 P1.5 Z-10 I-1 J0.2 K0.9 H1\nM2\n",
               mill(tmp_path))
    want = []
    for d in (1.2, 1.4, 1.6, 1.8, 1.9, 1.9):
        want += [(10 - d + 1.9, 5.0), (10 - d, 5.0), (10 - d, -10.0), (10 - d + 1.9, -10.0)]
    mv = moving(a, 4)
    assert [(float(m["x1"]), float(m["z1"])) for m in mv] == [pytest.approx(w) for w in want]
    cuts = mv[~(mv["flags"] & FLAG_RAPID).astype(bool)]
    assert list(cuts["feed_v"]) == [15.0] * 6 and r.interp.waits["G76"] == 6


def test_g76_tapers_and_compound_angle():
    """L3 E1 Q29.5, K0.9: the taper cuts run at pitch · hypot(1, 0.9) / 1 per revolution; each pass is shifted
    along Z by (d − |I|)·tan 29.5°; the entry taper is the cut that waits for the index."""
    moves = threading_passes(10.0, 0.0, 5.0, -10.0, {"P": 1.5, "I": -1.0, "J": 0.3, "K": 0.9, "Q": 29.5,
                                                    "L": 3.0, "E": 1.0}, 1.0)
    t = math.tan(math.radians(29.5))
    first = moves[:6]
    zoff = 0.3 * t
    target_z = -10.0 + 0.9 * t
    ratio = math.hypot(1.0, 0.9)
    want = [(10.6, 5 - zoff, THREAD_RAPID, 1.0), (9.6, 5 - zoff, THREAD_CUT_FROM_INDEX, ratio),
            (8.7, 4 - zoff, THREAD_CUT, ratio), (8.7, target_z - zoff + 1, THREAD_CUT, 1.0),
            (9.6, target_z - zoff, THREAD_CUT, ratio), (10.6, target_z - zoff, THREAD_RAPID, 1.0)]
    for (x, _, z, kind, rr), (wx, wz, wk, wr) in zip(first, want):
        assert (x, z, kind, rr) == (pytest.approx(wx), pytest.approx(wz), wk, pytest.approx(wr))
    assert len(moves) == 3 * 6 + 1            # depths 1.3, 1.6, then 1.9; the final rapid


@pytest.mark.parametrize("line,match", [
    ("G17 G76 P1 Z-10 I-1 J0.2 K0.9", "ZX plane"),
    ("G76 Z-10 I-1 J0.2 K0.9", "P word missing"),
    ("G76 P1 Z-10 I-1 K0.9", "I J or K words missing"),
    ("G76 P1 Z-10 I0 J0.2 K0.9", "I must not be 0"),
    ("G76 P1 Z-10 I-1 J0.2 K0.1", "K must be greater than J"),
    ("G76 P1 X1 Z-10 I-1 J0.2 K0.9", "X and Y words are not allowed"),
])
def test_g76_errors(tmp_path, line, match):
    with pytest.raises(GcodeError, match=match):
        run(tmp_path, "G21 G90 G18\nG0 X10 Z5\nM3 S600\n" + line + "\nM2\n", mill(tmp_path))


def test_order_of_execution_with_g10(tmp_path):
    """Coordinate system (step 15) and tool length offset (step 14) act before G10 (step 19) on one line:
    `G10 L20 P0 X0 G55` sets G55's origin; `G10 L1 P2 Z4 G43` applies the old length 10.5."""
    a, _ = run(tmp_path, PRE + "G10 L20 P0 X0 G55\nG54 G0 X1\nG55 G0 X0\nT2 M6\nG10 L1 P2 Z4 G43\nG0 Z0\nM2\n",
               mill(tmp_path))
    assert ends(a, 4) == [(1.0, 10.0, 5.0)]       # G54 untouched (origin 0)
    assert ends(a, 5) == [(10.0, 10.0, 5.0)]      # G55 X origin 10
    assert ends(a, 8) == [(10.0, 10.0, 10.5)]


def test_negative_spindle_speed_is_each_dialects_error(tmp_path):
    with pytest.raises(GcodeError, match="Negative spindle speed used"):
        run(tmp_path, PRE + "S-5\nM2\n", mill(tmp_path))
    # grbl rejects the line (error:4) and goes on (tests/test_grbl_block_errors.py)
    _, r = run(tmp_path, "G0 X1\nS-5\n", Machine(flavor="grbl", max_velocity=100.0), "p.nc")
    assert any(w.endswith("p.nc:2: S-5: grbl rejects it (error:4, negative value); the line is skipped")
               for w in r.summary.warnings)


def test_grbl_coordinate_systems_and_stored_positions(tmp_path):
    """grbl: six coordinate systems (G10 L2 P7 is its error:29), G28.1 stores the machine position that G28
    returns to, G10 L20 as LinuxCNC's."""
    g = Machine(flavor="grbl", max_velocity=100.0)
    a, _ = run(tmp_path, "G21 G90\nG0 X5 Y6 Z7\nG28.1\nG10 L20 P1 X0\nG0 X1 Y0 Z0\nG28\n", g, "p.nc")
    assert ends(a, 5) == [(6.0, 0.0, 0.0)]
    assert ends(a, 6) == [(5.0, 6.0, 7.0)]
    _, r = run(tmp_path, "G10 L2 P7 X1\n", g, "q.nc")
    assert any("q.nc:1: G10 P7 (coordinate systems 1..6, 0: the one in use): grbl rejects it (error:29" in w
               for w in r.summary.warnings)
