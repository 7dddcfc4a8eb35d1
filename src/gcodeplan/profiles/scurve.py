"""Jerk-limited (seven-phase, "double-S") profiles: the numba kernels.

Notation: distance h (mm), limits V (mm/s), A (mm/s²), J (mm/s³), end speeds v0, v1 (mm/s), acceleration zero
at both ends. The profile is

    +J for tj1, 0 for ta1, -J for tj1   (v0 -> vp, the "accel part")
    0 for cruise_t                      (at vp)
    -J for tj2, 0 for ta2, +J for tj2   (vp -> v1, the "decel part")

with the peak speed vp >= max(v0, v1).

Ramp (one part) from va to vb, dv = |vb - va| (seed optimal-motion-jerk-braking.es, "perfil S modificado"):
    dv >= A²/J: tj = A/J, ta = dv/A - A/J   (A is reached: constant-acceleration phase)
    dv <  A²/J: tj = sqrt(dv/J), ta = 0      (pure S, peak accel sqrt(J·dv))
    ramp time T(dv) = 2·tj + ta, ramp distance (va + vb)/2 · T(dv)
(the velocity of a ramp is point-symmetric about its midpoint, so its mean is (va + vb)/2).

Solving for vp
--------------
If the distance with vp = V is at most h, vp = V and the rest is cruise. Otherwise there is no cruise and vp
solves D(vp) = R(v0 -> vp) + R(vp -> v1) = h. Write vp = vh + s² (vh = max(v0, v1), dv = vh - vl):

    D(s) = (vl + vh + s²)/2 · T(dv + s²) + (2·vh + s²)/2 · T(s²)

Both T(s²) (linear in s, then convex, C¹ at s = A/sqrt(J)) and T(dv + s²) (a Euclidean norm, then convex, C¹ at
dv + s² = A²/J) are convex, non-decreasing and non-negative in s; so are the speed factors; a product of such
functions is convex. D is therefore convex and strictly increasing on s >= 0, and Newton's method started to the
right of the root decreases monotonically onto it with no safeguard needed (the tangent of a convex function lies
below it). The start point comes from lower bounds of D that invert in closed form, so it is always right of the
root. This is a bracketed root find of a monotone function: exact to rounding, never a wrong branch. When both
parts reach A (h >= D(A/sqrt(J))), D is quadratic in s² and solved in closed form instead; Newton is left for the
short moves where the vh side is a pure S (typically 3-5 steps).

Time-optimality (within forward-only profiles whose speed rises to vp and falls to v1, never dipping below
min(v0, v1)): for a fixed vp each part is the fastest change of speed under A and J (bang-zero-bang jerk), and the
cruise covers the rest. With cruise, the total time is T(vp) = Ta + Td + (h - Da - Dd)/vp, and
d/dvp [Ta - Da/vp] = Ta'·(vp - va)/(2vp) - Ta/(2vp), which is -Ta/(4vp) (pure S) or -A/(2·J·vp) (with constant
acceleration): always negative. So a higher peak is always faster; the fastest profile has the largest feasible
vp: either V (with cruise) or the root of D(vp) = h (no cruise). The test suite checks this against ruckig.

Feasibility: the least distance of such a profile is R(vl -> vh) (vp = vh, no cruise). Below it, v1 cannot be
reached moving forward only without dipping below an end speed; the kernels return NaN.
"""
from __future__ import annotations

import math

import numba
import numpy as np

# Slack when comparing a distance with the least distance a profile needs, so that an end speed computed by
# scurve_max_end_speed_kernel (v0 + x, rounded) stays feasible when handed back to the duration kernel. The least
# distance is ill-conditioned in the speeds (it grows like sqrt(v1 - v0)), so the slack is a few ulps of the speed
# (SPEED_ULPS · eps · v) rather than a relative distance; FEASIBILITY_RTOL covers the distance's own rounding.
FEASIBILITY_RTOL = 1e-12
SPEED_ULPS = 8.0
EPS = 2.220446049250313e-16
_NEWTON_MAX_ITER = 100


@numba.njit(cache=True)
def ramp_times_kernel(dv: float, a_max: float, j_max: float) -> tuple[float, float]:
    """(tj, ta): jerk-phase and constant-acceleration-phase times of the fastest change of speed by dv >= 0,
    acceleration zero at both ends. tj = A/J, ta = dv/A - A/J if dv >= A²/J, else tj = sqrt(dv/J), ta = 0."""
    if dv * j_max >= a_max * a_max:
        return a_max / j_max, max(dv / a_max - a_max / j_max, 0.0)
    return math.sqrt(dv / j_max), 0.0


