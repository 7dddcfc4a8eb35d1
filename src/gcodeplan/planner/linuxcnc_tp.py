"""LinuxCNC 2.9's trajectory planner, modelled: the segment queue and the servo-cycle execution.

Our own code after reading LinuxCNC's ``src/emc/tp/tp.c``, ``tc.c``, ``blendmath.c`` (docs/design.md,
"LinuxCNC planner"). Two numba kernels:

* :func:`queue_kernel` adds the TP segments one by one as LinuxCNC's ``tpAddLine``/``tpAddCircle`` do:
  terminal condition of the previous segment (G61.1 stop, G61 exact path, G64 blend), rapid↔feed stop,
  tangency test with the kink-ratio acceleration reduction (``tpSetupTangent``), blend arcs within the
  tolerance between lines and arcs in any combination (``blendmath.c``'s geometry, with its exact
  line-arc / arc-line / arc-arc post-processing, convexity, trim-angle and tangency checks, and the
  consumption of a line remainder shorter than ARC_BLEND_GAP_CYCLES; ARC_BLEND_ENABLE), the parabolic
  fallback chosen by the same performance
  comparison (``tpChooseBestBlend``), finalisation (sample-rate velocity clamp, the circle's normal
  acceleration limit) and the backward "rising tide" optimisation to ARC_BLEND_OPTIMIZATION_DEPTH after
  every segment (``tpRunOptimization``).
* :func:`execute_kernel` runs the queue one servo cycle at a time (``tpRunCycle``): trapezoid velocity
  per cycle, ramp acceleration for short tangent segments (ARC_BLEND_RAMP_FREQ), split cycles at tangent
  joins, parabolic blends running two segments at once, a whole cycle for the last bit of a segment that
  ends at rest. It records the executing segment and the commanded position of every cycle.

Units: mm, s, mm/s, mm/s². A segment (SEG_DTYPE row) is a line, a circle (arc or helix) or a blend arc
(a circle, possibly led by the straight remainder of a consumed line).
"""
from __future__ import annotations

import math

from .._jit import njit
import numpy as np

# terminal conditions (LinuxCNC's TC_TERM_COND_*)
TERM_STOP, TERM_EXACT, TERM_PARABOLIC, TERM_TANGENT = 0, 1, 2, 3
# segment kinds
SEG_LINE, SEG_CIRCLE, SEG_BLEND = 0, 1, 2

# tp_types.h / blendmath.h constants
TP_POS_EPSILON = 1e-12
TP_VEL_EPSILON = 1e-8
TP_TIME_EPSILON = 1e-12
TP_BIG_NUM = 1e10
TP_MIN_ARC_LENGTH = 1e-6
TP_MIN_ARC_ANGLE = 1e-3
TP_ANGLE_EPSILON = 1e-6
TP_ANGLE_EPSILON_SQ = TP_ANGLE_EPSILON ** 2
DOUBLE_FUZZ = 2.220446049250313e-16
BLEND_KINK_FACTOR = 0.25                                # blendmath.h
TP_OPTIMIZATION_CUTOFF = 4
BLEND_ACC_RATIO_TANGENTIAL = 0.5
BLEND_ACC_RATIO_NORMAL = math.sqrt(1.0 - BLEND_ACC_RATIO_TANGENTIAL ** 2)
SHARP_CORNER_EPSILON = (math.pi * 2.0 / 180.0) ** 2   # tp.c: anti-parallel within 2°
TOLERANCE_RATIO = 0.25                                  # tc.c: no tolerance = a quarter of the segment
BLEND_GREEDINESS = 0.5                                  # blendmath.c: a line-line blend takes ≤ half a line

SEG_DTYPE = np.dtype([
    ("kind", "i8"), ("line", "i8"), ("row0", "i8"), ("row1", "i8"),
    ("p0", "f8", 3), ("p1", "f8", 3), ("u", "f8", 3),          # start, end; unit direction (lines, lead-in line)
    ("c", "f8", 3), ("rt", "f8", 3), ("rp", "f8", 3),          # circle: centre, start radius vector, n × rt
    ("h", "f8", 3), ("radius", "f8"), ("angle", "f8"),          # helix displacement, radius, swept angle (rad)
    ("spiral", "f8"),                                          # end radius − start radius (LinuxCNC's spiral)
    ("lline", "f8"),                                           # blend: straight lead-in length
    ("target", "f8"), ("nominal", "f8"),                       # path length, length before blends cut it
    ("reqvel", "f8"), ("inivel", "f8"), ("maxvel", "f8"), ("maxaccel", "f8"), ("traverse", "i8"),
    ("term", "i8"), ("tolerance", "f8"), ("blend_prev", "i8"),
    ("kink_vel", "f8"), ("kink_red", "f8"), ("kink_red_prev", "f8"), ("acc_ratio_tan", "f8"),
    ("finalized", "i8"), ("finalvel", "f8"), ("at_max", "i8"),
    ("sync_after", "i8"), ("dwell_after", "f8"),               # the queue drains after this segment (M3, M5...)
])


# --------------------------------------------------------------------------- geometry
@njit(cache=True)
def seg_point(sg, s, out):
    """Position (mm) at path distance ``s`` along segment row ``sg`` into ``out`` (3)."""
    if sg.kind == SEG_LINE:
        for a in range(3):
            out[a] = sg.p0[a] + sg.u[a] * s
        return
    if sg.kind == SEG_BLEND and s < sg.lline:
        for a in range(3):
            out[a] = sg.p0[a] + sg.u[a] * s
        return
    if sg.kind == SEG_BLEND:
        frac = (s - sg.lline) / max(sg.target - sg.lline, 1e-300)
    else:
        frac = s / max(sg.target, 1e-300)
    if frac > 1.0:
        frac = 1.0
    phi = frac * sg.angle
    cp = math.cos(phi)
    sp = math.sin(phi)
    rf = 1.0 + sg.spiral * frac / sg.radius if sg.radius > 0.0 else 1.0
    for a in range(3):
        out[a] = sg.c[a] + (sg.rt[a] * cp + sg.rp[a] * sp) * rf + sg.h[a] * frac


@njit(cache=True)
def seg_tangent(sg, at_end, out):
    """Unit tangent at the start (``at_end`` False) or the end of a segment into ``out``."""
    if sg.kind == SEG_LINE or (sg.kind == SEG_BLEND and not at_end and sg.lline > 0.0):
        for a in range(3):
            out[a] = sg.u[a]
        return
    phi = sg.angle if at_end else 0.0
    cp = math.cos(phi)
    sp = math.sin(phi)
    rf = 1.0
    dr = 0.0
    if sg.radius > 0.0:
        rf = 1.0 + (sg.spiral / sg.radius if at_end else 0.0)
        dr = sg.spiral / sg.radius
    n = 0.0
    for a in range(3):
        # the circle's tangent at the spiral's radius: LinuxCNC 2.9's tangent ignores the radius change
        out[a] = (-sg.rt[a] * sp + sg.rp[a] * cp) * sg.angle * rf + sg.h[a]
        n += out[a] * out[a]
    n = math.sqrt(n)
    if n > 0.0:
        for a in range(3):
            out[a] /= n


@njit(cache=True)
def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit(cache=True)
def inscribed_limit(nrm, bx, by, bz):
    """blendmath.c calculateInscribedDiameter: the least axis bound on the plane with unit normal ``nrm``."""
    best = math.inf
    bounds = (bx, by, bz)
    for a in range(3):
        s2 = 0.0
        for b in range(3):
            comp = (1.0 if a == b else 0.0) - nrm[a] * nrm[b]
            s2 += comp * comp
        scale = math.sqrt(s2)
        if scale > 0.0:
            best = min(best, bounds[a] / scale)
    return best


# --------------------------------------------------------------------------- per-segment limits
@njit(cache=True)
def overall_accel(sg):
    """tc.c tcGetOverallMaxAccel: kink reduction, and half for a parabolic blend at either end."""
    a_scale = 1.0 - max(sg.kink_red, sg.kink_red_prev)
    if sg.blend_prev != 0 or sg.term == TERM_PARABOLIC:
        a_scale *= 0.5
    return sg.maxaccel * a_scale


