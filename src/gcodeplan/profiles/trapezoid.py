"""Trapezoidal (acceleration-limited) profiles: the numba kernels.

Seeds: trapezoidal-velocity-profile.it (rest to rest), optimal-motion-jerk-braking.es (v0, v1, different
accel A_a and decel A_d). Peak speed

    vp² = min(V², (2·A_a·A_d·h + A_d·v0² + A_a·v1²) / (A_a + A_d))

accel time (vp - v0)/A_a, decel time (vp - v1)/A_d, cruise (h - X_a - X_d)/vp with X_a = (vp² - v0²)/(2·A_a),
X_d = (vp² - v1²)/(2·A_d). Triangular when vp < V. Time-optimal: for a fixed peak every part runs at the limit,
and the time falls as the peak rises (the velocity-vs-position curve of a higher peak lies above), so the largest
feasible peak wins. Infeasible (NaN) when v1 cannot be reached within h:
v1 > v0 needs (v1² - v0²) <= 2·A_a·h; v1 < v0 needs (v0² - v1²) <= 2·A_d·h.
"""
from __future__ import annotations

import math

from .._jit import njit

from .scurve import EPS, FEASIBILITY_RTOL, SPEED_ULPS


@njit(cache=True)
def _valid(distance, v_max, accel, decel, v_start, v_end) -> bool:
    if not (distance >= 0.0 and v_max > 0.0 and accel > 0.0 and decel > 0.0):
        return False
    if not (v_start >= 0.0 and v_end >= 0.0):
        return False
    lim = v_max * (1.0 + FEASIBILITY_RTOL)
    return v_start <= lim and v_end <= lim


@njit(cache=True)
def trapezoid_phases_kernel(distance: float, v_max: float, a_max: float, v_start: float, v_end: float,
                            decel: float):
    """(accel_t s, cruise_t s, decel_t s, peak_v mm/s) of the time-optimal trapezoid; all NaN if infeasible
    or an argument is invalid. Acceleration a_max while speeding up, deceleration `decel` while slowing down."""
    nan = math.nan
    if not _valid(distance, v_max, a_max, decel, v_start, v_end):
        return nan, nan, nan, nan
    h = distance
    v0 = min(v_start, v_max)
    v1 = min(v_end, v_max)
    dv2 = (v0 - v1) * (v0 + v1)
    # a few ulps of the speeds (see scurve.SPEED_ULPS) plus the distance's own rounding
    dv2_slack = 2.0 * SPEED_ULPS * EPS * max(v0, v1) ** 2
    slack = 1.0 + FEASIBILITY_RTOL
    if dv2 - dv2_slack > 2.0 * decel * h * slack or -dv2 - dv2_slack > 2.0 * a_max * h * slack:
        return nan, nan, nan, nan
    # vp² - v0² = A_a·(2·A_d·h - (v0² - v1²))/(A_a + A_d) and vp² - v1² = A_d·(2·A_a·h + (v0² - v1²))/(A_a + A_d):
    # the same closed form, written as differences so that a peak barely above v0 or v1 keeps its digits
    rise0 = max(a_max * (2.0 * decel * h - dv2) / (a_max + decel), 0.0)
    rise1 = max(decel * (2.0 * a_max * h + dv2) / (a_max + decel), 0.0)
    vp = math.sqrt(max(v0 * v0 + rise0, v1 * v1 + rise1))
    if vp < v_max:
        # triangle: no cruise, the two ramps cover h exactly
        accel_t = rise0 / (vp + v0) / a_max if vp > 0.0 else 0.0
        decel_t = rise1 / (vp + v1) / decel if vp > 0.0 else 0.0
        return accel_t, 0.0, decel_t, vp
    vp = v_max
    accel_t = (vp - v0) / a_max
    decel_t = (vp - v1) / decel
    x_accel = (vp - v0) * (vp + v0) / (2.0 * a_max)
    x_decel = (vp - v1) * (vp + v1) / (2.0 * decel)
    cruise_t = max(h - x_accel - x_decel, 0.0) / vp
    return accel_t, cruise_t, decel_t, vp


@njit(cache=True)
def block_trapezoid_kernel(v0_sqr, v1_sqr, nominal, accel, mm, out):
    """A firmware planner block's trapezoid in closed form, as the firmware models' ideal plans time it
    (planner/marlin_ideal.py, planner/grbl_ideal.py): ``out`` = entry, cruise (or peak) and exit speed (mm/s),
    accelerating, cruising and braking time (s), from the entry and exit speed² (mm²/s², as the look-ahead passes
    keep them), nominal speed (mm/s), acceleration (mm/s², the same both ways) and length (mm). An entry or exit
    above the nominal speed (a firmware's floor speed) is kept; without room to cruise the ramps meet at
    v² = (v0² + v1²) / 2 + a·d."""
    v0 = math.sqrt(max(v0_sqr, 0.0))
    v1 = math.sqrt(max(v1_sqr, 0.0))
    vc = max(nominal, v0, v1)
    d_acc = (vc * vc - v0 * v0) / (2.0 * accel)
    d_dec = (vc * vc - v1 * v1) / (2.0 * accel)
    tc = 0.0
    if d_acc + d_dec <= mm:
        tc = (mm - d_acc - d_dec) / vc
    else:
        vc = max(math.sqrt(max((v0 * v0 + v1 * v1) * 0.5 + accel * mm, 0.0)), v0, v1)
    out[0], out[1], out[2] = v0, vc, v1
    out[3] = (vc - v0) / accel
    out[4] = tc
    out[5] = (vc - v1) / accel


