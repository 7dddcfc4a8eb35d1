"""G2/G3 arcs cut into segments as Marlin 2.1.2 cuts them (``ARC_SUPPORT``: gcode/motion/G2_G3.cpp).

Marlin does not bound a chord's sagitta: it cuts the arc's flat length into segments of about
``MAX_ARC_SEGMENT_MM`` (1 mm by default), at least ``MIN_CIRCLE_SEGMENTS`` (72) per full circle, then corrects
the count so that a segment is neither longer than ``MAX_ARC_SEGMENT_MM`` nor shorter than ``MIN_ARC_SEGMENT_MM``
(0.1 mm); with ``ARC_SEGMENTS_PER_SEC`` the nominal length is the feed rate's distance in 1/N s, clamped to
those two lengths. The segment end points come from rotating the radius vector by a small-angle approximation
of the segment angle (sin θ ≈ θ − θ³/6, cos θ ≈ 1 − θ²/2), put back on the circle with ``sin``/``cos`` every
``N_ARC_CORRECTION`` (25) segments; the helical axis and E advance by equal float steps. The last segment
ends exactly at the target. Everything is single precision (Marlin's ``float``) with Marlin's double
constants where its source has them, so the points are the firmware's (docs/design.md, *Marlin 2.1.2*).

With ``ARC_P_CIRCLES`` a ``P`` word adds P full circles first, each planned as an arc of its own from the
start point back to it (``plan_arc`` calling itself), the helical axis and E shared out by angle.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from .._jit import njit
import numpy as np

#: plane → (axis p, axis q, helical axis l), Marlin's CNC_WORKSPACE_PLANES: XY→Z, ZX→Y, YZ→X
PLANE_AXES = {17: (0, 1, 2), 18: (2, 0, 1), 19: (1, 2, 0)}
#: Marlin stores the segment count in a uint16
MAX_SEGMENTS = 65535


@dataclass(frozen=True)
class MarlinArcSettings:
    """A build's ``ARC_SUPPORT`` settings (Configuration_adv.h; the defaults are Marlin 2.1.2's)."""
    min_segment_mm: float = 0.1        # mm, MIN_ARC_SEGMENT_MM
    max_segment_mm: float = 1.0        # mm, MAX_ARC_SEGMENT_MM
    min_circle_segments: int = 72      # segments per full circle at least, MIN_CIRCLE_SEGMENTS
    segments_per_sec: float = 0.0      # 1/s, ARC_SEGMENTS_PER_SEC; 0 = off (the segment length is the maximum)
    n_arc_correction: int = 25         # segments between exact sin/cos corrections, N_ARC_CORRECTION
    enabled: bool = True               # ARC_SUPPORT (off: the build ignores G2/G3)
    p_circles: bool = False            # ARC_P_CIRCLES (off, Marlin's default: a P word is ignored)


def arc_settings(machine) -> MarlinArcSettings:
    """The arc settings of a Marlin-model machine: its ``marlin_arcs`` (from a Configuration_adv.h) or Marlin's
    defaults, with ``[arcs] resolution`` (mm, when > 0) as ``MAX_ARC_SEGMENT_MM``."""
    s = getattr(machine, "marlin_arcs", None)
    if s is not None:
        return s
    res = float(getattr(machine, "arc_resolution", 0.0) or 0.0)
    if res > 0.0:
        # Marlin: MIN_ARC_SEGMENT_MM defaults to MAX_ARC_SEGMENT_MM when only the maximum is given; the
        # default minimum 0.1 stays when it is below the maximum
        return MarlinArcSettings(min_segment_mm=min(0.1, res), max_segment_mm=res)
    return MarlinArcSettings()


def _f(x):
    return np.float32(x)


def _floats_overflow_quietly(fn):
    """Run ``fn`` with numpy's overflow warnings off: an absurd arc overflows Marlin's floats to inf, which the
    kernel refuses by name (a numpy warning would only repeat it)."""
    import functools

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            return fn(*args, **kwargs)
    return wrapper


@njit(cache=True)
def _radians_360():
    """RADIANS(360) as Marlin's macro evaluates it: 360 · float(π) / 180.0f in float."""
    return np.float32(np.float32(np.float32(360.0) * np.float32(math.pi)) / np.float32(180.0))


