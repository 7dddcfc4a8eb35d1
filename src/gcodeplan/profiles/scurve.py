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
solves D(vp) = R(v0 -> vp) + R(vp -> v1) = h. Write vp = vh + s² (vh = max(v0, v1), vl = min(v0, v1),
dv = vh - vl, sigma = vl + vh, c = A²/J):

    D(s) = (sigma + s²)/2 · T(dv + s²) + (2·vh + s²)/2 · T(s²)

Both T(s²) (linear in s, then convex, C¹ at s = A/sqrt(J)) and T(dv + s²) (a Euclidean norm, then convex, C¹ at
dv + s² = c) are convex, non-decreasing and non-negative in s; so are the speed factors; a product of such
functions is convex. D is therefore convex and strictly increasing on s >= 0: the root is unique, and Newton's
method started to the right of it decreases monotonically onto it with no safeguard needed (the tangent of a
convex function lies below it). This is a bracketed root find of a monotone function: exact to rounding, never
a wrong branch. Cases, cheapest first:

* both parts reach A (h >= D(A/sqrt(J))): D is quadratic in s², solved in closed form;
* otherwise the vh part is a pure S, T(s²) = 2s/sqrt(J) exactly. With v0 = v1 (dv = 0) both parts are that
  pure S and (D(s) - D(0))·sqrt(J) = 4·vh·s + 2·s³: a cubic, solved in closed form (Cardano);
* otherwise whether the vl part reaches A is decided once, by evaluating D at the switch point
  s_t = sqrt(c - dv) (dv >= c: it always does), and Newton runs on that part's smooth formula, which is convex
  and increasing on all of s >= 0 and equals D where the root is:
    vl part reaches A:  2A·(D(s) - h) = s⁴ + q·s³ + (2·vh + c)·s² + 2·q·vh·s - K, q = 2A/sqrt(J),
                        K = 2A·(h - D(0)) - sigma·(q/2 - sqrt(dv))² (the last term only when dv < c, where
                        D(0) is a pure S): a polynomial with non-negative coefficients, no square root;
    vl part pure S:     (D(s) - D(0))·sqrt(J) = s²·(sigma/(r + r0) + r) + (2·vh + s²)·s, r = sqrt(dv + s²),
                        r0 = sqrt(dv) ((sigma + s²)·r - sigma·r0 rewritten without cancellation): one square
                        root per step.
  The start point is right of the root: T(dv + s²) >= T(dv) and T(dv + s²) >= T(s²) give
  D(s) - D(0) >= (vh + s²)·T(s²) = 2·(vh + s²)·s/sqrt(J), a cubic inverted by Cardano, capped by the
  case bounds (s < A/sqrt(J), s < sqrt(V - vh), and s < s_t for a pure-S vl part). Typically 3-4 steps.

Batch (scurve_durations): one njit pass checks the arguments and solves each element; per block of elements the
ones that need Newton are set aside and iterated side by side, which turns the latency-bound chain of square
roots and divisions of one iteration into vectorised throughput. The arithmetic of each element is the scalar
kernel's, step for step: the results are bit-identical to scurve_duration_kernel.

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

from .._jit import njit
import numpy as np

# Slack when comparing a distance with the least distance a profile needs, so that an end speed computed by
# scurve_max_end_speed_kernel (v0 + x, rounded) stays feasible when handed back to the duration kernel. The least
# distance is ill-conditioned in the speeds (it grows like sqrt(v1 - v0)), so the slack is a few ulps of the speed
# (SPEED_ULPS · eps · v) rather than a relative distance; FEASIBILITY_RTOL covers the distance's own rounding.
FEASIBILITY_RTOL = 1e-12
SPEED_ULPS = 8.0
EPS = 2.220446049250313e-16
_NEWTON_MAX_ITER = 100
# The kernels use error_model="numpy" (no division-by-zero checks, which cost a branch per division and an
# exception path in the hot loop): every divisor is non-zero for valid arguments, and the kernels answer invalid
# arguments with NaN before dividing.


