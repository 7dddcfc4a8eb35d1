"""Linear delta kinematics against Klipper (../shared/reference/klipper/extensions/, delta.cfg and delta_wide.cfg)
and against closed forms.

Klipper's reference: totals (its planner with DeltaKinematics.check_move's slow zones), the e_spiral20k refusal
("Move out of range" at line 5247 on delta.cfg) and exact step times per tower (its 50 MHz clocks after the
step+dir+step filter). Ours: same totals within 1e-9 relative, same step counts and directions on every
tower, every step within 100 ns. The closed forms: the carriage height z + √(L² − (x − t_x)² − (y − t_y)²)
at every step time lands on the step's half-step point, also where a carriage reverses while the head moves
straight and when X/Y are input-shaped; the slow-zone speed caps give the hand-worked trapezoid times.
"""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from conftest import compare_with_klipper_steps, shared_path
from gcodeplan.errors import ConfigError, GcodeError
from gcodeplan.kinematics import rails_for
from gcodeplan.kinematics.delta import DeltaGeometry
from gcodeplan.machine import Machine
from gcodeplan.stepper.generate import KLIPPER_SDS_FILTER_T, generate_steps
from gcodeplan.stepper.shaping import ShapedStream, as_segments, shaper_pulses
from gcodeplan.stepper.synth import line_segments, polyline_segments

TOL_S = 100e-9
CUBE = "prusaslicer25_cube20_marlin2"
SYNTHETIC = ["a_long_x", "b_square", "c_circle200", "d_slicer_like"]


def ext(*parts):
    return shared_path("reference", "klipper", "extensions", *parts)


def times_json():
    return json.loads(ext("times.json").read_text())


def source(name):
    """The G-code as Klipper ran it: the cube's G28 became SET_KINEMATIC_POSITION X=0 Y=0 Z=0 (the reference
    README's preprocessing; on a delta, G28 would go to the top of the build volume), line numbers kept."""
    if name != CUBE:
        return str(shared_path("reference", "klipper", "synthetic", f"{name}.gcode"))
    lines = shared_path("gcode", f"{CUBE}.gcode").read_text().splitlines()
    return ["SET_KINEMATIC_POSITION X=0 Y=0 Z=0" if ln.split(";")[0].strip() == "G28" else ln for ln in lines]


def klipper_machine(cfg):
    from gcodeplan.config import load_klipper_config

    return load_klipper_config(str(ext(f"{cfg}.cfg")))


def klipper_steps(src, machine):
    """{stepper: (times, dirs)} through the pipeline and the step sink, with Klipper's step+dir+step filter."""
    from gcodeplan import pipeline
    from gcodeplan.stepper.source import StepSink

    rails = rails_for(machine, klipper_names=True)
    parts: dict[int, list] = {}

    def sink(si, t, d):
        parts.setdefault(si, []).append((t.copy(), d.copy()))

    pipeline.run(src, machine, sinks=[StepSink(rails, sink, sds_filter_t=KLIPPER_SDS_FILTER_T, machine=machine)])
    return {r.name: (np.concatenate([c[0] for c in parts[i]]) if parts.get(i) else np.empty(0),
                     np.concatenate([c[1] for c in parts[i]]) if parts.get(i) else np.empty(0, np.int8))
            for i, r in enumerate(rails)}


def compare(ours, ref, figures, truncated_at=None):
    return compare_with_klipper_steps(ours, ref, figures, TOL_S, truncated_at)


def total(src, machine):
    import gcodeplan.api as gp

    return gp.estimate(src, machine).total_time_s


# ----------------------------------------------------------------- Klipper's reference

@pytest.mark.parametrize("cfg", ["delta", "delta_wide"])
def test_geometry_is_klippers(cfg):
    """Every number Klipper's delta.py derived (times.json → delta), bit for bit."""
    ref = next(c["delta"] for f in times_json().values() if isinstance(f, dict) and "configs" in f
               for name, c in f["configs"].items() if name == cfg and "delta" in c)
    g = DeltaGeometry.from_machine(klipper_machine(cfg))
    for key in ("slow_xy2", "very_slow_xy2", "max_xy2", "limit_z", "max_z", "min_z"):
        assert getattr(g, key) == ref[key], key
    assert list(g.abs_endstops) == ref["abs_endstops"]
    assert [list(t) for t in g.towers_xy] == ref["towers_xy"]      # tower c's x is 1.2e-14, not 0
    assert list(g.arm_lengths) == ref["arm_lengths"] and g.radius == ref["radius"]


