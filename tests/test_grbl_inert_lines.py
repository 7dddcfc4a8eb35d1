"""grbl's fast path for lines that do nothing (``Rs274Commands.grbl_inert_line``, gcode/rs274.py).

A printer program run on grbl has tens of thousands of ``M204 P1000`` lines: an M code grbl does not have
(error:20) with a word only such a code reads. The reader interprets them from a memo instead of the full
RS274 path. Truth: the full path itself (``_execute_cnc``, the fast path turned off) on the same program must
give the same rows, warnings, counts and errors, line for line; and grbl's gcode.c for what the line means
(error:20 for the M code, the P word read by no command).
"""
from __future__ import annotations

import numpy as np
import pytest

from gcodeplan.errors import GcodeError
from gcodeplan.gcode import rs274
from gcodeplan.gcode import scan as S
from gcodeplan.gcode.lexing import FREE_TEXT_M
from gcodeplan.gcode.reader import read_moves
from gcodeplan.machine import Machine

# every kind of line near the fast path's edge: inert ones (memo hits and misses) and ones that must not be
LINES = [
    "G0 X1 Y2", "M204 P1000", "M204 P1000", "m204 p800", "M0204 P1.5", " M204\tP1000 ", "M204 P1000\r",
    "M204", "M999 I1 J2 K3 R4 L5 Q6 H7 D8", "M204 S1000", "M204 P1000 T1500", "M204 P1000 F600",
    "M204 P-.5", "M3 S1000", "M204 P1000", "M5", "M8", "M204 P1000 ; comment", "M204 P1000 (c)", "M117 hi",
    "M486 S1", "M204 X5", "G1 X3 F600", "M204 P1000", "N10 M204 P1000", "M204 P1000*10", "M204P1000",
    "M9", "M30 P1",
]


def _read(tmp_path, text, machine, **kw):
    path = tmp_path / "p.nc"
    path.write_bytes(text.encode())
    rows, reader = read_moves(str(path), machine, **kw)
    s = reader.summary
    return rows, s.warnings, s.warning_count, s.unknown_commands, s.ignored_commands, s.spindle_commands


def _full_path(monkeypatch):
    """Both fast paths off: the reader's memo (grbl_inert_line) and the scanner's (scan.I_GRBL_INERT)."""
    monkeypatch.setattr(rs274.Rs274Commands, "grbl_inert_line", lambda self, raw, lineno: False)
    init = rs274.Rs274Commands._cnc_init

    def init_without_scanner_path(self):
        init(self)
        if self.machine.is_cnc:
            self.ist[S.I_GRBL_INERT] = 0
    monkeypatch.setattr(rs274.Rs274Commands, "_cnc_init", init_without_scanner_path)


@pytest.mark.parametrize("force_python", [False, True])
def test_fast_path_equals_the_full_path(tmp_path, monkeypatch, force_python):
    g = Machine(flavor="grbl", max_velocity=100.0)
    text = "\n".join(LINES) + "\n"
    fast = _read(tmp_path, text, g, force_python=force_python)
    _full_path(monkeypatch)
    full = _read(tmp_path, text, g, force_python=force_python)
    # the same rows, field for field (nan equal to nan): G0 X1 Y2, G1 X3, the syncs of M3 M5 M8 M9; grbl rejects
    # "M204 X5" whole (error:20 before anything of the line runs), so it moves nowhere
    assert len(fast[0]) == len(full[0]) == 6
    for name in full[0].dtype.names:
        np.testing.assert_array_equal(fast[0][name], full[0][name], err_msg=name)
    assert fast[1:] == full[1:]
    # grbl's meaning, by hand: each M204 line is one error:20 that rejects the whole line (its P not read)
    assert fast[3]["M204"] == sum(1 for line in LINES if "M204" in line.upper() or "M0204" in line.upper())
    assert any(w.endswith("p.nc:2: M204: grbl rejects it (error:20, unsupported command); the line is skipped")
               for w in fast[1])
    assert not any("ignored" in w for w in fast[1])
    # grbl has no D, H or Q word: each is an error:20 of its own, named with the M code
    assert any(w.endswith("p.nc:9: M999 word Q word H word D: grbl rejects it (error:20, unsupported command); "
                          "the line is skipped") for w in fast[1])


