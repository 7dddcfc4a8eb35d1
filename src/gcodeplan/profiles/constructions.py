"""The course notes' profiles that are defined by timing rather than by limits.

* ``timed_scurve``: the S-curve of s-curve-and-multi-axis.es, velocity made of two parabolas
  v_A(t) = 2·v_m·t²/t_a² (t < t_a/2), v_B(t) = v_m - 2·v_m·(t_a - t)²/t_a² (t_a/2 < t < t_a): constant jerk
  ±4·v_m/t_a², peak acceleration 2·v_m/t_a, ramp distance v_m·t_a/2.
* ``equivalent_scurve``: the S-curve "equivalent" to a trapezoid (optimal-motion-jerk-braking.es): every
  constant-acceleration ramp is replaced by a jerk-limited ramp of the same duration and the same speed change,
  so the total time and distance are kept (a ramp's velocity is point-symmetric about its midpoint: mean speed
  unchanged) and the peak acceleration doubles; with ``jerk_fraction`` < 1 it is the notes' "modified S", whose
  ramps keep a constant-acceleration middle phase.
* ``via_points``: the notes' parabolic fit (trapezoidal-and-parabolic-blends.es, "ajuste parabólico"): linear
  segments joined by constant-acceleration blends of half-width tau around each via point; the path passes the
  via point at time t_i off by e = |a|·tau²/2 (a = (v_{i+1} - v_i)/(2·tau)).
"""
from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from .core import Profile, build_profile, check_limit


def parabolic_ramp_figures(v_m: float, t_a: float) -> dict:
    """The notes' two-parabola ramp from rest to v_m in t_a: jerk 4·v_m/t_a² (mm/s³), peak acceleration
    2·v_m/t_a (mm/s², twice the trapezoid's with the same t_a), distance v_m·t_a/2 (mm)."""
    return {"jerk": 4.0 * v_m / (t_a * t_a), "peak_accel": 2.0 * v_m / t_a, "ramp_distance": v_m * t_a / 2.0}


def timed_scurve(v_m, t_a, total_t=None) -> Profile:
    """Rest -> v_m over t_a (two parabolas), cruise, v_m -> rest over t_a; total_t defaults to 2·t_a.

    Distance v_m·(total_t - t_a). Phases are (duration s, jerk). Raises ValueError for bad arguments or
    total_t < 2·t_a."""
    vm = check_limit("v_m", v_m)
    ta = check_limit("t_a", t_a)
    tt = 2.0 * ta if total_t is None else check_limit("total_t", total_t)
    if tt < 2.0 * ta:
        raise ValueError(f"total_t = {tt:g} is shorter than the two ramps 2·t_a = {2 * ta:g}")
    j = 4.0 * vm / (ta * ta)
    h = ta / 2.0
    dt = [h, h, tt - 2.0 * ta, h, h]
    jerk = [j, -j, 0.0, -j, j]
    return build_profile("timed-scurve", "jerk", dt, jerk, None, 0.0,
                         limits={"v_m": vm, "t_a": ta, "total_t": tt}, distance=vm * (tt - ta),
                         peak_velocity=vm, v_end=0.0, info=parabolic_ramp_figures(vm, ta))


def equivalent_scurve(profile: Profile, jerk_fraction: float = 1.0) -> Profile:
    """The S-curve with the same duration, distance and end speeds as a trapezoid `profile`.

    Each ramp of duration T and acceleration a (speed change dv = a·T) becomes +J for t1, constant a_M for
    T - 2·t1, -J for t1 with t1 = jerk_fraction·T/2; dv = a_M·(T - t1) gives a_M = a·T/(T - t1) and J = a_M/t1.
    jerk_fraction = 1 is the pure S (a_M = 2·a, J = 4·a/T); smaller values are the notes' "modified S"."""
    if profile.phase_value != "accel":
        raise ValueError(f"equivalent_scurve needs a trapezoid-like profile, got a {profile.kind}")
    f = float(jerk_fraction)
    if not (0.0 < f <= 1.0):
        raise ValueError(f"jerk_fraction must be in (0, 1], got {jerk_fraction!r}")
    dts: list[float] = []
    jerks: list[float] = []
    pcs = profile.pieces
    for k in range(pcs.shape[0]):
        T = float(pcs["dt"][k])
        a = float(pcs["a0"][k])
        if T <= 0.0:
            continue
        if a == 0.0:
            dts.append(T)
            jerks.append(0.0)
            continue
        t1 = f * T / 2.0
        a_m = a * T / (T - t1)
        jm = a_m / t1
        dts += [t1, T - 2.0 * t1, t1]
        jerks += [jm, 0.0, -jm]
    out = build_profile("equivalent-scurve", "jerk", dts, jerks, None, profile.v_start, profile.p_start,
                        limits=dict(profile.limits, jerk_fraction=f), distance=profile.distance,
                        peak_velocity=profile.peak_velocity, v_end=profile.v_end)
    return out


