"""G2/G3 → chords: geometry against closed forms, hand-worked cases and Klipper's own move count."""
from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from gcodeplan.gcode.arcs import (
    END_TOLERANCE_MM,
    ERR_BUFFER,
    MAX_CHORD_ANGLE,
    SAME_POINT_REL,
    ArcError,
    arc_chords,
    arc_chords_kernel,
    arc_error_message,
    arc_segment_count_kernel,
)

from conftest import shared_path

# (first, second, helical) axis indices of G17/G18/G19 per RS274/NGC: XY, ZX, YZ.
PLANE_AXES = {17: (0, 1, 2), 18: (2, 0, 1), 19: (1, 2, 0)}


def point(plane, a, b, h):
    """A 3-vector from plane coordinates (first axis, second axis, helical axis)."""
    ax_a, ax_b, ax_h = PLANE_AXES[plane]
    p = [0.0, 0.0, 0.0]
    p[ax_a], p[ax_b], p[ax_h] = a, b, h
    return tuple(p)


def ijk_of(plane, off_a, off_b):
    """I/J/K offsets (indexed by X/Y/Z) from offsets along the plane's first/second axis."""
    ax_a, ax_b, _ = PLANE_AXES[plane]
    off = [0.0, 0.0, 0.0]
    off[ax_a], off[ax_b] = off_a, off_b
    return tuple(off)


def plane_coords(plane, pts):
    ax_a, ax_b, ax_h = PLANE_AXES[plane]
    pts = np.asarray(pts)
    return pts[:, ax_a], pts[:, ax_b], pts[:, ax_h]


def with_start(start, pts):
    return np.vstack([np.asarray(start, dtype=float)[None, :], pts])


def sagittas(a, b, ca, cb, r):
    """Gap between each chord's midpoint and the circle of radius r: r − |centre − midpoint|."""
    mid_a = 0.5 * (a[1:] + a[:-1])
    mid_b = 0.5 * (b[1:] + b[:-1])
    return r - np.hypot(mid_a - ca, mid_b - cb)


def sagitta_closed_form(r, sweep_abs, n):
    """r·(1 − cos(φ/2)) for n equal chords of an arc sweeping sweep_abs."""
    return r * (1.0 - math.cos(sweep_abs / (2.0 * n)))


# ----------------------------------------------------------------------------- hand-worked cases

def test_quarter_circle_g17_ccw_hand_count_and_points():
    # r = 10, 90°, tolerance 0.002: a chord may span φ ≤ 2·acos(1 − 0.002/10) = 0.0400007 rad,
    # so (π/2)/φ = 39.27 → 40 chords of 2.25° each.
    pts = arc_chords((10, 0, 0), (0, 10, 0), ijk=(-10, 0, 0), clockwise=False, tolerance=0.002)
    assert len(pts) == 40
    step = math.radians(2.25)
    assert pts[0] == pytest.approx((10 * math.cos(step), 10 * math.sin(step), 0.0), abs=1e-12)
    assert pts[19] == pytest.approx((10 * math.cos(20 * step), 10 * math.sin(20 * step), 0.0), abs=1e-12)
    assert tuple(pts[-1]) == (0.0, 10.0, 0.0)
    # 39 chords would leave a sagitta above the tolerance, 40 do not.
    assert sagitta_closed_form(10, math.pi / 2, 39) > 0.002 >= sagitta_closed_form(10, math.pi / 2, 40)


def test_same_endpoints_g2_goes_the_other_way():
    # Same start/end/centre as above but clockwise: 270°, the long way through −Y.
    pts = arc_chords((10, 0, 0), (0, 10, 0), ijk=(-10, 0, 0), clockwise=True, tolerance=0.002)
    assert pts[0][1] < 0.0  # first chord heads to −Y
    assert len(pts) == math.ceil((1.5 * math.pi) / (2 * math.acos(1 - 0.0002)))  # 118
    assert np.min(pts[:, 1]) == pytest.approx(-10.0, abs=0.002)
    assert np.min(pts[:, 0]) == pytest.approx(-10.0, abs=0.002)


