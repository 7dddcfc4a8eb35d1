"""Issue 21's proof for the grbl model: with an unbounded buffer and no quantisation
(``grbl.run(..., buffer_blocks=None, quantised=False)``, planner/grbl_ideal.py) it gives the ideal look-ahead
plan back.

The truth is a planner written here in plain float64 (:func:`_ideal_plan`): per move its length, nominal speed
and acceleration from the MOVE row and the machine's $110-$112 / $120-$122 (the largest the axes allow along the
move, MINIMUM_FEED_RATE 1 mm/min), then the textbook full look-ahead over each stretch between syncs (from rest,
to rest; backward v_entry² ≤ v_exit² + 2·a·d, forward v_entry² ≤ v_prev² + 2·a·d) and each trapezoid's time in
closed form. The junction caps are grbl's junction deviation rule: a copy here would only copy the kernel, so
they are taken from the model's own output (``OT_JUNCTION_SQR``); one of them, a 90° corner, is checked against
its hand-worked value, and the cap within the two blocks' nominal speeds is the test's own.
"""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

import gcodeplan as gp
from conftest import SAMPLES, shared_path
from gcodeplan.errors import ConfigError
from gcodeplan.planner import grbl as G
from gcodeplan.planner import grbl_ideal as GI
from gcodeplan.schema import FLAG_RAPID, KIND_DWELL, KIND_WAIT

REFERENCE = ["linuxcnc_plasmatest.ngc", "linuxcnc_arcspiral.ngc"]
# a 90° corner (line 3), a shallow corner, µm moves, a reversal, a rapid Z (its own limits), a feed under
# MINIMUM_FEED_RATE, an exact reversal (cap 0), a dwell, spindle syncs (M3 / M5), a 0.1 mm move from rest whose
# exit the forward pass limits, a diagonal 3-axis move
HAND = """G21 G90 G94
G1 X10 F3000
G1 X10 Y10
G1 X40 Y25 F6000
G1 X40.01 Y25.002
G1 X40.02 Y25.0
G1 X0 Y0.5
G0 Z5
G0 X100 Y50
G1 X100 Y49.99 F0.3
G1 X90 F1200
G1 X100
G4 P0.25
M3 S1000
G1 X120 Y60 F2000
G1 X130 Y60.2
G1 X120 Y60
M5
G1 X119.9 Y60
G1 X0 Y0 Z0 F4000
"""


def _machine():
    """grbl-sim's settings from its $$ report ($1 = 255: no idle delay at stops); skips without ../shared."""
    return gp.load_machine(str(shared_path("reference", "grbl", "grbl_settings.txt")))


def _moves(path, machine):
    return gp.plan(str(path), machine).moves


def _hand(tmp_path, text=HAND):
    p = tmp_path / "hand.gcode"
    p.write_text(text)
    return p


def _trapezoid_t(v0_sqr, v1_sqr, vc, a, d):
    """Closed-form time (s) of a trapezoid from v0 to v1 (squares, mm²/s²) under vc over d mm at a mm/s²."""
    v0, v1 = math.sqrt(v0_sqr), math.sqrt(v1_sqr)
    d_acc, d_dec = (vc * vc - v0_sqr) / (2 * a), (vc * vc - v1_sqr) / (2 * a)
    if d_acc + d_dec <= d:
        return (vc - v0) / a + (d - d_acc - d_dec) / vc + (vc - v1) / a
    vp = math.sqrt((v0_sqr + v1_sqr) / 2 + a * d)
    return (vp - v0) / a + (vp - v1) / a


def _block(d, row, max_v, max_a):
    """Length (mm), nominal speed (mm/s), acceleration (mm/s²) of a move by ``d`` (mm): each axis within its
    own limit, so the move's limit is the smallest of limit · length / |axis delta|."""
    mm = math.sqrt(sum(x * x for x in d))
    rapid_v = min(max_v[k] * mm / abs(d[k]) for k in range(3) if d[k])
    a = min(max_a[k] * mm / abs(d[k]) for k in range(3) if d[k])
    feed = float(row["feed_v"])
    v = rapid_v if (row["flags"] & FLAG_RAPID or not math.isfinite(feed)) else min(feed, rapid_v)
    return mm, max(v, 1.0 / 60.0), a


