"""Plug-in motors stepped from verified polynomial stand-ins of their ik (``ik_search="fit"``, stepper.kernel
ik_fit_pieces / gen_steps_ik_fit), against independent truth.

The bound (kernel section comment): a fitted span is accepted when its sampled fit error is at most
½·IK_FIT_TOL_S·min |speed| (every step within IK_FIT_TOL_S of the true crossing), or at the ik's own rounding (a
linear ik); elsewhere (turning points, unreachable positions) the exact search (``ik_search="exact"``) steps the
piece. Truths used here: the crossing residual (m(t) − level)/speed computed with the plug-in's ik in Python at
every step (the level from the grid rule, docs/design.md §9); closed forms along straight lines; the exact linear
kernel for linear motors written as plug-ins; real Klipper's steps (../shared).
"""
from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import shared_path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))
import compare_kinematics as ck  # noqa: E402
from test_ik_engine import _motor_position, _plan_rows  # noqa: E402
from test_kinematics_plugins import _line_rows as _rows  # noqa: E402

EXACT_S = 2.5e-9      # s, the exact search's own step error as measured here (its residual reaches 1.97 ns)


def _kin_ref():
    shared_path("reference", "klipper", "kinematics", "times.json")
    ck.KIN = shared_path("reference", "klipper", "kinematics")
    ck.SHARED = ck.KIN.parents[2]


def _tol():
    from gcodeplan.stepper.kernel import IK_FIT_TOL_S

    return IK_FIT_TOL_S


def _residual_s(rail, segs, t, d):
    """(m(t) − level)/speed (s) of every step: how far in time each step is from its half-step crossing, the
    position and speed from the plug-in's ik in Python on the plan rows (central difference, 0.1 µs), the level
    from the grid anchored at the plan's start and the steps' own directions (Klipper's filter drops steps in
    pairs, which keeps the count)."""
    t = np.asarray(t, np.float64)
    anchor = _motor_position(rail, segs, np.array([segs["t0"][0]]))[0]
    n_before = np.concatenate(([0], np.cumsum(d.astype(np.int64))[:-1]))
    level = anchor + (n_before + 0.5 * d) * rail.step_dist
    pos = _motor_position(rail, segs, t)
    gap = pos - level
    if rail.period:
        gap = (gap + 0.5 * rail.period) % rail.period - 0.5 * rail.period
    h = 1e-7
    speed = (_motor_position(rail, segs, t + h) - _motor_position(rail, segs, t - h)) / (2.0 * h)
    return gap / speed


def _within_bound_or_exact(rail, segs, fit, exact):
    """Every fitted step within IK_FIT_TOL_S of its true crossing (:func:`_residual_s`); a step past it must be the
    exact search's own, bit for bit (a span no stand-in verified), and such steps under 1 %."""
    res = np.abs(_residual_s(rail, segs, *fit))
    far = res > _tol()
    assert np.array_equal(fit[0][far], exact[0][far]), (rail.name, float(np.max(res)))
    assert np.count_nonzero(far) < 0.01 * len(res), rail.name


def _compare(a, b, bound):
    """Same step count and directions per motor, every time within ``bound`` (s)."""
    assert list(a) == list(b)
    for motor in a:
        (ta, da), (tb, db) = a[motor], b[motor]
        assert len(ta) == len(tb), (motor, len(ta), len(tb))
        assert np.array_equal(da, db), motor
        if len(ta):
            assert np.max(np.abs(ta - tb)) <= bound, (motor, float(np.max(np.abs(ta - tb))))


@pytest.mark.parametrize("config", ck.CONFIGS)
@pytest.mark.parametrize("name", ck.FILES)
def test_fit_equals_the_exact_search_on_the_reference_files(name, config):
    """All seven Klipper kinematics plug-ins on the three synthetic files: the fit's steps have the exact search's
    count and directions per motor, every time within IK_FIT_TOL_S + the exact search's own error of its; and on
    every plug-in motor each step lies within IK_FIT_TOL_S of its true crossing (residual by the Python ik) or is
    the exact search's own step, bit for bit (a span no stand-in verified, under 1 % of the steps)."""
    from gcodeplan.kinematics import rails_for

    _kin_ref()
    m = ck.machine(config)
    lines = ck.source_lines(name, config)
    exact = ck.klipper_steps(lines, m, ik_search="exact")
    fit = ck.klipper_steps(lines, m, ik_search="fit")
    _compare(exact, fit, _tol() + EXACT_S)
    rails = {r.name: r for r in rails_for(m, klipper_names=True)}
    segs = _plan_rows(lines, m)
    plugins = [mot for mot in fit if rails[mot].ik is not None and len(fit[mot][0])]
    assert bool(plugins) == (config in ("polar", "rotary_delta", "winch", "deltesian"))
    for motor in plugins:
        _within_bound_or_exact(rails[motor], segs, fit[motor], exact[motor])


