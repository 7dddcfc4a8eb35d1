"""RS274NGC as LinuxCNC (and grbl) execute one line: every word, in the documented order of execution.

Hand-worked one-line programs with their expected moves (machine mm), the order of execution checked for
every pair of the steps that make rows, modal-group errors, G28/G30, the tool table, M6's tool change
position, machine units, the .ini's travel limits. Truth: LinuxCNC's "G-code Order of Execution" and
"Modal Groups" pages and its interpreter (interp_execute.cc execute_block, interp_convert.cc convert_home,
convert_feed_rate before convert_length_units), grbl 1.1's gcode.c.
"""
from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from conftest import same_rows
from gcodeplan.config.linuxcnc import load_linuxcnc_ini
from gcodeplan.errors import ConfigError, GcodeError
from gcodeplan.gcode import interp as interp_mod
from gcodeplan.gcode.reader import read_moves
from gcodeplan.machine import Machine
from gcodeplan.schema import FLAG_RAPID, KIND_DWELL, KIND_WAIT

INI = ("[EMCMOT]\nSERVO_PERIOD = 1000000\n[TRAJ]\nCOORDINATES = X Y Z\nLINEAR_UNITS = {units}\n"
       "MAX_LINEAR_VELOCITY = 100\n"
       "[AXIS_X]\nMAX_VELOCITY = 100\nMAX_ACCELERATION = 1000\nMIN_LIMIT = -500\nMAX_LIMIT = 500\n"
       "[AXIS_Y]\nMAX_VELOCITY = 100\nMAX_ACCELERATION = 1000\n"
       "[AXIS_Z]\nMAX_VELOCITY = 20\nMAX_ACCELERATION = 500\n"
       "[RS274NGC]\nPARAMETER_FILE = mill.var\n"
       "[EMCIO]\nTOOL_TABLE = tool.tbl\n{emcio}")


def mill(tmp_path, units="mm", emcio="", var="5181 1.0\n5182 2.0\n5183 30.0\n"):
    (tmp_path / "tool.tbl").write_text("T1 P1 Z0 D0 ;zero\nT2 P2 Z10.5 D3 ;long tool\n")
    (tmp_path / "mill.var").write_text(var)
    p = tmp_path / "mill.ini"
    p.write_text(INI.format(units=units, emcio=emcio))
    return load_linuxcnc_ini(str(p))


def moves(tmp_path, text, machine):
    """Non-wait rows as (line, x1, y1, z1, rapid, feed mm/s) and the rows themselves; both interpreter paths."""
    path = tmp_path / "p.ngc"
    path.write_text(text)
    a, r = read_moves(str(path), machine)
    b, _ = read_moves(str(path), machine, force_python=True)
    assert same_rows(a, b), "numba scanner and Python interpreter disagree"
    keep = a[(a["kind"] != KIND_WAIT) & (a["kind"] != KIND_DWELL)]
    out = [(int(m["line"]), round(float(m["x1"]), 9), round(float(m["y1"]), 9), round(float(m["z1"]), 9),
            bool(m["flags"] & FLAG_RAPID), round(float(m["feed_v"]), 9)) for m in keep]
    return out, a, r


PRE = "G21 G90 G64\nG0 X10 Y10 Z5\n"          # line 2: the start point of every one-line program below
R = True
F = False
INF = math.inf

