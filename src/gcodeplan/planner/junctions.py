"""Junction rules: the highest speed at which the tool may pass from one straight move to the next.

Each rule is a small pure function (numba-compiled) of the two moves' directions and limits. All
speeds squared (``_v2``, mm²/s²) unless the name says ``_v`` (mm/s), as in Klipper.

Angle convention (Klipper and grbl alike): ``junction_cos_theta = −(u_prev · u_next)`` over x, y, z.
θ is the angle between the reversed incoming direction and the outgoing direction, so a straight
continuation has cos θ = −1 (θ = π, no slowdown) and an exact reversal has cos θ = +1 (θ = 0, stop).
"""
from __future__ import annotations

import math

from .._jit import njit

# Klipper toolhead.py: the deviation that makes a 90° corner pass at exactly square_corner_velocity.
SQRT2_MINUS_1 = math.sqrt(2.0) - 1.0


@njit(cache=True)
def klipper_junction_deviation(scv_v: float, max_accel: float) -> float:
    """δ = scv²·(√2 − 1)/max_accel (mm): Klipper's ``_calc_junction_deviation``.

    With it, a 90° corner (sin(θ/2) = √½, R = sin/(1−sin) = 1+√2) gives v² = R·δ·a = scv².
    Evaluated in Klipper's order, (scv²·(√2−1))/a, so the result is bit-identical.
    """
    scv_v2 = scv_v * scv_v
    return scv_v2 * SQRT2_MINUS_1 / max_accel


@njit(cache=True)
def half_angle_terms(junction_cos_theta: float) -> tuple[float, float]:
    """(sin(θ/2), cos(θ/2)) from cos θ by the half-angle identities, clamped at 0 against rounding."""
    sin_theta_d2 = math.sqrt(max(0.5 * (1.0 - junction_cos_theta), 0.0))
    cos_theta_d2 = math.sqrt(max(0.5 * (1.0 + junction_cos_theta), 0.0))
    return sin_theta_d2, cos_theta_d2


@njit(cache=True)
def klipper_centripetal_v2(junction_cos_theta: float,
                           jd: float, accel: float, delta_v2: float,
                           prev_jd: float, prev_accel: float, prev_delta_v2: float) -> float:
    """Klipper's corner cap (toolhead.Move.calc_junction, "approximated centripetal velocity").

    With s = sin(θ/2), c = cos(θ/2), R_jd = s/(1−s) and q = s/(4c):
        v² ≤ min(R_jd·δ·a, R_jd·δ_prev·a_prev, Δv²·q, Δv²_prev·q)
    where Δv² = 2·d·a. The first two are the junction-deviation circle (grbl) of each move, the
    last two keep that circle touching each move no further than mid-move (v² = a·r with
    r = (d/2)·tan(θ/2)). Returns +inf when the rule does not apply (straight line: c = 0).
    Exact reversal gives s = 0, hence 0.
    """
    sin_theta_d2, cos_theta_d2 = half_angle_terms(junction_cos_theta)
    one_minus_sin_theta_d2 = 1.0 - sin_theta_d2
    if not (one_minus_sin_theta_d2 > 0.0 and cos_theta_d2 > 0.0):
        return math.inf
    r_jd = sin_theta_d2 / one_minus_sin_theta_d2
    move_jd_v2 = r_jd * jd * accel
    prev_jd_v2 = r_jd * prev_jd * prev_accel
    quarter_tan_theta_d2 = 0.25 * sin_theta_d2 / cos_theta_d2
    move_centripetal_v2 = delta_v2 * quarter_tan_theta_d2
    prev_centripetal_v2 = prev_delta_v2 * quarter_tan_theta_d2
    return min(move_jd_v2, prev_jd_v2, move_centripetal_v2, prev_centripetal_v2)


@njit(cache=True)
def klipper_extruder_corner_v2(icv_v: float, axes_r_e: float, prev_axes_r_e: float,
                               max_cruise_v2: float) -> float:
    """Klipper extruder.calc_junction: v² ≤ (icv/|r_e − r_e,prev|)², or no cap (max_cruise_v2)
    when both moves extrude the same filament per mm of path (the E speed does not jump)."""
    diff_r = axes_r_e - prev_axes_r_e
    if diff_r != 0.0:
        q = icv_v / abs(diff_r)
        return q * q
    return max_cruise_v2


@njit(cache=True)
def jd_junction_v2(junction_cos_theta: float, accel: float, junction_dev: float) -> float:
    """grbl / Marlin 2 junction deviation: v² = a·δ·sin(θ/2)/(1 − sin(θ/2)).

    A circle of radius r = δ·s/(1−s) (s = sin(θ/2)) tangent to both moves deviates δ from the corner;
    v² = a·r is the centripetal speed on it. Straight (s = 1) → +inf, reversal (s = 0) → 0.
    grbl/Marlin clamp cos θ to ±0.999999 before this; we treat |cos θ| ≥ 0.999999 the same way:
    > +0.999999 (reversal) → 0 and < −0.999999 (straight) → +inf (the cruise caps apply instead).
    """
    if junction_cos_theta > 0.999999:
        return 0.0
    if junction_cos_theta < -0.999999:
        return math.inf
    sin_theta_d2 = math.sqrt(0.5 * (1.0 - junction_cos_theta))
    return accel * junction_dev * sin_theta_d2 / (1.0 - sin_theta_d2)


