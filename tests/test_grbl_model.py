"""The grbl 1.1 firmware model (planner/grbl.py, gcode/arcs_grbl.py) against grbl 1.1h itself (grbl-sim in
lock-step, ../shared/reference/grbl/: totals, per-line end times, every step pulse) and against the hand
calculations in that reference's README."""
from __future__ import annotations

import csv
import gzip
import json
import math

import numpy as np
import pytest

import gcodeplan as gp
from gcodeplan.gcode.arcs_grbl import grbl_arc_chords
from gcodeplan.planner import grbl as G
from gcodeplan.schema import KIND_WAIT

from conftest import shared_path

PROGRAMS = ["synth_square", "synth_polycircle30", "synth_arcs", "linuxcnc_plasmatest", "linuxcnc_arcspiral",
            pytest.param("cncjs_jscut_tball_pocket_laser", marks=pytest.mark.slow)]


def _machine():
    """grbl-sim's settings, from its $$ report ($1 = 255: no idle delay at stops)."""
    return gp.load_machine(str(shared_path("reference", "grbl", "grbl_settings.txt")))


def _program(tmp_path, entry) -> str:
    """The program as grbl-sim ran it: the README's preprocessing (lines grbl rejects with error:20)."""
    lines = shared_path(*entry["program"].split("/")[1:]).read_text().split("\n")
    for edit in entry["preprocessing"]:
        assert lines[edit["line"] - 1].rstrip("\r") == edit["before"]
        lines[edit["line"] - 1] = edit["after"]
    p = tmp_path / "program.gcode"
    p.write_text("\n".join(lines))
    return str(p)


@pytest.mark.parametrize("name", PROGRAMS)
def test_every_step_total_and_line_equal_grbl_sim(tmp_path, name):
    times = json.loads(shared_path("reference", "grbl", "times.json").read_text())
    entry = times[name]
    m = _machine()
    moves = gp.plan(_program(tmp_path, entry), m).moves
    z = np.load(shared_path("reference", "grbl", "steps", f"{name}_steps.npz"))
    run = G.run(moves, G.GrblSettings.from_machine(m),
                steps_capacity=max(len(z[f"stepper_{a}"]) for a in "xyz") + 1)
    # the total: the last step pulse, to grbl's 16 MHz tick (the reference prints 7 decimals)
    assert run.total_s == pytest.approx(entry["total_time_s"], abs=2e-7)
    for a in "xyz":
        ref_t, ref_d = z[f"stepper_{a}"], z[f"stepper_{a}_dir"]
        t, d = run.steps[f"stepper_{a}"]
        assert len(t) == len(ref_t) == entry["steps"][a]
        assert np.array_equal(d, ref_d)
        if len(t):
            assert np.abs(t - ref_t).max() <= 0.25e-6     # every pulse within 4 ticks of 62.5 ns
    ends: dict[int, float] = {}
    ok = np.isfinite(run.row_end_s)
    for line, t in zip(moves["line"][ok], run.row_end_s[ok]):
        ends[int(line)] = max(ends.get(int(line), -1.0), float(t))
    with gzip.open(shared_path("reference", "grbl", "per_line", f"{name}.per_line_end_time.csv.gz"), "rt") as f:
        rows = list(csv.DictReader(f))
    worst = max(abs(ends[int(r["source_line"])] - float(r["end_time_s"])) for r in rows)
    assert worst <= 5e-4 * entry["total_time_s"]       # the bound: 0.05 % of the total


def _run_text(tmp_path, text, m=None):
    m = m or _machine()
    p = tmp_path / "p.gcode"
    p.write_text(text)
    moves = gp.plan(str(p), m).moves
    return moves, G.run(moves, G.GrblSettings.from_machine(m))


@pytest.mark.parametrize("feed, ideal_s, grbl_s", [(3000, 2.1000, 2.10053), (100, 60.00333, 59.99875)])
def test_single_line_against_the_readme_hand_calculation(tmp_path, feed, ideal_s, grbl_s):
    """README Validation: G1 X100 at F3000 is 2.1000 s ideal (0.1 s ramps at 500 mm/s², 1.9 s cruise) and
    2.10053 s in grbl (Timer1's OCR1A + 1 period, cycles rounded up); F100: 60.00333 s ideal, 59.99875 s."""
    _, run = _run_text(tmp_path, f"G21 G90 G94\nG1 X100 F{feed}\nM2\n")
    v = feed / 60.0
    assert ideal_s == pytest.approx(100.0 / v + v / 500.0, abs=1e-5)     # closed form of the ideal trapezoid
    assert run.total_s == pytest.approx(grbl_s, abs=1e-5)


