"""RS274NGC program language (gcode/ngc.py): expressions against hand values, O-word programs against their
hand-expanded equivalents (identical MOVE rows), errors naming file, line and O-word, and the Estlcam
2-Spool program (an O-word subroutine) against real LinuxCNC 2.9 (../shared/reference/linuxcnc2)."""
from __future__ import annotations

import csv
import gzip
import json
import math

import numpy as np
import pytest

from conftest import shared_path
from gcodeplan.config.linuxcnc import load_linuxcnc_ini
from gcodeplan.errors import GcodeError
from gcodeplan.gcode import ngc
from gcodeplan.gcode.ngc import NgcParams, evaluate, needs_expansion
from gcodeplan.gcode.reader import read_moves
from gcodeplan.machine import Machine
from gcodeplan.schema import KIND_WAIT, MOVE_DTYPE

REF2 = ("reference", "linuxcnc2")


def _mill() -> Machine:
    return Machine(name="mill", flavor="linuxcnc", max_velocity=100.0, max_accel=1000.0)


def _read(text: str, machine: Machine | None = None, name: str | None = None, tmp_path=None):
    """MOVE rows and reader of a program given as text (a file in tmp_path when given, else lines)."""
    m = machine or _mill()
    if tmp_path is not None:
        p = tmp_path / (name or "prog.ngc")
        p.write_text(text)
        return read_moves(str(p), m)
    return read_moves(text.splitlines(), m)


def _same_moves(a: np.ndarray, b: np.ndarray) -> None:
    """Every MOVE field but the line number identical (bit for bit)."""
    assert a.shape == b.shape, (a.shape, b.shape)
    for f in MOVE_DTYPE.names:
        if f == "line":
            continue
        assert np.array_equal(a[f], b[f], equal_nan=True), f


# ------------------------------------------------------------------ expressions (hand values)
@pytest.mark.parametrize("expr, value", [
    ("[2.0 / 3 * 1.5 - 5.5 / 11.0]", 0.5),                # LinuxCNC manual's example: left to right per level
    ("[9+8*7/6+5-4*3**2+1]", 9 + 8 * 7 / 6 + 5 - 4 * 9 + 1),
    ("[2 ** 3 ** 2]", 64.0),                               # ** is left-associative: (2**3)**2
    ("[-2 ** 2]", 4.0),                                    # the sign belongs to the number
    ("[- [2] ** 2]", 4.0),                                 # ... and to a bracketed value
    ("[1 + 2 EQ 3]", 1.0),                                 # + before EQ
    ("[3 - 1 GT 1]", 1.0),
    ("[0 OR 1 AND 0]", 0.0),                               # AND OR XOR: one level, left to right
    ("[1 AND 0 OR 1]", 1.0),
    ("[1 XOR 1]", 0.0), ("[0 XOR 2]", 1.0),
    ("[1 EQ 1.0000001]", 1.0),                             # EQ within 1e-6
    ("[1 NE 1.0000001]", 0.0),
    ("[1 LT 1.0000001]", 1.0),                             # LT / GT exact
    ("[1.0000005 LE 1]", 1.0), ("[1 GE 1.0000005]", 1.0),
    ("[1 GT 1]", 0.0),
    ("[-7 MOD 3]", 2.0),                                   # never negative
    ("[7 MOD -3]", 1.0),
    ("[7.5 MOD 2]", 1.5),
    ("ABS[-2.5]", 2.5),
    ("SIN[30]", math.sin(math.pi / 6)), ("COS[60]", math.cos(math.pi / 3)), ("TAN[45]", math.tan(math.pi / 4)),
    ("ASIN[0.5]", math.degrees(math.asin(0.5))), ("ACOS[0.5]", math.degrees(math.acos(0.5))),
    ("ATAN[1]/[-1]", 135.0), ("atan[-1]/[0]", -90.0),
    ("FIX[-2.8]", -3.0), ("FUP[-2.8]", -2.0), ("FIX[2.8]", 2.0), ("FUP[2.2]", 3.0),
    ("ROUND[2.5]", 3.0), ("ROUND[-2.5]", -3.0), ("ROUND[2.4999]", 2.0),
    ("EXP[0]", 1.0), ("LN[EXP[2]]", 2.0), ("SQRT[16]", 4.0),
    ("[1 + sqrt[9] * 2]", 7.0),
    ("[ 1 0 + 0 . 5 ]", 10.5),                             # blanks removed before reading (close_and_downcase)
])
def test_expression_values(expr, value):
    assert evaluate(expr) == pytest.approx(value, rel=0, abs=1e-12)


