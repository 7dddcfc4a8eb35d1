"""Review of the planner and the stepper where their pieces meet: each test pins a bug that was found
(and fixed) with a hand-worked value or a physical invariant, plus hand-worked checks of the non-Klipper
policies on the marlin and grbl presets.

Truth used: closed forms (junction deviation, classic jerk, trapezoid, profiles.scurve), the ordering of
policies (exact stop is never faster than a policy that may keep speed), and invariants measured on the
SEGMENT pieces (position continuous, axis limits, step counts = change of the rounded position).
"""
from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from gcodeplan.config import load_machine
from gcodeplan.planner import StreamPlanner, plan_moves, plan_with_segments

from conftest import moves_from_points

AX = "xyze"

# A square of four 10 mm sides at 100 mm/s: every corner is 90°.
SQUARE = [(0, 0, 0, 0), (10, 0, 0, 0), (10, 10, 0, 0), (0, 10, 0, 0), (0, 0, 0, 0)]


def square_moves(feed_v=100.0, accel=1000.0):
    mv = moves_from_points(SQUARE, feed_v=feed_v, accel=accel)
    mv["blend_p"] = math.nan
    return mv


def total_time(plan) -> float:
    return float(plan["t_start"][-1] + plan["duration"][-1])


def stream_plan(moves, limits, machine, chunk=2, **kw):
    sp = StreamPlanner(machine, **kw)
    plans = []
    for i in range(0, len(moves), chunk):
        plans += [p for _, p in sp.feed(moves[i:i + chunk], limits)]
    plans += [p for _, p in sp.finish()]
    return np.concatenate(plans)


# --------------------------------------------------------------------------- S-curves follow the policy asked for
@pytest.mark.parametrize("preset", ["marlin", "grbl", "klipper"])
def test_scurve_exact_stop_is_never_faster_than_trapezoid_exact_stop(preset):
    """Bug: with a jerk, plan_moves / StreamPlanner planned the junctions of machine.junction_policy and ignored
    the policy argument, so `estimate --policy exact-stop --jerk J` kept corner speed (marlin: 0.7925 s for the
    square, less than the 0.8 s of trapezoids with full stops). With a stop at every corner each side is a
    rest-to-rest move: an S-curve of the same limits is never faster than the trapezoid, and equals
    profiles.scurve for each side."""
    from gcodeplan import profiles

    mach = load_machine(preset)
    mv = square_moves()
    if preset == "grbl":
        mv["accel"] = math.inf
    lim = mach.limits_row()
    trap = plan_moves(mv, lim, mach, "exact-stop")
    jerk = 1e5
    scur = plan_moves(mv, lim, mach, "exact-stop", jerk=jerk)
    assert np.all(scur["start_v"] == 0.0) and np.all(scur["end_v"] == 0.0)
    # each side rest to rest: the 1-D solver's duration at the move's own speed and accel limits
    for k in range(len(mv)):
        v_cap, a_cap = _move_caps(mv[k:k + 1], lim, mach)
        want = profiles.scurve(10.0, v_cap, a_cap, jerk).duration
        assert scur["duration"][k] == pytest.approx(want, rel=1e-12)
    assert total_time(scur) >= total_time(trap)
    # the streaming planner and plan_with_segments follow the same policy, bit for bit
    assert np.array_equal(stream_plan(mv, lim, mach, policy="exact-stop", jerk=jerk), scur)
    plan2, segs = plan_with_segments(mv, lim, mach, "exact-stop", jerk=jerk)
    assert np.array_equal(plan2, scur)


def _move_caps(one_move, lim, mach):
    from gcodeplan.planner import prepare

    p = prepare(one_move, lim, mach, "exact-stop")[0]
    return math.sqrt(p["max_cruise_v2"]), float(p["accel"])


def test_scurve_policy_changes_the_corner_speeds():
    """The junction-deviation corner cap with S-curves is the trapezoid planner's (prepare), not the machine's
    classic jerk: on the marlin preset (classic-jerk) a 90° corner under junction deviation passes at
    v² = a·δ·sin(θ/2)/(1 − sin(θ/2)) with a = 1000 (M201 X/Y cap the travel accel 1500), δ = 0.013."""
    mach = load_machine("marlin")
    lim = mach.limits_row()
    mv = square_moves()
    plan = plan_moves(mv, lim, mach, "junction-deviation", jerk=1e6)
    s = math.sqrt(0.5)
    v_corner = math.sqrt(1000.0 * 0.013 * s / (1.0 - s))
    assert plan["end_v"][:3] == pytest.approx([v_corner] * 3, rel=1e-12)
    cj = plan_moves(mv, lim, mach, "classic-jerk", jerk=1e6)
    assert cj["end_v"][:3] == pytest.approx([8.0] * 3, rel=1e-12)   # Marlin classic jerk: X/Y jerk 8 mm/s