def test_square_corner_junction_speed_is_grbl_s(tmp_path):
    """A 90° XY corner: junction acceleration 500/√½ = 707.1 mm/s², v² = a·δ·s/(1 − s) with s = √½, δ = 0.01:
    4.1317 mm/s (README). The corner is where X's steps stop and Y's start: the step period of Y's first
    step there is 1/(v·80)."""
    a_j = 500.0 / math.sqrt(0.5)
    v = math.sqrt(a_j * 0.01 * math.sqrt(0.5) / (1.0 - math.sqrt(0.5)))
    assert v == pytest.approx(4.1317, abs=1e-4)
    m = _machine()
    p = tmp_path / "c.gcode"
    p.write_text("G21 G90 G94\nG1 X50 F3000\nY50\nM2\n")
    moves = gp.plan(str(p), m).moves
    run = G.run(moves, G.GrblSettings.from_machine(m), steps_capacity=10000)
    tx, _ = run.steps["stepper_x"]
    ty, _ = run.steps["stepper_y"]
    # grbl runs each 10 ms segment at the mean speed of its slice: the first Y steps after the corner are at
    # the corner speed within one segment's acceleration (500 mm/s² × 10 ms = 5 mm/s at most)
    first_gap = ty[1] - ty[0]
    assert 1.0 / (80 * (v + 5.0)) < first_gap < 1.0 / (80 * v) * 1.01
    assert ty[0] > tx[-1]


def test_grbl_arc_chord_count_is_grbl_s_floor_rule():
    """motion_control.c: floor(|½·θ·r| / √(tol·(2r − tol))) chords, the last ending on the target."""
    pts = grbl_arc_chords((10.0, 0.0, 0.0), (10.0, 0.0, 0.0), [-10.0, 0.0, 0.0], None, 17, True, 0.002)
    n = math.floor(0.5 * 2 * math.pi * 10 / math.sqrt(0.002 * (20 - 0.002)))
    assert n == 157
    assert len(pts) == n and tuple(pts[-1]) == (10.0, 0.0, 0.0)
    r = np.hypot(pts[:, 0], pts[:, 1])
    assert np.abs(r - 10.0).max() < 1e-4                          # on the circle, to single precision
    # zero chords (a tiny arc): one straight move to the target
    pts = grbl_arc_chords((0.0, 0.0, 0.0), (0.01, 0.0, 0.0), [0.005, 0.0, 0.0], None, 17, True, 0.002)
    assert len(pts) == 1
    with pytest.raises(ValueError, match="radius"):
        grbl_arc_chords((0.0, 0.0, 0.0), (10.0, 0.0, 0.0), None, 4.0, 17, True, 0.002)


def test_grbl_spindle_and_coolant_changes_stop_the_motion(tmp_path):
    """gc_execute: a spindle state change, a coolant change and an S change while the spindle turns each
    sync (a full stop); a repeated M3 or an S change with the spindle off does not."""
    moves, _ = _run_text(tmp_path, "G21 G90\nS100\nG1 X10 F600\nM3\nM3\nG1 X20\nS200\nG1 X30\nM8\nM8\nG1 X40\n"
                                   "M5\nS300\nG1 X50\nM9\n")
    waits = moves[moves["kind"] == KIND_WAIT]
    assert [int(l) for l in waits["line"]] == [4, 7, 9, 12, 15]


def test_sub_step_moves_are_dropped_and_carried(tmp_path):
    """planner.c: a move rounding to zero steps is dropped and its displacement goes into the next move
    (X at 80 steps/mm: 0.004 mm is 0.32 step)."""
    moves, run = _run_text(tmp_path, "G21 G90\nG1 X0.004 F600\nG1 X0.008\nG1 X10\nM2\n")
    ends = run.row_end_s[moves["kind"] <= 1]
    assert np.isnan(ends[0])          # 0.32 step: no step, the line has no end time
    assert np.isfinite(ends[1])       # 0.64 step → lround 1 step from 0
    assert np.isfinite(ends[2])


def test_read_float_is_grbls_not_the_nearest_float():
    """nuts_bolts.c read_float scales an integer by 0.01 and 0.1 in single precision with double constants:
    -0.4252 comes out one unit in the last place away from the nearest float."""
    assert G.read_float("-0.4252") != np.float32(-0.4252)
    expected = -np.float32(float(np.float32(float(np.float32(4252)) * 0.01)) * 0.01)
    assert G.read_float("-0.4252") == expected
    assert G.read_float("0.010") == np.float32(0.01)
    assert G.read_float("123456789") == np.float32(123456780)     # digits past 8 are dropped, scaled by 10


