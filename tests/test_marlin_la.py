"""Linear advance in the marlin-2.1.2 firmware model: the extruder pulses of Marlin 2.1.2.4's LIN_ADVANCE
interrupt (``advance_isr`` on its own ``la_interval``, the E direction flipped while the advance drains),
against the firmware's own pulses (shared/reference/marlin/variants/la, ADVANCE_K 0.05), against single
blocks worked by hand, and the planner's advance fields and ``use_advance_lead`` rule by hand.

``python tools/compare_marlin.py --reference variants/la`` prints the same agreement as a table.
"""
import json

import numpy as np
import pytest

import gcodeplan as gp
from gcodeplan import pipeline
from gcodeplan.planner import marlin_kernels as mk
from gcodeplan.planner.marlin import advance_fields, advance_lead
from gcodeplan.stepper.marlin_la import (LA_ADVANCE_STEPS, LA_DIR_BITS, isr_ticks, la_blocks_pulses_kernel,
                                         new_state)
from gcodeplan.stepper.source import StepSink, rails_from
from conftest import shared_path, steps_window, toolhead_steps_line_by_line

CUBE = "prusaslicer25_cube20_marlin2"
HZ = 25_000_000
#: the reference build's K factor (Configuration_adv.h ADVANCE_K)
K = 0.05


def _la_machine(tmp_path):
    m = tmp_path / "la.toml"
    m.write_text(f'base = "marlin-2.1.2"\n[extruder]\npressure_advance = {K}\n')
    return gp.load_machine(str(m))


class _Keep(StepSink):
    """Every pulse per stepper, in order."""

    def __init__(self, machine):
        self.got = {}
        super().__init__(rails_from(machine), self._keep, machine=machine)
        self.names = [r.name for r in self.rails]

    def _keep(self, si, t, d):
        self.got.setdefault(self.names[si], []).append((t.copy(), d.copy()))

    def steps(self, name):
        parts = self.got.get(name, [])
        if not parts:
            return np.zeros(0), np.zeros(0, np.int8)
        return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])


def _la_run(machine, name):
    times = json.loads(shared_path("reference", "marlin", "variants", "la", "times.json").read_text())
    run = times[name + ".gcode"]["marlin-2.1.2.4-la"]
    sink = _Keep(machine)
    pipeline.run(str(shared_path("gcode", name + ".gcode")), machine, sinks=[sink])
    return sink, run


@pytest.fixture(scope="module")
def cube_la(tmp_path_factory):
    """The whole cube's pulses under K 0.05 (one run for the tests that read them), with the run's figures."""
    machine = _la_machine(tmp_path_factory.mktemp("la"))
    sink, run = _la_run(machine, CUBE)
    return machine, sink, run


def test_cube_extruder_pulses_are_marlins_to_the_tick(cube_la):
    """The cube under K 0.05: the extruder's pulses, forward and back, number what Marlin 2.1.2.4's
    linear-advance build issued (537,193: 478,854 forward, 58,339 back; net = the blocks' net E + the 4 steps
    of advance left at the end), every stored one (its first 200,000, or the vendored first 45 s) at Marlin's
    tick in Marlin's direction; X/Y/Z keep their counts."""
    _, sink, run = cube_la
    la = run["linear_advance"]
    t, d = sink.steps("e")
    assert len(t) == la["extruder_pulses_total"] == 537_193
    assert (int((d > 0).sum()), int((d < 0).sum())) == (la["extruder_pulses_forward"], la["extruder_pulses_backward"])
    assert int(d.sum(dtype=np.int64)) == la["extruder_pulses_net"] == la["extruder_block_steps_net"] + 4
    for name, key in (("x", "stepper_x"), ("y", "stepper_y"), ("z", "stepper_z")):
        tx, dx = sink.steps(name)
        assert len(tx) == run["steps"][key]["steps_total"], name
        assert int(dx.sum(dtype=np.int64)) == run["steps"][key]["net_steps"], name
    ref = np.load(shared_path("reference", "marlin", "variants", "la", "steps", CUBE + "_steps.npz"))
    rt, rd = ref["extruder"], ref["extruder_dir"]
    cut = steps_window(ref)
    n = len(rt) if cut is None else int(np.count_nonzero(rt < cut))
    assert n >= 24_000
    assert np.array_equal(np.round(t[:n] * HZ), np.round(rt[:n] * HZ)), \
        f"worst {np.max(np.abs(t[:n] - rt[:n])) * 1e6:.3f} µs"
    assert np.array_equal(d[:n], rd[:n])
    assert np.all(np.diff(t) >= 0)


