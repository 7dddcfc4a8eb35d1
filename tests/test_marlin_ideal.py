"""Issue 21's proof for the Marlin model: with an unbounded buffer and no quantisation
(``MarlinModel(..., buffer_blocks=None, quantised=False)``) it gives the ideal look-ahead plan back.

The truth is a planner written here in plain float64 (:func:`_ideal_plan`): per move its length, nominal speed
and acceleration from the MOVE row and the machine's limits, then the textbook full look-ahead (backward
v_entry² ≤ v_exit² + 2·a·d, forward v_entry² ≤ v_prev² + 2·a·d) and each trapezoid's time in closed form. The
junction caps are Marlin's classic-jerk rule (Průša's safe speed, coasting and reversal cases): a copy here would
only copy the kernel, so they are taken from the model's own block output (``OT_MAX_ENTRY_SQR``); one of them,
a 90° corner, is checked against its hand-worked value. Marlin's plan that is not quantisation stays in both: a
block queued behind an empty buffer and the newest block start / end at MINIMUM_PLANNER_SPEED (0.05 mm/s).
"""
from __future__ import annotations

import math
from collections import deque

import numpy as np
import pytest

from conftest import SAMPLES, shared_path
from gcodeplan.config import load_machine
from gcodeplan.errors import ConfigError
from gcodeplan.gcode.reader import read_moves
from gcodeplan.planner import marlin_ideal as mi
from gcodeplan.planner import marlin_kernels as mk
from gcodeplan.planner.marlin import MarlinModel, run_marlin
from gcodeplan.schema import KIND_DWELL, KIND_WAIT

MIN_SQR = 0.05 ** 2                      # planner.cpp MINIMUM_PLANNER_SPEED, squared
CUBE = "prusaslicer25_cube20_marlin2"
# corners (90°, acute), a reversal, moves of a few µm to 0.1 mm, a long straight at the axes' speed limit, E-only
# retract / unretract, a Z move (its own M203 / M201 limits) and a G92 E
HAND = """M204 P1000 T1500 R1200
G92 E0
G1 X10 Y10 F6000
G1 X60 Y10 F9000
G1 X60 Y40
G1 X20 Y40 E2 F3000
G1 X50 Y40 E3 F4000
G1 X50.05 Y40.02 E3.01
G1 X50.1 Y40.0 E3.02
G1 X50.1 Y40.004 E3.021
G1 X20 Y20 E4
G1 E3.2 F2400
G1 X200 Y180 F12000
G1 E4 F2400
G1 Z0.4 F600
G92 E0
G1 X10 Y150 E8 F1800
G1 X12 Y150.5 E8.1
G1 X10 Y151 E8.2
G1 X10 Y10 F20000
"""


def _read(path, machine):
    moves, reader = read_moves(str(path), machine)
    sets = reader.interp.e_position_sets
    return moves, reader.limits, (deque(sets) if sets is not None else None)


def _run(path, machine, **kw):
    """MOVE rows, LIMITS, PLAN rows, per-row end times (s) and the per-row block outputs of the model on ``path``
    (quantised: ``oi``, with ``of`` as ``_run.of``; else ``out_t``)."""
    moves, limits, sets = _read(path, machine)
    plan, model = run_marlin(moves, limits, machine, keep_blocks=True, e_position_sets=sets, **kw)
    out = np.concatenate([b[0] for b in model.blocks])
    _run.of = np.concatenate([b[1] for b in model.blocks]) if model.quantised else None
    return moves, limits, plan, plan["t_start"] + plan["duration"], out


def _trapezoid_t(v0_sqr, v1_sqr, vc, a, d):
    """Closed-form time (s) of a trapezoid from v0 to v1 (squares, mm²/s²) under vc over d mm at a mm/s²."""
    v0, v1 = math.sqrt(v0_sqr), math.sqrt(v1_sqr)
    vc = max(vc, v0, v1)
    d_acc, d_dec = (vc * vc - v0_sqr) / (2 * a), (vc * vc - v1_sqr) / (2 * a)
    if d_acc + d_dec <= d:
        return (vc - v0) / a + (d - d_acc - d_dec) / vc + (vc - v1) / a
    vp = math.sqrt((v0_sqr + v1_sqr) / 2 + a * d)
    return (vp - v0) / a + (vp - v1) / a