@njit(cache=True)
def marlin_segment_count(flat_mm, abs_travel, full_circle, fr_mm_s, min_mm, max_mm, min_circle, per_sec):
    """Segments of one arc by plan_arc's rule: ``flat_mm`` (float32, radius × |angle|), ``abs_travel``
    (float32 rad), ``fr_mm_s`` the scaled feed (float32 mm/s); the lengths are the build's double constants.
    Returns the count (may exceed Marlin's uint16: the caller refuses that)."""
    if full_circle:
        min_segments = min_circle
    else:
        portion = np.float32(abs_travel / _radians_360())
        min_segments = int(math.ceil(np.float64(np.float32(np.float32(min_circle) * portion))))
        if min_segments < 1:
            min_segments = 1
    if per_sec > 0.0:
        # constrain(fr · RECIPROCAL(N), MIN, MAX): a double comparison, the result stored in a float
        ideal = np.float64(np.float32(fr_mm_s * np.float32(np.float32(1.0) / np.float32(per_sec))))
        if ideal < min_mm:
            ideal = min_mm
        elif ideal > max_mm:
            ideal = max_mm
        ideal32 = np.float32(ideal)
    else:
        ideal32 = np.float32(max_mm)
    nominal = np.float32(math.floor(np.float64(np.float32(flat_mm / ideal32))))
    if nominal < np.float32(min_segments):
        nominal = np.float32(min_segments)
    nominal_mm = np.float32(flat_mm / nominal)
    if np.float64(nominal_mm) > max_mm:
        return int(math.ceil(np.float64(np.float32(np.float64(flat_mm) / max_mm))))
    if np.float64(nominal_mm) < min_mm:
        n = int(math.floor(np.float64(np.float32(np.float64(flat_mm) / min_mm))))
        return n if n > 1 else 1
    return int(nominal)