@njit(cache=True)
def tangential_accel(sg):
    """tc.c tcGetTangentialMaxAccel: circles and blend arcs keep part of the acceleration for the normal one."""
    a = overall_accel(sg)
    if sg.kind != SEG_LINE:
        a *= sg.acc_ratio_tan
    return a


@njit(cache=True)
def max_target_vel(sg, vlimit):
    """tp.c tpGetMaxTargetVel at feed override 1: requested, [TRAJ] and segment limits."""
    return min(sg.reqvel, vlimit, sg.maxvel)


@njit(cache=True)
def circle_limits(sg, cycle):
    """blendmath.c pmCircleActualMaxVel: speed within 0.866 of the overall accel as normal acceleration on the
    effective radius, and the tangential share that remains. The effective radius is
    pmCircleEffectiveMinRadius's: r_s + h²/r_s, r_s = (ρ² + r²)^1.5 / (2ρ² + r²) the spiral's (ρ = radius change
    per radian, r the start radius), h the helix' *whole* axial travel (not its travel per radian, as the
    curvature of a helix would have it: LinuxCNC 2.9 runs a helical turn that fast)."""
    if sg.kind != SEG_CIRCLE:
        return
    sg.maxvel = min(sg.inivel, sg.target / cycle)
    a_max = overall_accel(sg)
    h2 = sg.h[0] ** 2 + sg.h[1] ** 2 + sg.h[2] ** 2
    dr = sg.spiral / sg.angle if sg.angle > 0.0 else 0.0
    n_inner = dr * dr + sg.radius * sg.radius
    r_s = math.sqrt(n_inner * n_inner * n_inner) / max(n_inner + dr * dr, 1e-300)
    eff_r = h2 / max(r_s, 1e-300) + r_s
    a_n_cut = BLEND_ACC_RATIO_NORMAL * a_max
    a_n_vmax = sg.maxvel * sg.maxvel / max(eff_r, 1e-300)
    if a_n_vmax > a_n_cut:
        sg.maxvel = math.sqrt(a_n_cut * eff_r)
        sg.acc_ratio_tan = BLEND_ACC_RATIO_TANGENTIAL
    else:
        sg.acc_ratio_tan = math.sqrt(max(0.0, 1.0 - (a_n_vmax / a_max) ** 2))


@njit(cache=True)
def finalize(sg, cycle):
    """tc.c tcFinalizeLength: no faster than one segment per servo cycle; the circle's limits."""
    if sg.finalized != 0:
        return
    sg.maxvel = min(sg.maxvel, sg.target / cycle)
    circle_limits(sg, cycle)
    sg.finalized = 1


@njit(cache=True)
def set_term(q, i_prev, i_cur, term):
    """tc.c tcSetTermCond: the previous segment's end, and whether the next one starts in a parabolic blend."""
    if i_prev >= 0:
        q[i_prev].term = term
    if i_cur >= 0:
        q[i_cur].blend_prev = 1 if term == TERM_PARABOLIC else 0


@njit(cache=True)
def set_kink(q, i_prev, i_cur, kink_vel, reduce):
    q[i_prev].kink_vel = kink_vel
    q[i_prev].kink_red = max(reduce, q[i_prev].kink_red)
    q[i_cur].kink_red_prev = max(reduce, q[i_cur].kink_red_prev)


@njit(cache=True)
def remove_kink(q, i_prev, i_cur):
    q[i_prev].kink_vel = -1.0
    q[i_prev].kink_red = 0.0
    q[i_cur].kink_red_prev = 0.0


# --------------------------------------------------------------------------- blend choices
@njit(cache=True)
def find_vpeak(acc, dist):
    return math.sqrt(max(acc * dist, 0.0))


@njit(cache=True)
def blend_velocity(q, i, j, v_target_this, v_target_next, tan1, tan2):
    """tp.c tpComputeBlendVelocity: parabolic blend speeds of segment i into j, and their net speed."""
    acc_this = tangential_accel(q[i])
    acc_next = tangential_accel(q[j])
    len_this = q[i].target if q[i].finalized != 0 else q[i].target / 2.0
    len_next = q[j].target if q[j].finalized != 0 else q[j].target / 2.0
    v_reach_this = min(find_vpeak(acc_this, len_this), v_target_this)
    v_reach_next = min(find_vpeak(acc_next, len_next), v_target_next)
    if v_reach_this <= 0.0 or v_reach_next <= 0.0 or acc_this <= 0.0 or acc_next <= 0.0:
        return 0.0, 0.0, 0.0
    t_max_reach = min(q[i].target / v_reach_this, q[j].target / v_reach_next)
    t_max_blend = max(v_reach_this / acc_this, v_reach_next / acc_next)
    t_blend = min(t_max_reach, t_max_blend)
    v_this = min(v_reach_this, t_blend * acc_this)
    v_next = min(v_reach_next, t_blend * acc_next)
    d = max(-1.0, min(1.0, _dot(tan1, tan2)))
    theta = math.acos(-d) / 2.0
    cos_theta = math.cos(theta)
    if q[i].tolerance > 0.0:
        min_cos = math.cos(math.pi / 2.0 - TP_MIN_ARC_ANGLE)
        if cos_theta > min_cos:
            tblend = 2.0 * math.sqrt(acc_this * q[i].tolerance / cos_theta)
            v_this = min(v_this, tblend)
            v_next = min(v_next, tblend)
    v_net = math.sin(theta) * (v_this + v_next) / 2.0
    return v_this, v_next, v_net


@njit(cache=True)
def choose_best_blend(q, i_prev, i_cur, perf_arc, vlimit, tan1, tan2):
    """tp.c tpChooseBestBlend: parabolic (at half its net speed), tangent-with-kink or the blend arc,
    whichever is fastest; 0 parabolic, 1 tangent, 2 arc, 3 none."""
    tp = q[i_prev].term
    if tp == TERM_EXACT or tp == TERM_STOP:
        return 3
    _, _, v_net = blend_velocity(q, i_prev, i_cur, max_target_vel(q[i_prev], vlimit),
                                 max_target_vel(q[i_cur], vlimit), tan1, tan2)
    perf = (v_net / 2.0, q[i_prev].kink_vel, perf_arc)
    best = 0
    for k in range(3):
        if perf[k] > perf[best]:
            best = k
    if best == 0:
        remove_kink(q, i_prev, i_cur)
        set_term(q, i_prev, i_cur, TERM_PARABOLIC)
    elif best == 1:
        set_term(q, i_prev, i_cur, TERM_TANGENT)
    else:
        remove_kink(q, i_prev, i_cur)
    return best


@njit(cache=True)
def setup_tangent(q, i_prev, i_cur, acc_bound, cycle, kink_ratio, opt_depth, tan1, tan2):
    """tp.c tpSetupTangent: -1 no blending at all, 0 joined as tangent, 1 not tangent (blend next)."""
    if opt_depth < 2:
        return -1
    if q[i_prev].term == TERM_STOP:
        return -1
    # anti-parallel: a reversal stops
    d = _dot(tan1, tan2)
    if (1.0 + d) < SHARP_CORNER_EPSILON:
        set_term(q, i_prev, i_cur, TERM_STOP)
        return -1
    v_max1 = min(q[i_prev].maxvel, q[i_prev].reqvel)
    v_max2 = min(q[i_cur].maxvel, q[i_cur].reqvel)
    v_max = min(v_max1, v_max2)
    a_inst = v_max / cycle + q[i_cur].maxaccel
    acc_scale_max = 0.0
    for a in range(3):
        diff = abs((tan2[a] - tan1[a]) * a_inst)
        if acc_bound[a] > 0.0:
            acc_scale_max = max(acc_scale_max, diff / acc_bound[a])
    if q[i_prev].kind == SEG_CIRCLE or q[i_cur].kind == SEG_CIRCLE:
        acc_scale_max /= BLEND_ACC_RATIO_TANGENTIAL
    if acc_scale_max < kink_ratio:
        set_term(q, i_prev, i_cur, TERM_TANGENT)
        set_kink(q, i_prev, i_cur, v_max, acc_scale_max)
        return 0
    set_kink(q, i_prev, i_cur, v_max * kink_ratio / acc_scale_max, kink_ratio)
    return 1


