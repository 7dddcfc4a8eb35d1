"""Plots read back: the drawn curves are the plan, sampled at the plotted times.

The windows here are built by hand from closed-form trapezoids, S-curve phases and a parabolic
blend, so every plotted value has an independent formula to be checked against.
"""
from __future__ import annotations

import math
import struct
from itertools import combinations

import numpy as np
import pytest

from gcodeplan.errors import GcodeplanError
from gcodeplan.machine import Machine
from gcodeplan.report import plots
from gcodeplan.schema import (
    KIND_PRINT,
    KIND_TRAVEL,
    KIND_WAIT,
    MOVE_DTYPE,
    PHASE_ACCEL,
    PHASE_BLEND,
    PHASE_CRUISE,
    PHASE_DECEL,
    PLAN_DTYPE,
    SEGMENT_DTYPE,
)

AX = ("x", "y", "z", "e")


# ----------------------------------------------------------------------------- hand-built plans
def trapezoid_move(p0, p1, v0, vc, v1, accel, t_start, move, kind=KIND_PRINT, feed_v=None, line=1):
    """MOVE row, PLAN row and SEGMENT rows of a straight move p0 → p1 (xyz + e) with a symmetric
    trapezoid v0 → vc → v1 at ``accel`` (textbook closed form: phase times Δv/A, cruise distance
    = length − ramp distances)."""
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    d = p1 - p0
    length = float(np.linalg.norm(d[:3]))
    u = d / length  # per mm of path (e rides along)
    accel_t = (vc - v0) / accel
    decel_t = (vc - v1) / accel
    accel_d = (v0 + vc) / 2 * accel_t
    decel_d = (vc + v1) / 2 * decel_t
    cruise_d = length - accel_d - decel_d
    assert cruise_d >= -1e-12
    cruise_t = cruise_d / vc
    segs = np.zeros(3, SEGMENT_DTYPE)
    t = t_start
    pos = p0.copy()
    for k, (dt, v, a, ph) in enumerate(((accel_t, v0, accel, PHASE_ACCEL), (cruise_t, vc, 0.0, PHASE_CRUISE),
                                        (decel_t, vc, -accel, PHASE_DECEL))):
        s = segs[k]
        s["t0"], s["dt"], s["move"], s["phase"] = t, dt, move, ph
        for i, a_name in enumerate(AX):
            s["p" + a_name] = pos[i]
            s["v" + a_name] = v * u[i]
            s["a" + a_name] = a * u[i]
        pos = pos + u * (v * dt + a * dt * dt / 2)
        t += dt
    segs = segs[segs["dt"] > 0]
    m = np.zeros(1, MOVE_DTYPE)
    m["line"], m["kind"], m["layer"], m["feature"] = line, kind, 0, 0
    for i, a_name in enumerate(AX):
        m[a_name + "0"], m[a_name + "1"] = p0[i], p1[i]
    m["move_d"], m["feed_v"], m["accel"] = length, feed_v if feed_v is not None else vc, accel
    pl = np.zeros(1, PLAN_DTYPE)
    pl["t_start"], pl["start_v"], pl["cruise_v"], pl["end_v"] = t_start, v0, vc, v1
    pl["accel"], pl["decel"] = accel, accel
    pl["accel_t"], pl["cruise_t"], pl["decel_t"] = accel_t, cruise_t, decel_t
    pl["duration"] = accel_t + cruise_t + decel_t
    return m, pl, segs


def trapezoid_speed(t, t_start, v0, vc, v1, accel, accel_t, cruise_t, decel_t):
    """Closed-form speed of that trapezoid at absolute time t."""
    tau = np.asarray(t) - t_start
    return np.where(tau <= accel_t, v0 + accel * tau,
                    np.where(tau <= accel_t + cruise_t, vc, vc - accel * (tau - accel_t - cruise_t)))


def join(parts, label="hand-built"):
    moves = np.concatenate([p[0] for p in parts])
    plan = np.concatenate([p[1] for p in parts])
    segs = np.concatenate([p[2] for p in parts])
    limits = Machine().limits_row()
    return plots.Window(moves, plan, segs, first_index=int(segs["move"].min()), limits=limits, label=label)


def corner_window(first_index=0):
    """Two print moves with a 90° corner at 20 mm/s, then a travel back, all rest to rest at the ends."""
    a = 1000.0
    m1 = trapezoid_move([0, 0, 0.2, 0], [40, 0, 0.2, 1.5], 0.0, 100.0, 20.0, a, 0.0, first_index, feed_v=120.0,
                        line=10)
    t1 = float(m1[1]["t_start"][0] + m1[1]["duration"][0])
    m2 = trapezoid_move([40, 0, 0.2, 1.5], [40, 30, 0.2, 2.6], 20.0, 80.0, 0.0, a, t1, first_index + 1,
                        feed_v=80.0, line=11)
    t2 = float(m2[1]["t_start"][0] + m2[1]["duration"][0])
    m3 = trapezoid_move([40, 30, 0.2, 2.6], [0, 0, 0.2, 2.6], 0.0, 150.0, 0.0, a, t2, first_index + 2,
                        kind=KIND_TRAVEL, feed_v=200.0, line=12)
    return join([m1, m2, m3])


def line_by_gid(fig, gid):
    found = [ln for ax in fig.axes for ln in ax.get_lines() if ln.get_gid() == gid]
    assert len(found) == 1, f"{gid}: {len(found)} lines"
    return found[0]


def xy(line):
    x, y = line.get_data()
    return np.asarray(x, float), np.asarray(y, float)