@pytest.mark.parametrize("plane", [17, 18, 19])
@pytest.mark.parametrize("clockwise", [False, True])
def test_each_plane_direction_and_helix(plane, clockwise):
    # Centre at (1, 2) in the plane, r = 5, from angle 30° to 120° (CCW: +90°, CW: −270°), helical 0 → 4.
    ca, cb, r = 1.0, 2.0, 5.0
    a0, a1 = math.radians(30), math.radians(120)
    start = point(plane, ca + r * math.cos(a0), cb + r * math.sin(a0), 0.0)
    end = point(plane, ca + r * math.cos(a1), cb + r * math.sin(a1), 4.0)
    ijk = ijk_of(plane, ca - start[PLANE_AXES[plane][0]], cb - start[PLANE_AXES[plane][1]])
    tol = 0.001
    pts = arc_chords(start, end, ijk=ijk, plane=plane, clockwise=clockwise, tolerance=tol)
    a, b, h = plane_coords(plane, with_start(start, pts))
    # Direction: the cross product of successive radius vectors has the sign of the rotation
    # (positive = from the plane's first axis towards its second, RS274/NGC's counter-clockwise).
    ra, rb = a - ca, b - cb
    cross = ra[:-1] * rb[1:] - rb[:-1] * ra[1:]
    assert np.all(cross < 0) if clockwise else np.all(cross > 0)
    sweep = -1.5 * math.pi if clockwise else 0.5 * math.pi
    total = np.unwrap(np.arctan2(rb, ra))
    assert total[-1] - total[0] == pytest.approx(sweep, abs=1e-12)
    # On the circle, and the helical axis proportional to the swept angle.
    assert np.abs(np.hypot(ra, rb) - r).max() < 1e-9
    assert np.abs(h - 4.0 * (total - total[0]) / sweep).max() < 1e-9
    # Tolerance respected and minimal.
    n = len(pts)
    assert sagittas(a, b, ca, cb, r).max() <= tol * (1 + 1e-9)
    assert sagitta_closed_form(r, abs(sweep), n - 1) > tol


def test_g18_is_zx_plane_per_rs274ngc():
    # G18: first axis Z, second X. G3 (counter-clockwise) from Z+ turns towards X+.
    pts = arc_chords((0, 0, 10), (10, 0, 0), ijk=(0, 0, -10), plane=18, clockwise=False)
    assert pts[0][0] > 0 and pts[0][2] < 10
    assert len(pts) == 40  # a quarter, as in the G17 case
    pts = arc_chords((0, 0, 10), (10, 0, 0), ijk=(0, 0, -10), plane=18, clockwise=True)
    assert pts[0][0] < 0 and len(pts) == 118  # G2: the other three quarters, through X−


def test_full_circle_and_turns():
    start = (15.0, 5.0, 1.0)
    one = arc_chords(start, start, ijk=(-5, 0, 0), clockwise=True, tolerance=0.01)
    three = arc_chords(start, (15.0, 5.0, 7.0), ijk=(-5, 0, 0), clockwise=True, tolerance=0.01, turns=3)
    phi_max = 2 * math.acos(1 - 0.01 / 5)
    assert len(one) == math.ceil(2 * math.pi / phi_max)
    assert len(three) == math.ceil(6 * math.pi / phi_max)
    for pts, sweep in ((one, -2 * math.pi), (three, -6 * math.pi)):
        full = with_start(start, pts)
        ang = np.unwrap(np.arctan2(full[:, 1] - 5.0, full[:, 0] - 10.0))
        assert ang[-1] - ang[0] == pytest.approx(sweep, abs=1e-12)
        assert np.abs(np.hypot(full[:, 0] - 10, full[:, 1] - 5) - 5).max() < 1e-9
    # Helix over three turns: Z climbs 2 mm per turn, linearly with the angle.
    full = with_start(start, three)
    ang = np.unwrap(np.arctan2(full[:, 1] - 5.0, full[:, 0] - 10.0))
    assert np.abs(full[:, 2] - (1.0 + 6.0 * (ang - ang[0]) / (-6 * math.pi))).max() < 1e-9
    assert tuple(three[-1]) == (15.0, 5.0, 7.0)


def test_r_short_and_long():
    # Chord 10 along +X, |R| = 10: the short arc sweeps 60°, the long one 300°.
    apothem = math.sqrt(100 - 25)
    cases = [
        (10.0, True, (5.0, -apothem), -math.pi / 3),    # G2 short: centre right of the chord
        (-10.0, True, (5.0, apothem), -5 * math.pi / 3),  # G2 long: centre left
        (10.0, False, (5.0, apothem), math.pi / 3),     # G3 short: centre left
        (-10.0, False, (5.0, -apothem), 5 * math.pi / 3),  # G3 long: centre right
    ]
    for radius, cw, (ca, cb), sweep in cases:
        pts = with_start((0, 0, 0), arc_chords((0, 0, 0), (10, 0, 0), r=radius, clockwise=cw, tolerance=0.001))
        assert np.abs(np.hypot(pts[:, 0] - ca, pts[:, 1] - cb) - 10).max() < 1e-9, (radius, cw)
        ang = np.unwrap(np.arctan2(pts[:, 1] - cb, pts[:, 0] - ca))
        assert ang[-1] - ang[0] == pytest.approx(sweep, abs=1e-9), (radius, cw)