@pytest.mark.parametrize("config", ["winch", "deltesian", "rotary_delta", "polar"])
def test_fit_against_real_klipper(config):
    """Klipper's reference (c_circle200, its batch windows): every motor's step count, net steps and directions
    equal Klipper's, and every step within 100 ns of Klipper's wherever the exact search's is (the exact search
    differs more only on rotary joints at low angular speed, by Klipper's own stopping rule; there the fit stays
    within the bound of the exact search)."""
    _kin_ref()
    name = "c_circle200"
    info, ref = ck.reference(name, config)
    m = ck.machine(config)
    lines = ck.source_lines(name, config)
    windows = ck.batch_windows(lines, m)
    fit = ck.klipper_steps(lines, m, windows, ik_search="fit")
    exact = ck.klipper_steps(lines, m, windows, ik_search="exact")
    figures = info["steps"]["steppers"]
    for motor, (t, d) in fit.items():
        assert len(t) == figures[motor]["n_steps"], motor
        assert int(d.sum(dtype=np.int64)) == figures[motor]["net_steps"], motor
        rt, rd = ref[motor], ref[motor + "_dir"]
        k = len(rt)
        assert np.array_equal(d[:k], rd), motor
        near = np.abs(exact[motor][0][:k] - rt) <= 100e-9
        assert np.all(np.abs(t[:k] - rt)[near] <= 100e-9), motor
        assert np.max(np.abs(t - exact[motor][0]), initial=0.0) <= _tol() + EXACT_S, motor


def _linear_as_plugin(rails):
    """The linear rails with X/Y/Z weights rewritten as plug-in motors (ik = Σ w·axis), the extruder kept."""
    import numba

    from gcodeplan.kinematics import Rail

    def make(w0, w1, w2):
        @numba.njit
        def ik(x, y, z, p):
            return w0 * x + w1 * y + w2 * z
        return ik

    out = []
    for r in rails:
        w = r.weights
        if w is not None and not w[3]:
            out.append(Rail(r.name, r.steps_per_mm, None, ik=make(float(w[0]), float(w[1]), float(w[2])),
                            ik_params=()))
        else:
            out.append(r)
    return out


def _generate(rails, lines, m, ik_search, **kw):
    from gcodeplan.pipeline import Run
    from gcodeplan.stepper.generate import StepGenerator
    from gcodeplan.stepper.source import homing_resets

    parts = [[] for _ in rails]
    gen = StepGenerator(rails, lambda si, t, d: parts[si].append((t.copy(), d.copy())), ik_search=ik_search, **kw)
    pending = False
    drive = Run(lines, m)
    for piece in drive:
        reset, pending = homing_resets(piece.moves, piece.segments, piece.first_move, pending)
        gen.feed(piece.segments, reset, moves=piece.moves, limits=drive.reader.limits, first_move=piece.first_move)
    gen.finish()
    return {r.name: (np.concatenate([c[0] for c in p]) if p else np.empty(0),
                     np.concatenate([c[1] for c in p]) if p else np.empty(0, np.int8)) for r, p in zip(rails, parts)}


