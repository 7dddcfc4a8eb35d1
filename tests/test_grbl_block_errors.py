"""grbl's block errors as grbl handles them (gcode/rs274.py ``_grbl_block_error``).

Truth: grbl 1.1h's gcode.c. gc_execute_line checks a whole line (step 2: each word; step 3: the block against
the modal state) before it executes any of it (step 4); on the first error it answers ``error:N``, the line
does nothing at all (no mode, offset, feed, spindle or position change) and a streaming sender sends the next
line. So the independent truth for each case is the same program with the rejected line blanked out (line
numbers kept): grbl runs the rest as if the line were absent. A few cases are also worked by hand. LinuxCNC
aborts the program on such lines: unchanged.
"""
from __future__ import annotations

import numpy as np
import pytest

import gcodeplan as gp
from conftest import same_rows
from test_grbl_rejects import grbl, read_both as rows_of, rejected_lines_blank   # shared with the other files
from gcodeplan.errors import GcodeError
from gcodeplan.gcode.reader import read_moves
from gcodeplan.machine import Machine
from gcodeplan.schema import KIND_DWELL, KIND_WAIT

HEAD = "G21 G90 G17 G94\nG0 X1 Y1\nG1 X2 F600\nM3 S1000\n"          # lines 1-4; the line under test is 5
TAIL = "X4 Y3\nG2 X6 Y3 R1\nG0 X0 Y0\nG1 X1 Y0\n"                    # after it: modal G1, an arc, G0, G1

# (line 5, grbl's error number, what the warning names); every line is valid elsewhere, so a wrong
# rejection or a missed one changes the rows
CASES = [
    ("M3 P1 S2000", 36, "word(s) P unused"),                       # M3 reads no P
    ("G0 X9 R5", 36, "word(s) R unused"),                          # a straight move reads no R
    ("G1 X9 F100 L2", 36, "word(s) L unused"),                     # L is G10's
    ("G17 I5", 36, "word(s) I unused"),                            # no motion on the line: I unused
    ("G2 X4 Y1 I1 R3", 36, "word(s) I unused"),                    # R-format arc: I J K unused
    ("G2 X12 Y1 R2", 34, "G2 R2 (shorter than half the chord)"),   # chord 10 mm > 2·R
    ("G2 X6 Y1 I3", 33, "G2 (the end point is not on the circle)"),    # centre (5, 1): r 3 ≠ 1
    ("G3 X2 Y1 R4", 33, "G3 (the end point is not on the circle)"),    # an R arc to its own start
    ("G2 Z5 I1", 32, "G2 without axis words in the G17 plane"),
    ("G2 X5 Y2", 35, "G2 without centre offsets in the G17 plane"),
    ("G20 G91 G2 F300", 26, "G2 without axis words"),             # G20 and G91 do not take effect either
    ("G55 G0 X3 G56", 21, "G56"),                                  # two coordinate systems
    ("G0 G1 X3", 24, "G1"),          # two motion codes: gcode.c meets the axis command conflict first
    ("M8 M9 X3", 21, "M8 M9"),                                     # grbl: M8 and M9 are one modal group
    ("M7 X3", 20, "M7"),             # default config.h: no ENABLE_M7, so gcode.c has no M7 at all
    ("M56 P1", 20, "M56"),           # nor M56 (ENABLE_PARKING_OVERRIDE_CONTROL off)
    ("G10 L2 P1 X5 G0 X1", 24, "G0"),                              # G10 and G0 both want the axis words
    ("G43.1 Z1 G1 X3", 24, "G1"),
    ("G1 X5 S-1", 4, "S-1"),
    ("G4 P-1", 4, "P-1"),
    ("G1 X5 X6", 25, "word X repeated"),
    ("G4", 28, "G4 without P"),
    ("G4 S2", 28, "G4 without P"),                                 # S is the spindle speed on grbl
    ("G10 L2 X5", None, None),                                     # valid: no P is P0, the system in use
    ("G10 X5", 28, "G10 without P and L"),
    ("G10 L2 P1", 26, "G10 without axis words"),
    ("G10 L2 P7 X5", 29, "G10 P7 (coordinate systems 1..6, 0: the one in use)"),
    ("G10 L20 P1 X5 R1", 36, "word(s) R unused"),
    ("G92", 26, "G92 without axis words"),
    ("G2 G53 X1 Y1 R5", 30, "G53 needs G0 or G1 in force"),
    ("G38.2 X2 Y1", 33, "G38.2 to where the probe is"),           # the probe already at the target
    ("G43.1 X1 Z1", 37, "G43.1 X Z (the tool length offset takes Z alone)"),
    ("T300", 38, "T300 (tools 0..255)"),
    ("G1 X5 F0", 22, "F0 (no feed rate in force)"),
    ("G1.5 X5", 23, "G1.5"),
    ("G59.1", 23, "G59.1"),
    ("G61.1 X5", 20, "G61.1"),
    ("G90.1 X5", 20, "G90.1"),
    ("G92 E0", 20, "word E"),                                      # E is no grbl word
    ("G28 E1", 20, "word E"),
]
TEXT = {4: "negative value", 20: "unsupported command", 21: "modal group violation", 22: "undefined feed rate",
        23: "command value not integer", 24: "axis command conflict", 25: "word repeated", 26: "no axis words",
        28: "value word missing", 29: "unsupported coordinate system", 30: "G53 invalid motion mode",
        32: "no axis words in plane", 33: "invalid target", 34: "arc radius error", 35: "no offsets in plane",
        36: "unused words", 37: "G43 dynamic axis error", 38: "max value exceeded"}


