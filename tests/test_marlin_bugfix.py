"""The marlin-bugfix firmware model against Marlin bugfix-2.1.x's own planner.cpp / stepper.cpp (2024-07-30,
shared/reference/marlin/bugfix-2.1.x: every planner block as the stepper ran it, per-line end times, totals),
and hand-worked checks of each rule that changed since 2.1.2.4.

The cube's block and per-line files are vendored (tests/data/reference/marlin/bugfix-2.1.x, whole copies), so
a bare clone checks the cube; the cylinder needs ../shared. ``python tools/compare_marlin.py --machine
marlin-bugfix --reference bugfix-2.1.x`` prints the same agreement as a table.
"""
import csv
import gzip
import json

import numpy as np
import pytest

import gcodeplan as gp
from gcodeplan.config import load_machine
from gcodeplan.gcode.reader import read_moves
from gcodeplan.planner import marlin_kernels as mk
from gcodeplan.planner.marlin import run_marlin
from gcodeplan.stepper.marlin_isr import (MARLIN_TIMER_HZ, acceleration_rate, block_step_times_kernel_bugfix,
                                          block_ticks_kernel, block_ticks_kernel_bugfix)
from conftest import shared_path

CUBE = "prusaslicer25_cube20_marlin2"
CYLINDER = "cura413_ender3_cylinder30"
# the cylinder's files are only in ../shared (1.6 MB of blocks); its run takes longer
FILES = [CUBE, pytest.param(CYLINDER, marks=pytest.mark.slow)]
BLOCK_COLUMNS = [("step_event_count", mk.OI_SEC), ("nominal_rate", mk.OI_NOMINAL_RATE),
                 ("acceleration_steps_per_s2", mk.OI_ACCEL_STEPS), ("initial_rate", mk.OI_INITIAL_RATE),
                 ("final_rate", mk.OI_FINAL_RATE), ("accelerate_end", mk.OI_ACCEL_UNTIL),
                 ("decelerate_start", mk.OI_DECEL_AFTER), ("steps_x", mk.OI_SX), ("steps_y", mk.OI_SY),
                 ("steps_z", mk.OI_SZ), ("steps_e", mk.OI_SE)]


def _csv(path):
    with gzip.open(path, "rt", newline="") as fh:
        rows = list(csv.reader(fh))
    return {name: np.array([float(r[i]) for r in rows[1:]]) for i, name in enumerate(rows[0])}


def _blocks(name):
    b = _csv(shared_path("reference", "marlin", "bugfix-2.1.x", "blocks", name + ".blocks.csv.gz"))
    moving = b["sync"] == 0
    return {k: v[moving] for k, v in b.items()}


def _gcode(name):
    return str(shared_path("gcode", name + ".gcode"))


# ------------------------------------------------------------------------------------------- the reference


@pytest.mark.parametrize("name", FILES)
def test_bugfix_isr_times_every_reference_block_to_the_tick(name):
    """Given the trapezoid bugfix executed, its interrupt model's block time is the firmware's, tick for tick
    (25 MHz), for every block; 2.1.2's interrupt on the same blocks is not (its rate is read half a step
    earlier), so the test tells the two apart."""
    b = _blocks(name)
    ph = np.zeros(3, dtype=np.int64)
    ref_ticks = np.round((b["t_end_s"] - b["t_pick_s"]) * MARLIN_TIMER_HZ).astype(np.int64)
    args = [(int(b["step_event_count"][i]), int(b["initial_rate"][i]), int(b["nominal_rate"][i]),
             int(b["final_rate"][i]), int(b["accelerate_end"][i]), int(b["decelerate_start"][i]),
             acceleration_rate(int(b["acceleration_steps_per_s2"][i]))) for i in range(len(ref_ticks))]
    mine = np.array([block_ticks_kernel_bugfix(*a, MARLIN_TIMER_HZ, ph) for a in args])
    assert np.array_equal(mine, ref_ticks)
    old = np.array([block_ticks_kernel(*a, MARLIN_TIMER_HZ, ph) for a in args[:200]])
    assert np.count_nonzero(old != ref_ticks[:200]) > 100