@njit(cache=True)
def blend_tolerance(q, i_prev, i_cur):
    """tc.c tcFindBlendTolerance: a zero tolerance means a quarter of each segment's nominal length."""
    t1 = q[i_prev].tolerance
    t2 = q[i_cur].tolerance
    if t1 == 0.0:
        t1 = q[i_prev].nominal * TOLERANCE_RATIO
    if t2 == 0.0:
        t2 = q[i_cur].nominal * TOLERANCE_RATIO
    nominal = min(t1, t2)
    return min(min(nominal, q[i_prev].nominal * TOLERANCE_RATIO), q[i_cur].nominal * TOLERANCE_RATIO)


@njit(cache=True)
def _coplanar(sg, binormal):
    """blendmath.c pmUnitCartsColinear: the blend's plane is the circle's plane."""
    nrm = np.empty(3)
    nrm[0] = sg.rt[1] * sg.rp[2] - sg.rt[2] * sg.rp[1]
    nrm[1] = sg.rt[2] * sg.rp[0] - sg.rt[0] * sg.rp[2]
    nrm[2] = sg.rt[0] * sg.rp[1] - sg.rt[1] * sg.rp[0]
    nn = math.sqrt(_dot(nrm, nrm))
    if not nn > 0.0:
        return False
    return abs(abs(_dot(nrm, binormal)) / nn - 1.0) < 1e-9


@njit(cache=True)
def trim_end(sg, d):
    """Shorten a segment by ``d`` mm at its end."""
    if sg.kind == SEG_LINE:
        for a in range(3):
            sg.p1[a] = sg.p1[a] - sg.u[a] * d
        sg.target -= d
        return
    keep = 1.0 - d / sg.target
    sg.angle *= keep
    sg.spiral *= keep
    for a in range(3):
        sg.h[a] *= keep
    sg.target -= d
    seg_point(sg, sg.target, sg.p1)


@njit(cache=True)
def trim_start(sg, d):
    """Shorten a segment by ``d`` mm at its start."""
    if sg.kind == SEG_LINE:
        for a in range(3):
            sg.p0[a] = sg.p0[a] + sg.u[a] * d
        sg.target -= d
        return
    frac = d / sg.target
    phi = frac * sg.angle
    cp = math.cos(phi)
    sp = math.sin(phi)
    rf = 1.0 + sg.spiral * frac / sg.radius if sg.radius > 0.0 else 1.0
    for a in range(3):
        rt = (sg.rt[a] * cp + sg.rp[a] * sp) * rf
        rp = (-sg.rt[a] * sp + sg.rp[a] * cp) * rf
        sg.rt[a] = rt
        sg.rp[a] = rp
        sg.c[a] += sg.h[a] * frac
        sg.h[a] *= 1.0 - frac
    sg.radius *= rf
    sg.spiral *= 1.0 - frac
    sg.angle *= 1.0 - frac
    sg.target -= d
    seg_point(sg, 0.0, sg.p0)


@njit(cache=True)
def _circle_point_at(sg, phi, out):
    """posemath pmCirclePoint: the point of circle segment ``sg`` at angle ``phi`` (rad) from its start."""
    frac = phi / sg.angle if sg.angle > 0.0 else 0.0
    cp = math.cos(phi)
    sp = math.sin(phi)
    rf = 1.0 + sg.spiral * frac / sg.radius if sg.radius > 0.0 else 1.0
    for a in range(3):
        out[a] = sg.c[a] + (sg.rt[a] * cp + sg.rp[a] * sp) * rf + sg.h[a] * frac


@njit(cache=True)
def _circle_tangent_at(sg, phi, out):
    """tc.c pmCircleTangentVector: unit tangent of circle segment ``sg`` at angle ``phi``, with the spiral's
    radial and the helix' axial components."""
    cp = math.cos(phi)
    sp = math.sin(phi)
    dr = sg.spiral / sg.angle if sg.angle > 0.0 else 0.0
    r = np.empty(3)
    for a in range(3):
        r[a] = sg.rt[a] * cp + sg.rp[a] * sp
    rn = math.sqrt(_dot(r, r))
    n = 0.0
    for a in range(3):
        # n × r is (−rt sinφ + rp cosφ): rp = n × rt
        out[a] = -sg.rt[a] * sp + sg.rp[a] * cp + sg.h[a] / max(sg.angle, 1e-300)
        if rn > 0.0:
            out[a] += r[a] / rn * dr
        n += out[a] * out[a]
    n = math.sqrt(n)
    if n > 0.0:
        for a in range(3):
            out[a] /= n


@njit(cache=True)
def _unit_eq(v):
    n = math.sqrt(_dot(v, v))
    if not n > 0.0:
        return False
    for a in range(3):
        v[a] /= n
    return True


@njit(cache=True)
def _cross(a, b, out):
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]


@njit(cache=True)
def _colinear(u, v):
    """blendmath.c pmUnitCartsColinear: unit vectors parallel or anti-parallel within TP_ANGLE_EPSILON."""
    dm = 0.0
    dp = 0.0
    for a in range(3):
        dm += (u[a] - v[a]) ** 2
        dp += (u[a] + v[a]) ** 2
    return dm < TP_ANGLE_EPSILON_SQ or dp < TP_ANGLE_EPSILON_SQ


@njit(cache=True)
def _circle_normal(sg, out):
    _cross(sg.rt, sg.rp, out)
    return _unit_eq(out)


@njit(cache=True)
def _trim_angle(P, arc_center, center):
    """blendmath.c findTrimAngle: the angle at ``center`` between the corner ``P`` and the blend's centre."""
    u = np.empty(3)
    w = np.empty(3)
    for a in range(3):
        u[a] = P[a] - center[a]
        w[a] = arc_center[a] - center[a]
    _unit_eq(u)
    _unit_eq(w)
    return math.acos(max(-1.0, min(1.0, _dot(u, w))))


@njit(cache=True)
def _line_circle_center(P, c_circ, d_c, R, u, binormal, sgn):
    """blendmath.c blendLineArcPostProcess / blendArcLinePostProcess: the centre of the blend circle of
    radius ``R`` tangent to the line through ``P`` along ``u`` (``sgn`` −1: the line before P, +1: after)
    and at distance ``d_c`` from the circle centre ``c_circ``. Returns (ok, distance along the line)."""
    nl = np.empty(3)
    _cross(binormal, u, nl)
    if not _unit_eq(nl):
        return False, 0.0, nl
    cu = 0.0
    cn = 0.0
    for a in range(3):
        cu += (c_circ[a] - P[a]) * u[a]
        cn += (c_circ[a] - P[a]) * nl[a]
    B = 2.0 * cu * (-sgn)
    C = cu * cu - d_c * d_c + (R - cn) ** 2
    disc = B * B - 4.0 * C
    if disc < 0.0:
        return False, 0.0, nl
    t1 = math.sqrt(disc)
    d_l = min(abs((-B + t1) / 2.0), abs((-B - t1) / 2.0))
    out = np.empty(3)
    for a in range(3):
        out[a] = P[a] + sgn * u[a] * d_l + nl[a] * R
    return True, d_l, out