@pytest.mark.parametrize("line,error,what", CASES)
def test_a_rejected_line_runs_as_if_it_were_absent(tmp_path, line, error, what):
    got, s = rows_of(tmp_path, HEAD + line + "\n" + TAIL)
    blank, s_blank = rows_of(tmp_path, HEAD + "\n" + TAIL, name="q.nc")
    warning = f"p.nc:5: {what}: grbl rejects it (error:{error}, {TEXT.get(error)}); the line is skipped"
    if error is None:           # accepted: it must do something (here: the G54 origin moves)
        assert not same_rows(got, blank) and not any("grbl rejects" in w for w in s.warnings)
        return
    assert same_rows(got, blank), "the rejected line changed something"
    assert any(w.endswith(warning) for w in s.warnings), s.warnings


def test_the_grbl_model_times_a_program_with_rejected_lines_as_without_them():
    # the whole model (planner, segments, steps): the total equals the one of the program with those lines
    # blanked, and a rejected arc or feed change between two moves leaves their junction as it was
    bad = ["G21 G90 F1200", "G1 X10", "G1 Y10 F60 R2", "G2 X0 Y10 R1", "M3 P1 S500", "G1 X0 Y0", "G1 X9 X8",
           "G0 X20"]
    clean = [ln if i in (0, 1, 5, 7) else "" for i, ln in enumerate(bad)]
    got, want = gp.plan(bad, "grbl"), gp.plan(clean, "grbl")
    assert got.total_time_s == want.total_time_s > 0 and same_rows(got.moves, want.moves)
    assert (got.plan == want.plan).all()
    warnings = got.summary.warnings
    assert len(warnings) == 4 and all("grbl rejects it" in w for w in warnings)


def test_hand_worked_positions_and_modes_after_rejected_lines(tmp_path):
    # line 3 (G20 G91 with an arc that has no axis words, error:26) is rejected whole: line 4 is still
    # absolute millimetres at the F600 of line 2 (10 mm/s), in G1; line 5's G55 is refused with its G56
    # (error:21), so line 6 is still in G54 (origin 0); line 7's S-1 (error:4) leaves F600
    a, s = rows_of(tmp_path, "G21 G90\nG1 X1 F600\nG20 G91 G2 F300\nX2\nG55 G0 X3 G56\nX3\nG1 Y1 F60 S-1\n"
                             "Y2\n")
    keep = a[(a["kind"] != KIND_WAIT) & (a["kind"] != KIND_DWELL)]
    assert [(int(m["line"]), float(m["x1"]), float(m["y1"]), float(m["feed_v"])) for m in keep] == [
        (2, 1.0, 0.0, 10.0), (4, 2.0, 0.0, 10.0), (6, 3.0, 0.0, 10.0), (8, 3.0, 2.0, 10.0)]
    assert [w.split("(error:")[1][:2] for w in s.warnings] == ["26", "21", "4,"]


def test_g4_with_axis_words_dwells_then_moves(tmp_path):
    # gcode.c: G4 does not take the axis words (it is no axis command), so X2 moves in the modal motion
    # mode after the dwell; P is G4's: no unused word, no error
    a, s = rows_of(tmp_path, "G21 G90\nG1 X1 F600\nG4 P1.5 X2\n")
    line3 = a[a["line"] == 3]
    assert [int(k) for k in line3["kind"]] == [KIND_DWELL, 0] and float(line3["dwell_t"][0]) == 1.5
    assert float(line3["x1"][1]) == 2.0 and not s.warnings


def test_g4_with_s_dwells_p_seconds_and_s_is_the_spindle_speed(tmp_path):
    # grbl's G4 takes P in seconds; an S on the line is the spindle speed (gcode.c's single-meaning S)
    a, s = rows_of(tmp_path, "G21 G90\nG4 P0.5 S500\n")
    dwell = a[a["kind"] == KIND_DWELL]
    assert [float(t) for t in dwell["dwell_t"]] == [0.5] and s.spindle_commands == 1


