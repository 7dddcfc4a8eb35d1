"""G2/G3 arcs turned into chords (straight G1-like segments) before planning.

Geometry follows RS274/NGC (NIST RS274NGC v3, LinuxCNC): the arc lies in the selected plane, the third
axis (the "helical" axis) moves linearly with the swept angle.

==========  ==================  =============  =============
plane       (first, second)     IJK offsets    helical axis
==========  ==================  =============  =============
0 = G17     (X, Y)              I, J           Z
1 = G18     (Z, X)              K, I           Y
2 = G19     (Y, Z)              J, K           X
==========  ==================  =============  =============

Counter-clockwise (G3) is the positive rotation from the plane's first axis towards its second, seen from
the positive helical axis (right-handed axes). Klipper's ``gcode_arcs`` takes G18 as (X, Z) instead, which
mirrors the G18 sense; we keep RS274/NGC's.

Two ways to choose the chord count:

* tolerance mode (``resolution <= 0``): the fewest chords whose sagitta (the largest gap between a chord
  and the arc, ``r·(1 − cos(φ/2))`` for a chord spanning φ) stays within ``tolerance``; every chord spans at
  most 90° whatever the tolerance (see ``MAX_CHORD_ANGLE``);
* Klipper mode (``resolution > 0``): Klipper's ``[gcode_arcs] resolution`` rule, exactly, so the chords and
  hence the planned times are Klipper's (docs/design.md §5, "Arcs").

The numba kernels work on a caller-provided buffer and return a count or a negative error code; the Python
wrapper :func:`arc_chords` raises :class:`ArcError` with the text of :func:`arc_error_message`.
"""
from __future__ import annotations

import math

from .._jit import njit
import numpy as np

__all__ = [
    "ArcError",
    "arc_chords",
    "arc_chords_kernel",
    "arc_segment_count_kernel",
    "arc_error_message",
    "linuxcnc_end_tolerance",
    "END_TOLERANCE_MM",
    "END_TOLERANCE_INCH_MODE_MM",
    "END_RELATIVE_TOLERANCE",
    "MAX_ARC_SEGMENTS",
]


class ArcError(ValueError):
    """An arc that cannot be drawn. The message carries no file:line: the parser adds it."""


# Error codes returned (negated) by the kernels.
ERR_NONFINITE = -1
ERR_PLANE = -2
ERR_TURNS = -3
ERR_R_FULL_CIRCLE = -4
ERR_R_IMPOSSIBLE = -5
ERR_ZERO_RADIUS = -6
ERR_END_OFF_CIRCLE = -7
ERR_TOO_MANY_SEGMENTS = -8
ERR_TOLERANCE = -9
ERR_BUFFER = -10

# Above this an arc is a typo (a radius in microns, a tolerance of 1e-9), not a part: refuse, don't allocate.
# A 10 m radius full circle at 0.002 mm is 2,500 chords; each chord is a ~200-byte MOVE row, so a million is
# 200 MB and about a second (10 million took 2 GB and 12 s before the arc was refused as out of range;
# tools/fuzz.py --seed 20261206 --replay 348621).
MAX_ARC_SEGMENTS = 1_000_000

# End-radius check. LinuxCNC's interpreter (interp_internal.hh) has CENTER_ARC_RADIUS_TOLERANCE
# = 2·0.01·√2 mm in G21 and 2·0.001·√2 inch in G20, and SPIRAL_RELATIVE_TOLERANCE = 0.001. Its 2.7/2.8
# rule (arc_data_ijk) rejects an arc when |r_end − r_start| exceeds 100× the absolute tolerance, or exceeds
# both the absolute and the relative tolerance; i.e. the allowed difference is
# min(100·abs, max(abs, 0.001·max(r_start, r_end))). LinuxCNC 2.9 made it stricter (either one exceeded is
# an error, i.e. min(abs, 0.001·r)). We keep the lenient 2.8 rule: printer firmware (Marlin, Klipper) does
# not check at all, and CAM output rounded to 3 decimals must not be refused on small arcs.
END_TOLERANCE_MM = 2.0 * 0.01 * math.sqrt(2.0)                   # 0.02828 mm
END_TOLERANCE_INCH_MODE_MM = 2.0 * 0.001 * math.sqrt(2.0) * 25.4  # 0.002828 inch = 0.07184 mm
END_RELATIVE_TOLERANCE = 0.001
END_TOLERANCE_CAP_FACTOR = 100.0

