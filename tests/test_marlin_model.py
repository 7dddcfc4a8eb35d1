"""The marlin-2.1.2 firmware model against Marlin 2.1.2.4's own planner.cpp / stepper.cpp
(shared/reference/marlin: every planner block as the stepper ran it, per-line end times, totals), and
against hand-worked trapezoids.

``python tools/compare_marlin.py`` prints the same agreement as a table.
"""
import csv
import gzip
import json
import math

import numpy as np
import pytest

import gcodeplan as gp
from gcodeplan.config import load_machine
from gcodeplan.errors import ConfigError
from gcodeplan.gcode.reader import read_moves
from gcodeplan.planner import marlin_kernels as mk
from gcodeplan.planner.marlin import run_marlin
from gcodeplan.stepper.marlin_isr import MARLIN_TIMER_HZ, acceleration_rate, block_ticks_kernel
from conftest import shared_path

FILES = ["prusaslicer25_cube20_marlin2", "cura413_ender3_cylinder30"]


def _csv(path):
    with gzip.open(path, "rt", newline="") as fh:
        rows = list(csv.reader(fh))
    return {name: np.array([float(r[i]) for r in rows[1:]]) for i, name in enumerate(rows[0])}


def _blocks(name):
    b = _csv(shared_path("reference", "marlin", "blocks", name + ".blocks.csv.gz"))
    moving = b["sync"] == 0
    return {k: v[moving] for k, v in b.items()}


@pytest.mark.parametrize("name", FILES)
def test_isr_times_every_reference_block_to_the_tick(name):
    """Given the trapezoid the firmware executed, the interrupt model's block time is the firmware's,
    tick for tick (25 MHz), for every block of both programs."""
    b = _blocks(name)
    ph = np.zeros(3, dtype=np.int64)
    ref_ticks = np.round((b["t_end_s"] - b["t_pick_s"]) * MARLIN_TIMER_HZ).astype(np.int64)
    mine = np.array([block_ticks_kernel(int(b["step_event_count"][i]), int(b["initial_rate"][i]),
                                        int(b["nominal_rate"][i]), int(b["final_rate"][i]),
                                        int(b["accelerate_end"][i]), int(b["decelerate_start"][i]),
                                        acceleration_rate(int(b["acceleration_steps_per_s2"][i])),
                                        MARLIN_TIMER_HZ, ph) for i in range(len(ref_ticks))])
    assert np.array_equal(mine, ref_ticks)


@pytest.mark.parametrize("name", FILES)
def test_every_planner_block_is_marlins(name):
    """Step counts, nominal rate, acceleration, initial/final rate, step boundaries and pick-up time of
    every block equal the firmware's (the finite buffer, jerk rule, slowdown and merges all show here)."""
    machine = load_machine("marlin-2.1.2")
    moves, reader = read_moves(str(shared_path("gcode", name + ".gcode")), machine)
    _, model = run_marlin(moves, reader.limits, machine, keep_blocks=True,
                          e_position_sets=reader.interp.e_position_sets)
    oi = np.concatenate([x[0] for x in model.blocks])
    lines = np.concatenate([x[2] for x in model.blocks])
    has = oi[:, mk.OI_HAS_BLOCK] == 1
    oi, lines = oi[has], lines[has]
    b = _blocks(name)
    assert len(oi) == len(b["seq"])
    assert np.array_equal(lines, b["source_line"].astype(np.int64))
    for col, o in [("step_event_count", mk.OI_SEC), ("nominal_rate", mk.OI_NOMINAL_RATE),
                   ("acceleration_steps_per_s2", mk.OI_ACCEL_STEPS), ("initial_rate", mk.OI_INITIAL_RATE),
                   ("final_rate", mk.OI_FINAL_RATE), ("accelerate_end", mk.OI_ACCEL_UNTIL),
                   ("decelerate_start", mk.OI_DECEL_AFTER), ("steps_e", mk.OI_SE)]:
        assert np.array_equal(oi[:, o], b[col].astype(np.int64)), col
    t_pick = np.round(b["t_pick_s"] * MARLIN_TIMER_HZ).astype(np.int64)
    assert np.array_equal(oi[:, mk.OI_T_PICK], t_pick)


@pytest.mark.parametrize("name", FILES)
def test_estimate_total_and_line_times_match_marlin(name):
    """Through the pipeline (``gcodeplan estimate --machine marlin-2.1.2``): the total and every per-line
    end time equal Marlin's (its times are whole 40 ns ticks, printed to 10 ns)."""
    times = json.loads(shared_path("reference", "marlin", "times.json").read_text())
    est = gp.estimate(str(shared_path("gcode", name + ".gcode")), gp.load_machine("marlin-2.1.2"))
    assert est.time.total_time_s == pytest.approx(times[name + ".gcode"]["total_time_s"], abs=1e-8)
    ref = _csv(shared_path("reference", "marlin", "per_line", name + ".per_line_end_time.csv.gz"))
    lines, ends = est.line_times()
    idx = np.searchsorted(lines, ref["source_line"].astype(np.int64))
    assert np.array_equal(lines[idx], ref["source_line"].astype(np.int64))
    assert np.max(np.abs(ends[idx] - ref["end_time_s"])) < 1e-8