@njit(cache=True)
def marlin_small_segment_v2(junction_cos_theta: float, move_d: float, accel: float) -> float:
    """Marlin 2 JD_HANDLE_SMALL_SEGMENTS: for a move shorter than 1 mm turning by less than 45°
    (cos θ < −√½), the moves are taken as chords of an arc: each chord of length d turns the
    direction by φ = acos(u_prev·u_next), so the arc radius is d/φ and v² ≤ a·d/φ.

    Marlin evaluates φ with a polynomial acos approximation (±0.033 rad, floored at 0.033 rad);
    we use the exact acos with the same floor, so a straight line (φ = 0) is not capped to 0.
    Returns +inf when the rule does not apply.
    """
    if move_d < 1.0 and junction_cos_theta < -0.7071067812:
        turn_theta = math.acos(min(1.0, max(-1.0, -junction_cos_theta)))
        turn_theta = max(turn_theta, 0.033)
        return move_d * accel / turn_theta
    return math.inf


@njit(cache=True)
def marlin_safe_v(nominal_v: float,
                  vel_x: float, vel_y: float, vel_z: float, vel_e: float,
                  jerk_x: float, jerk_y: float, jerk_z: float, jerk_e: float) -> float:
    """Marlin classic jerk "safe speed": the highest speed along the move, at most nominal_v, that
    every axis can reach from rest (or drop to rest from) in one step: |v_i|·k ≤ jerk_i.

    ``vel_*`` are the per-axis velocities at nominal speed (u_i·nominal_v). Marlin scales the speed
    by jerk_i/|v_i| for the first axis over its jerk and then by the most limiting one; the result
    is nominal_v·min(1, min_i jerk_i/|v_i|), which is what we compute (planner.cpp, HAS_CLASSIC_JERK).
    An axis with jerk_i = 0 (not set) does not limit.
    """
    factor = 1.0
    vels = (float(vel_x), float(vel_y), float(vel_z), float(vel_e))
    jerks = (float(jerk_x), float(jerk_y), float(jerk_z), float(jerk_e))
    for k in range(4):
        v = abs(vels[k])
        j = jerks[k]
        if j > 0.0 and v > j:
            factor = min(factor, j / v)
    return nominal_v * factor


@njit(cache=True)
def _axis_jump(v_exit: float, v_entry: float) -> float:
    """Marlin's per-axis jerk at a junction: the speed change when the axis keeps its direction
    (coasting); on a reversal only the larger of the two magnitudes counts, since the axis passes
    through rest (Marlin planner.cpp, classic jerk)."""
    if v_exit > v_entry:
        if v_entry > 0.0 or v_exit < 0.0:
            return v_exit - v_entry
        return max(v_exit, -v_entry)
    if v_entry < 0.0 or v_exit > 0.0:
        return v_entry - v_exit
    return max(-v_exit, v_entry)


@njit(cache=True)
def marlin_jerk_junction_v(prev_nominal_v: float, nominal_v: float,
                           prev_ux: float, prev_uy: float, prev_uz: float, prev_ue: float,
                           ux: float, uy: float, uz: float, ue: float,
                           jerk_x: float, jerk_y: float, jerk_z: float, jerk_e: float,
                           prev_safe_v: float, safe_v: float) -> float:
    """Marlin classic jerk junction speed (mm/s), planner.cpp ``vmax_junction``.

    Start from the lower nominal speed v_j = min(v_prev, v_next). The previous move's axis
    velocities are scaled to v_j (exit = u_prev,i·v_j), the next move's are u_i·v_next at first.
    For each axis in turn, if the jump (see _axis_jump) of the already-scaled velocities exceeds
    jerk_i, both are scaled by jerk_i/jump and the factor accumulates; v_j is multiplied by the
    accumulated factor. Finally, if both moves' safe speeds exceed 0.99·v_j, the junction may run at
    the next move's safe speed instead (each side can jump from/to rest anyway).
    ``u_*`` are per-mm-of-path components (E included, as Marlin's classic jerk does).
    """
    if prev_nominal_v <= 0.0:
        return safe_v
    vmax_junction = min(nominal_v, prev_nominal_v)
    smaller_speed_factor = vmax_junction / prev_nominal_v
    v_factor = 1.0
    limited = False
    prev_u = (float(prev_ux), float(prev_uy), float(prev_uz), float(prev_ue))
    u = (float(ux), float(uy), float(uz), float(ue))
    jerks = (float(jerk_x), float(jerk_y), float(jerk_z), float(jerk_e))
    for k in range(4):
        v_exit = prev_u[k] * prev_nominal_v * smaller_speed_factor
        v_entry = u[k] * nominal_v
        if limited:
            v_exit *= v_factor
            v_entry *= v_factor
        jump = _axis_jump(v_exit, v_entry)
        j = jerks[k]
        if j > 0.0 and jump > j:
            v_factor *= j / jump
            limited = True
    if limited:
        vmax_junction *= v_factor
    threshold = vmax_junction * 0.99
    if prev_safe_v > threshold and safe_v > threshold:
        vmax_junction = safe_v
    return vmax_junction
