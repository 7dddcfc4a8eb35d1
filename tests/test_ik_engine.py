"""The step engine's guarded search for plug-in motors (stepper.kernel.gen_steps_ik), against closed forms.

Each motor here has a position whose half-step crossings can be solved by hand: x² along a line (t = (√L − x0)/v),
(x − 5)² through its minimum (a turning point inside a piece and on a piece boundary, and a minimum a millionth of
a step below or above a half-step point), atan2 of a line crossing the ±π cut (a cyclic motor). The grid follows
docs/design.md §9: anchored at the first position, a reversal steps on the other side's half-step point. Plug-in
motors run Klipper's own search by default (``ik_search="klipper"``); these tests ask for the guarded search
(``ik_search="exact"``). Against real Klipper (../shared) the guarded search keeps every step count; its times differ from Klipper's
by no more than Klipper's own stopping rule allows (a guess within 1e-9 units of the half-step point).
"""
from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import shared_path
from gcodeplan.errors import ConfigError

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))
import compare_kinematics as ck  # noqa: E402
from test_kinematics_plugins import _line_rows as _rows  # noqa: E402  (SEGMENT rows of a straight line)

TOL_S = 1e-9          # s, the guarded search converges well below this


def _rail(fn, step, period=0.0):
    from gcodeplan.kinematics import Rail

    return Rail("m", 1.0 / step, None, ik=fn, ik_params=(), period=period)


def _steps(seg, rail, reset=None, chunk=None):
    from gcodeplan.stepper.generate import StepGenerator

    parts = []
    kw = {} if chunk is None else {"chunk_steps": chunk}
    gen = StepGenerator([rail], lambda si, t, d: parts.append((t.copy(), d.copy())), ik_search="exact", **kw)
    gen.feed(seg, reset)
    gen.finish()
    if not parts:
        return np.empty(0), np.empty(0, np.int8), 0
    return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts]), len(parts)


def _ik(expr):
    import numba

    return numba.njit(expr)


def _square(x, y, z, p):
    return x * x


def _parabola(x, y, z, p):
    return (x - 5.0) * (x - 5.0)


def _angle(x, y, z, p):
    return math.atan2(y, x)


def _parabola_steps(step, v=10.0, m0=25.0):
    """Closed form of (v·t − 5)² from t = 0 to 10/v: down steps at levels m0 − (k + ½)·step while above 0, at
    t = (5 − √L)/v, then up steps from the commanded position at levels c + (k + ½)·step up to m0, at
    t = (5 + √L)/v."""
    k = np.arange(int(m0 / step) + 2)
    down = m0 - (k + 0.5) * step
    down = down[down > 0.0]
    c = m0 - len(down) * step
    up = c + (k + 0.5) * step
    up = up[up <= m0]
    t = np.concatenate(((5.0 - np.sqrt(down)) / v, (5.0 + np.sqrt(up)) / v))
    d = np.concatenate((-np.ones(len(down), np.int8), np.ones(len(up), np.int8)))
    return t, d


def test_square_of_a_line_steps_at_the_closed_form():
    """Motor x² (mm²) along x = 1 + 10·t for 1 s in three pieces: steps at 1 + (k + ½)·d, t = (√L − 1)/10."""
    step = 0.05
    t, d, _ = _steps(_rows(1.0, 0.0, 10.0, 0.0, [0.3, 0.3, 0.4]), _rail(_ik(_square), step))
    levels = 1.0 + (np.arange(int(120 / step) + 2) + 0.5) * step
    levels = levels[levels <= 121.0]
    want = (np.sqrt(levels) - 1.0) / 10.0
    assert len(t) == len(want) == 2400
    assert np.all(d == 1)
    assert np.max(np.abs(t - want)) < TOL_S


@pytest.mark.parametrize("spans", [[0.3, 0.3, 0.4], [0.5, 0.5], [1.0]], ids=["inside", "boundary", "one-piece"])
def test_turning_point_inside_a_piece_or_on_its_boundary(spans):
    """(x − 5)² along x = 10·t: falls to 0 at t = 0.5 and rises; the minimum inside a piece, on a piece boundary or
    in the middle of the only piece. Every step at its closed-form time, the reversal on the hysteresis' level."""
    step = 0.37
    t, d, _ = _steps(_rows(0.0, 0.0, 10.0, 0.0, spans), _rail(_ik(_parabola), step))
    want_t, want_d = _parabola_steps(step)
    assert np.array_equal(d, want_d)
    assert np.max(np.abs(t - want_t)) < TOL_S


