"""The step pulses of the marlin-2.1.2 firmware model against Marlin 2.1.2.4's own stepper interrupt
(shared/reference/marlin/steps: every pulse as the firmware issued it on its 25 MHz timer), against
Bresenham worked by hand, and its invariants (a block's pulses end where its PLAN row ends; every step a
block makes is issued, a merged sub-6-step move's too).

``python tools/compare_marlin.py`` prints the same agreement as a table (its steps section).
"""
import json

import numpy as np
import pytest

import gcodeplan as gp
from gcodeplan import pipeline
from gcodeplan.errors import ConfigError
from gcodeplan.stepper.marlin_isr import (MARLIN_TIMER_HZ, N_ISR, block_phase_isr, block_pickup,
                                          blocks_pulses_kernel, block_step_times_kernel)
from gcodeplan.stepper.source import StepSink, rails_from
from conftest import shared_path, steps_window, toolhead_steps_line_by_line

CUBE = "prusaslicer25_cube20_marlin2"
#: the reference's stepper names, in X, Y, Z, E order, and gcodeplan's (cartesian short names)
REF_NAMES = ("stepper_x", "stepper_y", "stepper_z", "extruder")
OUR_NAMES = ("x", "y", "z", "e")


class _StepsUntil(StepSink):
    """A StepSink that keeps every pulse, counts them per stepper, and says it is done once a piece starts
    after ``until_s`` (a prefix of a long program plans only its beginning)."""

    def __init__(self, machine, until_s=None):
        self.got = {}
        super().__init__(rails_from(machine), self._keep, machine=machine)
        self.names = [r.name for r in self.rails]
        self.until_s = until_s

    def _keep(self, si, t, d):
        self.got.setdefault(self.names[si], []).append((t.copy(), d.copy()))

    def add(self, piece):
        super().add(piece)
        return self.until_s is not None and len(piece.plan) > 0 and piece.plan["t_start"][-1] > self.until_s

    def steps(self, name):
        parts = self.got.get(name, [])
        if not parts:
            return np.zeros(0), np.zeros(0, np.int8)
        return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])


def _run(machine, gcode, policy=None, until_s=None):
    sink = _StepsUntil(machine, until_s)
    # small reader batches: the model settles rows, and the sink gets pieces, as the program is read
    pipeline.run(str(gcode), machine, policy=policy, sinks=[sink], batch_moves=8192 if until_s is None else 500)
    return sink


def _machine(variant, tmp_path):
    if variant == "scurve":
        m = tmp_path / "scurve.toml"
        m.write_text('base = "marlin-2.1.2"\nacceleration_profile = "s-curve"\n')
        return gp.load_machine(str(m)), None
    if variant == "jd":
        return gp.load_machine("marlin-2.1.2"), "junction-deviation"
    if variant == "bugfix":
        return gp.load_machine("marlin-bugfix"), None
    return gp.load_machine("marlin-2.1.2"), None


def _ref_dir(variant):
    if variant == "bugfix":
        return ("marlin", "bugfix-2.1.x")
    return ("marlin",) if variant == "" else ("marlin", "variants", variant)


def _check_prefix(sink, ref, cut):
    """Every pulse before ``cut`` s equals the firmware's, tick for tick, with its direction."""
    for rn, on in zip(REF_NAMES, OUR_NAMES):
        if rn not in ref.files:
            continue
        t, d = sink.steps(on)
        rt, rd = ref[rn], ref[rn + "_dir"]
        keep = t < cut
        rkeep = rt < cut
        assert keep.sum() == rkeep.sum(), f"{rn}: {keep.sum()} pulses before {cut} s, Marlin {rkeep.sum()}"
        assert np.array_equal(t[keep], rt[rkeep]), f"{rn}: worst {np.max(np.abs(t[keep] - rt[rkeep])) * 1e6} µs"
        assert np.array_equal(d[keep], rd[rkeep]), f"{rn}: directions differ"


@pytest.mark.parametrize("variant", ["", "scurve", "bugfix"])
def test_cube_prefix_pulses_are_marlins_to_the_tick(variant, tmp_path):
    """The first seconds of the cube (the vendored prefix when ../shared is absent): every X, Y, Z and E pulse
    of ``gcodeplan steps`` at the tick and in the direction Marlin 2.1.2.4 issued it (its S-curve build's too),
    the reading stopping early as the sink asks."""
    ref = np.load(shared_path("reference", *_ref_dir(variant), "steps", CUBE + "_steps.npz"))
    # the vendored prefix's cut, else up to where the reference stopped storing (its first 200,000 per stepper)
    cut = steps_window(ref) or np.inf
    cut = min([cut] + [float(ref[k][-1]) for k in REF_NAMES if k in ref.files and len(ref[k]) == 200_000])
    machine, policy = _machine(variant, tmp_path)
    sink = _run(machine, shared_path("gcode", CUBE + ".gcode"), policy, until_s=cut + 1.0)
    _check_prefix(sink, ref, cut)
    # a prefix, not the whole 1130 s run: the sink stopped the reading
    assert sink.steps("x")[0][-1] < 300.0