def _ideal_plan(moves, machine, caps):
    """Per-row end times (s) of the full look-ahead plan: each stretch between syncs planned at once, from rest to
    rest; a dwell lasts its P once motion has started; NaN for a row without a block. ``caps`` (per row,
    mm²/s²): the junction caps, each then within the smaller nominal speed of the two blocks."""
    max_v = [machine.axes[a].max_velocity for a in "xyz"]
    max_a = [machine.axes[a].max_accel for a in "xyz"]
    ends = np.full(len(moves), np.nan)
    state = {"clock": 0.0, "started": False}

    def run(stretch):
        n = len(stretch)
        e = [0.0] * (n + 1)                                   # entries, then the last block's exit (rest)
        for i in range(n - 1, 0, -1):
            e[i] = min(stretch[i][2], e[i + 1] + 2 * stretch[i][1][2] * stretch[i][1][0])
        for i in range(1, n):
            e[i] = min(e[i], e[i - 1] + 2 * stretch[i - 1][1][2] * stretch[i - 1][1][0])
        for i, (r, (mm, v, a), _) in enumerate(stretch):
            state["clock"] += _trapezoid_t(e[i], e[i + 1], v, a, mm)
            ends[r] = state["clock"]
        state["started"] = state["started"] or n > 0

    pos, prev_v, stretch = [0.0, 0.0, 0.0], 0.0, []
    for r, row in enumerate(moves):
        if row["kind"] in (KIND_WAIT, KIND_DWELL):
            run(stretch)
            stretch = []
            if row["kind"] == KIND_DWELL and state["started"] and row["dwell_t"] > 0:
                state["clock"] += float(row["dwell_t"])
        elif row["kind"] <= 1:
            target = [float(row["x1"]), float(row["y1"]), float(row["z1"])]
            d = [target[k] - pos[k] for k in range(3)]
            if not any(d):
                continue
            b = _block(d, row, max_v, max_a)
            stretch.append((r, b, min(caps[r], min(b[1], prev_v) ** 2)))
            pos, prev_v = target, b[1]
    run(stretch)
    return ends


def _check_ideal(path, machine):
    """The model (unbounded, continuous) against :func:`_ideal_plan`: every row's end within 1e-9 relative."""
    moves = _moves(path, machine)
    res = G.run(moves, G.GrblSettings.from_machine(machine), buffer_blocks=None, quantised=False)
    caps = np.full(len(moves), np.nan)
    caps[res.rows] = res.out[:, GI.OT_JUNCTION_SQR]
    truth = _ideal_plan(moves, machine, caps)
    assert np.array_equal(np.isnan(truth), np.isnan(res.row_end_s))
    assert np.nanmax(truth) > 0
    np.testing.assert_allclose(res.row_end_s, truth, rtol=1e-9, atol=1e-12)
    assert res.total_s == pytest.approx(np.nanmax(truth), rel=1e-9)
    return moves, res


def test_hand_worked_single_line(tmp_path):
    """The reference README's hand calculation: G1 X100 F3000 at 500 mm/s² is 2.1000 s ideal (0.1 s ramps of
    2.5 mm each, 95 mm cruise at 50 mm/s in 1.9 s), with any buffer. grbl itself takes 2.10053 s: Timer1 waits
    OCR1A + 1 cycles per interrupt with OCR1A the step period rounded up, so each interrupt is at most 2 ticks
    (125 ns) late and never early; 8000 steps, at most 2³ interrupts each (AMASS level ≤ 3): within
    8000 · 8 · 125 ns = 8 ms above it."""
    m = _machine()
    moves = _moves(_hand(tmp_path, "G21 G90\nG1 X100 F3000\n"), m)
    s = G.GrblSettings.from_machine(m)
    for n in (2, 16, None):
        assert G.run(moves, s, buffer_blocks=n, quantised=False).total_s == pytest.approx(2.1, rel=1e-12)
    q = G.run(moves, s).total_s
    assert 0 < q - 2.1 <= 8000 * 8 * 2 / 16e6
    assert q == pytest.approx(2.10053, abs=1e-5)


def test_hand_made_program_is_the_full_lookahead_plan(tmp_path):
    """Corners, µm moves, reversals, rapids, a feed under MINIMUM_FEED_RATE, a dwell and spindle syncs: with an
    unbounded buffer and no quantisation every row's end is the float64 full look-ahead's within 1e-9
    relative. The 90° corner of line 3 at 500 mm/s² and $11 = 0.01 mm, by hand: the junction vector (−1, 1)/√2
    lets both axes give a_j = 500 √2 mm/s², sin(θ/2) = sin 45°, so
    v² = a_j · δ · sin(θ/2) / (1 − sin(θ/2)) = 5 / (1 − 1/√2) = 17.0711 mm²/s²; the exact reversal of line 12
    is capped at 0, the slow line 10 runs at 1 mm/min."""
    m = _machine()
    moves, res = _check_ideal(_hand(tmp_path), m)
    by_line = {int(moves["line"][r]): j for j, r in enumerate(res.rows)}
    assert res.out[by_line[3], GI.OT_JUNCTION_SQR] == pytest.approx(5 / (1 - 1 / math.sqrt(2)), rel=1e-12)
    assert res.out[by_line[3], GI.OT_V0] == pytest.approx(math.sqrt(5 / (1 - 1 / math.sqrt(2))), rel=1e-12)
    assert res.out[by_line[12], GI.OT_JUNCTION_SQR] == 0 and res.out[by_line[12], GI.OT_V0] == 0
    assert res.out[by_line[10], GI.OT_NOMINAL] == pytest.approx(1 / 60, rel=1e-12)
    # the dwell: its own 0.25 s after the motion stopped (grbl rounds it up to 50 ms steps: the same here)
    j = by_line[13]
    assert res.out[j, GI.OT_T_END] - res.out[j, GI.OT_T_PICK] == pytest.approx(0.25, rel=1e-12)


