"""The named parts of the byte scanner (gcode/scan.py), each on hand-worked lines.

The parts are inline="always" numba functions: called from Python they run as ordinary compiled functions,
so each can be checked alone. ``ok`` False means "this line goes to the Python interpreter" and the state
must then be untouched.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from gcodeplan.gcode import scan as S
from gcodeplan.schema import FLAG_RAPID, FLAG_RETRACT, KIND_DWELL, KIND_EXTRUDE_ONLY, KIND_PRINT, KIND_TRAVEL, \
    MOVE_DTYPE

G, M = ord("g"), ord("m")


def _buf(text: bytes) -> np.ndarray:
    return np.frombuffer(text, dtype=np.uint8)


def _state(dialect=S.DIALECT_KLIPPER, f32=0):
    """Modal state at power-on of a printer: G90, M82, mm, 100 % speed and flow, accels 1000 mm/s²."""
    st = np.zeros(S.N_ST)
    st[S.S_UNIT] = st[S.S_SPEED_F] = st[S.S_FLOW_F] = 1.0
    st[S.S_ACC_P] = st[S.S_ACC_T] = st[S.S_ACC_R] = 1000.0
    st[S.S_FEED] = 25.0
    st[S.S_BLEND_P] = math.nan
    ist = np.zeros(S.N_IST, dtype=np.int64)
    ist[S.I_DIALECT] = dialect
    ist[S.I_ABS_COORD] = ist[S.I_ABS_E] = 1
    ist[S.I_MOTION] = 1
    ist[S.I_F32_REL] = f32
    return st, ist


# ------------------------------------------------------------------ numbers
@pytest.mark.parametrize("text, value, after", [
    (b"-.5 ", -0.5, 3),
    (b"+1.25\n", 1.25, 5),
    (b"  12.", 12.0, 5),                  # blanks before the number are skipped; "12." is 12
    (b"0.1Y", 0.1, 3),                    # the next word's letter ends the number
    (b"1e3", 1.0, 1),                     # no exponent in G-code: "1" then the word E3 (see scan_words)
    (b"123456789012345;", 123456789012345.0, 15),   # 15 digits: still exact
])
def test_parse_decimal_takes(text, value, after):
    ok, v, p = S.parse_decimal(_buf(text), 0, len(text))
    assert ok and p == after
    assert v == value          # bit for bit: one rounding, as float() of the same text
    assert v == float(text[:after])


@pytest.mark.parametrize("text", [b"1.2.3", b"-", b".", b"1234567890123456", b"1/2", b"*3"])
def test_parse_decimal_leaves_odd_numbers_to_python(text):
    ok, _, _ = S.parse_decimal(_buf(text), 0, len(text))
    assert not ok


# ------------------------------------------------------------------ the command word
@pytest.mark.parametrize("text, motion, expect", [
    (b"G1 X1", 1, (G, 1, 2)),
    (b"g0x1", 1, (G, 0, 2)),              # case-blind; the next letter ends the code
    (b"M204 S5", 1, (M, 204, 4)),
    (b"G01 X1", 1, (G, 1, 3)),
    (b"X5 Y1", 0, (G, 0, 0)),             # no command word: the modal G0 again
    (b"E-1", 1, (G, 1, 0)),
])
def test_command_word(text, motion, expect):
    assert S.command_word(_buf(text), 0, len(text), motion) == expect


@pytest.mark.parametrize("text, motion", [
    (b"G0001 X1", 1),    # four digits
    (b"G1.5 X1", 1),     # G1.5 is not G1
    (b"G", 1),
    (b"X5", 2),          # a bare word repeats an arc: the interpreter's job
    (b"T0", 1),
    (b"(note) G1 X1", 1),   # a comment in parentheses
    (b"N10 G1 X1", 1),
])
def test_command_word_leaves_other_lines_to_python(text, motion):
    assert S.command_word(_buf(text), 0, len(text), motion)[0] == 0


def test_word_bit():
    assert S.word_bit(ord("x")) == S.WORD_X
    assert S.word_bit(ord("r")) == S.WORD_R
    assert S.word_bit(ord("i")) == 0
    assert S.word_bit(ord("X")) == 0      # takes the lower-case letter (scan_words lowers it first)


# ------------------------------------------------------------------ the words
def test_scan_words_reads_values_and_stops_at_the_comment():
    text = b" X1.5 y-2 E.25 F1200 ; wipe\nG1 X9\n"
    ok, has, vx, vy, vz, ve, vf, vs, vp, vt, vr, eol = S.scan_words(_buf(text), 0, len(text))
    assert ok
    assert has == S.WORD_X | S.WORD_Y | S.WORD_E | S.WORD_F
    assert (vx, vy, vz, ve, vf) == (1.5, -2.0, 0.0, 0.25, 1200.0)
    assert eol == text.index(b"\n")


def test_scan_words_splits_1e3_into_two_words():
    # as Klipper's and Marlin's parsers do: a letter starts the next word, so "X1e3" is X1 E3
    text = b"X1e3\n"
    ok, has, vx, _, _, ve, *_rest, eol = S.scan_words(_buf(text), 0, len(text))
    assert ok and has == S.WORD_X | S.WORD_E and (vx, ve) == (1.0, 3.0) and eol == 4


@pytest.mark.parametrize("text", [b" X1 X2\n", b" X1 I2\n", b" X1 (slow)\n", b" X1.2.3\n", b" S\n"])
def test_scan_words_leaves_other_words_to_python(text):
    assert not S.scan_words(_buf(text), 0, len(text))[0]


# ------------------------------------------------------------------ comments
def test_skip_comment_line():
    feat_raw = np.zeros((S.FEAT_MAX, S.FEAT_NAME_MAX), np.uint8)
    feat_raw[0, :9] = _buf(b"Perimeter")
    feat_len = np.zeros(S.FEAT_MAX, np.int64)
    feat_len[0] = 9
    feat_idx = np.zeros(S.FEAT_MAX, np.int64)
    feat_idx[0] = 4
    _, ist = _state()
    ist[S.I_NFEAT] = 1
    ist[S.I_FEATURE] = -1

    def run(text):
        return S.skip_comment_line(_buf(text), 0, len(text), ist, feat_raw, feat_len, feat_idx)

    assert run(b"; just words\nG1") == (True, 12)
    assert run(b";") == (True, 1)
    assert run(b";LAYER:3\n") == (False, 8)              # layer markers: Python
    assert run(b";TYPE:Infill\n")[0] is False            # a name not in the table yet: Python adds it
    assert ist[S.I_FEATURE] == -1
    assert run(b";TYPE:Perimeter\r\n") == (True, 16)     # a known name is applied here
    assert ist[S.I_FEATURE] == 4


# ------------------------------------------------------------------ G0 / G1
def test_linear_target_units_offsets_and_flow():
    st, ist = _state()
    st[S.S_UNIT] = 25.4          # G20
    st[S.S_OX] = 10.0
    st[S.S_X], st[S.S_E], st[S.S_ELOG] = 3.0, 7.0, 2.0
    st[S.S_FLOW_F] = 0.5
    x1, y1, z1, e1, elog, feed = S.linear_target(st, ist, S.WORD_X | S.WORD_E | S.WORD_F, 1.0, 0.0, 0.0, 3.0,
                                                 6.0)
    assert x1 == 25.4 + 10.0 and y1 == 0.0 and z1 == 0.0
    assert elog == 3.0 * 25.4
    assert e1 == 7.0 + (3.0 * 25.4 - 2.0) * 0.5       # machine E moves by the logical step times the flow
    assert feed == 6.0 * 25.4 / 60.0
    assert st[S.S_X] == 3.0                             # nothing committed


def test_linear_target_relative_float32_on_marlin():
    st, ist = _state(S.DIALECT_MARLIN, f32=1)
    ist[S.I_ABS_COORD] = 0
    st[S.S_X] = 0.1
    x1, *_ = S.linear_target(st, ist, S.WORD_X, 0.2, 0.0, 0.0, 0.0, 0.0)
    assert x1 == float(np.float32(np.float32(0.1) + np.float32(0.2)))   # 0.30000001192092896
    assert x1 != 0.1 + 0.2


def test_linear_move_writes_a_print_row():
    st, ist = _state()
    out = np.zeros(2, MOVE_DTYPE)
    st[S.S_SPEED_F] = 2.0
    ok, n = S.linear_move(out, 0, 7, 1, S.DIALECT_KLIPPER, st, ist, S.WORD_X | S.WORD_Y | S.WORD_E | S.WORD_F,
                          3.0, 4.0, 0.0, 0.5, 600.0)
    assert ok and n == 1
    r = out[0]
    assert (r["line"], r["kind"], r["flags"]) == (7, KIND_PRINT, 0)
    assert r["move_d"] == 5.0                       # 3-4-5
    assert r["feed_v"] == 600.0 / 60.0 * 2.0        # F in mm/min, M220 200 %
    assert (r["x1"], r["y1"], r["e1"]) == (3.0, 4.0, 0.5)
    assert (st[S.S_X], st[S.S_Y], st[S.S_E], st[S.S_FEED]) == (3.0, 4.0, 0.5, 10.0)


def test_linear_move_rapid_retract_and_refusals():
    st, ist = _state(S.DIALECT_CNC)
    out = np.zeros(2, MOVE_DTYPE)
    ok, n = S.linear_move(out, 0, 1, 0, S.DIALECT_CNC, st, ist, S.WORD_Z, 0.0, 0.0, 5.0, 0.0, 0.0)
    assert ok and n == 1
    assert out[0]["kind"] == KIND_TRAVEL and out[0]["flags"] == FLAG_RAPID and out[0]["feed_v"] == math.inf

    st, ist = _state(S.DIALECT_MARLIN)
    st[S.S_ACC_R] = 300.0
    ok, n = S.linear_move(out, 0, 2, 1, S.DIALECT_MARLIN, st, ist, S.WORD_E, 0.0, 0.0, 0.0, -0.8, 0.0)
    assert ok and n == 1
    assert out[0]["kind"] == KIND_EXTRUDE_ONLY and out[0]["flags"] == FLAG_RETRACT
    assert out[0]["move_d"] == 0.8 and out[0]["accel"] == 300.0    # Marlin: E alone takes the retract accel

    before = st.copy()
    for has, vf in ((S.WORD_X | S.WORD_F, 0.0), (S.WORD_X | S.WORD_S, 1.0)):   # F0; G1 with S
        ok, n = S.linear_move(out, 0, 3, 1, S.DIALECT_MARLIN, st, ist, has, 1.0, 0.0, 0.0, 0.0, vf)
        assert not ok and n == 0
    np.testing.assert_array_equal(st, before)


def test_linear_move_without_motion_writes_no_row():
    st, ist = _state()
    out = np.zeros(1, MOVE_DTYPE)
    ok, n = S.linear_move(out, 0, 1, 1, S.DIALECT_KLIPPER, st, ist, S.WORD_F, 0.0, 0.0, 0.0, 0.0, 3000.0)
    assert ok and n == 0 and st[S.S_FEED] == 50.0


# ------------------------------------------------------------------ other commands
def test_dwell():
    out = np.zeros(1, MOVE_DTYPE)
    st, ist = _state()
    assert S.dwell(out, 0, 1, S.DIALECT_MARLIN, st, ist, S.WORD_P, 0.0, 500.0) == (True, 1)
    assert out[0]["kind"] == KIND_DWELL and out[0]["dwell_t"] == 0.5        # P in ms on printers
    # CNC: G4 goes to the interpreter (on grbl a sync, after which a $ setting applies: grbl_line.py)
    assert S.dwell(out, 0, 1, S.DIALECT_CNC, st, ist, S.WORD_P, 0.0, 2.5) == (False, 0)
    assert S.dwell(out, 0, 1, S.DIALECT_MARLIN, st, ist, S.WORD_S, 3.0, 0.0) == (True, 1)
    assert out[0]["dwell_t"] == 3.0
    assert S.dwell(out, 0, 1, S.DIALECT_KLIPPER, st, ist, S.WORD_S, 3.0, 0.0) == (False, 0)
    assert S.dwell(out, 0, 1, S.DIALECT_MARLIN, st, ist, S.WORD_P, 0.0, -1.0) == (False, 0)
    assert S.dwell(out, 0, 1, S.DIALECT_MARLIN, st, ist, S.WORD_P | S.WORD_X, 0.0, 1.0) == (False, 0)


def test_set_logical_e_notes_the_line():
    st, _ = _state()
    st[S.S_E] = 42.0
    eset_line = np.zeros(2, np.int64)
    eset_v = np.zeros(2)
    eset_n = np.zeros(1, np.int64)
    assert S.set_logical_e(9, S.DIALECT_MARLIN, st, S.WORD_E, 1.5, eset_line, eset_v, eset_n)
    assert st[S.S_ELOG] == 1.5 and st[S.S_E] == 42.0            # the machine E runs on
    assert (eset_n[0], eset_line[0], eset_v[0]) == (1, 9, 1.5)
    assert not S.set_logical_e(10, S.DIALECT_MARLIN, st, S.WORD_E | S.WORD_X, 0.0, eset_line, eset_v, eset_n)
    assert not S.set_logical_e(10, S.DIALECT_CNC, st, S.WORD_E, 0.0, eset_line, eset_v, eset_n)
    assert S.set_logical_e(10, S.DIALECT_MARLIN, st, S.WORD_E, 0.0, eset_line, eset_v, eset_n)
    assert not S.set_logical_e(11, S.DIALECT_MARLIN, st, S.WORD_E, 0.0, eset_line, eset_v, eset_n)   # full
    assert eset_n[0] == 2 and st[S.S_ELOG] == 0.0


def test_set_accel_klipper_and_marlin():
    st, ist = _state()
    P, T, S_, R = S.WORD_P, S.WORD_T, S.WORD_S, S.WORD_R
    assert S.set_accel(S.DIALECT_KLIPPER, st, ist, P | T, 0.0, 1500.0, 800.0, 0.0)
    assert (st[S.S_ACC_P], st[S.S_ACC_T], st[S.S_ACC_R]) == (800.0, 800.0, 800.0)     # min(P, T)
    assert S.set_accel(S.DIALECT_KLIPPER, st, ist, P, 0.0, 1500.0, 0.0, 0.0)             # P alone: ignored
    assert ist[S.I_M204_IGNORED] == 1 and st[S.S_ACC_P] == 800.0
    st, ist = _state(S.DIALECT_MARLIN)
    assert S.set_accel(S.DIALECT_MARLIN, st, ist, S_ | P, 2000.0, 500.0, 0.0, 0.0)
    assert (st[S.S_ACC_P], st[S.S_ACC_T], st[S.S_ACC_R]) == (500.0, 2000.0, 1000.0)
    assert not S.set_accel(S.DIALECT_MARLIN, st, ist, R, 0.0, 0.0, 0.0, -5.0)
    assert not S.set_accel(S.DIALECT_MARLIN, st, ist, S_ | S.WORD_X, 100.0, 0.0, 0.0, 0.0)
    assert st[S.S_ACC_R] == 1000.0


def test_modal_g_and_printer_m():
    out = np.zeros(1, MOVE_DTYPE)
    e = np.zeros(4, np.int64), np.zeros(4), np.zeros(1, np.int64)
    st, ist = _state(S.DIALECT_MARLIN)
    ist[S.I_G90_SETS_E] = 1                               # Marlin 2: G91 also makes E relative
    assert S.modal_g(91, out, 0, 1, S.DIALECT_MARLIN, st, ist, 0, 0.0, 0.0, 0.0, *e) == (True, 0)
    assert ist[S.I_ABS_COORD] == 0 and ist[S.I_ABS_E] == 0
    assert S.modal_g(90, out, 0, 1, S.DIALECT_MARLIN, st, ist, S.WORD_X, 0.0, 0.0, 0.0, *e) == (False, 0)
    assert S.modal_g(28, out, 0, 1, S.DIALECT_MARLIN, st, ist, 0, 0.0, 0.0, 0.0, *e) == (False, 0)
    assert S.modal_g(4, out, 0, 1, S.DIALECT_MARLIN, st, ist, S.WORD_P, 0.0, 0.0, 250.0, *e) == (True, 1)
    assert S.printer_m(82, S.DIALECT_MARLIN, st, ist, 0, 0.0, 0.0, 0.0, 0.0) and ist[S.I_ABS_E] == 1
    assert S.printer_m(83, S.DIALECT_MARLIN, st, ist, 0, 0.0, 0.0, 0.0, 0.0) and ist[S.I_ABS_E] == 0
    assert not S.printer_m(82, S.DIALECT_MARLIN, st, ist, S.WORD_E, 0.0, 0.0, 0.0, 0.0)
    assert S.printer_m(106, S.DIALECT_MARLIN, st, ist, S.WORD_S, 255.0, 0.0, 0.0, 0.0)
    assert not S.printer_m(84, S.DIALECT_MARLIN, st, ist, 0, 0.0, 0.0, 0.0, 0.0)
    assert not S.printer_m(83, S.DIALECT_CNC, st, ist, 0, 0.0, 0.0, 0.0, 0.0)   # CNC M lines: RS274NGC order