def test_leading_axis_pulses_are_bugfixs_to_the_tick():
    """Every step pulse of the leading axis of the cube's blocks, as far as the reference stores pulses (all of
    Z, the first 200,000 of X, Y and E): the interrupt model's tick of each step equals the firmware's."""
    b = _blocks(CUBE)
    steps = np.load(shared_path("reference", "marlin", "bugfix-2.1.x", "steps", CUBE + "_steps.npz"))
    checked = 0
    for col, key in (("steps_z", "stepper_z"), ("steps_x", "stepper_x"), ("steps_y", "stepper_y"),
                     ("steps_e", "extruder")):
        ref = np.round(steps[key] * MARLIN_TIMER_HZ).astype(np.int64)
        for i in np.flatnonzero(b[col] == b["step_event_count"]):
            t_pick = int(round(b["t_pick_s"][i] * MARLIN_TIMER_HZ))
            t_end = int(round(b["t_end_s"][i] * MARLIN_TIMER_HZ))
            if t_end > ref[-1]:
                break                                   # past the stored pulses
            n = int(b["step_event_count"][i])
            out = np.zeros(n, dtype=np.int64)
            block_step_times_kernel_bugfix(n, int(b["initial_rate"][i]), int(b["nominal_rate"][i]),
                                           int(b["final_rate"][i]), int(b["accelerate_end"][i]),
                                           int(b["decelerate_start"][i]),
                                           acceleration_rate(int(b["acceleration_steps_per_s2"][i])),
                                           MARLIN_TIMER_HZ, t_pick, out)
            lo, hi = np.searchsorted(ref, [t_pick, t_end], side="right")
            assert np.array_equal(ref[lo:hi], out), (key, i)
            checked += n
    assert checked > 400000


@pytest.mark.parametrize("name", FILES)
def test_every_planner_block_is_bugfixs(name):
    """Step counts, nominal rate, acceleration, initial/final rate, step boundaries and pick-up time of every
    block equal bugfix's: its minimum speed, rounding, jerk rule and look-ahead all show here."""
    machine = load_machine("marlin-bugfix")
    moves, reader = read_moves(_gcode(name), machine)
    _, model = run_marlin(moves, reader.limits, machine, keep_blocks=True,
                          e_position_sets=reader.interp.e_position_sets)
    oi = np.concatenate([x[0] for x in model.blocks])
    lines = np.concatenate([x[2] for x in model.blocks])
    has = oi[:, mk.OI_HAS_BLOCK] == 1
    oi, lines = oi[has], lines[has]
    b = _blocks(name)
    assert len(oi) == len(b["seq"])
    assert np.array_equal(lines, b["source_line"].astype(np.int64))
    for col, o in BLOCK_COLUMNS:
        assert np.array_equal(oi[:, o], b[col].astype(np.int64)), col
    t_pick = np.round(b["t_pick_s"] * MARLIN_TIMER_HZ).astype(np.int64)
    assert np.array_equal(oi[:, mk.OI_T_PICK], t_pick)
    # the entry speed the planner gave each block (mm²/s², float32 as the firmware prints it to 9 digits)
    entry = np.concatenate([x[1] for x in model.blocks])[:, mk.OF_ENTRY_SQR][has]
    assert np.allclose(entry, b["entry_speed_sqr"], rtol=1e-6, atol=0)