@njit(cache=True)
def marlin_arc_kernel(position, target, offset, p, q, l, clockwise, fr_mm_s, min_mm, max_mm, min_circle,
                      per_sec, n_correction, out):
    """Segment end points of one ``plan_arc`` call into ``out`` (rows of x, y, z, e in float32; the last is
    the target). ``position``/``target`` float32[4] (x, y, z, logical E, mm), ``offset`` float32[2]: the centre
    from the start along the plane's axes p, q. Returns the count, 0 when Marlin plans nothing (no angle, or
    an arc under 0.0001 mm), −1 − n when the n segments exceed Marlin's uint16 or ``out`` (nothing written)."""
    rv_a = np.float32(-offset[0])
    rv_b = np.float32(-offset[1])
    radius = np.float32(math.sqrt(np.float64(np.float32(np.float32(rv_a * rv_a) + np.float32(rv_b * rv_b)))))
    center_p = np.float32(position[p] - rv_a)
    center_q = np.float32(position[q] - rv_b)
    rt_x = np.float32(target[p] - center_p)
    rt_y = np.float32(target[q] - center_q)
    full = False
    dp = np.float32(position[p] - target[p])
    dq = np.float32(position[q] - target[q])
    # NEAR(): |a − b| within 1e-6 (float)
    if abs(np.float64(dp)) <= np.float64(np.float32(0.000001)) and abs(np.float64(dq)) <= np.float64(np.float32(0.000001)):
        full = True
        travel = -_radians_360() if clockwise else _radians_360()
        abs_travel = _radians_360()
    else:
        travel = np.float32(math.atan2(np.float64(np.float32(np.float32(rv_a * rt_y) - np.float32(rv_b * rt_x))),
                                       np.float64(np.float32(np.float32(rv_a * rt_x) + np.float32(rv_b * rt_y)))))
        if travel == 0.0:
            return 0
        if travel >= 0.0 and clockwise:
            travel = np.float32(travel - _radians_360())
        elif travel < 0.0 and not clockwise:
            travel = np.float32(travel + _radians_360())
        abs_travel = np.float32(abs(travel))
    travel_l = np.float32(target[l] - position[l])
    travel_e = np.float32(target[3] - position[3])
    flat_mm = np.float32(radius * abs_travel)
    # Marlin compares the signed helical travel (a downward helix of a tiny arc is "near zero" too)
    if flat_mm < np.float32(0.0001) and travel_l < np.float32(0.0001):
        return 0
    if not (math.isfinite(np.float64(flat_mm)) and math.isfinite(np.float64(center_p))
            and math.isfinite(np.float64(center_q))):
        return -1 - 2 ** 31                 # single precision overflowed: an absurd arc
    segments = marlin_segment_count(flat_mm, abs_travel, full, fr_mm_s, min_mm, max_mm, min_circle, per_sec)
    if segments > 65535 or segments + 1 > out.shape[0]:
        return -1 - segments
    raw = position.copy()
    n = 0
    if segments > 1:
        seg = np.float32(segments)
        theta = np.float32(travel / seg)
        sq_theta = np.float32(theta * theta)
        sin_t = np.float32(theta - np.float32(np.float32(sq_theta * theta) / np.float32(6.0)))
        cos_t = np.float32(np.float32(1.0) - np.float32(np.float32(0.5) * sq_theta))
        per_l = np.float32(travel_l / seg)
        per_e = np.float32(travel_e / seg)
        count = n_correction
        for i in range(1, segments):
            count -= 1
            if n_correction > 1 and count != 0:
                r_new = np.float32(np.float32(rv_a * sin_t) + np.float32(rv_b * cos_t))
                rv_a = np.float32(np.float32(rv_a * cos_t) - np.float32(rv_b * sin_t))
                rv_b = r_new
            else:
                count = n_correction
                a = np.float64(np.float32(np.float32(i) * theta))
                cos_ti = np.float32(math.cos(a))
                sin_ti = np.float32(math.sin(a))
                rv_a = np.float32(np.float32(-offset[0] * cos_ti) + np.float32(offset[1] * sin_ti))
                rv_b = np.float32(np.float32(-offset[0] * sin_ti) - np.float32(offset[1] * cos_ti))
            raw[p] = np.float32(center_p + rv_a)
            raw[q] = np.float32(center_q + rv_b)
            raw[l] = np.float32(raw[l] + per_l)
            raw[3] = np.float32(raw[3] + per_e)
            for k in range(4):
                out[n, k] = raw[k]
            n += 1
    for k in range(4):
        out[n, k] = target[k]
    return n + 1


@_floats_overflow_quietly
def marlin_r_offset(start, end, r: float, clockwise: bool, p: int = 0, q: int = 1):
    """The centre offset (float32 a, b) G2/G3 R gives in Marlin: the perpendicular bisector of the chord at
    distance √(r² − (chord/2)²) from its midpoint, or the midpoint itself when |r| is shorter than half the
    chord (Marlin draws that half circle instead of refusing). None when R is 0 or the end is the start
    (Marlin: "Invalid arc args", the line does nothing)."""
    r32 = _f(r)
    s_p, s_q = _f(start[p]), _f(start[q])
    e_p, e_q = _f(end[p]), _f(end[q])
    if r32 == 0 or (s_p == e_p and s_q == e_q):
        return None
    d_a = _f(_f(e_p - s_p) * _f(0.5))
    d_b = _f(_f(e_q - s_q) * _f(0.5))
    sign = _f(-1.0) if (bool(clockwise) != bool(r32 < 0)) else _f(1.0)
    length = _f(math.sqrt(float(_f(_f(d_a * d_a) + _f(d_b * d_b)))))
    h2 = _f(_f(r32 - length) * _f(r32 + length))
    h = _f(math.sqrt(float(h2))) if h2 >= 0 else _f(0.0)
    s_a, s_b = _f(-d_b), d_a
    return (_f(d_a + _f(_f(_f(s_a / length) * sign) * h)), _f(d_b + _f(_f(_f(s_b / length) * sign) * h)))