@pytest.mark.parametrize("expr, msg", [
    ("[1 / 0]", "divide by zero"), ("SQRT[-1]", "SQRT"), ("LN[0]", "LN"), ("ACOS[2]", "ACOS"),
    ("[-8 ** 0.5]", "non-integer power"), ("[1 + 2", "unclosed"), ("[1 FOO 2]", "unknown operation"),
    ("BAR[1]", "unknown function"), ("[#<nope>]", "#<nope> not defined"), ("[#6000]", "out of range"),
    ("ATAN[1]", "'/' missing"),
])
def test_expression_errors(expr, msg):
    with pytest.raises(ValueError, match=msg):
        evaluate(expr)


def test_parameters_indirection_and_exists():
    p = NgcParams()
    p.set(2, 7.0)
    p.set(7, 3.5)
    assert evaluate("##2", p) == 3.5                 # the parameter whose number is in #2
    assert evaluate("#[#2]", p) == 3.5
    assert evaluate("[#1+2]", p) == 2.0              # '#' before '+': #1 + 2, not #3
    assert evaluate("EXISTS[#<_foo>]", p) == 0.0
    p.set_named("_foo", 1.0)
    assert evaluate("EXISTS[#<_foo>]", p) == 1.0
    assert evaluate("#<_F o O>", p) == 1.0           # names lower-cased, blanks removed


def test_needs_expansion_only_for_the_language():
    assert not needs_expansion("G1 X1 Y2 F300")
    assert not needs_expansion("(HSS Twist Drill, 4.5mm [R])")     # brackets inside a comment
    assert not needs_expansion("O1000 (program number)")           # a bare O-word: program number
    assert needs_expansion("O100 sub")
    assert needs_expansion("n10 o<probe> call [1]")
    assert needs_expansion("G1 X#1")
    assert needs_expansion("G1 X[1+2]")
    assert needs_expansion("(debug, #1)")


# ------------------------------------------------------------------ line semantics
def test_reads_on_a_line_happen_before_its_assignments():
    """LinuxCNC manual: with #3 = 15, '#3=6 G1 X#3' moves to X15 and leaves #3 = 6."""
    mv, r = _read("G21 G90 F600\n#3 = 15\n#3=6 G1 X#3\nG1 Y#3\n#3=1 #3=2 (last wins)\nG1 Z#3\nM2")
    assert mv["x1"][0] == 15.0 and mv["y1"][1] == 6.0 and mv["z1"][2] == 2.0
    assert list(mv["line"]) == [3, 4, 6]


def test_plain_files_never_make_an_expander():
    mv, r = _read("G21 G90\n(HSS Twist Drill, 4.5mm [R])\nG1 X1 F600\nO1 (title)\nM2")
    assert r.interp.ngc is None
    assert mv["x1"][0] == 1.0


