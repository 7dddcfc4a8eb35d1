"""grbl's answers to lines it cannot read (gcode/grbl_line.py) and to ``$`` lines in a program.

Truth: grbl 1.1h's own source. protocol.c keeps a line in an 80-byte buffer after dropping blanks, control
characters, ``/`` and comments and upcasing letters: 79 bytes at most, a longer line is answered error:11 and not
parsed. gcode.c gc_execute_line (step 2) reads the kept bytes word by word: a word must start with a letter A-Z
(else error:1) followed by a number read_float accepts (sign, digits, one '.'; else error:2); each word is
checked as it is read (a code grbl lacks: error:20), so the first bad word in the line's order names the
error. A line number above MAX_LINE_NUMBER (10,000,000) is error:27. grbl's default config.h has neither
ENABLE_M7 nor ENABLE_PARKING_OVERRIDE_CONTROL: M7 and M56 are error:20. A rejected line does nothing at all, so
the independent truth is the same program with that line blank (line numbers kept), as in
tests/test_grbl_block_errors.py; ``$`` lines follow system.c system_execute_line.
"""
from __future__ import annotations

import pytest

from conftest import same_rows
from test_grbl_rejects import grbl, read_both as rows_of, rejected_lines_blank
from gcodeplan.errors import GcodeError
from gcodeplan.gcode.grbl_line import lex, protocol_line
from gcodeplan.gcode.reader import read_moves
from gcodeplan.schema import KIND_DWELL, KIND_WAIT

HEAD = "G21 G90 G17 G94\nG0 X1 Y1\nG1 X2 F600\nM3 S1000\n"          # lines 1-4; the line under test is 5
TAIL = "X4 Y3\nG2 X6 Y3 R1\nG0 X0 Y0\nG1 X1 Y0\n"
TEXT = {1: "expected command letter", 2: "bad number format", 3: "invalid statement", 11: "line overflow",
        16: "invalid jog command", 20: "unsupported command", 22: "undefined feed rate", 27: "invalid line number",
        36: "unused words"}
LONG_OK = "G1 X9." + "0" * 74                 # 79 bytes kept: fits grbl's buffer
LONG_BAD = "G1 X9." + "0" * 75                # 80 bytes kept: error:11

CASES = [
    ("G1 X", 2, "word X without a number in X"),
    ("G1 X-", 2, "word X without a number in X-"),
    ("G1 X.", 2, "word X without a number in X."),
    ("SET_VELOCITY_LIMIT ACCEL=500", 2, "word S without a number in SET_VELOCITY_LIMITACCEL=500"),
    ("G1 X1.2.3", 1, "'.3' (a word must start with a letter)"),    # read_float stops at the second '.'
    ("G1 X1.2.3 M204", 1, "'.3M204' (a word must start with a letter)"),   # grbl never reaches M204
    ("M204 X1.2.3", 20, "M204"),                                    # ... but here M204 comes first
    ("10 G1 X5", 1, "'10G1X5' (a word must start with a letter)"),
    ("G1 10", 20, "G110"),                                          # blanks dropped: G110, no such code
    ("G1 X5 -3", 1, "'-3' (a word must start with a letter)"),      # blanks dropped: X5 then "-3"
    ("G1 X5*71", 1, "'*71' (a word must start with a letter)"),     # a checksum is no grbl word
    ("O100 call", 20, "word O"),                                    # O is no grbl letter (not error:25)
    ("O100", 20, "word O"),
    ("M117 Hello", 20, "M117"),                                     # no free-text M codes on grbl
    ("M117", 20, "M117"),
    ("M7", 20, "M7"),
    ("N10000001 G1 X5", 27, "N10000001 (line numbers up to 10000000)"),
    ("N10000001", 27, "N10000001 (line numbers up to 10000000)"),
    (LONG_BAD, 11, "80 characters without blanks and comments (grbl's line buffer holds 79)"),
    ("$Q", 3, "$Q"),
    ("$J=G91 X5", 22, "$J= without F"),
    ("$J=G1 X5 F100", 16, "$J= G1"),                               # a jog takes G20/21, G90/91, G53 only
    ("$J=G91 X5 F100 S5", 36, "$J= word(s) S unused"),
    ("N10000000 G1 X9", None, None),                                # the largest line number grbl takes
    (LONG_OK, None, None),
    ("G1 X9 (" + "a comment that makes the line long, which grbl drops " * 2 + ")", None, None),
]