@pytest.mark.parametrize("config", ["hybrid_corexy", "hybrid_corexz", "generic_cartesian"])
def test_linear_motors_as_plugins_fit_first_time(config):
    """Klipper's linear kinematics (x − y, x − z, x + y, y, z) written as plug-ins: every piece's stand-in
    verifies at the first, lowest degree (one FIT_CUBIC row per piece, none left to the exact search), and the
    steps are the exact linear kernel's (closed-form crossings): same counts and directions, every time within
    1 ns."""
    from gcodeplan.kinematics import rails_for
    from gcodeplan.kinematics.plugin import ik_bound_cfunc
    from gcodeplan.stepper import kernel
    from gcodeplan.stepper.generate import _xyz_columns

    _kin_ref()
    lines = ck.source_lines("d_slicer_like", config)
    m = ck.machine(config)
    linear = rails_for(m, klipper_names=True)
    plug = _linear_as_plugin(linear)
    assert sum(r.ik is not None for r in plug) == 3
    _compare(_generate(linear, lines, m, "exact"), _generate(plug, lines, m, "fit"), 1e-9)
    t0, dt, p, v, a, j = _xyz_columns(_plan_rows(lines, m))
    for r in plug:
        if r.ik is None:
            continue
        fn = ik_bound_cfunc(r.ik, ())
        refs = kernel.ik_branch_refs(t0, dt, p, v, a, j, fn, 0.0, kernel.new_state(), 0)
        rows = kernel.ik_fit_pieces(t0, dt, p, v, a, j, np.zeros(len(t0), np.uint8), fn, 0.0, refs,
                                    kernel.IK_FIT_TOL_S, kernel.IK_FIT_ROUND)
        assert len(rows[0]) == len(t0) and np.all(rows[3] == kernel.FIT_CUBIC), r.name


def _scara():
    """docs/api.md's SCARA arm (shoulder and elbow angles in rad, two 150 mm links), registered as a user would."""
    import numba

    import gcodeplan as gp

    @numba.njit
    def elbow(x, y, z, p):
        c = (x * x + y * y - p[0] ** 2 - p[1] ** 2) / (2.0 * p[0] * p[1])
        return math.acos(min(1.0, max(-1.0, c)))

    @numba.njit
    def shoulder(x, y, z, p):
        e = elbow(x, y, z, p)
        return math.atan2(y, x) - math.atan2(p[1] * math.sin(e), p[0] + p[1] * math.cos(e))

    steps_per_rad = 200 * 16 * 10 / (2 * math.pi)
    gp.kinematics.register("scara_fit_test", gp.kinematics.Plugin(
        {"shoulder": shoulder, "elbow": elbow, "z": (0, 0, 1)}, {"shoulder": steps_per_rad, "elbow": steps_per_rad},
        params=[150.0, 150.0, 4.0]), replace=True)
    return gp.Machine(kinematics="scara_fit_test", max_velocity=300.0, max_accel=3000.0)


def test_a_users_scara_fits_within_the_bound():
    """docs/api.md's SCARA on a square around (100, 100): the exact search's counts and directions, every step
    within IK_FIT_TOL_S + the exact search's error of its, and within IK_FIT_TOL_S of its true crossing (residual
    by the Python ik) unless it is the exact search's own (a span left to it)."""
    import gcodeplan as gp
    from gcodeplan.kinematics import rails_for

    arm = _scara()
    lines = ["SET_KINEMATIC_POSITION X=60 Y=60 Z=0", "G1 X140 Y60 F6000", "G1 X140 Y140", "G1 X60 Y140",
             "G1 X60 Y60", "G1 X100 Y150 F3000", "G1 X150 Y40"]
    exact = gp.steps(lines, arm, ik_search="exact")
    fit = gp.steps(lines, arm, ik_search="fit")
    _compare(exact, fit, _tol() + EXACT_S)
    assert len(fit["shoulder"][0]) > 1000 and len(fit["elbow"][0]) > 1000
    segs = _plan_rows(lines, arm)
    for r in rails_for(arm):
        if r.ik is not None:
            _within_bound_or_exact(r, segs, fit[r.name], exact[r.name])


def _steps(seg, rail, reset=None, chunk=None, **attrs):
    from gcodeplan.stepper.generate import StepGenerator

    parts = []
    kw = {} if chunk is None else {"chunk_steps": chunk}
    gen = StepGenerator([rail], lambda si, t, d: parts.append((t.copy(), d.copy())), ik_search="fit", **kw)
    for key, value in attrs.items():
        setattr(gen, key, value)
    gen.feed(seg, reset)
    gen.finish()
    return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts]), len(parts)


def _rail(fn, step, period=0.0):
    import numba

    from gcodeplan.kinematics import Rail

    return Rail("m", 1.0 / step, None, ik=numba.njit(fn), ik_params=(), period=period)


def _hyperbola(x, y, z, p):
    return math.sqrt((x - 5.0) * (x - 5.0) + 1.0)