# --------------------------------------------------------------------------- the stepper fed every mode
PART = """G21
G90
M83
G64 P0.05
G1 X10 Y0 F6000
G1 X10 Y10 E0.5
G1 X0.5 Y10.5 E0.5
G1 X0.7 Y10.4 E0.02
G1 X0.8 Y10.6 E0.02
G1 E-0.8 F2400
G1 Z0.4 F600
G1 X13.3 Y2.2 Z0.2 F9000
G61
G1 X15 Y1
G64 P0.02
G1 X17 Y1.5 F3000
G1 X17.2 Y1.6 E0.01
G1 X12 Y1.6 E0.1
G1 E0.8 F2400
G4 P100
G1 X1.25 Y3.75 F6000
"""
END_XYZ = (1.25, 3.75, 0.2)
MODES = [("classic-jerk", None), ("junction-deviation", None), ("exact-stop", None), ("blend", None),
         ("junction-deviation", 5e4), ("klipper", 2e4), ("exact-stop", 1e3)]


@pytest.fixture
def part_file(tmp_path):
    p = tmp_path / "part.gcode"
    p.write_text(PART)
    return p


@pytest.mark.parametrize("policy,jerk", MODES)
def test_steps_count_the_rounded_position_in_every_mode(part_file, policy, jerk):
    """Every planning mode through the streaming planner's segments and the step kernel: at any time the steps
    taken equal the planned position in steps within ½ step (the half-step convention), the path is continuous,
    and the net steps are the change of round(position·steps_per_mm)."""
    from gcodeplan.kinematics import rails_for
    from gcodeplan.stepper.generate import generate_steps
    from gcodeplan.stepper.source import segment_batches

    mach = load_machine("marlin")
    if jerk is not None:                       # S-curves are the generic planner's (a firmware machine refuses --jerk)
        mach = replace(mach, firmware="generic")
    # the part's G64 P (the blend tolerance) is read on the reprap flavor: Marlin's default build has no G64
    mach = replace(mach, flavor="reprap")
    batches = list(segment_batches(str(part_file), mach, policy=policy, jerk=jerk))
    segs = np.concatenate([b[0] for b in batches])
    assert not np.any(np.concatenate([b[1] for b in batches]))
    if jerk is not None:
        assert np.any(segs["jx"] != 0.0)
    if policy == "blend" and jerk is None:   # with a jerk, S-curves under junction deviation's caps
        assert np.any(segs["phase"] == 3)
    # pieces back to back in time, position continuous
    t_end = segs["t0"] + segs["dt"]
    assert np.allclose(segs["t0"][1:], t_end[:-1], rtol=0, atol=1e-12)
    rails = rails_for(mach)
    steps = generate_steps(segs, rails=rails)
    ts = np.sort(np.concatenate([np.linspace(0, t_end[-1], 5000), segs["t0"] + 0.37 * segs["dt"]]))
    k = np.clip(np.searchsorted(segs["t0"], ts, side="right") - 1, 0, len(segs) - 1)
    tau = ts - segs["t0"][k]
    for rail in rails:
        ax = rail.name
        s = segs[k]
        pos = s["p" + ax] + s["v" + ax] * tau + s["a" + ax] * tau ** 2 / 2 + s["j" + ax] * tau ** 3 / 6
        t, d = steps[ax]
        cum = np.concatenate(([0], np.cumsum(d, dtype=np.int64)))
        n_at = cum[np.searchsorted(t, ts, side="right")]
        assert np.max(np.abs(n_at - pos * rail.steps_per_mm)) <= 0.5 + 1e-6, ax
        end = {"x": END_XYZ[0], "y": END_XYZ[1], "z": END_XYZ[2], "e": 0.24 + 0.01 + 0.1 + 0.8 - 0.8 + 0.8}[ax]
        if ax != "e":
            assert int(cum[-1]) == round(end * rail.steps_per_mm), ax