def _model_rows(text, tmp_path, batch_moves=8192):
    p = tmp_path / "t.gcode"
    p.write_text(text)
    machine = load_machine("marlin-2.1.2")
    moves, reader = read_moves(str(p), machine, batch_moves=batch_moves)
    plan, model = run_marlin(moves, reader.limits, machine, keep_blocks=True,
                             e_position_sets=reader.interp.e_position_sets)
    oi = np.concatenate([x[0] for x in model.blocks])
    return moves, plan, oi


def test_single_move_trapezoid_by_hand(tmp_path):
    """G1 X10 F6000 from rest, 100 steps/mm, travel accel 1500 capped by X's 1000 mm/s²: 1000 steps,
    nominal 10000 steps/s, 100000 steps/s²; entry and exit at MINIMUM_PLANNER_SPEED give 5 steps/s, raised
    to the 120 steps/s floor; accelerate ceil((10000²−120²)/2e5) = 500 steps, brake floor(499.93) = 499,
    one step of cruise."""
    moves, plan, oi = _model_rows("G28\nG1 X10 F6000\n", tmp_path)
    row = oi[moves["kind"] != 4][0]
    assert row[mk.OI_SEC] == 1000 and row[mk.OI_NOMINAL_RATE] == 10000
    assert row[mk.OI_ACCEL_STEPS] == 100000
    assert row[mk.OI_INITIAL_RATE] == 120 and row[mk.OI_FINAL_RATE] == 120
    assert row[mk.OI_ACCEL_UNTIL] == 500 and row[mk.OI_DECEL_AFTER] == 501
    # the ideal trapezoid 1.2 -> 100 -> 1.2 mm/s at 1000 mm/s² takes 2·(98.8/1000) + (10 − 2·4.9993)/100 s;
    # the interrupt holds each rate for a whole step (the first, at 120 steps/s, for 8.3 ms), so its ramps
    # lag while accelerating and lead while braking: near the ideal, not on it
    ideal = 2 * 0.0988 + (10 - 2 * (100 ** 2 - 1.2 ** 2) / 2000) / 100
    total = plan["duration"].sum()
    assert total == pytest.approx(ideal, rel=0.05)


def test_moves_under_six_steps_merge_into_the_next(tmp_path):
    """MIN_STEPS_PER_SEGMENT: a 0.05 mm move (5 steps) makes no block; its steps go to the next move."""
    moves, plan, oi = _model_rows("G28\nG1 X0.05 F600\nG1 X1 F600\n", tmp_path)
    lines = list(moves["line"])
    tiny, nxt = oi[lines.index(2)], oi[lines.index(3)]
    assert tiny[mk.OI_HAS_BLOCK] == 0 and nxt[mk.OI_SEC] == 100
    assert plan["duration"][lines.index(2)] == 0.0


def test_streaming_in_small_batches_is_identical(tmp_path):
    """The model settles rows only when the firmware's buffer lets them go: any batch size, same plan."""
    src = shared_path("gcode", "prusaslicer25_cube20_marlin2.gcode").read_text()
    text = "\n".join(src.splitlines()[:1500]) + "\n"
    _, whole, _ = _model_rows(text, tmp_path)
    p = tmp_path / "s.gcode"
    p.write_text(text)
    machine = load_machine("marlin-2.1.2")
    pieces = []
    for piece in gp.pipeline.Run(str(p), machine, batch_moves=7):
        pieces.append(piece.plan)
    streamed = np.concatenate(pieces)
    for f in whole.dtype.names:
        assert np.array_equal(streamed[f], whole[f]), f


def test_firmware_key_option_and_errors(tmp_path):
    m = tmp_path / "m.toml"
    m.write_text('base = "marlin"\nfirmware = "marlin-2.1.2"\n')
    assert load_machine(str(m)).firmware == "marlin-2.1.2"
    m.write_text('base = "marlin"\nfirmware = "marlin-9"\n')
    with pytest.raises(ConfigError, match="firmware"):
        load_machine(str(m))
    assert load_machine("marlin").firmware == "marlin-2.1.2"     # issue 21: the preset is the Marlin 2.1.2 model
    g = tmp_path / "a.gcode"
    g.write_text("G28\nG1 X10 F6000\nG1 Y10\n")
    est = gp.estimate(str(g), gp.load_machine("marlin-2.1.2"))
    assert est.policy == "marlin-2.1.2"
    # an explicit other policy plans with that policy instead of the firmware model
    assert gp.estimate(str(g), gp.load_machine("marlin-2.1.2"), "klipper").policy == "klipper"
    with pytest.raises(ConfigError, match="jerk"):
        gp.estimate(str(g), gp.load_machine("marlin-2.1.2"), jerk=1000.0)


