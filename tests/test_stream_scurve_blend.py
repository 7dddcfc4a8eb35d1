"""Streaming S-curve and blend planning: bounded look-ahead, output bit-identical to whole-program planning.

Truth: ``plan_with_segments`` on the whole program (the same planners without a window), closed forms of the
jerk-limited braking reach, and a grid search for its least value.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from gcodeplan.errors import ConfigError
from gcodeplan.planner import StreamPlanner, plan_moves, plan_with_segments
from gcodeplan.planner.scurve import SETTLED_RTOL, least_reach_start_v, longest_brake_end_v
from gcodeplan.profiles.scurve import ramp_distance_kernel, scurve_max_start_speed_kernel
from gcodeplan.schema import PHASE_BLEND

from conftest import shared_path
from conftest import klipper_machine, limits_variants, moves_from_points, random_program

CHUNKS = (1, 7, 100, 5000)


def stream_all(moves, limits, machine, chunk, **kw):
    """Feed ``moves`` in chunks; (moves, plan, segments from segments_for, largest window, emissions before
    finish)."""
    sp = StreamPlanner(machine, **kw)
    parts, segs = [], []
    first = window = early = 0

    def take(pairs):
        nonlocal first
        for mv, pl in pairs:
            parts.append((mv, pl))
            segs.append(sp.segments_for(mv, pl, first))
            first += len(mv)

    for i in range(0, len(moves), chunk):
        take(sp.feed(moves[i:i + chunk], limits))
        window = max(window, sp.pending)
    early = first
    take(sp.finish())
    return (np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts]),
            np.concatenate(segs), window, early)


def assert_same_rows(got, want, what):
    assert len(got) == len(want), what
    for f in want.dtype.names:
        nan_ok = want[f].dtype.kind == "f"   # MOVE.blend_p is nan = "machine default"
        assert np.array_equal(got[f], want[f], equal_nan=nan_ok), (what, f)


def blend_machine(policy="klipper"):
    return replace(klipper_machine(policy), blend_tolerance=0.05)


# --------------------------------------------------------------------------- the settled-junction bound
def reach(d, a, j, x, v_max=1e9):
    return scurve_max_start_speed_kernel(d, v_max, a, j, x)


def test_backward_reach_is_not_monotone_and_least_reach_matches_the_closed_form():
    # Pure S (small d): from end speed x the ramp covers (2x + Δv)·√(Δv/J) = d. At x = 0: R = (d·√J)^(2/3);
    # the least R is at x = Δv/2 with Δv = (d·√J/2)^(2/3), R = 1.5·Δv (hand-derived, module docstring).
    d, a, j = 0.5, 1e9, 1e5
    r0 = (d * math.sqrt(j)) ** (2 / 3)
    dv = (0.5 * d * math.sqrt(j)) ** (2 / 3)
    assert reach(d, a, j, 0.0) == pytest.approx(r0, rel=1e-12)
    x_star = least_reach_start_v(d, a, j)
    assert x_star == pytest.approx(dv / 2, rel=1e-12)
    assert reach(d, a, j, x_star) == pytest.approx(1.5 * dv, rel=1e-12)
    assert reach(d, a, j, x_star) < 0.95 * reach(d, a, j, 0.0)   # braking to rest is not the worst case


@pytest.mark.parametrize("d,a,j", [(0.5, 3000.0, 1e5), (5.0, 3000.0, 1e5), (40.0, 500.0, 1e4),
                                   (0.01, 20000.0, 1e6), (2.0, 100.0, 1e6), (300.0, 3000.0, 5e3)])
def test_least_reach_start_v_is_the_minimum_over_every_end_speed(d, a, j):
    x_star = least_reach_start_v(d, a, j)
    r_star = reach(d, a, j, x_star)
    grid = np.linspace(0.0, 4.0 * max(x_star, r_star), 20001)
    r = np.array([reach(d, a, j, x) for x in grid])
    assert r_star <= r.min() * (1 + 1e-12)
    assert r_star >= r.min() * (1 - 1e-6)     # the grid brackets it closely
    # falls then rises: the bound R(max(x_lo, x*)) is the least reach over every x >= x_lo
    for x_lo in (0.0, 0.5 * x_star, 2.0 * x_star, 3.0 * r_star):
        above = r[grid >= x_lo]
        assert reach(d, a, j, max(x_lo, x_star)) * (1 - SETTLED_RTOL) <= above.min()


@pytest.mark.parametrize("v_max,a,j", [(150.0, 3000.0, 1e5), (300.0, 3000.0, 1e5), (50.0, 10000.0, 1e5),
                                         (150.0, 500.0, 1e6), (20.0, 3000.0, 1e4)])
def test_longest_brake_end_v_is_the_maximum_braking_distance_from_v_max(v_max, a, j):
    x_w = longest_brake_end_v(v_max, a, j)
    grid = np.linspace(0.0, v_max, 20001)
    dist = np.array([ramp_distance_kernel(x, v_max, a, j) for x in grid])
    d_w = ramp_distance_kernel(x_w, v_max, a, j)
    assert d_w >= dist.max() * (1 - 1e-12)
    assert d_w <= dist.max() * (1 + 1e-6)
    for x_lo in (0.0, 0.5 * x_w, 1.5 * x_w, 0.9 * v_max):
        assert ramp_distance_kernel(max(x_lo, x_w), v_max, a, j) >= dist[grid >= x_lo].max() * (1 - 1e-12)


# --------------------------------------------------------------------------- S-curves
@pytest.mark.parametrize("policy,jerk", [("klipper", 1e5), ("junction-deviation", 1e5), ("klipper", 2e3),
                                         ("classic-jerk", 3e4), ("exact-stop", 1e5)])
def test_scurve_stream_is_bit_identical_to_the_whole_program(policy, jerk):
    rng = np.random.default_rng(7)
    m = klipper_machine(policy)
    if policy == "classic-jerk":
        m.axes["x"].jerk = m.axes["y"].jerk = 8.0
        m.axes["z"].jerk = 0.4
        m.axes["e"].jerk = 5.0
    for trial in range(2):
        lim = limits_variants(m, 3, rng)
        mv = random_program(rng, 1200, n_limits=3, dwell_p=0.004 * trial, exact_p=0.004 * trial)
        want, want_segs = plan_with_segments(mv, lim, m, jerk=jerk)
        assert np.all(want["jerk"][want["duration"] > 0][mv["kind"][want["duration"] > 0] < 3] == jerk)
        for chunk in CHUNKS:
            mv_out, plan, segs, window, _ = stream_all(mv, lim, m, chunk, jerk=jerk)
            assert_same_rows(mv_out, mv, "moves")
            assert_same_rows(plan, want, ("plan", chunk))
            assert_same_rows(segs, want_segs, ("segments", chunk))
            if chunk <= 100:
                assert window < 300, window   # a look-ahead window, not the whole program


def test_scurve_stream_emits_inside_a_long_run_without_stops():
    # 3000 chords of 0.2 mm along a wavy line at 150 mm/s: no full stop until the end. With a = 0 at every
    # junction, such short moves gain or shed little speed each, so the whole plan needs hundreds of moves to
    # reach 150 mm/s and as many to brake: a move is final once the moves after it can brake it from any
    # speed, so the window should be about that braking run, not the program.
    t = np.linspace(0.0, 600.0, 3001)
    pts = np.stack([t, 5.0 * np.sin(t / 7.0), np.full_like(t, 0.2)], axis=1)
    mv = moves_from_points(pts, feed_v=150.0, accel=3000.0)
    m = klipper_machine()
    lim = m.limits_row()
    want = plan_moves(mv, lim, m, jerk=1e5)
    assert np.all(want["start_v"][1:] > 0)   # truly no stop inside
    cruising = np.flatnonzero(want["start_v"] == 150.0)
    braking_moves = len(mv) - cruising[-1]
    assert 300 < braking_moves < 1500 and cruising[0] > 300
    chunk = 50
    _, plan, _, window, early = stream_all(mv, lim, m, chunk, jerk=1e5)
    assert_same_rows(plan, want, "plan")
    assert window <= 1.05 * braking_moves + chunk, (window, braking_moves)
    assert early >= len(mv) - 1.05 * braking_moves - chunk, (early, braking_moves)


def test_scurve_jerk_from_the_limits_streams_like_the_jerk_argument():
    rng = np.random.default_rng(3)
    m = klipper_machine()
    lim = m.limits_row()
    lim["max_jerk"] = 5e4
    mv = random_program(rng, 800)
    want = plan_moves(mv, lim, m)
    assert np.all(want["jerk"][want["accel"] > 0] == 5e4)
    sp = StreamPlanner(m)
    parts = [p for i in range(0, len(mv), 64) for p in sp.feed(mv[i:i + 64], lim)] + sp.finish()
    assert sp.mode == "scurve"
    assert_same_rows(np.concatenate([p[1] for p in parts]), want, "plan")


def test_scurve_jerk_changing_along_the_program_is_refused():
    m = klipper_machine()
    lim = np.concatenate([m.limits_row(), m.limits_row()])
    lim["max_jerk"] = [5e4, 2e4]
    mv = moves_from_points([(0, 0, 0), (10, 0, 0), (10, 10, 0), (0, 10, 0)])
    sp = StreamPlanner(m)
    sp.feed(mv[:2], lim)
    later = mv[2:].copy()
    later["limits"] = 1
    with pytest.raises(ConfigError, match="max_jerk changes"):
        sp.feed(later, lim)


def test_bad_jerk_is_a_config_error_at_construction():
    with pytest.raises(ConfigError, match="max_jerk"):
        StreamPlanner(klipper_machine(), jerk=-1.0)
    with pytest.raises(ConfigError, match="max_jerk"):
        StreamPlanner(klipper_machine(), jerk=math.inf)


# --------------------------------------------------------------------------- blends
@pytest.mark.parametrize("policy", ["klipper", "junction-deviation"])
def test_blend_stream_is_bit_identical_to_the_whole_program(policy):
    rng = np.random.default_rng(11)
    m = replace(blend_machine(policy), junction_policy="blend")
    for trial in range(2):
        lim = limits_variants(m, 3, rng)
        mv = random_program(rng, 1200, n_limits=3, dwell_p=0.004 * trial, exact_p=0.004 * trial)
        if trial:
            mv["blend_p"] = np.where(rng.random(len(mv)) < 0.1, rng.choice([0.0, 0.01, 0.2], len(mv)), np.nan)
        want, want_segs = plan_with_segments(mv, lim, m, "blend")
        if trial:   # with 0.2 mm tolerances here and there, corners blend (0.05 mm alone loses to stopping)
            assert np.any(want_segs["phase"] == PHASE_BLEND)
        for chunk in CHUNKS:
            mv_out, plan, segs, window, _ = stream_all(mv, lim, m, chunk, policy="blend")
            assert_same_rows(mv_out, mv, "moves")
            assert_same_rows(plan, want, ("plan", chunk))
            assert_same_rows(segs, want_segs, ("segments", chunk))
            if chunk <= 100:
                assert window < 300, window


def test_blend_stream_emits_each_run_once_its_closing_stop_is_known():
    # square loops joined by reversals: each loop is a run of blended corners closed by a full stop
    loop = [(0, 0, 0), (10, 0, 0), (10, 10, 0), (0, 10, 0), (0, 0.5, 0), (10, 0.5, 0)]
    pts = np.concatenate([np.array(loop, float) + [0, 0, 0.2 * k] for k in range(200)])
    mv = moves_from_points(pts, feed_v=100.0)
    m = blend_machine()
    lim = m.limits_row()
    want, want_segs = plan_with_segments(mv, lim, m, "blend")
    _, plan, segs, window, early = stream_all(mv, lim, m, 10, policy="blend")
    assert_same_rows(plan, want, "plan")
    assert_same_rows(segs, want_segs, "segments")
    assert early > 0.9 * len(mv) and window < 30, (early, window)


# --------------------------------------------------------------------------- segments_for
def test_segments_for_only_knows_the_last_emissions_for_blend_and_scurve():
    m = klipper_machine()
    mv = moves_from_points([(0, 0, 0), (50, 0, 0), (50, 50, 0)])
    _, want_segs = plan_with_segments(mv, m.limits_row(), m, jerk=1e5, first_index=10)
    sp = StreamPlanner(m, jerk=1e5)
    got, first = [], 10
    (moves_a, plan_a), = sp.feed(mv, m.limits_row())     # a 50 mm move can brake from any speed: final
    got.append(sp.segments_for(moves_a, plan_a, first))
    (moves_b, plan_b), = sp.finish()
    with pytest.raises(ConfigError, match="segments_for"):
        sp.segments_for(moves_a, plan_a, first)            # asked too late: the pieces are gone
    with pytest.raises(ConfigError, match="segments_for"):
        sp.segments_for(moves_b, plan_b.copy(), first + 1)  # not an emitted plan
    got.append(sp.segments_for(moves_b, plan_b, first + len(moves_a)))
    assert_same_rows(np.concatenate(got), want_segs, "segments")
    assert set(want_segs["move"]) == {10, 11}


def test_plan_with_segments_offsets_segment_move_indices():
    m = blend_machine()
    mv = moves_from_points([(0, 0, 0), (20, 0, 0), (20, 20, 0), (0, 20, 0)])
    for kw in ({"jerk": 1e5}, {"policy": "blend"}):
        _, s0 = plan_with_segments(mv, m.limits_row(), m, kw.get("policy"), jerk=kw.get("jerk"))
        _, s5 = plan_with_segments(mv, m.limits_row(), m, kw.get("policy"), jerk=kw.get("jerk"), first_index=5)
        assert np.array_equal(s5["move"], s0["move"] + 5)
        assert np.array_equal(s5["t0"], s0["t0"])


# --------------------------------------------------------------------------- corpus
@pytest.mark.slow
@pytest.mark.parametrize("name,kw", [("cura413_ender3_cylinder30.gcode", {"jerk": 1e5}),
                                     ("prusaslicer25_cube20_marlin2.gcode", {"jerk": 2e4}),
                                     ("prusaslicer25_cube20_marlin2.gcode", {"policy": "blend"})])
def test_corpus_file_streams_bit_identically_with_a_bounded_window(name, kw):
    from gcodeplan import pipeline
    from gcodeplan.planner.blend import corner_geometry

    path = shared_path("gcode", name)
    m = blend_machine()
    batch_moves = 997
    run = pipeline.Run(str(path), m, batch_moves=batch_moves, **kw)
    parts, segs, batches = [], [], []
    window = 0
    for piece in run:
        batches.append(piece.moves)
        parts.append(piece.plan)
        segs.append(piece.segments)
        window = max(window, run.planner.pending)
    reader = run.reader
    moves = np.concatenate(batches)
    want, want_segs = plan_with_segments(moves, reader.limits, m, kw.get("policy"), jerk=kw.get("jerk"))
    assert len(moves) > 5000
    assert_same_rows(np.concatenate(parts), want, "plan")
    assert_same_rows(np.concatenate(segs), want_segs, "segments")
    if "jerk" in kw:
        assert window < batch_moves + 1000, window   # the batch plus a braking tail
    else:   # a blend run is emitted when the stop that closes it is known
        rows, _, corner_v2 = corner_geometry(moves, reader.limits, m)
        stops = np.flatnonzero(corner_v2 <= 0.0)
        longest_run = int(np.diff(rows[np.minimum(stops, len(rows) - 1)]).max())
        assert window <= batch_moves + longest_run + 2, (window, longest_run)
        assert longest_run < 2000