def test_r_impossible_and_near_half_circle():
    with pytest.raises(ArcError, match=r"R arc impossible: radius 4\.0000 mm is smaller than half the chord "
                                       r"5\.0000 mm"):
        arc_chords((0, 0, 0), (10, 0, 0), r=4.0)
    # 0.4 µm short of half the chord: within rounding, a half circle about the midpoint.
    pts = with_start((0, 0, 0), arc_chords((0, 0, 0), (10, 0, 0), r=5 - 4e-4, clockwise=True, tolerance=0.001))
    assert np.abs(np.hypot(pts[:, 0] - 5, pts[:, 1]) - 5).max() < 1e-9
    assert pts[:, 1].max() == pytest.approx(5.0, abs=0.001)  # G2 over the top (+Y)
    with pytest.raises(ArcError, match="full circle cannot be given by R"):
        arc_chords((1, 2, 0), (1, 2, 3), r=5.0)


def test_r_short_within_linuxcnc_radius_tolerance():
    """LinuxCNC's arc_data_r runs an R arc up to RADIUS_TOLERANCE (0.00127 mm = 0.00005 inch) short of half
    its chord, as a half circle about the chord's midpoint; a little more is its 'Arc radius too small'."""
    for short in (0.001, 0.00126):
        pts = with_start((0, 0, 0), arc_chords((0, 0, 0), (10, 0, 0), r=5 - short, clockwise=True,
                                               tolerance=0.001))
        assert np.abs(np.hypot(pts[:, 0] - 5, pts[:, 1]) - 5).max() < 1e-9
    with pytest.raises(ArcError, match="R arc impossible"):
        arc_chords((0, 0, 0), (10, 0, 0), r=5 - 0.0013, clockwise=True)


def test_end_not_on_circle():
    with pytest.raises(ArcError, match=r"arc end is not on the circle: radius at start 10\.000 mm, at end "
                                       r"10\.300 mm"):
        arc_chords((10, 0, 0), (0, 10.3, 0), ijk=(-10, 0, 0), clockwise=False)
    # LinuxCNC 2.8 rule: allowed max(0.0283 mm, 0.1 % of r), capped at 2.83 mm.
    arc_chords((10, 0, 0), (0, 10.028, 0), ijk=(-10, 0, 0), clockwise=False)
    with pytest.raises(ArcError):
        arc_chords((10, 0, 0), (0, 10.029, 0), ijk=(-10, 0, 0), clockwise=False)
    arc_chords((100, 0, 0), (0, 100.09, 0), ijk=(-100, 0, 0), clockwise=False)       # 0.09 < 0.1 % of 100
    with pytest.raises(ArcError):
        arc_chords((100, 0, 0), (0, 100.11, 0), ijk=(-100, 0, 0), clockwise=False)
    with pytest.raises(ArcError):
        arc_chords((5000, 0, 0), (0, 5002.9, 0), ijk=(-5000, 0, 0), clockwise=False)  # > 100 × 0.0283
    # G20 files get LinuxCNC's inch tolerance (0.002·√2 inch = 0.0718 mm).
    arc_chords((10, 0, 0), (0, 10.07, 0), ijk=(-10, 0, 0), clockwise=False, units_mm=False)
    # A fixed tolerance overrides the rule.
    with pytest.raises(ArcError):
        arc_chords((10, 0, 0), (0, 10.005, 0), ijk=(-10, 0, 0), clockwise=False, end_tolerance=0.004)
    assert END_TOLERANCE_MM == pytest.approx(0.028284271, abs=1e-9)


def test_inconsistent_end_spirals_linearly_to_the_target():
    # r_start = 10, r_end = 10.02: the radius grows linearly with the angle and the last chord ends on target.
    pts = with_start((10, 0, 0), arc_chords((10, 0, 0), (-10.02, 0, 0), ijk=(-10, 0, 0), clockwise=False))
    ang = np.unwrap(np.arctan2(pts[:, 1], pts[:, 0]))
    expected_r = 10 + 0.02 * (ang - ang[0]) / math.pi
    assert np.abs(np.hypot(pts[:, 0], pts[:, 1]) - expected_r).max() < 1e-9
    assert tuple(pts[-1]) == (-10.02, 0.0, 0.0)


