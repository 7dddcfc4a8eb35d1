"""grbl rejects a line it cannot run whole (gcode/rs274.py ``_grbl_check_block``).

Truth: grbl 1.1h's gcode.c. gc_execute_line parses and checks every word of a line (its steps 1-3) before it
executes any of it (step 4): a G or M code it does not have, or a word letter it does not read (A, B, C, D, H,
Q, U, V, W …), fails with error:20 (unsupported command), an M code with a fraction with error:23, and then
nothing of the line happens — no F, no S, no units, no modal motion change, no move. A sender shows
``error:20`` and sends the next line, which runs from the unchanged position and modes. The programs below
are worked by hand from that rule; LinuxCNC, which reads such lines differently, is unchanged.
"""
from __future__ import annotations

import pytest

from conftest import same_rows
from gcodeplan.errors import GcodeError
from gcodeplan.gcode.reader import read_moves
from gcodeplan.machine import Machine
from gcodeplan.schema import FLAG_RAPID, KIND_DWELL, KIND_WAIT


def grbl() -> Machine:
    return Machine(flavor="grbl", max_velocity=100.0)


def read_both(tmp_path, text, machine=None, name="p.nc", **kw):
    """(MOVE rows, summary) of ``text`` on a grbl machine; the numba scanner and the Python interpreter must agree."""
    path = tmp_path / name
    path.write_text(text)
    m = machine or grbl()
    a, r = read_moves(str(path), m, **kw)
    b, _ = read_moves(str(path), m, force_python=True, **kw)
    assert same_rows(a, b), "numba scanner and Python interpreter disagree"
    return a, r.summary


def rejected_lines_blank(tmp_path, programs) -> int:
    """For each program (a list of lines) on grbl: nothing raises but a GcodeError naming the line, and the program
    with the lines the reader rejects blanked gives the same rows (scanner and Python agreeing on both). Returns
    the number of rejected lines."""
    count = 0
    for lines in programs:
        try:
            got, s = read_both(tmp_path, "\n".join(lines) + "\n")
        except GcodeError as err:
            assert err.line is not None
            continue
        bad = {int(w.split("p.nc:")[1].split(":")[0]) for w in s.warnings if "grbl rejects it" in w}
        count += len(bad)
        blanked = "\n".join("" if i + 1 in bad else ln for i, ln in enumerate(lines)) + "\n"
        want, _ = read_both(tmp_path, blanked, name="q.nc")
        assert same_rows(got, want), lines
    return count


def run(tmp_path, text, machine=None, name="p.nc", **kw):
    """(moves as (line, x0, y0, x1, y1, z1, rapid, feed mm/s), summary); scanner and Python agree."""
    a, summary = read_both(tmp_path, text, machine, name, **kw)
    keep = a[(a["kind"] != KIND_WAIT) & (a["kind"] != KIND_DWELL)]
    out = [(int(m["line"]), round(float(m["x0"]), 9), round(float(m["y0"]), 9), round(float(m["x1"]), 9),
            round(float(m["y1"]), 9), round(float(m["z1"]), 9), bool(m["flags"] & FLAG_RAPID),
            round(float(m["feed_v"]), 9)) for m in keep]
    return out, summary


def rejected(summary, line, what, error=20):
    text = {20: "unsupported command", 23: "command value not integer"}[error]
    want = f"p.nc:{line}: {what}: grbl rejects it (error:{error}, {text}); the line is skipped"
    return any(w.endswith(want) for w in summary.warnings)


def test_an_unsupported_m_code_rejects_the_move_on_its_line(tmp_path):
    # line 3 is rejected whole: the X10 move does not happen, its F100 is not read; line 4 runs from X5 at
    # the F600 of line 2 (10 mm/s)
    got, s = run(tmp_path, "G21 G90\nG1 X5 F600\nG1 X10 F100 M204\nG1 Y5\n")
    assert got == [(2, 0, 0, 5, 0, 0, False, 10.0), (4, 5, 0, 5, 5, 0, False, 10.0)]
    assert rejected(s, 3, "M204")
    assert s.unknown_commands == {"M204": 1}


def test_an_m_code_with_a_fraction_is_error_23_and_rejects_the_line(tmp_path):
    got, s = run(tmp_path, "G21 G90\nG1 X5 F600\nG1 X10 M7.5\nG1 Y5\n")
    assert got == [(2, 0, 0, 5, 0, 0, False, 10.0), (4, 5, 0, 5, 5, 0, False, 10.0)]
    assert rejected(s, 3, "M7.5", error=23)


