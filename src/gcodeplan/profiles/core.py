"""The Profile object every builder returns, argument checks, and the sampling kernel.

A profile is a list of pieces; on piece k, with tau = t - t0[k] in [0, dt[k]]:

    q = p0 + v0·tau + a0·tau²/2 + j·tau³/6,  v = v0 + a0·tau + j·tau²/2,  a = a0 + j·tau

which covers trapezoids (j = 0), S-curves (a0 continuous) and parabolic blends alike (SEGMENT_DTYPE's form).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from .._jit import njit
import numpy as np

PIECE_DTYPE = np.dtype([("t0", "f8"), ("dt", "f8"), ("p0", "f8"), ("v0", "f8"), ("a0", "f8"), ("j", "f8")])

# A piece shorter than this fraction of the profile is listed as merged into its neighbour in Profile.phases
# (rounding leaves e.g. 1e-19 s constant-acceleration phases exactly at a case boundary).
PHASE_MERGE_RTOL = 1e-12


class InfeasibleProfile(ValueError):
    """No forward-only motion reaches v_end within the distance under the limits."""


# --------------------------------------------------------------------------- argument checks
def check_limit(name: str, value, allow_inf: bool = False) -> float:
    """A limit must be a positive number (inf only where `allow_inf`)."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if math.isnan(x):
        raise ValueError(f"{name} must be a number, got NaN")
    if x <= 0.0:
        raise ValueError(f"{name} must be > 0, got {x:g}")
    if math.isinf(x) and not allow_inf:
        raise ValueError(f"{name} must be finite, got {x:g}")
    return x


def check_distance(name: str, value) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(x):
        raise ValueError(f"{name} must be a finite number, got {x:g}")
    if x < 0.0:
        raise ValueError(f"{name} must be >= 0 (profiles move forward; flip the sign yourself), got {x:g}")
    return x


def check_speed(name: str, value, v_max: float) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if math.isnan(x):
        raise ValueError(f"{name} must be a number, got NaN")
    if x < 0.0:
        raise ValueError(f"{name} must be >= 0, got {x:g}")
    if x > v_max:
        raise ValueError(f"{name} = {x:g} exceeds v_max = {v_max:g}")
    return x


def check_array(name: str, arr: np.ndarray, positive: bool, allow_inf: bool) -> None:
    """Vectorised form of the checks above for the batch functions."""
    if np.isnan(arr).any():
        raise ValueError(f"{name} contains NaN")
    if positive:
        if not (arr > 0.0).all():
            raise ValueError(f"{name} must be > 0 everywhere, got {arr[~(arr > 0.0)][0]:g}")
    elif not (arr >= 0.0).all():
        raise ValueError(f"{name} must be >= 0 everywhere, got {arr[~(arr >= 0.0)][0]:g}")
    if not allow_inf and np.isinf(arr).any():
        raise ValueError(f"{name} must be finite everywhere")


def check_batch_args(distance: np.ndarray, v_max: np.ndarray, limits: dict[str, np.ndarray],
                     v_start: np.ndarray, v_end: np.ndarray) -> None:
    """The batch solvers' argument checks: ValueError naming the first bad argument. ``limits``
    maps accel/decel/jerk names to arrays that must be positive and finite."""
    check_array("distance", distance, positive=False, allow_inf=False)
    check_array("v_max", v_max, positive=True, allow_inf=True)
    for name, arr in limits.items():
        check_array(name, arr, positive=True, allow_inf=False)
    check_array("v_start", v_start, positive=False, allow_inf=False)
    check_array("v_end", v_end, positive=False, allow_inf=False)
    if (v_start > v_max).any():
        raise ValueError("v_start exceeds v_max")
    if (v_end > v_max).any():
        raise ValueError("v_end exceeds v_max")