def closed_form_speed(win, t):
    """Speed of a window of hand-built trapezoids from the PLAN rows' closed form (not the segments)."""
    out = np.full(t.shape, np.nan)
    for p in win.plan:
        m = (t >= p["t_start"]) & (t <= p["t_start"] + p["duration"])
        out[m] = trapezoid_speed(t[m], p["t_start"], p["start_v"], p["cruise_v"], p["end_v"], p["accel"],
                                 p["accel_t"], p["cruise_t"], p["decel_t"])
    return out


# ----------------------------------------------------------------------------- sampling
def test_eval_segments_matches_the_trapezoid_closed_form():
    win = corner_window()
    t = np.linspace(0.0, win.t_range[1], 997)
    k = np.clip(np.searchsorted(win.segs["t0"], t, side="right") - 1, 0, win.segs.size - 1)
    _, vel, acc, jerk = plots.eval_segments(win.segs, k, t - win.segs["t0"][k])
    speed = np.linalg.norm(vel[:, :3], axis=1)
    np.testing.assert_allclose(speed, closed_form_speed(win, t), atol=1e-9)
    assert np.all(jerk == 0.0)


def test_sample_plan_includes_both_sides_of_every_boundary_in_time_order():
    win = corner_window()
    s = plots.sample_plan(win.segs, n_uniform=50)
    assert np.all(np.diff(s.t) >= 0)
    for i, seg in enumerate(win.segs):
        at = s.seg == i
        assert np.isclose(s.t[at].min(), seg["t0"]) and np.isclose(s.t[at].max(), seg["t0"] + seg["dt"])
    assert not s.gap.any()


def test_sample_plan_breaks_the_line_across_a_hole_in_time():
    a = trapezoid_move([0, 0, 0, 0], [10, 0, 0, 0], 0, 50, 0, 1000, 0.0, 0)
    b = trapezoid_move([10, 0, 0, 0], [20, 0, 0, 0], 0, 50, 0, 1000, 5.0, 7)
    win = join([a, b])
    s = plots.sample_plan(win.segs, n_uniform=100)
    assert s.gap.sum() == 1
    assert s.t[s.gap][0] == 5.0
    fig = plots.plot_velocity(win)
    x, y = xy(line_by_gid(fig, "speed"))
    assert np.isnan(y).sum() == 1 and np.isnan(x).sum() == 1


# ----------------------------------------------------------------------------- velocity
def test_velocity_plot_speed_is_the_closed_form_trapezoid_at_the_plotted_times():
    win = corner_window()
    fig = plots.plot_velocity(win)
    t, v = xy(line_by_gid(fig, "speed"))
    assert t.size > 4000
    np.testing.assert_allclose(v, closed_form_speed(win, t), atol=1e-9)
    # every segment boundary is a plotted time
    bounds = np.r_[win.segs["t0"], win.segs["t0"][-1] + win.segs["dt"][-1]]
    assert np.all(np.min(np.abs(t[:, None] - bounds[None, :]), axis=0) < 1e-12)


def test_velocity_plot_of_trapezoids_has_steps_in_acceleration_and_no_jerk_panel():
    """A trapezoid plan's jerk is zero inside phases and impulses between them: no panel of its own
    (issue 19: it was noise); the steps are the acceleration curve's, found by ``jerk_steps``."""
    win = corner_window()
    fig = plots.plot_velocity(win)
    t, a = xy(line_by_gid(fig, "accel"))
    assert set(np.round(np.unique(a), 9)) <= {-1000.0, 0.0, 1000.0}
    assert len(fig.axes) == 2
    names = {ln.get_gid() for ax in fig.axes for ln in ax.get_lines()}
    assert not names & {"jerk", "jerk_steps_up", "jerk_steps_down"}
    # impulses: each phase change where the acceleration changes, plus start from / stop at rest
    s = plots.sample_plan(win.segs)
    speed, a_t, _ = plots.toolhead_kinematics(s.vel, s.acc, s.jerk, s.side)
    step_t, step_da = plots.jerk_steps(s, a_t, speed)
    up_t, down_t = step_t[step_da > 1e-6], step_t[step_da < -1e-6]
    expected_up, expected_down = [], []
    for p in win.plan:
        t0 = p["t_start"]
        ta, tc, td = p["accel_t"], p["cruise_t"], p["decel_t"]
        expected_up.append(t0)                      # 0 (or −A at the corner) → +A
        expected_down += [t0 + ta, t0 + ta + tc]    # +A → 0 → −A
        expected_up.append(t0 + ta + tc + td)       # −A → 0 (or → +A next move, counted at its start)
    # at the corner the step −A → +A is one impulse of 2A, not two
    exp_up = np.unique(np.round(expected_up, 12))
    np.testing.assert_allclose(np.sort(up_t), exp_up, atol=1e-12)
    np.testing.assert_allclose(np.sort(down_t), np.sort(expected_down), atol=1e-12)


