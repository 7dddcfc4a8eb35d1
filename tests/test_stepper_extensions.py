"""Input shaping and pressure advance against Klipper's exact steps (../shared/reference/klipper/extensions/).

Klipper's times are its 50 MHz step clocks after its step+dir+step filter (README "Common step
convention"). On shaped and pressure-advanced motors we run Klipper's own search (itersolve), which skips
excursions past a half-step point that fall between its probes; the result is the same count per stepper,
same directions, every step within 100 ns (in practice within 13 ns). The cube's reference files stop at
t = 250 s; its full counts are in times.json. Plus properties that need no reference: shaping keeps a constant-speed stretch far from any
speed change, the shaped path ends where the commanded one does, K = 0 is the identity, and neither
feature changes the planned times.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import compare_with_klipper_steps, shared_path
from gcodeplan.kinematics import rails_for
from gcodeplan.machine import Machine
from gcodeplan.stepper.generate import KLIPPER_SDS_FILTER_T, generate_steps
from gcodeplan.stepper.pressure_advance import SmoothedStream
from gcodeplan.stepper.shaping import ShapedStream, as_segments, shaper_coefficients, shaper_pulses
from gcodeplan.stepper.synth import line_segments, polyline_segments

TOL_S = 100e-9
CUBE = "prusaslicer25_cube20_marlin2"
SYNTHETIC = ["a_long_x", "b_square", "c_circle200", "d_slicer_like", "e_spiral20k"]


def ext(*parts):
    return shared_path("reference", "klipper", "extensions", *parts)


def gcode_path(name):
    if name == CUBE:
        return shared_path("gcode", f"{CUBE}.gcode")
    return shared_path("reference", "klipper", "synthetic", f"{name}.gcode")


def run_steps(source, machine, rails, sink_fn, sds_filter_t=None, flush_times=None):
    """The pipeline with a step sink (the machine's shaper / pressure advance, and mid-file changes);
    ``flush_times``: Klipper's step-generation windows (default: every 0.25 s)."""
    from gcodeplan import pipeline
    from gcodeplan.stepper.source import StepSink

    if flush_times is None:
        return pipeline.run(source, machine, sinks=[StepSink(rails, sink_fn, sds_filter_t=sds_filter_t,
                                                             machine=machine)])
    from gcodeplan.stepper.generate import StepGenerator
    from gcodeplan.stepper.source import homing_resets

    class ScheduledSink(pipeline.Sink):
        """StepSink with a given window schedule."""

        def __init__(self):
            self.gen = StepGenerator(rails, sink_fn, sds_filter_t=sds_filter_t, settings=machine.limits_row(),
                                     flush_times=flush_times)
            self.pending = False

        def add(self, piece):
            reset, self.pending = homing_resets(piece.moves, piece.segments, piece.first_move, self.pending)
            self.gen.feed(piece.segments, reset, moves=piece.moves, limits=piece.limits, first_move=piece.first_move)

        def close(self, result):
            self.gen.finish()

    return pipeline.run(source, machine, sinks=[ScheduledSink()])


def batch_schedule(name):
    """Klipper's batch-mode step-generation windows recorded for ``name`` (s from the first move's start), or
    None. Batch mode makes 0.25 s windows but, after 100 of them in one timer call, jumps ahead
    (motion_queuing.py _flush_handler_debug), so some windows depend on how the 4096-byte reads of the file
    fall. The compression reference recorded every call on corexy_corpus.cfg; the same file reads the same
    way under the other configs (their scan windows differ by < 20 ms). Its last two calls (the final flush
    of that config) are left out: our run ends with its own final window."""
    path = shared_path("reference", "klipper", "compression", f"{name}_corexy_queue_step.npz")
    z = np.load(path)
    return (z["step_gen_time_s"] - z["first_move_print_time_s"])[:-2]


def klipper_steps(gcode, cfg, flush_times=None):
    """{stepper: (times, dirs)} and the plan's end time, through the parser, planner and step sink."""
    from gcodeplan.config import load_klipper_config
    machine = load_klipper_config(str(cfg))
    rails = rails_for(machine, klipper_names=True)
    parts: dict[int, list] = {}

    def sink(si, t, d):
        parts.setdefault(si, []).append((t.copy(), d.copy()))

    result = run_steps(str(gcode), machine, rails, sink, sds_filter_t=KLIPPER_SDS_FILTER_T, flush_times=flush_times)
    out = {}
    for si, r in enumerate(rails):
        chunks = parts.get(si, [])
        out[r.name] = (np.concatenate([c[0] for c in chunks]) if chunks else np.empty(0),
                       np.concatenate([c[1] for c in chunks]) if chunks else np.empty(0, np.int8))
    return out, result, machine


def plan_total(gcode, machine):
    import gcodeplan.api as gp

    return gp.estimate(str(gcode), machine).total_time_s


def compare(ours, ref, figures, truncated_at=None):
    return compare_with_klipper_steps(ours, ref, figures, TOL_S, truncated_at)


CASES = [(n, c) for n in SYNTHETIC for c in ("shaper_cartesian", "shaper_corexy", "pa_cartesian")]


@pytest.mark.parametrize("name, cfg", CASES)
def test_synthetic_files_match_klipper(name, cfg):
    times = json.loads(ext("times.json").read_text())[f"{name}.gcode"]["configs"][cfg]
    ref = np.load(ext("steps", f"{name}_{cfg}_exact_steps.npz"))
    ours, _, machine = klipper_steps(gcode_path(name), ext(f"{cfg}.cfg"))
    compare(ours, ref, times["steps"]["steppers"])
    # shaping and pressure advance act on the steps only: the plan keeps Klipper's (= unshaped) total
    assert plan_total(gcode_path(name), machine) == pytest.approx(times["total_time_s"], abs=1e-9)


@pytest.mark.slow
@pytest.mark.parametrize("cfg", ["shaper_cartesian", "shaper_corexy", "pa_cartesian"])
def test_cube_matches_klipper(cfg):
    """Identical counts, net steps and directions on every motor (3.2 M steps on corexy motor A), every step
    within 100 ns, with Klipper's batch-mode windows."""
    info = json.loads(ext("times.json").read_text())[f"{CUBE}.gcode"]["configs"][cfg]
    ref = np.load(ext("steps", f"{CUBE}_{cfg}_exact_steps.npz"))
    ours, _, machine = klipper_steps(gcode_path(CUBE), ext(f"{cfg}.cfg"), flush_times=batch_schedule(CUBE))
    worst = compare(ours, ref, info["steps"]["steppers"], truncated_at=info["steps"]["truncated_at_s"])
    assert worst < 20e-9
    assert plan_total(gcode_path(CUBE), machine) == pytest.approx(info["total_time_s"], abs=1e-9)


@pytest.mark.slow
@pytest.mark.parametrize("cfg", ["shaper_cartesian", "pa_cartesian"])
def test_cube_matches_klipper_with_regular_windows(cfg):
    """The default 0.25 s windows give Klipper's steps too where no skipped batch-mode window matters (on
    shaper_corexy 3 of motor B's back-and-forth pairs depend on the skipped windows: see test above)."""
    info = json.loads(ext("times.json").read_text())[f"{CUBE}.gcode"]["configs"][cfg]
    ref = np.load(ext("steps", f"{CUBE}_{cfg}_exact_steps.npz"))
    ours, _, _ = klipper_steps(gcode_path(CUBE), ext(f"{cfg}.cfg"))
    compare(ours, ref, info["steps"]["steppers"], truncated_at=info["steps"]["truncated_at_s"])


def test_d_slicer_like_matches_klipper_with_its_batch_windows():
    """d_slicer_like with Klipper's recorded batch windows still matches (the windows are an input, not a fit)."""
    name, cfg = "d_slicer_like", "shaper_corexy"
    times = json.loads(ext("times.json").read_text())[f"{name}.gcode"]["configs"][cfg]
    ref = np.load(ext("steps", f"{name}_{cfg}_exact_steps.npz"))
    ours, _, _ = klipper_steps(gcode_path(name), ext(f"{cfg}.cfg"), flush_times=batch_schedule(name))
    compare(ours, ref, times["steps"]["steppers"])


# ----------------------------------------------------------------- shaper definitions

def test_pulses_are_klippers():
    """README figures, as Klipper's kin_shaper.c computes them (mzv 45 Hz on X, ei 38 Hz on Y, ζ = 0.1)."""
    a, tau = shaper_pulses("mzv", 45.0, 0.1)
    assert np.allclose(a, [0.22738275855619269, 0.40748935315116658, 0.36512788829264081], rtol=0, atol=1e-15)
    assert np.allclose(tau, [-0.0095289739959344057, -0.0011536588687743043, 0.007221656258385797],
                       rtol=0, atol=1e-16)
    a, tau = shaper_pulses("ei", 38.0, 0.1)
    assert np.allclose(a, [0.19212053, 0.45299809, 0.35488138], rtol=0, atol=1e-15)
    assert np.allclose(tau, [-0.015320278921397344, -0.0022203403263428498, 0.011128084638055605],
                       rtol=0, atol=1e-16)


@pytest.mark.parametrize("name", ["zv", "mzv", "zvd", "ei", "2hump_ei", "3hump_ei"])
def test_every_shaper_is_normalised_centred_and_cancels_its_frequency(name):
    f, zeta = 50.0, 0.1
    a, tau = shaper_pulses(name, f, zeta)
    assert a.sum() == pytest.approx(1.0, abs=1e-12) and np.dot(a, tau) == pytest.approx(0.0, abs=1e-15)
    amps, delays = shaper_coefficients(name, f, zeta)
    # residual vibration of the damped mode at the design frequency (the shaper's purpose): small
    wd = 2 * np.pi * f * np.sqrt(1 - zeta ** 2)
    t_end = delays[-1]
    decay = np.exp(-zeta * 2 * np.pi * f * (t_end - np.array(delays)))
    resid = np.hypot(np.sum(amps * decay * np.cos(wd * np.array(delays))),
                     np.sum(amps * decay * np.sin(wd * np.array(delays)))) / np.sum(amps)
    assert resid < 0.06, resid
    assert shaper_pulses(name, 0.0, zeta)[0].size == 0


# ----------------------------------------------------------------- properties

def _shaped(seg, px, py):
    s = ShapedStream(px, py)
    return np.concatenate([as_segments(s.feed(seg)), as_segments(s.finish())])


def _eval(seg, ax, t):
    k = np.clip(np.searchsorted(seg["t0"], t, side="right") - 1, 0, len(seg) - 1)
    s = np.clip(t - seg["t0"][k], 0, seg["dt"][k])
    return seg["p" + ax][k] + s * (seg["v" + ax][k] + s * (seg["a" + ax][k] / 2 + s * seg["j" + ax][k] / 6))


def test_shaping_leaves_constant_speed_alone_and_ends_where_commanded():
    seg = line_segments((0, 0, 0, 0), (300, 120, 0, 5), 0.0, 100.0, 0.0, 3000.0)
    px, py = shaper_pulses("mzv", 45.0), shaper_pulses("3hump_ei", 60.0)
    out = _shaped(seg, px, py)
    # continuous, contiguous, time-ordered pieces
    assert np.allclose(out["t0"][1:], out["t0"][:-1] + out["dt"][:-1], rtol=0, atol=1e-12)
    cruise = seg[seg["phase"] == 1][0]
    reach = 0.04
    t = np.linspace(cruise["t0"] + reach, cruise["t0"] + cruise["dt"] - reach, 200)
    for ax in "xyze":
        assert np.allclose(_eval(out, ax, t), _eval(seg, ax, t), rtol=0, atol=1e-9), ax
    end_t = out["t0"][-1] + out["dt"][-1]
    for ax, v in zip("xyze", (300, 120, 0, 5)):
        assert _eval(out, ax, np.array([end_t]))[0] == pytest.approx(v, abs=1e-9)
    # and Z / E untouched everywhere
    t = np.linspace(0, seg["t0"][-1] + seg["dt"][-1], 500)
    assert np.array_equal(_eval(out, "e", t), _eval(seg, "e", t)) or np.allclose(_eval(out, "e", t),
                                                                                _eval(seg, "e", t), atol=1e-12)


def test_shaped_position_is_the_weighted_sum_of_shifted_positions():
    pts = [(0, 0, 0, 0), (30, 0, 0, 0), (30, 25, 0, 0), (5, 40, 0, 0)]
    seg = polyline_segments(pts, 120.0, 2500.0, junction_v=6.0)
    px, py = shaper_pulses("ei", 38.0), shaper_pulses("zvd", 55.0)
    out = _shaped(seg, px, py)
    t = np.linspace(-0.05, seg["t0"][-1] + seg["dt"][-1] + 0.05, 997)
    for ax, (a, tau) in (("x", px), ("y", py)):
        want = sum(w * _eval(seg, ax, t + s) for w, s in zip(a, tau))
        assert np.allclose(_eval(out, ax, t), want, rtol=0, atol=1e-9)


def test_batches_give_the_same_shaped_steps_as_one_array():
    pts = [(0, 0, 0, 0)] + [(10 * k, 7 * (k % 3), 0, 0) for k in range(1, 12)]
    seg = polyline_segments(pts, 150.0, 3000.0, junction_v=5.0)
    m = Machine(kinematics="corexy")
    m.shaper_freq_x, m.shaper_freq_y, m.shaper_type_y = 45.0, 38.0, "ei"
    whole = generate_steps(seg, m)
    parts = generate_steps([seg[i:i + 3] for i in range(0, len(seg), 3)], m)
    for name in whole:
        assert np.array_equal(whole[name][1], parts[name][1])
        assert np.allclose(whole[name][0], parts[name][0], rtol=0, atol=1e-12)


def _smoothed(seg, h, k):
    s = SmoothedStream(h)
    kk = np.full(len(seg), k)
    parts = [s.feed(seg["t0"], seg["dt"], seg["pe"], seg["ve"], seg["ae"], seg["je"], kk), s.finish()]
    return tuple(np.concatenate([p[i] for p in parts]) for i in range(3))


def _eval_poly(t0, dt, c, t):
    k = np.clip(np.searchsorted(t0, t, side="right") - 1, 0, len(t0) - 1)
    s = np.clip(t - t0[k], 0, dt[k])
    return sum(c[k, i] * s ** i for i in range(c.shape[1]))


def test_pressure_advance_is_the_triangle_average_of_e_plus_k_edot():
    seg = line_segments((0, 0, 0, 0), (40, 10, 0, 2.0), 0.0, 60.0, 0.0, 1500.0)
    h, k = 0.02, 0.045
    t0, dt, c = _smoothed(seg, h, k)
    t = np.linspace(-0.03, seg["t0"][-1] + seg["dt"][-1] + 0.03, 301)
    # brute-force quadrature of ∫ pa(x)(h − |t − x|)dx / h², pa = e + K·ė
    w = np.linspace(-h, h, 40001)
    kern = (h - np.abs(w)) / h ** 2

    def pa(x):
        kk = np.clip(np.searchsorted(seg["t0"], x, side="right") - 1, 0, len(seg) - 1)
        s = np.clip(x - seg["t0"][kk], 0, seg["dt"][kk])
        inside = (x >= seg["t0"][0]) & (x <= seg["t0"][-1] + seg["dt"][-1])
        e = seg["pe"][kk] + seg["ve"][kk] * s + seg["ae"][kk] * s * s / 2
        return e + np.where(inside, k * (seg["ve"][kk] + seg["ae"][kk] * s), 0.0)

    want = np.array([np.trapezoid(pa(ti + w) * kern, w) for ti in t])
    assert np.allclose(_eval_poly(t0, dt, c, t), want, rtol=0, atol=2e-7)
    assert _eval_poly(t0, dt, c, np.array([t0[-1] + dt[-1]]))[0] == pytest.approx(2.0, abs=1e-12)


def test_pressure_advance_with_k_zero_is_the_identity():
    pts = [(0, 0, 0, 0), (20, 0, 0, 1.0), (20, 20, 0, 2.0), (20, 20, 0, 1.2), (0, 0, 0, 1.2), (5, 0, 0, 1.5)]
    seg = polyline_segments(pts, 100.0, 3000.0, junction_v=5.0)
    m = Machine()
    m.axes["e"].steps_per_mm = 400.0
    plain = generate_steps(seg, m)
    m.pressure_advance = 0.0
    m.pressure_advance_smooth_time = 0.04
    again = generate_steps(seg, m)
    for name in plain:
        assert np.array_equal(plain[name][0], again[name][0]) and np.array_equal(plain[name][1], again[name][1])
    # and with K > 0: X/Y/Z untouched, E the same net steps, more steps in total (back-and-forth)
    m.pressure_advance = 0.05
    pa = generate_steps(seg, m)
    for name in "xyz":
        assert np.array_equal(plain[name][0], pa[name][0])
    assert int(pa["e"][1].sum()) == int(plain["e"][1].sum())
    assert len(pa["e"][0]) > len(plain["e"][0])


def test_poly_kernel_finds_every_crossing_of_a_wiggle():
    from gcodeplan.stepper import kernel

    # s(τ) = 0.3·sin-like quintic with three turning points inside, step 0.01 mm
    c = np.array([[0.0, 3.0, -20.0, 40.0, -25.0, 0.0]])
    rail_state = kernel.new_state()
    out_t = np.empty(1000)
    out_d = np.empty(1000, np.int8)
    nxt, n, need = kernel.gen_steps_poly(np.array([0.0]), np.array([1.0]), c, np.zeros(1, np.uint8), 0.01,
                                         rail_state, 0, out_t, out_d, 0)
    assert need == 0 and n > 0
    t, d = out_t[:n], out_d[:n]
    pos = sum(c[0, i] * t ** i for i in range(6))
    # every step lands on its half-step point, and the count follows the position
    n_at = np.cumsum(d)
    assert np.allclose(pos, (n_at - 0.5 * d) * 0.01, atol=1e-12)
    final = sum(c[0])
    assert abs(n_at[-1] * 0.01 - final) <= 0.005 + 1e-12


# ----------------------------------------------------------------- mid-file commands

PROGRAM = """G90
M83
G1 X10 Y0 F6000
G1 X40 Y10 E2.0 F3000
G1 X40 Y40 E1.5
G1 E-0.8 F2400
G1 X0 Y0 F9000
G1 E0.8 F2400
G1 X20 Y5 E1.2 F3000
"""


def _program_steps(machine, text):
    rails = rails_for(machine)
    parts: dict[int, list] = {}
    result = run_steps(text.splitlines(), machine, rails,
                          lambda si, t, d: parts.setdefault(si, []).append((t.copy(), d.copy())))
    out = {r.name: (np.concatenate([c[0] for c in parts.get(i, [])]) if parts.get(i) else np.empty(0),
                    np.concatenate([c[1] for c in parts.get(i, [])]) if parts.get(i) else np.empty(0, np.int8))
           for i, r in enumerate(rails)}
    return out, result


def _pa_machine(flavor="klipper"):
    m = Machine(flavor=flavor)
    m.axes["e"].steps_per_mm = 400.0
    return m


def test_set_pressure_advance_and_m900_m572_act_like_klippers_setting():
    base, _ = _program_steps(_pa_machine(), PROGRAM)
    m = _pa_machine()
    m.pressure_advance = 0.05
    cfg, _ = _program_steps(m, PROGRAM)
    cmd, _ = _program_steps(_pa_machine(), "SET_PRESSURE_ADVANCE ADVANCE=0.05\n" + PROGRAM)
    assert len(cfg["e"][0]) != len(base["e"][0]) or not np.allclose(cfg["e"][0], base["e"][0])
    assert np.allclose(cmd["e"][0], cfg["e"][0], atol=1e-12) and np.array_equal(cmd["e"][1], cfg["e"][1])
    for name in "xyz":                     # pressure advance touches the extruder only
        assert np.array_equal(cfg[name][0], base[name][0])
    # Marlin's M900 K and RepRapFirmware's M572 S: the same physics, and the summary says so
    for flavor, line in (("marlin", "M900 K0.05\n"), ("reprap", "M572 D0 S0.05\n")):
        ours, result = _program_steps(_pa_machine(flavor), line + PROGRAM)
        assert np.allclose(ours["e"][0], cfg["e"][0], atol=1e-12), flavor
        assert any("pressure advance" in w for w in result.reader.summary.warnings), flavor
    # ADVANCE=0 turns it off: the nominal steps again
    off, _ = _program_steps(m, "SET_PRESSURE_ADVANCE ADVANCE=0\n" + PROGRAM)
    assert np.array_equal(off["e"][0], base["e"][0])


def test_set_input_shaper_mid_file_stops_and_keeps_planned_times_apart_from_the_stop():
    import gcodeplan.api as gp

    text = PROGRAM + "SET_INPUT_SHAPER SHAPER_FREQ_X=45 SHAPER_FREQ_Y=38 SHAPER_TYPE_Y=ei\n" + PROGRAM
    m = _pa_machine()
    shaped, _ = _program_steps(m, text)
    with_stop = gp.estimate((PROGRAM + "M400\n" + PROGRAM).splitlines(), m).total_time_s
    assert gp.estimate(text.splitlines(), m).total_time_s == pytest.approx(with_stop, abs=1e-12)   # Klipper flushes: a stop
    plain, _ = _program_steps(m, PROGRAM + "M400\n" + PROGRAM)
    for name in "xy":
        assert int(shaped[name][1].sum()) == int(plain[name][1].sum())
    # the first half is unshaped: identical steps up to the stop
    first_end = gp.estimate(PROGRAM.splitlines(), m).total_time_s
    k = np.searchsorted(plain["x"][0], first_end - 0.02)
    assert np.allclose(shaped["x"][0][:k], plain["x"][0][:k], atol=1e-12)
    with pytest.raises(Exception, match="SHAPER_FREQ_Z"):
        _program_steps(m, "SET_INPUT_SHAPER SHAPER_FREQ_Z=30\n" + PROGRAM)