CASES = [(n, "delta") for n in SYNTHETIC] + [("e_spiral20k", "delta_wide")]


@pytest.mark.parametrize("name, cfg", CASES)
def test_synthetic_files_match_klipper(name, cfg):
    info = times_json()[f"{name}.gcode"]["configs"][cfg]
    machine = klipper_machine(cfg)
    assert total(source(name), machine) == pytest.approx(info["total_time_s"], rel=1e-9, abs=0)
    ref = np.load(ext("steps", f"{name}_{cfg}_exact_steps.npz"))
    compare(klipper_steps(source(name), machine), ref, info["steps"]["steppers"])


@pytest.mark.slow
def test_cube_matches_klipper():
    """The cube: the park move at line 7441 (r = 200 mm, very slow zone) is the whole +0.031 s over cartesian;
    steps before t = 250 s (the npz window) step for step, full counts from times.json."""
    info = times_json()[f"{CUBE}.gcode"]["configs"]["delta"]
    machine = klipper_machine("delta")
    assert total(source(CUBE), machine) == pytest.approx(info["total_time_s"], rel=1e-9, abs=0)
    ref = np.load(ext("steps", f"{CUBE}_delta_exact_steps.npz"))
    compare(klipper_steps(source(CUBE), machine), ref, info["steps"]["steppers"],
            truncated_at=info["steps"]["truncated_at_s"])


@pytest.mark.parametrize("name, cfg", [("e_spiral20k", "delta_wide"), ("a_long_x", "delta")])
def test_moves_in_the_slow_zones_are_klippers(name, cfg):
    """The source lines of the moves that reach each slow zone (extreme of start and end x² + y² beyond
    slow_xy2 / very_slow_xy2), as Klipper's check_move found them (times.json → delta.moves_in_slow_zone)."""
    from gcodeplan.gcode import read_moves

    ref = times_json()[f"{name}.gcode"]["configs"][cfg]["delta"]["moves_in_slow_zone"]
    machine = klipper_machine(cfg)
    g = DeltaGeometry.from_machine(machine)
    mv, _ = read_moves(source(name), machine)
    mv = mv[mv["move_d"] > 0]
    extreme = np.maximum(mv["x0"] ** 2 + mv["y0"] ** 2, mv["x1"] ** 2 + mv["y1"] ** 2)
    very = extreme > g.very_slow_xy2
    slow = (extreme > g.slow_xy2) & ~very
    for zone, ours in (("slow", slow), ("very_slow", very)):
        assert mv["line"][ours].tolist() == ref.get(zone, {}).get("source_lines", []), zone


def test_spiral_is_refused_where_klipper_refuses_it():
    info = times_json()["e_spiral20k.gcode"]["configs"]["delta"]
    line, text = info["klipper_errors_first"][0]
    with pytest.raises(GcodeError) as err:
        total(source("e_spiral20k"), klipper_machine("delta"))
    assert err.value.line == line == 5247
    # "Move out of range: 145.894 139.772 0.200 [87.212]"
    assert err.value.message.startswith(text.removeprefix("!! "))
    assert str(err.value).startswith(f"{source('e_spiral20k')}:5247: Move out of range")


# ----------------------------------------------------------------- closed forms

def delta_machine(**kw):
    m = Machine(kinematics="delta", flavor="klipper", delta_radius=196.0, print_radius=202.0,
                delta_arm_length=(400.0, 400.0, 400.0), delta_position_endstop=(300.0, 300.0, 300.0),
                delta_steps_per_mm=(80.0, 100.0, 80.0))
    m.axes["z"].max_velocity, m.axes["z"].max_accel = 15.0, 100.0
    for k, v in kw.items():
        setattr(m, k, v)
    return m


def eval_segments(seg, t):
    """Head position (n, 3) at times t from SEGMENT rows (the path at rest before and after)."""
    k = np.clip(np.searchsorted(seg["t0"], t, side="right") - 1, 0, len(seg) - 1)
    s = np.clip(t - seg["t0"][k], 0, seg["dt"][k])
    return np.stack([seg["p" + a][k] + s * (seg["v" + a][k] + s * (seg["a" + a][k] / 2 + s * seg["j" + a][k] / 6))
                     for a in "xyz"], axis=1)