@pytest.mark.parametrize("extra", [["--policy", "blend"], ["--jerk", "20000"], ["--policy", "exact-stop", "--jerk", "1e3"]])
def test_steps_command_blend_and_scurve_with_compress(part_file, tmp_path, extra):
    """`gcodeplan steps` with blends and S-curves (--jerk): net steps = round(end·steps_per_mm), and every
    decompressed step within [t − max_error − ½ tick, t + ½ tick] of its exact time."""
    from gcodeplan.cli import main
    from gcodeplan.stepper.export import load_npz
    from gcodeplan.stepper.compress import decompress_runs

    out = tmp_path / "s.npz"
    m = tmp_path / "m.toml"                    # the marlin machine on the generic planner (--jerk S-curves)
    m.write_text('base = "marlin"\nfirmware = "generic"\n')
    rc = main([str(a) for a in ["steps", part_file, "--machine", m, "-o", out, "--compress", "-q", *extra]])
    assert rc == 0
    z = load_npz(out)
    spm = dict(zip(list(z["steppers"]), z["steps_per_mm"]))
    f = float(z["clock_hz"])
    max_err = float(z["max_error_s"])
    for name, end in zip("xyz", END_XYZ):
        t, d = z[name], z[name + "_dir"]
        assert int(np.sum(d, dtype=np.int64)) == round(end * spm[name])
        clocks, rd = decompress_runs(z[name + "_runs"])
        assert np.array_equal(rd, d)
        err = clocks / f - t
        assert err.min() >= -max_err - 0.5 / f - 1e-12 and err.max() <= 0.5 / f + 1e-12


def test_steps_command_rejects_a_bad_jerk_and_names_the_file_of_a_planner_error(tmp_path, capsys):
    from gcodeplan.cli import main

    g = tmp_path / "mill.gcode"
    g.write_text("G21\nG90\nG1 X5 F600\nG1 X5 E2\n")
    rc = main(["steps", str(g), "-o", str(tmp_path / "s.npz"), "--jerk", "-5"])
    assert rc == 2 and "--jerk" in capsys.readouterr().err
    # an extrude-only move on a machine with no acceleration limit for E: the planner's error, file:line
    rc = main(["steps", str(g), "--machine", "grbl", "-o", str(tmp_path / "s.npz")])
    err = capsys.readouterr().err
    assert rc == 2 and f"{g}:4:" in err, err


# --------------------------------------------------------------------------- blends of nearly collinear moves
def test_blend_of_collinear_chords_keeps_every_axis_accel_limit():
    """Bug: chords of one straight line (a slicer splits lines) differ in direction only by rounding; the blend
    there lasts ~1e-19 s and its acceleration was (v·u_out − v·u_in)/(2τ): the rounding of the two products
    over a τ that small gave up to 1.28× the E limit (6400 mm/s² with M201 E5000 on the marlin preset).
    The acceleration of a blend is v·Δu/(2τ) = Δu/(2c), which the corner constant c keeps within each limit."""
    mach = replace(load_machine("marlin"), blend_tolerance=0.05)
    a_e = mach.axes["e"].max_accel
    worst = 0.0
    for seed in range(12):
        rng = np.random.default_rng(seed)
        d, p0 = rng.uniform(-5, 5, 2), rng.uniform(50, 150, 2)
        pts = [(p0[0] + k * d[0], p0[1] + k * d[1], 0.2, 0.03 * k * math.hypot(*d)) for k in range(12)]
        mv = moves_from_points(pts, feed_v=50.0, accel=1250.0)
        mv["blend_p"] = math.nan
        _, segs = plan_with_segments(mv, mach.limits_row(), mach, "blend")
        worst = max(worst, float(np.abs(segs["ae"]).max()) / a_e)
        for ax in "xyz":
            assert np.abs(segs["a" + ax]).max() <= mach.axes[ax].max_accel * (1 + 1e-12)
    assert worst <= 1.0 + 1e-12


# --------------------------------------------------------------------------- estimate JSON accounts for every second
PRINT = """G21
G90
M83
G28
G1 Z0.3 F600
G1 X5 Y5 F6000
G1 X60 Y5 E3 F1500
;LAYER_CHANGE
;Z:0.2
G1 Z0.2 F600
G1 X10 Y10 F6000
G1 X30 Y10 E1 F1800
G1 X30 Y30 E1
G1 X10.5 Y31 E1
G1 X10 Y12 E1
G1 E-0.8 F2400
G4 P250
;LAYER_CHANGE
;Z:0.4
G1 Z0.4 F600
G1 E0.8 F2400
G1 X30 Y10 E1 F1800
G1 X30.2 Y10.3 E0.02
G1 X30.5 Y10.4 E0.02
G1 X10 Y30 E1
"""