@njit(cache=True)
def blend_geom3_init(tan1, tan2):
    """blendmath.c blendGeom3Init: the half angle between the segments at the corner (``theta_tan``), the
    plane's binormal tan1 × tan2 and the unit normal tan2 − tan1 (towards the inside of the corner).
    Returns (ok, theta_tan, binormal, normal)."""
    binormal = np.empty(3)
    normal = np.empty(3)
    d = max(-1.0, min(1.0, _dot(tan1, tan2)))
    theta_tan = math.acos(-d) / 2.0
    if math.pi / 2.0 - theta_tan < TP_ANGLE_EPSILON or theta_tan < TP_ANGLE_EPSILON:
        return False, theta_tan, binormal, normal
    _cross(tan1, tan2, binormal)
    for a in range(3):
        normal[a] = tan2[a] - tan1[a]
    if not (_unit_eq(binormal) and _unit_eq(normal)):
        return False, theta_tan, binormal, normal
    return True, theta_tan, binormal, normal


@njit(cache=True)
def find_spiral_approximation(sg, P, tan, center):
    """blendmath.c findSpiralApproximation: the circle through the corner ``P`` standing in for the spiral
    ``sg`` there, its centre shifted along the tangent ``tan`` by the spiral's radius change per radian.
    Writes the centre into ``center``; returns the radius (mm)."""
    bp = np.empty(3)
    for a in range(3):
        center[a] = sg.c[a] + tan[a] * (sg.spiral / sg.angle)
        bp[a] = P[a] - center[a]
    return math.sqrt(_dot(bp, bp))


@njit(cache=True)
def blend_init3(q, i_prev, i_cur, tan1, tan2):
    """blendmath.c blendInit3FromLineLine / blendInit3FromLineArc / blendInit3FromArcLine /
    blendInit3FromArcArc, their geometry (blendParamKinematics is :func:`blend_param_kinematics`): the corner
    ``P``, the directions ``u1``, ``u2`` the blend sees (an arc convex towards the other segment is replaced by
    a secant), the blend's half angle ``theta`` and swept angle ``phi``, each arc's approximating circle
    (centre, radius, convexity, the largest angle the blend may take from it) and the lengths ``L1``, ``L2`` the
    blend may take from each segment. Returns (ok, P, u1, u2, binormal, normal, theta, phi, c1, c2, r1, r2,
    convex1, convex2, phi1_max, phi2_max, L1, L2)."""
    pv = q[i_prev]
    cu = q[i_cur]
    line1 = pv.kind == SEG_LINE
    line2 = cu.kind == SEG_LINE
    P = np.empty(3)
    u1 = tan1.copy()
    u2 = tan2.copy()
    c1 = np.zeros(3)
    c2 = np.zeros(3)
    nrm = np.empty(3)
    bp = np.empty(3)
    r1 = 0.0
    r2 = 0.0
    convex1 = False
    convex2 = False
    phi1_max = 0.0
    phi2_max = 0.0
    phi = 0.0
    L1 = 0.0
    L2 = 0.0
    ok, theta_tan, binormal, normal = blend_geom3_init(tan1, tan2)
    theta = theta_tan
    if not ok:
        return (False, P, u1, u2, binormal, normal, theta, phi, c1, c2, r1, r2, convex1, convex2, phi1_max,
                phi2_max, L1, L2)
    for a in range(3):
        P[a] = cu.p0[a]
    if not line1:
        # a helix can be neither blended in its plane nor cut (pmCircleStretch)
        if _dot(pv.h, pv.h) > 1e-6 or not _circle_normal(pv, nrm) or not _colinear(binormal, nrm):
            return (False, P, u1, u2, binormal, normal, theta, phi, c1, c2, r1, r2, convex1, convex2, phi1_max,
                    phi2_max, L1, L2)
        r1 = find_spiral_approximation(pv, P, tan1, c1)
        for a in range(3):
            bp[a] = P[a] - c1[a]
        convex1 = _dot(bp, tan2) < 0.0                     # arcConvexTest(center1, P, u_tan2, false)
        phi1_max = min(pv.angle * 2.0 / 3.0, theta_tan if convex1 else math.pi / 2.0)
        if convex1:
            # the secant over the last half of the blendable angle replaces the tangent
            _circle_point_at(pv, pv.angle - phi1_max / 2.0, bp)
            for a in range(3):
                u1[a] = P[a] - bp[a]
            _unit_eq(u1)
            theta = min(theta, theta_tan - phi1_max / 4.0)
    if not line2:
        if _dot(cu.h, cu.h) > 1e-6 or not _circle_normal(cu, nrm) or not _colinear(binormal, nrm):
            return (False, P, u1, u2, binormal, normal, theta, phi, c1, c2, r1, r2, convex1, convex2, phi1_max,
                    phi2_max, L1, L2)
        r2 = find_spiral_approximation(cu, P, tan2, c2)
        for a in range(3):
            bp[a] = P[a] - c2[a]
        convex2 = not (_dot(bp, tan1) < 0.0)               # arcConvexTest(center2, P, u_tan1, true)
        phi2_max = min(cu.angle / 3.0, theta_tan if convex2 else math.pi / 2.0)
        if convex2:
            _circle_point_at(cu, phi2_max / 2.0, bp)
            for a in range(3):
                u2[a] = bp[a] - P[a]
            _unit_eq(u2)
            theta = min(theta, theta_tan - phi2_max / 4.0)
    if not line1 and not line2 and theta < math.pi / 12.0:
        return (False, P, u1, u2, binormal, normal, theta, phi, c1, c2, r1, r2, convex1, convex2, phi1_max,
                phi2_max, L1, L2)
    phi = math.pi - 2.0 * theta
    # blend lengths: half a line (the previous one only up to half its programmed length); on an arc the
    # blendable angle, or half its chord when the arc is convex towards the other segment
    if line1:
        L1 = min(pv.target, pv.nominal * BLEND_GREEDINESS)
    else:
        L1 = math.sin(phi1_max / 4.0) * r1 if convex1 else phi1_max * r1
    if line2:
        L2 = cu.target * BLEND_GREEDINESS
    else:
        L2 = math.sin(phi2_max / 4.0) * r2 if convex2 else phi2_max * r2
    return (True, P, u1, u2, binormal, normal, theta, phi, c1, c2, r1, r2, convex1, convex2, phi1_max, phi2_max,
            L1, L2)


@njit(cache=True)
def blend_param_kinematics(q, i_prev, i_cur, binormal, u1, u2, phi, acc_bound, vel_bound):
    """blendmath.c blendParamKinematics: the tolerance (mm), the acceleration in the blend's plane and its
    normal share (mm/s²), the requested speed and the speed the blend aims at (mm/s; for two lines the
    speed that keeps both segments' limits, LinuxCNC's triangle construction). Returns
    (tol, a_max, a_n_max, v_req, v_goal)."""
    pv = q[i_prev]
    cu = q[i_cur]
    tol = blend_tolerance(q, i_prev, i_cur)
    a_max = inscribed_limit(binormal, acc_bound[0], acc_bound[1], acc_bound[2])
    a_n_max = a_max * BLEND_ACC_RATIO_NORMAL
    v_req = max(pv.reqvel, cu.reqvel)
    v_goal = v_req
    v_planar = inscribed_limit(binormal, vel_bound[0], vel_bound[1], vel_bound[2])
    v_alt = 0.0
    if pv.kind == SEG_LINE and cu.kind == SEG_LINE:
        phi_eff = min(phi, math.pi * 0.49)
        v1 = min(pv.maxvel, cu.maxvel / math.cos(phi_eff))
        v2 = min(cu.maxvel, pv.maxvel / math.cos(phi_eff))
        area = v1 * v2 / 2.0 * math.sin(phi)
        base2 = 0.0
        for a in range(3):
            base2 += (u2[a] * v2 - u1[a] * v1) ** 2
        base = math.sqrt(base2)
        v_alt = 2.0 * area / base if base > 0.0 else 0.0
    v_goal = min(v_goal, max(v_alt, v_planar))
    return tol, a_max, a_n_max, v_req, v_goal