# ------------------------------------------------------------------ O-word programs vs hand-expanded ones
PROGRAMS = [
    # in-file subroutine with arguments, a local and a global named parameter, a return value
    ("""G21 G90 G64 F1200
o<side> sub
  #<len> = [#1 * 2]
  G91 G1 X#<len> Y#2
  #<_calls> = [#<_calls> + 1]
o<side> endsub [#<len> + 1]
#<_calls> = 0
o<side> call [5] [1]
G90 G1 X#<_value> Y#<_calls>
o<side> call [2.5]
G90 G1 Z#<_value>
M2""", """G21 G90 G64 F1200
G91 G1 X10 Y1
G90 G1 X11 Y1
G91 G1 X5 Y0
G90 G1 Z6
M2"""),
    # if / elseif / else, nested, inside a loop
    ("""G21 G90 F600
#1 = 0
o1 while [#1 LT 4]
  o2 if [#1 EQ 0]
    G1 X1
  o2 elseif [#1 EQ 1]
    G1 X2
    o3 if [1]
      G1 Y1
    o3 endif
  o2 elseif [#1 EQ 1]
    G1 X99
  o2 else
    G1 X[10 + #1]
  o2 endif
  #1 = [#1 + 1]
o1 endwhile
M2""", """G21 G90 F600
G1 X1
G1 X2
G1 Y1
G1 X12
G1 X13
M2"""),
    # do / while with break and continue, repeat, nested loops
    ("""G21 G90 F600
#1 = 0
o10 do
  #1 = [#1 + 1]
  o12 if [#1 EQ 4]
    o10 break
  o12 endif
  o11 if [#1 EQ 2]
    o10 continue
  o11 endif
  G1 X#1
o10 while [#1 LT 10]
o20 repeat [2]
  o21 repeat [3]
    G91 G1 Y1
  o21 endrepeat
  G90 G1 Z[#<_z> + 1]
o20 endrepeat
o30 repeat [0]
  G1 X99
o30 endrepeat
o31 repeat [0.5]
  G1 X98
o31 endrepeat
M2""", """G21 G90 F600
G1 X1
G1 X3
G91 G1 Y1
G91 G1 Y1
G91 G1 Y1
G90 G1 Z1
G91 G1 Y1
G91 G1 Y1
G91 G1 Y1
G90 G1 Z2
M2"""),
    # recursion, #1..#30 restored after a call, locals not visible to the caller, ##n indirection
    ("""G21 G90 F600
#1 = 7
#<n> = 1
#40 = 1
o100 sub
  o101 if [#1 GT 0]
    G1 X#1
    o100 call [#1 - 1]
  o101 endif
  #<n> = 99
o100 endsub
o100 call [##40]
G1 Y#1 Z#<n>
M2""", """G21 G90 F600
G1 X7
G1 X6
G1 X5
G1 X4
G1 X3
G1 X2
G1 X1
G1 Y7 Z1
M2"""),
]


@pytest.mark.parametrize("k", range(len(PROGRAMS)))
def test_o_word_programs_equal_their_expansion(k):
    prog, expanded = PROGRAMS[k]
    a, _ = _read(prog)
    b, _ = _read(expanded)
    _same_moves(a, b)


def test_rows_keep_the_source_lines():
    """A subroutine's lines give their own line numbers each time they run (as LinuxCNC's motion.program-line)."""
    prog = "G21 G90 F600\no1 sub\n  G91 G1 X1\n  G1 Y1\no1 endsub\no1 call\no1 call\nG90 G1 Z1\nM2"
    mv, _ = _read(prog)
    assert list(mv["line"]) == [3, 4, 3, 4, 8]


def test_position_parameters_ask_the_interpreter():
    """#5420-#5422 and #<_x> are the position in the active coordinate system, in program units."""
    prog = ("G21 G90 F600\nG10 L2 P1 X10\nG54\nG1 X5 Y2\nG1 X[#5420 + 1] Y[#<_y> * 2] Z#<_abs_x>\n"
            "G20\nG1 X[#5420 * 25.4]\nM2")
    mv, _ = _read(prog)
    assert mv["x1"][0] == 15.0
    assert (mv["x1"][1], mv["y1"][1], mv["z1"][1]) == (16.0, 4.0, 15.0)
    # in inch, #5420 is 6 mm / 25.4: the move back to it (times 25.4 in) is 6 in + 10 mm
    assert mv["x1"][2] == pytest.approx(6.0 * 25.4 + 10.0, abs=1e-9)


def test_debug_print_and_msg_are_events_and_m0_m1_m60_are_pauses():
    prog = ("G21 G90 F600\n#1 = 2.5\n#<_d> = 3\n(DEBUG, one #1 two %d#<_d> missing #<_none>)\n"
            "(print,at %.2f#1)\n(MSG,Suck out the chips)\nM0\nM1\nM60\nG1 X1\nM2")
    mv, r = _read(prog)
    events = dict(r.summary.events)
    assert events[4] == "DEBUG one 2.500000 two 3 missing ######"
    assert events[5] == "PRINT at 2.50"
    assert events[6] == "MSG Suck out the chips"
    assert r.summary.waits == {"M0": 1, "M1": 1, "M60": 1}
    assert int(np.sum(mv["kind"] == KIND_WAIT)) == 3