@dataclass(frozen=True, eq=False)
class ViaPointTrajectory(Profile):
    """A Profile through via points, plus what the fit did at each point.

    point_times: notional time t_i of every point (s; t_0 = tau_0, the trajectory starts at rest at 0).
    tau: blend half-width at every point (s). blend_accel: signed constant acceleration of each blend.
    via_times / deviation: interior via points only: time t_i and |q(t_i) - q_i| = |a_i|·tau_i²/2 (mm).
    The first and last points are reached exactly, at rest, at t = 0 and t = duration."""

    positions: np.ndarray | None = None
    point_times: np.ndarray | None = None
    tau: np.ndarray | None = None
    blend_accel: np.ndarray | None = None
    via_times: np.ndarray | None = None
    deviation: np.ndarray | None = None


def via_points(positions, segment_times, blend_time=None, accel=None) -> ViaPointTrajectory:
    """Linear segments through `positions` (mm) taking `segment_times` (s) each, joined by parabolic blends.

    Give exactly one of
      blend_time: the full duration 2·tau of every blend (s);
      accel: the blend acceleration magnitude (mm/s²); each blend then lasts 2·tau_i = |v_{i+1} - v_i|/accel.
    The first and last points are treated as blends from / to rest (speed 0 outside), so the trajectory starts
    and ends at rest exactly at them. Raises ValueError when two blends overlap inside a segment."""
    q = np.asarray(positions, dtype=np.float64).reshape(-1)
    seg_t = np.asarray(segment_times, dtype=np.float64).reshape(-1)
    if q.shape[0] < 2:
        raise ValueError("positions needs at least 2 points")
    if not np.isfinite(q).all():
        raise ValueError("positions must be finite numbers")
    if seg_t.shape[0] != q.shape[0] - 1:
        raise ValueError(f"segment_times needs {q.shape[0] - 1} values (one per segment), got {seg_t.shape[0]}")
    if not (np.isfinite(seg_t).all() and (seg_t > 0.0).all()):
        raise ValueError("segment_times must be finite and > 0")
    if (blend_time is None) == (accel is None):
        raise ValueError("give exactly one of blend_time or accel")
    # segment speeds, with rest before the first point and after the last
    v = np.concatenate(([0.0], np.diff(q) / seg_t, [0.0]))
    dv = np.diff(v)                                   # speed change at each point
    if blend_time is not None:
        bt = check_limit("blend_time", blend_time)
        tau = np.full(q.shape[0], bt / 2.0)
    else:
        acc = check_limit("accel", accel)
        tau = np.abs(dv) / (2.0 * acc)
    with np.errstate(divide="ignore", invalid="ignore"):
        a = np.where(tau > 0.0, dv / (2.0 * tau), 0.0)
    overlap = tau[:-1] + tau[1:] - seg_t
    bad = np.nonzero(overlap > 1e-12 * seg_t)[0]
    if bad.size:
        i = int(bad[0])
        raise ValueError(f"blends at points {i} and {i + 1} overlap: tau {tau[i]:g} + {tau[i + 1]:g} s > "
                         f"segment time {seg_t[i]:g} s (use a shorter blend_time or a higher accel)")
    dts: list[float] = []
    accs: list[float] = []
    n = q.shape[0]
    for i in range(n):
        dts.append(2.0 * tau[i])
        accs.append(a[i])
        if i < n - 1:
            dts.append(max(seg_t[i] - tau[i] - tau[i + 1], 0.0))
            accs.append(0.0)
    t_pts = tau[0] + np.concatenate(([0.0], np.cumsum(seg_t)))
    base = build_profile("via-points", "accel", dts, 0.0, accs, 0.0, float(q[0]),
                         limits={"blend_time": blend_time, "accel": accel}, distance=float(q[-1] - q[0]),
                         v_end=0.0)
    dev = np.abs(a) * tau * tau / 2.0
    return ViaPointTrajectory(**{f.name: getattr(base, f.name) for f in fields(Profile)},
                              positions=q, point_times=t_pts, tau=tau, blend_accel=a,
                              via_times=t_pts[1:-1].copy(), deviation=dev[1:-1].copy())