@pytest.mark.parametrize("name", FILES)
def test_estimate_total_and_line_times_match_bugfix(name):
    """Through the pipeline (``--machine marlin-bugfix``): the total and every per-line end time equal
    bugfix-2.1.x's (whole 40 ns ticks, printed to 10 ns), 2.5 % away from 2.1.2.4's."""
    times = json.loads(shared_path("reference", "marlin", "times.json").read_text())[name + ".gcode"]
    est = gp.estimate(_gcode(name), gp.load_machine("marlin-bugfix"))
    assert est.policy == "marlin-bugfix"
    assert est.time.total_time_s == pytest.approx(times["bugfix-2.1.x"]["total_time_s"], abs=1e-8)
    assert abs(est.time.total_time_s - times["marlin-2.1.2.4"]["total_time_s"]) > 25.0
    ref = _csv(shared_path("reference", "marlin", "bugfix-2.1.x", "per_line", name + ".per_line_end_time.csv.gz"))
    lines, ends = est.line_times()
    idx = np.searchsorted(lines, ref["source_line"].astype(np.int64))
    assert np.array_equal(lines[idx], ref["source_line"].astype(np.int64))
    assert np.max(np.abs(ends[idx] - ref["end_time_s"])) < 1e-8


# ------------------------------------------------------------------------------------------ selection


def test_firmware_is_selectable_by_toml_option_library_and_preset(tmp_path, capsys):
    """``firmware = "marlin-bugfix"`` in a machine TOML, ``--firmware marlin-bugfix``, load_machine(firmware=)
    and the preset all run the bugfix model, and the summary names it; an unknown name is an error."""
    from gcodeplan.cli import main
    from gcodeplan.errors import ConfigError

    m = tmp_path / "m.toml"
    m.write_text('base = "marlin"\nfirmware = "marlin-bugfix"\n')
    assert load_machine(str(m)).firmware == "marlin-bugfix"
    preset = load_machine("marlin-bugfix")
    assert preset.firmware == "marlin-bugfix"
    # the preset is the "marlin" machine on bugfix's rules
    base = load_machine("marlin")
    assert preset.axes == base.axes and preset.accel_print == base.accel_print
    assert gp.load_machine("marlin", firmware="marlin-bugfix").firmware == "marlin-bugfix"
    with pytest.raises(ConfigError, match="firmware"):
        gp.load_machine("marlin", firmware="marlin-bugfixx")
    g = tmp_path / "a.gcode"
    g.write_text("G28\nG1 X20 F6000\nG1 X0\n")
    e_bug = gp.estimate(str(g), gp.load_machine("marlin", firmware="marlin-bugfix"))
    e_old = gp.estimate(str(g), gp.load_machine("marlin"))
    assert e_bug.policy == "marlin-bugfix" and e_old.policy == "marlin-2.1.2"
    assert e_bug.time.total_time_s != e_old.time.total_time_s
    capsys.readouterr()
    assert main(["estimate", str(g), "--machine", "marlin", "--firmware", "marlin-bugfix"]) in (0, None)
    assert "firmware marlin-bugfix" in capsys.readouterr().out


# ------------------------------------------------------------------------------- hand-worked rules


def _model_blocks(text, tmp_path, firmware):
    p = tmp_path / "t.gcode"
    p.write_text(text)
    machine = load_machine("marlin-bugfix" if firmware == "marlin-bugfix" else "marlin-2.1.2")
    moves, reader = read_moves(str(p), machine)
    plan, model = run_marlin(moves, reader.limits, machine, keep_blocks=True,
                             e_position_sets=reader.interp.e_position_sets)
    oi = np.concatenate([x[0] for x in model.blocks])
    of = np.concatenate([x[1] for x in model.blocks])
    has = oi[:, mk.OI_HAS_BLOCK] == 1
    return oi[has], of[has], plan