# ------------------------------------------------------------------ subroutine files
def test_subroutine_from_the_subroutine_path(tmp_path):
    libdir = tmp_path / "subs"
    libdir.mkdir()
    (libdir / "square.ngc").write_text("(a library file)\no<square> sub\n  G91 G1 X#1\n  G1 Y#1\n"
                                        "  G1 X-#1\n  G1 Y-#1\n  G90\no<square> endsub\nM2\n")
    ini = tmp_path / "m.ini"
    src = shared_path(*REF2, "config", "mill.ini").read_text()
    ini.write_text(src.replace("[RS274NGC]\n", "[RS274NGC]\nSUBROUTINE_PATH = subs\n"))
    m = load_linuxcnc_ini(str(ini))
    mv, _ = _read("G21 G90 F600\no<Square> call [4]\nG1 X1\nM2", m, tmp_path=tmp_path)
    ref, _ = _read("G21 G90 F600\nG91 G1 X4\nG1 Y4\nG1 X-4\nG1 Y-4\nG90\nG1 X1\nM2", m)
    _same_moves(mv, ref)
    assert list(mv["line"]) == [2, 2, 2, 2, 3]       # a library file's rows belong to the calling line


def test_call_before_a_definition_after_m2(tmp_path):
    """LinuxCNC seeks forward in the main file for a sub not yet defined (a definition after M2)."""
    mv, _ = _read("G21 G90 F600\no7 call [3]\nG1 Y1\nM2\no7 sub\n  G1 X#1\no7 endsub\n", tmp_path=tmp_path)
    assert list(mv["x1"]) == [3.0, 3.0] and list(mv["line"]) == [6, 3]


# ------------------------------------------------------------------ errors: file, line, O-word
@pytest.mark.parametrize("prog, line, words", [
    ("G21\no5 call\nM2", 2, ["o5 call", "unknown subroutine"]),
    ("G21\no5 endsub\nM2", 2, ["o5 endsub", "not inside a subroutine"]),
    ("G21\no5 endif\nM2", 2, ["o5 endif", "no matching 'if'"]),
    ("G21\no5 if [1]\no5 endwhile\nM2", 3, ["o5 endwhile", "no matching 'while'"]),
    ("G21\no5 sub\nG1 X1\n", 2, ["o5 sub", "no matching endsub"]),
    ("G21\no5 if [0]\nG1 X1\n", 2, ["o5 if", "no matching endif"]),
    ("G21\no5 while [1]\nG1 X1\n", 2, ["o5 while", "no matching endwhile"]),
    ("G21\no5 sub\no6 sub\no6 endsub\no5 endsub\nM2", 3, ["o6 sub", "nested subroutine"]),
    ("G21\no1 sub\no2 endsub\no1 endsub\no1 call\nM2", 3, ["o2 endsub", "does not match", "o1"]),
    ("G21\no<a> sub\nG1 X#<nothere>\no<a> endsub\no<a> call\nM2", 3, ["#<nothere> not defined",
                                                                       "subroutine o<a>"]),
    ("G21\no1 if [1]\no1 endif\no1 if [1]\no1 endif\nM2", 4, ["o1 if", "duplicate"]),
    ("G21\n#5420 = 1\nM2", 2, ["read-only"]),
    ("G21\n#5221 = 1\nM2", 2, ["not supported", "G10 L2"]),
    ("G21\nG1 X#<_spindle_on>\nM2", 2, ["not modelled"]),
    ("G21\no1 repeat [2]\no1 break\no1 endrepeat\nM2", 3, ["o1 break", "no matching while/do"]),
    ("G21\n(ABORT, tool #1 missing)\nM2", 2, ["(ABORT, tool 0.000000 missing)"]),
    ("G21\no1 if [1] G1 X1\no1 endif\nM2", 2, ["o1 if", "unexpected text"]),
    ("G21\no1 while [0]\no1 endwhile\no1 endwhile\nM2", 4, ["o1 endwhile", "outside its loop"]),
    ("G21\n(note) o1 if [1]\nM2", 2, ["O-word must start the line"]),
])
def test_errors_name_file_line_and_o_word(tmp_path, prog, line, words):
    with pytest.raises(GcodeError) as ei:
        _read(prog, tmp_path=tmp_path)
    err = ei.value
    assert err.file == str(tmp_path / "prog.ngc") and err.line == line, str(err)
    for w in words:
        assert w in str(err), str(err)