def _block(row, lim):
    """Length (mm), nominal speed (mm/s) and acceleration (mm/s²) of a MOVE row, None when nothing moves: the
    feed within the minimum feed and each axis' M203 speed; the row's M204 class accel within each axis' M201."""
    d = [float(row[ax + "1"] - row[ax + "0"]) for ax in "xyze"]
    if not any(d):
        return None
    mm = math.sqrt(d[0] ** 2 + d[1] ** 2 + d[2] ** 2) or abs(d[3])
    v = max(float(row["feed_v"]), float(lim["min_feed_v"] if d[3] else lim["min_travel_v"]))
    a = float(row["accel"])
    for k, ax in enumerate("xyze"):
        if d[k]:
            v = min(v, float(lim["axis_v_" + ax]) * mm / abs(d[k]))
            a = min(a, float(lim["axis_a_" + ax]) * mm / abs(d[k]))
    return mm, v, a


def _ideal_plan(moves, limits, caps):
    """Per-row end times (s) of the full look-ahead plan: each stretch between waits is planned at once, its first
    block from MINIMUM_PLANNER_SPEED, its last to it; a wait lasts its dwell once motion has started; a row
    without a block ends where the row before it did. ``caps`` (per row, mm²/s²): the junction caps."""
    ends = np.full(len(moves), np.nan)
    clock, stretch = 0.0, []

    def run(stretch, clock):
        e = [MIN_SQR] * (len(stretch) + 1)                    # entries, then the last block's exit
        for i in range(len(stretch) - 1, 0, -1):              # backward; block 0 keeps its entry
            mm, _, a = stretch[i][1]
            e[i] = min(caps[stretch[i][0]], e[i + 1] + 2 * a * mm)
        for i in range(1, len(stretch)):                       # forward
            mm, _, a = stretch[i - 1][1]
            e[i] = min(e[i], e[i - 1] + 2 * a * mm)
        for i, (r, (mm, v, a)) in enumerate(stretch):
            clock += _trapezoid_t(e[i], e[i + 1], v, a, mm)
            ends[r] = clock
        return clock

    started = False
    for r in range(len(moves)):
        row = moves[r]
        if row["kind"] in (KIND_WAIT, KIND_DWELL):
            clock = run(stretch, clock)
            started = started or bool(stretch)
            stretch = []
            if started and not math.isnan(row["dwell_t"]):
                clock += float(row["dwell_t"])
            ends[r] = clock
            continue
        b = _block(row, limits[row["limits"]])
        if b is not None:
            stretch.append((r, b))
    run(stretch, clock)
    last = 0.0
    for r in range(len(moves)):
        if math.isnan(ends[r]):
            ends[r] = last
        last = ends[r]
    return ends


def _check_ideal(path, machine, **kw):
    moves, limits, plan, ends, out = _run(path, machine, buffer_blocks=None, quantised=False, **kw)
    assert np.all(out[:, mi.OT_HAS] >= 0)
    truth = _ideal_plan(moves, limits, out[:, mi.OT_MAX_ENTRY_SQR])
    assert truth[-1] > 0
    np.testing.assert_allclose(ends, truth, rtol=1e-9, atol=1e-12)
    return moves, out, ends


def test_hand_made_program_is_the_full_lookahead_plan(tmp_path):
    """Corners, a reversal, µm-short moves, a long straight, E-only moves and a Z move: with an unbounded buffer and
    no quantisation every row's end time and the total are the float64 full look-ahead's, within 1e-9 relative.
    The 90° corner at 150 mm/s (line 5) is capped at the axes' 8 mm/s jerk: both moves' Průša safe speed is 8 mm/s
    (one axis from 150 to 0 within 8), above 0.99 of the jerk-scaled junction speed 150 · 8/150, so 8² mm²/s²."""
    path = tmp_path / "hand.gcode"
    path.write_text(HAND)
    machine = load_machine("marlin-2.1.2")
    moves, out, ends = _check_ideal(path, machine)
    out_cj = out
    corner = np.nonzero(moves["line"] == 5)[0][0]
    assert out[corner, mi.OT_MAX_ENTRY_SQR] == pytest.approx(64.0, rel=1e-6)
    # the µm move (line 10: 4 µm of Y, under Marlin's 6 steps) is a block of its own here
    assert out[np.nonzero(moves["line"] == 10)[0][0], mi.OT_HAS] == 1
    # junction deviation's caps (0.013 mm; its small-segment arc rule at the sharp short corners) go through too
    moves, out, _ = _check_ideal(path, machine, junction="junction-deviation")
    assert not np.array_equal(out[:, mi.OT_MAX_ENTRY_SQR], out_cj[:, mi.OT_MAX_ENTRY_SQR])