def test_cube_line_ends_are_marlins_last_pulses(cube_la):
    """Every line's end in Marlin's linear-advance build (shared per-line CSV: when its last block's last step
    pulse was issued) is the tick of the last pulse gcodeplan issues for that block: the block's last event,
    or, where an advance pulse started the interrupt call less than the margin before it (1 of the cube's
    4659 lines, 9 ticks), that call's start."""
    machine, sink, _ = cube_la
    import csv
    import gzip

    with gzip.open(shared_path("reference", "marlin", "variants", "la", "per_line",
                               CUBE + ".per_line_end_time.csv.gz"), "rt") as fh:
        rows = list(csv.reader(fh))[1:]
    ref_line = np.array([int(r[0]) for r in rows])
    ref_end = np.round(np.array([float(r[1]) for r in rows]) * HZ).astype(np.int64)
    lines, ends = gp.estimate(str(shared_path("gcode", CUBE + ".gcode")), machine).line_times()
    block_end = np.round(ends[np.searchsorted(lines, ref_line)] * HZ).astype(np.int64)
    pulses = np.sort(np.round(np.concatenate([sink.steps(a)[0] for a in ("x", "y", "z", "e")]) * HZ).astype(np.int64))
    last = pulses[np.searchsorted(pulses, block_end, side="right") - 1]
    assert np.array_equal(last, ref_end)
    assert np.count_nonzero(last != block_end) == 1 and np.max(block_end - last) == 9


@pytest.mark.slow
def test_cylinder_extruder_pulse_counts_are_marlins(tmp_path):
    """The Cura cylinder (3453 s) under K 0.05: extruder pulses forward and back and every axis' count and
    net as Marlin's linear-advance build issued them (no step file is stored for it)."""
    machine = _la_machine(tmp_path)
    sink, run = _la_run(machine, "cura413_ender3_cylinder30")
    la = run["linear_advance"]
    t, d = sink.steps("e")
    assert (len(t), int((d > 0).sum()), int((d < 0).sum())) == (
        la["extruder_pulses_total"], la["extruder_pulses_forward"], la["extruder_pulses_backward"])
    assert abs(t[-1] - run["steps"]["extruder"]["last_step_s"]) < 1e-9
    for name, key in (("x", "stepper_x"), ("y", "stepper_y"), ("z", "stepper_z")):
        tx, dx = sink.steps(name)
        assert (len(tx), int(dx.sum(dtype=np.int64))) == (run["steps"][key]["steps_total"],
                                                          run["steps"][key]["net_steps"]), name


def _one(v):
    return np.array([v], np.int64)


def _block(st, sec, e_steps, la_rate, max_adv, final_adv, ticks=None):
    """One block through the linear-advance interrupt: ``sec`` events of X, ``e_steps`` of E, 1000 → 2000 →
    1000 steps/s accelerating over event 1 (acceleration_rate 671089: +1000 steps/s per 25,000 ticks),
    cruising to event 3, then decelerating; picked up at tick 0."""
    out_t = np.zeros((4, 64), np.int64)
    out_d = np.zeros((4, 64), np.int8)
    n_out = np.zeros(4, np.int64)
    zero = _one(0)
    la_blocks_pulses_kernel(_one(0), _one(sec), np.array([[sec, 0, 0, e_steps]], np.int64), zero, _one(1000),
                            _one(2000), _one(1000), _one(1), _one(3), _one(671089), _one(2000), zero, zero, zero, zero,
                            False, HZ, _one(la_rate), zero, _one(max_adv), _one(final_adv),
                            *(isr_ticks(HZ) if ticks is None else ticks), st, out_t, out_d, n_out)
    return {a: (out_t[a, :n_out[a]].tolist(), out_d[a, :n_out[a]].tolist()) for a in range(4)}


def test_advance_drains_backwards_while_decelerating_as_worked_by_hand():
    """A 6-event block (X 6, E 6 steps) entered with 5 steps of advance, la_advance_rate 3000, max 2, final 0.
    By hand (25 MHz): events at 25000 (first interval 25e6/1000), 37500 (rate 1000 + 1000 → 2000), 50000,
    62500 (cruise), 75000 (decelerating, still 2000), 91666 (1500). Each event's E Bresenham step only lowers
    the advance (5 → 4 → 3). The advance phase is armed at the first event with the pick-up's interval
    (25e6/1000 = 25000 ticks: the advance is not below max, no extra rate), so it first runs at 50000, then
    every 25e6/2000 = 12500 (cruise): forward pulses at 50000 and 62500. At event 4 the decelerating
    extruder rate 2000 − 3000 (advance 3 > final 0) is negative: the E direction flips and the interval is
    25e6/1000, so the pulse at 75000 is backwards; the block ends at 91666 before the next one (100000).
    Net E +1 = 6 steps − the 5 of advance drained; the E direction is left reversed."""
    st = new_state()
    st[LA_ADVANCE_STEPS] = 5
    out = _block(st, 6, 6, 3000, 2, 0)
    assert out[0] == ([25000, 37500, 50000, 62500, 75000, 91666], [1] * 6)
    assert out[3] == ([50000, 62500, 75000], [1, 1, -1])
    assert st[LA_ADVANCE_STEPS] == 0 and st[LA_DIR_BITS] == 8