def test_start_stop_rate_is_sqrt_half_the_acceleration(tmp_path):
    """G1 X10 F6000 from rest: 1000 steps, nominal 10000 steps/s, 100000 steps/s² (travel 1500 capped by X's
    1000 mm/s²). bugfix starts and stops at v² = a / (2 · steps/mm) = 1000 / 200 = 5 mm²/s², i.e. √(a/2) =
    √50000 = 223.6 → 224 steps/s (2.1.2: 0.05 mm/s = 5 steps/s, floored to 120). Both ramps rounded up:
    ceil((10000² − 224²) / 200000) = ceil(499.75) = 500 each, so no cruise step (2.1.2: 500 and
    floor(499.93) = 499, one cruise step)."""
    bug, of, _ = _model_blocks("G28\nG1 X10 F6000\n", tmp_path, "marlin-bugfix")
    old, _, _ = _model_blocks("G28\nG1 X10 F6000\n", tmp_path, "marlin-2.1.2")
    assert bug[0, mk.OI_SEC] == 1000 and bug[0, mk.OI_NOMINAL_RATE] == 10000 and bug[0, mk.OI_ACCEL_STEPS] == 100000
    assert bug[0, mk.OI_INITIAL_RATE] == 224 and bug[0, mk.OI_FINAL_RATE] == 224
    assert of[0, mk.OF_ENTRY_SQR] == pytest.approx(5.0, rel=1e-6)
    assert bug[0, mk.OI_ACCEL_UNTIL] == 500 and bug[0, mk.OI_DECEL_AFTER] == 500
    assert old[0, mk.OI_INITIAL_RATE] == 120 and old[0, mk.OI_ACCEL_UNTIL] == 500 and old[0, mk.OI_DECEL_AFTER] == 501
    # a Z move at Z's 200 mm/s² and 400 steps/mm: v² = 200 / 800 = 0.25, 0.5 mm/s, √(80000/2) = 200 steps/s
    z, of, _ = _model_blocks("G28\nG1 Z0.2 F720\n", tmp_path, "marlin-bugfix")
    assert z[0, mk.OI_ACCEL_STEPS] == 80000 and z[0, mk.OI_INITIAL_RATE] == 200 and z[0, mk.OI_FINAL_RATE] == 200


def _one_block(sec, nominal_rate, accel, spmm):
    bf, bi, gi, gf = mk.new_state()
    bi[0, mk.BI_SEC] = sec
    bi[0, mk.BI_NOMINAL_RATE] = nominal_rate
    bi[0, mk.BI_ACCEL_STEPS] = accel
    bf[0, mk.BF_STEPS_PER_MM] = spmm
    return bf, bi


def test_trapezoid_rates_round_to_nearest_and_the_ramps_meet_at_the_rounded_midpoint():
    """The cube's first block (80 Z steps at 400 steps/mm, nominal 4800 steps/s, 80000 steps/s²) entering at
    0.5 mm/s and leaving at √5 mm/s: rates 0.5 · 400 = 200 and 2.2360680 · 400 = 894.43 → 894 (to nearest;
    2.1.2 rounds up). Ramps to and from nominal: (4800² − 200²) / 160000 = 143.75 and (4800² − 894²) / 160000
    = 139.00 steps, more than 80: no cruise; they meet at (80 + 143.75 − 139.00) / 2 = 42.37 → 42 (to
    nearest; 2.1.2 rounds up), and the braking takes the other 38."""
    bf, bi = _one_block(80, 4800, 80000, 400.0)
    mk.calculate_trapezoid_for_block_bugfix(bf, bi, 0, np.float32(0.5), np.float32(np.sqrt(np.float32(5.0))))
    assert bi[0, mk.BI_INITIAL_RATE] == 200 and bi[0, mk.BI_FINAL_RATE] == 894
    assert bi[0, mk.BI_ACCEL_UNTIL] == 42 and bi[0, mk.BI_DECEL_AFTER] == 42
    # 2.1.2.4 on the same block, speeds as fractions of a nominal 12 mm/s: 894.43 → 895, meeting point 43
    bi[0, mk.BI_FLAG] = 0
    mk.calculate_trapezoid_for_block(bf, bi, 0, np.float32(0.5 / 12), np.float32(np.sqrt(5.0) / 12))
    assert bi[0, mk.BI_FINAL_RATE] == 895 and bi[0, mk.BI_ACCEL_UNTIL] == 43
    # a cruise: braking rounded up. 2000 steps at 100 steps/mm, nominal 2000, 80000 steps/s², 8 → 2.236 mm/s:
    # accelerate (2000² − 800²) / 160000 = 21.0 → 21; brake (2000² − 224²) / 160000 = 24.686 → 25 (2.1.2: 24)
    bf, bi = _one_block(2000, 2000, 80000, 100.0)
    mk.calculate_trapezoid_for_block_bugfix(bf, bi, 0, np.float32(8.0), np.float32(np.sqrt(np.float32(5.0))))
    assert bi[0, mk.BI_INITIAL_RATE] == 800 and bi[0, mk.BI_FINAL_RATE] == 224
    assert bi[0, mk.BI_ACCEL_UNTIL] == 21 and bi[0, mk.BI_DECEL_AFTER] == 2000 - 25
    # an entry speed of 0 keeps the block's initial rate (the block behind a running one)
    bi[0, mk.BI_INITIAL_RATE] = 777
    mk.calculate_trapezoid_for_block_bugfix(bf, bi, 0, np.float32(0.0), np.float32(2.0))
    assert bi[0, mk.BI_INITIAL_RATE] == 777 and bi[0, mk.BI_FINAL_RATE] == 200