# --------------------------------------------------------------------------- as a machine's firmware
def _settings_machine():
    return gp.load_machine(str(shared_path("reference", "grbl", "grbl_settings.txt")))


def test_dollar_dollar_report_is_a_machine():
    """grbl's $$ report (the reference's grbl_settings.txt) is recognised by content: grbl 1.1 model, the
    report's limits in gcodeplan's units, no travel bounds with soft limits off ($20=0)."""
    m = _settings_machine()
    assert m.firmware == "grbl-1.1"
    assert [m.axes[a].steps_per_mm for a in "xyz"] == [80.0, 80.0, 400.0]
    assert [m.axes[a].max_velocity for a in "xyz"] == pytest.approx([100.0, 100.0, 20.0])
    assert [m.axes[a].max_accel for a in "xyz"] == [500.0, 500.0, 100.0]
    assert (m.junction_deviation, m.arc_tolerance, m.grbl_idle_lock_ms) == (0.01, 0.002, 255.0)
    assert m.axes["y"].position_max == math.inf


def test_dollar_dollar_report_errors_name_the_file(tmp_path):
    from gcodeplan.errors import ConfigError

    p = tmp_path / "settings.txt"
    p.write_text("$100=80\n$101=80\n$102=400\n$99=1\n")
    with pytest.raises(ConfigError, match=r"\$99.*settings.txt|settings.txt.*\$99"):
        gp.load_machine(str(p))
    p.write_text("$100=80\n$101=0\n$102=400\n")
    with pytest.raises(ConfigError, match=r"\$101"):
        gp.load_machine(str(p))
    p.write_text("$100=80.000 (x, step/mm)\n$101=80.000 (y, step/mm)\nok\n$102=400\n$20=1\n$130=200\n")
    m = gp.load_machine(str(p))                    # grbl 0.9's commented report; soft limits on: travel bounds
    assert m.axes["x"].position_max == 200.0 and m.axes["z"].steps_per_mm == 400.0


@pytest.mark.parametrize("name", ["synth_square", "synth_arcs", "linuxcnc_plasmatest", "linuxcnc_arcspiral"])
def test_estimate_on_the_grbl_machine_is_grbl_s_time(tmp_path, name):
    """The whole pipeline (gp.estimate) on the $$ machine: total and every line's end equal grbl's."""
    entry = json.loads(shared_path("reference", "grbl", "times.json").read_text())[name]
    est = gp.estimate(_program(tmp_path, entry), _settings_machine())
    assert est.firmware == "grbl-1.1" and "firmware grbl-1.1" in est.to_text()
    assert est.total_time_s == pytest.approx(entry["total_time_s"], abs=2e-7)
    lines, ends = est.line_times()
    ours = dict(zip(lines.tolist(), ends.tolist()))
    with gzip.open(shared_path("reference", "grbl", "per_line", f"{name}.per_line_end_time.csv.gz"), "rt") as f:
        for r in csv.DictReader(f):
            assert ours[int(r["source_line"])] == pytest.approx(float(r["end_time_s"]),
                                                                abs=5e-4 * entry["total_time_s"])


def test_idle_lock_delay_costs_what_grbl_sim_measured(tmp_path):
    """README (settings): with $1 = 25 grbl busy-waits 25 ms in st_go_idle at every stop; plasmatest took
    0.716 s longer over its 29 stops in grbl-sim."""
    entry = json.loads(shared_path("reference", "grbl", "times.json").read_text())["linuxcnc_plasmatest"]
    program = _program(tmp_path, entry)
    text = shared_path("reference", "grbl", "grbl_settings.txt").read_text().replace("$1=255", "$1=25")
    p = tmp_path / "settings25.txt"
    p.write_text(text)
    base = gp.estimate(program, _settings_machine()).total_time_s
    slow = gp.estimate(program, gp.load_machine(str(p))).total_time_s
    assert slow - base == pytest.approx(0.716, abs=0.002)


def test_streaming_in_any_chunks_is_bit_identical(tmp_path):
    """The grbl mode emits a row once its last step pulse is out: any chunking gives the same PLAN rows,
    and the window stays bounded (15 planner blocks, 5 segments)."""
    from gcodeplan.planner.stream import StreamPlanner

    entry = json.loads(shared_path("reference", "grbl", "times.json").read_text())["synth_arcs"]
    m = _settings_machine()
    mv = gp.plan(_program(tmp_path, entry), m).moves
    lim = m.limits_row()
    outs = []
    for chunk in (len(mv), 1, 7, 64):
        sp = StreamPlanner(m)
        got, window = [], 0
        for i in range(0, len(mv), chunk):
            got.extend(sp.feed(mv[i:i + chunk], lim))
            window = max(window, sp.pending)
        got.extend(sp.finish())
        plan = np.concatenate([g[1] for g in got])
        assert len(plan) == len(mv)
        outs.append(plan)
        if chunk == 1:
            assert window < 40
    for plan in outs[1:]:
        for f in plan.dtype.names:
            assert np.array_equal(plan[f], outs[0][f]), f