def test_runaway_loop_is_an_error_not_a_hang(monkeypatch):
    monkeypatch.setattr(ngc, "MAX_LOOP_ITERATIONS", 1000)
    with pytest.raises(GcodeError, match=r"o9 endwhile: loop from line 2 repeated more than 1000 times") as ei:
        _read("G21\no9 while [1]\n  G91 G1 X1 F600\no9 endwhile\nM2")
    assert ei.value.line == 4


def test_error_inside_a_subroutine_file_names_that_file(tmp_path):
    libdir = tmp_path / "subs"
    libdir.mkdir()
    (libdir / "bad.ngc").write_text("o<bad> sub\n  G1 X[1/0]\no<bad> endsub\n")
    ini = tmp_path / "m.ini"
    src = shared_path(*REF2, "config", "mill.ini").read_text()
    ini.write_text(src.replace("[RS274NGC]\n", "[RS274NGC]\nSUBROUTINE_PATH = subs\n"))
    m = load_linuxcnc_ini(str(ini))
    with pytest.raises(GcodeError) as ei:
        _read("G21\no<bad> call\nM2", m, tmp_path=tmp_path)
    assert ei.value.file == str(libdir / "bad.ngc") and ei.value.line == 2
    assert "divide by zero" in str(ei.value)


# ------------------------------------------------------------------ the Estlcam program against LinuxCNC 2.9
def test_estlcam_subroutine_program_matches_linuxcnc():
    """Refused before ('E needs a number'); now within 0.1 % of LinuxCNC's total and per-line end times within
    0.1 % of the total (the subroutine's lines: their last execution, as the reference CSV)."""
    import gcodeplan as gp

    prog = shared_path("gcode", "cnc2", "estlcam10_2-Spool.nc")
    m = load_linuxcnc_ini(str(shared_path(*REF2, "config", "mill.ini")))
    sink = gp.pipeline.LineTimes()
    gp.pipeline.run(str(prog), m, policy="linuxcnc", sinks=[sink])
    line, end = sink.arrays()
    stem = "estlcam10_2-Spool_g64"
    ref = json.loads(shared_path(*REF2, "times.json").read_text())[stem]["total_time_noidle_plus_dwell_s"]
    total = float(end.max())
    assert abs(total - ref) / ref < 0.001, (total, ref)
    with gzip.open(shared_path(*REF2, "per_line", stem + ".csv.gz"), "rt") as fh:
        rows = list(csv.DictReader(fh))
    ref_line = np.array([int(r["source_line"]) for r in rows])
    ref_end = np.array([float(r["end_time_noidle_s"]) for r in rows])
    idx = np.searchsorted(line, ref_line)
    assert np.all(line[np.minimum(idx, line.size - 1)] == ref_line)       # every motion line is there
    assert np.max(np.abs(end[idx] - ref_end)) / ref < 0.001


# ------------------------------------------------------------------ streaming: scanner, Python-only and push mode agree
LOOP_PROGRAM = """G21 G90 G64 F3000
G0 X1 Y1
#1 = 0
o1 while [#1 LT 200]
  G1 X[10 * COS[#1 * 3]] Y[10 * SIN[#1 * 3]] Z[-#1 / 200]
  #1 = [#1 + 1]
o1 endwhile
G0 Z5
G1 X2 Y2
M2
"""


def test_scanner_python_and_push_mode_give_the_same_rows():
    from gcodeplan.gcode.reader import GcodeReader

    a, ra = _read(LOOP_PROGRAM)
    b, _ = read_moves(LOOP_PROGRAM.splitlines(), _mill(), force_python=True)
    _same_moves(a, b)
    assert np.array_equal(a["line"], b["line"])
    r = GcodeReader(["G21"], _mill())
    data = LOOP_PROGRAM.encode()
    parts = []
    for k in range(0, len(data), 37):                 # pieces that cut lines anywhere
        parts += r.feed(data[k:k + 37])
    parts += r.end()
    c = np.concatenate(parts)
    _same_moves(a, c)
    assert np.array_equal(a["line"], c["line"])
    assert len(a) == 203 and list(a["line"][1:4]) == [5, 5, 5]


