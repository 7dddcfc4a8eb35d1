"""grbl 1.1h's laser mode ($32=1) on the grbl-1.1 model (gcode/commands_state.py _grbl_syncs).

The independent truth: a sync is a full stop, the same stop whatever made it, so a laser program takes exactly
as long as the same program with its S, M3, M4 and M5 words removed and a ``G4 P0`` (grbl's mc_dwell: a sync and
no wait) in front of each line where grbl syncs. Where grbl syncs is counted here by hand from gcode.c
(gc_execute_line step 4 with the laser-mode flags, step 7) and motion_control.c (mc_line's empty block); the
stripped programs have no spindle word at all, so the model's spindle rules do not enter their time.
"""
from __future__ import annotations

import json
from dataclasses import replace

import pytest

import gcodeplan as gp
from gcodeplan.schema import KIND_WAIT

from conftest import shared_path

# (line, grbl syncs before its motion in laser mode, in spindle mode), on the grbl preset (250 steps/mm)
PROGRAM = [
    ("G21 G90 F3000", False, False),
    ("G0 X5 Y5", False, False),
    ("M4 S100", True, True),              # step 7: a spindle state change syncs in both modes
    ("G1 X15 S200", False, True),         # an S change on a motion line: LASER_ISMOTION, no sync in laser mode
    ("G1 Y15 S300", False, True),
    ("G1 X5 S400", False, True),
    ("G0 X30 Y5 S0", False, True),        # G0 with axis words is a motion too (LASER_DISABLE: power 0)
    ("G1 X40 S500", False, True),
    ("S600", True, True),                 # a bare S: no motion, the laser is on: spindle_sync
    ("S600", False, False),               # no change, no sync
    ("G1 S700", True, True),              # G1 without axis words is no motion (axis_command none)
    ("G1 Y15", False, False),
    ("M5", True, True),
    ("S800", False, False),               # the laser is off: S changes nothing
    ("G0 X50 Y20", False, False),
    ("M3", True, True),
    ("G1", True, False),                  # M3, G0 → G1 without motion: LASER_FORCE_SYNC
    ("G1 X60 S900", False, True),
    ("G0", True, False),                  # M3, G1 → G0 without motion: LASER_FORCE_SYNC
    ("G0 X70", False, False),
    ("G1 X70 F2000", True, False),        # M3, a move of no length: mc_line's empty block syncs
    ("G1 X80", False, False),
    ("G1 X80.001", True, False),          # 0.25 step: an empty block too
    ("G1 X90", False, False),
    ("M4", True, True),
    ("G1 X100 Y25", False, False),
    ("G1", False, False),                 # M4 (not M3): no forced sync
    ("G0 X0 Y0 S0", False, True),
    ("M5", True, True),
    ("M2", False, False),
]


def _machine(laser: int):
    return replace(gp.load_machine("grbl"), grbl_laser_mode=laser)


def _strip(line: str) -> str:
    """The line without its S, M3, M4 and M5 words."""
    keep = [w for w in line.split() if w[0] != "S" and w not in ("M3", "M4", "M5")]
    return " ".join(keep)


def _stripped(sync_column: int) -> str:
    out = []
    for row in PROGRAM:
        if row[sync_column]:
            out.append("G4 P0")
        out.append(_strip(row[0]))
    return "\n".join(out) + "\n"


def _total(tmp_path, text: str, m) -> tuple[float, object]:
    p = tmp_path / "p.gcode"
    p.write_text(text)
    est = gp.estimate(str(p), m)
    return est.total_time_s, gp.plan(str(p), m).moves


@pytest.mark.parametrize("laser, column", [(1, 1), (0, 2)])
def test_laser_and_spindle_mode_times_are_the_stripped_programs_with_their_syncs(tmp_path, laser, column):
    program = "\n".join(row[0] for row in PROGRAM) + "\n"
    t, moves = _total(tmp_path, program, _machine(laser))
    t_stripped, moves_stripped = _total(tmp_path, _stripped(column), _machine(laser))
    # the syncs are where gcode.c says: one wait row per hand-counted sync, on its line
    waits = [int(x) for x in moves["line"][moves["kind"] == KIND_WAIT]]
    assert waits == [i + 1 for i, row in enumerate(PROGRAM) if row[column]]
    assert t == t_stripped