@pytest.mark.slow
@pytest.mark.parametrize("name,variant", [(CUBE, ""), ("cura413_ender3_cylinder30", ""), (CUBE, "jd"),
                                          (CUBE, "scurve"), (CUBE, "bugfix")])
def test_whole_run_counts_and_stored_pulses_are_marlins(name, variant, tmp_path):
    """Whole programs: the pulses per stepper and their net equal Marlin's counts (times.json), and every pulse
    the reference stores (the first 200,000 per stepper) is at Marlin's tick, in Marlin's direction."""
    times_dir = _ref_dir(variant) if variant != "bugfix" else ("marlin",)
    times = json.loads(shared_path("reference", *times_dir, "times.json").read_text())
    entry = times[name + ".gcode"]
    version = "bugfix-2.1.x" if variant == "bugfix" else "marlin-2.1.2.4"
    run = entry.get(version) or next(v for k, v in entry.items() if k.startswith(version + "-"))
    ref = np.load(shared_path("reference", *_ref_dir(variant), "steps", name + "_steps.npz"))
    if steps_window(ref) is not None:
        pytest.skip("only a prefix of the reference's pulses is here (../shared is absent)")
    machine, policy = _machine(variant, tmp_path)
    sink = _run(machine, shared_path("gcode", name + ".gcode"), policy)
    for rn, on in zip(REF_NAMES, OUR_NAMES):
        t, d = sink.steps(on)
        assert len(t) == run["steps"][rn]["steps_total"], rn
        assert int(d.sum(dtype=np.int64)) == run["steps"][rn]["net_steps"], rn
        rt, rd = ref[rn], ref[rn + "_dir"]
        assert np.array_equal(t[:len(rt)], rt), f"{rn}: worst {np.max(np.abs(t[:len(rt)] - rt)) * 1e6} µs"
        assert np.array_equal(d[:len(rd)], rd), rn