@numba.njit(cache=True)
def ramp_time_kernel(dv: float, a_max: float, j_max: float) -> float:
    """s, time of the fastest change of speed by dv >= 0 with a = 0 at both ends: 2·tj + ta."""
    tj, ta = ramp_times_kernel(dv, a_max, j_max)
    return 2.0 * tj + ta


@numba.njit(cache=True)
def ramp_distance_kernel(v_from: float, v_to: float, a_max: float, j_max: float) -> float:
    """mm covered by the fastest change of speed from v_from to v_to (either direction): (v_from + v_to)/2 · T."""
    return 0.5 * (v_from + v_to) * ramp_time_kernel(abs(v_to - v_from), a_max, j_max)


@numba.njit(cache=True)
def _ramp_time_s(dv: float, s: float, a_max: float, sqrt_j: float) -> tuple[float, float]:
    """T(dv + s²) and dT/ds, for the Newton iteration on s."""
    x = dv + s * s
    if x * sqrt_j * sqrt_j >= a_max * a_max:
        return x / a_max + a_max / (sqrt_j * sqrt_j), 2.0 * s / a_max
    r = math.sqrt(x)
    if r > 0.0:
        return 2.0 * r / sqrt_j, 2.0 * s / (sqrt_j * r)
    return 0.0, 2.0 / sqrt_j


@numba.njit(cache=True)
def _peak_distance(s: float, vl: float, vh: float, dv: float, a_max: float, sqrt_j: float) -> tuple[float, float]:
    """D(s) and D'(s) (see the module docstring): distance of the accel + decel parts with peak vh + s²."""
    tl, dtl = _ramp_time_s(dv, s, a_max, sqrt_j)
    th, dth = _ramp_time_s(0.0, s, a_max, sqrt_j)
    fl = 0.5 * (vl + vh + s * s)
    fh = 0.5 * (2.0 * vh + s * s)
    d = fl * tl + fh * th
    dd = s * tl + fl * dtl + s * th + fh * dth
    return d, dd


@numba.njit(cache=True)
def _ramp_fit_distance(v_from: float, dv: float, up: bool, h: float, a_max: float, j_max: float):
    """(tj, ta) of one ramp starting at v_from whose speed change is dv up to rounding, re-fitted so that its
    distance is exactly h. Used when h is short of the ramp distance by the feasibility slack only: the ramp
    distance grows like sqrt(dv), so a few ulps of speed can be 1e-7 mm of position; it is position that must
    come out exact. Newton steps on s = sqrt(dv), where the distance (v_from ± s²/2)·T(s²) is smooth."""
    sqrt_j = math.sqrt(j_max)
    sign = 1.0 if up else -1.0
    s = math.sqrt(dv)
    for _ in range(3):
        t, dt = _ramp_time_s(0.0, s, a_max, sqrt_j)
        speed = v_from + 0.5 * sign * s * s
        f = speed * t - h
        df = sign * s * t + speed * dt
        if f == 0.0 or not df > 0.0:
            break
        s = max(s - f / df, 0.0)
    if s * sqrt_j >= a_max:
        return a_max / j_max, max(s * s / a_max - a_max / j_max, 0.0)
    return s / sqrt_j, 0.0


@numba.njit(cache=True)
def _cubic_root(p: float, q: float) -> float:
    """The real root s >= 0 of s³ + p·s = q for p >= 0, q >= 0 (Cardano, written without cancellation:
    s = u - v with u·v = p/3, u³ - v³ = q, hence s = q / (u² + u·v + v²))."""
    if q <= 0.0:
        return 0.0
    u = np.cbrt(0.5 * q + math.sqrt(0.25 * q * q + p * p * p / 27.0))
    v = p / (3.0 * u)
    return q / (u * u + u * v + v * v)


@numba.njit(cache=True)
def _valid(distance, v_max, a_max, j_max, v_start, v_end) -> bool:
    # NaN fails every comparison, so NaN inputs are invalid too
    if not (distance >= 0.0 and v_max > 0.0 and a_max > 0.0 and j_max > 0.0):
        return False
    if not (v_start >= 0.0 and v_end >= 0.0):
        return False
    lim = v_max * (1.0 + FEASIBILITY_RTOL)
    return v_start <= lim and v_end <= lim