@pytest.mark.parametrize("eps, extra", [(1e-6, 1), (-1e-6, 0)], ids=["touches", "misses"])
def test_a_minimum_barely_past_a_half_step_point(eps, extra):
    """Step d = (25 − ε)/24.5: the 25th half-step point below 25 lies ε = 1e-6 mm² above the minimum 0, reached
    for 2·√(ε)/10 = 200 µs: one more step down and back up than with ε = −1e-6 (never reached)."""
    step = (25.0 - eps) / 24.5
    t, d, _ = _steps(_rows(0.0, 0.0, 10.0, 0.0, [0.3, 0.3, 0.4]), _rail(_ik(_parabola), step))
    want_t, want_d = _parabola_steps(step)
    assert int(np.sum(d == -1)) == 24 + extra
    assert np.array_equal(d, want_d)
    assert np.max(np.abs(t - want_t)) < TOL_S


def test_unreachable_position_is_a_clear_error():
    """√(100 − x²) along x = 15·t: no position past x = 10 (t = 0.667 s, inside the second piece): the error names
    the motor and the piece's start; no steps made up."""
    def half_circle(x, y, z, p):
        return math.sqrt(100.0 - x * x)

    with pytest.raises(ConfigError, match=r"m: the kinematics cannot reach the position at t = 0\.5 s"):
        _steps(_rows(0.0, 0.0, 15.0, 0.0, [0.5, 0.5]), _rail(_ik(half_circle), 0.01))


def test_still_zero_length_and_reset_pieces_step_as_the_exact_linear_kernel():
    """Motor x through moving, zero-length, still and jumped pieces (a position set, RESET_ANCHOR, and a silent
    jump): the same steps as the exact linear kernel (stepper.kernel.gen_steps) on the same rows."""
    from gcodeplan.kinematics import Rail
    from gcodeplan.stepper.kernel import RESET_ANCHOR

    def ident(x, y, z, p):
        return x

    seg = _rows(0.0, 0.0, 7.3, 0.0, [0.2, 0.0, 0.3, 0.25, 0.2, 0.2])
    seg["vx"][2] = 0.0              # still: x stays at 1.46
    seg["px"][2] = 1.46
    seg["px"][3] = 1.46             # moving again
    seg["px"][4] = 40.0             # set position (reset) then moving
    seg["px"][5] = 42.0 + 1e-3      # a silent jump
    seg["vx"][4] = -3.0
    reset = np.zeros(len(seg), np.uint8)
    reset[4] = RESET_ANCHOR
    step = 0.0125
    t, d, _ = _steps(seg, _rail(_ik(ident), step), reset)
    lt, ld, _ = _steps(seg, Rail("m", 1.0 / step, (1.0, 0.0, 0.0, 0.0)), reset)
    assert len(t) == len(lt) > 200 and np.array_equal(d, ld)
    assert np.max(np.abs(t - lt)) < TOL_S


def test_full_buffer_resumes_with_the_same_steps():
    """A 7-step output buffer (every piece holds more): the kernel stops before a piece that does not fit and the
    generator grows or flushes it; the steps equal one big buffer's, bit for bit."""
    rail = _rail(_ik(_parabola), 0.05)
    seg = _rows(0.0, 0.0, 10.0, 0.0, [0.13, 0.21, 0.3, 0.36])
    big_t, big_d, _ = _steps(seg, rail)
    small_t, small_d, n_parts = _steps(seg, rail, chunk=7)
    assert n_parts > 1 and len(big_t) > 500
    assert np.array_equal(small_t, big_t) and np.array_equal(small_d, big_d)


def test_cyclic_motor_crosses_the_angle_cut_continuously():
    """A turntable angle atan2(y, x) (period 2π) along x = −10, y = −1 + 2·t: the angle runs from −π + atan(0.1)
    down through ±π to π − atan(0.1), continuously −π − atan(y/10). Steps at levels θ0 − (k + ½)·d,
    y = −10·tan(L), t = (y + 1)/2; none made up at the cut."""
    step = 2.0 * math.pi / 3200.0
    t, d, _ = _steps(_rows(-10.0, -1.0, 0.0, 2.0, [0.4, 0.6]), _rail(_ik(_angle), step, period=2.0 * math.pi))
    th0 = math.atan2(-1.0, -10.0)
    th1 = -math.pi - math.atan(0.1)
    k = np.arange(int((th0 - th1) / step) + 2)
    levels = th0 - (k + 0.5) * step
    levels = levels[levels >= th1]
    want = (-10.0 * np.tan(levels) + 1.0) / 2.0
    assert len(t) == len(want) == 102        # 2·atan(0.1)/d = 101.5 steps of travel
    assert np.all(d == -1)
    assert np.max(np.abs(t - want)) < TOL_S