@njit(cache=True, error_model="numpy")
def ramp_times_kernel(dv: float, a_max: float, j_max: float) -> tuple[float, float]:
    """(tj, ta): jerk-phase and constant-acceleration-phase times of the fastest change of speed by dv >= 0,
    acceleration zero at both ends. tj = A/J, ta = dv/A - A/J if dv >= A²/J, else tj = sqrt(dv/J), ta = 0."""
    if dv * j_max >= a_max * a_max:
        return a_max / j_max, max(dv / a_max - a_max / j_max, 0.0)
    return math.sqrt(dv / j_max), 0.0


@njit(cache=True, error_model="numpy")
def ramp_time_kernel(dv: float, a_max: float, j_max: float) -> float:
    """s, time of the fastest change of speed by dv >= 0 with a = 0 at both ends: 2·tj + ta."""
    tj, ta = ramp_times_kernel(dv, a_max, j_max)
    return 2.0 * tj + ta


@njit(cache=True, error_model="numpy")
def ramp_distance_kernel(v_from: float, v_to: float, a_max: float, j_max: float) -> float:
    """mm covered by the fastest change of speed from v_from to v_to (either direction): (v_from + v_to)/2 · T."""
    return 0.5 * (v_from + v_to) * ramp_time_kernel(abs(v_to - v_from), a_max, j_max)


@njit(cache=True, error_model="numpy")
def _ramp_time_s(dv: float, s: float, a_max: float, sqrt_j: float) -> tuple[float, float]:
    """T(dv + s²) and dT/ds, for the Newton iteration on s."""
    x = dv + s * s
    if x * sqrt_j * sqrt_j >= a_max * a_max:
        return x / a_max + a_max / (sqrt_j * sqrt_j), 2.0 * s / a_max
    r = math.sqrt(x)
    if r > 0.0:
        return 2.0 * r / sqrt_j, 2.0 * s / (sqrt_j * r)
    return 0.0, 2.0 / sqrt_j


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
def _cubic_root(p: float, q: float) -> float:
    """The real root s >= 0 of s³ + p·s = q for p >= 0, q >= 0 (Cardano, written without cancellation:
    s = u - v with u·v = p/3, u³ - v³ = q, hence s = q / (u² + u·v + v²))."""
    if q <= 0.0:
        return 0.0
    u = np.cbrt(0.5 * q + math.sqrt(0.25 * q * q + p * p * p / 27.0))
    v = p / (3.0 * u)
    return q / (u * u + u * v + v * v)


@njit(cache=True, error_model="numpy")
def _valid(distance, v_max, a_max, j_max, v_start, v_end) -> bool:
    # NaN fails every comparison, so NaN inputs are invalid too
    if not (distance >= 0.0 and v_max > 0.0 and a_max > 0.0 and j_max > 0.0):
        return False
    if not (v_start >= 0.0 and v_end >= 0.0):
        return False
    lim = v_max * (1.0 + FEASIBILITY_RTOL)
    return v_start <= lim and v_end <= lim


# What _solve_head leaves to do: nothing, or Newton on one of the two no-cruise formulas (module docstring).
_DONE = 0
_NEWTON_QUARTIC = 1     # vl part reaches A: polynomial in s
_NEWTON_PURE_S = 2      # vl part pure S: one square root per step


@njit(cache=True, error_model="numpy")
def _quartic_step(s: float, q: float, b2: float, b1: float, k: float, _unused: float) -> tuple[float, bool]:
    """One Newton step on 2A·(D(s) - h) = s⁴ + q·s³ + b2·s² + b1·s - k from s right of the root.
    Returns (next s, whether to go on). Branch-free, so that the batch can run many of them in lockstep."""
    f = ((s + q) * s + b2) * s * s + b1 * s - k
    df = ((4.0 * s + 3.0 * q) * s + 2.0 * b2) * s + b1
    return _newton_update(s, f, df)