def test_velocity_plot_feed_rate_and_junction_speeds_are_the_requested_and_planned_values():
    win = corner_window()
    fig = plots.plot_velocity(win)
    ft, fv = xy(line_by_gid(fig, "feed"))
    # one flat piece per move, over the move's planned interval, at its requested feed; NaN between
    pieces = np.stack([ft[0::3], ft[1::3], fv[0::3], fv[1::3]], axis=1)
    assert np.all(np.isnan(ft[2::3])) and np.all(np.isnan(fv[2::3]))
    np.testing.assert_array_equal(pieces[:, 0], win.plan["t_start"])
    np.testing.assert_array_equal(pieces[:, 1], win.plan["t_start"] + win.plan["duration"])
    np.testing.assert_array_equal(pieces[:, 2], win.moves["feed_v"])
    np.testing.assert_array_equal(pieces[:, 3], [120.0, 80.0, 200.0])
    jt, jv = xy(line_by_gid(fig, "junctions"))
    np.testing.assert_array_equal(jt, win.plan["t_start"])
    np.testing.assert_array_equal(jv, win.plan["start_v"])
    np.testing.assert_allclose(jv, [0.0, 20.0, 0.0])
    # and the speed curve passes through each junction marker (plan and segments agree)
    st, sv = xy(line_by_gid(fig, "speed"))
    for tt, vv in zip(jt, jv):
        assert np.min(np.abs(sv[st == tt] - vv)) < 1e-9


def scurve_window():
    """Rest → 100 mm/s along x as a pure S (jerk J up for T, −J for T), then the reverse: a = J·τ, v = J·τ²/2."""
    J, T = 50_000.0, 0.04
    segs = np.zeros(4, SEGMENT_DTYPE)
    v, a, p, t = 0.0, 0.0, 0.0, 0.0
    for k, j in enumerate((J, -J, -J, J)):
        s = segs[k]
        s["t0"], s["dt"], s["px"], s["vx"], s["ax"], s["jx"], s["move"] = t, T, p, v, a, j, 0
        s["phase"] = PHASE_ACCEL if k < 2 else PHASE_DECEL
        p += v * T + a * T * T / 2 + j * T ** 3 / 6
        v += a * T + j * T * T / 2
        a += j * T
        t += T
    m = np.zeros(1, MOVE_DTYPE)
    m["kind"], m["move_d"], m["feed_v"], m["x1"] = KIND_TRAVEL, p, 100.0, p
    pl = np.zeros(1, PLAN_DTYPE)
    pl["duration"], pl["cruise_v"], pl["jerk"] = 4 * T, J * T * T, J
    return plots.Window(m, pl, segs), J, T


def test_scurve_jerk_is_finite_and_continuous_acceleration_has_no_impulses():
    win, J, T = scurve_window()
    fig = plots.plot_velocity(win)
    t, v = xy(line_by_gid(fig, "speed"))
    # closed form of the pure S up: v = J τ²/2 for τ ≤ T, V − J (2T − τ)²/2 up to 2T; the way down mirrors it
    vpk = J * T * T
    tau = np.where(t <= 2 * T, t, 4 * T - t)
    expect = np.where(tau <= T, J * tau ** 2 / 2, vpk - J * (2 * T - tau) ** 2 / 2)
    np.testing.assert_allclose(v, expect, atol=1e-9)
    _, j = xy(line_by_gid(fig, "jerk"))
    assert set(np.round(np.unique(j), 6)) <= {-J, J}
    names = {ln.get_gid() for ax in fig.axes for ln in ax.get_lines()}
    assert "jerk_steps_up" not in names and "jerk_steps_down" not in names


def test_blend_toolhead_acceleration_and_jerk_are_the_derivatives_of_the_plotted_speed():
    # parabolic blend turning x → y: v(τ) = (V − Aτ, Aτ) with A = V/τb: |v| dips to V/√2 mid-blend
    V, tb = 50.0, 0.1
    A = V / tb
    segs = np.zeros(1, SEGMENT_DTYPE)
    segs["dt"], segs["vx"], segs["ax"], segs["ay"], segs["phase"] = tb, V, -A, A, PHASE_BLEND
    m = np.zeros(1, MOVE_DTYPE)
    m["kind"], m["move_d"], m["feed_v"] = KIND_PRINT, 3.5, V
    win = plots.Window(m, np.zeros(1, PLAN_DTYPE), segs)
    s = plots.sample_plan(segs, n_uniform=20001)
    speed, a_t, j_t = plots.toolhead_kinematics(s.vel, s.acc, s.jerk, s.side)
    tau = s.t
    np.testing.assert_allclose(speed, np.hypot(V - A * tau, A * tau), atol=1e-9)
    assert np.isclose(speed.min(), V / math.sqrt(2), rtol=1e-6)
    # independent check: finite differences of the speed and of a_t
    mid = slice(5, -5)
    np.testing.assert_allclose(np.gradient(speed, tau)[mid], a_t[mid], atol=1e-3 * A)
    np.testing.assert_allclose(np.gradient(a_t, tau)[mid], j_t[mid], rtol=2e-3, atol=1e-3 * A / tb)
    fig = plots.plot_velocity(win)
    _, jp = xy(line_by_gid(fig, "jerk"))
    assert np.all(jp > 0)  # the speed's curvature through a blend is positive (a dip)


def test_velocity_plot_matches_the_planners_sampler():
    from gcodeplan.planner import sample_segments

    win = corner_window()
    fig = plots.plot_velocity(win)
    t, v = xy(line_by_gid(fig, "speed"))
    _, vel, _, _ = sample_segments(win.segs, t)
    np.testing.assert_allclose(v, np.linalg.norm(np.asarray(vel)[:, :3], axis=1), atol=1e-9)


