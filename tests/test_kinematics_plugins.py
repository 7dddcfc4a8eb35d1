"""Kinematics as plug-ins through one step engine, against real Klipper (../shared/reference/klipper/kinematics/).

Klipper's polar, rotary_delta, winch, deltesian, hybrid_corexy, hybrid_corexz and generic_cartesian, each a
plug-in (gcodeplan.kinematics.plugin) read from Klipper's own printer.cfg: totals within 1e-9 relative, the
same step count and net steps per motor, and every step within 100 ns of Klipper's (the plug-in motors run
Klipper's own search, itersolve.c, with the inverse kinematics as its position callback), in the step-generation
windows of Klipper's batch mode that made the reference (gcodeplan.stepper.klipper_batch: its search restarts at each
window, and on a slowly turning angle motor where it restarts moves a step by up to ~0.3 µs).
A user's polar, written in this file outside the package, gives the built-in's steps bit for bit.
"""
from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import shared_path
from gcodeplan.errors import ConfigError, GcodeError

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))
import compare_kinematics as ck  # noqa: E402

TOL_S = 100e-9
CONFIGS = ck.CONFIGS
FAST_FILES = ck.FILES


def kin_ref():
    """Skips (not vanishes) without ../shared; the tool reads from there."""
    shared_path("reference", "klipper", "kinematics", "times.json")
    ck.KIN = shared_path("reference", "klipper", "kinematics")
    ck.SHARED = ck.KIN.parents[2]


def run_case(name, config):
    kin_ref()
    info, ref = ck.reference(name, config)
    m = ck.machine(config)
    lines = ck.source_lines(name, config)
    assert ck.total(lines, m) == pytest.approx(info["total_time_s"], rel=1e-9, abs=0)
    ours = ck.klipper_steps(lines, m, ck.batch_windows(lines, m))
    figures = info["steps"]["steppers"]
    assert set(ours) == set(figures)
    worst = {}
    for motor, (t, d) in ours.items():
        full = figures[motor]
        assert len(t) == full["n_steps"], f"{motor}: {len(t)} steps, Klipper {full['n_steps']}"
        assert int(d.sum(dtype=np.int64)) == full["net_steps"], motor
        rt, rd = ref[motor], ref[motor + "_dir"]
        k = len(rt)      # the cube's npz holds an exact prefix
        assert np.array_equal(d[:k], rd), f"{motor}: directions differ"
        worst[motor] = float(np.max(np.abs(t[:k] - rt))) if k else 0.0
    return ours, ref, worst, m, lines


@pytest.mark.parametrize("config", CONFIGS)
@pytest.mark.parametrize("name", FAST_FILES)
def test_matches_klipper(name, config):
    """Every step of the synthetic files within 100 ns of Klipper's, no exception."""
    _, _, worst, _, _ = run_case(name, config)
    assert max(worst.values()) < TOL_S, {k: f"{v * 1e9:.1f} ns" for k, v in worst.items()}


@pytest.mark.parametrize("config", ["polar", "rotary_delta", "winch", "deltesian"])
def test_klippers_own_windows_give_klippers_steps(config):
    """With Klipper's recorded batch windows (the compression reference's run of d_slicer_like, whose batch mode
    jumps from 25 s to 33 s), the search restarts where Klipper's did, and every step of the non-linear motors is
    Klipper's to two clock ticks (40 ns; 74 ns on rotary delta's arm b with regular 0.25 s windows)."""
    kin_ref()
    sched = ck.batch_schedule("d_slicer_like")
    if sched is None:
        pytest.skip("no recorded batch windows (../shared/reference/klipper/compression)")
    assert np.any(np.diff(sched) > 1.0)          # the jump that the regular windows miss
    info, ref = ck.reference("d_slicer_like", config)
    m = ck.machine(config)
    ours = ck.klipper_steps(ck.source_lines("d_slicer_like", config), m, sched)
    ok, worst = ck.compare_steps(ours, ref, info["steps"]["steppers"])
    assert ok and worst < 40e-9, f"{worst * 1e9:.1f} ns"