def test_bad_input_is_an_arc_error():
    with pytest.raises(ArcError, match="zero radius"):
        arc_chords((0, 0, 0), (1, 0, 0), ijk=(0, 0, 0))
    with pytest.raises(ArcError, match="zero radius"):
        arc_chords((0.001, 0, 0), (0.001, 0, 0), ijk=(-0.001, 0, 0))
    with pytest.raises(ArcError, match="not finite"):
        arc_chords((0, 0, 0), (1, float("nan"), 0), ijk=(1, 0, 0))
    with pytest.raises(ArcError, match="not finite"):
        arc_chords((0, 0, 0), (1, 1, 0), r=float("inf"))
    # 2π / (4·asin(√(1e-11 / 2000))) = 2.221e7 chords.
    with pytest.raises(ArcError, match=r"arc would need 2\.221e\+07 segments"):
        arc_chords((1000, 0, 0), (1000, 0, 0), ijk=(-1000, 0, 0), tolerance=1e-11)
    with pytest.raises(ArcError, match="arc would need"):
        arc_chords((1000, 0, 0), (1000, 0, 0), ijk=(-1000, 0, 0), resolution=1e-6)
    # a count past int64: 2π·1e20 mm at 1 mm chords (numba's math.floor overflowed it into one chord: a 250 mm
    # line for a 6e20 mm arc; tools/fuzz.py --differential found it)
    with pytest.raises(ArcError, match=r"arc would need 6\.283e\+20 segments"):
        arc_chords((0, 0, 0), (9, 249.70716, 0), ijk=(1e20, 1.0, 0), resolution=1.0)
    with pytest.raises(ArcError, match=r"arc would need"):
        arc_chords((0, 0, 0), (9, 249.70716, 0), ijk=(1e20, 1.0, 0), tolerance=0.002)
    with pytest.raises(ArcError, match="turn count"):
        arc_chords((1, 0, 0), (1, 0, 0), ijk=(-1, 0, 0), turns=0)
    with pytest.raises(ArcError, match="turn count"):
        arc_chords((1, 0, 0), (1, 0, 0), ijk=(-1, 0, 0), turns=1.5)
    with pytest.raises(ArcError, match="G17, G18 or G19"):
        arc_chords((1, 0, 0), (0, 1, 0), ijk=(-1, 0, 0), plane=20)
    with pytest.raises(ArcError, match="tolerance must be > 0"):
        arc_chords((1, 0, 0), (0, 1, 0), ijk=(-1, 0, 0), tolerance=0.0)
    with pytest.raises(ArcError, match="I/J/K"):
        arc_chords((1, 0, 0), (0, 1, 0))
    with pytest.raises(ArcError, match="not both"):
        arc_chords((1, 0, 0), (0, 1, 0), ijk=(-1, 0, 0), r=1.0)


def test_tiny_radius_keeps_the_minimum_chord_count():
    # r = 0.002 mm < tolerance: any chord meets the sagitta rule; the 90° cap still gives a square.
    pts = arc_chords((0.002, 0, 0), (0.002, 0, 0), ijk=(-0.002, 0, 0), tolerance=0.01)
    assert len(pts) == round(2 * math.pi / MAX_CHORD_ANGLE) == 4


def test_kernel_on_caller_buffer():
    args = (10.0, 0.0, 0.0, 0.0, 10.0, 1.0, -10.0, 0.0, 0.0, 0.0, False, 0, False, 1, 0.002, 0.0,
            -END_TOLERANCE_MM)
    n = arc_segment_count_kernel(*args)
    assert n == 40
    buf = np.full((64, 3), np.nan)
    assert arc_chords_kernel(*args, buf) == 40
    assert np.array_equal(buf[:40], arc_chords((10, 0, 0), (0, 10, 1), ijk=(-10, 0, 0), clockwise=False))
    assert np.isnan(buf[40:]).all()  # nothing written past the count
    small = np.empty((39, 3))
    assert arc_chords_kernel(*args, small) == ERR_BUFFER
    assert "buffer too small" in arc_error_message(ERR_BUFFER, *args)
    bad = args[:3] + (0.0, 10.5, 1.0) + args[6:]
    code = arc_segment_count_kernel(*bad)
    assert code < 0
    assert arc_error_message(code, *bad).startswith("arc end is not on the circle: radius at start 10.000 mm, "
                                                     "at end 10.500 mm")