@numba.njit(cache=True)
def scurve_phases_kernel(distance: float, v_max: float, a_max: float, j_max: float,
                         v_start: float, v_end: float):
    """Time-optimal forward-only double-S profile.

    Returns ((t1, ..., t7), (j1, ..., j7), peak_v): phase durations (s), their jerks (mm/s³:
    +J, 0, -J, 0, -J, 0, +J) and the peak speed (mm/s). Acceleration is 0 at both ends; the acceleration during
    phase k is the running sum of j·t. All NaN when no forward-only motion exists or an argument is invalid.
    """
    nan = math.nan
    jerks = (j_max, 0.0, -j_max, 0.0, -j_max, 0.0, j_max)
    if not _valid(distance, v_max, a_max, j_max, v_start, v_end):
        return (nan, nan, nan, nan, nan, nan, nan), jerks, nan
    v0 = min(v_start, v_max)
    v1 = min(v_end, v_max)
    h = distance
    vh = max(v0, v1)
    vl = min(v0, v1)
    dv = vh - vl
    d_min = ramp_distance_kernel(vl, vh, a_max, j_max)
    dv_lo = max(dv - SPEED_ULPS * EPS * vh, 0.0)
    if h < 0.5 * (vl + vh) * ramp_time_kernel(dv_lo, a_max, j_max) * (1.0 - FEASIBILITY_RTOL):
        return (nan, nan, nan, nan, nan, nan, nan), jerks, nan

    cruise_t = 0.0
    if vh >= v_max:
        # an end speed is at the limit: one monotone ramp and cruise at V
        vp = v_max
        if h > d_min:
            cruise_t = (h - d_min) / vp
        tj1, ta1 = ramp_times_kernel(vp - v0, a_max, j_max)
        tj2, ta2 = ramp_times_kernel(vp - v1, a_max, j_max)
        if h < d_min:
            if v0 < v1:
                tj1, ta1 = _ramp_fit_distance(v0, dv, True, h, a_max, j_max)
            else:
                tj2, ta2 = _ramp_fit_distance(v0, dv, False, h, a_max, j_max)
    else:
        d_vmax = ramp_distance_kernel(v0, v_max, a_max, j_max) + ramp_distance_kernel(v_max, v1, a_max, j_max)
        if h >= d_vmax:
            vp = v_max
            cruise_t = (h - d_vmax) / vp
            tj1, ta1 = ramp_times_kernel(vp - v0, a_max, j_max)
            tj2, ta2 = ramp_times_kernel(vp - v1, a_max, j_max)
        else:
            sqrt_j = math.sqrt(j_max)
            extra = h - d_min
            c = a_max * a_max / j_max
            # with peak vh + c both parts reach A (the vl side changes by dv + c >= c)
            d_c = 0.5 * (vl + vh + c) * ((dv + c) / a_max + a_max / j_max) + (vh + 0.5 * c) * 2.0 * a_max / j_max
            if extra <= 0.0:
                s = 0.0
            elif h >= d_c:
                # both parts reach A: D is quadratic in x = s² = vp - vh,
                # x²/A + (2·vh/A + A/J)·x + C' = 0, C' = (vh² - vl²)/(2A) + (3·vh + vl)·A/(2J) - h <= 0
                b = 2.0 * vh / a_max + a_max / j_max
                c1 = dv * (vh + vl) / (2.0 * a_max) + (3.0 * vh + vl) * a_max / (2.0 * j_max) - h
                x = -2.0 * c1 / (b + math.sqrt(b * b - 4.0 * c1 / a_max))
                s = math.sqrt(max(x, c))
            else:
                # The vh side is a pure S (s < A/sqrt(J)). Start right of the root: D(s) - D(0) >=
                # (2vh + s²)·s/sqrt(J) and D(s) - D(0) >= vh·s²/A + s⁴/(2A) (T(s²) >= 2s/sqrt(J) by AM-GM,
                # T(s²) >= s²/A); each inverts in closed form.
                s_cubic = _cubic_root(2.0 * vh, extra * sqrt_j)
                disc = math.sqrt(vh * vh + 2.0 * a_max * extra)
                s_quad = math.sqrt(2.0 * a_max * extra / (vh + disc))
                s = min(s_cubic, s_quad, a_max / sqrt_j, math.sqrt(v_max - vh))
                for _ in range(_NEWTON_MAX_ITER):
                    d, dd = _peak_distance(s, vl, vh, dv, a_max, sqrt_j)
                    f = d - h
                    if f <= 0.0 or dd <= 0.0:
                        break
                    step = f / dd
                    s_next = s - step
                    if s_next <= 0.0:
                        s_next = 0.5 * s
                    s = s_next
                    # quadratic convergence: after a step below 1e-8·s the error is ~(1e-8)² relative
                    if step <= 1e-8 * s:
                        break
            vp = vh + s * s
            # the vh-side ramp has dv = s² exactly: take its times from s to keep digits when s is tiny
            if s * sqrt_j >= a_max:
                tjh, tah = a_max / j_max, max(s * s / a_max - a_max / j_max, 0.0)
            else:
                tjh, tah = s / sqrt_j, 0.0
            if extra < 0.0:
                tjl, tal = _ramp_fit_distance(v0, dv, v0 < v1, h, a_max, j_max)
            else:
                tjl, tal = ramp_times_kernel(dv + s * s, a_max, j_max)
            if v0 >= v1:
                tj1, ta1, tj2, ta2 = tjh, tah, tjl, tal
            else:
                tj1, ta1, tj2, ta2 = tjl, tal, tjh, tah
    return (tj1, ta1, tj1, cruise_t, tj2, ta2, tj2), jerks, vp