@njit(cache=True)
def blend_compute_parameters(theta, phi, tol, L1, L2, a_max, a_n_max, v_goal):
    """blendmath.c blendComputeParameters: the blend's speed (mm/s), radius (mm) and the distance (mm) from
    the corner to where it meets each segment, the largest the tolerance, the lengths and the normal
    acceleration allow. Returns (ok, v_plan, r_plan, d_plan)."""
    if not (theta > 0.0 and theta < math.pi / 2.0):
        return False, 0.0, 0.0, 0.0
    h_tol = tol / (1.0 - math.sin(theta))
    d_tol = math.cos(theta) * h_tol
    d_geom = min(min(L1, L2), d_tol)
    r_geom = math.tan(theta) * d_geom
    v_normal = math.sqrt(max(a_n_max * r_geom, 0.0))
    v_plan = min(v_normal, v_goal)
    a_par = a_max * 0.5
    v_tri = math.sqrt(max(2.0 * a_par * d_geom, 0.0))
    t_blend = min(v_tri, v_plan) / a_par
    s_blend = t_blend * v_plan
    r_blend = min(s_blend / phi, r_geom)
    r_plan = max(v_plan * v_plan / a_n_max, r_blend)
    d_plan = r_plan / math.tan(theta)
    s_arc = r_plan * phi
    if r_plan < TP_POS_EPSILON or s_arc < TP_MIN_ARC_LENGTH or not v_plan > 0.0:
        return False, v_plan, r_plan, d_plan
    return True, v_plan, r_plan, d_plan


@njit(cache=True)
def blend_find_points3(P, normal, theta, r_plan, d_plan):
    """blendmath.c blendFindPoints3 (two lines): the blend circle's centre on the corner's bisector and how
    much of each line it replaces (mm). Returns (center, trim1, trim2)."""
    center = np.empty(3)
    center_dist = r_plan / math.sin(theta)
    for a in range(3):
        center[a] = P[a] + normal[a] * center_dist
    return center, d_plan, d_plan


@njit(cache=True)
def blend_line_arc_post_process(P, c2, r2, convex2, r_plan, u1, binormal):
    """blendmath.c blendLineArcPostProcess: the exact centre of the blend circle tangent to the line before
    ``P`` and to the arc after it; trims: mm of the line, rad of the arc. Returns (ok, center, trim1, trim2)."""
    ok, trim1, center = _line_circle_center(P, c2, (r2 - r_plan) if convex2 else (r2 + r_plan), r_plan,
                                            u1, binormal, -1.0)
    if not ok:
        return False, center, 0.0, 0.0
    return True, center, trim1, _trim_angle(P, center, c2)


@njit(cache=True)
def blend_arc_line_post_process(P, c1, r1, convex1, r_plan, u2, binormal):
    """blendmath.c blendArcLinePostProcess: as :func:`blend_line_arc_post_process` for an arc then a line;
    trims: rad of the arc, mm of the line. Returns (ok, center, trim1, trim2)."""
    ok, trim2, center = _line_circle_center(P, c1, (r1 - r_plan) if convex1 else (r1 + r_plan), r_plan,
                                            u2, binormal, 1.0)
    if not ok:
        return False, center, 0.0, 0.0
    return True, center, _trim_angle(P, center, c1), trim2


@njit(cache=True)
def blend_arc_arc_post_process(P, c1, c2, r1, r2, convex1, convex2, r_plan, binormal, normal):
    """blendmath.c blendArcArcPostProcess: the centre at distance d1 from centre 1 and d2 from centre 2 (the
    intersection nearer the corner); trims in rad of each arc. Returns (ok, center, trim1, trim2)."""
    center = np.empty(3)
    d1 = (r1 - r_plan) if convex1 else (r1 + r_plan)
    d2 = (r2 - r_plan) if convex2 else (r2 + r_plan)
    uc = np.empty(3)
    for a in range(3):
        uc[a] = c2[a] - c1[a]
    c2x = math.sqrt(_dot(uc, uc))
    if not _unit_eq(uc):
        return False, center, 0.0, 0.0
    cx = (-d1 * d1 + d2 * d2 - c2x * c2x) / (-2.0 * c2x)
    cy2 = d1 * d1 - cx * cx
    if not cy2 >= 0.0:
        return False, center, 0.0, 0.0
    cy = math.sqrt(cy2)
    nc = np.empty(3)
    _cross(binormal, uc, nc)
    if _dot(normal, nc) < 0.0:
        for a in range(3):
            nc[a] = -nc[a]
    if not _unit_eq(nc):
        return False, center, 0.0, 0.0
    m1 = 0.0
    m2 = 0.0
    for a in range(3):
        base_a = c1[a] - P[a] + uc[a] * cx
        m1 += (base_a + nc[a] * cy) ** 2
        m2 += (base_a - nc[a] * cy) ** 2
    if m2 < m1:
        cy = -cy
    for a in range(3):
        center[a] = c1[a] + uc[a] * cx + nc[a] * cy
    return True, center, _trim_angle(P, center, c1), _trim_angle(P, center, c2)


@njit(cache=True)
def blend_check_consume(pv, trim1, v_plan, gap_cycles, cycle):
    """blendmath.c blendCheckConsume: a line remainder shorter than ARC_BLEND_GAP_CYCLES at the blend speed is
    swallowed by the blend (not a line that starts in a parabolic blend: tcCanConsume). Returns
    (consume, remainder mm)."""
    l_prev = max(pv.target - trim1, 0.0)
    consume = pv.kind == SEG_LINE and (l_prev / v_plan) < gap_cycles * cycle and pv.blend_prev == 0
    return consume, l_prev


@njit(cache=True)
def blend_stretch_points(pv, cu, trim1, trim2, tan1, tan2):
    """tp.c tpCreate*Blend: the cut segments (pmCartLineStretch / pmCircleStretch refuse to cut to nothing)
    and the points where the blend leaves the previous segment and joins this one (pmCartLinePoint /
    pmCirclePoint). Returns (ok, start, end)."""
    line1 = pv.kind == SEG_LINE
    line2 = cu.kind == SEG_LINE
    start = np.empty(3)
    end = np.empty(3)
    if line1 and not line2 and not (pv.target - trim1 > DOUBLE_FUZZ):
        return False, start, end
    if line2 and not line1 and not (cu.target - trim2 > DOUBLE_FUZZ):
        return False, start, end
    if line2 and trim2 > cu.target:
        return False, start, end
    if not line1 and not (pv.angle - trim1 > DOUBLE_FUZZ):
        return False, start, end
    if not line2 and not (cu.angle - trim2 > DOUBLE_FUZZ):
        return False, start, end
    if line1:
        for a in range(3):
            start[a] = pv.p1[a] - tan1[a] * trim1
    else:
        _circle_point_at(pv, pv.angle - trim1, start)
    if line2:
        for a in range(3):
            end[a] = cu.p0[a] + tan2[a] * trim2
    else:
        _circle_point_at(cu, trim2, end)
    return True, start, end


@njit(cache=True)
def arc_from_blend_points3(start, end, center):
    """blendmath.c arcFromBlendPoints3 (spherical_arc.c arcInitFromPoints): the blend arc from ``start`` to
    ``end`` around ``center``. Returns (ok, start radius vector, end radius vector, start radius mm, end
    radius mm, swept angle rad)."""
    rs = np.empty(3)
    re = np.empty(3)
    for a in range(3):
        rs[a] = start[a] - center[a]
        re[a] = end[a] - center[a]
    rad0 = math.sqrt(_dot(rs, rs))
    rad1 = math.sqrt(_dot(re, re))
    if rad0 < TP_POS_EPSILON or rad1 < TP_POS_EPSILON:
        return False, rs, re, rad0, rad1, 0.0
    ang = math.acos(max(-1.0, min(1.0, _dot(rs, re) / (rad0 * rad1))))
    if ang < TP_ANGLE_EPSILON:
        return False, rs, re, rad0, rad1, ang
    return True, rs, re, rad0, rad1, ang