# ----------------------------------------------------------------------------- axes
def test_axes_plot_positions_velocities_and_limits():
    win = corner_window()
    lim = win.limits.copy()
    lim["axis_v_x"] = 250.0
    lim["axis_v_y"] = 180.0
    win.limits = lim
    fig = plots.plot_axes(win, Machine())
    t, x = xy(line_by_gid(fig, "pos_x"))
    # closed form along move 1 (x from 0 with the trapezoid's distance)
    p = win.plan[0]
    m1 = t <= p["duration"]
    tau = t[m1]
    A, V = p["accel"], p["cruise_v"]
    dist = np.where(tau <= p["accel_t"], A * tau ** 2 / 2,
                    np.where(tau <= p["accel_t"] + p["cruise_t"], V * p["accel_t"] / 2 + V * (tau - p["accel_t"]),
                             40.0 - (p["end_v"] * (p["duration"] - tau) + A * (p["duration"] - tau) ** 2 / 2)))
    np.testing.assert_allclose(x[m1], dist, atol=1e-9)
    # e position follows the path share: 1.5 mm over move 1's 40 mm
    _, e = xy(line_by_gid(fig, "pos_e"))
    np.testing.assert_allclose(e[m1], 1.5 * dist / 40.0, atol=1e-9)
    _, lv = xy(line_by_gid(fig, "limit_axis_v_x"))
    assert np.nanmax(lv) == 250.0 and np.nanmin(lv) == 250.0
    _, lvy = xy(line_by_gid(fig, "limit_axis_v_y"))
    assert np.nanmax(lvy) == 180.0
    names = {ln.get_gid() for ax in fig.axes for ln in ax.get_lines()}
    assert "pos_a" not in names and "limit_axis_v_z" not in names  # cartesian; machine z limit is inf


def test_axes_plot_corexy_adds_the_steppers_and_step_rate_limit():
    win = corner_window()
    mach = Machine(kinematics="corexy", max_step_rate=16000.0)
    fig = plots.plot_axes(win, mach)
    _, x = xy(line_by_gid(fig, "pos_x"))
    _, y = xy(line_by_gid(fig, "pos_y"))
    _, a = xy(line_by_gid(fig, "pos_a"))
    _, b = xy(line_by_gid(fig, "vel_b"))
    _, vx = xy(line_by_gid(fig, "vel_x"))
    _, vy = xy(line_by_gid(fig, "vel_y"))
    np.testing.assert_allclose(a, x + y)
    np.testing.assert_allclose(b, vx - vy)
    _, lim = xy(line_by_gid(fig, "steprate_a"))
    assert np.allclose(lim, 16000.0 / 80.0)


# ----------------------------------------------------------------------------- path
def test_path_plot_pieces_lie_on_the_path_coloured_by_the_closed_form_speed():
    win = corner_window()
    fig = plots.plot_path(win)
    ax = fig.axes[0]
    cols = {c.get_gid(): c for c in ax.collections}
    pr, tr = cols["path_print"], cols["path_travel"]
    pieces = np.asarray(pr.get_segments())
    speeds = np.asarray(pr.get_array())
    # print moves: first along y = 0 from x 0..40, then x = 40 from y 0..30
    on_first = np.all(np.abs(pieces[:, :, 1]) < 1e-12, axis=1)
    on_second = np.all(np.abs(pieces[:, :, 0] - 40.0) < 1e-12, axis=1)
    assert np.all(on_first | on_second)
    assert np.isclose(pieces[on_first][:, :, 0].min(), 0) and np.isclose(pieces[on_first][:, :, 0].max(), 40)
    assert np.isclose(pieces[on_second][:, :, 1].max(), 30)
    # colour = speed at the piece's middle: from the distance covered, v² = v0² + 2·A·s on ramps
    p = win.plan[0]
    s_mid = pieces[on_first][:, :, 0].mean(axis=1)  # accel/decel pieces: middle time is not middle distance
    v_ramp_lo = np.sqrt(np.minimum(2 * p["accel"] * pieces[on_first][:, 0, 0], p["cruise_v"] ** 2))
    v_ramp_hi = np.sqrt(np.minimum(2 * p["accel"] * pieces[on_first][:, 1, 0], p["cruise_v"] ** 2))
    v = speeds[on_first]
    acc_part = s_mid < p["cruise_v"] ** 2 / (2 * p["accel"])
    assert np.all(v[acc_part] >= v_ramp_lo[acc_part] - 1e-9) and np.all(v[acc_part] <= v_ramp_hi[acc_part] + 1e-9)
    assert np.isclose(speeds.max(), 100.0) or speeds.max() <= 100.0 + 1e-9
    # travel is dashed and goes back to the origin, coloured up to its 150 mm/s cruise
    ls = tr.get_linestyle()[0]
    assert ls[1] is not None and len(ls[1]) >= 2
    assert np.isclose(np.asarray(tr.get_array()).max(), 150.0)
    assert pr.get_clim() == tr.get_clim() == (0.0, 150.0)
    assert any(a.get_label() == "<colorbar>" or "colorbar" in type(a).__name__.lower() or a.get_ylabel()
               == "toolhead speed (mm/s)" for a in fig.axes[1:])