@njit(cache=True, error_model="numpy")
def _pure_s_step(s: float, dv: float, sigma: float, r0: float, two_vh: float, gain: float) -> tuple[float, bool]:
    """One Newton step on (D(s) - D(0))·sqrt(J) - gain = s²·(sigma/(r + r0) + r) + (2·vh + s²)·s - gain,
    r = sqrt(dv + s²), from s right of the root. Returns (next s, whether to go on)."""
    x = s * s
    r = math.sqrt(dv + x)
    f = x * (sigma / (r + r0) + r) + (two_vh + x) * s - gain
    # d/ds of (sigma + s²)·r is 2s·r + (sigma + s²)·s/r
    df = s * (2.0 * r + (sigma + x) / r) + two_vh + 3.0 * x
    return _newton_update(s, f, df)


@njit(cache=True, error_model="numpy")
def _newton_update(s: float, f: float, df: float) -> tuple[float, bool]:
    # f <= 0: at the root to rounding (the iterates approach it from the right)
    moving = (f > 0.0) & (df > 0.0)
    step = f / df
    s_next = s - step
    s_next = s_next if s_next > 0.0 else 0.5 * s
    # quadratic convergence: after a step below 1e-8·s the error is ~(1e-8)² relative
    return (s_next if moving else s), moving & (step > 1e-8 * s_next)


@njit(cache=True, error_model="numpy")
def _newton_setup(extra: float, vl: float, vh: float, dv: float, a_max: float, j_max: float, s_cap: float):
    """(what, s, p1..p5) for the no-cruise peak s = sqrt(vp - vh) when the vh part is a pure S; extra = h - D(0)
    > 0 (mm), s_cap an upper bound of the root (min(A/sqrt(J), sqrt(V - vh))). what = _DONE: s is the root
    (v0 = v1, Cardano); else Newton is to run from s with _quartic_step or _pure_s_step and parameters p1..p5."""
    sqrt_j = math.sqrt(j_max)
    gain = extra * sqrt_j          # (D(s) - D(0))·sqrt(J) at the root
    if dv == 0.0:
        # 4·vh·s + 2·s³ = gain
        return _DONE, _cubic_root(2.0 * vh, 0.5 * gain), 0.0, 0.0, 0.0, 0.0, 0.0
    c = a_max * a_max / j_max
    sigma = vl + vh
    r0 = math.sqrt(dv)
    # 2·(vh + s²)·s <= gain at the root: Cardano on the bound, right of the root
    s = min(_cubic_root(vh, 0.5 * gain), s_cap)
    vl_reaches_a = dv >= c
    if not vl_reaches_a:
        x_t = c - dv
        s_t = math.sqrt(x_t)
        r_t = a_max / sqrt_j       # sqrt(dv + x_t)
        vl_reaches_a = x_t * (sigma / (r_t + r0) + r_t) + (2.0 * vh + x_t) * s_t <= gain
        if not vl_reaches_a:
            s = min(s, s_t)
    if vl_reaches_a:
        q = 2.0 * a_max / sqrt_j
        k = 2.0 * a_max * extra
        if dv < c:
            k -= sigma * (0.5 * q - r0) ** 2
        return _NEWTON_QUARTIC, s, q, 2.0 * vh + c, 2.0 * q * vh, k, 0.0
    return _NEWTON_PURE_S, s, dv, sigma, r0, 2.0 * vh, gain


@njit(cache=True, error_model="numpy")
def _newton_solve(what: int, s: float, p1: float, p2: float, p3: float, p4: float, p5: float) -> float:
    """Run _newton_setup's iteration to its end (the scalar path; the batch runs the same steps in lockstep)."""
    if what == _NEWTON_QUARTIC:
        for _ in range(_NEWTON_MAX_ITER):
            s, more = _quartic_step(s, p1, p2, p3, p4, p5)
            if not more:
                break
    elif what == _NEWTON_PURE_S:
        for _ in range(_NEWTON_MAX_ITER):
            s, more = _pure_s_step(s, p1, p2, p3, p4, p5)
            if not more:
                break
    return s