@njit(cache=True)
def check_tangent_angle(circ, phi, binormal, r_vec, rad, rad0, rad1, ang, ang_max):
    """blendmath.c checkTangentAngle: the blend arc (radius vector ``r_vec`` of length ``rad`` where it meets
    the cut arc ``circ`` at angle ``phi``) meets it within the kink ``ang_max`` (rad) the servo cycle allows."""
    ua = np.empty(3)
    uc2 = np.empty(3)
    _cross(binormal, r_vec, ua)
    for a in range(3):
        ua[a] += r_vec[a] / rad * ((rad1 - rad0) / ang)
    _unit_eq(ua)
    _circle_tangent_at(circ, phi, uc2)
    return not (math.acos(max(-1.0, min(1.0, _dot(ua, uc2)))) > ang_max)


@njit(cache=True)
def init_blend_arc_from_prev(q, i_prev, i_cur, i_blend, consume, l_prev, center, rs, rad0, rad1, ang, start,
                             end, tan1, binormal, v_req, v_plan, a_max, cycle):
    """tp.c tpInitBlendArcFromPrev: the blend arc as segment row ``i_blend``, tangent-joined, at the blend
    speed ``v_plan`` (mm/s) and acceleration ``a_max`` (mm/s²), led by the consumed line's remainder
    ``l_prev`` (mm) when ``consume``; then finalised (tpFinalizeSegment)."""
    pv = q[i_prev]
    cu = q[i_cur]
    bl = q[i_blend]
    bl.kind = SEG_BLEND
    bl.line = cu.line
    # LinuxCNC tags the arc with the next line, so its time counts with the next row-bearing segment. When it
    # swallows the previous line, that line's MOVE rows go to the segment LinuxCNC showed executing under the
    # line's number: the blend arc before it if there is one, else this arc.
    bl.row0 = -1
    bl.row1 = -1
    if consume:
        ib = i_prev - 1
        if (ib >= 0 and q[ib].kind == SEG_BLEND and q[ib].row0 < 0 and q[ib].line == pv.line
                and q[ib].sync_after == 0):
            q[ib].row0 = pv.row0
            q[ib].row1 = pv.row1
        else:
            bl.row0 = pv.row0
            bl.row1 = pv.row1
    for a in range(3):
        bl.c[a] = center[a]
        bl.rt[a] = rs[a]
        bl.h[a] = 0.0
        bl.u[a] = tan1[a]
    # rp = binormal × rt points along the motion at the start
    _cross(binormal, rs, bl.rp)
    if _dot(bl.rp, tan1) < 0.0:
        for a in range(3):
            bl.rp[a] = -bl.rp[a]
    bl.radius = rad0
    bl.spiral = rad1 - rad0
    bl.angle = ang
    if consume:
        bl.lline = l_prev
        for a in range(3):
            bl.p0[a] = pv.p0[a]
    else:
        bl.lline = 0.0
        for a in range(3):
            bl.p0[a] = start[a]
    for a in range(3):
        bl.p1[a] = end[a]
    bl.target = rad0 * ang + bl.lline
    bl.nominal = bl.target
    bl.reqvel = v_req
    bl.inivel = v_plan
    bl.maxvel = v_plan
    bl.maxaccel = a_max
    bl.traverse = pv.traverse
    bl.term = TERM_TANGENT
    bl.tolerance = 0.0
    bl.blend_prev = 0
    bl.kink_vel = -1.0
    bl.kink_red = 0.0
    bl.kink_red_prev = 0.0
    bl.acc_ratio_tan = BLEND_ACC_RATIO_TANGENTIAL
    bl.finalized = 0
    bl.finalvel = 0.0
    bl.at_max = 0
    bl.sync_after = 0
    bl.dwell_after = 0.0
    finalize(bl, cycle)


@njit(cache=True)
def connect_blend_arc(pv, cu, consume, trim1, trim2):
    """tp.c tcConnectBlendArc (with tcSetLineXYZ / tcSetCircleXYZ): the previous segment ends where the arc
    starts (unless the arc consumed it), this one starts where it ends; the join is tangent."""
    if not consume:
        if pv.kind == SEG_LINE:
            trim_end(pv, trim1)
        else:
            trim_end(pv, trim1 / pv.angle * pv.target)
    if cu.kind == SEG_LINE:
        trim_start(cu, trim2)
    else:
        trim_start(cu, trim2 / cu.angle * cu.target)
    pv.term = TERM_TANGENT
    cu.blend_prev = 0


@njit(cache=True)
def blend_arc(q, i_prev, i_cur, i_blend, acc_bound, vel_bound, cycle, gap_cycles, vlimit, tan1, tan2):
    """tp.c tpCreateLineLineBlend / tpCreateLineArcBlend / tpCreateArcLineBlend / tpCreateArcArcBlend in one,
    step by step as they are (blendmath.c's geometry): a circular arc tangent to both segments within the
    tolerance, as fast as the normal acceleration allows. Writes the arc into row ``i_blend``, trims both
    segments when the arc wins tpChooseBestBlend, and returns (ok, consume_prev)."""
    pv = q[i_prev]
    cu = q[i_cur]
    line1 = pv.kind == SEG_LINE
    line2 = cu.kind == SEG_LINE
    (ok, P, u1, u2, binormal, normal, theta, phi, c1, c2, r1, r2, convex1, convex2, phi1_max, phi2_max,
     L1, L2) = blend_init3(q, i_prev, i_cur, tan1, tan2)
    if not ok:
        return False, False
    tol, a_max, a_n_max, v_req, v_goal = blend_param_kinematics(q, i_prev, i_cur, binormal, u1, u2, phi,
                                                                acc_bound, vel_bound)
    ok, v_plan, r_plan, d_plan = blend_compute_parameters(theta, phi, tol, L1, L2, a_max, a_n_max, v_goal)
    if not ok:
        return False, False
    # the blend circle's centre and how much of each segment it replaces
    if line1 and line2:
        center, trim1, trim2 = blend_find_points3(P, normal, theta, r_plan, d_plan)
    elif line1:
        ok, center, trim1, trim2 = blend_line_arc_post_process(P, c2, r2, convex2, r_plan, u1, binormal)
    elif line2:
        ok, center, trim1, trim2 = blend_arc_line_post_process(P, c1, r1, convex1, r_plan, u2, binormal)
    else:
        ok, center, trim1, trim2 = blend_arc_arc_post_process(P, c1, c2, r1, r2, convex1, convex2, r_plan,
                                                              binormal, normal)
    if not ok:
        return False, False
    if not line1 or not line2:
        hv = 0.0
        for a in range(3):
            hv += (center[a] - P[a]) ** 2
        if math.sqrt(hv) - r_plan > tol:            # the projected blend leaves the tolerance
            return False, False
        if not line1 and trim1 > phi1_max:
            return False, False
        if not line2 and trim2 > phi2_max:
            return False, False
    consume, l_prev = blend_check_consume(pv, trim1, v_plan, gap_cycles, cycle)
    ok, start, end = blend_stretch_points(pv, cu, trim1, trim2, tan1, tan2)
    if not ok:
        return False, False
    ok, rs, re, rad0, rad1, ang = arc_from_blend_points3(start, end, center)
    if not ok:
        return False, False
    if not line1 or not line2:
        ang_max = BLEND_ACC_RATIO_NORMAL * BLEND_KINK_FACTOR * a_max / (v_plan / cycle)
        if not line2 and not check_tangent_angle(cu, trim2, binormal, re, rad1, rad0, rad1, ang, ang_max):
            return False, False
        if not line1 and not check_tangent_angle(pv, pv.angle - trim1, binormal, rs, rad0, rad0, rad1, ang,
                                                 ang_max):
            return False, False
    init_blend_arc_from_prev(q, i_prev, i_cur, i_blend, consume, l_prev, center, rs, rad0, rad1, ang, start, end,
                             tan1, binormal, v_req, v_plan, a_max, cycle)
    if choose_best_blend(q, i_prev, i_cur, q[i_blend].maxvel, vlimit, tan1, tan2) != 2:
        return False, False
    connect_blend_arc(pv, cu, consume, trim1, trim2)
    return True, consume