@pytest.mark.slow
@pytest.mark.parametrize("config", CONFIGS)
def test_cube_matches_klipper(config):
    """Every step of the cube's first 25 layers within 100 ns of Klipper's on every motor, the angle motors
    included (with regular 0.25 s windows polar's bed is 310 ns off: tests/test_klipper_batch.py)."""
    _, _, worst, _, _ = run_case(ck.CUBE, config)
    assert max(worst.values()) < TOL_S, {k: f"{v * 1e9:.1f} ns" for k, v in worst.items()}


# ----------------------------------------------------------------- a user's plug-in, outside the package

def user_polar():
    """Klipper's polar written by a user: bed angle and arm radius by ik functions, Z linear, the centre rule."""
    import numba

    import gcodeplan as gp

    @numba.njit
    def bed(x, y, z, p):
        return math.atan2(y, x)

    @numba.njit
    def arm(x, y, z, p):
        return math.sqrt(x * x + y * y)

    @numba.njit
    def limits(move, p):
        x0, y0, x1, y1 = move[0], move[1], move[3], move[4]
        if x1 * x1 + y1 * y1 > p[0]:
            return math.inf, math.inf, 1
        if x0 == x1 and y0 == y1:
            return math.inf, math.inf, 0
        ab_x, ab_y = x1 - x0, y1 - y0
        dot = ab_x * -x0 + ab_y * -y0
        ab_len = math.sqrt(ab_x ** 2 + ab_y ** 2)
        if dot <= 0:
            dist = math.sqrt(x0 ** 2 + y0 ** 2)
        elif dot >= ab_len ** 2:
            dist = math.sqrt(x1 ** 2 + y1 ** 2)
        else:
            dist = abs(ab_x * -y0 - ab_y * -x0) / ab_len
        if dist == 0.0:
            return math.inf, math.inf, 0
        omega = math.sqrt(move[7]) / dist
        if omega > p[1]:
            return p[2] * p[1] / omega, p[3] * p[1] / omega, 0
        return math.inf, math.inf, 0

    def params(machine):
        kp = machine.kinematics_params
        return [kp["arm_max"] ** 2, kp["max_angular_velocity"], kp["max_velocity"], kp["max_accel"]]

    plugin = gp.kinematics.Plugin(
        {"bed": bed, "arm": arm, "z": (0, 0, 1)},
        {"bed": lambda m: m.kinematics_params["bed_steps_per_rad"],
         "arm": lambda m: m.kinematics_params["arm_steps_per_mm"]},
        params=params, check_move=limits, periods={"bed": 2 * math.pi},
        klipper_names={"bed": "stepper_bed", "arm": "stepper_arm", "z": "stepper_z"})
    return gp.kinematics.register("users_polar", plugin, replace=True)


def test_a_users_plugin_equals_the_builtin_it_reimplements():
    kin_ref()
    user_polar()
    lines = ck.source_lines("d_slicer_like", "polar")
    builtin = ck.machine("polar")
    mine = ck.machine("polar")
    mine.kinematics = "users_polar"
    assert ck.total(lines, mine) == ck.total(lines, builtin)
    a, b = ck.klipper_steps(lines, builtin), ck.klipper_steps(lines, mine)
    assert list(a) == list(b)
    for motor in a:
        assert np.array_equal(a[motor][0], b[motor][0]) and np.array_equal(a[motor][1], b[motor][1]), motor


# ----------------------------------------------------------------- limits hooks, hand-worked

def polar_machine(**kp):
    from gcodeplan.machine import Machine

    m = Machine(kinematics="polar", flavor="klipper", max_velocity=300.0, max_accel=3000.0)
    m.kinematics_params = {"bed_steps_per_rad": 64000 / (2 * math.pi), "arm_steps_per_mm": 80.0, "arm_max": 300.0,
                           "max_angular_velocity": 3.0, **kp}
    return m