def test_advance_event_under_two_us_after_a_step_is_issued_with_it():
    """la_advance_rate 995 makes the pick-up's interval 25e6 // (1000 + 995) = 12531 ticks: the advance phase,
    armed at the first event (25000), first runs at 37531, 31 ticks (1.24 µs) after the second event (37500),
    and from then on every 12500 (cruise) and 16666 (25e6/1500, decelerating) ticks after it, 31 ticks after
    each event. Marlin's interrupt loops while the next event is due before its timer's count + 1 µs (25
    ticks), the count having run on by the X step pulse's high time (20 ticks): 31 < 45, so the E pulses are
    issued in the same call, at the events' ticks 37500, 50000, 62500, 75000; the one due at 91697 never
    comes, the block having ended at 91666. Each of the 6 E steps of the block lowered the advance, each pulse
    raised it: 4 − 6 = −2 left. Were the count 0 (no pulse hold), the same pulses would come 31 ticks later."""
    assert isr_ticks(HZ) == (25, 20)
    st = new_state()
    out = _block(st, 6, 6, 995, 2, 0)
    assert out[3] == ([37500, 50000, 62500, 75000], [1, 1, 1, 1])
    assert st[LA_ADVANCE_STEPS] == -2
    out = _block(new_state(), 6, 6, 995, 2, 0, ticks=(25, 0))
    assert out[3][0] == [37531, 50031, 62531, 75031]


def _oi(rows):
    """Per-row outputs of blocks: (steps X, Y, Z, E, direction bits, events, accel steps/s², cruise, final)."""
    oi = np.zeros((len(rows), mk.N_OI), np.int64)
    for i, (sx, sy, sz, se, dirs, sec, acc, cruise, final) in enumerate(rows):
        oi[i, mk.OI_HAS_BLOCK] = 1
        oi[i, mk.OI_SX:mk.OI_SE + 1] = (sx, sy, sz, se)
        oi[i, mk.OI_DIR_BITS] = dirs
        oi[i, mk.OI_SEC] = sec
        oi[i, mk.OI_ACCEL_STEPS] = acc
        oi[i, mk.OI_CRUISE_RATE] = cruise
        oi[i, mk.OI_FINAL_RATE] = final
    return oi


def test_advance_fields_as_worked_by_hand():
    """K 0.05 on a block of 1000 events, 70 E steps, 125,000 steps/s², cruise 5000 and final 120 steps/s:
    la_advance_rate = 0.05 · 125000 = 6250; la_scaling 1 (2·70 = 140 ≤ 1000/4 = 250, 280 is not);
    max_adv_steps = 5000 · 0.05 · 70 / 1000 = 17.5 → 17; final_adv_steps = 120 · 0.0035 = 0.42 → 0. A block
    without advance has none of them."""
    oi = _oi([(1000, 0, 0, 70, 0, 1000, 125000, 5000, 120), (1000, 0, 0, 70, 0, 1000, 125000, 5000, 120)])
    got = advance_fields(oi, np.array([True, False]), np.array([K, K], np.float32))
    assert got.tolist() == [[6250, 1, 17, 0], [0, 0, 0, 0]]