# A radius below this is "the centre is on the start (or end) point"; LinuxCNC's RADIUS_TOLERANCE
# (0.00005 inch = 0.00127 mm) plays the same role.
MIN_RADIUS_MM = 0.00127

# R form: |R| may fall short of half the chord by this much (rounding in the file) and still give a half
# circle about the chord's midpoint; beyond it the arc is impossible. LinuxCNC's arc_data_r allows
# RADIUS_TOLERANCE: 0.00005 inch under G20, 0.00005 × 25.4 = 0.00127 mm under G21 (the same length); a
# relative 1e-6 on top for radii of metres.
R_SHORT_REL = 1e-6
R_SHORT_ABS_MM = 0.00005 * 25.4

# Whatever the tolerance, a chord never spans more than 90°: a full circle is at least a square, never a
# zero-length chord, even when the radius is smaller than the tolerance.
MAX_CHORD_ANGLE = 0.5 * math.pi

# Start and end closer than this (relative to max(1 mm, r)) in the plane mean "the same point": an IJK arc
# then goes all the way round instead of a near-zero sliver decided by rounding noise.
SAME_POINT_REL = 1e-9

TWO_PI = 2.0 * math.pi


@njit(cache=True)
def _plane_axes(plane: int) -> tuple[int, int, int]:
    """Axis indices (first, second, helical) of an arc plane code 0/1/2 (G17/G18/G19)."""
    if plane == 0:
        return 0, 1, 2
    if plane == 1:
        return 2, 0, 1
    return 1, 2, 0


@njit(cache=True)
def _pick(x: float, y: float, z: float, axis: int) -> float:
    if axis == 0:
        return x
    if axis == 1:
        return y
    return z


@njit(cache=True)
def linuxcnc_end_tolerance(r_start: float, r_end: float, abs_tolerance: float) -> float:
    """Allowed |r_end − r_start| (mm), LinuxCNC 2.8: min(100·abs, max(abs, 0.001·max(r_start, r_end)))."""
    rel = END_RELATIVE_TOLERANCE * max(r_start, r_end)
    return min(END_TOLERANCE_CAP_FACTOR * abs_tolerance, max(abs_tolerance, rel))