@pytest.mark.parametrize("name", REFERENCE)
def test_reference_programs_are_the_full_lookahead_plan(name):
    """The grbl reference programs (plasma cuts with M3/M5 syncs and arcs as grbl's chords; a 1000-line spiral of
    arcs): every line's end within 1e-9 relative of the float64 full look-ahead plan."""
    _check_ideal(SAMPLES / name, _machine())


def _by_buffer(path, machine, sizes=(2, 4, 8, 16, 64, None)):
    moves = _moves(path, machine)
    s = G.GrblSettings.from_machine(machine)
    return {n: G.run(moves, s, buffer_blocks=n, quantised=False) for n in sizes}


@pytest.mark.parametrize("name", REFERENCE + [None])
def test_a_longer_buffer_is_never_slower_without_quantisation(name, tmp_path):
    """Look-ahead can only be conservative: the newest block is planned to stop, and a block runs with the
    entries planned from what is queued when it starts. With 3 slots or more the planner never runs empty
    inside a stretch, so the junction caps are the unbounded buffer's; every block's entry is at most the
    unbounded buffer's, and the totals never increase with the buffer (2 slots: one block, a stop at every
    junction). A trapezoid's time falls as its end speeds rise, so entries that only rise give totals that
    only fall."""
    res = _by_buffer(SAMPLES / name if name else _hand(tmp_path), _machine())
    inf = res[None].out
    has = inf[:, GI.OT_HAS] == 1
    prev = math.inf
    for n, r in res.items():
        out = r.out
        assert np.array_equal(out[:, GI.OT_HAS] == 1, has)
        if n != 2:
            assert np.array_equal(out[has, GI.OT_JUNCTION_SQR], inf[has, GI.OT_JUNCTION_SQR])
        else:
            assert np.all(out[has, GI.OT_V0] == 0)
        assert np.all(out[has, GI.OT_V0] <= inf[has, GI.OT_V0] * (1 + 1e-12))
        assert r.total_s <= prev * (1 + 1e-12)
        prev = r.total_s
    assert res[2].total_s > res[None].total_s
    if name == "linuxcnc_plasmatest.ngc":    # (the spiral's 0.4 mm/s need 0.16 µm ramps: 4 slots are enough; the
        assert res[4].total_s > res[16].total_s > res[None].total_s     # hand-made stretches fit in 16)


def test_reference_totals_unchanged_at_16():
    """The default ring (16 slots) is grbl's: buffer_blocks=16 gives grbl-sim's totals (times.json) to a tick,
    bit for bit the default run's; 4 slots are slower."""
    times = json.loads(shared_path("reference", "grbl", "times.json").read_text())
    m = _machine()
    s = G.GrblSettings.from_machine(m)
    moves = _moves(SAMPLES / "linuxcnc_plasmatest.ngc", m)
    assert times["linuxcnc_plasmatest"]["total_time_s"] == pytest.approx(G.run(moves, s).total_s, abs=2e-7)
    r16 = G.run(moves, s, buffer_blocks=16)
    assert np.array_equal(r16.row_end_s, G.run(moves, s).row_end_s, equal_nan=True)
    assert G.run(moves, s, buffer_blocks=4).total_s > r16.total_s + 1.0


def test_quantised_against_continuous_timer_floor():
    """The spiral's arcs run at 0.4 mm/s: 32 steps/s at most on an axis, mostly under grbl's slowest step rate,
    16 MHz / (8 · 65536) = 30.5 steps/s (AMASS level 3 and the 16-bit OCR1A at 0xFFFF): such a block takes
    whole-step-count · 32.768 ms, less than its programmed time. The continuous model (16 slots) with each block
    held to that floor is within 1 % of grbl's total (grbl-sim's, 236.44 s), while the continuous model without
    it is 7 % slower."""
    m = _machine()
    s = G.GrblSettings.from_machine(m)
    moves = _moves(SAMPLES / "linuxcnc_arcspiral.ngc", m)
    q = G.run(moves, s).total_s
    ri = G.run(moves, s, quantised=False)
    lines = ri.out[:, GI.OT_HAS] == 1
    rows = ri.rows[lines]
    steps = G.grbl_steps_of(np.stack([moves["x1"][rows], moves["y1"][rows], moves["z1"][rows]], 1),
                            s.steps_per_mm)
    sec = np.abs(np.diff(np.vstack([np.zeros((1, 3), np.int64), steps]), axis=0)).max(axis=1)
    dur = ri.out[lines, GI.OT_T_END] - ri.out[lines, GI.OT_T_PICK]
    floored = ri.total_s - (dur - np.minimum(dur, sec * 8 * 65536 / 16e6)).sum()
    assert ri.total_s > 1.05 * q
    assert abs(q - floored) < 0.01 * q