# ----------------------------------------------------------------------------- Klipper mode

def test_klipper_mode_hand_computed():
    # The arc of reference/klipper/synthetic/d_slicer_like.gcode line 61: from (105, 100), G2 X100 Y95 I-5 J0.
    # mm_of_travel = 5·π/2 = 7.854 → floor(7.854 / 1.0) = 7 chords; chord i ends at angle −i·(π/2)/7.
    pts = arc_chords((105, 100, 0.2), (100, 95, 0.2), ijk=(-5, 0, 0), clockwise=True, resolution=1.0)
    assert len(pts) == 7
    for i in range(1, 7):
        t = -i * (math.pi / 2) / 7
        assert pts[i - 1] == pytest.approx((100 + 5 * math.cos(t), 100 + 5 * math.sin(t), 0.2), abs=1e-12)
    assert tuple(pts[-1]) == (100.0, 95.0, 0.2)
    # Helical: hypot(5·π/2, 3) = 8.407 → 8 chords, Z moves 3/8 per chord.
    pts = arc_chords((105, 100, 0), (100, 95, 3), ijk=(-5, 0, 0), clockwise=True, resolution=1.0)
    assert len(pts) == 8
    assert pts[:, 2] == pytest.approx(np.arange(1, 9) * 3 / 8, abs=1e-12)
    # Full circle r = 5: 10π = 31.4 → 31 chords. Arc shorter than the resolution: 1 chord.
    assert len(arc_chords((105, 100, 0), (105, 100, 0), ijk=(-5, 0, 0), resolution=1.0)) == 31
    assert len(arc_chords((105, 100, 0), (100, 105, 0), ijk=(-5, 0, 0), clockwise=False, resolution=10.0)) == 1


def test_klipper_mode_keeps_the_start_radius_like_klipper():
    # Klipper rotates the start offset and jumps to the target on the last chord, even when r_end ≠ r_start.
    pts = arc_chords((10, 0, 0), (0, 10.02, 0), ijk=(-10, 0, 0), clockwise=False, resolution=1.0)
    assert np.abs(np.hypot(pts[:-1, 0], pts[:-1, 1]) - 10).max() < 1e-12
    assert len(pts) == math.floor(10 * math.pi / 2)


def test_klipper_move_count_of_synthetic_file():
    """Klipper planned 192 moves for d_slicer_like.gcode: its G1 moves plus our chords of its three arcs."""
    gcode = shared_path("reference", "klipper", "synthetic", "d_slicer_like.gcode")
    times = json.loads(shared_path("reference", "klipper", "synthetic", "times.json").read_text())
    pos = {"X": 0.0, "Y": 0.0, "Z": 0.0}
    moves = 0
    for raw in gcode.read_text().splitlines():
        line = raw.split(";")[0].strip()
        if not line:
            continue
        words = dict((w[0], float(w[1:])) for w in line.split()[1:] if re.fullmatch(r"[A-Z]-?[\d.]+", w))
        cmd = line.split()[0]
        if cmd == "G1" and any(k in words for k in "XYZE"):
            moves += 1
        elif cmd == "G2":
            end = tuple(words.get(k, pos[k]) for k in "XYZ")
            ijk = (words.get("I", 0.0), words.get("J", 0.0), 0.0)
            chords = arc_chords(tuple(pos[k] for k in "XYZ"), end, ijk=ijk, clockwise=True, resolution=1.0)
            moves += len(chords)
        for k in "XYZ":
            pos[k] = words.get(k, pos[k])
    assert moves == times["d_slicer_like.gcode"]["moves"] == 192


# ----------------------------------------------------------------------------- random arcs