@pytest.mark.parametrize("name", ["d_slicer_like.gcode", "c_circle200.gcode"])
def test_sample_files_are_the_full_lookahead_plan(name):
    """The slicer-like sample (retracts, z-hop, G2 arc as Marlin segments it, 180 lines) and the 200-segment
    circle: every line's end time within 1e-9 relative of the float64 full look-ahead plan."""
    _check_ideal(SAMPLES / name, load_machine("marlin-2.1.2"))


def test_cube_is_the_full_lookahead_plan():
    """The 20 mm cube as PrusaSlicer wrote it (7,718 lines, its waits for heating included): the same."""
    _check_ideal(shared_path("gcode", CUBE + ".gcode"), load_machine("marlin-2.1.2"))


def test_hand_worked_single_move(tmp_path):
    """G1 X100 F6000 at 1000 mm/s²: Marlin's plan starts and ends at MINIMUM_PLANNER_SPEED v_m = 0.05 mm/s, so
    2 · (100 − 0.05) / 1000 + (100 − (100² − 0.05²) / 1000) / 100 = 0.1999 + 0.900000025 = 1.099900025 s (from
    rest to rest it would be 1.1 s). Quantised, the 120 steps/s floor (1.2 mm/s at 100 steps/mm) starts and ends
    faster: the same trapezoid from 1.2 mm/s takes 0.1976 + 0.9000144 = 1.0976144 s; the interrupt times each step
    at the rate at its start, which on a ramp drifts by less than one step period at the ramp's slow end
    (telescoping 1/r_k − 1/r_{k+1}), so within 2 / 120 s of it."""
    path = tmp_path / "one.gcode"
    path.write_text("M204 P1000 T1000 R1000\nG1 X100 F6000\n")
    machine = load_machine("marlin-2.1.2")
    for junction in ("classic-jerk", "junction-deviation"):
        for buffer_blocks in (16, None):
            *_, ends, _ = _run(path, machine, junction=junction, buffer_blocks=buffer_blocks, quantised=False)
            assert ends[-1] == pytest.approx(1.099900025, rel=1e-12)
    *_, ends, _ = _run(path, machine)
    floor_t = 2 * (100 - 1.2) / 1000 + (100 - (100 ** 2 - 1.2 ** 2) / 1000) / 100
    assert floor_t == pytest.approx(1.0976144, rel=1e-12)
    assert abs(ends[-1] - floor_t) <= 2 / 120
    assert ends[-1] < 1.099900025            # the floor only ever shortens it here


def _totals(path, machine, quantised, sizes=(4, 8, 16, 64, None)):
    res = {}
    for n in sizes:
        *_, plan, ends, out = _run(path, machine, buffer_blocks=n, quantised=quantised)
        res[n] = (ends[-1], plan, out)
    return res


@pytest.mark.parametrize("path", [SAMPLES / "d_slicer_like.gcode", SAMPLES / "e_spiral20k.gcode", None])
def test_a_longer_buffer_is_never_slower_without_quantisation(path, monkeypatch):
    """Look-ahead can only be conservative. With SLOWDOWN off (MIN_SEGMENT_TIME 0), for 4, 8, 16, 64 blocks and
    unbounded every block's entry speed is at most the unbounded buffer's and the totals never increase with the
    buffer (the cube: 1149.73 s with 4 blocks, 1144.546858 s from 8 up). From 8 blocks up the junction caps are
    the unbounded buffer's; with 4, the cube's park move (line 7440) comes after a G92 E0 whose sync block took a
    slot: the stepper skips it and leaves no block queued, so Marlin caps the junction as a start from rest
    (0.4² instead of 12² mm²/s²), as the firmware would."""
    from gcodeplan.planner import marlin

    monkeypatch.setattr(marlin, "MIN_SEGMENT_TIME_US", 0)
    path = path or shared_path("gcode", CUBE + ".gcode")
    res = _totals(path, load_machine("marlin-2.1.2"), quantised=False)
    inf_plan, inf_out = res[None][1], res[None][2]
    has = inf_out[:, mi.OT_HAS] == 1
    prev = math.inf
    for n in (4, 8, 16, 64, None):
        total, plan, out = res[n]
        assert np.array_equal(out[:, mi.OT_HAS] == 1, has)
        if n != 4:
            assert np.array_equal(out[has, mi.OT_MAX_ENTRY_SQR], inf_out[has, mi.OT_MAX_ENTRY_SQR])
        assert np.all(plan["start_v"][has] <= inf_plan["start_v"][has] * (1 + 1e-12))
        assert total <= prev * (1 + 1e-12)
        prev = total
    assert res[4][0] > res[None][0]