# --------------------------------------------------------------------------- optimisation
@njit(cache=True)
def optimize(q, n, depth, vlimit, cycle):
    """tp.c tpRunOptimization: backward pass from the newest segment (which may still be cut, so it is
    assumed to stop halfway), through tangent joins only, at most ``depth`` segments or a few peaks."""
    hit_peaks = 0
    hit_non_tangent = False
    for x in range(1, depth + 2):
        ind = n - x
        if ind - 1 < 0:
            return
        tc = q[ind]
        pv = q[ind - 1]
        if pv.sync_after != 0:
            return
        if pv.term != TERM_TANGENT:
            if hit_non_tangent:
                return
            hit_non_tangent = True
            continue
        if tc.finalized == 0:
            acc = tangential_accel(tc)
            init_v = min(find_vpeak(acc, tc.target), max_target_vel(tc, vlimit))
            pv.finalvel = min(pv.maxvel, init_v)
            if pv.kink_vel >= 0.0:
                pv.finalvel = min(pv.finalvel, pv.kink_vel)
            tc.finalvel = 0.0
        else:
            acc_this = tangential_accel(tc)
            vs_back = math.sqrt(tc.finalvel * tc.finalvel + 2.0 * acc_this * tc.target)
            vf_limit_prev = pv.maxvel
            if pv.kink_vel >= 0.0:
                vf_limit_prev = min(vf_limit_prev, pv.kink_vel)
            vf_limit = min(tc.maxvel, vf_limit_prev)
            if vs_back >= vf_limit:
                vs_back = vf_limit
                pv.at_max = 1
            pv.finalvel = vs_back
        if tc.at_max != 0:
            hit_peaks += 1
        if hit_peaks > TP_OPTIMIZATION_CUTOFF:
            return


# --------------------------------------------------------------------------- the queue
@njit(cache=True)
def queue_kernel(segs, n_in, q, acc_bound, vel_bound, vlimit, cycle, kink_ratio, opt_depth, gap_cycles,
                 arc_blend):
    """Add the ``n_in`` input segments of ``segs`` to the queue ``q`` (capacity ≥ 2·n_in) the way
    LinuxCNC's tpAddLine/tpAddCircle do; returns the queue length. Input rows carry their own terminal
    condition and tolerance (the G61/G61.1/G64 mode in force) and ``sync_after`` (queue drains)."""
    n = 0
    tan1 = np.empty(3)
    tan2 = np.empty(3)
    for k in range(n_in):
        q[n] = segs[k]
        cur = n
        prev = n - 1
        if prev >= 0 and q[prev].sync_after == 0:
            # handlePrevTermCondition, handleModeChange
            set_term(q, prev, cur, q[prev].term)
            if q[prev].traverse != q[cur].traverse:
                set_term(q, prev, cur, TERM_STOP)
            if arc_blend:
                seg_tangent(q[prev], True, tan1)
                seg_tangent(q[cur], False, tan2)
                res = setup_tangent(q, prev, cur, acc_bound, cycle, kink_ratio, opt_depth, tan1, tan2)
                if res == 1:
                    done = False
                    if (q[prev].term == TERM_PARABOLIC and q[prev].kind != SEG_BLEND
                            and q[cur].kind != SEG_BLEND and q[prev].finalized == 0):
                        # the arc goes where ``cur`` is now; ``cur`` moves one slot on
                        q[n + 1] = q[cur]
                        ok, consume = blend_arc(q, prev, n + 1, n, acc_bound, vel_bound, cycle,
                                                gap_cycles, vlimit, tan1, tan2)
                        if ok:
                            done = True
                            if consume:
                                q[prev] = q[n]
                                q[n] = q[n + 1]
                                cur = n
                            else:
                                finalize(q[prev], cycle)
                                n += 1
                                cur = n
                        else:
                            q[n] = q[n + 1]
                    if not done:
                        choose_best_blend(q, prev, cur, 0.0, vlimit, tan1, tan2)
            finalize(q[prev], cycle)
        n = cur + 1
        optimize(q, n, opt_depth, vlimit, cycle)
    return n


# --------------------------------------------------------------------------- execution
@njit(cache=True)
def _real_target(q, i, vlimit):
    if i < 0:
        return 0.0
    return min(q[i].reqvel, max_target_vel(q[i], vlimit))


@njit(cache=True)
def _real_final(q, i, nx, vlimit):
    """tp.c tpGetRealFinalVel: zero unless the join is tangent."""
    if q[i].term != TERM_TANGENT:
        return 0.0
    v_next = _real_target(q, nx, vlimit) if nx >= 0 else 0.0
    return min(q[i].finalvel, min(_real_target(q, i, vlimit), v_next))


@njit(cache=True)
def trapezoidal_desired_vel(a_max, dx, v_final, v_cur, cycle_time):
    """blendmath.c findTrapezoidalDesiredVel: the speed from which braking at a_max ends at v_final."""
    dt = max(cycle_time, TP_TIME_EPSILON)
    t1 = v_final * v_final
    t2 = a_max * (2.0 * dx - v_cur * dt)
    adt = a_max * dt * 0.5
    t3 = adt * adt
    disc = t1 + t2 + t3
    v = -adt
    if disc > t3:
        v += math.sqrt(disc)
    return v


@njit(cache=True)
def end_condition(cycle, dtg, v_cur, v_f, a_max):
    """blendmath.c checkEndCondition: (time to the end, speed there) if the segment ends within reach."""
    big = TP_BIG_NUM * cycle
    v_avg = (v_cur + v_f) / 2.0
    dt = TP_TIME_EPSILON / 2.0
    if v_avg > TP_VEL_EPSILON:
        dt = max(dt, dtg / v_avg)
    else:
        if dtg > v_avg * cycle and dtg > TP_POS_EPSILON:
            return big, v_f
    a = (v_f - v_cur) / max(dt, TP_TIME_EPSILON)
    if a > a_max or a < -a_max:
        a = a_max if a > 0.0 else -a_max
        if a == 0.0:
            return big, v_f
        disc = (v_cur / a) ** 2 + 2.0 / a * dtg
        if disc < 0.0:
            return big, v_f
        if disc < TP_TIME_EPSILON * TP_TIME_EPSILON:
            dt = -v_cur / a
        elif a > 0.0:
            dt = -v_cur / a + math.sqrt(disc)
        else:
            dt = -v_cur / a - math.sqrt(disc)
        v_f = v_cur + dt * a
    return dt, v_f


@njit(cache=True)
def _update_cycle(q, i, nx, st, flags, vlimit, cycle):
    """tp.c tpUpdateCycle on segment i (``nx`` its successor or -1); returns the distance moved."""
    PROG, VEL, CT, TV, VBS = 0, 1, 2, 3, 4
    if flags[i, 2] == 0:                       # not blending_next
        st[i, VBS] = st[i, VEL]
    sg = q[i]
    ct = st[i, CT]
    acc = 0.0
    vdes = 0.0
    ok = False
    if flags[i, 3] != 0 and sg.term == TERM_TANGENT:     # ramp acceleration
        vf = _real_final(q, i, nx, vlimit)
        if vf >= TP_VEL_EPSILON:
            dx = sg.target - st[i, PROG]
            v_avg = (st[i, VEL] + vf) / 2.0
            dt = 1e-16
            if v_avg > TP_VEL_EPSILON:
                dt = max(dx / v_avg, 1e-16)
            acc = (vf - st[i, VEL]) / dt
            amax = tangential_accel(sg)
            acc = max(-amax, min(amax, acc))
            vdes = vf
            ok = True
    if not ok:
        v_target = _real_target(q, i, vlimit)
        v_final = _real_final(q, i, nx, vlimit)
        dx = sg.target - st[i, PROG]
        amax = tangential_accel(sg)
        maxnew = trapezoidal_desired_vel(amax, dx, v_final, st[i, VEL], ct)
        newvel = max(-v_target, min(v_target, maxnew))
        dt = max(ct, TP_TIME_EPSILON)
        acc = (newvel - st[i, VEL]) / dt
        acc = max(-amax, min(amax, acc))
        vdes = maxnew
    # tcUpdateDistFromAccel
    before = st[i, PROG]
    v_next = st[i, VEL] + acc * ct
    if v_next < 0.0:
        v_next = 0.0
        if sg.target - st[i, PROG] < st[i, VEL] * ct:
            st[i, PROG] = sg.target
    else:
        st[i, PROG] += (v_next + st[i, VEL]) * 0.5 * ct
        if st[i, PROG] > sg.target:
            st[i, PROG] = sg.target
    st[i, VEL] = v_next
    flags[i, 4] = 1 if (abs(vdes - v_next) < TP_VEL_EPSILON and acc < 0.0) else 0   # on_final_decel
    # tpCheckEndCondition
    dt_end, v_f = end_condition(cycle, sg.target - st[i, PROG], st[i, VEL], _real_final(q, i, nx, vlimit),
                                tangential_accel(sg))
    if dt_end < cycle:
        if dt_end < TP_TIME_EPSILON:
            dt_end = 0.0
        if not (flags[i, 0] != 0 and dt_end > 0.0):
            flags[i, 0] = 1                    # splitting
            st[i, CT] = dt_end
            st[i, TV] = v_f
    return st[i, PROG] - before