def test_polar_centre_rule_caps_a_radial_move_by_hand():
    """A radial travel 30,30 → 120,120 at 150 mm/s: d = 42.43 mm, ω = 150/42.43 = 3.54 rad/s > 3, so the
    accel is capped at 3000·3/ω = 2545.58 mm/s² (the README's line 8) and the speed cap 300·3/ω is above 150."""
    from gcodeplan import api as gp

    prog = ["SET_KINEMATIC_POSITION X=30 Y=30 Z=0", "G1 X120 Y120 F9000"]
    plan = gp.plan(prog, polar_machine())
    d = math.hypot(90, 90)
    omega = 150.0 / math.hypot(30, 30)
    accel = 3000.0 * 3.0 / omega
    # trapezoid 0 → 150 → 0 at that accel
    expect = d / 150.0 + 150.0 / accel
    assert plan.total_time_s == pytest.approx(expect, rel=1e-12)
    assert accel == pytest.approx(2545.58, abs=0.01)


def test_polar_refuses_a_move_beyond_the_arm():
    from gcodeplan import api as gp

    with pytest.raises(GcodeError, match="Move out of range"):
        gp.estimate(["SET_KINEMATIC_POSITION X=30 Y=30 Z=0", "G1 X200 Y250 F3000"], polar_machine())


def test_rotary_delta_z_rule_caps_speed_not_accel():
    """A pure 0.2 mm Z hop on the reference rotary delta: capped at max_z_velocity 15 mm/s, full 3000 mm/s²
    accel (no Z ratio, no max_z_accel): a triangle of peak √(0.2·3000) = 24.5 > 15, so a trapezoid at 15."""
    from gcodeplan import api as gp

    kin_ref()
    m = ck.machine("rotary_delta")
    plan = gp.plan(["SET_KINEMATIC_POSITION X=0 Y=0 Z=0", "G1 Z0.2 F6000"], m)
    expect = 0.2 / 15.0 + 15.0 / 3000.0
    assert plan.total_time_s == pytest.approx(expect, rel=1e-12)


def test_deltesian_slow_zone_applies_the_intended_limit():
    """Klipper 0.13 crashes here (it reads max_velocity it never set); we apply the config's maxima × ½:
    a move to x = 170 (past √slow_x2 = 166.39, before √very_slow_x2 = 177.73) runs at ≤ 150 mm/s, 1500 mm/s²."""
    from gcodeplan import api as gp

    kin_ref()
    m = ck.machine("deltesian")
    plan = gp.plan(["SET_KINEMATIC_POSITION X=0 Y=0 Z=0", "G1 X170 F18000"], m)
    expect = 170.0 / 150.0 + 150.0 / 1500.0
    assert plan.total_time_s == pytest.approx(expect, rel=1e-12)


def test_winch_has_no_limits():
    from gcodeplan import api as gp

    kin_ref()
    m = ck.machine("winch")
    assert math.isinf(m.axes["z"].max_velocity)
    plan = gp.plan(["SET_KINEMATIC_POSITION X=0 Y=0 Z=0", "G1 Z30 F6000"], m)
    assert plan.total_time_s == pytest.approx(30.0 / 100.0 + 100.0 / 3000.0, rel=1e-12)


# ----------------------------------------------------------------- the interface

def test_register_refuses_builtins_and_bad_plugins():
    import gcodeplan as gp

    with pytest.raises(ConfigError, match="built-in"):
        gp.kinematics.register("polar", gp.kinematics.Plugin({"x": (1, 0, 0)}))
    with pytest.raises(ConfigError, match="rails"):
        gp.kinematics.register("thing", object())
    with pytest.raises(ConfigError, match="weights"):
        gp.kinematics.Plugin({"x": (0, 0, 0)})
    with pytest.raises(ConfigError, match="steps_per_unit is required"):
        gp.kinematics.Plugin({"x": lambda x, y, z, p: x}).rails(None)


def test_a_machine_file_names_a_plugin_and_its_params(tmp_path):
    """kinematics = "polar" with its [kinematics_params] in a machine TOML, and the TOML twin round trip."""
    from gcodeplan.config import load_machine, machine_to_toml

    p = tmp_path / "polar.toml"
    p.write_text('kinematics = "polar"\nflavor = "klipper"\n[kinematics_params]\nbed_steps_per_rad = 10185.916357881302\n'
                 'arm_steps_per_mm = 80.0\narm_max = 300.0\nmax_angular_velocity = 3.0\n')
    m = load_machine(str(p))
    assert m.kinematics == "polar" and m.kinematics_params["arm_max"] == 300.0
    q = tmp_path / "twin.toml"
    q.write_text(machine_to_toml(m))
    assert load_machine(str(q)) == m