@njit(cache=True)
def trapezoid_duration_kernel(distance: float, v_max: float, a_max: float, v_start: float, v_end: float,
                              decel: float) -> float:
    """s, duration of the time-optimal trapezoid; NaN if infeasible or an argument is invalid."""
    ta, tc, td, _ = trapezoid_phases_kernel(distance, v_max, a_max, v_start, v_end, decel)
    return ta + tc + td


@njit(cache=True)
def trapezoid_max_end_speed_kernel(distance: float, v_max: float, a_max: float, v_start: float) -> float:
    """mm/s, min(V, sqrt(v0² + 2·A·h)): the highest end speed reachable over `distance` from v_start."""
    if not _valid(distance, v_max, a_max, a_max, v_start, 0.0):
        return math.nan
    return min(v_max, math.sqrt(v_start * v_start + 2.0 * a_max * distance))


@njit(cache=True)
def trapezoid_state_kernel(t: float, accel_t: float, cruise_t: float, decel_t: float, v_start: float,
                           a_max: float, decel: float):
    """(position mm, velocity mm/s, acceleration mm/s²) at time t of a trapezoid starting at 0 with v_start;
    t is clamped into [0, duration]."""
    if t < 0.0:
        t = 0.0
    if t <= accel_t:
        return v_start * t + a_max * t * t / 2.0, v_start + a_max * t, a_max
    vp = v_start + a_max * accel_t
    p = v_start * accel_t + a_max * accel_t * accel_t / 2.0
    t -= accel_t
    if t <= cruise_t:
        return p + vp * t, vp, 0.0
    p += vp * cruise_t
    t = min(t - cruise_t, decel_t)
    return p + vp * t - decel * t * t / 2.0, vp - decel * t, -decel


@njit(cache=True)
def _trapezoid_durations_loop(distance, v_max, a_max, v_start, v_end, decel, out):
    for i in range(out.shape[0]):
        out[i] = trapezoid_duration_kernel(distance[i], v_max[i], a_max[i], v_start[i], v_end[i], decel[i])
    return out


# --------------------------------------------------------------------------- Python API
def trapezoid(distance, v_max, a_max, v_start=0.0, v_end=0.0, decel=None):
    """The time-optimal acceleration-limited profile (trapezoid, or triangle when v_max is not reached).

    distance mm >= 0; v_max mm/s > 0 (inf allowed); a_max mm/s² > 0 used while speeding up; decel mm/s² > 0
    while slowing down (default a_max); 0 <= v_start, v_end <= v_max. Raises ValueError naming a bad argument,
    InfeasibleProfile when v_end cannot be reached within the distance. Phases are (duration s, accel mm/s²)."""
    import numpy as np

    from .core import InfeasibleProfile, build_profile, check_distance, check_limit, check_speed

    h = check_distance("distance", distance)
    vm = check_limit("v_max", v_max, allow_inf=True)
    am = check_limit("a_max", a_max)
    dm = am if decel is None else check_limit("decel", decel)
    v0 = check_speed("v_start", v_start, vm)
    v1 = check_speed("v_end", v_end, vm)
    ta, tc, td, vp = trapezoid_phases_kernel(h, vm, am, v0, v1, dm)
    if math.isnan(vp):
        if v1 > v0:
            need, which = (v1 * v1 - v0 * v0) / (2.0 * am), f"a_max = {am:g}"
        else:
            need, which = (v0 * v0 - v1 * v1) / (2.0 * dm), f"decel = {dm:g}"
        raise InfeasibleProfile(
            f"cannot go from v_start = {v0:g} to v_end = {v1:g} within distance = {h:g} under {which}: "
            f"that needs at least {need:.9g}")
    return build_profile("trapezoid", "accel", np.array([ta, tc, td]), 0.0, np.array([am, 0.0, -dm]), v0,
                         limits={"v_max": vm, "a_max": am, "decel": dm}, distance=h, peak_velocity=vp, v_end=v1)


def trapezoid_durations(distance, v_max, a_max, v_start, v_end, decel=None):
    """Durations (s) of many time-optimal trapezoids from broadcastable arrays; NaN where infeasible.
    Raises ValueError for NaN or out-of-range arguments (naming the argument)."""
    import numpy as np

    from .core import batch_arrays, check_batch_args

    shape, (h, vm, am, v0, v1, dm) = batch_arrays(distance=distance, v_max=v_max, a_max=a_max, v_start=v_start,
                                                  v_end=v_end, decel=a_max if decel is None else decel)
    check_batch_args(h, vm, {"a_max": am, "decel": dm}, v0, v1)
    out = np.empty(h.shape[0])
    _trapezoid_durations_loop(h, vm, am, v0, v1, dm, out)
    return out.reshape(shape)