def test_plan_rows_are_continuous_trapezoids(tmp_path):
    """Each PLAN row's phases cover its own length and its duration (the pieces the plots and samplers use)."""
    entry = json.loads(shared_path("reference", "grbl", "times.json").read_text())["synth_polycircle30"]
    p = gp.plan(_program(tmp_path, entry), _settings_machine())
    mv, pl = p.moves, p.plan
    moving = (mv["kind"] <= 1) & (pl["duration"] > 0)
    d = ((pl["start_v"] + pl["cruise_v"]) / 2 * pl["accel_t"] + pl["cruise_v"] * pl["cruise_t"]
         + (pl["cruise_v"] + pl["end_v"]) / 2 * pl["decel_t"])
    assert np.allclose(d[moving], mv["move_d"][moving], rtol=1e-9)
    assert np.allclose((pl["accel_t"] + pl["cruise_t"] + pl["decel_t"])[moving], pl["duration"][moving], rtol=1e-9)
    assert np.all(np.diff(pl["t_start"]) >= 0)
    assert pl["t_start"][-1] + pl["duration"][-1] == pytest.approx(entry["total_time_s"], abs=2e-7)


@pytest.mark.parametrize("batch_moves", [8192, 7])
def test_steps_on_the_grbl_machine_are_grbl_s_pulses(tmp_path, batch_moves):
    """The step stage of a grbl-1.1 machine hands on the stepper interrupt's own pulses (not a stepping of
    the plan): every pulse of every axis within 2 ticks of grbl-sim's, in any batching."""
    from gcodeplan import pipeline
    from gcodeplan.stepper.source import StepSink, rails_from

    entry = json.loads(shared_path("reference", "grbl", "times.json").read_text())["synth_arcs"]
    m = _settings_machine()
    rails = rails_from(m)
    got: dict[int, list] = {}
    sink = StepSink(rails, lambda si, t, d: got.setdefault(si, []).append((t.copy(), d.copy())), machine=m)
    pipeline.run(_program(tmp_path, entry), m, sinks=[sink], batch_moves=batch_moves)
    z = np.load(shared_path("reference", "grbl", "steps", "synth_arcs_steps.npz"))
    for si, rail in enumerate(rails):
        if rail.name[-1] not in "xyz":
            assert si not in got
            continue
        t = np.concatenate([c[0] for c in got[si]])
        d = np.concatenate([c[1] for c in got[si]])
        ref_t = z[f"stepper_{rail.name[-1]}"]
        assert len(t) == len(ref_t) and np.array_equal(d, z[f"stepper_{rail.name[-1]}_dir"])
        assert np.abs(t - ref_t).max() <= 0.25e-6


def test_random_arcs_never_crash_and_end_on_the_target():
    """Any G2/G3 (tiny, huge, degenerate, every plane): grbl's chords or its error, never a crash (an arc once
    needed more rows than estimated: the kernel wrote past its buffer; found by tools/fuzz.py)."""
    rng = np.random.default_rng(7)
    for _ in range(3000):
        s = rng.uniform(-1e3, 1e3, 3)
        e = s + rng.normal(0, rng.choice([0.0, 1e-3, 1.0, 100.0, 1e4, 1e20, 1e39]), 3)
        ijk = list(rng.normal(0, rng.choice([0.0, 1e-3, 1.0, 100.0, 1e4, 1e20, 1e39]), 3)) if rng.random() < 0.5 else None
        r = None if ijk is not None else float(rng.normal(0, rng.choice([0.0, 1e-3, 1.0, 100.0, 1e4, 1e20, 1e39])))
        try:
            pts = grbl_arc_chords(tuple(s), tuple(e), ijk, r, int(rng.choice([17, 18, 19])), bool(rng.random() < .5),
                                  float(rng.choice([0.002, 1e-6, 1.0])))
        except ValueError as err:
            assert "error:33" in str(err) or "error:34" in str(err)    # invalid target, arc radius error
            continue
        assert 1 <= len(pts) <= 65536
        assert np.array_equal(pts[-1], np.array(e, dtype=np.float32).astype(np.float64))