def carriage(xyz, angle_deg, radius=196.0, arm=400.0):
    """The closed form, computed here on its own: z + √(L² − (x − t_x)² − (y − t_y)²)."""
    tx, ty = radius * np.cos(np.radians(angle_deg)), radius * np.sin(np.radians(angle_deg))
    return xyz[:, 2] + np.sqrt(arm ** 2 - (xyz[:, 0] - tx) ** 2 - (xyz[:, 1] - ty) ** 2)


def assert_on_half_steps(path_seg, steps, machine):
    """Each step sits on its half-step point of the closed-form carriage height: c(t_k) = c(0) + (n_k − d_k/2)·s,
    n_k the running step count, and the last count holds the end height within half a step."""
    t_end = path_seg["t0"][-1] + path_seg["dt"][-1]
    for name, ang, spm in zip("abc", machine.delta_angle, machine.delta_steps_per_mm):
        t, d = steps[name]
        step = 1.0 / spm
        c0, c_end = carriage(eval_segments(path_seg, np.array([path_seg["t0"][0], t_end])), ang)
        n = np.cumsum(d.astype(np.int64))
        c = carriage(eval_segments(path_seg, t), ang)
        assert np.max(np.abs(c - (c0 + (n - 0.5 * d) * step))) < 1e-9, name
        assert abs(c0 + (n[-1] if len(n) else 0) * step - c_end) <= 0.5 * step + 1e-12, name


def test_a_carriage_reverses_while_the_head_moves_straight():
    """Head along y = 100 from x = −150 to 150: tower c (0, 196) is nearest at x = 0, so its carriage rises
    then falls; the reversal is where the line passes closest to the tower."""
    m = delta_machine()
    seg = line_segments((-150, 100, 5, 0), (150, 100, 5, 0), 0.0, 120.0, 0.0, 2000.0)
    steps = generate_steps(seg, m)
    assert_on_half_steps(seg, steps, m)
    t, d = steps["c"]
    flip = int(np.flatnonzero(d < 0)[0])
    assert np.all(d[:flip] > 0) and np.all(d[flip:] < 0)
    # the head's x at the turn is 0 within one step's worth of carriage travel:
    # c(x) ≈ c_max − x²/(2·√(L² − 96²))
    x_turn = eval_segments(seg, np.array([t[flip - 1], t[flip]]))[:, 0]
    tol = math.sqrt(2 * 1.25e-2 * math.sqrt(400 ** 2 - 96 ** 2))
    assert np.all(np.abs(x_turn) < tol)
    assert len(d) - 2 * abs(int(d.sum())) > 0        # both ways, ending near where it started (symmetric path)


def test_steps_follow_the_closed_form_with_z_motion_and_s_curves():
    from gcodeplan.stepper.synth import scurve_line_segments

    m = delta_machine()
    seg = polyline_segments([(0, 0, 0, 0), (120, -40, 3, 0), (-60, 150, 10, 0), (-100, -100, 0.4, 0)],
                            150.0, 3000.0, junction_v=[20.0, 5.0])
    assert_on_half_steps(seg, generate_steps(seg, m), m)
    seg = scurve_line_segments((-120, 30, 2, 0), (140, -20, 40, 0), 180.0, 4000.0, 80000.0)
    assert_on_half_steps(seg, generate_steps(seg, m), m)


def test_shaping_acts_on_xy_before_the_towers():
    """Input shaping shapes x, y, then the towers follow the shaped point: on the half-step points of the
    carriage of the shaped path; same net steps; far from speed changes the steps are the unshaped ones."""
    m = delta_machine(shaper_freq_x=45.0, shaper_type_y="ei", shaper_freq_y=38.0)
    seg = polyline_segments([(-150, -60, 0.2, 0), (140, -60, 0.2, 0), (140, 90, 0.2, 0), (-20, 120, 0.2, 0)],
                            100.0, 3000.0, junction_v=[5.0, 5.0])
    shaped = generate_steps(seg, m)
    stream = ShapedStream(shaper_pulses("mzv", 45.0), shaper_pulses("ei", 38.0))
    path = np.concatenate([as_segments(stream.feed(seg)), as_segments(stream.finish())])
    assert_on_half_steps(path, shaped, m)
    plain = generate_steps(seg, delta_machine())
    for name in "abc":
        assert int(shaped[name][1].sum()) == int(plain[name][1].sum())
        # the first move's cruise, 40 ms (> the shapers' reach) away from its ends
        cruise = seg[(seg["phase"] == 1)][0]
        lo, hi = cruise["t0"] + 0.04, cruise["t0"] + cruise["dt"] - 0.04
        a = plain[name][0][(plain[name][0] > lo) & (plain[name][0] < hi)]
        b = shaped[name][0][(shaped[name][0] > lo) & (shaped[name][0] < hi)]
        assert len(a) > 100 and len(a) == len(b) and np.allclose(a, b, rtol=0, atol=1e-9), name