@njit(cache=True)
def _arc_geometry(x0, y0, z0, x1, y1, z1, off_i, off_j, off_k, radius, use_r, plane, clockwise, turns,
                  tolerance, resolution, end_tolerance):
    """Centre, radii and swept angle of an arc.

    Returns (code, centre_a, centre_b, r_start, r_end, angle_start, sweep, aux): code 0 when valid, else an
    ERR_* code; sweep in rad, > 0 counter-clockwise; aux is half the chord for the R form (for messages) and
    the allowed end-radius difference for the IJK form.
    """
    nan = math.nan
    if not (math.isfinite(x0) and math.isfinite(y0) and math.isfinite(z0) and math.isfinite(x1)
            and math.isfinite(y1) and math.isfinite(z1) and math.isfinite(tolerance)
            and math.isfinite(resolution) and math.isfinite(end_tolerance)):
        return ERR_NONFINITE, nan, nan, nan, nan, nan, nan, nan
    if use_r:
        if not math.isfinite(radius):
            return ERR_NONFINITE, nan, nan, nan, nan, nan, nan, nan
    elif not (math.isfinite(off_i) and math.isfinite(off_j) and math.isfinite(off_k)):
        return ERR_NONFINITE, nan, nan, nan, nan, nan, nan, nan
    if plane < 0 or plane > 2:
        return ERR_PLANE, nan, nan, nan, nan, nan, nan, nan
    if turns < 1:
        return ERR_TURNS, nan, nan, nan, nan, nan, nan, nan
    if not (tolerance > 0.0 or resolution > 0.0):
        return ERR_TOLERANCE, nan, nan, nan, nan, nan, nan, nan

    ax_a, ax_b, _ = _plane_axes(plane)
    start_a = _pick(x0, y0, z0, ax_a)
    start_b = _pick(x0, y0, z0, ax_b)
    end_a = _pick(x1, y1, z1, ax_a)
    end_b = _pick(x1, y1, z1, ax_b)
    chord_a = end_a - start_a
    chord_b = end_b - start_b
    chord = math.hypot(chord_a, chord_b)
    aux = 0.0

    if use_r:
        if chord == 0.0:
            return ERR_R_FULL_CIRCLE, nan, nan, nan, nan, nan, nan, nan
        r_abs = abs(radius)
        half = 0.5 * chord
        aux = half
        if half - r_abs > R_SHORT_REL * r_abs + R_SHORT_ABS_MM:
            return ERR_R_IMPOSSIBLE, nan, nan, r_abs, r_abs, nan, nan, half
        # Centre on the perpendicular bisector at distance √(R² − (c/2)²) from the chord's midpoint:
        # on the left of start→end for a short CCW arc (the centre of a CCW turn is on the left),
        # on the right for a short CW arc; R < 0 (the long way) swaps the side (RS274/NGC, NCMS p. 21).
        apothem = math.sqrt(max(r_abs * r_abs - half * half, 0.0))
        left = (not clockwise) == (radius > 0.0)
        side = 1.0 if left else -1.0
        centre_a = 0.5 * (start_a + end_a) - side * apothem * chord_b / chord
        centre_b = 0.5 * (start_b + end_b) + side * apothem * chord_a / chord
    else:
        off_a = _pick(off_i, off_j, off_k, ax_a)
        off_b = _pick(off_i, off_j, off_k, ax_b)
        centre_a = start_a + off_a
        centre_b = start_b + off_b

    rel_sa = start_a - centre_a
    rel_sb = start_b - centre_b
    rel_ea = end_a - centre_a
    rel_eb = end_b - centre_b
    r_start = math.hypot(rel_sa, rel_sb)
    r_end = math.hypot(rel_ea, rel_eb)
    if r_start < MIN_RADIUS_MM or r_end < MIN_RADIUS_MM:
        return ERR_ZERO_RADIUS, centre_a, centre_b, r_start, r_end, nan, nan, aux
    if not use_r:
        if end_tolerance >= 0.0:
            allowed = end_tolerance
        else:
            allowed = linuxcnc_end_tolerance(r_start, r_end, -end_tolerance)
        aux = allowed
        if abs(r_end - r_start) > allowed:
            return ERR_END_OFF_CIRCLE, centre_a, centre_b, r_start, r_end, nan, nan, allowed

    # Signed angle from the start radius vector to the end radius vector, in (−π, π].
    cross = rel_sa * rel_eb - rel_sb * rel_ea
    dot = rel_sa * rel_ea + rel_sb * rel_eb
    sweep = math.atan2(cross, dot)
    if (not use_r) and chord <= SAME_POINT_REL * max(1.0, r_start):
        sweep = -TWO_PI if clockwise else TWO_PI
    elif clockwise:
        if sweep >= 0.0:
            sweep -= TWO_PI
    elif sweep <= 0.0:
        sweep += TWO_PI
    extra = (turns - 1) * TWO_PI
    sweep += -extra if clockwise else extra
    angle_start = math.atan2(rel_sb, rel_sa)
    return 0, centre_a, centre_b, r_start, r_end, angle_start, sweep, aux


@njit(cache=True)
def _sagitta(radius: float, sweep_abs: float, n: float) -> float:
    """Sagitta (mm) of one of n equal chords of an arc: r·(1 − cos(φ/2)) = 2r·sin²(φ/4), φ = sweep/n."""
    s = math.sin(sweep_abs / (4.0 * n))
    return 2.0 * radius * s * s