def test_use_advance_lead_as_planner_cpp_decides():
    """From the origin: X 10 mm with E 0.5 (e/D 0.05) advances; a retract (E backwards, no X/Y/Z) and its
    recover (E forwards, no X/Y/Z) do not; X 0.1 mm with E 0.5 (e/D 5 > 3: a retract merged into a print move)
    does not; nor a print move under K 0; a G92 E0 on a row sets position_float's E before its block (e/D from
    0, not from the previous E). position_float ends at the last block's target."""
    tgt = np.array([[10, 0, 0, 0.5], [10, 0, 0, -0.3], [10, 0, 0, 0.5], [10.1, 0, 0, 1.0], [20, 0, 0, 1.5],
                    [30, 0, 0, 0.5]], np.float32)
    oi = _oi([(1000, 0, 0, 140, 0, 1000, 1, 1, 1), (0, 0, 0, 224, 8, 224, 1, 1, 1), (0, 0, 0, 224, 0, 224, 1, 1, 1),
              (10, 0, 0, 140, 0, 140, 1, 1, 1), (1000, 0, 0, 140, 0, 1000, 1, 1, 1),
              (1000, 0, 0, 140, 0, 1000, 1, 1, 1)])
    reset_bits = np.array([0, 0, 0, 0, 0, 8], np.int64)
    reset_pos = np.zeros((6, 4), np.float32)
    k = np.array([K, K, K, K, 0, K], np.float32)
    pos = np.zeros(4, np.float32)
    lead = advance_lead(oi, tgt, reset_bits, reset_pos, k, pos)
    assert lead.tolist() == [True, False, False, False, False, True]
    assert pos.tolist() == [30, 0, 0, 0.5]
    # without the G92 E0 the last move's E would go backwards from 1.5 to 0.5: a retract-while-moving, no advance
    oi[5, mk.OI_DIR_BITS] = 8
    assert not advance_lead(oi, tgt, np.zeros(6, np.int64), reset_pos, k, np.zeros(4, np.float32))[5]


PROGRAM = ("G21\nG90\nM83\nM900 K0.05\nG1 X10 F3000\nG1 X10.03 F3000\nG1 X30 Y5 E0.5 F1800\nG1 X30 Y25 E0.5\n"
           "G1 E-0.8 F2400\nG1 X0 Y0 F6000\nG1 E0.8 F2400\nG1 X20 Y0 E0.5 F1200\nG4 P50\nG1 X20 Y20 E0.5 F1800\n"
           "M900 K0\nG1 X0 Y20 E0.5\n")


def test_toolhead_line_by_line_gives_gp_steps_pulses_under_advance(tmp_path):
    """gp.Toolhead(steps=True) fed one line at a time (the model settles short stretches, the advance
    state and the planner's float position carried between them) hands out exactly gp.steps' pulses under
    M900 K0.05; against the same program with K 0, X/Y/Z make the same pulses, each on time or (handled in a
    call an advance pulse started) less than the margin plus one pulse hold (1.8 µs) early, and E adds advance
    pulses both ways."""
    g = tmp_path / "la.gcode"
    g.write_text(PROGRAM)
    machine = gp.load_machine("marlin-2.1.2")
    ref = gp.steps(str(g), machine)
    mine = toolhead_steps_line_by_line(machine, PROGRAM)
    for k, (t, d) in ref.items():
        assert np.array_equal(mine[k][0], t) and np.array_equal(mine[k][1], d), k
    g0 = tmp_path / "k0.gcode"
    g0.write_text(PROGRAM.replace("M900 K0.05", "M900 K0"))
    plain = gp.steps(str(g0), machine)
    for k in ("x", "y"):
        t, d = ref[k]
        t0, d0 = plain[k]
        assert len(t) == len(t0) > 0 and np.array_equal(d, d0), k
        early = np.round((t0 - t) * HZ)
        assert early.min() >= 0 and early.max() < sum(isr_ticks(HZ)), k
    e, ed = ref["e"]
    e0, ed0 = plain["e"]
    assert len(e) > len(e0) and np.any(ed < 0)
    # what the advance pulses add drains again: net E differs by the few steps of advance left in the last blocks
    assert abs(int(ed.sum()) - int(ed0.sum())) <= 5


@pytest.mark.parametrize("firmware, says", [("marlin-2.1.2", "Marlin's linear advance"),
                                            ("generic", "planned as Klipper's pressure advance")])
def test_m900_says_what_plans_it(tmp_path, firmware, says):
    """M900 K on the Marlin model is Marlin's own linear advance (its acceleration cap lengthens the moves); on
    the generic policy it is Klipper's pressure advance, which leaves the motion's time alone."""
    from dataclasses import replace

    path = tmp_path / "la.gcode"
    body = "G21\nG90\nM83\nG1 X50 Y0 E10 F6000\nG1 X50 Y50 E10\n"      # 0.2 mm of filament per mm
    machine = replace(gp.load_machine("marlin"), firmware=firmware)
    path.write_text("M900 K0.05\n" + body)
    est = gp.estimate(str(path), machine)
    assert any(says in w for w in est.parse.warnings), est.parse.warnings
    with_la = est.total_time_s
    path.write_text(body)
    without = gp.estimate(str(path), machine).total_time_s
    assert (with_la > without) if firmware != "generic" else with_la == without