def test_isr_reads_the_rate_half_an_interval_in():
    """Two steps from 200 steps/s, accelerating at 80000 steps/s² (acceleration_rate = ⌊80000 · 2²⁴ / 25e6⌋ =
    53687): the first interval is 25e6 / 200 = 125000 ticks. bugfix starts its acceleration clock at half of
    it, 62500: rate 200 + (62500 · 53687 + 2²³) >> 24 = 200 + 200 = 400 steps/s, a 62500-tick second interval,
    187500 in all. 2.1.2 counts the whole first interval: 200 + 400 = 600 steps/s, 41666 ticks, 166666."""
    ar = acceleration_rate(80000)
    assert ar == 53687
    ph = np.zeros(3, dtype=np.int64)
    assert block_ticks_kernel_bugfix(2, 200, 4800, 200, 2, 2, ar, MARLIN_TIMER_HZ, ph) == 187500
    assert block_ticks_kernel(2, 200, 4800, 200, 1, 1, ar, MARLIN_TIMER_HZ, ph) == 166666
    # braking after a cruise starts its clock at half the cruise interval: 4 steps at 1000 steps/s, braking
    # from the 4th: intervals 25000 (pick-up), 25000, 25000 (cruise), then 1000 − (12500 · 53687 + 2²³) >> 24
    # = 1000 − 40 = 960 steps/s, 26041 ticks
    assert block_ticks_kernel_bugfix(4, 1000, 1000, 200, 0, 3, ar, MARLIN_TIMER_HZ, ph) == 3 * 25000 + 26041
    assert list(ph) == [25000, 50000, 26041]


def test_classic_jerk_of_a_reversal_is_the_whole_speed_change(tmp_path):
    """G1 X20 then back to X0 at 100 mm/s, X jerk 8 mm/s: bugfix's jerk is the speed difference, 100 − (−100)
    = 200 mm/s, so the junction is 100 · 8 / 200 = 4 mm/s: the first block ends at 4 · 100 = 400 steps/s and
    the second starts there. 2.1.2 (Průša's rule) takes a reversal's jerk as max(100, 100) and allows 8 mm/s:
    800 steps/s."""
    text = "G28\nG1 X20 F6000\nG1 X0\n"
    bug, of, _ = _model_blocks(text, tmp_path, "marlin-bugfix")
    old, _, _ = _model_blocks(text, tmp_path, "marlin-2.1.2")
    assert bug[0, mk.OI_FINAL_RATE] == 400 and bug[1, mk.OI_INITIAL_RATE] == 400
    assert of[1, mk.OF_ENTRY_SQR] == pytest.approx(16.0, rel=1e-6)
    assert old[0, mk.OI_FINAL_RATE] == 800 and old[1, mk.OI_INITIAL_RATE] == 800
    # a right angle, 100 mm/s then 50 mm/s: the faster move's speeds scaled to 50, differences (−50, 50),
    # limited to 8 / 50: 8 mm/s, both versions
    gf = np.zeros(mk.N_GF, dtype=np.float32)
    gf[mk.GF_PREV_SPEED] = 100.0
    gf[mk.GF_PREV_NOMINAL] = 100.0
    jerk = np.array([8.0, 8.0, 0.4, 4.5], dtype=np.float32)
    cur = np.array([0.0, 50.0, 0.0, 0.0], dtype=np.float32)
    v2 = mk._classic_jerk_sqr_bugfix(gf, cur, np.float32(50.0), 3, jerk, np.zeros((4, 4), np.float32))
    assert v2 == pytest.approx(64.0, rel=1e-6)
    # from rest (nothing queued): the jerk is the move's own axis speeds, 50 → 8 mm/s
    v2 = mk._classic_jerk_sqr_bugfix(gf, cur, np.float32(50.0), 0, jerk, np.zeros((4, 4), np.float32))
    assert v2 == pytest.approx(64.0, rel=1e-6)