def test_memory_is_bounded_outside_loops():
    """Lines are kept only while a loop may jump back: after 5000 computed lines the buffer holds none."""
    prog = "G21 G90 F3000\n#1 = 0\n" + "#1 = [#1 + 1] G1 X#1\n" * 5000 + "M2\n"
    mv, r = _read(prog)
    assert len(mv) == 4999 and mv["x1"][-1] == 4999.0     # the first, to X0, has no length
    assert len(r.interp.ngc.main.lines) <= 1


# ------------------------------------------------------------------ Fanuc-style subprograms (M98 / M99)
def test_m98_m99_subprograms(tmp_path):
    """LinuxCNC's Fanuc-style subprograms: #1..#30 shared with the caller, L repeats, L0 skips."""
    prog = ("O0001 (main)\nG21 G90 F600\n#1 = 0\nM98 P100 L3\nM98 P100 L0\nG1 Y#1\nM98 P200\nM30\n"
            "O100\n#1 = [#1 + 1]\nG1 X#1\nM99\nO200 (second)\nG1 Z1\nM98 P100\nM99\n")
    mv, _ = _read(prog, tmp_path=tmp_path)
    ref, _ = _read("G21 G90 F600\nG1 X1\nG1 X2\nG1 X3\nG1 Y3\nG1 Z1\nG1 X4\nM30")
    _same_moves(mv, ref)
    assert list(mv["line"]) == [11, 11, 11, 6, 14, 11]


@pytest.mark.parametrize("prog, line, words", [
    ("G21\nM99\nM30", 2, ["M99 in the main program", "endless"]),
    ("G21\nM98 P7\nM30", 2, ["M98 P7", "no subprogram O7"]),
    ("G21\no7 sub\no7 endsub\nM98 P7\nM30", 4, ["M98 P7", "call it with o7 call"]),
    ("G21\no7 call\nM30\nO7\nM99\n", 2, ["o7 call", "call it with M98 P7"]),
    ("G21\nM98 P7 X1\nM30\nO7\nM99\n", 2, ["M98 takes P"]),
])
def test_m98_errors(tmp_path, prog, line, words):
    with pytest.raises(GcodeError) as ei:
        _read(prog, tmp_path=tmp_path)
    assert ei.value.line == line, str(ei.value)
    for w in words:
        assert w in str(ei.value), str(ei.value)


def test_modal_state_parameters():
    """#<_metric>, #<_absolute>, #<_coord_system>, #<_motion_mode>, #<_plane>, #5220/#5221 as LinuxCNC numbers them."""
    prog = ("G21 G90 G17 F600\nG10 L2 P2 X3\nG55\nG1 X1\n"
            "G1 X#<_metric> Y#<_absolute> Z[#<_coord_system> / 100]\n"
            "G1 X[#<_motion_mode> / 10] Y[#<_plane> / 10] Z#5220\n"
            "G91\nG1 X[#5241 - #<_incremental>] Y0 Z0\nG90 G18\nG1 X#<_plane> Y#<_imperial> Z#<_ijk_absolute_mode>\nM2")
    mv, _ = _read(prog)
    assert (mv["x1"][1] - 3, mv["y1"][1], mv["z1"][1]) == (1.0, 1.0, 5.5)
    assert (mv["x1"][2] - 3, mv["y1"][2], mv["z1"][2]) == (1.0, 17.0, 2.0)
    assert mv["x1"][3] - mv["x1"][2] == 2.0          # #5241 (G55 X) = 3, minus #<_incremental> = 1
    assert (mv["x1"][4] - 3, mv["y1"][4], mv["z1"][4]) == (180.0, 0.0, 0.0)


def test_random_arithmetic_matches_python():
    """+ - * / with LinuxCNC's precedence and left-to-right order equal Python's for the same text (an
    independent evaluator); 300 random expressions, nested brackets included."""
    rng = np.random.default_rng(20)

    def expr(depth):
        parts = []
        for k in range(int(rng.integers(1, 5))):
            if k:
                parts.append(str(rng.choice(["+", "-", "*", "/"])))
            if depth and rng.random() < 0.3:
                parts.append(expr(depth - 1))
            else:
                parts.append(f"{rng.uniform(0.5, 9):.3f}")
        return "[" + " ".join(parts) + "]"

    for _ in range(300):
        e = expr(3)
        assert evaluate(e) == eval(e.replace("[", "(").replace("]", ")")), e