def test_bad_buffer_sizes_are_named_errors(tmp_path):
    """A ring of fewer than 2 slots or not an int, an unbounded ring for the quantised model, step pulses
    without a stepper."""
    m = _machine()
    s = G.GrblSettings.from_machine(m)
    moves = _moves(_hand(tmp_path, "G1 X1 F100\n"), m)
    for bad in (0, 1, 2.5, 16.0, True, "16"):
        for q in (True, False):
            with pytest.raises(ConfigError, match="buffer_blocks"):
                G.run(moves, s, buffer_blocks=bad, quantised=q)
    for unbounded in (None, math.inf):
        with pytest.raises(ConfigError, match="buffer_blocks"):
            G.run(moves, s, buffer_blocks=unbounded)
        assert G.run(moves, s, buffer_blocks=unbounded, quantised=False).total_s > 0
    with pytest.raises(ConfigError, match="step pulses"):
        G.run(moves, s, steps_capacity=10, quantised=False)


def test_quantised_against_continuous_on_whole_steps():
    """Plasma cuts at 97 mm/s with arcs as short chords: grbl is 2.4 % slower than the continuous plan, and the
    whole-step targets are why: a chord's direction rounded to 12.5 µm steps bends its junctions, and the
    junction cap grows as 1/angle². The continuous plan of the same moves on their step-rounded targets
    (``lround(target · steps/mm)`` / steps/mm) leaves only the timer: every interrupt waits OCR1A + 1 cycles,
    OCR1A the period rounded up, so it is late by at most 2 ticks (125 ns) and never early, and a step takes at
    most 2³ interrupts (AMASS level ≤ 3): grbl's total is above it by at most 8 · 125 ns per step. With 4096
    slots (each stretch planned whole, as unbounded) and 16 (grbl's own: its blocks leave the planner when
    their last segment is prepared, up to 5 segments before they end, which only plans further ahead)."""
    m = _machine()
    s = G.GrblSettings.from_machine(m)
    moves = _moves(SAMPLES / "linuxcnc_plasmatest.ngc", m)
    rounded = moves.copy()
    steps = G.grbl_steps_of(np.stack([moves["x1"], moves["y1"], moves["z1"]], 1), s.steps_per_mm)
    for k, a in enumerate("xyz"):
        rounded[a + "1"] = steps[:, k] / s.steps_per_mm[k].astype(np.float64)
    lines = moves["kind"] <= 1
    path_steps = np.abs(np.diff(np.vstack([np.zeros((1, 3), np.int64), steps[lines]]), axis=0)).max(axis=1).sum()
    for n in (4096, 16):
        q = G.run(moves, s, buffer_blocks=n).total_s
        c = G.run(moves, s, buffer_blocks=n, quantised=False).total_s
        c_steps = G.run(rounded, s, buffer_blocks=n, quantised=False).total_s
        assert q > 1.02 * c
        assert c_steps <= q <= c_steps + path_steps * 8 * 2 / 16e6


def test_idle_delay_at_every_stop(tmp_path):
    """$1 (stepper idle delay) kept: st_go_idle busy-waits it inside the stepper interrupt when the motion stops,
    so the next motion starts that much later. The hand-made program stops with motion before G4 (line 13) and
    M5 (line 18); M3 (line 14) finds the steppers idle already: 25 ms · 2 = 50 ms more. grbl's next cycle then
    starts at Timer1's next compare match (its period from before the stop: at most 65536 · 62.5 ns = 4.1 ms
    later), so the quantised model gains 50 ms within 2 · 4.1 ms (measured 49.27 ms)."""
    m = _machine()
    moves = _moves(_hand(tmp_path), m)
    s = G.GrblSettings.from_machine(m)
    base_q, base_c = G.run(moves, s).total_s, G.run(moves, s, quantised=False).total_s
    s.idle_lock_ticks = 25 * 16000
    assert G.run(moves, s, quantised=False).total_s - base_c == pytest.approx(0.05, rel=1e-9)
    assert G.run(moves, s).total_s - base_q == pytest.approx(0.05, abs=2 * 65536 / 16e6)
