"""Several axes moving one straight move (s-curve-and-multi-axis.es, "movimiento multi-eje").

* sequential: one axis after the other, each with its own fastest profile.
* slew: all axes start together with their own fastest profiles and end at different times.
* interpolated (what G1 does): one profile along the straight path; axis i moves by its share u_i = |d_i|/L, so
  all start and end together. The path limits are the largest that no axis exceeds:
  v = min_i V_i/u_i, a = min_i A_i/u_i, j = min_i J_i/u_i (docs/design.md §2, "Path limits from axis limits").
  In the notes' example (Lx = 16, Ly = 12, V = 4, t_a = 0.2 -> A = 20) this gives the path V = 5, A = 25,
  T = 20/5 + 5/25 = 4.2 s for both axes, v_y = 3: the notes' "interpolated" answer.
"""
from __future__ import annotations

import numpy as np

from .core import Profile, build_profile, check_limit
from .scurve import scurve
from .trapezoid import trapezoid

MODES = ("interpolated", "slew", "sequential")


class AxisProfiles(list):
    """One Profile per axis (each for |d_i|, forward), with the timing of the whole move.

    start_times / end_times: s, when each axis starts and ends; signs: direction of each axis (+1/-1/0);
    duration: s, the end of the last axis; sample(t) -> (position, velocity, acceleration, jerk), each of shape
    (n_axes, len(t)), signed, at absolute times t (an axis rests before its start and after its end)."""

    def __init__(self, profiles, start_times, signs, mode):
        super().__init__(profiles)
        self.start_times = np.asarray(start_times, dtype=np.float64)
        self.end_times = self.start_times + np.array([p.duration for p in profiles])
        self.signs = np.asarray(signs, dtype=np.float64)
        self.mode = mode

    @property
    def duration(self) -> float:
        return float(self.end_times.max()) if len(self) else 0.0

    def sample(self, t):
        ta = np.atleast_1d(np.asarray(t, dtype=np.float64))
        out = [np.zeros((len(self), ta.shape[0])) for _ in range(4)]
        for i, p in enumerate(self):
            local = ta - self.start_times[i]
            vals = p.sample(local)
            inside = (local >= 0.0) & (local <= p.duration)
            for k in range(4):
                x = vals[k] * self.signs[i]
                out[k][i] = x if k == 0 else np.where(inside, x, 0.0)
        return tuple(out)


def _per_axis(name: str, value, n: int, allow_inf: bool) -> np.ndarray:
    arr = np.broadcast_to(np.asarray(value, dtype=np.float64), (n,)).copy()
    for i, x in enumerate(arr):
        check_limit(f"{name}[{i}]", x, allow_inf=allow_inf)
    return arr


def _stationary(duration: float) -> Profile:
    return build_profile("stationary", "accel", [duration], 0.0, [0.0], 0.0, distance=0.0, v_end=0.0)


def _scaled(p: Profile, factor: float) -> Profile:
    """The same timing with every kinematic quantity multiplied by factor (an axis's share of a path)."""
    pcs = p.pieces
    kind = "interpolated-" + p.kind
    return build_profile(kind, p.phase_value, pcs["dt"], pcs["j"] * factor, pcs["a0"] * factor,
                         p.v_start * factor, limits={k: v * factor for k, v in p.limits.items()},
                         distance=p.distance * factor, peak_velocity=p.peak_velocity * factor,
                         v_end=p.v_end * factor)


def synchronize(distances, v_max, a_max, mode: str = "interpolated", j_max=None) -> AxisProfiles:
    """Profiles for a multi-axis straight move from rest to rest.

    distances: signed per-axis distances (mm); v_max, a_max (and j_max for S-curves; None = trapezoids):
    per-axis limits, scalars apply to every axis. mode: "interpolated" | "slew" | "sequential"."""
    if mode not in MODES:
        raise ValueError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
    d = np.asarray(distances, dtype=np.float64).reshape(-1)
    if d.shape[0] == 0 or not np.isfinite(d).all():
        raise ValueError("distances must be a non-empty list of finite numbers")
    n = d.shape[0]
    vm = _per_axis("v_max", v_max, n, allow_inf=True)
    am = _per_axis("a_max", a_max, n, allow_inf=False)
    jm = None if j_max is None else _per_axis("j_max", j_max, n, allow_inf=False)
    signs = np.sign(d)
    ad = np.abs(d)

    def solve(h, v, a, j):
        return trapezoid(h, v, a) if j is None else scurve(h, v, a, j)

    if mode in ("slew", "sequential"):
        profs = [solve(ad[i], vm[i], am[i], None if jm is None else jm[i]) if ad[i] > 0 else _stationary(0.0)
                 for i in range(n)]
        if mode == "slew":
            starts = np.zeros(n)
        else:
            durs = np.array([p.duration for p in profs])
            starts = np.concatenate(([0.0], np.cumsum(durs)[:-1]))
        return AxisProfiles(profs, starts, signs, mode)

    length = float(np.sqrt(np.sum(ad * ad)))
    if length == 0.0:
        return AxisProfiles([_stationary(0.0) for _ in range(n)], np.zeros(n), signs, mode)
    u = ad / length
    moving = u > 0.0
    v_path = float(np.min(vm[moving] / u[moving]))
    a_path = float(np.min(am[moving] / u[moving]))
    j_path = None if jm is None else float(np.min(jm[moving] / u[moving]))
    path = solve(length, v_path, a_path, j_path)
    profs = [_scaled(path, float(u[i])) for i in range(n)]
    return AxisProfiles(profs, np.zeros(n), signs, mode)