def test_slowdown_makes_a_longer_buffer_slower():
    """With Marlin's SLOWDOWN (the default) a longer buffer is not always faster: SLOWDOWN slows a segment under
    MIN_SEGMENT_TIME (20 ms) while 2 … N/2 − 1 blocks are queued, a window that grows with the buffer N (none for
    an unbounded one, which never runs low). On the slicer-like sample, after the first moves the 0.9 mm move of
    line 21 (18 ms at F3000) is slowed with 64 blocks, not with 16; its lower nominal speed lowers its float32
    junction cap by an ulp (8 mm/s → 7.9999995): 64 blocks take 0.75 ns longer than 16. What holds: every total is
    at least the unbounded buffer's, and every entry speed at most its (within float32's 1e-6)."""
    res = _totals(SAMPLES / "d_slicer_like.gcode", load_machine("marlin-2.1.2"), quantised=False)
    assert res[64][0] > res[16][0]
    assert res[64][0] - res[16][0] < 1e-9
    inf_plan = res[None][1]
    has = res[None][2][:, mi.OT_HAS] == 1
    for n in (4, 8, 16, 64):
        assert res[n][0] >= res[None][0] * (1 - 1e-12)
        assert np.all(res[n][1]["start_v"][has] <= inf_plan["start_v"][has] * (1 + 1e-6))


def test_a_longer_buffer_quantised_within_rounding():
    """Quantised, the same holds up to the firmware's rounding. SLOWDOWN's window grows with the buffer, and a
    block it slows gets its entry rate rounded up from another nominal rate: on the cube two 0.2 mm moves (lines
    43, 45) enter at 161 instead of 160 steps/s with 64 blocks, so 64 blocks (1130.8952309 s) are 34 µs faster
    than unbounded (1130.8952652 s). Each total is within 1e-6 relative of the shorter buffer's or below it, and
    4 blocks are clearly slower than 16."""
    res = _totals(shared_path("gcode", CUBE + ".gcode"), load_machine("marlin-2.1.2"), quantised=True)
    sizes = (4, 8, 16, 64, None)
    for a, b in zip(sizes, sizes[1:]):
        assert res[b][0] <= res[a][0] * (1 + 1e-6)
    assert res[16][0] == pytest.approx(1130.89526516, abs=1e-6)      # the default: the firmware's own total
    assert res[4][0] > res[16][0] + 1.0


def test_quantised_against_continuous_on_the_cube():
    """The quantised and the continuous model at 16 blocks: the continuous one is slower (the floor and the
    interrupt only ever shorten), by less than a bound summed over the quantised blocks from where each
    difference comes from: per ramp, the interrupt's drift (under one step period at its slow end: 1/initial +
    1/final rate) and the 120 steps/s floor (raising a ramp's end speed to v_f saves at most v_f / a); per block,
    whole-step boundaries (a step each side: 2 / nominal rate) and the nominal rate rounded up (its time / nominal
    rate); and the rows Marlin merges (under 6 steps) at their continuous time."""
    machine = load_machine("marlin-2.1.2")
    path = shared_path("gcode", CUBE + ".gcode")
    *_, ends_q, oi = _run(path, machine)
    of = _run.of
    *_, ends_i, out = _run(path, machine, quantised=False)
    has = oi[:, mk.OI_HAS_BLOCK] == 1
    b = oi[has]
    steps_per_mm = b[:, mk.OI_SEC] / of[has, mk.OF_MM].astype(np.float64)
    accel = b[:, mk.OI_ACCEL_STEPS] / steps_per_mm
    dur = (b[:, mk.OI_T_END] - b[:, mk.OI_T_PICK]) / 25e6
    merged = ~has & (out[:, mi.OT_HAS] == 1)
    bound = ((1 / b[:, mk.OI_INITIAL_RATE] + 1 / b[:, mk.OI_FINAL_RATE]).sum()
             + (2 * 120 / steps_per_mm / accel).sum() + (2 / b[:, mk.OI_NOMINAL_RATE]).sum()
             + (dur / b[:, mk.OI_NOMINAL_RATE]).sum() + (out[merged, mi.OT_T_END] - out[merged, mi.OT_T_PICK]).sum())
    diff = ends_i[-1] - ends_q[-1]
    assert 0 < diff < bound
    assert bound < 0.05 * ends_q[-1]          # the bound says something: under 5 % of the total