# ----------------------------------------------------------------------------- layers
def test_layer_feature_times_fold_chunks_and_bars_read_back():
    lt = plots.LayerFeatureTimes()
    m = np.zeros(5, MOVE_DTYPE)
    p = np.zeros(5, PLAN_DTYPE)
    m["layer"] = [-1, 0, 0, 1, 1]
    m["feature"] = [-1, 0, 1, 1, 0]
    m["kind"] = [KIND_WAIT, KIND_PRINT, KIND_PRINT, KIND_PRINT, KIND_WAIT]
    p["duration"] = [100.0, 2.0, 3.0, 5.0, 7.0]
    lt.add(m[:2], p[:2])
    lt.add(m[2:], p[2:])  # the second chunk grows the table (layer 1, feature 1)
    names = lt.column_names(["perimeter", "infill"])
    assert names == ["(untagged)", "perimeter", "infill", "(waits)"]
    expect = np.array([[0, 0, 0, 100.0], [0, 2.0, 3.0, 0], [0, 0, 5.0, 7.0]])
    np.testing.assert_array_equal(lt.t_s, expect)
    np.testing.assert_array_equal(lt.layer_times(), [5.0, 12.0])
    fig = plots.plot_layers(lt, ["perimeter", "infill"], layer_z=[0.2, 0.4])
    ax = fig.axes[0]
    heights = {c.get_label(): [r.get_height() for r in c] for c in ax.containers}
    assert heights == {"infill": [3.0, 5.0], "(waits)": [0.0, 7.0], "perimeter": [2.0, 0.0]}
    assert {r.get_gid() for c in ax.containers for r in c} == {"layer_bars:infill", "layer_bars:(waits)",
                                                               "layer_bars:perimeter"}
    assert "100.0 s" in fig._suptitle.get_text()


def test_plot_layers_without_layers_is_a_user_error():
    with pytest.raises(GcodeplanError):
        plots.plot_layers(plots.LayerFeatureTimes(), [])


# ----------------------------------------------------------------------------- files, size, text
def png_size(path):
    with open(path, "rb") as f:
        head = f.read(24)
    assert head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR"
    return struct.unpack(">II", head[16:24])


def layer_window_fig():
    lt = plots.LayerFeatureTimes()
    m = np.zeros(40, MOVE_DTYPE)
    p = np.zeros(40, PLAN_DTYPE)
    m["layer"] = np.repeat(np.arange(20), 2)
    m["feature"] = np.tile([0, 1], 20)
    p["duration"] = np.linspace(1, 30, 40)
    lt.add(m, p)
    return plots.plot_layers(lt, ["External perimeter", "Solid infill"], layer_z=list(0.2 * np.arange(1, 21)))


UNITLESS = {"layer index"}


def drawn_texts(fig):
    """The text a reader sees: titles, axis labels, tick labels inside the view, legend entries."""
    out = [t for t in fig.texts] + ([fig._suptitle] if fig._suptitle is not None else [])
    axes = list(fig.axes)
    axes += [c for ax in fig.axes for c in getattr(ax, "child_axes", [])]
    for ax in axes:
        out += [ax.title, ax._left_title, ax._right_title]
        for axis, lim in ((ax.xaxis, ax.get_xlim()), (ax.yaxis, ax.get_ylim())):
            if not axis.get_visible():
                continue
            out.append(axis.label)
            lo, hi = min(lim), max(lim)
            span = hi - lo
            for tick in axis.get_major_ticks():
                loc = tick.get_loc()
                if lo - 1e-9 * span <= loc <= hi + 1e-9 * span:
                    out += [lab for lab in (tick.label1, tick.label2) if lab.get_visible()]
        leg = ax.get_legend()
        if leg is not None:
            out += list(leg.get_texts()) + [leg.get_title()]
    unique = {id(t): t for t in out}
    return [t for t in unique.values() if t.get_visible() and t.get_text().strip()]


ALL_KINDS = {
    "velocity": lambda: plots.plot_velocity(corner_window()),
    "axes": lambda: plots.plot_axes(corner_window(), Machine(kinematics="corexy")),
    "path": lambda: plots.plot_path(corner_window()),
    "layers": layer_window_fig,
}


@pytest.mark.parametrize("kind", sorted(ALL_KINDS))
def test_png_is_1600x900_and_no_text_overlaps(kind, tmp_path):
    fig = ALL_KINDS[kind]()
    out = tmp_path / f"{kind}.png"
    plots.save_png(fig, out)
    assert out.stat().st_size > 10_000
    assert png_size(out) == (1600, 900)
    renderer = fig.canvas.get_renderer()
    boxes = [(t.get_text(), t.get_window_extent(renderer)) for t in drawn_texts(fig)]
    assert len(boxes) > 10
    fig_box = fig.bbox
    for text, b in boxes:  # inside the picture
        assert b.x0 >= fig_box.x0 - 1 and b.x1 <= fig_box.x1 + 1 and b.y0 >= -1 and b.y1 <= fig_box.y1 + 1, text
    overlaps = [(a[0], b[0]) for a, b in combinations(boxes, 2)
                if a[1].width > 0 and b[1].width > 0 and a[1].shrunk(0.9, 0.9).overlaps(b[1].shrunk(0.9, 0.9))]
    assert not overlaps, overlaps
    # every axis carries a unit: "(mm...)", "(s)" ...
    for ax in fig.axes:
        for label in (ax.get_xlabel(), ax.get_ylabel()):
            if label and label not in UNITLESS:
                assert "(" in label and ")" in label, label


def test_save_png_to_an_unwritable_place_is_a_user_error(tmp_path):
    fig = plots.plot_velocity(corner_window())
    with pytest.raises(GcodeplanError, match="cannot write"):
        plots.save_png(fig, tmp_path / "no" / "such" / "dir" / "v.png")


def test_empty_window_is_a_user_error():
    win = plots.Window(np.zeros(0, MOVE_DTYPE), np.zeros(0, PLAN_DTYPE), np.zeros(0, SEGMENT_DTYPE))
    with pytest.raises(GcodeplanError, match="no motion"):
        plots.plot_velocity(win)