def _bresenham_by_hand(n_events, steps):
    """Event (1-based) of each step of an axis making ``steps`` of ``n_events``: Marlin's error starts at −N,
    grows 2·s per event and the axis steps at ≥ 0, dropping 2·N; so the j-th step falls on the first event k
    with 2·s·k ≥ N·(2j − 1), k = ⌈N·(2j − 1) / (2·s)⌉."""
    j = np.arange(1, steps + 1)
    return -(-(n_events * (2 * j - 1)) // (2 * steps))


def test_bresenham_shares_the_leading_axis_ticks_as_worked_by_hand():
    """One block of 1000 events with Y 333, Z 7, E 1000 (a tie with the leading X) and X 1000 steps: each axis
    steps on the event the hand-worked Bresenham names, at that event's tick (the leading axis's pulse times),
    with its own direction."""
    n = 1000
    lead = np.zeros(n, np.int64)
    # a block cruising at 10,000 steps/s from 1000 to ... : initial 1000, nominal 10000, final 1000, 100,000 steps/s²
    args = (n, 1000, 10_000, 1_000, 300, 700, 67108)
    block_step_times_kernel(*args, MARLIN_TIMER_HZ, 5_000, lead)
    axis_steps = np.array([[1000, 333, 7, 1000]], np.int64)
    cap = 1000
    out_t = np.zeros((4, cap), np.int64)
    out_d = np.zeros((4, cap), np.int8)
    n_out = np.zeros(4, np.int64)
    one = lambda v: np.array([v], np.int64)   # noqa: E731
    zero = one(0)
    blocks_pulses_kernel(one(5_000), one(n), axis_steps, one(0b0110), one(1000), one(10_000), one(1_000), one(300),
                         one(700), one(67108), one(10_000), zero, zero, zero, zero, False, MARLIN_TIMER_HZ, out_t,
                         out_d, n_out)
    assert list(n_out) == [1000, 333, 7, 1000]
    for a, s in enumerate(axis_steps[0]):
        events = _bresenham_by_hand(n, s)
        assert np.array_equal(out_t[a, :s], lead[events - 1]), a
        assert np.all(out_d[a, :s] == (-1 if a in (1, 2) else 1)), a
    # Y's first step on event ⌈1000/666⌉ = 2, its last on ⌈1000·665/666⌉ = 999; Z's on ⌈1000/14⌉ = 72 …
    assert _bresenham_by_hand(n, 333)[[0, -1]].tolist() == [2, 999]
    assert _bresenham_by_hand(n, 7).tolist() == [72, 215, 358, 500, 643, 786, 929]


def test_leading_axis_intervals_follow_the_interrupts_rate_rule():
    """The leading axis's intervals by hand (25 MHz, 2.1.2's trapezoid): pick-up at TIMER / initial_rate,
    then initial + STEP_MULTIPLY(elapsed ticks, acceleration_rate) while accelerating, nominal in cruise, and
    acc_step_rate − STEP_MULTIPLY(decelerating ticks, rate) after; the block lasts the sum."""
    isr = np.zeros(N_ISR, np.int64)
    hz = MARLIN_TIMER_HZ
    acc_rate = 67108                          # ≈ 100,000 steps/s² · 2^24 / 25 MHz
    first = block_pickup(isr, 10, 1000, 2000, 1000, 3, 6, acc_rate, 2000, 0, 0, 0, 0, False, hz)
    assert first == hz // 1000
    acc_t = first
    want = []
    for _ in range(3):                        # events 1..3 accelerate
        r = min(1000 + ((acc_t * acc_rate + 0x800000) >> 24), 2000)
        want.append(hz // r)
        acc_t += hz // r
    want += [hz // 2000] * 3                  # events 4..6 cruise
    dec_t = 0
    for _ in range(3):                        # events 7..9 decelerate from nominal
        s = (dec_t * acc_rate + 0x800000) >> 24
        s = max(2000 - s, 1000) if s < 2000 else 1000
        want.append(hz // s)
        dec_t += hz // s
    got = [block_phase_isr(isr, k, hz) for k in range(1, 10)]
    assert got == want
    times = np.zeros(10, np.int64)
    block_step_times_kernel(10, 1000, 2000, 1000, 3, 6, acc_rate, hz, 0, times)
    assert np.array_equal(np.diff(times), want) and times[0] == first


def test_pulses_end_where_the_plan_rows_end_and_a_merged_move_steps_in_time(tmp_path):
    """A 3-step move (under MIN_STEPS_PER_SEGMENT) merges into the next block: its X steps are issued among
    that block's pulses, spread in time (not in zero time at a row boundary); every block's last leading-axis
    pulse is its PLAN row's end; counts and net steps are the moves' step deltas."""
    g = tmp_path / "merge.gcode"
    g.write_text("G21\nG90\nM83\nG1 X10 F3000\nG1 X10.03 F3000\nG1 X12 Y1 E0.5 F1200\nG1 X0 Y0 F6000\nM400\n")
    machine = gp.load_machine("marlin-2.1.2")
    out = gp.steps(str(g), machine)
    plan = gp.plan(str(g), machine)
    x, xd = out["x"]
    y, yd = out["y"]
    e, ed = out["e"]
    assert len(x) == 1000 + 200 + 1200 and int(xd.sum()) == 0
    assert len(y) == 200 and int(yd.sum()) == 0
    assert len(e) == 140 and int(ed.sum()) == 140
    assert np.all(np.diff(x) > 0) and np.all(np.diff(y) > 0)
    # the merged row lasts 0 s in the plan; its 3 steps are among the next block's 200 X pulses
    rows, mv = plan.plan, plan.moves
    blocks = ((mv["x1"] != mv["x0"]) | (mv["y1"] != mv["y0"])) & (rows["duration"] > 0)
    assert blocks.tolist() == [True, False, True, True, False]
    ends = (rows["t_start"] + rows["duration"])[blocks]
    x_ticks = np.round(x * MARLIN_TIMER_HZ).astype(np.int64)
    assert set(np.round(ends * MARLIN_TIMER_HZ).astype(np.int64).tolist()) <= set(x_ticks.tolist())
    assert x[-1] == ends[-1]
    second = (x > ends[0]) & (x <= ends[1])
    assert second.sum() == 200 and np.all(xd[second] == 1)


def test_a_stepper_the_model_does_not_drive_is_an_error_not_missing_pulses(tmp_path):
    """The firmware model issues the pulses of its own steppers (X, Y, Z, E on a cartesian build): a stepper
    that follows none of them (here a CoreXY motor asked of a cartesian Marlin machine) is a clear error, never a
    silent run without its pulses or with another stepper's."""
    g = tmp_path / "xy.gcode"
    g.write_text("G1 X10 Y5 F3000\n")
    m = gp.load_machine("marlin-2.1.2")
    core = gp.kinematics.Linear({"a": (1, 1, 0), "b": (1, -1, 0), "z": (0, 0, 1)})
    with pytest.raises(ConfigError, match="firmware model"):
        gp.steps(str(g), m, kinematics=core)


def test_toolhead_line_by_line_gives_the_pulses_of_gp_steps(tmp_path):
    """gp.Toolhead(steps=True), fed one line at a time, hands out the firmware's pulses as rows become final:
    their concatenation is gp.steps' bit for bit."""
    text = ("G21\nG90\nM83\nG1 X10 F3000\nG1 X10.03 F3000\nG1 X12 Y1 E0.5 F1200\nG1 X0 Y0 F6000\n"
            "G1 Z0.4 F600\nG1 X5 Y5 E0.3 F1800\nG4 P50\nG1 X0 Y3 F6000\n")
    g = tmp_path / "th.gcode"
    g.write_text(text)
    machine = gp.load_machine("marlin-2.1.2")
    ref = gp.steps(str(g), machine)
    mine = toolhead_steps_line_by_line(machine, text)
    for k, (t, d) in ref.items():
        assert np.array_equal(mine[k][0], t) and np.array_equal(mine[k][1], d), k
    assert len(ref["z"][0]) == 160 and len(ref["x"][0]) == 2400 + 500 + 500