# one line after PRE -> its moves (line 3): (x, y, z, rapid, feed_v)
ONE_LINE = [
    ("G43 H1 Z100. M3 S22000", [(10, 10, 100, R, INF)]),           # the lines: motion kept
    ("G43 Z2.5 H01 M08", [(10, 10, 2.5, R, INF)]),
    ("Z25. M09", [(10, 10, 25, R, INF)]),
    ("M3 S1000 X20", [(20, 10, 5, R, INF)]),                        # modal G0
    ("G1 X20 F600 M8", [(20, 10, 5, F, 10.0)]),
    ("G43 H2 Z0", [(10, 10, 10.5, R, INF)]),                       # tool table: T2 is 10.5 mm long
    ("G43.1 Z3", []),                                              # G43.1 takes the Z word
    ("G20 G0 X1", [(25.4, 10, 5, R, INF)]),                        # units before motion
    ("G20 G1 X1 F60", [(25.4, 10, 5, F, 1.0)]),                    # LinuxCNC: F before G20 (60 mm/min)
    ("G91 X1", [(11, 10, 5, R, INF)]),                             # distance mode before motion
    ("G10 L2 P2 X100", []),                                        # G10 takes the axis words: no motion
    ("G92 X0", []),
    ("G4 P0.5 G1 X20 F600", [(20, 10, 5, F, 10.0)]),
    ("G28", [(0, 0, 0, R, INF)]),                                  # no axis word: straight to #5161.. (0)
    ("G28 X5", [(5, 10, 5, R, INF), (0, 10, 5, R, INF)]),          # via X5, then X home only
    ("G91 G28 Z0", [(10, 10, 0, R, INF)]),                         # intermediate = here, then Z home
    ("G30 Z7", [(10, 10, 7, R, INF), (10, 10, 30, R, INF)]),       # #5183 = 30 from mill.var
    ("G30", [(1, 2, 30, R, INF)]),
    ("G53 G0 X0", [(0, 10, 5, R, INF)]),
    ("M7 M8 X12", [(12, 10, 5, R, INF)]),                          # LinuxCNC allows M7 with M8
]


@pytest.mark.parametrize("line,expect", ONE_LINE, ids=[t for t, _ in ONE_LINE])
def test_one_line_programs(tmp_path, line, expect):
    got, _, _ = moves(tmp_path, PRE + line + "\nM2\n", mill(tmp_path))
    assert [g[1:] for g in got if g[0] == 3] == [tuple(float(v) if not isinstance(v, bool) else v for v in e)
                                                  for e in expect]


def test_next_move_starts_where_the_m_code_line_ended(tmp_path):
    """`Z25. M09` used to lose its motion and the next move started from the wrong place."""
    got, a, _ = moves(tmp_path, PRE + "Z25. M09\nG1 X20 F600\nM2\n", mill(tmp_path))
    feed = a[a["line"] == 4][0]
    assert (feed["x0"], feed["y0"], feed["z0"]) == (10.0, 10.0, 25.0)


def test_g28_1_stores_the_position_g28_returns_to(tmp_path):
    got, _, _ = moves(tmp_path, PRE + "G28.1\nG0 X50 Y50 Z50\nG28\nM2\n", mill(tmp_path))
    assert [g[1:4] for g in got if g[0] == 5] == [(10.0, 10.0, 5.0)]


def test_m6_moves_to_the_tool_change_position(tmp_path):
    m = mill(tmp_path, emcio="TOOL_CHANGE_POSITION = 0 0 50\n")
    got, _, r = moves(tmp_path, PRE + "T2 M6\nG0 X20\nM2\n", m)
    assert [g[1:5] for g in got if g[0] == 3] == [(0.0, 0.0, 50.0, True)]
    assert [g[1:4] for g in got if g[0] == 4] == [(20.0, 0.0, 50.0)]      # from the change position
    assert r.interp.tool == 2


def test_program_without_units_runs_in_the_machines_units(tmp_path):
    m = mill(tmp_path, units="inch")
    got, _, _ = moves(tmp_path, "G0 X1\nG21 G0 X1\nM2\n", m)
    assert [g[1] for g in got] == [pytest.approx(25.4), 1.0]


# ------------------------------------------------------------------ order of execution, every pair
# the steps that make rows, in LinuxCNC's order; each writes a log entry through the interpreter
STEPS = [
    ("T2 M6", "tool_change"),
    ("M3", "M3"),
    ("M8", "M8"),
    ("G4 P0.25", "dwell"),
    ("G43 H2", "G43"),
    ("G28", "move"),
    ("G1 X20 F600", "move"),
]