def test_g10_without_p_sets_the_coordinate_system_in_use(tmp_path):
    # gcode.c reads an absent P as 0, the active system: G10 L2 X5 in G55 moves G55's origin; G54 stays 0
    a, s = rows_of(tmp_path, "G21 G90\nG55\nG10 L2 X5\nG0 X1\nG54 G0 X1\n")
    keep = a[a["kind"] != KIND_WAIT]
    assert [(int(m["line"]), float(m["x1"])) for m in keep] == [(4, 6.0), (5, 1.0)] and not s.warnings


@pytest.mark.parametrize("line,error", [("M3 P1 S2000", 36), ("G2 X12 Y1 R2", 34), ("G55 G0 X3 G56", 21),
                                        ("G92", 26), ("G10 L2 P7 X5", 29)])
def test_strict_makes_each_rejection_an_error_naming_file_line_and_error(tmp_path, line, error):
    path = tmp_path / "p.nc"
    path.write_text(HEAD + line + "\n" + TAIL)
    with pytest.raises(GcodeError, match=rf"p\.nc:5: .*grbl error:{error} \({TEXT[error]}\)"):
        read_moves(str(path), grbl(), strict=True)


@pytest.mark.parametrize("line,message", [
    ("G55 G0 X3 G56", "Two G codes used from same modal group"),
    ("G10 L2 P1 G0 X5", "Cannot use two G codes that both use axis values"),
    ("S-5", "Negative spindle speed used"),
    ("G92", "G92 needs at least one axis word"),
])
def test_linuxcnc_still_stops_at_the_same_line(tmp_path, line, message):
    lc = Machine(flavor="linuxcnc", max_velocity=100.0)
    path = tmp_path / "p.ngc"
    path.write_text(HEAD + line + "\n" + TAIL + "M2\n")
    with pytest.raises(GcodeError, match=rf"p\.ngc:5: .*{message}"):
        read_moves(str(path), lc)


def test_an_e_word_on_the_grbl_model_stays_an_error():
    # a printer's file is not for this machine: the grbl model refuses an E move by name (planner/grbl.py)
    with pytest.raises(GcodeError, match="grbl 1.1 has no E axis"):
        gp.plan(["G21 G90 F600", "G1 X10 E1"], "grbl")


def test_random_lines_rejected_by_grbl_change_nothing(tmp_path):
    """Property, on random lines of grbl's codes and words (and some it lacks): every line the reader rejects
    leaves the program as if it were blank (the program with those lines blanked gives the same rows), the
    numba scanner and the Python interpreter agree, and nothing raises but a GcodeError naming the line."""
    rng = np.random.default_rng(11)
    codes = ["G0", "G1", "G2", "G3", "G4", "G10", "G17", "G18", "G19", "G20", "G21", "G28", "G28.1", "G30",
             "G38.2", "G43.1", "G49", "G53", "G54", "G55", "G80", "G90", "G91", "G91.1", "G92", "G92.1", "G61",
             "M3", "M5", "M8", "M9", "M7", "M204", "M1.5", "G1.5", "M204 P1000"]
    values = ["0", "1", "-1", "2.5", "100", "-0.001", "7", "300", ".5", "99999999999", ""]
    letters = list("XYZIJKRPLFSTNQA")
    def program():
        lines = ["G21 G90 F600", "G0 X1 Y1"]
        for _ in range(8):
            toks = list(rng.choice(codes, rng.integers(0, 3))) + [
                f"{k}{rng.choice(values)}" for k in rng.choice(letters, rng.integers(0, 4))]
            rng.shuffle(toks)
            lines.append(" ".join(toks))
        return lines

    assert rejected_lines_blank(tmp_path, [program() for case in range(150)]) > 300


def test_a_feed_move_before_any_f_is_error_22(tmp_path):
    # grbl powers up with no feed rate (gc_state.feed_rate 0): G1 X5 before any F is rejected (error:22), so
    # is G1 X3 after F0 (grbl reads F0 as a feed: only a feed move needs it non-zero); G0 does not need one
    a, s = rows_of(tmp_path, "G21 G90\nG1 X5\nG0 X1 F0\nG1 X3\nG1 X4 F600\n")
    keep = a[(a["kind"] != KIND_WAIT) & (a["kind"] != KIND_DWELL)]
    assert [(int(m["line"]), float(m["x1"]), float(m["feed_v"])) for m in keep] == [
        (3, 1.0, float("inf")), (5, 4.0, 10.0)]
    assert [w.split("p.nc:")[1] for w in s.warnings] == [
        f"{n}: G1 without F (no feed rate in force): grbl rejects it (error:22, undefined feed rate); "
        "the line is skipped" for n in (2, 4)]
    # LinuxCNC keeps its own start (unchanged): the same first move runs
    lc, _ = rows_of(tmp_path, "G21 G90\nG1 X5\nM2\n", Machine(flavor="linuxcnc", max_velocity=100.0), "q.ngc")
    assert [float(x) for x in lc[lc["kind"] != KIND_WAIT]["x1"]] == [5.0]