def test_fast_path_takes_only_inert_lines():
    inert = rs274.Rs274Commands._grbl_inert_effect
    assert inert(b"M204 P1000") == ("M204",
                                    "M204: grbl rejects it (error:20, unsupported command); the line is skipped")
    assert inert(b"M204 Q1")[1].startswith("M204 word Q: grbl rejects it (error:20")
    for line in (b"M3 P1", b"M204 S1", b"M204 F1", b"M204 T1", b"M204 X1", b"M204 P1 P2", b"M117 P1",
                 b"M486 P1", b"M204 P1 ;c", b"G4 P1", b"M204 P1e3", b"M204.5 P1", b"M204 N1"):
        assert inert(line) is False, line


# a repeated word after an M code grbl lacks: gcode.c's word loop meets the M code first (error:20)
@pytest.mark.parametrize("text,match", [("G0 X1\nM204 P1000\n", "M204: grbl error:20"),
                                        ("M204 P1 P2\n", "M204: grbl error:20"),
                                        ("G0 X1\nG1 X2 X3\n", "word X repeated: grbl error:25")])
def test_strict_and_errors_are_the_full_paths(tmp_path, monkeypatch, text, match):
    g = Machine(flavor="grbl", max_velocity=100.0)
    strict = "grbl error" in match
    with pytest.raises(GcodeError, match=match) as fast:
        _read(tmp_path, text, g, strict=strict)
    _full_path(monkeypatch)
    with pytest.raises(GcodeError, match=match) as full:
        _read(tmp_path, text, g, strict=strict)
    assert str(fast.value) == str(full.value)


def test_linuxcnc_lines_go_the_full_path(tmp_path):
    lc = Machine(flavor="linuxcnc", max_velocity=100.0)
    _, warnings, count, unknown, _, _ = _read(tmp_path, "M204 P1000\nM204 P1000\n", lc)
    # LinuxCNC counts an unknown M code and warns of nothing; grbl's error:20 is no LinuxCNC word
    assert unknown == {"M204": 2} and count == 0 and not warnings


def test_the_scanner_rejects_only_lines_the_memo_path_rejects():
    """scan.py's grbl_inert_words accepts a subset of rs274's _INERT_LINE, and its M code table is rs274's
    GRBL_M, the free-text M codes and M486: a line the scanner skips is one the Python path skips with the
    same warning (checked on edge cases and on random word strings)."""
    not_inert = {c for c in range(1000) if S.GRBL_NOT_INERT_M[c]}
    assert not_inert == (rs274.GRBL_M | FREE_TEXT_M | {486})
    rng = np.random.default_rng(3)
    pieces = [" ", "\t", "P", "R", "I", "L", "Q", "S", "p", "1", "12", "1234567890", ".", "-", "+", "5", ";",
              "\r", "0.123456789", ".1234567890", "P1", " R2"]
    tails = ["", " P1000", " P1000\r", " P1 R2", " P1 P2", " P-.5", " P.", " P1.", "\tp800 ", " P1;c", " P1R2",
             " P1000*10"] + ["".join(rng.choice(pieces, rng.integers(1, 8))) for _ in range(4000)]
    accepted = 0
    for tail in tails:
        raw = ("M204" + tail).encode()
        buf = np.frombuffer(raw + b"\n", dtype=np.uint8)
        ok, eol = S.grbl_inert_words(buf, 4, len(buf))
        if ok:
            accepted += 1
            assert eol == len(buf) - 1, tail
            assert rs274.Rs274Commands._grbl_inert_effect(raw) == (
                "M204", "M204: grbl rejects it (error:20, unsupported command); the line is skipped"), tail
    assert accepted > 100


def test_the_scanner_takes_printer_m_lines_on_grbl(tmp_path, monkeypatch):
    """On grbl the scanner itself skips "M204 P1000" (no trip to Python per line), with the same warnings."""
    calls = []
    inert = rs274.Rs274Commands.grbl_inert_line
    monkeypatch.setattr(rs274.Rs274Commands, "grbl_inert_line",
                        lambda self, raw, lineno: calls.append(lineno) or inert(self, raw, lineno))
    g = Machine(flavor="grbl", max_velocity=100.0)
    _, warnings, count, unknown, _, _ = _read(tmp_path, "G0 X1\nM204 P1000\nG1 X2 F600\nM204 P800\nM107\n", g)
    # line 1 goes to Python: grbl is idle until its first motion (a $ setting would apply there, grbl_line.py)
    assert calls == [1] and unknown == {"M204": 2, "M107": 1} and count == 3
    assert [w.split("p.nc:")[1] for w in warnings] == [
        f"{n}: M{c}: grbl rejects it (error:20, unsupported command); the line is skipped"
        for n, c in ((2, 204), (4, 204), (5, 107))]