def test_cli_plugin_file_registers_a_kinematics(tmp_path, capsys):
    """--plugin FILE.py registers a kinematics that the machine file then names (a user's skewed gantry); the
    machine file alone is refused naming it."""
    from gcodeplan.cli import main
    from gcodeplan.kinematics import plugin

    plug = tmp_path / "gantry.py"
    plug.write_text("import gcodeplan as gp\n"
                    "gp.kinematics.register('skew_gantry', gp.kinematics.Plugin({'a': (1, 0.01, 0), 'y': (0, 1, 0),"
                    " 'z': (0, 0, 1)}), replace=True)\n")
    mach = tmp_path / "m.toml"
    mach.write_text('kinematics = "skew_gantry"\n')
    gcode = tmp_path / "p.gcode"
    gcode.write_text("G1 X10 Y10 F3000\n")
    plugin._REGISTRY.pop("skew_gantry", None)
    assert main(["estimate", "--quiet", "--machine", str(mach), str(gcode)]) != 0
    assert "skew_gantry" in capsys.readouterr().err
    assert main(["estimate", "--quiet", "--plugin", str(plug), "--machine", str(mach), str(gcode)]) == 0
    plugin._REGISTRY.pop("skew_gantry", None)


# ----------------------------------------------------------------- the engine against closed forms

def _line_rows(x0, y0, vx, vy, spans):
    """SEGMENT rows of a straight line at constant velocity (vx, vy) mm/s from (x0, y0), one row per span (s)."""
    from gcodeplan.schema import SEGMENT_DTYPE

    seg = np.zeros(len(spans), SEGMENT_DTYPE)
    t = np.concatenate(([0.0], np.cumsum(spans)[:-1]))
    seg["t0"], seg["dt"] = t, spans
    seg["px"], seg["py"] = x0 + vx * t, y0 + vy * t
    seg["vx"], seg["vy"] = vx, vy
    seg["move"] = np.arange(len(spans))
    return seg


def _ik_rail(fn, params, step):
    from gcodeplan.kinematics import Rail

    return Rail("m", 1.0 / step, None, ik=fn, ik_params=tuple(params))


def test_engine_finds_both_crossings_around_a_turning_point():
    """An arm radius r = √(d² + (v·t − s0)²) along a straight line passing the centre at d = 20 mm: the radius
    falls, turns at t = s0/v and rises. Every half-step crossing is at t = (s0 ± √(r*² − d²))/v (closed form);
    the reversal steps on the other side's half-step point (the hysteresis). Klipper's search takes a time
    within 1 ns of the crossing or a position within 1e-9 mm of it (itersolve.c): every step must be one of those."""
    from gcodeplan.kinematics.polar import arm_radius
    from gcodeplan.stepper.generate import generate_steps

    d, s0, v, step = 20.0, 30.0, 100.0, 0.0125
    seg = _line_rows(-s0, d, v, 0.0, np.array([0.6]))
    t, dirs = generate_steps(seg, rails=[_ik_rail(arm_radius, (), step)])["m"]
    r0 = math.hypot(s0, d)
    r_end = math.hypot(v * 0.6 - s0, d)
    down = np.arange(1, 10_000)
    down_r = r0 - (down - 0.5) * step
    down_r = down_r[down_r > d]
    n_down = len(down_r)
    last = r0 - n_down * step              # commanded radius at the turn
    up_r = last + (np.arange(1, 10_000) - 0.5) * step
    up_r = up_r[up_r <= r_end]
    expect = np.concatenate(((s0 - np.sqrt(down_r ** 2 - d * d)) / v, (s0 + np.sqrt(up_r ** 2 - d * d)) / v))
    assert len(t) == len(expect)
    assert np.array_equal(dirs, np.r_[-np.ones(n_down), np.ones(len(up_r))].astype(np.int8))
    r_at = np.hypot(v * t - s0, d)
    r_target = np.concatenate((down_r, up_r))
    ok = (np.abs(t - expect) <= 1e-9 + 1e-15) | (np.abs(r_at - r_target) <= 1e-9 + 1e-13)
    assert ok.all(), np.flatnonzero(~ok)[:5]
    # and the search is no looser than that: most steps are far closer to the crossing than 1 ns
    assert np.median(np.abs(t - expect)) < 1e-10