@njit(cache=True, error_model="numpy")
def _no_cruise_phases(s: float, h: float, v0: float, v1: float, a_max: float, j_max: float, refit: bool):
    """(durations, peak_v) of the profile without cruise peaking at vh + s² (v0, v1 already capped by V);
    refit: h is short of D(0) by the feasibility slack, fit the one ramp to h exactly."""
    vh = max(v0, v1)
    dv = vh - min(v0, v1)
    sqrt_j = math.sqrt(j_max)
    vp = vh + s * s
    # the vh-side ramp has dv = s² exactly: take its times from s to keep digits when s is tiny
    if s * sqrt_j >= a_max:
        tjh, tah = a_max / j_max, max(s * s / a_max - a_max / j_max, 0.0)
    else:
        tjh, tah = s / sqrt_j, 0.0
    if refit:
        tjl, tal = _ramp_fit_distance(v0, dv, v0 < v1, h, a_max, j_max)
    else:
        tjl, tal = ramp_times_kernel(dv + s * s, a_max, j_max)
    if v0 >= v1:
        tj1, ta1, tj2, ta2 = tjh, tah, tjl, tal
    else:
        tj1, ta1, tj2, ta2 = tjl, tal, tjh, tah
    return (tj1, ta1, tj1, 0.0, tj2, ta2, tj2), vp


