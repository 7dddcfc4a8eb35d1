"""Braking figures (seed optimal-motion-jerk-braking.es, "frenado de emergencia").

Stopping distance from speed v at constant deceleration d: X_f = v²/(2·d), after v/d seconds. The "safe braking
distance" v_max²/(2·d_max) is the gap a body must keep ahead of it. For bodies of length L moving in a line at
speed v, each keeping that gap, the flow is v / (L + v²/(2·d)) bodies per unit time; it peaks where
d/dv = 0 <=> L = v²/(2·d), at v* = sqrt(2·d·L): the speed that moves the most bodies is not the top speed.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .core import Profile, check_limit


def _speed(name: str, v) -> np.ndarray:
    arr = np.asarray(v, dtype=np.float64)
    if np.isnan(arr).any() or (arr < 0.0).any():
        raise ValueError(f"{name} must be >= 0 (and not NaN)")
    return arr


def stopping_distance(v, decel):
    """mm, v²/(2·decel): distance to stop from speed v (mm/s, scalar or array) at constant decel (mm/s²)."""
    d = check_limit("decel", decel)
    out = _speed("v", v) ** 2 / (2.0 * d)
    return float(out) if np.ndim(out) == 0 else out


def stopping_time(v, decel):
    """s, v/decel: time to stop from speed v at constant deceleration."""
    d = check_limit("decel", decel)
    out = _speed("v", v) / d
    return float(out) if np.ndim(out) == 0 else out


def safe_spacing(v_max, decel_max):
    """mm, the "safe braking distance" v_max²/(2·decel_max) a body must keep free ahead of it."""
    return stopping_distance(v_max, decel_max)


def line_throughput(v, body_length, decel):
    """Bodies per second passing a point when bodies of length `body_length` (mm) move in a line at speed v
    (mm/s), each keeping the safe spacing v²/(2·decel) ahead: v / (L + v²/(2·decel))."""
    length = check_limit("body_length", body_length)
    vv = _speed("v", v)
    out = vv / (length + vv * vv / (2.0 * check_limit("decel", decel)))
    return float(out) if np.ndim(out) == 0 else out


def optimal_line_speed(body_length, decel, v_max=float("inf")) -> float:
    """mm/s, the speed that maximises line_throughput: v* = sqrt(2·decel·L), capped by v_max (the flow rises
    with v up to v*, so below it the cap is the best)."""
    length = check_limit("body_length", body_length)
    d = check_limit("decel", decel)
    vm = check_limit("v_max", v_max, allow_inf=True)
    return min(float(np.sqrt(2.0 * d * length)), vm)


class BrakingPoint(NamedTuple):
    position: float   # mm from the profile's start where the final slow-down begins
    time: float       # s
    speed: float      # mm/s at that point


def braking_point(profile: Profile) -> BrakingPoint:
    """Where the final slow-down of a profile begins: the start of its trailing run of decelerating pieces.

    For a trapezoid this is the notes' X_if = h - (vp² - v1²)/(2·A_d); for an S-curve the start of phase 5.
    A profile that never slows down at its end brakes at its end."""
    pcs = profile.pieces
    k = pcs.shape[0]
    while k > 0:
        pc = pcs[k - 1]
        if pc["dt"] <= 0.0:
            k -= 1
            continue
        a_end = pc["a0"] + pc["j"] * pc["dt"]
        if min(pc["a0"], a_end) < 0.0 and max(pc["a0"], a_end) <= 0.0:
            k -= 1
            continue
        break
    t = profile.duration if k == pcs.shape[0] else float(pcs["t0"][k])
    p, v, _, _ = profile.sample(np.array([t]))
    return BrakingPoint(float(p[0] - profile.p_start), t, float(v[0]))


def stop_position(profile: Profile, t, decel):
    """mm, where a feed hold at time(s) t stops when it brakes at constant `decel` from the speed it has then:
    q(t) + v(t)²/(2·decel) (acceleration assumed to switch to -decel at once)."""
    d = check_limit("decel", decel)
    p, v, _, _ = profile.sample(t)
    out = p + v * v / (2.0 * d)
    return float(out) if np.ndim(out) == 0 else out