def test_slow_zones_and_z_limits_give_the_hand_worked_times():
    """Rest-to-rest moves from the centre along +X on delta.cfg's geometry (300 mm/s, 3000 mm/s²): beyond
    ratio_to_xy(3) = 183.48 mm half the speed and accel, beyond ratio_to_xy(6) = 198.56 mm a quarter;
    t = d/v + v/a once the cruise is reached. Z: max_z_velocity 15, max_z_accel 100."""
    m = delta_machine()
    prog = "SET_KINEMATIC_POSITION X=0 Y=0 Z=0\nG90\nG1 X{x} F18000\n"
    assert total(prog.format(x=180).splitlines(), m) == pytest.approx(180 / 300 + 300 / 3000, abs=1e-12)
    assert total(prog.format(x=190).splitlines(), m) == pytest.approx(190 / 150 + 150 / 1500, abs=1e-12)
    assert total(prog.format(x=200).splitlines(), m) == pytest.approx(200 / 75 + 75 / 750, abs=1e-12)
    # the start point counts too: coming back from r = 190 is slow as well
    back = "SET_KINEMATIC_POSITION X=190 Y=0 Z=0\nG90\nG1 X0 F18000\n"
    assert total(back.splitlines(), m) == pytest.approx(190 / 150 + 150 / 1500, abs=1e-12)
    z = "SET_KINEMATIC_POSITION X=0 Y=0 Z=0\nG90\nG1 Z10 F6000\n"
    assert total(z.splitlines(), m) == pytest.approx(10 / 15 + 15 / 100, abs=1e-12)
    # a cartesian twin is not slowed: the rule is the delta's
    cart = Machine(flavor="klipper")
    assert total(prog.format(x=200).splitlines(), cart) == pytest.approx(200 / 300 + 300 / 3000, abs=1e-12)


def test_moves_out_of_reach_are_refused_with_klippers_text():
    m = delta_machine()
    g = DeltaGeometry.from_machine(m)
    ok = "SET_KINEMATIC_POSITION X=0 Y=0 Z=0\nG90\n"
    total((ok + "G1 X201.9 F6000\n").splitlines(), m)
    with pytest.raises(GcodeError, match=r"<lines>:3: Move out of range: 202\.100 0\.000 0\.000 \[0\.000\]") as err:
        total((ok + "G1 X202.1 F6000\n").splitlines(), m)
    assert err.value.line == 3
    with pytest.raises(GcodeError, match=r"Move out of range: 0\.000 0\.000 -0\.500"):
        total((ok + "G1 Z-0.5\n").splitlines(), m)
    with pytest.raises(GcodeError, match=r"Move out of range: 0\.000 0\.000 300\.100"):
        total((ok + "G1 Z300.1\n").splitlines(), m)
    # above limit_z (= 648.689 − 400) the reach tapers:
    # at z = 290 it is 196 − √(L² − (L − (290 − limit_z))²)
    assert g.limit_z == pytest.approx(300 + math.sqrt(400 ** 2 - 196 ** 2) - 400)
    r290 = 196 - math.sqrt(400 ** 2 - (400 - (290 - g.limit_z)) ** 2)
    total((ok + f"G1 Z290\nG1 X{r290 - 0.01:.3f}\n").splitlines(), m)
    with pytest.raises(GcodeError, match="Move out of range") as err:
        total((ok + f"G1 Z290\nG1 X{r290 + 0.01:.3f}\n").splitlines(), m)
    assert err.value.line == 4
    # an extrude-only move is not checked (Klipper checks moves with XYZ motion only)
    total("SET_KINEMATIC_POSITION X=0 Y=0 Z=0\nM83\nG1 E2 F300\n".splitlines(), m)


# ----------------------------------------------------------------- configuration