def _kin_ref():
    shared_path("reference", "klipper", "kinematics", "times.json")
    ck.KIN = shared_path("reference", "klipper", "kinematics")
    ck.SHARED = ck.KIN.parents[2]


def _plan_rows(lines, m):
    """The plan's SEGMENT rows, in memory."""
    from gcodeplan.pipeline import Run

    return np.concatenate([piece.segments for piece in Run(lines, m)])


def _motor_position(rail, segs, t):
    """The motor position (units) of plug-in rail ``rail`` at times ``t`` (s) on the plan rows ``segs``."""
    i = np.searchsorted(segs["t0"], t, side="right") - 1
    r = segs[i]
    s = t - r["t0"]
    xyz = [r["p" + a] + s * (r["v" + a] + s * (0.5 * r["a" + a] + s * r["j" + a] / 6.0)) for a in "xyz"]
    params = np.asarray(rail.ik_params or (0.0,), np.float64)
    fn = getattr(rail.ik, "py_func", rail.ik)
    return np.array([fn(xyz[0][q], xyz[1][q], xyz[2][q], params) for q in range(len(t))])


@pytest.mark.parametrize("config", ["winch", "deltesian", "rotary_delta", "polar"])
def test_guarded_search_against_real_klipper(config):
    """Klipper's reference (c_circle200): every motor's step count, net steps and directions equal; every step
    within 100 ns of Klipper's, or — where Klipper's own stopping rule allows more (it takes a guess within
    1e-9 units of the half-step point: on a rotary joint at 0.001 rad/s that is 1 µs) — at a motor position within
    1.5e-9 units of the position at Klipper's time (both on the same half-step point, within Klipper's rule)."""
    from gcodeplan.kinematics import rails_for

    _kin_ref()
    name = "c_circle200"
    info, ref = ck.reference(name, config)
    m = ck.machine(config)
    lines = ck.source_lines(name, config)
    ours = ck.klipper_steps(lines, m, ck.batch_windows(lines, m), ik_search="exact")
    figures = info["steps"]["steppers"]
    rails = {r.name: r for r in rails_for(m, klipper_names=True)}
    segs = None
    for motor, (t, d) in ours.items():
        assert len(t) == figures[motor]["n_steps"], motor
        assert int(d.sum(dtype=np.int64)) == figures[motor]["net_steps"], motor
        rt, rd = ref[motor], ref[motor + "_dir"]
        k = len(rt)
        assert np.array_equal(d[:k], rd), motor
        far = np.flatnonzero(np.abs(t[:k] - rt) > 100e-9)
        if len(far) == 0:
            continue
        assert rails[motor].ik is not None, motor
        segs = _plan_rows(lines, m) if segs is None else segs
        gap = _motor_position(rails[motor], segs, t[far]) - _motor_position(rails[motor], segs, rt[far])
        assert np.max(np.abs(gap)) <= 1.5e-9, (motor, float(np.max(np.abs(gap))))


def test_a_users_plugin_equals_the_builtin_under_the_guarded_search():
    """The user's polar of tests/test_kinematics_plugins.py (written outside the package) through the guarded
    search: the built-in polar's steps bit for bit, and Klipper's step counts."""
    import test_kinematics_plugins as tkp

    _kin_ref()
    tkp.user_polar()
    lines = ck.source_lines("d_slicer_like", "polar")
    builtin = ck.machine("polar")
    mine = ck.machine("polar")
    mine.kinematics = "users_polar"
    a, b = ck.klipper_steps(lines, builtin, ik_search="exact"), ck.klipper_steps(lines, mine, ik_search="exact")
    assert list(a) == list(b)
    figures = ck.reference("d_slicer_like", "polar")[0]["steps"]["steppers"]
    for motor in a:
        assert np.array_equal(a[motor][0], b[motor][0]) and np.array_equal(a[motor][1], b[motor][1]), motor
        # the guarded search has no step-generation windows: Klipper's counts whatever windows it is given
        assert len(b[motor][0]) == figures[motor]["n_steps"], motor


