"""Evaluate SEGMENT pieces on a time grid: position, velocity, acceleration, jerk per axis.

In a piece, q(τ) = p + v·τ + a·τ²/2 + j·τ³/6 (τ = t − t0), so q' = v + a·τ + j·τ²/2,
q'' = a + j·τ, q''' = j. Before the first piece the machine rests at its start, after a piece
that is not followed by another (the end, or a gap) it rests where that piece ended.
"""
from __future__ import annotations

from .._jit import njit
import numpy as np

from ..profiles.core import piece_acceleration, piece_position, piece_velocity

# a time this far past a piece's end still belongs to it (the next piece's t0 is a rounded sum)
_END_SLACK_T = 1e-9


@njit(cache=True)
def _sample_kernel(t0, dt, p, v, a, j, times, o_pos, o_vel, o_acc, o_jerk):
    n = t0.shape[0]
    k = 0
    for m in range(times.shape[0]):
        t = times[m]
        while k + 1 < n and t0[k + 1] <= t:
            k += 1
        tau = t - t0[k]
        at_rest = False
        if tau < 0.0:
            tau = 0.0
            at_rest = True
        elif tau > dt[k] + _END_SLACK_T:
            tau = dt[k]
            at_rest = True
        for ax in range(4):
            o_pos[m, ax] = piece_position(p[k, ax], v[k, ax], a[k, ax], j[k, ax], tau)
            if at_rest:
                o_vel[m, ax] = 0.0
                o_acc[m, ax] = 0.0
                o_jerk[m, ax] = 0.0
            else:
                o_vel[m, ax] = piece_velocity(v[k, ax], a[k, ax], j[k, ax], tau)
                o_acc[m, ax] = piece_acceleration(a[k, ax], j[k, ax], tau)
                o_jerk[m, ax] = j[k, ax]


def sample_segments(segs: np.ndarray, times) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(pos, vel, acc, jerk), each (len(times), 4) for x, y, z, e.

    ``times`` (s) must be sorted ascending (one forward sweep over the pieces: ``np.sort`` them first)
    and not NaN; otherwise a ValueError says which entry is out of order."""
    times = np.ascontiguousarray(np.asarray(times, dtype=np.float64).reshape(-1))
    if np.isnan(times).any():
        k = int(np.flatnonzero(np.isnan(times))[0])
        raise ValueError(f"sample times must be numbers: times[{k}] is NaN")
    if times.size > 1:
        back = np.flatnonzero(np.diff(times) < 0.0)
        if back.size:
            k = int(back[0]) + 1
            raise ValueError(f"sample times must be sorted ascending (np.sort them first): times[{k}] = "
                             f"{float(times[k])!r} comes after times[{k - 1}] = {float(times[k - 1])!r}")
    shape = (times.size, 4)
    out = [np.zeros(shape) for _ in range(4)]
    segs = np.asarray(segs)
    if len(segs) == 0 or times.size == 0:
        return tuple(out)
    if np.any(np.diff(segs["t0"]) < 0.0):
        raise ValueError("sample_segments: segments must be in time order")
    col = lambda pre: np.stack([segs[pre + ax] for ax in "xyze"], axis=1)  # noqa: E731
    _sample_kernel(np.ascontiguousarray(segs["t0"]), np.ascontiguousarray(segs["dt"]), col("p"), col("v"),
                   col("a"), col("j"), times, *out)
    return tuple(out)