@njit(cache=True)
def _segment_count_float(r_start, r_end, sweep, helical_travel, tolerance, resolution) -> float:
    """Chord count as a float (may exceed MAX_ARC_SEGMENTS; the caller checks before converting).

    Klipper mode: max(1, floor(hypot(r_start·sweep, helical)/resolution)) (gcode_arcs.py, Marlin plan_arc).
    Tolerance mode: the smallest n with 2·r·sin²(|sweep|/(4n)) ≤ tolerance, r = max(r_start, r_end), and at
    least ceil(|sweep|/MAX_CHORD_ANGLE).
    """
    # np.floor / np.ceil, not math's: numba's math.floor returns an int64, which a 1e20 mm arc overflows into a
    # negative count (planned as one chord; found by tools/fuzz.py --differential, where Python's exact int
    # gave the right "too many segments" error)
    sweep_abs = abs(sweep)
    if resolution > 0.0:
        travel = math.hypot(r_start * sweep, helical_travel)
        return max(1.0, np.floor(travel / resolution))
    radius = max(r_start, r_end)
    n_angle = max(1.0, np.ceil(sweep_abs / MAX_CHORD_ANGLE - 1e-12))
    ratio = tolerance / (2.0 * radius)
    if ratio >= 1.0:
        return n_angle
    # sin(|sweep|/(4n)) ≤ √(tol/2r)  ⇔  n ≥ |sweep| / (4·asin(√(tol/2r))),
    # valid while |sweep|/(4n) ≤ π/2, which n ≥ n_angle guarantees.
    n = max(n_angle, np.ceil(sweep_abs / (4.0 * math.asin(math.sqrt(ratio)))))
    if n > MAX_ARC_SEGMENTS:
        return n
    # The closed form can be off by one through rounding: settle on the exact minimal count.
    while n > n_angle and _sagitta(radius, sweep_abs, n - 1.0) <= tolerance:
        n -= 1.0
    while _sagitta(radius, sweep_abs, n) > tolerance:
        n += 1.0
    return n


@njit(cache=True)
def arc_segment_count_kernel(x0, y0, z0, x1, y1, z1, off_i, off_j, off_k, radius, use_r, plane, clockwise,
                             turns, tolerance, resolution, end_tolerance) -> int:
    """Number of chords (≥ 1) the arc will be cut into, or a negative ERR_* code.

    Same arguments as :func:`arc_chords_kernel` without ``out``; call it first to size the buffer.
    """
    code, _ca, _cb, r_start, r_end, _a0, sweep, _aux = _arc_geometry(
        x0, y0, z0, x1, y1, z1, off_i, off_j, off_k, radius, use_r, plane, clockwise, turns,
        tolerance, resolution, end_tolerance)
    if code < 0:
        return code
    _, _, ax_h = _plane_axes(plane)
    helical = _pick(x1, y1, z1, ax_h) - _pick(x0, y0, z0, ax_h)
    n = _segment_count_float(r_start, r_end, sweep, helical, tolerance, resolution)
    if not (n <= MAX_ARC_SEGMENTS):
        return ERR_TOO_MANY_SEGMENTS
    return int(n)


