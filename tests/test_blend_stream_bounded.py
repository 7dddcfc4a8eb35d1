"""Blend mode streams with a bounded window even when a run never stops (issue 13).

Truth: whole-program planning (``plan_with_segments``), bit for bit; and, for the split at settled corners
itself, the earlier rule that planned each stop-to-stop run whole (re-implemented here from the kernels):
splitting a run where nothing after a corner can lower it must give the same corner speeds.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from gcodeplan import pipeline

from conftest import klipper_machine, moves_from_points, shared_path
from gcodeplan.planner import StreamPlanner, plan_with_segments
from gcodeplan.planner import blend as B
from gcodeplan.schema import PHASE_BLEND


def stream(moves, limits, machine, chunk):
    sp = StreamPlanner(machine, policy="blend")
    plans, segs, window, first = [], [], 0, 0
    for i in range(0, len(moves), chunk):
        for mv, pl in sp.feed(moves[i:i + chunk], limits):
            plans.append(pl)
            segs.append(sp.segments_for(mv, pl, first))
            first += len(mv)
        window = max(window, sp.pending)
    for mv, pl in sp.finish():
        plans.append(pl)
        segs.append(sp.segments_for(mv, pl, first))
        first += len(mv)
    return np.concatenate(plans), np.concatenate(segs), window


def same(got, want, what):
    assert len(got) == len(want), what
    for f in want.dtype.names:
        assert np.array_equal(got[f], want[f], equal_nan=True), (what, f)


def spiral_points(n, seg=0.5, seed=None):
    """A flat spiral whose radius swings between 20 and 80 mm: ~seg mm chords, small turns, no stop."""
    rng = np.random.default_rng(seed)
    pts = []
    theta = 0.0
    for i in range(n + 1):
        r = 50.0 + 30.0 * math.sin(theta / 40.0)
        pts.append((100.0 + r * math.cos(theta), 100.0 + r * math.sin(theta), 0.2, 0.02 * i))
        step = seg if seed is None else seg * rng.uniform(0.05, 3.0)
        theta += step / r
    return pts


def blend_machine(tol=0.05):
    return replace(klipper_machine("blend"), blend_tolerance=tol)


def path(points, feed_v):
    mv = moves_from_points(points, feed_v=feed_v)
    mv["blend_p"] = np.nan          # the machine's tolerance (moves_from_points leaves 0: exact path)
    return mv


@pytest.mark.parametrize("chunk", [1, 7, 1000])
def test_never_stopping_spiral_streams_bit_identically_in_a_small_window(chunk):
    m = blend_machine()
    mv = path(spiral_points(6000), 150.0)
    lim = m.limits_row()
    want, want_segs = plan_with_segments(mv, lim, m, "blend")
    rows, _, corner_v2 = B.corner_geometry(mv, lim, m)
    assert np.count_nonzero(corner_v2[1:-1] <= 0.0) == 0          # not one stop inside: one run of 6000 moves
    assert np.any(want_segs["phase"] == PHASE_BLEND)
    plan, segs, window = stream(mv, lim, m, chunk)
    same(plan, want, "plan")
    same(segs, want_segs, "segments")
    # the window holds the chunk and a braking distance (150 mm/s at 3000 mm/s² ≈ 4 mm ≈ 8 chords), not the run
    assert window <= chunk + 40, window


def old_rule_corner_speeds(moves, limits, machine):
    """The rule before issue 13: each run between two stops planned whole, no split at settled corners."""
    prep, aux = B.blend_row_limits(moves, limits, machine)
    ml = B._window_rows(moves, prep, aux)
    corner_c, corner_v2 = B.blend_corners_kernel(*(ml[k] for k in B._CORNER_INPUTS))
    m = len(ml["rows"])
    a = 0
    for j in range(1, m + 1):
        if j == m or corner_v2[j] <= 0.0:
            B.blend_speeds_kernel(ml["move_d"], ml["accel"], ml["max_cruise_v2"], corner_c, corner_v2, a, j, False)
            a = j
    return corner_v2


@pytest.mark.parametrize("seed", range(12))
def test_split_at_settled_corners_keeps_the_corner_speeds(seed):
    """Random spirals with uneven chords, mixed accelerations (M204 per move), tolerances and slow per-axis
    limits (corners that may lose to a stop): the same corner speeds as planning each run whole, and the
    stream bit-identical to the whole program."""
    rng = np.random.default_rng(seed)
    m = blend_machine(tol=float(rng.choice([0.01, 0.05, 0.5])))
    if seed % 3 == 0:
        m.axes["x"] = replace(m.axes["x"], max_accel=float(rng.choice([200.0, 800.0])))
    pts = np.array(spiral_points(1500, seg=float(rng.choice([0.2, 1.0, 4.0])), seed=seed))
    pts[:, 2] += np.cumsum(rng.choice([0.0, 0.0, 0.0, 0.02], len(pts)))     # some Z steps
    kink = rng.random(len(pts)) < 0.15                                      # sharper corners here and there
    pts[kink, :2] += rng.normal(0.0, 0.5, (int(kink.sum()), 2))
    mv = path(pts, float(rng.choice([40.0, 150.0, 400.0])))
    mv["accel"] = rng.choice([500.0, 1500.0, 3000.0, 10000.0], len(mv))
    mv["blend_p"] = np.where(rng.random(len(mv)) < 0.2, rng.choice([0.001, 0.2, 1.0], len(mv)), np.nan)
    lim = m.limits_row()
    _, _, got = B.corner_geometry(mv, lim, m)
    want = old_rule_corner_speeds(mv, lim, m)
    assert np.allclose(got, want, rtol=1e-9, atol=1e-9), float(np.max(np.abs(got - want)))
    want_plan, want_segs = plan_with_segments(mv, lim, m, "blend")
    for chunk in (1, 13, 400):
        plan, segs, _ = stream(mv, lim, m, chunk)
        same(plan, want_plan, ("plan", chunk))
        same(segs, want_segs, ("segments", chunk))


def test_window_start_continues_the_blend_across_emissions():
    # a square spiral cut into chunks of one move: every corner blends, and the pieces stay continuous in
    # position and velocity across the emission boundaries (the first move of a window enters through a blend)
    m = blend_machine(tol=0.2)
    pts = [(0, 0, 0, 0)]
    for k in range(40):
        s = 40.0 - k
        x, y = pts[-1][0], pts[-1][1]
        pts.append((x + s * (k % 4 == 0) - s * (k % 4 == 2), y + s * (k % 4 == 1) - s * (k % 4 == 3), 0, 0))
    mv = path(pts, 200.0)
    plan, segs, window = stream(mv, m.limits_row(), m, 1)
    assert np.count_nonzero(segs["phase"] == PHASE_BLEND) >= 70
    t_end = segs["t0"] + segs["dt"]
    assert np.allclose(t_end[:-1], segs["t0"][1:], rtol=0, atol=1e-12)
    for ax in "xyz":
        dt = segs["dt"][:-1]
        p_end = segs["p" + ax][:-1] + segs["v" + ax][:-1] * dt + 0.5 * segs["a" + ax][:-1] * dt ** 2
        v_end = segs["v" + ax][:-1] + segs["a" + ax][:-1] * dt
        assert np.allclose(p_end, segs["p" + ax][1:], atol=1e-9)
        assert np.allclose(v_end, segs["v" + ax][1:], atol=1e-7)
    assert window <= 8


@pytest.mark.slow
def test_vase_spiral_streams_bit_identically_in_a_small_window():
    path = shared_path("gcode", "prusaslicer25_twisted_vase_spiral.gcode")
    m = blend_machine()
    run = pipeline.Run(str(path), m, policy="blend", batch_moves=997)
    batches, plans, segs, window = [], [], [], 0
    for piece in run:                  # the library's own driver: reader -> streaming planner
        batches.append(piece.moves)
        plans.append(piece.plan)
        segs.append(piece.segments)
        window = max(window, run.planner.pending)
    reader = run.reader
    moves = np.concatenate(batches)
    want, want_segs = plan_with_segments(moves, reader.limits, m, "blend")
    same(np.concatenate(plans), want, "plan")
    same(np.concatenate(segs), want_segs, "segments")
    rows, _, corner_v2 = B.corner_geometry(moves, reader.limits, m)
    stops = np.flatnonzero(corner_v2 <= 0.0)
    longest_run = int(np.diff(stops).max())
    assert longest_run > 5000            # runs of thousands of moves without a stop …
    assert window < 997 + 100, window    # … planned in a window of a batch and a braking distance