@pytest.mark.parametrize("line,error,what", CASES)
def test_a_line_grbl_cannot_read_runs_as_if_it_were_absent(tmp_path, line, error, what):
    got, s = rows_of(tmp_path, HEAD + line + "\n" + TAIL)
    blank, _ = rows_of(tmp_path, HEAD + "\n" + TAIL, name="q.nc")
    if error is None:           # accepted: a move to X9 happens on line 5
        five = got[got["line"] == 5]
        assert [float(x) for x in five["x1"]] == [9.0] and not any("grbl rejects" in w for w in s.warnings)
        return
    assert same_rows(got, blank), "the rejected line changed something"
    warning = f"p.nc:5: {what}: grbl rejects it (error:{error}, {TEXT[error]}); the line is skipped"
    assert [w.split("/")[-1] for w in s.warnings] == [warning]


def test_protocol_line_and_lex_by_hand():
    # blanks, "/", comments (to ')' or the end; ';' to the end) dropped, letters upcased
    assert protocol_line(b"g1 x1 (c;d) y2 / ; z3\r")[0] == b"G1X1Y2"
    assert protocol_line(b"(unclosed G1 X5")[0] == b""
    assert lex(b"G1X1020") == ([("G", "1"), ("X", "1020")], 0, "")
    assert lex(b"G1X+.5Y-2.") == ([("G", "1"), ("X", "+.5"), ("Y", "-2.")], 0, "")
    assert lex(b"G1X--5")[1:] == (2, "word X without a number in X--5")


def test_blanks_inside_a_number_join_it_with_a_warning(tmp_path):
    # grbl drops the blank: "X1 0" is X10 (elsewhere two words, or an error); the same rows as "G1 X10"
    got, s = rows_of(tmp_path, HEAD + "G1 X1 0\n" + TAIL)
    want, _ = rows_of(tmp_path, HEAD + "G1 X10\n" + TAIL, name="q.nc")
    assert same_rows(got, want)
    assert [w.split("/")[-1] for w in s.warnings] == ["p.nc:5: G1 X1 0: grbl drops blanks and reads G1 X10"]


def test_an_unclosed_comment_is_a_comment_to_the_end_of_the_line(tmp_path):
    got, s = rows_of(tmp_path, HEAD + "G1 X7 (no closing parenthesis\n" + TAIL)
    want, _ = rows_of(tmp_path, HEAD + "G1 X7\n" + TAIL, name="q.nc")
    assert same_rows(got, want) and not s.warnings


@pytest.mark.parametrize("line,error", [("G1 X1.2.3", 1), ("G1 X", 2), (LONG_BAD, 11), ("N10000001", 27),
                                        ("$Q", 3)])
def test_strict_makes_it_an_error_naming_file_line_and_error(tmp_path, line, error):
    path = tmp_path / "p.nc"
    path.write_text(HEAD + line + "\n" + TAIL)
    with pytest.raises(GcodeError, match=rf"p\.nc:5: .*grbl error:{error} \({TEXT[error]}\)"):
        read_moves(str(path), grbl(), strict=True)


def test_a_jog_moves_from_rest_to_rest_and_leaves_the_modes(tmp_path):
    # line 4 jogs +5 mm in X in G91 at F300 (5 mm/s) from (2, 0), after line 3's dwell left grbl idle; a second
    # jog (line 5) follows it (grbl jogs in its JOG state too); the G91 is the jogs' own: line 6's X1 is still
    # absolute (G90) in the modal G1 at F600 (10 mm/s), from the jogs' end (8, 0)
    a, s = rows_of(tmp_path, "G21 G90\nG1 X2 F600\nG4 P0\n$J=G91 X5 F300\n$J=G91 X1 F300\nX1\n")
    keep = [(int(r["line"]), int(r["kind"]), float(r["x1"]), float(r["feed_v"]), int(r["exact_stop"]))
            for r in a if r["kind"] != KIND_DWELL]
    assert keep == [(2, 0, 2.0, 10.0, 0), (4, KIND_WAIT, 2.0, 0.0, 0), (4, 0, 7.0, 5.0, 1),
                    (5, KIND_WAIT, 7.0, 0.0, 0), (5, 0, 8.0, 5.0, 1), (6, 0, 1.0, 10.0, 0)]
    assert s.waits == {"$J": 2}
    assert [w.split("/")[-1] for w in s.warnings] == [
        "p.nc:4: $J= jog: timed as a feed move from rest to rest (grbl starts a jog only when idle; its modes "
        "stay as they were)"]