def _logged(monkeypatch, tmp_path, text, machine):
    log = []
    cls = interp_mod.Interpreter
    wait0, stop0, row0 = cls._wait, cls._stop_row, cls._row

    def wait(self, name, dwell_t=0.0, flags=0):
        log.append((self.line, name))
        stop0(self, KIND_WAIT, flags, dwell_t)
        self.waits[name] = self.waits.get(name, 0) + 1

    def stop_row(self, kind, flags, dwell_t):
        if kind == KIND_DWELL:
            log.append((self.line, "dwell"))
        stop0(self, kind, flags, dwell_t)

    def row(self, kind, *a):
        if kind not in (KIND_WAIT, KIND_DWELL):
            log.append((self.line, "move"))
        row0(self, kind, *a)

    monkeypatch.setattr(cls, "_wait", wait)
    monkeypatch.setattr(cls, "_stop_row", stop_row)
    monkeypatch.setattr(cls, "_row", row)
    path = tmp_path / "p.ngc"
    path.write_text(text)
    read_moves(str(path), machine, force_python=True)
    return [name for line, name in log if line == 3]


# pairs LinuxCNC refuses on one line: two non-modal codes (G4, G28), G28 with a motion using axis words
_REFUSED = [{"G4 P0.25", "G28"}, {"G28", "G1 X20 F600"}]


@pytest.mark.parametrize("i,j", [(i, j) for i, j in itertools.combinations(range(len(STEPS)), 2)
                                 if {STEPS[i][0], STEPS[j][0]} not in _REFUSED])
def test_order_of_execution_every_pair(monkeypatch, tmp_path, i, j):
    """Both words on one line, the later step written first: the earlier step still acts first."""
    (a, ra), (b, rb) = STEPS[i], STEPS[j]
    got = _logged(monkeypatch, tmp_path, PRE + f"{b} {a}\nM2\n", mill(tmp_path))
    assert ra in got and rb in got
    assert got.index(ra) < len(got) - 1 - got[::-1].index(rb), got


def test_modal_state_words_act_before_the_motion(tmp_path):
    """Plane, units, tool length, coordinate system, distance mode, written after the axis words."""
    m = mill(tmp_path)
    cases = [("X1 G20", 25.4, 10.0, 5.0), ("Z0 G43 H2", 10.0, 10.0, 10.5), ("X1 G55", 1.0, 10.0, 5.0),
             ("X1 G91", 11.0, 10.0, 5.0), ("X1 G54 G91 G20", 35.4, 10.0, 5.0)]
    for line, x, y, z in cases:
        got, _, _ = moves(tmp_path, PRE + line + "\nM2\n", m)
        assert [g[1:4] for g in got if g[0] == 3] == [(pytest.approx(x), y, z)], line
    # G18 before the arc: the arc turns in XZ
    got, a, _ = moves(tmp_path, PRE + "G2 X20 Z5 I5 K0 G18\nM2\n", m)
    arc = a[a["line"] == 3]
    assert np.ptp(arc["y1"]) == 0.0 and np.ptp(arc["z1"]) > 4.0


# ------------------------------------------------------------------ errors
@pytest.mark.parametrize("line,match", [
    ("G0 G1 X1", "two G codes of one modal group \\(motion\\); LinuxCNC: 'Two G codes used from same modal"),
    ("G20 G21", "modal group \\(units\\)"),
    ("G90 G91 X1", "modal group \\(distance\\)"),
    ("G54 G55", "coordinate system"),
    ("M3 M5", "two M codes of one modal group \\(spindle\\)"),
    ("M0 M2", "stopping"),
    ("G0 X1 G28", "G28 and G0 both use the axis words"),
    ("G4 P1 G28", "modal group \\(non-modal\\)"),
    ("G80 X1", "without a motion mode"),
])
def test_modal_group_conflicts_are_errors(tmp_path, line, match):
    with pytest.raises(GcodeError, match=match):
        moves(tmp_path, PRE + line + "\nM2\n", mill(tmp_path))