def test_klipper_config_defaults_and_toml_twin(tmp_path):
    from gcodeplan.config import load_machine, machine_to_toml

    m = klipper_machine("delta")
    assert m.kinematics == "delta" and m.delta_radius == 196 and m.print_radius == 202
    assert m.delta_arm_length == (400.0,) * 3 and m.delta_position_endstop == (300.0,) * 3   # b, c from a
    assert m.delta_angle == (210.0, 330.0, 90.0) and m.delta_steps_per_mm == (80.0,) * 3
    assert m.axes["z"].max_velocity == 15 and m.axes["z"].max_accel == 100
    assert m.axes["z"].home == pytest.approx(300.0, abs=1e-9)     # G28: carriages at their endstops
    assert [r.name for r in rails_for(m, klipper_names=True)] == ["stepper_a", "stepper_b", "stepper_c", "extruder"]
    p = tmp_path / "d.toml"
    p.write_text(machine_to_toml(m))
    assert load_machine(str(p)) == m
    p.write_text('kinematics = "delta"\nflavor = "klipper"\n[delta]\nradius = 196\nprint_radius = 202\n'
                 'arm_length = 400\nposition_endstop = [300, 300, 300]\nsteps_per_mm = 80\n'
                 '[axis.z]\nmax_velocity = 15\nmax_accel = 100\n[axis.x]\nmax_velocity = inf\n')
    t = load_machine(str(p))
    assert DeltaGeometry.from_machine(t) == DeltaGeometry.from_machine(m)


def test_bad_delta_configs_are_errors(tmp_path):
    from gcodeplan.config import load_klipper_config

    text = ext("delta.cfg").read_text()
    for old, new, msg in (("delta_radius: 196\n", "", r"\[printer\] delta_radius is required"),
                          ("arm_length: 400", "arm_length: 150", r"\[stepper_a\] arm_length: must be above 196"),
                          ("minimum_z_position: 0", "minimum_z_position: 301",
                           r"\[printer\] minimum_z_position: must be at most 300")):
        p = tmp_path / "printer.cfg"
        p.write_text(text.replace(old, new, 1))
        with pytest.raises(ConfigError, match=msg):
            load_klipper_config(str(p))
    with pytest.raises(ConfigError, match="delta_radius"):
        rails_for(Machine(kinematics="delta"))


# ----------------------------------------------------------------- plots: driven motors against commanded

def test_axes_plot_shows_shaped_towers_against_commanded():
    """``plot --what axes`` on a shaped delta: per tower the commanded carriage height (the planned path) and
    the driven one (x, y shaped first), each equal to the closed form at the plotted times."""
    import gcodeplan.api as gp
    from gcodeplan.report import plots

    m = delta_machine(shaper_freq_x=45.0, shaper_type_y="ei", shaper_freq_y=38.0)
    prog = "SET_KINEMATIC_POSITION X=0 Y=0 Z=0\nG90\nG1 X120 Y-30 F9000\nG1 X-40 Y150\nG1 X0 Y0 Z2\n"
    plan = gp.plan(prog.splitlines(), m)
    win = plots.Window(plan.moves, plan.plan, plan.segments, limits=plan.limits)
    fig = plots.plot_axes(win, m)
    px, py = shaper_pulses("mzv", 45.0), shaper_pulses("ei", 38.0)
    for name, ang in zip("abc", m.delta_angle):
        t, cmd = (np.asarray(v, float) for v in line_by_gid(fig, f"cmd_{name}").get_data())
        _, drv = (np.asarray(v, float) for v in line_by_gid(fig, f"motor_{name}").get_data())
        xyz = eval_segments(plan.segments, t)
        assert np.allclose(cmd, carriage(xyz, ang), rtol=0, atol=1e-9)
        # shaped: x_s(t) = Σ a_i·x(t + τ_i), likewise y; z unshaped
        shaped = xyz.copy()
        for q, (a, tau) in ((0, px), (1, py)):
            shaped[:, q] = sum(w * eval_segments(plan.segments, t + s)[:, q] for w, s in zip(a, tau))
        assert np.allclose(drv, carriage(shaped, ang), rtol=0, atol=1e-9)
        assert np.max(np.abs(drv - cmd)) > 1e-3          # shaping shows (corners at 150 mm/s)
    # an unshaped cartesian machine keeps its plot as it was: no motor rows
    fig = plots.plot_axes(win, Machine())
    assert not any(str(ln.get_gid()).startswith("motor_") for ax in fig.axes for ln in ax.get_lines())


def line_by_gid(fig, gid):
    found = [ln for ax in fig.axes for ln in ax.get_lines() if ln.get_gid() == gid]
    assert len(found) == 1, f"{gid}: {len(found)} lines"
    return found[0]