def test_a_target_beyond_grbls_int32_steps_is_an_error_naming_the_line(tmp_path):
    """grbl's positions are int32 steps: 30 m at 100 000 steps/mm is 3e9 steps, past 2³¹."""
    from gcodeplan.errors import GcodeError

    m = tmp_path / "m.toml"
    m.write_text('base = "grbl"\n[axis.x]\nsteps_per_mm = 100000.0\nposition_min = -inf\nposition_max = inf\n')
    p = tmp_path / "p.gcode"
    p.write_text("G21 G90\nG1 X10 F600\nG1 X30000\n")
    with pytest.raises(GcodeError, match="beyond grbl's reach") as err:
        gp.estimate(str(p), gp.load_machine(str(m)))
    assert err.value.line == 3


def test_grbl_floats_are_read_float_of_the_shortest_decimal():
    """The vectorised grbl_floats against read_float (nuts_bolts.c) of each value's decimal text: short decimals
    (0 … 8 decimals, at most 8 significant digits) are what grbl reads; other values the nearest float."""
    rng = np.random.default_rng(7)
    texts = ["0", "-0.4252", "0.010", "12345678", "-99999.999", "0.0000001", "1.5", "-2.25", "300.0125"]
    for d in range(9):
        for v in rng.uniform(-10 ** (7 - d), 10 ** (7 - d), 40):
            t = f"{v:.{d}f}"
            # read_float keeps 8 digits (leading zeros count); grbl_floats takes the shortest decimal of the
            # value, so a text with trailing zeros (read in more scaling steps) is not compared
            if sum(c.isdigit() for c in t) <= 8 and not (d and t.endswith("0")):
                texts.append(t)
    x = np.array([float(t) for t in texts])
    want = np.array([G.read_float(t) for t in texts], dtype=np.float32)
    got = G.grbl_floats(x)
    assert got.dtype == np.float32
    np.testing.assert_array_equal(got.view(np.uint32), want.view(np.uint32))
    odd = np.array([1 / 3, -math.pi, 1e9 + 0.5, np.inf, -np.inf])     # no short decimal: the nearest float
    np.testing.assert_array_equal(G.grbl_floats(odd), odd.astype(np.float32))
    assert np.isnan(G.grbl_floats(np.array([np.nan]))[0])


def test_operations_of_move_rows():
    """MOVE rows → grbl's operations: lines and arc chords are lines (a chord's float kept as it is), G4 and
    waits syncs (G4 P rounded up to 50 ms steps of 800,000 ticks), E-only rows skipped, a rapid or an
    unbounded feed runs at the rapid rate (rate 0), a feed in mm/s becomes mm/min."""
    from gcodeplan.schema import FLAG_ARC, FLAG_RAPID, KIND_DWELL, KIND_EXTRUDE_ONLY, MOVE_DTYPE

    m = np.zeros(6, MOVE_DTYPE)
    m["kind"] = [0, 1, KIND_EXTRUDE_ONLY, KIND_DWELL, KIND_WAIT, 0]
    m["flags"] = [0, FLAG_ARC, 0, 0, 0, FLAG_RAPID]
    m["x1"] = [-0.4252, 1 / 3, 5.0, 0, 0, 12.5]
    m["feed_v"] = [10.0, 20.0, 5.0, np.nan, np.nan, np.inf]
    m["dwell_t"] = [0, 0, 0, 0.12, 2.0, 0]
    kind, target, rate, rapid, dwell_ticks, rows = G.operations(m)
    assert rows.tolist() == [0, 1, 3, 4, 5]
    assert kind.tolist() == [G.OP_LINE, G.OP_LINE, G.OP_SYNC, G.OP_SYNC, G.OP_LINE]
    assert target[0, 0] == G.read_float("-0.4252") and target[1, 0] == np.float32(1 / 3)
    assert rate[0] == np.float32(600.0) and rate[1] == np.float32(1200.0) and rate[4] == 0
    assert rapid.tolist() == [False, False, True, True, True]     # no feed on a sync row: nan
    assert dwell_ticks.tolist() == [0, 0, 3 * 800_000, 0, 0]


def test_a_machine_files_laser_mode_is_no_warning_on_the_command_line(tmp_path, capsys):
    """$32=1 (laser mode) is modelled (tests/test_grbl_laser.py): no warning on standard error."""
    from gcodeplan.cli import main

    s = tmp_path / "settings.txt"
    s.write_text("$100=80\n$101=80\n$102=400\n$32=1\n")
    g = tmp_path / "p.gcode"
    g.write_text("G21 G90\nG1 X10 F600\n")
    assert main(["estimate", str(g), "--machine", str(s)]) == 0
    assert capsys.readouterr().err == ""