def batch_arrays(**named) -> tuple[tuple[int, ...], list[np.ndarray]]:
    """Broadcast the named arguments together; return the shape and flat contiguous float64 copies."""
    try:
        arrs = np.broadcast_arrays(*[np.asarray(v, dtype=np.float64) for v in named.values()])
    except ValueError as err:
        raise ValueError(f"arguments {', '.join(named)} do not have compatible shapes: {err}") from None
    shape = arrs[0].shape
    return shape, [np.ascontiguousarray(a).reshape(-1) for a in arrs]


# --------------------------------------------------------------------------- the one piece evaluator
# Every polynomial piece in the package (Profile pieces, SEGMENT rows, stepper pieces) is evaluated by these
# three functions; callable from numba kernels on floats and from Python on NumPy arrays (broadcasting).
@njit(cache=True)
def piece_position(p, v, a, j, tau):
    """Position p + v·τ + a·τ²/2 + j·τ³/6 (mm), Horner form; τ in s from the piece's start."""
    return p + tau * (v + tau * (0.5 * a + tau * (j * (1.0 / 6.0))))


@njit(cache=True)
def piece_velocity(v, a, j, tau):
    """Velocity v + a·τ + j·τ²/2 (mm/s)."""
    return v + tau * (a + 0.5 * j * tau)


@njit(cache=True)
def piece_acceleration(a, j, tau):
    """Acceleration a + j·τ (mm/s²); the jerk is j itself."""
    return a + j * tau


# --------------------------------------------------------------------------- sampling
@njit(cache=True)
def _sample_pieces(t, t0, dt, p0, v0, a0, jerk, pos, vel, acc, jrk):
    n = t0.shape[0]
    t_end = t0[n - 1] + dt[n - 1]
    for i in range(t.shape[0]):
        ti = min(max(t[i], 0.0), t_end)
        k = np.searchsorted(t0, ti, side="right") - 1
        if k < 0:
            k = 0
        tau = min(max(ti - t0[k], 0.0), dt[k])
        j = jerk[k]
        a = a0[k]
        v = v0[k]
        pos[i] = piece_position(p0[k], v, a, j, tau)
        vel[i] = piece_velocity(v, a, j, tau)
        acc[i] = piece_acceleration(a, j, tau)
        jrk[i] = j