def zigzag_window(n_moves):
    """n straight print moves on a zigzag (5 mm in x, 0.4 mm in y), corners at 10 mm/s, cruise 40 mm/s,
    2000 mm/s²: the same closed-form trapezoid as ``trapezoid_move``, built for all moves at once."""
    A, V, Vc = 2000.0, 40.0, 10.0
    i = np.arange(n_moves)
    d = np.stack([np.where(i % 2 == 0, 5.0, -5.0), np.full(n_moves, 0.4), np.zeros(n_moves),
                  np.full(n_moves, 0.02)], axis=1)
    p0 = np.r_[[[0.0, 0.0, 0.2, 0.0]], np.cumsum(d, axis=0)[:-1] + [0.0, 0.0, 0.2, 0.0]]
    length = np.linalg.norm(d[:, :3], axis=1)
    u = d / length[:, None]
    v0 = np.where(i == 0, 0.0, Vc)
    v1 = np.where(i == n_moves - 1, 0.0, Vc)
    ta, td = (V - v0) / A, (V - v1) / A
    tc = (length - (v0 + V) / 2 * ta - (V + v1) / 2 * td) / V
    dur = ta + tc + td
    t_start = np.r_[0.0, np.cumsum(dur)[:-1]]
    moves = np.zeros(n_moves, MOVE_DTYPE)
    plan = np.zeros(n_moves, PLAN_DTYPE)
    moves["line"], moves["kind"], moves["move_d"], moves["feed_v"], moves["accel"] = i + 1, KIND_PRINT, length, V, A
    for k, a in enumerate(AX):
        moves[a + "0"], moves[a + "1"] = p0[:, k], p0[:, k] + d[:, k]
    plan["t_start"], plan["start_v"], plan["cruise_v"], plan["end_v"] = t_start, v0, V, v1
    plan["accel"] = plan["decel"] = A
    plan["accel_t"], plan["cruise_t"], plan["decel_t"], plan["duration"] = ta, tc, td, dur
    segs = np.zeros((n_moves, 3), SEGMENT_DTYPE)
    seg_dt = np.stack([ta, tc, td], axis=1)
    seg_v = np.stack([v0, np.full(n_moves, V), np.full(n_moves, V)], axis=1)
    seg_a = np.array([A, 0.0, -A])
    dist0 = np.stack([np.zeros(n_moves), (v0 + V) / 2 * ta, length - (V + v1) / 2 * td], axis=1)
    segs["t0"] = t_start[:, None] + np.c_[np.zeros(n_moves), ta, ta + tc]
    segs["dt"], segs["move"] = seg_dt, i[:, None]
    segs["phase"] = np.array([PHASE_ACCEL, PHASE_CRUISE, PHASE_DECEL])
    for k, a in enumerate(AX):
        segs["p" + a] = p0[:, k, None] + u[:, k, None] * dist0
        segs["v" + a] = seg_v * u[:, k, None]
        segs["a" + a] = seg_a[None, :] * u[:, k, None]
    segs = segs.ravel()
    return plots.Window(moves, plan, segs[segs["dt"] > 0], 0, Machine().limits_row(), "zigzag")


def test_zigzag_builder_agrees_with_the_per_move_builder():
    fast = zigzag_window(4)
    parts, t, pt = [], 0.0, np.array([0.0, 0.0, 0.2, 0.0])
    for i in range(4):
        nxt = pt + np.array([5.0 if i % 2 == 0 else -5.0, 0.4, 0.0, 0.02])
        part = trapezoid_move(pt, nxt, 0.0 if i == 0 else 10.0, 40.0, 0.0 if i == 3 else 10.0, 2000.0, t, i,
                              line=i + 1)
        parts.append(part)
        t += float(part[1]["duration"][0])
        pt = nxt
    slow = join(parts)
    for name in SEGMENT_DTYPE.names:
        np.testing.assert_allclose(fast.segs[name], slow.segs[name], atol=1e-12, err_msg=name)
    np.testing.assert_allclose(fast.plan["t_start"], slow.plan["t_start"], atol=1e-12)


def test_a_10000_move_window_draws_in_a_bounded_number_of_artists(tmp_path):
    """What keeps a big window fast to draw: a fixed number of artists (collections and a few lines), never
    one per move. The time itself is a benchmark (``python tools/bench.py plots``), not a unit test."""
    win = zigzag_window(10_000)
    for what, fn in (("velocity", plots.plot_velocity), ("path", plots.plot_path)):
        fig = fn(win)
        artists = sum(len(ax.lines) + len(ax.collections) for ax in fig.axes)
        assert 0 < artists <= 40, f"{what}: {artists} artists"
        if what == "path":     # every moving piece of the 10,000 moves is in the two collections
            drawn = sum(len(c.get_segments()) for c in fig.axes[0].collections)
            assert drawn >= 10_000
        out = tmp_path / f"{what}.png"
        plots.save_png(fig, out)
        assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_plot_profile_1d_draws_the_given_arrays():
    t = np.linspace(0, 1, 11)
    fig = plots.plot_profile_1d(t, t ** 2, 2 * t, 2 + 0 * t, 0 * t, "x")
    _, v = xy(line_by_gid(fig, "v"))
    np.testing.assert_array_equal(v, 2 * t)


# ----------------------------------------------------------------------------- the command, on real files
CUBE = "prusaslicer25_cube20_marlin2.gcode"


def klipper_machine():
    from gcodeplan.config import load_machine

    return load_machine("klipper")