@njit(cache=True)
def arc_chords_kernel(x0, y0, z0, x1, y1, z1, off_i, off_j, off_k, radius, use_r, plane, clockwise, turns,
                      tolerance, resolution, end_tolerance, out) -> int:
    """Write the chord end points of a G2/G3 arc into ``out`` and return their count n ≥ 1.

    Arguments (mm, absolute machine axes): start (x0, y0, z0), target (x1, y1, z1); centre offsets from the
    start (incremental I, J, K; only the plane's two are used; ignored when ``use_r``); ``radius`` the R word
    (negative = the long way round); ``plane`` 0/1/2 = G17/G18/G19; ``clockwise`` (G2); ``turns`` ≥ 1
    (LinuxCNC's P word); ``tolerance`` the largest chord sagitta in tolerance mode; ``resolution`` > 0 selects
    Klipper's rule instead; ``end_tolerance`` the allowed |r_end − r_start| (≥ 0: that many mm; < 0: LinuxCNC's
    rule with absolute part −end_tolerance, see :func:`linuxcnc_end_tolerance`). ``out`` is float64[m, 3],
    m ≥ the count from :func:`arc_segment_count_kernel`.

    Row i (0-based) is the end of chord i+1; the last row is exactly (x1, y1, z1). Tolerance mode: the radius
    goes linearly from r_start to r_end with the angle (LinuxCNC's way with slightly inconsistent ends) and the
    helical axis moves linearly with the angle. Klipper mode: chord i ends at centre + rotation(i·sweep/n)
    of the start offset, helical start + i·(travel/n), as Klipper does.

    Returns n, or a negative ERR_* code (nothing useful written); :func:`arc_error_message` explains it.
    """
    code, centre_a, centre_b, r_start, r_end, angle_start, sweep, _aux = _arc_geometry(
        x0, y0, z0, x1, y1, z1, off_i, off_j, off_k, radius, use_r, plane, clockwise, turns,
        tolerance, resolution, end_tolerance)
    if code < 0:
        return code
    ax_a, ax_b, ax_h = _plane_axes(plane)
    helical_start = _pick(x0, y0, z0, ax_h)
    helical = _pick(x1, y1, z1, ax_h) - helical_start
    n_float = _segment_count_float(r_start, r_end, sweep, helical, tolerance, resolution)
    if not (n_float <= MAX_ARC_SEGMENTS):
        return ERR_TOO_MANY_SEGMENTS
    n = int(n_float)
    if out.shape[0] < n or out.shape[1] < 3:
        return ERR_BUFFER
    if resolution > 0.0:
        # Klipper (gcode_arcs.py planArc): rotate the start offset (−I, −J) by i·θ/n about the centre.
        rel_a = _pick(x0, y0, z0, ax_a) - centre_a
        rel_b = _pick(x0, y0, z0, ax_b) - centre_b
        theta_per_segment = sweep / n_float
        helical_per_segment = helical / n_float
        for i in range(1, n):
            cos_t = math.cos(i * theta_per_segment)
            sin_t = math.sin(i * theta_per_segment)
            out[i - 1, ax_a] = centre_a + (rel_a * cos_t - rel_b * sin_t)
            out[i - 1, ax_b] = centre_b + (rel_a * sin_t + rel_b * cos_t)
            out[i - 1, ax_h] = helical_start + i * helical_per_segment
    else:
        r_change = r_end - r_start
        for i in range(1, n):
            fraction = i / n_float
            angle = angle_start + sweep * fraction
            r_i = r_start + r_change * fraction
            out[i - 1, ax_a] = centre_a + r_i * math.cos(angle)
            out[i - 1, ax_b] = centre_b + r_i * math.sin(angle)
            out[i - 1, ax_h] = helical_start + helical * fraction
    out[n - 1, 0] = x1
    out[n - 1, 1] = y1
    out[n - 1, 2] = z1
    return n


def _plane_code(plane: int) -> int:
    if plane in (17, 18, 19):
        return plane - 17
    if plane in (0, 1, 2):
        return plane
    raise ArcError(f"arc plane must be G17, G18 or G19, got {plane!r}")