def test_turning_point_falls_back_to_the_exact_search_there_only():
    """Motor √((x − 5)² + 1) along x = 10·t for 1 s in five pieces: it falls to 1 at t = 0.5 and rises. The piece
    holding the minimum is left to the exact search (FIT_EXACT; its neighbours too, where the curvature defeats a
    quintic on a quarter piece), the outer ones fitted in halved spans. Every step at its closed-form time
    t = (5 ± √(L² − 1))/10: within IK_FIT_TOL_S on the fitted spans, the exact search's steps bit for bit on the
    others; the reversal on the hysteresis' level."""
    from test_ik_engine import _steps as exact_steps

    from gcodeplan.kinematics.plugin import ik_bound_cfunc
    from gcodeplan.stepper import kernel
    from gcodeplan.stepper.generate import _xyz_columns

    step = 0.01
    seg = _rows(0.0, 0.0, 10.0, 0.0, [0.2, 0.2, 0.2, 0.2, 0.2])
    t0, dt, p, v, a, j = _xyz_columns(seg)
    fn = ik_bound_cfunc(_rail(_hyperbola, step).ik, ())
    refs = kernel.ik_branch_refs(t0, dt, p, v, a, j, fn, 0.0, kernel.new_state(), 0)
    f_t0, f_dt, _, mode, src, _ = kernel.ik_fit_pieces(t0, dt, p, v, a, j, np.zeros(5, np.uint8), fn, 0.0, refs,
                                                       kernel.IK_FIT_TOL_S, kernel.IK_FIT_ROUND)
    assert 2 in src[mode == kernel.FIT_EXACT]        # the piece 0.4–0.6 s holds the minimum
    assert {0, 4} <= set(src[mode != kernel.FIT_EXACT].tolist())
    t, d, _ = _steps(seg, _rail(_hyperbola, step))
    m0 = math.sqrt(26.0)
    k = np.arange(int(m0 / step) + 2)
    down = m0 - (k + 0.5) * step
    down = down[down > 1.0]
    c = m0 - len(down) * step
    up = c + (k + 0.5) * step
    up = up[up <= m0]
    want = np.concatenate(((5.0 - np.sqrt(down ** 2 - 1.0)) / 10.0, (5.0 + np.sqrt(up ** 2 - 1.0)) / 10.0))
    want_d = np.concatenate((-np.ones(len(down), np.int8), np.ones(len(up), np.int8)))
    assert np.array_equal(d, want_d) and len(t) > 800
    et, _, _ = exact_steps(seg, _rail(_hyperbola, step))
    row = np.searchsorted(f_t0, t, side="right") - 1
    left = mode[row] == kernel.FIT_EXACT
    assert np.array_equal(t[left], et[left]) and 10 < np.count_nonzero(left) < len(t) - 200
    assert np.max(np.abs(t - want)[~left]) <= _tol()
    assert np.max(np.abs(t - want)) <= EXACT_S


def test_polynomial_motor_through_its_minimum_fits_at_rounding():
    """Motor (x − 5)² along x = 10·t: a quadratic in t, so its stand-in is exact to rounding even through the
    minimum (acceptance (b)); steps at the closed form t = (5 ∓ √L)/10 within 1 ns, the reversal's hysteresis."""
    from test_ik_engine import _parabola, _parabola_steps

    step = 0.37
    t, d, _ = _steps(_rows(0.0, 0.0, 10.0, 0.0, [0.3, 0.3, 0.4]), _rail(_parabola, step))
    want_t, want_d = _parabola_steps(step)
    assert np.array_equal(d, want_d)
    assert np.max(np.abs(t - want_t)) < 1e-9


def test_forced_failure_gives_the_exact_search():
    """A tolerance no stand-in can meet (IK_FIT_TOL_S and the rounding floor negative): every piece falls back and
    the steps are the exact search's bit for bit — on polar (a cyclic bed, c_circle200) and on the hyperbola."""
    from gcodeplan.kinematics import rails_for
    from gcodeplan.stepper.generate import StepGenerator

    _kin_ref()
    lines = ck.source_lines("c_circle200", "polar")
    m = ck.machine("polar")
    rails = rails_for(m, klipper_names=True)

    def run(search, forced):
        from gcodeplan.pipeline import Run

        parts = [[] for _ in rails]
        gen = StepGenerator(rails, lambda si, t, d: parts[si].append((t.copy(), d.copy())), ik_search=search)
        if forced:
            gen.ik_fit_tol_s = gen.ik_fit_round = -1.0
        for piece in Run(lines, m):
            gen.feed(piece.segments)
        gen.finish()
        return {r.name: (np.concatenate([c[0] for c in p]), np.concatenate([c[1] for c in p]))
                for r, p in zip(rails, parts) if p}

    exact, forced, fit = run("exact", False), run("fit", True), run("fit", False)
    assert set(exact) == set(forced) >= {"stepper_bed", "stepper_arm"}
    for motor in exact:
        assert np.array_equal(exact[motor][0], forced[motor][0]) and np.array_equal(exact[motor][1], forced[motor][1])
    # the unforced fit differs (it is a different computation) but within the bound
    assert not np.array_equal(exact["stepper_bed"][0], fit["stepper_bed"][0])
    _compare(exact, fit, _tol() + EXACT_S)
    seg = _rows(0.0, 0.0, 10.0, 0.0, [0.2, 0.2, 0.2, 0.2, 0.2])
    from test_ik_engine import _steps as exact_steps

    rail = _rail(_hyperbola, 0.01)
    et, ed, _ = exact_steps(seg, rail)
    ft, fd, _ = _steps(seg, rail, ik_fit_tol_s=-1.0, ik_fit_round=-1.0)
    assert np.array_equal(et, ft) and np.array_equal(ed, fd)