@_floats_overflow_quietly
def marlin_arc_points(start, end, offset, clockwise: bool, plane: int = 17, feed_mm_s: float = 0.0,
                      settings: MarlinArcSettings | None = None, circles: int = 0) -> np.ndarray:
    """The segment end points (n, 4: x, y, z, logical E in mm, float32 values) Marlin plans for one G2/G3,
    the last the target; (0, 4) when Marlin plans nothing. ``start``/``end`` are (x, y, z, e) in mm,
    ``offset`` the centre from the start along the plane's two axes (mm, as Marlin computes it from I/J/K or
    R), ``feed_mm_s`` the scaled feed rate (ARC_SEGMENTS_PER_SEC only), ``circles`` the full circles first
    (ARC_P_CIRCLES). Raises ValueError for an arc Marlin cannot count (over 65535 segments, overflow)."""
    s = settings or MarlinArcSettings()
    p, q, l = PLANE_AXES[plane]
    pos = np.array([_f(v) for v in start], dtype=np.float32)
    tgt = np.array([_f(v) for v in end], dtype=np.float32)
    off = np.array([_f(offset[0]), _f(offset[1])], dtype=np.float32)
    args = (p, q, l, bool(clockwise), _f(feed_mm_s), float(s.min_segment_mm), float(s.max_segment_mm),
            int(s.min_circle_segments), float(s.segments_per_sec), int(max(1, s.n_arc_correction)))
    # room for an estimate of the count; exactly what the kernel asks for when that was short
    r_est = math.hypot(float(off[0]), float(off[1]))
    est = int(min(MAX_SEGMENTS, 2 * math.pi * r_est / max(float(s.min_segment_mm), 1e-9)
                  + s.min_circle_segments + 2)) if math.isfinite(r_est) else MAX_SEGMENTS

    def one_arc(start, target):
        out = np.empty((est + 2, 4), np.float32)
        n = marlin_arc_kernel(start, target, off, *args, out)
        if n < 0 and -1 - n <= MAX_SEGMENTS:
            out = np.empty((-1 - n + 1, 4), np.float32)
            n = marlin_arc_kernel(start, target, off, *args, out)
        if n < 0:
            raise ValueError(_too_many(-1 - n))
        return out[:n]

    pieces = []
    if circles:
        # ARC_P_CIRCLES: each circle ends where it starts in the plane, the helical axis and E shared by angle
        whole = _radians_360()
        # the arc's own angle, as plan_arc computes it before the circles (a full circle when the end is the start)
        rv_a, rv_b = _f(-off[0]), _f(-off[1])
        c_p, c_q = _f(pos[p] - rv_a), _f(pos[q] - rv_b)
        rt_x, rt_y = _f(tgt[p] - c_p), _f(tgt[q] - c_q)
        if abs(float(_f(pos[p] - tgt[p]))) <= float(_f(1e-6)) and abs(float(_f(pos[q] - tgt[q]))) <= float(_f(1e-6)):
            abs_travel = whole
        else:
            travel = _f(math.atan2(float(_f(_f(rv_a * rt_y) - _f(rv_b * rt_x))), float(_f(_f(rv_a * rt_x) + _f(rv_b * rt_y)))))
            if travel == 0:
                return np.zeros((0, 4))
            if travel >= 0 and clockwise:
                travel = _f(travel - whole)
            elif travel < 0 and not clockwise:
                travel = _f(travel + whole)
            abs_travel = _f(abs(travel))
        total = _f(abs_travel + _f(_f(int(circles)) * whole))
        part = _f(whole / total)
        per_l = _f(_f(tgt[l] - pos[l]) * part)
        per_e = _f(_f(tgt[3] - pos[3]) * part)
        temp = pos.copy()
        cur = pos.copy()
        for _ in range(int(circles)):
            temp[l] = _f(temp[l] + per_l)
            temp[3] = _f(temp[3] + per_e)
            pts = one_arc(cur, temp.copy())
            if len(pts):
                pieces.append(pts)
                cur = pts[-1].copy()
        pos = cur
    pieces.append(one_arc(pos, tgt))
    return np.concatenate(pieces).astype(np.float64)


def _too_many(n: int) -> str:
    if n >= 2 ** 31:
        return "arc out of range: Marlin's single precision overflows (centre or radius too large)"
    return (f"arc of {n} segments: Marlin counts an arc's segments in 16 bits (at most {MAX_SEGMENTS}); "
            "the firmware would cut it wrongly")