arc_cases = st.tuples(
    st.sampled_from([17, 18, 19]),
    st.booleans(),                                    # clockwise
    st.floats(0.05, 500.0),                            # radius mm
    st.floats(-math.pi, math.pi),                      # start angle
    st.floats(-math.pi, math.pi),                      # end angle
    st.floats(-50.0, 50.0),                            # helical travel
    st.integers(1, 3),                                 # turns
    st.sampled_from([0.0005, 0.002, 0.01, 0.1]),       # tolerance
    st.floats(-200.0, 200.0), st.floats(-200.0, 200.0),  # centre
)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(arc_cases)
def test_random_ijk_arcs_on_circle_minimal_and_within_tolerance(case):
    plane, cw, r, a0, a1, helical, turns, tol, ca, cb = case
    start = point(plane, ca + r * math.cos(a0), cb + r * math.sin(a0), 1.0)
    end = point(plane, ca + r * math.cos(a1), cb + r * math.sin(a1), 1.0 + helical)
    ax_a, ax_b, _ = PLANE_AXES[plane]
    ijk = ijk_of(plane, ca - start[ax_a], cb - start[ax_b])
    pts = arc_chords(start, end, ijk=ijk, plane=plane, clockwise=cw, turns=turns, tolerance=tol)
    assert tuple(pts[-1]) == end
    a, b, h = plane_coords(plane, with_start(start, pts))
    r_start = math.hypot(start[ax_a] - ca, start[ax_b] - cb)   # the radii the arc really has (floating)
    r_end = math.hypot(end[ax_a] - ca, end[ax_b] - cb)
    ang = np.unwrap(np.arctan2(b - cb, a - ca))
    sweep = ang[-1] - ang[0]
    # Direction and extent: G2 negative, G3 positive, (turns − 1) extra full turns, less than `turns` turns —
    # plus the sliver of a start and end that count as the same point (a whole turn then, as grbl does).
    assert (sweep < 0) == cw
    same_point_rad = SAME_POINT_REL * max(1.0, r) / r
    assert (turns - 1) * 2 * math.pi - 1e-9 <= abs(sweep) <= turns * 2 * math.pi + 1e-9 + same_point_rad
    frac = (ang - ang[0]) / sweep
    assert np.abs(np.hypot(a - ca, b - cb) - (r_start + (r_end - r_start) * frac)).max() < 1e-9
    assert np.abs(h - (1.0 + helical * frac)).max() < 1e-9 * max(1.0, abs(helical))
    n = len(pts)
    assert sagittas(a, b, ca, cb, r).max() <= tol + 1e-9 * r
    n_cap = max(1, math.ceil(abs(sweep) / MAX_CHORD_ANGLE - 1e-9))
    assert n == n_cap or sagitta_closed_form(r, abs(sweep), n - 1) > tol * (1 - 1e-9)


@settings(max_examples=60, deadline=None)
@given(st.floats(0.1, 100.0), st.floats(0.0, 1.0), st.booleans(), st.booleans(), st.floats(-5, 5),
       st.floats(-5, 5))
@example(14.5, 0.9999999999999999, False, False, 0.0, 0.0)       # a half circle to the last bit (CI found it)
def test_random_r_arcs_never_raise_and_stay_on_circle(r_abs, chord_frac, long_way, cw, sx, sy):
    chord = max(2 * r_abs * chord_frac, 1e-3)
    if chord > 2 * r_abs:
        chord = 2 * r_abs
    start = (sx, sy, 0.0)
    end = (sx + chord * 0.6, sy + chord * 0.8, 0.0)
    radius = -r_abs if long_way else r_abs
    pts = with_start(start, arc_chords(start, end, r=radius, clockwise=cw, tolerance=0.002))
    # The centre is on the bisector at √(R² − (c/2)²): all points at distance |R| from one common centre.
    mid = np.array([(start[0] + end[0]) / 2, (start[1] + end[1]) / 2])
    normal = np.array([-0.8, 0.6])  # left of start→end
    apothem = math.sqrt(max(r_abs**2 - (chord / 2) ** 2, 0.0))
    left = (not cw) == (radius > 0)
    centre = mid + (apothem if left else -apothem) * normal
    dist = np.hypot(pts[:, 0] - centre[0], pts[:, 1] - centre[1])
    # That apothem is ill-conditioned near a half circle: a few ε·R² of rounding in R² − (c/2)² moves it by that
    # over 2·apothem, at most about √ε·R (hypothesis: R 14.5, chord 2R·(1 − 1e-16): the chords lie on a circle
    # of radius 14.5 within 5e-15 around the midpoint, while this apothem comes out 1.7e-7)
    eps = np.finfo(float).eps
    centre_slack = min(8 * eps * r_abs**2 / max(apothem, 1e-300), math.sqrt(8 * eps) * r_abs)
    assert np.abs(dist - dist[0]).max() < 1e-9 * max(1, r_abs) + 2 * centre_slack
    ang = np.unwrap(np.arctan2(pts[:, 1] - centre[1], pts[:, 0] - centre[0]))
    sweep = ang[-1] - ang[0]
    assert (sweep < 0) == cw
    assert (abs(sweep) <= math.pi + 1e-6) != long_way or abs(abs(sweep) - math.pi) < 1e-3