@dataclass(frozen=True, eq=False)
class Profile:
    """A solved 1-D motion from position `p_start` at t = 0 to its end at t = duration.

    kind: "trapezoid", "scurve", "timed-scurve", "via-points", "stationary", ...
    phase_value: "accel" (phases are (duration s, acceleration mm/s²)) or "jerk" ((duration s, jerk mm/s³)).
    pieces: PIECE_DTYPE rows (t0, dt, p0, v0, a0, j), all of them, zero-length ones included.
    """

    kind: str
    phase_value: str
    pieces: np.ndarray
    distance: float
    v_start: float
    v_end: float
    peak_velocity: float
    limits: dict = field(default_factory=dict)
    info: dict = field(default_factory=dict)

    @property
    def duration(self) -> float:
        """s, total time."""
        return float(self.pieces["t0"][-1] + self.pieces["dt"][-1])

    @property
    def p_start(self) -> float:
        return float(self.pieces["p0"][0])

    @property
    def phases(self) -> list[tuple[float, float]]:
        """[(duration s, jerk or accel)], zero-length pieces merged away and equal neighbours joined."""
        tiny = PHASE_MERGE_RTOL * max(self.duration, 1e-300)
        value = self.pieces["j"] if self.phase_value == "jerk" else self.pieces["a0"]
        out: list[list[float]] = []
        carry = 0.0   # duration of dropped tiny pieces before the first kept one
        for dt, val in zip(self.pieces["dt"].tolist(), value.tolist()):
            if dt <= tiny:
                if out:
                    out[-1][0] += dt
                else:
                    carry += dt
                continue
            if out and out[-1][1] == val:
                out[-1][0] += dt
            else:
                out.append([dt + carry, val])
                carry = 0.0
        return [(d, v) for d, v in out]

    def sample(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(position mm, velocity mm/s, acceleration mm/s², jerk mm/s³) at the times t (s, array-like).

        Times outside [0, duration] are clamped (the profile holds its end state). Jerk is the piece's jerk
        (0 for trapezoids and blends); at a piece boundary the later piece's values are reported."""
        ta = np.asarray(t, dtype=np.float64)
        if np.isnan(ta).any():
            raise ValueError("t contains NaN")
        flat = np.ascontiguousarray(ta).reshape(-1)
        out = [np.empty_like(flat) for _ in range(4)]
        pc = self.pieces
        _sample_pieces(flat, np.ascontiguousarray(pc["t0"]), np.ascontiguousarray(pc["dt"]),
                       np.ascontiguousarray(pc["p0"]), np.ascontiguousarray(pc["v0"]),
                       np.ascontiguousarray(pc["a0"]), np.ascontiguousarray(pc["j"]), *out)
        pos, vel, acc, jrk = (o.reshape(ta.shape) for o in out)
        return pos, vel, acc, jrk

    def phase_table(self) -> list[dict]:
        """One row per phase of `phases`: start time, duration, value, and position/velocity/acceleration at
        its end (what `gcodeplan profile` prints)."""
        rows = []
        t = 0.0
        for dt, val in self.phases:
            end = t + dt
            p, v, a, _ = self.sample(np.array([end]))
            rows.append({"t_start": t, "duration": dt, self.phase_value: val,
                         "position_end": float(p[0]), "velocity_end": float(v[0]), "accel_end": float(a[0])})
            t = end
        return rows

    def __repr__(self) -> str:
        return (f"Profile({self.kind}, distance={self.distance:g}, duration={self.duration:.9g} s, "
                f"v_start={self.v_start:g}, peak={self.peak_velocity:g}, v_end={self.v_end:g}, "
                f"{len(self.phases)} phases)")


def build_profile(kind: str, phase_value: str, dt, jerk, a0=None, v_start: float = 0.0, p_start: float = 0.0,
                  limits: dict | None = None, info: dict | None = None,
                  distance: float | None = None, peak_velocity: float | None = None,
                  v_end: float | None = None) -> Profile:
    """Integrate pieces (durations, jerks, and start accelerations or None to carry the acceleration on from 0)
    into a Profile. The end speed, distance and peak come out of the integration unless given."""
    dt = np.asarray(dt, dtype=np.float64)
    n = dt.shape[0]
    pcs = np.zeros(max(n, 1), dtype=PIECE_DTYPE)
    jerk = np.broadcast_to(np.asarray(jerk, dtype=np.float64), (n,))
    t = 0.0
    p = p_start
    v = v_start
    a = 0.0
    peak = v_start
    for k in range(n):
        if a0 is not None:
            a = float(a0[k])
        d = float(dt[k])
        j = float(jerk[k])
        pcs[k] = (t, d, p, v, a, j)
        # peak inside the piece: where v' = a + j·tau = 0
        if j != 0.0 and 0.0 < -a / j < d:
            tau = -a / j
            peak = max(peak, v + a * tau + j * tau * tau / 2.0)
        p += v * d + a * d * d / 2.0 + j * d * d * d / 6.0
        v += a * d + j * d * d / 2.0
        a += j * d
        t += d
        peak = max(peak, v)
    if n == 0:
        pcs[0] = (0.0, 0.0, p_start, v_start, 0.0, 0.0)
    return Profile(kind=kind, phase_value=phase_value, pieces=pcs,
                   distance=float(p - p_start) if distance is None else float(distance),
                   v_start=float(v_start), v_end=float(v if v_end is None else v_end),
                   peak_velocity=float(peak if peak_velocity is None else peak_velocity),
                   limits=dict(limits or {}), info=dict(info or {}))