def test_forward_pass_keeps_the_entry_at_or_above_the_minimum():
    """A block whose predecessor cannot accelerate to its entry speed is lowered to what the predecessor
    reaches, v² = u² + 2·a·d, but not below its own minimum; the result becomes its minimum and maximum."""
    bf, bi, gi, gf = mk.new_state()
    bf[0, mk.BF_ENTRY_SQR], bf[0, mk.BF_ACCEL], bf[0, mk.BF_MM] = 5.0, 1000.0, 0.01
    bf[1, mk.BF_ENTRY_SQR], bf[1, mk.BF_MIN_ENTRY_SQR], bf[1, mk.BF_MAX_ENTRY_SQR] = 400.0, 30.0, 400.0
    mk.forward_pass_kernel_bugfix(bf, bi, 0, 1)        # 5 + 2 · 1000 · 0.01 = 25 < 30: held at 30
    assert bf[1, mk.BF_ENTRY_SQR] == pytest.approx(30.0) and bf[1, mk.BF_MAX_ENTRY_SQR] == pytest.approx(30.0)
    bf[0, mk.BF_MM] = 0.1
    bf[1, mk.BF_ENTRY_SQR], bf[1, mk.BF_MIN_ENTRY_SQR], bf[1, mk.BF_MAX_ENTRY_SQR] = 400.0, 5.0, 400.0
    mk.forward_pass_kernel_bugfix(bf, bi, 0, 1)        # 5 + 200 = 205
    assert bf[1, mk.BF_ENTRY_SQR] == pytest.approx(205.0) and bf[1, mk.BF_MIN_ENTRY_SQR] == pytest.approx(205.0)


def test_scurve_is_refused_for_bugfix(tmp_path):
    """No reference covers bugfix's S-curve interrupt: asking for it is an error, not a 2.1.2 answer."""
    from gcodeplan.errors import ConfigError

    m = tmp_path / "s.toml"
    m.write_text('base = "marlin-bugfix"\nacceleration_profile = "s-curve"\n')
    with pytest.raises(ConfigError, match="S-curve"):
        gp.estimate(["G28", "G1 X10 F6000"], gp.load_machine(str(m)))


def test_streaming_in_small_batches_is_identical(tmp_path):
    """The bugfix model settles rows only when the firmware's buffer lets them go: batches of 7 rows give the
    same PLAN rows as the whole file."""
    src = shared_path("gcode", CUBE + ".gcode").read_text()
    p = tmp_path / "s.gcode"
    p.write_text("\n".join(src.splitlines()[:1500]) + "\n")
    machine = load_machine("marlin-bugfix")
    whole = gp.plan(str(p), machine).plan
    streamed = np.concatenate([piece.plan for piece in gp.pipeline.Run(str(p), machine, batch_moves=7)])
    for f in whole.dtype.names:
        assert np.array_equal(streamed[f], whole[f]), f