def shaped_cartesian_plugin_steps(search: str) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """{motor: (times s, dirs)} of a cartesian machine written as a plug-in (x, y, z motors by ik) with input
    shaping (mzv 45 Hz on X, ei 38 Hz on Y) on the corpus cube's first 800 lines, fed through a 997-step buffer,
    stepped by ``search`` (StepGenerator.IK_SEARCHES); tests/test_ik_fit.py uses it too."""
    import bench_steps_features as bsf

    from gcodeplan.stepper.generate import StepGenerator

    path = shared_path("gcode", "prusaslicer25_cube20_marlin2.gcode")
    m = bsf._machine("shaped")
    plug = bsf._generic_cartesian_ik()
    pieces, lim = bsf._pieces(path.read_text().splitlines()[:800], m)
    rails = plug.rails(m)
    out = [[] for _ in rails]
    gen = StepGenerator(rails, lambda si, t, d: out[si].append((t.copy(), d.copy())),
                        settings=m.limits_row(), chunk_steps=997, ik_search=search)
    for segs, reset, moves, first in pieces:
        gen.feed(segs, reset, moves=moves, limits=lim, first_move=first)
    gen.finish()
    return {r.name: (np.concatenate([c[0] for c in o]), np.concatenate([c[1] for c in o]))
            for r, o in zip(rails, out)}


def test_shaped_plugin_motors_match_klippers_search():
    """A cartesian machine as a plug-in (x, y, z motors by ik) with input shaping (mzv 45 Hz on X, ei 38 Hz on Y)
    on the corpus cube's first 800 lines, through a 997-step buffer: the guarded search steps the shaped pieces as
    they come; every motor has the step count of Klipper's search with the same ik, every step within 10 ns of it
    (on mm motors Klipper's 1e-9 mm stopping rule is ~1e-11 s)."""
    klipper, guarded = shaped_cartesian_plugin_steps("klipper"), shaped_cartesian_plugin_steps("exact")
    assert sum(len(t) for t, _ in guarded.values()) > 100_000
    for (kt, kd), (gt, gd) in zip(klipper.values(), guarded.values()):
        assert len(gt) == len(kt) and np.array_equal(gd, kd)
        assert np.max(np.abs(gt - kt)) < 10e-9


def test_ik_search_is_chosen_per_call_from_the_library_and_the_command(tmp_path):
    """``gp.steps(..., ik_search="exact")`` and ``gcodeplan steps --ik-search exact`` step a plug-in machine with the
    guarded search (the same steps as the step generator asked for it), the default stays Klipper's search, and an
    unknown search is an error naming the choices."""
    import gcodeplan as gp
    from gcodeplan.cli import main

    _kin_ref()
    lines = ck.source_lines("c_circle200", "polar")
    m = ck.machine("polar")
    src = tmp_path / "c.gcode"
    src.write_text("\n".join(lines) + "\n")
    exact = ck.klipper_steps(lines, m, ik_search="exact")
    lib = gp.steps(str(src), m, ik_search="exact", sds_filter=ck.KLIPPER_SDS_FILTER_T)
    default = gp.steps(str(src), m, sds_filter=ck.KLIPPER_SDS_FILTER_T)
    assert list(lib) == list(exact) and "stepper_bed" in lib
    for motor in lib:
        assert np.array_equal(lib[motor][0], exact[motor][0]), motor
        assert len(default[motor][0]) == len(lib[motor][0]), motor
    # Klipper's search stops within 1e-9 rad of the half-step point: on the bed, up to microseconds from the exact
    assert not np.array_equal(default["stepper_bed"][0], lib["stepper_bed"][0])
    with pytest.raises(ConfigError, match="exact"):
        gp.steps(str(src), m, ik_search="fast")
    cfg = tmp_path / "polar.cfg"
    cfg.write_text((ck.KIN / "polar.cfg").read_text())
    out = tmp_path / "s.npz"
    assert main(["steps", "--klipper-config", str(cfg), "--ik-search", "exact", "--quiet", str(src), "-o",
                 str(out)]) == 0
    with np.load(out) as z:
        bed = [k for k in z.files if "bed" in k and not k.endswith("_dir")][0]
        assert np.array_equal(z[bed], exact["stepper_bed"][0])