def test_engine_resumes_when_its_output_is_full():
    """The output-full protocol: with a buffer of 10 steps (one window holds more: it grows), the steps equal
    those made with one big buffer, bit for bit."""
    from gcodeplan.kinematics.winch import cable_length
    from gcodeplan.stepper.generate import StepGenerator

    rail = _ik_rail(cable_length, (110.0, -290.0, -20.0), 1 / 80)
    seg = _line_rows(0.0, 0.0, 50.0, 20.0, np.full(4, 0.25))

    def run(chunk):
        parts = []
        gen = StepGenerator([rail], lambda si, t, d: parts.append((t.copy(), d.copy())), chunk_steps=chunk)
        gen.feed(seg[:2])
        gen.feed(seg[2:])
        gen.finish()
        return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts]), len(parts)

    big_t, big_d, _ = run(1 << 16)
    small_t, small_d, n_parts = run(10)
    assert n_parts > 1 and len(big_t) > 100
    assert np.array_equal(small_t, big_t) and np.array_equal(small_d, big_d)


def test_engine_refuses_a_position_the_kinematics_cannot_give():
    """A motor position √(100 − x²) mm along x = 0 → 15 mm: no position past x = 10 (NaN), which the search would
    otherwise take for a step: a clear error naming the motor and the time, no steps made up."""
    import numba

    from gcodeplan.stepper.generate import generate_steps

    @numba.njit
    def half_circle(x, y, z, p):
        return math.sqrt(100.0 - x * x)

    seg = _line_rows(0.0, 0.0, 15.0, 0.0, np.array([0.5, 0.5]))
    with pytest.raises(ConfigError, match=r"m: the kinematics cannot reach the position at t = 0\.5 s"):
        generate_steps(seg, rails=[_ik_rail(half_circle, (), 0.01)])


@pytest.mark.parametrize("config", CONFIGS)
def test_klipper_configs_have_a_toml_twin_with_the_same_steps(config, tmp_path):
    """Each reference printer.cfg read, written as a machine TOML (kinematics + [kinematics_params]) and read
    back: an equal machine, with the same motors."""
    from gcodeplan.config import load_machine, machine_to_toml
    from gcodeplan.kinematics import rails_for

    kin_ref()
    m = ck.machine(config)
    p = tmp_path / f"{config}.toml"
    p.write_text(machine_to_toml(m))
    twin = load_machine(str(p))
    assert twin.kinematics == config and twin.kinematics_params == m.kinematics_params
    assert rails_for(twin, klipper_names=True) == rails_for(m, klipper_names=True)


@pytest.mark.parametrize("policy,firmware,match", [
    ("blend", None, "kinematics 'polar': its speed limits .* not by the blend planner"),
    ("linuxcnc", None, "kinematics 'polar': its speed limits .* not by the linuxcnc planner"),
    ("junction-deviation", "grbl-1.1", "grbl-1.1 firmware model steps a cartesian machine, not 'polar'"),
    ("classic-jerk", "marlin-2.1.2", "kinematics 'polar': its speed limits .* not by marlin-2.1.2")])
def test_a_planner_that_would_skip_the_limits_hook_refuses(policy, firmware, match):
    """Polar's centre rule is applied by the shared preparation; the blend and LinuxCNC planners and the firmware
    models prepare their own rows: on a polar machine they are an error naming the kinematics, not a plan
    without its limits. The look-ahead policies plan it (the hand-worked cap above)."""
    from gcodeplan import api as gp

    m = polar_machine()
    if firmware:
        m.firmware = firmware
    lines = ["G1 X30 Y30 F9000", "G1 X120 Y120"]
    with pytest.raises(ConfigError, match=match):
        gp.estimate(lines, m, policy)      # a firmware model runs with a policy it has
    m.firmware = "generic"
    assert gp.estimate(lines, m, "junction-deviation").time.total_time_s > 0