@njit(cache=True)
def _next_of(q, i, n):
    if i + 1 < n and q[i].sync_after == 0:
        return i + 1
    return -1


@njit(cache=True)
def activate_segment(q, tc, st, flags, vlimit, ramp_freq):
    """tp.c tpActivateSegment: a segment starts executing; a short tangent segment ramps its velocity
    (ARC_BLEND_RAMP_FREQ) instead of running a trapezoid."""
    flags[tc, 5] = 1
    length = q[tc].target - st[tc, 0]
    denom = st[tc, 1] + min(q[tc].finalvel, _real_target(q, tc, vlimit))
    seg_time = 2.0 * length / denom if denom > 0.0 else math.inf
    if (seg_time < 1.0 / max(ramp_freq, TP_TIME_EPSILON) and q[tc].traverse == 0
            and q[tc].term == TERM_TANGENT):
        flags[tc, 3] = 1
    flags[tc, 2] = 0
    flags[tc, 4] = 0


@njit(cache=True)
def handle_split_cycle(q, tc, nx, nx2, st, flags, vlimit, cycle, pos, p_a, p_b):
    """tp.c tpHandleSplitCycle: the cycle in which segment ``tc`` ends; the rest of the cycle runs the next
    segment ``nx`` (tangent or parabolic join). Moves ``pos``; returns (path distance mm, the segment shown
    executing)."""
    execd = tc
    moved = 0.0
    seg_point(q[tc], st[tc, 0], p_a)
    moved += q[tc].target - st[tc, 0]
    st[tc, 0] = q[tc].target
    seg_point(q[tc], st[tc, 0], p_b)
    for a in range(3):
        pos[a] += p_b[a] - p_a[a]
    flags[tc, 1] = 1
    if nx >= 0:
        term = q[tc].term
        if term == TERM_TANGENT or term == TERM_PARABOLIC:
            if term == TERM_TANGENT:
                st[nx, 2] = cycle - st[tc, 2]
                st[nx, 1] = st[tc, 3]
            seg_point(q[nx], st[nx, 0], p_a)
            moved += _update_cycle(q, nx, nx2, st, flags, vlimit, cycle)
            seg_point(q[nx], st[nx, 0], p_b)
            for a in range(3):
                pos[a] += p_b[a] - p_a[a]
        if not (term == TERM_STOP or term == TERM_EXACT or (st[tc, 2] > st[nx, 2] and term == TERM_TANGENT)):
            execd = nx
    return moved, execd


@njit(cache=True)
def handle_regular_cycle(q, tc, nx, st, flags, vlimit, cycle, pos, p_a, p_b):
    """tp.c tpHandleRegularCycle: one whole cycle of segment ``tc``, and of the next one too while a parabolic
    blend runs both (tcIsBlending). Moves ``pos``; returns (path distance mm, the segment shown executing)."""
    execd = tc
    moved = 0.0
    st[tc, 2] = cycle
    seg_point(q[tc], st[tc, 0], p_a)
    moved += _update_cycle(q, tc, nx, st, flags, vlimit, cycle)
    seg_point(q[tc], st[tc, 0], p_b)
    for a in range(3):
        pos[a] += p_b[a] - p_a[a]
    if q[tc].term == TERM_PARABOLIC:
        if nx >= 0:
            seg_tangent(q[tc], True, p_a)
            seg_tangent(q[nx], False, p_b)
            v_this, v_next, _ = blend_velocity(q, tc, nx, _real_target(q, tc, vlimit),
                                               _real_target(q, nx, vlimit), p_a, p_b)
            st[tc, 5] = v_this
            st[nx, 5] = v_next
        else:
            st[tc, 5] = 0.0
    if nx >= 0:
        # tcIsBlending: latched once the decelerating segment drops below its blend speed
        if (q[tc].term == TERM_PARABOLIC and flags[tc, 4] != 0 and st[tc, 1] < st[tc, 5]):
            flags[tc, 2] = 1
        if flags[tc, 2] != 0:
            seg_point(q[nx], st[nx, 0], p_a)
            moved += _update_cycle(q, nx, -1, st, flags, vlimit, cycle)
            seg_point(q[nx], st[nx, 0], p_b)
            for a in range(3):
                pos[a] += p_b[a] - p_a[a]
            if not (st[tc, 1] > st[nx, 1]):
                execd = nx
    return moved, execd


@njit(cache=True)
def execute_kernel(q, n, vlimit, cycle, ramp_freq, max_cycles, out_seg, out_pos, out_dist):
    """Run the queue servo cycle by servo cycle. Per cycle k: ``out_seg[k]`` the executing segment,
    ``out_pos[k]`` the commanded position at its end, ``out_dist[k]`` the path distance covered.
    Returns the number of cycles (-1 if ``max_cycles`` was too small). Queue drains (``sync_after``)
    restart from rest at the next cycle; dwells add whole cycles at rest."""
    st = np.zeros((n, 6))
    # flags: splitting, remove, blending_next, ramp, on_final_decel, active
    flags = np.zeros((n, 6), dtype=np.int64)
    for i in range(n):
        st[i, 2] = cycle
    pos = np.empty(3)
    p_a = np.empty(3)
    p_b = np.empty(3)
    pos[0] = 0.0
    pos[1] = 0.0
    pos[2] = 0.0
    if n > 0:
        seg_point(q[0], 0.0, pos)
    k = 0
    i = 0
    while i < n:
        if k >= max_cycles:
            return -1
        tc = i
        nx = _next_of(q, tc, n)
        nx2 = _next_of(q, nx, n) if nx >= 0 else -1
        if flags[tc, 5] == 0:
            activate_segment(q, tc, st, flags, vlimit, ramp_freq)
        if flags[tc, 0] != 0:
            moved, execd = handle_split_cycle(q, tc, nx, nx2, st, flags, vlimit, cycle, pos, p_a, p_b)
        else:
            moved, execd = handle_regular_cycle(q, tc, nx, st, flags, vlimit, cycle, pos, p_a, p_b)
        out_seg[k] = execd
        out_dist[k] = moved
        for a in range(3):
            out_pos[k, a] = pos[a]
        k += 1
        if flags[tc, 1] != 0:
            i += 1
            if q[tc].sync_after != 0:
                # dwell: whole cycles at rest
                nd = int(math.ceil(q[tc].dwell_after / cycle - 1e-9)) if q[tc].dwell_after > 0.0 else 0
                for _ in range(nd):
                    if k >= max_cycles:
                        return -1
                    out_seg[k] = tc
                    out_dist[k] = 0.0
                    for a in range(3):
                        out_pos[k, a] = pos[a]
                    k += 1
    return k