def test_a_jog_while_the_program_moves_is_error_8(tmp_path):
    """system.c runs $J= only when grbl is idle or jogging: after a motion line (the buffer fed, the cycle
    running) it answers error:8 and nothing of the jog happens: the rows are those of the program without it."""
    got, s = rows_of(tmp_path, "G21 G90\nG1 X2 F600\n$J=G91 X5 F300\nX1\n")
    blank, _ = rows_of(tmp_path, "G21 G90\nG1 X2 F600\n\nX1\n", name="q.nc")
    assert same_rows(got, blank)
    assert any("p.nc:3" in w and "error:8" in w for w in s.warnings), s.warnings


def test_a_jog_in_inches_and_machine_coordinates(tmp_path):
    # G20 G53: X1 is machine X 25.4 mm, F10 is 10 in/min = 4.2333 mm/s; the G54 offset (G10 L2 X5) is not used
    a, _ = rows_of(tmp_path, "G21 G90\nG10 L2 P1 X5\n$J=G20 G53 X1 F10\nG0 X0\n")
    moves = [(int(r["line"]), float(r["x1"]), float(r["feed_v"])) for r in a if r["move_d"] > 0]
    assert moves == [(3, 25.4, 10 * 25.4 / 60), (4, 5.0, float("inf"))]


def test_a_timing_setting_in_the_file_applies_when_grbl_is_idle(tmp_path):
    """system.c stores a setting only when grbl is idle: after M3's sync (line 4) $110 applies from line 5 on (a
    new LIMITS row, tests/test_grbl_settings_lines.py times it); after a motion line it is error:8."""
    got, s = rows_of(tmp_path, HEAD + "$110=5000\n" + TAIL)
    blank, _ = rows_of(tmp_path, HEAD + "\n" + TAIL, name="q.nc")
    assert [int(r["limits"]) for r in got] == [0, 0, 0] + [1] * (len(got) - 3)
    got["limits"] = 0
    assert same_rows(got, blank)
    assert s.warnings == [] and s.unknown_commands == {}
    moving = HEAD.replace("M3 S1000\n", "G1 X3\n")
    got, s = rows_of(tmp_path, moving + "$110=5000\n" + TAIL)
    blank, _ = rows_of(tmp_path, moving + "\n" + TAIL, name="q.nc")
    assert same_rows(got, blank)
    assert [w.split("/")[-1] for w in s.warnings] == [
        "p.nc:5: $110=5000 while grbl moves (it stores a setting only when idle): grbl rejects it (error:8, not "
        "idle); the line is skipped"]
    path = tmp_path / "p.nc"
    with pytest.raises(GcodeError, match=r"p\.nc:5: \$110=5000 while grbl moves"):
        read_moves(str(path), grbl(), strict=True)


def test_other_dollar_lines(tmp_path):
    # a setting that does not change the time, reports and the unlock: ignored; homing: named, not timed
    got, s = rows_of(tmp_path, HEAD + "$22=1\n$$\n$X\n$H\n" + TAIL)
    blank, _ = rows_of(tmp_path, HEAD + "\n\n\n\n" + TAIL, name="q.nc")
    assert same_rows(got, blank)
    assert s.ignored_commands == {"$22": 1, "$$": 1, "$X": 1}
    assert s.unknown_commands == {"$H": 1}
    assert [w.split("/")[-1][:20] for w in s.warnings] == ["p.nc:8: $H: the homi"]


def test_random_text_is_read_as_grbl_reads_it(tmp_path):
    """Property, on random lines of word letters, digits, signs, dots, blanks and comment characters: the numba
    scanner and the Python interpreter agree, nothing raises but a GcodeError naming the line, and every line
    the reader rejects leaves the program as if it were blank."""
    import numpy as np

    rng = np.random.default_rng(5)
    alphabet = list("GGMXXYZFNIJRSP0123456789012345678901234567890.-+  (()*%;/$O")
    programs = [["G21 G90 F600", "G0 X1 Y1"] + ["".join(rng.choice(alphabet, int(rng.integers(1, 14)))).strip()
                                                or "G1 X2" for _ in range(6)] for case in range(120)]
    assert rejected_lines_blank(tmp_path, programs) > 300