def test_layer_window_is_planned_from_the_file_start_and_matches_klippers_per_line_times(samples):
    import csv
    import gzip

    from conftest import shared_path
    from gcodeplan.commands.plot import Selection, load_window

    ref = shared_path("reference", "klipper", "per_line", CUBE.replace(".gcode", ".per_line_end_time.csv.gz"))
    with gzip.open(ref, "rt") as fh:
        klipper_end = {int(r["source_line"]): float(r["end_time_s"]) for r in csv.DictReader(fh)}
    win, _ = load_window(str(samples / CUBE), klipper_machine(), Selection(layer=3))
    assert np.all(win.moves["layer"] == 3) and win.moves.size > 20
    end = win.plan["t_start"] + win.plan["duration"]
    # the window's plan carries the file's absolute times: Klipper's per-line end times
    lines = win.moves["line"]
    checked = 0
    for line in np.unique(lines):
        if int(line) in klipper_end:
            assert abs(end[lines == line].max() - klipper_end[int(line)]) < 2e-6, line
            checked += 1
    assert checked > 20
    # and the segments drawn are that plan: each move's pieces tile [t_start, t_start + duration]
    seg_rows = win.move_rows(win.segs["move"])
    for k in np.unique(seg_rows):
        s = win.segs[seg_rows == k]
        assert np.isclose(s["t0"][0], win.plan["t_start"][k], atol=1e-9)
        assert np.isclose(s["t0"][-1] + s["dt"][-1], end[k], atol=1e-9)
    fig = plots.plot_velocity(win)
    t, v = xy(line_by_gid(fig, "speed"))
    from gcodeplan.planner import sample_segments

    _, vel, _, _ = sample_segments(win.segs, t)
    inner = np.r_[True, np.diff(t) > 0] & np.r_[np.diff(t) > 0, True]  # away from two-sided boundary samples
    np.testing.assert_allclose(v[inner], np.linalg.norm(vel[inner, :3], axis=1), atol=1e-9)


def test_time_window_is_cut_exactly_at_its_ends(samples):
    from gcodeplan.commands.plot import Selection, load_window

    win, _ = load_window(str(samples / CUBE), klipper_machine(), Selection(t_from=100.0, t_to=101.5))
    assert np.isclose(win.segs["t0"][0], 100.0) and np.isclose(win.segs["t0"][-1] + win.segs["dt"][-1], 101.5)
    full, _ = load_window(str(samples / CUBE), klipper_machine(), Selection(lines=(int(win.moves["line"][0]),
                                                                                  int(win.moves["line"][-1]))))
    # the cut pieces are the same polynomials re-based: positions agree at common times
    t = np.linspace(100.0, 101.5, 301)
    from gcodeplan.planner import sample_segments

    a = sample_segments(win.segs, t)[0]
    b = sample_segments(full.segs, t)[0]
    np.testing.assert_allclose(a, b, atol=1e-9)


def run_cli(argv):
    from gcodeplan.cli import main

    return main(argv)


@pytest.mark.parametrize("what,window", [("velocity", ["--layer", "3"]), ("axes", ["--lines", "500:560"]),
                                         ("path", ["--layer", "3"]), ("layers", [])])
def test_plot_command_writes_a_1600x900_png(what, window, samples, tmp_path, capsys):
    out = tmp_path / f"{what}.png"
    assert run_cli(["plot", str(samples / CUBE), "--what", what, "-o", str(out), *window]) == 0
    assert png_size(out) == (1600, 900) and out.stat().st_size > 20_000
    assert capsys.readouterr().out.strip() == str(out)