def test_batches_give_the_whole_programs_rows():
    """Fed in batches of 7 rows (the window's buffers shift after each; an unbounded ring grows between them), the
    model's PLAN rows are those of the program fed at once, quantised or not, for 4, 16 and unbounded buffers."""
    machine = load_machine("marlin-2.1.2")
    moves, limits, sets = _read(SAMPLES / "d_slicer_like.gcode", machine)
    for n, q in [(None, False), (16, False), (4, False), (None, True), (4, True)]:
        whole, _ = run_marlin(moves, limits, machine, e_position_sets=deque(sets or ()), buffer_blocks=n,
                              quantised=q)
        m = MarlinModel(machine, e_position_sets=deque(sets or ()), buffer_blocks=n, quantised=q)
        outs = []
        for i in range(0, len(moves), 7):
            outs += m.feed(moves[i:i + 7], limits)
        outs += m.finish()
        got = np.concatenate([p for _, p in outs])
        for f in whole.dtype.names:
            assert np.array_equal(got[f], whole[f]), f


def test_bad_settings_are_named_errors():
    """A ring that is not a power of 2 (Marlin's SanityCheck.h), and the modes the switch does not cover."""
    machine = load_machine("marlin-2.1.2")
    for bad in (0, 1, 12, 2.5, 16.0, True, "16"):
        with pytest.raises(ConfigError, match="power of 2"):
            MarlinModel(machine, buffer_blocks=bad)
    assert MarlinModel(machine, buffer_blocks=math.inf).buffer_blocks is None
    with pytest.raises(ConfigError, match="quantised=False"):
        MarlinModel(load_machine("marlin-bugfix"), quantised=False)
    m = MarlinModel(machine, quantised=False)
    m.want_steps = True
    moves, limits, _ = _read(SAMPLES / "c_circle200.gcode", machine)
    with pytest.raises(ConfigError, match="step pulses"):
        m.feed(moves, limits)
        m.finish()


def test_corexy_diagonal_is_limited_per_motor(tmp_path):
    """CoreXY: G1 X100 Y100 turns motor A by 200 mm (A = X + Y) and B not at all, so the head's 141.42 mm run at
    most at 200 mm/s · 141.42 / 200 = 100√2 mm/s (motor A's M203) and 1000 mm/s² · 141.42 / 200 = 500√2 mm/s² (its
    M201): the closed-form trapezoid from and to 0.05 mm/s with these."""
    path = tmp_path / "diag.gcode"
    path.write_text("M204 P1000 T1000 R1000\nG1 X100 Y100 F12000\n")
    machine = load_machine("marlin-2.1.2")
    machine.kinematics = "corexy"
    *_, ends, out = _run(path, machine, quantised=False)
    d = 100 * math.sqrt(2)
    v, a = 200 * d / 200, 1000 * d / 200
    assert out[-1, mi.OT_NOMINAL] == pytest.approx(v, rel=1e-12)
    assert out[-1, mi.OT_ACCEL] == pytest.approx(a, rel=1e-12)
    assert ends[-1] == pytest.approx(_trapezoid_t(MIN_SQR, MIN_SQR, v, a, d), rel=1e-12)


def test_linear_advance_caps_the_acceleration(tmp_path):
    """Linear advance (M900 K0.05) caps a print move's acceleration so that E can jump to its advance speed within
    its jerk (planner.cpp ``use_advance_lead``): E jerk / (K · e/D) = 4.5 / (0.05 · 2/10) = 450 mm/s², under
    M204 P1000. The quantised model gets it in whole steps/s² (449.99 mm/s² at 100 steps/mm)."""
    path = tmp_path / "la.gcode"
    path.write_text("M204 P1000 T1000 R1000\nM900 K0.05\nG92 E0\nG1 X10 E2 F1200\n")
    machine = load_machine("marlin-2.1.2")
    *_, ends, out = _run(path, machine, quantised=False)
    assert out[-1, mi.OT_ACCEL] == pytest.approx(450.0, rel=1e-12)
    assert ends[-1] == pytest.approx(_trapezoid_t(MIN_SQR, MIN_SQR, 20.0, 450.0, 10.0), rel=1e-12)
    _run(path, machine)
    assert _run.of[-1, mk.OF_ACCEL] == pytest.approx(450.0, abs=0.02)