def test_full_buffer_resumes_with_the_same_steps():
    """A 7-step output buffer: the fit kernel stops before a fitted row that does not fit and the generator grows
    or flushes it; the steps equal one big buffer's, bit for bit."""
    rail = _rail(_hyperbola, 0.01)
    seg = _rows(0.0, 0.0, 10.0, 0.0, [0.13, 0.21, 0.3, 0.36])
    big_t, big_d, _ = _steps(seg, rail)
    small_t, small_d, n_parts = _steps(seg, rail, chunk=7)
    assert n_parts > 1 and len(big_t) > 500
    assert np.array_equal(small_t, big_t) and np.array_equal(small_d, big_d)


def test_unreachable_position_is_the_exact_searchs_clear_error():
    """√(100 − x²) along x = 15·t has no position past x = 10 (inside the second piece): no stand-in verifies
    there, the exact search reports it naming the motor and the piece's start."""
    from gcodeplan.errors import ConfigError

    def half_circle(x, y, z, p):
        return math.sqrt(100.0 - x * x)

    with pytest.raises(ConfigError, match=r"m: the kinematics cannot reach the position at t = 0\.5 s"):
        _steps(_rows(0.0, 0.0, 15.0, 0.0, [0.5, 0.5]), _rail(half_circle, 0.01))


def test_fit_is_chosen_from_the_library_and_the_command(tmp_path):
    """``gcodeplan steps --ik-search fit`` writes the steps ``gp.steps(..., ik_search="fit")`` returns."""
    import gcodeplan as gp
    from gcodeplan.cli import main

    _kin_ref()
    lines = ck.source_lines("c_circle200", "polar")
    src = tmp_path / "c.gcode"
    src.write_text("\n".join(lines) + "\n")
    lib = gp.steps(str(src), ck.machine("polar"), ik_search="fit", sds_filter=ck.KLIPPER_SDS_FILTER_T)
    cfg = tmp_path / "polar.cfg"
    cfg.write_text((ck.KIN / "polar.cfg").read_text())
    out = tmp_path / "s.npz"
    assert main(["steps", "--klipper-config", str(cfg), "--ik-search", "fit", "--quiet", str(src), "-o",
                 str(out)]) == 0
    with np.load(out) as z:
        bed = [k for k in z.files if "bed" in k and not k.endswith("_dir")][0]
        assert np.array_equal(z[bed], lib["stepper_bed"][0])


def test_shaped_plugin_motors_fit_as_the_exact_search_steps_them():
    """A cartesian machine as a plug-in with input shaping (mzv 45 Hz on X, ei 38 Hz on Y) on the corpus cube's
    first 800 lines, through a 997-step buffer: the shaped x, y, z pieces' stand-ins (linear ik: exact to rounding)
    give the exact search's step counts and directions, every step within IK_FIT_TOL_S + the exact search's own
    error of it, and within IK_FIT_TOL_S of Klipper's search with the same ik (which stops within 1e-9 mm of the
    half-step point: ~1e-11 s at these speeds; the exact search is up to 2 ns from it here)."""
    from test_ik_engine import shaped_cartesian_plugin_steps as run

    exact, fit, klipper = run("exact"), run("fit"), run("klipper")
    assert sum(len(t) for t, _ in fit.values()) > 100_000
    _compare(exact, fit, _tol() + EXACT_S)
    _compare(klipper, fit, _tol())