def test_a_lightburn_style_job_keeps_moving_through_its_power_changes(tmp_path):
    """A grey-scale raster: scan lines of 0.4 mm segments, every one with its own S under M4. In laser mode
    nothing stops between the segments, so the time is the job's with no S words at all; in spindle mode every
    segment runs from rest to rest (2·√(0.4 mm / 500 mm/s²) = 57 ms, plus $1's 25 ms, against 4 ms)."""
    lines = ["G21 G90", "M4 S0", "G0 X0 Y0", "G1 F6000"]
    plain = ["G21 G90", "G4 P0", "G0 X0 Y0", "G1 F6000"]
    for row in range(4):
        lines.append(f"G0 X0 Y{row * 0.2:.1f} S0")
        plain.append(f"G0 X0 Y{row * 0.2:.1f}")
        for k in range(1, 26):
            lines.append(f"G1 X{0.4 * k:.1f} S{(k * 37 + row) % 1000}")
            plain.append(f"G1 X{0.4 * k:.1f}")
    lines += ["M5", "M2"]
    plain += ["G4 P0", "M2"]
    t_laser, _ = _total(tmp_path, "\n".join(lines) + "\n", _machine(1))
    t_plain, _ = _total(tmp_path, "\n".join(plain) + "\n", _machine(1))
    t_spindle, _ = _total(tmp_path, "\n".join(lines) + "\n", _machine(0))
    assert t_laser == t_plain
    rest_to_rest_s = 2 * (0.4 / 500.0) ** 0.5 + 0.025
    assert t_spindle > t_laser + 100 * 0.9 * (rest_to_rest_s - 0.4 / 100.0)


def test_laser_mode_from_the_settings_report_and_a_machine_file(tmp_path):
    from gcodeplan.errors import ConfigError

    report = tmp_path / "settings.txt"
    report.write_text("$100=80\n$101=80\n$102=400\n$32=1\n")
    with __import__("warnings").catch_warnings():
        __import__("warnings").simplefilter("error")      # no "stops as in spindle mode" warning any more
        m = gp.load_machine(str(report))
    assert m.grbl_laser_mode == 1
    report.write_text("$100=80\n$101=80\n$102=400\n$32=0\n")
    assert gp.load_machine(str(report)).grbl_laser_mode == 0
    toml = tmp_path / "laser.toml"
    toml.write_text('base = "grbl"\ngrbl_laser_mode = 1\n')
    assert gp.load_machine(str(toml)).grbl_laser_mode == 1
    toml.write_text('base = "grbl"\ngrbl_laser_mode = 2\n')
    with pytest.raises(ConfigError, match="grbl_laser_mode"):
        gp.load_machine(str(toml))


def test_the_estimate_notes_laser_mode(tmp_path):
    program = "\n".join(row[0] for row in PROGRAM) + "\n"
    p = tmp_path / "p.gcode"
    p.write_text(program)
    est = gp.estimate(str(p), _machine(1))
    assert any("laser mode" in w for w in est.parse.warnings)
    est0 = gp.estimate(str(p), _machine(0))
    assert not any("laser mode" in w for w in est0.parse.warnings)


REFERENCE = ["synth_square", "synth_polycircle30", "synth_arcs", "linuxcnc_plasmatest", "linuxcnc_arcspiral"]
# lines where a laser-mode grbl syncs and a spindle-mode one does not: a G0 / G1 of no length under M3
# (motion_control.c mc_line: an empty block syncs in M3 laser mode). arcspiral's line 4 (g0x0y0z1 after g0z1)
# and line 7 (g1 to the X Y the g0 of line 5 reached). The reference README ("in these programs every S word
# is on a line without motion or with an M3/M5 state change ... so $32 would not change any time") counts the
# S words only; these two lines are the exception it does not name.
LASER_ONLY_SYNCS = {"linuxcnc_arcspiral": [4, 7]}


def _reference_program(tmp_path, name, sync_before=()):
    times = json.loads(shared_path("reference", "grbl", "times.json").read_text())
    entry = times[name]
    lines = shared_path(*entry["program"].split("/")[1:]).read_text().split("\n")
    for edit in entry["preprocessing"]:
        lines[edit["line"] - 1] = edit["after"]
    for k in sorted(sync_before, reverse=True):
        lines.insert(k - 1, "G4 P0")
    p = tmp_path / f"program{len(sync_before)}.gcode"
    p.write_text("\n".join(lines))
    return str(p), entry


@pytest.mark.parametrize("name", REFERENCE)
def test_reference_programs_take_the_same_time_with_laser_mode(tmp_path, name):
    """$32=1 on the reference programs: the same total as $32=0 (grbl-sim's), but for the empty-block syncs
    of M3 laser mode, which take exactly the time of a G4 P0 (a sync) at those lines in spindle mode."""
    m = gp.load_machine(str(shared_path("reference", "grbl", "grbl_settings.txt")))
    path, entry = _reference_program(tmp_path, name)
    t0 = gp.estimate(path, m).total_time_s
    t1 = gp.estimate(path, replace(m, grbl_laser_mode=1)).total_time_s
    assert t0 == pytest.approx(entry["total_time_s"], abs=2e-7)
    extra = LASER_ONLY_SYNCS.get(name, [])
    if not extra:
        assert t1 == t0
    else:
        path_synced, _ = _reference_program(tmp_path, name, extra)
        assert t1 == gp.estimate(path_synced, m).total_time_s
        assert t1 > t0