def test_random_structured_programs_never_traceback(monkeypatch):
    """Random nests of if/elseif/else, while, do-while, repeat, break/continue (some misplaced), subs and calls:
    each program runs or stops with a GcodeError naming a line, never another exception."""
    import random

    monkeypatch.setattr(ngc, "MAX_LOOP_ITERATIONS", 30)
    rnd = random.Random(7)
    counter = [0]

    def block(depth):
        out = []
        for _ in range(rnd.randint(1, 4)):
            r = rnd.random()
            if depth and r < 0.5:
                counter[0] += 1
                k = counter[0]
                cond = rnd.choice(["[#1 LT 3]", "[#2 GT 1]", "[1]", "[0]", "[#1 MOD 2 EQ 0]"])
                body = block(depth - 1)
                if rnd.random() < 0.2:
                    body.append(f"o{rnd.choice([k, k - 1, 99])} {rnd.choice(['break', 'continue', 'endif', 'endwhile'])}")
                kind = rnd.choice(["if", "while", "repeat", "do"])
                if kind == "if":
                    out += [f"o{k} if {cond}"] + body + [f"o{k} elseif [#1 EQ 1]"] + block(depth - 1) + \
                        [f"o{k} else"] + block(depth - 1) + [f"o{k} endif"]
                elif kind == "while":
                    out += [f"o{k} while {cond}"] + body + ["#1 = [#1 + 1]", f"o{k} endwhile"]
                elif kind == "repeat":
                    out += [f"o{k} repeat [{rnd.randint(0, 3)}]"] + body + [f"o{k} endrepeat"]
                else:
                    out += [f"o{k} do"] + body + ["#2 = [#2 + 1]", f"o{k} while {cond}"]
            elif r < 0.6:
                out.append(f"o<s{rnd.randint(1, 3)}> call [#1] [2]")
            else:
                out.append(rnd.choice(["G1 X[#1 + 1] F600", "G1 Y#2", "#1 = [#1 + 1]", "#<l> = #1", "G1 Z#<l>",
                                       "(debug, #1 #<l>)", "M0"]))
        return out

    ran = failed = 0
    for _ in range(60):
        counter[0] = 0
        prog = ["G21 G90"]
        for k in (1, 2, 3):
            if rnd.random() < 0.7:
                counter[0] += 10
                prog += [f"o<s{k}> sub"] + block(1) + [f"o<s{k}> endsub"]
        prog += block(3) + ["M2"]
        try:
            read_moves(prog, _mill())
            ran += 1
        except GcodeError as err:
            assert err.line is not None
            failed += 1
    assert ran > 5 and failed > 5


def test_return_with_the_label_of_an_enclosing_if():
    """LinuxCNC's nc_files/retval.ngc: 'o1010 return [..]' inside 'o1010 if' returns from o1000, with its value."""
    prog = ("G21 G90 F600\no1000 sub\no1010 if [#1 GT 0]\no1010    return [123*[#1]]\no1010 endif\n"
            "o1020 if [#1 LT 0]\no1020    return\no1020 endif\no1000 endsub [4712]\n"
            "o1000 call [0]\nG1 X[#<_value> / 1000]\no1000 call [2]\nG1 X[#<_value> / 1000]\n"
            "o1000 call [-1]\nG1 Y[#<_value> + #<_value_returned> + 1]\nM2")
    mv, _ = _read(prog)
    assert list(mv["x1"]) == [4.712, 0.246, 0.246] and mv["y1"][2] == 1.0


def test_parameter_file_values(tmp_path):
    """[RS274NGC]PARAMETER_FILE is read (LinuxCNC's .var: 'number value' lines): #5161 is the stored G28 X."""
    (tmp_path / "mill.var").write_text("5161\t12.5\n5162 -3\nnot a line\n5220 1.0\n")
    ini = tmp_path / "m.ini"
    ini.write_text(shared_path(*REF2, "config", "mill.ini").read_text())     # PARAMETER_FILE = mill.var
    m = load_linuxcnc_ini(str(ini))
    mv, _ = _read("G21 G90 F600\nG1 X#5161 Y#5162\nM2", m)
    assert (mv["x1"][0], mv["y1"][0]) == (12.5, -3.0)
    assert NgcParams().load_var(str(tmp_path / "mill.var")).get(5161) == 12.5