@numba.njit(cache=True)
def scurve_duration_kernel(distance: float, v_max: float, a_max: float, j_max: float,
                           v_start: float, v_end: float) -> float:
    """s, duration of the time-optimal forward-only double-S profile; NaN if none exists (or bad arguments)."""
    t, _, _ = scurve_phases_kernel(distance, v_max, a_max, j_max, v_start, v_end)
    return t[0] + t[1] + t[2] + t[3] + t[4] + t[5] + t[6]


@numba.njit(cache=True)
def scurve_max_end_speed_kernel(distance: float, v_max: float, a_max: float, j_max: float,
                                v_start: float) -> float:
    """mm/s, the highest end speed reachable over `distance` from v_start moving forward, a = 0 at both ends,
    under V, A, J. The jerk-limited replacement of sqrt(v² + 2·a·d).

    It is the speed v1 >= v_start with R(v_start -> v1) = distance (or V if that is reachable): with
    x = v1 - v_start, (2·v_start + x)/2 · T(x) = h, solved in closed form per case:
    x >= A²/J: x²/A + (2·v0/A + A/J)·x + 2·v0·A/J - 2h = 0 (quadratic);
    x <  A²/J: with s = sqrt(x), s³ + 2·v0·s = h·sqrt(J) (Cardano). NaN for invalid arguments.
    """
    if not _valid(distance, v_max, a_max, j_max, v_start, 0.0):
        return math.nan
    v0 = min(v_start, v_max)
    h = distance
    if h >= ramp_distance_kernel(v0, v_max, a_max, j_max):
        return v_max
    c = a_max * a_max / j_max
    # distance of the ramp that just reaches A
    d_c = (2.0 * v0 + c) * a_max / j_max
    if h >= d_c:
        b = 2.0 * v0 / a_max + a_max / j_max
        c0 = 2.0 * v0 * a_max / j_max - 2.0 * h    # <= 0 here
        x = -2.0 * c0 / (b + math.sqrt(b * b - 4.0 * c0 / a_max))
    else:
        s = _cubic_root(2.0 * v0, h * math.sqrt(j_max))
        x = s * s
    return min(v0 + x, v_max)


@numba.njit(cache=True)
def scurve_max_start_speed_kernel(distance: float, v_max: float, a_max: float, j_max: float,
                                  v_end: float) -> float:
    """mm/s, the highest start speed from which v_end can be reached over `distance` (backward pass). By time
    reversal a ramp down from v to v_end covers the same distance as a ramp up from v_end to v."""
    return scurve_max_end_speed_kernel(distance, v_max, a_max, j_max, v_end)


@numba.njit(cache=True)
def scurve_min_distance_kernel(v_max: float, a_max: float, j_max: float, v_start: float, v_end: float) -> float:
    """mm, the least distance of a forward-only profile from v_start to v_end (one monotone ramp)."""
    return ramp_distance_kernel(min(v_start, v_max), min(v_end, v_max), a_max, j_max)


@numba.njit(cache=True)
def scurve_state_kernel(t: float, durations, jerks, v_start: float):
    """(position mm, velocity mm/s, acceleration mm/s², jerk mm/s³) at time t of a piecewise-constant-jerk
    profile starting at position 0, speed v_start, acceleration 0 (e.g. the output of scurve_phases_kernel).
    t is clamped into [0, total duration]."""
    p = 0.0
    v = v_start
    a = 0.0
    n = len(durations)
    if t < 0.0:
        t = 0.0
    for k in range(n):
        dt = durations[k]
        j = jerks[k]
        if t <= dt or k == n - 1:
            tau = min(t, dt)
            return (p + v * tau + a * tau * tau / 2.0 + j * tau * tau * tau / 6.0,
                    v + a * tau + j * tau * tau / 2.0, a + j * tau, j)
        p += v * dt + a * dt * dt / 2.0 + j * dt * dt * dt / 6.0
        v += a * dt + j * dt * dt / 2.0
        a += j * dt
        t -= dt
    return p, v, a, 0.0