@pytest.mark.parametrize("extra", [[], ["--policy", "blend"], ["--jerk", "20000"], ["--policy", "exact-stop"]])
def test_estimate_json_breakdowns_each_sum_to_the_total(tmp_path, capsys, extra):
    """Bugs: the moves before the first layer change (homing, purge line) were in no layer, so the layers summed
    to less than the total; in blend mode the blend halves were in no phase, so accelerating + cruising +
    decelerating + dwell + waits fell short of the total. Now `before_first_layer_s` and `blending_s` close both
    sums; kinds, limits and features sum to the total as before."""
    from gcodeplan.cli import main

    g = tmp_path / "print.gcode"
    g.write_text(PRINT)
    m = tmp_path / "m.toml"
    # S-curves (--jerk) are the generic planner's: a firmware machine refuses --jerk
    firmware = 'firmware = "generic"\n' if "--jerk" in extra else ""
    m.write_text(f'base = "marlin"\n{firmware}[junction]\nblend_tolerance = 0.05\n')
    assert main(["estimate", "--json", "-q", "--machine", str(m), str(g), *extra]) == 0
    d = json.loads(capsys.readouterr().out)
    total = d["total_time_s"]
    assert total > 1.0
    close = lambda x: x == pytest.approx(total, rel=1e-12)  # noqa: E731
    assert close(d["print_time_s"] + d["travel_time_s"] + d["extrude_only_time_s"] + d["dwell_s"] + d["waits_s"])
    assert close(sum(d["limits_s"].values()))
    assert close(sum(d["features"].values()))
    assert d["before_first_layer_s"] > 0.5 and len(d["layers"]) == 2
    assert close(d["before_first_layer_s"] + sum(L["time_s"] for L in d["layers"]))
    assert close(d["accelerating_s"] + d["cruising_s"] + d["decelerating_s"] + d["blending_s"] + d["dwell_s"]
                 + d["waits_s"])
    assert (d["blending_s"] > 0) == (extra == ["--policy", "blend"])


# --------------------------------------------------------------------------- Marlin M205 S / T
@pytest.mark.parametrize("policy", ["junction-deviation", "classic-jerk", "exact-stop"])
def test_m205_minimum_feeds_follow_marlin_s_for_any_e_motion_t_otherwise(policy):
    """Marlin planner.cpp: `if (esteps) NOLESS(fr, min_feedrate) else NOLESS(fr, min_travel_feedrate)`: S floors
    every move that steps E, retractions included. Bug: a retraction (E decreasing) took the T floor.
    Each move stands alone (rest to rest, long enough to cruise): time = d/v + v/a."""
    mach = load_machine("marlin")
    lim = mach.limits_row()
    lim["min_feed_v"], lim["min_travel_v"] = 50.0, 5.0
    a = 1e6
    cases = [((0, 0, 0, 0), (100, 0, 0, 1.0), 50.0),     # printing: S
             ((0, 0, 0, 0), (100, 0, 0, -1.0), 50.0),    # wipe with retraction: S (was T)
             ((0, 0, 0, 0), (0, 0, 0, -3.0), 50.0),      # retraction alone: S (was T)
             ((0, 0, 0, 0), (100, 0, 0, 0), 5.0)]        # travel: T
    for start, end, v in cases:
        mv = moves_from_points([start, end], feed_v=1.0, accel=a)
        mv["exact_stop"] = 1
        plan = plan_moves(mv, lim, mach, policy)
        d = float(mv["move_d"][0])
        assert plan["cruise_v"][0] == pytest.approx(v, rel=1e-12), (start, end)
        a_used = plan["accel"][0]   # M201 caps the 1e6 (X 1000, E 5000 mm/s²)
        assert a_used == (5000.0 if end[0] == 0 else 1000.0)
        if policy != "classic-jerk":   # (classic jerk starts and ends at the safe speed, not at rest)
            assert plan["duration"][0] == pytest.approx(d / v + v / a_used, rel=1e-12), (start, end)
    # Klipper has no M205 S/T: the requested feed stands
    mv = moves_from_points([(0, 0, 0, 0), (100, 0, 0, -1.0)], feed_v=1.0, accel=a)
    assert plan_moves(mv, lim, mach, "klipper")["cruise_v"][0] == pytest.approx(1.0, rel=1e-12)


def test_blend_policy_with_a_jerk_limit_is_refused_not_silently_replaced():
    from gcodeplan.errors import ConfigError
    from gcodeplan.planner import StreamPlanner, plan_moves

    m = load_machine("klipper")
    moves = moves_from_points([(0, 0, 0, 0), (10, 0, 0, 0), (10, 10, 0, 0)])
    with pytest.raises(ConfigError, match="blend policy and S-curves"):
        plan_moves(moves, m.limits_row(), m, "blend", jerk=1e4)
    with pytest.raises(ConfigError, match="blend policy and S-curves"):
        StreamPlanner(m, "blend", jerk=1e4).feed(moves, m.limits_row())