@pytest.mark.parametrize("name", FILES)
@pytest.mark.parametrize("variant", ["jd", "la", "scurve"])
def test_variant_builds_match_marlin(name, variant, tmp_path):
    """The reference's junction-deviation build (CLASSIC_JERK off, JD_HANDLE_SMALL_SEGMENTS with Marlin's acos
    table), linear-advance build (ADVANCE_K 0.05: its acceleration cap) and S_CURVE_ACCELERATION build (the
    Bézier ramps of the stepper interrupt): totals and per-line end times."""
    times = json.loads(shared_path("reference", "marlin", "variants", variant, "times.json").read_text())
    if variant == "la":
        m = tmp_path / "la.toml"
        m.write_text('base = "marlin-2.1.2"\n[extruder]\npressure_advance = 0.05\n')
        machine, policy = gp.load_machine(str(m)), None
    elif variant == "scurve":
        m = tmp_path / "scurve.toml"
        m.write_text('base = "marlin-2.1.2"\nacceleration_profile = "s-curve"\n')
        machine, policy = gp.load_machine(str(m)), None
    else:
        machine, policy = gp.load_machine("marlin-2.1.2"), "junction-deviation"
    est = gp.estimate(str(shared_path("gcode", name + ".gcode")), machine, policy)
    assert est.policy == "marlin-2.1.2"
    assert est.time.total_time_s == pytest.approx(times[name + ".gcode"]["total_time_s"], abs=1e-8)
    ref = _csv(shared_path("reference", "marlin", "variants", variant, "per_line",
                           name + ".per_line_end_time.csv.gz"))
    lines, ends = est.line_times()
    idx = np.searchsorted(lines, ref["source_line"].astype(np.int64))
    # la: the reference's extruder interrupt may issue a block's last E pulse up to 1 µs after its last X/Y step
    assert np.max(np.abs(ends[idx] - ref["end_time_s"])) < (2e-6 if variant == "la" else 1e-8)


def test_toolhead_line_by_line_equals_plan_for_the_firmware_model():
    """gp.Toolhead (the library's line-by-line door) hands G92 E to the model as the pipeline does: the same
    PLAN rows as gp.plan on the whole file."""
    path = shared_path("gcode", "prusaslicer25_cube20_marlin2.gcode")
    machine = gp.load_machine("marlin-2.1.2")
    ref = gp.plan(str(path), machine)
    th = gp.Toolhead(machine, block_lines=97)
    for line in path.read_text().splitlines(keepends=True):
        th.gcode(line)
    th.close()
    moves, plan = th.committed_arrays()
    for f in ("t_start", "duration", "start_v", "end_v"):
        assert np.array_equal(plan[f], ref.plan[f]), f


def test_absurd_numbers_are_errors_or_capped_never_negative_times():
    """tools/fuzz.py (seed 13): E1e20 crashed the model (ZeroDivisionError), Y1e308 gave a negative cruise
    time, F1e20 a negative duration. Positions beyond Marlin's int32 steps are an error naming the line; an
    absurd F is the axes' own limit, as an unlimited rapid."""
    import gcodeplan as gp
    from gcodeplan.errors import GcodeError

    m = gp.load_machine("marlin")
    with pytest.raises(GcodeError, match="beyond Marlin's reach") as err:
        gp.plan(["G1 X1 Y1 E1 F600", "G1 X125.258 Y113.634 E99999999999999999999"], m)
    assert err.value.line == 2
    # (the software endstops clamp the Y of 1e308 to 212.5: a move of 1e308 mm, as absurd)
    with pytest.raises(GcodeError, match="beyond Marlin's reach|has no finite length") as err:
        gp.plan(["G1 Z1.95 Y-1 E3.19 X213", "SET_KINEMATIC_POSITION X=0 Y=1e308 Z=0", "G1 X200 F6000"], m)
    assert err.value.line == 3
    p = gp.plan(["G1 X116.344 Y113.656 E5.62511 F1200", "G1 X133.656 Y96.344 E6.45378", "G1 Z7.95 F10800",
                 "G1 Z8.15 F99999999999999999999", "G1 X116.039 Y96.039", "G1 Z7.95"], m, policy="junction-deviation")
    for k in ("duration", "accel_t", "cruise_t", "decel_t"):
        assert p.plan[k].min() >= 0.0, k
    z_only = p.plan[(p.moves["z1"] != p.moves["z0"]) & (p.moves["x1"] == p.moves["x0"])]
    # Marlin rounds the nominal step rate up (ceil): a hair over M203 (12.002 mm/s), never the absurd F
    assert len(z_only) == 3 and z_only["cruise_v"].max() <= m.axes["z"].max_velocity * (1 + 1e-3)