@numba.njit(cache=True)
def scurve_position_kernel(t: float, distance: float, v_max: float, a_max: float, j_max: float,
                           v_start: float, v_end: float) -> float:
    """mm, position at time t of the time-optimal double-S profile (solves the profile each call)."""
    dur, jerks, _ = scurve_phases_kernel(distance, v_max, a_max, j_max, v_start, v_end)
    p, _, _, _ = scurve_state_kernel(t, dur, jerks, v_start)
    return p


@numba.njit(cache=True)
def _scurve_durations_loop(distance, v_max, a_max, j_max, v_start, v_end, out):
    for i in range(out.shape[0]):
        out[i] = scurve_duration_kernel(distance[i], v_max[i], a_max[i], j_max[i], v_start[i], v_end[i])
    return out


@numba.njit(cache=True)
def _scurve_max_end_loop(distance, v_max, a_max, j_max, v_start, out):
    for i in range(out.shape[0]):
        out[i] = scurve_max_end_speed_kernel(distance[i], v_max[i], a_max[i], j_max[i], v_start[i])
    return out


# --------------------------------------------------------------------------- Python API
def scurve(distance, v_max, a_max, j_max, v_start=0.0, v_end=0.0):
    """The time-optimal forward-only jerk-limited profile (seven-phase double-S, a = 0 at both ends).

    distance mm >= 0; v_max mm/s > 0 (inf allowed); a_max mm/s² > 0; j_max mm/s³ > 0; 0 <= v_start, v_end <=
    v_max. Raises ValueError naming a bad argument, InfeasibleProfile when v_end cannot be reached within the
    distance moving forward only. Phases are (duration s, jerk mm/s³)."""
    from .core import InfeasibleProfile, build_profile, check_distance, check_limit, check_speed

    h = check_distance("distance", distance)
    vm = check_limit("v_max", v_max, allow_inf=True)
    am = check_limit("a_max", a_max)
    jm = check_limit("j_max", j_max)
    v0 = check_speed("v_start", v_start, vm)
    v1 = check_speed("v_end", v_end, vm)
    dur, jerks, vp = scurve_phases_kernel(h, vm, am, jm, v0, v1)
    if math.isnan(vp):
        need = scurve_min_distance_kernel(vm, am, jm, v0, v1)
        raise InfeasibleProfile(
            f"cannot go from v_start = {v0:g} to v_end = {v1:g} within distance = {h:g} moving forward only "
            f"under a_max = {am:g}, j_max = {jm:g}: that needs at least {need:.9g}")
    return build_profile("scurve", "jerk", np.array(dur), np.array(jerks), None, v0,
                         limits={"v_max": vm, "a_max": am, "j_max": jm}, distance=h, peak_velocity=vp, v_end=v1)


def scurve_durations(distance, v_max, a_max, j_max, v_start, v_end) -> np.ndarray:
    """Durations (s) of many time-optimal S-curves at once from broadcastable arrays; NaN where no forward-only
    motion exists. Raises ValueError for NaN or out-of-range arguments (naming the argument)."""
    from .core import batch_arrays, check_array

    shape, (h, vm, am, jm, v0, v1) = batch_arrays(distance=distance, v_max=v_max, a_max=a_max, j_max=j_max,
                                                  v_start=v_start, v_end=v_end)
    check_array("distance", h, positive=False, allow_inf=False)
    check_array("v_max", vm, positive=True, allow_inf=True)
    check_array("a_max", am, positive=True, allow_inf=False)
    check_array("j_max", jm, positive=True, allow_inf=False)
    check_array("v_start", v0, positive=False, allow_inf=False)
    check_array("v_end", v1, positive=False, allow_inf=False)
    if (v0 > vm).any():
        raise ValueError("v_start exceeds v_max")
    if (v1 > vm).any():
        raise ValueError("v_end exceeds v_max")
    out = np.empty(h.shape[0])
    _scurve_durations_loop(h, vm, am, jm, v0, v1, out)
    return out.reshape(shape)