def test_grbl_names_its_own_errors(tmp_path):
    g = Machine(flavor="grbl", max_velocity=100.0)
    # grbl rejects the line (nothing of it happens) and runs the next: a warning, an error under --strict
    got, _, r = moves(tmp_path, "G0 G1 X1\nG0 X2\n", g)
    assert [x[1] for x in got] == [2.0]
    # gcode.c meets G1's axis command conflict with G0 (error:24) before the modal group (error:21)
    assert any("p.ngc:1: G1: grbl rejects it (error:24, axis command conflict)" in w for w in r.summary.warnings)
    path = tmp_path / "g.nc"
    path.write_text("G17 G18 X1\n")
    with pytest.raises(GcodeError, match="g.nc:1: G18: grbl error:21"):
        read_moves(str(path), g, strict=True)
    _, _, r = moves(tmp_path, "G81 X1 Z-1 R1\nM6\n", g)
    assert any("G81: grbl rejects it (error:20" in w for w in r.summary.warnings)
    assert any("M6: grbl rejects it (error:20" in w for w in r.summary.warnings)
    path = tmp_path / "s.nc"
    path.write_text("G64\n")
    with pytest.raises(GcodeError, match="G64: grbl error:20"):
        read_moves(str(path), g, strict=True)
    # grbl converts F with the line's own units (gcode.c), LinuxCNC with the units before the line
    got, _, _ = moves(tmp_path, "G21\nG20 G1 X1 F60\n", g)
    assert got[0][5] == pytest.approx(25.4)


def test_grbl_axis_words_with_m_code_move(tmp_path):
    g = Machine(flavor="grbl", max_velocity=100.0)
    got, _, _ = moves(tmp_path, "G0 X1\nX5 M8\n", g)
    assert [x[1] for x in got] == [1.0, 5.0]


# ------------------------------------------------------------------ the .ini
def test_min_limit_above_max_limit_is_a_config_error(tmp_path):
    p = tmp_path / "bad.ini"
    p.write_text(INI.format(units="mm", emcio="").replace("MIN_LIMIT = -500", "MIN_LIMIT = 600"))
    with pytest.raises(ConfigError, match=r"bad.ini:\d+: \[AXIS_X\]MIN_LIMIT 600 is above MAX_LIMIT 500"):
        load_linuxcnc_ini(str(p))


def test_travel_limits_from_the_ini_are_enforced(tmp_path):
    with pytest.raises(GcodeError, match=r"p.ngc:3: .*X 501"):
        moves(tmp_path, PRE + "G0 X501\nM2\n", mill(tmp_path))
    moves(tmp_path, PRE + "G0 X500\nM2\n", mill(tmp_path))


def test_unknown_tool_in_g43_is_an_error(tmp_path):
    with pytest.raises(GcodeError, match="G43 H7: tool 7 is not in the tool table"):
        moves(tmp_path, PRE + "G43 H7\nM2\n", mill(tmp_path))


@pytest.mark.parametrize("line", ["G90.1 G2 X20 Y10 I15 J10", "G91.1 G2 X20 Y10 I5 J0", "G2 X20 Y10 I5 J0"])
def test_arc_centre_modes(tmp_path, line):
    """G90.1: I J are the centre's coordinates; G91.1 (the default): offsets from the start. From (10, 10) to
    (20, 10) clockwise about (15, 10): a half circle over (15, 15)."""
    _, a, _ = moves(tmp_path, PRE + line + "\nM2\n", mill(tmp_path))
    arc = a[a["line"] == 3]
    assert np.abs(np.hypot(arc["x1"] - 15.0, arc["y1"] - 10.0) - 5.0).max() < 1e-9
    assert arc["y1"].max() == pytest.approx(15.0, abs=0.01)