@pytest.mark.parametrize("argv,message", [
    (["--layer", "500"], "no moves in the selected window (layer 500)"),
    (["--lines", "9:3"], "--lines: expected A:B"),
    (["--layer", "2", "--lines", "1:5"], "choose one window"),
    (["--from", "5", "--to", "2"], "must be after --from"),
    (["--what", "layers", "--layer", "2"], "--what layers draws every layer"),
    (["--size", "12x9"], "--size"),
    (["-o", "/nonexistent-dir/x.png"], "cannot write"),
    (["-o", "picture.jpg"], "must end in .png, .svg or .pdf"),
])
def test_plot_command_user_errors_exit_2_with_one_line(argv, message, samples, capsys):
    assert run_cli(["plot", str(samples / CUBE), *argv]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and "Traceback" not in err


def test_plot_command_on_a_missing_file_names_it(tmp_path, capsys):
    assert run_cli(["plot", str(tmp_path / "nope.gcode"), "-o", str(tmp_path / "x.png")]) == 2
    assert "nope.gcode" in capsys.readouterr().err
@pytest.mark.parametrize("policy,jerk", [("blend", None), (None, 50_000.0)])
def test_blend_and_scurve_windows_are_drawn_from_their_planners_segments(policy, jerk, samples):
    from gcodeplan.planner import sample_segments
    from gcodeplan.commands.plot import Selection, load_window

    from dataclasses import replace

    machine = replace(klipper_machine(), blend_tolerance=0.05)  # a path tolerance, so that corners blend
    win, _ = load_window(str(samples / "d_slicer_like.gcode"), machine, Selection(t_from=5.0, t_to=8.0),
                         policy=policy, jerk=jerk)
    if policy == "blend":
        assert np.any(win.segs["phase"] == PHASE_BLEND)
    else:
        assert np.all(win.plan["jerk"][win.plan["duration"] > 0] == jerk)
    fig = plots.plot_velocity(win)
    t, v = xy(line_by_gid(fig, "speed"))
    ok = ~np.isnan(t)  # breaks where the window has holes in time (dwell rows carry no motion)
    t, v = t[ok], v[ok]
    _, vel, _, _ = sample_segments(win.segs, t)
    inner = np.r_[True, np.diff(t) > 0] & np.r_[np.diff(t) > 0, True]
    np.testing.assert_allclose(v[inner], np.linalg.norm(vel[inner, :3], axis=1), atol=1e-9)
    names = {ln.get_gid() for ax in fig.axes for ln in ax.get_lines()}
    if jerk:  # jerk-limited: acceleration is continuous, no impulses, |jerk| ≤ J on straight pieces
        assert "jerk_steps_up" not in names and "jerk_steps_down" not in names
        _, j = xy(line_by_gid(fig, "jerk"))
        assert np.nanmax(np.abs(j)) <= jerk * (1 + 1e-9)


# ----------------------------------------------------------------------------- issue 19
def _dark_share(fig, ax) -> float:
    """Share of the pixels inside ``ax`` that are dark (all channels < 0.35): a solid black block is ~1."""
    fig.canvas.draw()
    img = np.asarray(fig.canvas.buffer_rgba())[..., :3] / 255.0
    b = ax.get_window_extent()
    h = img.shape[0]
    crop = img[int(h - b.y1) + 2:int(h - b.y0) - 2, int(b.x0) + 2:int(b.x1) - 2]
    return float(np.mean(np.all(crop < 0.35, axis=-1)))


def test_whole_print_velocity_is_an_envelope_with_its_time_weighted_mean():
    """A window of more moves than pixels: a light min–max band per pixel column and the time-weighted mean
    speed, whose integral over time is the distance the toolhead covers (trapezoid rule: exact here)."""
    win = zigzag_window(10_000)
    fig = plots.plot_velocity(win)
    ax_v = fig.axes[0]
    assert _dark_share(fig, ax_v) < 0.05           # was a solid black block
    t, mean = xy(line_by_gid(fig, "speed_mean"))
    ok = np.isfinite(mean)
    lo, hi = win.t_range
    width = (hi - lo) / plots.DENSE_COLUMNS
    distance = float(np.sum(mean[ok]) * width)
    xyz = (win.moves["kind"] <= 1)
    assert distance == pytest.approx(float(win.moves["move_d"][xyz].sum()), rel=1e-3)
    assert len(fig.axes) == 2                       # trapezoids: no jerk panel
    names = {ln.get_gid() for ax in fig.axes for ln in ax.get_lines()}
    assert "junctions" not in names                 # 10 000 markers are not drawn over each other


def test_a_window_late_in_a_print_has_plain_time_ticks():
    """Times around 18 700 s over a few seconds: the ticks say 18701.5, not 1.5 with a '+1.87e4' offset."""
    win = corner_window()
    shift = 18700.0
    win.plan["t_start"] += shift
    win.segs["t0"] += shift
    fig = plots.plot_velocity(win)
    fig.canvas.draw()
    for ax in fig.axes:
        assert ax.xaxis.get_offset_text().get_text() == ""
        assert ax.yaxis.get_offset_text().get_text() == ""
    labels = [t.get_text() for t in fig.axes[-1].get_xticklabels() if t.get_text()]
    assert labels and all(float(x.replace("−", "-")) >= 18699 for x in labels), labels


def _cnc_window(tmp_path):
    from gcodeplan.commands.plot import Selection, load_window
    from gcodeplan.config import load_machine

    src = tmp_path / "pocket.ngc"
    src.write_text("G21 G90\nG0 Z5\nG0 X10 Y10\nG1 Z-1 F300\nG1 X30 F1200\nG1 Y30\nG1 X10\nG1 Y10\nG0 Z5\n"
                   "G0 X0 Y0\nM2\n")
    machine = load_machine("grbl")
    win, _ = load_window(str(src), machine, Selection())
    return win, machine


def test_cnc_plots_say_cutting_moves_and_have_no_e_row(tmp_path):
    win, machine = _cnc_window(tmp_path)
    fig = plots.plot_path(win, machine=machine)
    texts = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert texts == ["cutting (feed) moves", "rapids (G0, dashed)"]
    cols = {c.get_gid(): c for c in fig.axes[0].collections}
    assert len(cols["path_print"].get_segments()) >= 4       # the four sides of the pocket are cuts
    fig = plots.plot_axes(win, machine)
    labels = [ax.get_ylabel() for ax in fig.axes]
    assert not any(lab.startswith("e ") for lab in labels), labels
    assert any(lab.startswith("z ") for lab in labels)


def test_a_piece_turning_at_constant_speed_is_shaded_as_cruise():
    """LinuxCNC's arc pieces accelerate normal to the path (v ⟂ a): the speed is constant, so the shading
    says cruise, whatever phase the fit gave the piece; a piece accelerating along its path stays accel."""
    from gcodeplan.schema import PHASE_ACCEL, PHASE_CRUISE, PHASE_DECEL, SEGMENT_DTYPE

    segs = np.zeros(3, SEGMENT_DTYPE)
    segs["dt"] = 0.1
    segs["t0"] = [0.0, 0.1, 0.2]
    segs["vx"] = [10.0, 100.0, 100.0]
    segs["vy"] = [-0.25, 0.0, 0.0]      # at the piece's middle v ⟂ a (a chord of the circle)
    segs["ay"] = [5.0, 0.0, 0.0]        # v²/r: a 20 mm circle at 10 mm/s
    segs["ax"] = [0.0, 1000.0, -1000.0]
    segs["phase"] = [PHASE_DECEL, PHASE_ACCEL, PHASE_DECEL]
    out = plots.tangential_phases(segs)
    assert out["phase"].tolist() == [PHASE_CRUISE, PHASE_ACCEL, PHASE_DECEL]