@njit(cache=True, error_model="numpy")
def _solve_head(distance: float, v_max: float, a_max: float, j_max: float, v_start: float, v_end: float):
    """Everything but the Newton iteration: (durations, peak_v, what, s, p1..p5). what = _DONE: durations and
    peak_v are the answer (NaN if infeasible or invalid); otherwise run _newton_setup's iteration from s with
    p1..p5 and finish with _no_cruise_phases."""
    nan = math.nan
    nans = (nan, nan, nan, nan, nan, nan, nan)
    if not _valid(distance, v_max, a_max, j_max, v_start, v_end):
        return nans, nan, _DONE, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    v0 = min(v_start, v_max)
    v1 = min(v_end, v_max)
    h = distance
    vh = max(v0, v1)
    vl = min(v0, v1)
    dv = vh - vl
    if vh < v_max:
        d_vmax = ramp_distance_kernel(v0, v_max, a_max, j_max) + ramp_distance_kernel(v_max, v1, a_max, j_max)
        if h >= d_vmax:
            # cruise at V (the feasibility test below cannot fail here: d_vmax > d_min, as a ramp's distance
            # grows with its speed change, by far more than FEASIBILITY_RTOL)
            tj1, ta1 = ramp_times_kernel(v_max - v0, a_max, j_max)
            tj2, ta2 = ramp_times_kernel(v_max - v1, a_max, j_max)
            return ((tj1, ta1, tj1, (h - d_vmax) / v_max, tj2, ta2, tj2), v_max,
                    _DONE, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    d_min = ramp_distance_kernel(vl, vh, a_max, j_max)
    if h < d_min:
        dv_lo = max(dv - SPEED_ULPS * EPS * vh, 0.0)
        if h < 0.5 * (vl + vh) * ramp_time_kernel(dv_lo, a_max, j_max) * (1.0 - FEASIBILITY_RTOL):
            return nans, nan, _DONE, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0

    if vh >= v_max:
        # an end speed is at the limit: one monotone ramp and cruise at V
        cruise_t = (h - d_min) / v_max if h > d_min else 0.0
        tj1, ta1 = ramp_times_kernel(v_max - v0, a_max, j_max)
        tj2, ta2 = ramp_times_kernel(v_max - v1, a_max, j_max)
        if h < d_min:
            if v0 < v1:
                tj1, ta1 = _ramp_fit_distance(v0, dv, True, h, a_max, j_max)
            else:
                tj2, ta2 = _ramp_fit_distance(v0, dv, False, h, a_max, j_max)
        return (tj1, ta1, tj1, cruise_t, tj2, ta2, tj2), v_max, _DONE, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0

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
        s_cap = min(a_max / math.sqrt(j_max), math.sqrt(v_max - vh))
        what, s, p1, p2, p3, p4, p5 = _newton_setup(extra, vl, vh, dv, a_max, j_max, s_cap)
        if what != _DONE:
            return nans, nan, what, s, p1, p2, p3, p4, p5
    t, vp = _no_cruise_phases(s, h, v0, v1, a_max, j_max, extra < 0.0)
    return t, vp, _DONE, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0


@njit(cache=True, error_model="numpy")
def scurve_phases_kernel(distance: float, v_max: float, a_max: float, j_max: float,
                         v_start: float, v_end: float):
    """Time-optimal forward-only double-S profile.

    Returns ((t1, ..., t7), (j1, ..., j7), peak_v): phase durations (s), their jerks (mm/s³:
    +J, 0, -J, 0, -J, 0, +J) and the peak speed (mm/s). Acceleration is 0 at both ends; the acceleration during
    phase k is the running sum of j·t. All NaN when no forward-only motion exists or an argument is invalid.
    """
    jerks = (j_max, 0.0, -j_max, 0.0, -j_max, 0.0, j_max)
    t, vp, what, s, p1, p2, p3, p4, p5 = _solve_head(distance, v_max, a_max, j_max, v_start, v_end)
    if what != _DONE:
        s = _newton_solve(what, s, p1, p2, p3, p4, p5)
        t, vp = _no_cruise_phases(s, distance, min(v_start, v_max), min(v_end, v_max), a_max, j_max, False)
    return t, jerks, vp


@njit(cache=True, error_model="numpy")
def _total(t) -> float:
    """s, the sum of seven phase durations, in phase order (the batch and the scalar kernel must agree to the bit)."""
    return t[0] + t[1] + t[2] + t[3] + t[4] + t[5] + t[6]


@njit(cache=True, error_model="numpy")
def scurve_duration_kernel(distance: float, v_max: float, a_max: float, j_max: float,
                           v_start: float, v_end: float) -> float:
    """s, duration of the time-optimal forward-only double-S profile; NaN if none exists (or bad arguments)."""
    t, _, _ = scurve_phases_kernel(distance, v_max, a_max, j_max, v_start, v_end)
    return _total(t)


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
def scurve_max_start_speed_kernel(distance: float, v_max: float, a_max: float, j_max: float,
                                  v_end: float) -> float:
    """mm/s, the highest start speed from which v_end can be reached over `distance` (backward pass). By time
    reversal a ramp down from v to v_end covers the same distance as a ramp up from v_end to v."""
    return scurve_max_end_speed_kernel(distance, v_max, a_max, j_max, v_end)


@njit(cache=True, error_model="numpy")
def scurve_min_distance_kernel(v_max: float, a_max: float, j_max: float, v_start: float, v_end: float) -> float:
    """mm, the least distance of a forward-only profile from v_start to v_end (one monotone ramp)."""
    return ramp_distance_kernel(min(v_start, v_max), min(v_end, v_max), a_max, j_max)


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
def scurve_position_kernel(t: float, distance: float, v_max: float, a_max: float, j_max: float,
                           v_start: float, v_end: float) -> float:
    """mm, position at time t of the time-optimal double-S profile (solves the profile each call)."""
    dur, jerks, _ = scurve_phases_kernel(distance, v_max, a_max, j_max, v_start, v_end)
    p, _, _, _ = scurve_state_kernel(t, dur, jerks, v_start)
    return p


@njit(cache=True, error_model="numpy")
def _scurve_durations_loop(distance, v_max, a_max, j_max, v_start, v_end, out):
    for i in range(out.shape[0]):
        out[i] = scurve_duration_kernel(distance[i], v_max[i], a_max[i], j_max[i], v_start[i], v_end[i])
    return out


# Elements per block of the batch loop: the Newton cases of a block are iterated in lockstep, a few hundred
# keeps their buffers in L1.
_BATCH_BLOCK = 256


@njit(cache=True, error_model="numpy")
def _lockstep_newton(what: int, s, params, m: int) -> None:
    """Run the iteration `what` (_NEWTON_QUARTIC or _NEWTON_PURE_S) on s[:m], with p1..p5 in the rows of
    params[:, :m], until every one has stopped, each exactly as _newton_solve would: the same steps in the same
    order, so the results are bit-identical. Many independent iterations side by side run at the throughput of
    sqrt and division instead of their latency (the scalar loop waits for each step before the next), and the
    loop over them vectorises. (Two copies of the loop rather than the step function as an argument:
    first-class functions defeat numba's cache.)"""
    active = np.ones(m, dtype=np.bool_)
    for _ in range(_NEWTON_MAX_ITER):
        any_active = False
        if what == _NEWTON_QUARTIC:
            for j in range(m):
                s_next, more = _quartic_step(s[j], params[0, j], params[1, j], params[2, j], params[3, j], 0.0)
                on = active[j]
                s[j] = s_next if on else s[j]
                active[j] = on & more
                any_active |= on & more
        else:
            for j in range(m):
                s_next, more = _pure_s_step(s[j], params[0, j], params[1, j], params[2, j], params[3, j],
                                            params[4, j])
                on = active[j]
                s[j] = s_next if on else s[j]
                active[j] = on & more
                any_active |= on & more
        if not any_active:
            break


@njit(cache=True, error_model="numpy")
def _scurve_durations_checked(distance, v_max, a_max, j_max, v_start, v_end, out) -> int:
    """scurve_duration_kernel over arrays with scurve_durations' argument checks fused in (one pass). Returns -1,
    or the index of the first element with an invalid argument (out is then incomplete).

    Per block, the cases that need Newton are set aside (one list per formula) and iterated in lockstep
    (_lockstep_newton), then finished; each element's arithmetic is the scalar kernel's, operation for
    operation, so out[i] == scurve_duration_kernel(...) exactly."""
    inf = math.inf
    n = out.shape[0]
    block = _BATCH_BLOCK
    idx = np.empty((2, block), dtype=np.int64)
    s = np.empty((2, block))
    params = np.empty((2, 5, block))    # parameter-major: the lockstep loop reads each contiguously
    for start in range(0, n, block):
        stop = min(start + block, n)
        m_quartic = 0
        m_pure = 0
        for i in range(start, stop):
            h = distance[i]
            vm = v_max[i]
            am = a_max[i]
            jm = j_max[i]
            v0 = v_start[i]
            v1 = v_end[i]
            # non-short-circuit & keeps this branch-free; NaN fails every comparison
            ok = ((h >= 0.0) & (h < inf) & (vm > 0.0) & (am > 0.0) & (am < inf) & (jm > 0.0) & (jm < inf)
                  & (v0 >= 0.0) & (v0 <= vm) & (v0 < inf) & (v1 >= 0.0) & (v1 <= vm) & (v1 < inf))
            if not ok:
                return i
            t, _, what, s0, p1, p2, p3, p4, p5 = _solve_head(h, vm, am, jm, v0, v1)
            if what == _DONE:
                out[i] = _total(t)
                continue
            k = 0 if what == _NEWTON_QUARTIC else 1
            m = m_quartic if k == 0 else m_pure
            idx[k, m] = i
            s[k, m] = s0
            params[k, 0, m] = p1
            params[k, 1, m] = p2
            params[k, 2, m] = p3
            params[k, 3, m] = p4
            params[k, 4, m] = p5
            if k == 0:
                m_quartic += 1
            else:
                m_pure += 1
        _lockstep_newton(_NEWTON_QUARTIC, s[0], params[0], m_quartic)
        _lockstep_newton(_NEWTON_PURE_S, s[1], params[1], m_pure)
        for k in range(2):
            for j in range(m_quartic if k == 0 else m_pure):
                i = idx[k, j]
                t, _ = _no_cruise_phases(s[k, j], distance[i], min(v_start[i], v_max[i]), min(v_end[i], v_max[i]),
                                         a_max[i], j_max[i], False)
                out[i] = _total(t)
    return -1


@njit(cache=True, error_model="numpy")
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
    from .core import batch_arrays, check_batch_args

    shape, (h, vm, am, jm, v0, v1) = batch_arrays(distance=distance, v_max=v_max, a_max=a_max, j_max=j_max,
                                                  v_start=v_start, v_end=v_end)
    out = np.empty(h.shape[0])
    if _scurve_durations_checked(h, vm, am, jm, v0, v1, out) >= 0:
        # an invalid argument somewhere: the per-array checks name it (and raise)
        check_batch_args(h, vm, {"a_max": am, "j_max": jm}, v0, v1)
        raise AssertionError("unreachable: the fused and the per-array argument checks disagree")
    return out.reshape(shape)