@pytest.mark.parametrize("laser", [0, 1])
def test_scanner_and_interpreter_give_the_same_rows(tmp_path, laser):
    """Laser mode under M3 and grbl's idle state send lines to the interpreter (scan.I_TO_PYTHON): the rows are
    those of the interpreter alone."""
    from conftest import same_rows
    from gcodeplan.gcode.reader import read_moves

    text = "\n".join(row[0] for row in PROGRAM[:-1]) + "\nG0 X1 Y1\nG4 P0.2\n$110=3000\nG0 X90\nG1 X10 Y2\n"
    p = tmp_path / "p.gcode"
    p.write_text(text)
    a, _ = read_moves(str(p), _machine(laser))
    b, _ = read_moves(str(p), _machine(laser), force_python=True)
    assert same_rows(a, b)
    assert int(a["limits"][-1]) == 1          # the $110 after G4 applied


def test_two_collinear_lines_with_their_own_power_hand_worked(tmp_path):
    """grbl-sim's settings (X 500 mm/s², $1 = 255: no idle delay), two collinear 100 mm lines at F3000 under M4,
    each with its own S. Laser mode: one trapezoid over 200 mm, 200/50 + 50/500 = 4.1 s; spindle mode: the S
    change stops between them, two trapezoids of 100/50 + 50/500 = 2.1 s each (grbl's timer adds < 0.1 %)."""
    m = gp.load_machine(str(shared_path("reference", "grbl", "grbl_settings.txt")))
    text = "G21 G90 F3000\nM4 S0\nG1 X100 S10\nG1 X200 S20\nM5\n"
    t_laser, _ = _total(tmp_path, text, replace(m, grbl_laser_mode=1))
    t_spindle, _ = _total(tmp_path, text, replace(m, grbl_laser_mode=0))
    assert t_laser == pytest.approx(200 / 50 + 50 / 500, rel=1e-3)
    assert t_spindle == pytest.approx(2 * (100 / 50 + 50 / 500), rel=1e-3)


@pytest.mark.parametrize("laser", [0, 1])
def test_the_scanner_takes_free_s_words_as_the_interpreter_does(tmp_path, laser):
    """Under M4 in laser mode and with the spindle off in either mode, an S word on a moving G0/G1 only sets grbl's
    spindle speed: the numba scanner takes such lines (a raster of S-per-segment lines reads at the scanner's speed)
    and its rows, stops, spindle-command count and later sync decisions equal the Python interpreter's."""
    from test_grbl_rejects import read_both

    lines = [p[0] for p in PROGRAM[:-1]]
    raster = ["M4 S0"] + [f"G1 X{10 + (i % 7) * 0.4:.1f} Y{i * 0.1:.1f} S{(i * 37) % 1000}" for i in range(200)]
    off = ["M5"] + [f"G1 X{i % 5} S{i * 3}" for i in range(20)] + ["M4", "S5", "G1 X3 S7", "S7", "G1 X1"]
    text = "\n".join(lines + raster + off + ["M5", "M2"]) + "\n"
    from gcodeplan.gcode.reader import read_moves

    rows, summary = read_both(tmp_path, text, machine=_machine(laser))
    _, by_python = read_moves(str(tmp_path / "p.nc"), _machine(laser), force_python=True)
    assert summary.spindle_commands == by_python.summary.spindle_commands > 200
    waits = [int(r["line"]) for r in rows if r["kind"] == KIND_WAIT]
    n0 = len(lines)
    if laser:
        # the raster and the spindle-off lines stop nowhere; after M4 the bare "S5" stops, "S7" after the moving
        # "G1 X3 S7" does not (the scanner's S reached the interpreter)
        raster_lines = range(n0 + 2, n0 + 202)              # the 200 G1 lines after "M4 S0"
        off_lines = range(n0 + 203, n0 + 223)               # the 20 G1 lines after "M5"
        assert not [w for w in waits if w in raster_lines or w in off_lines]
        assert {n0 + 202, n0 + 223, n0 + 224} <= set(waits)   # M5, M4, the bare S5
        assert n0 + 225 not in waits and n0 + 226 not in waits
    else:
        # spindle mode: every S change under M4 stops (the first raster line keeps S0: 199 stops)
        assert len([w for w in waits if n0 + 2 <= w < n0 + 202]) == 199