def arc_error_message(code: int, x0, y0, z0, x1, y1, z1, off_i, off_j, off_k, radius, use_r, plane, clockwise,
                      turns, tolerance, resolution, end_tolerance) -> str:
    """The ArcError text for a negative kernel code; the arguments are the kernel's (without ``out``)."""
    geo = _arc_geometry(float(x0), float(y0), float(z0), float(x1), float(y1), float(z1), float(off_i),
                        float(off_j), float(off_k), float(radius), bool(use_r), int(plane), bool(clockwise),
                        int(turns), float(tolerance), float(resolution), float(end_tolerance))
    _code, _ca, _cb, r_start, r_end, _a0, sweep, aux = geo
    if code == ERR_NONFINITE:
        return "arc has a number that is not finite (nan or inf) in its end point, centre, radius or tolerance"
    if code == ERR_PLANE:
        return f"arc plane must be G17, G18 or G19 (plane code {plane})"
    if code == ERR_TURNS:
        return f"arc turn count P must be a whole number >= 1, got {turns}"
    if code == ERR_TOLERANCE:
        return f"arc tolerance must be > 0 mm (got {tolerance:g}) unless a resolution > 0 is given"
    if code == ERR_R_FULL_CIRCLE:
        return "R arc ends where it starts: a full circle cannot be given by R (use I/J/K)"
    if code == ERR_R_IMPOSSIBLE:
        return (f"R arc impossible: radius {abs(radius):.4f} mm is smaller than half the chord "
                f"{aux:.4f} mm")
    if code == ERR_ZERO_RADIUS:
        return (f"arc has a zero radius: radius at start {r_start:.4f} mm, at end {r_end:.4f} mm "
                f"(below {MIN_RADIUS_MM} mm: the centre is on the start or end point)")
    if code == ERR_END_OFF_CIRCLE:
        return (f"arc end is not on the circle: radius at start {r_start:.3f} mm, at end {r_end:.3f} mm "
                f"(difference {abs(r_end - r_start):.4f} mm, allowed {aux:.4f} mm)")
    if code == ERR_TOO_MANY_SEGMENTS:
        ax_h = _plane_axes(int(plane))[2]
        helical = (x1, y1, z1)[ax_h] - (x0, y0, z0)[ax_h]
        n = _segment_count_float(r_start, r_end, sweep, helical, float(tolerance), float(resolution))
        how = f"resolution {resolution:g} mm" if resolution > 0 else f"tolerance {tolerance:g} mm"
        return (f"arc would need {n:.4g} segments (limit {MAX_ARC_SEGMENTS}): radius {r_start:.4g} mm, "
                f"{abs(sweep) / TWO_PI:.4g} turns at {how}")
    if code == ERR_BUFFER:
        return "arc chord buffer too small (size it with arc_segment_count_kernel)"
    return f"arc error {code}"


def arc_chords(start, end, *, ijk=None, r=None, plane: int = 17, clockwise: bool = True, turns: int = 1,
               tolerance: float = 0.002, resolution: float = 0.0, units_mm: bool = True,
               end_tolerance: float | None = None) -> np.ndarray:
    """Chord end points (n, 3) of the arc from ``start`` to ``end`` (mm, machine axes); last row == end.

    Give the centre as ``ijk`` (offsets from the start, any of the three may be 0) or the radius as ``r``
    (negative: more than half a circle). ``plane`` 17/18/19. ``units_mm`` picks the default end-radius
    tolerance: the file's units decide LinuxCNC's absolute part (0.0283 mm in G21, 0.0028 inch in G20);
    ``end_tolerance`` (mm) overrides it with a fixed value. Raises :class:`ArcError`.
    """
    if (ijk is None) == (r is None):
        raise ArcError("arc needs either I/J/K (centre) or R (radius), not both" if ijk is not None
                       else "arc needs I/J/K (centre) or R (radius)")
    plane_code = _plane_code(plane)
    if isinstance(turns, float) and turns.is_integer():
        turns = int(turns)
    if not isinstance(turns, (int, np.integer)) or isinstance(turns, bool) or turns < 1:
        raise ArcError(f"arc turn count P must be a whole number >= 1, got {turns!r}")
    x0, y0, z0 = (float(v) for v in start)
    x1, y1, z1 = (float(v) for v in end)
    if ijk is not None:
        off_i, off_j, off_k = (float(v) for v in ijk)
        radius, use_r = 0.0, False
    else:
        off_i = off_j = off_k = 0.0
        radius, use_r = float(r), True
    if end_tolerance is None:
        end_tol = -(END_TOLERANCE_MM if units_mm else END_TOLERANCE_INCH_MODE_MM)
    else:
        end_tol = float(end_tolerance)
        if not end_tol >= 0.0:
            raise ArcError(f"arc end tolerance must be >= 0 mm, got {end_tolerance!r}")
    args = (x0, y0, z0, x1, y1, z1, off_i, off_j, off_k, radius, use_r, plane_code, bool(clockwise),
            int(turns), float(tolerance), float(resolution), end_tol)
    n = arc_segment_count_kernel(*args)
    if n < 0:
        raise ArcError(arc_error_message(n, *args))
    out = np.empty((n, 3), dtype=np.float64)
    got = arc_chords_kernel(*args, out)
    if got != n:  # cannot happen: both kernels share the geometry
        raise ArcError(arc_error_message(got, *args) if got < 0 else f"arc chord count changed ({n} -> {got})")
    return out