def test_modes_on_a_rejected_line_do_not_change(tmp_path):
    # G20 (inches) and G1 (feed motion) on the rejected line 3 do not take effect: line 4's X2 is 2 mm, in
    # the G0 still in force (rapid)
    got, s = run(tmp_path, "G21 G90 F600\nG0 X1\nG20 G1 X3 G64\nX2\n")
    assert [g[:7] for g in got] == [(2, 0, 0, 1, 0, 0, True), (4, 1, 0, 2, 0, 0, True)]
    assert rejected(s, 3, "G64")


@pytest.mark.parametrize("line,what", [("G1 X10 A5", "word A"), ("G1 X10 D1", "word D"),
                                       ("G1 X10 Q1", "word Q"), ("G81 X10 Z-1 R1", "G81"),
                                       ("G1 X10 M6", "M6"), ("G43 H1 X10", "G43 word H")])
def test_every_code_or_word_grbl_lacks_rejects_the_line(tmp_path, line, what):
    got, s = run(tmp_path, f"G21 G90\nG1 X5 F600\n{line}\nG1 Y5\n")
    assert [g[:5] for g in got] == [(2, 0, 0, 5, 0), (4, 5, 0, 5, 5)]
    assert rejected(s, 3, what)


def test_g10_with_an_l_grbl_lacks_sets_no_offset(tmp_path):
    # grbl's G10 takes L2 and L20 only, and L2 without R (gcode.c): G10 L1, G10 L2 R0 and G10 without L (read
    # as L0) are rejected, so the G0 X0 of line 5 is machine X0; the accepted G10 L2 P1 X5 of line 6 makes X0
    # machine X5
    got, s = run(tmp_path, "G21 G90 G54\nG10 L1 P1 Z3\nG10 L2 P1 X5 R0\nG10 P1 X7\nG0 X0\nG10 L2 P1 X5\nG0 X0\n")
    assert [g[3] for g in got] == [5.0]           # line 5 from machine 0 to 0: no move; line 7 to X5
    assert got[0][0] == 7
    assert rejected(s, 2, "G10 L1") and rejected(s, 3, "G10 L2 R") and rejected(s, 4, "G10 without L")


def test_spindle_and_coolant_on_a_rejected_line_do_nothing(tmp_path):
    # M3 S1000 on a line grbl rejects: no spindle command counted, no motion sync row for it
    _, s = run(tmp_path, "G21 G90 F600\nG1 X1\nM3 S1000 M204\nG1 X2\n")
    _, s_ok = run(tmp_path, "G21 G90 F600\nG1 X1\nM3 S1000\nG1 X2\n", name="q.nc")
    assert s.spindle_commands == 0 and s_ok.spindle_commands == 1


def test_strict_makes_the_rejection_an_error_naming_the_line(tmp_path):
    path = tmp_path / "p.nc"
    path.write_text("G21 G90\nG1 X5 F600\nG1 X10 M204\n")
    with pytest.raises(GcodeError, match=r"p\.nc:3: M204: grbl error:20"):
        read_moves(str(path), grbl(), strict=True)


def test_the_inert_lines_memo_replays_the_rejection_at_each_line(tmp_path):
    # the same text on lines 2 and 4: the second is a memo hit, its warning names its own line
    text = "G21 G90 F600\nM204 P1000\nG1 X1\nM204 P1000\nG1 X2\n"
    got, s = run(tmp_path, text)
    assert [g[0] for g in got] == [3, 5]
    assert rejected(s, 2, "M204") and rejected(s, 4, "M204")
    assert s.unknown_commands == {"M204": 2}


def test_linuxcnc_still_runs_the_rest_of_such_a_line(tmp_path):
    # LinuxCNC counts an unknown M code and executes the line's other words (its own semantics, unchanged)
    lc = Machine(flavor="linuxcnc", max_velocity=100.0)
    got, s = run(tmp_path, "G21 G90\nG1 X5 F600\nG1 X10 M204\nM2\n", lc, name="p.ngc")
    assert [g[3] for g in got] == [5.0, 10.0]
    assert not any("grbl" in w for w in s.warnings)
