"""Pressure advance: the extruder position as Klipper's kin_extruder.c computes it.

Klipper's model (kinematics/extruder.py, chelper/kin_extruder.c):

* the advanced position is ``pa(t) = e(t) + K·ė(t)`` on moves that extrude (E ratio > 0) *and* move X or
  Y; on every other move (retractions, unretractions, extrude-only moves, Z-only moves, travels) it is
  ``e(t)``: Klipper's ``can_pressure_advance`` flag, ``axis_r > 0 and (axes_d[0] or axes_d[1])``;
* the motor follows a triangular-weighted average of it over ±h, h = smooth_time/2:
  ``e_s(t) = ∫ pa(x)·(h − |t − x|) dx / h²`` over [t − h, t + h];
* with K = 0 Klipper turns the smoothing off too (smooth time 0): the motor follows e(t) exactly.

Exact form used here: the triangle is two boxes convolved, so ``e_s(t) = (Q(t+h) − 2Q(t) + Q(t−h))/h²``
for any Q with Q'' = pa. pa is piecewise polynomial (degree ≤ 3), so on every interval between the
merged breakpoints {b_k − h, b_k, b_k + h} e_s is one polynomial of degree ≤ 5 (4 for trapezoids):
:func:`smooth_pieces` builds its power-basis coefficients with Q taken locally (second antiderivative
from the start of the leftmost piece in the window, values measured from that piece's start value, so
no large numbers cancel), and :func:`gcodeplan.stepper.kernel.gen_steps_poly` finds every half-step
crossing exactly (monotone stretches from the derivative's roots, then bracketed Newton).
"""
from __future__ import annotations

import math

from .._jit import njit
import numpy as np

DEGREE = 5            # of the smoothed pieces
NCOEF = DEGREE + 1


@njit(cache=True, inline="always")
def _taylor_shift(c, n, d, out):
    """Coefficients (power basis in s) of Σ c[m]·(d + s)^m, m < n, into out[:n] (repeated synthetic division)."""
    for m in range(n):
        out[m] = c[m]
    for i in range(n - 1):
        for m in range(n - 2, i - 1, -1):
            out[m] += d * out[m + 1]


@njit(cache=True)
def smooth_pieces(t0, dt, pa, h, u_from, u_to, out_t0, out_dt, out_c):
    """Smoothed extruder pieces for u in [u_from, u_to); returns how many were written.

    ``pa[k, 0..3]``: the advanced position on piece k as c0 + c1·σ + c2·σ² + c3·σ³, σ = t − t0[k] (mm, s).
    Pieces must be contiguous and cover [u_from − h, u_to + h] (the caller adds rest pieces at the ends).
    ``out_c[m, 0..5]``: e_s(out_t0[m] + s) = Σ out_c[m, i]·s^i.
    """
    n = t0.shape[0]
    cap = out_t0.shape[0]
    inv_h2 = 1.0 / (h * h)
    delta = np.array([-h, 0.0, h])
    wgt = np.array([1.0, -2.0, 1.0])
    ptr = np.empty(3, np.int64)
    for c in range(3):
        k = np.searchsorted(t0, u_from + delta[c], side="right") - 1
        ptr[c] = max(0, min(k, n - 1))
    r_c = np.zeros(NCOEF)       # R_k(σ) = ∫0^σ (σ − y)(pa_k(y) − base) dy, power basis
    sh = np.zeros(NCOEF)
    acc = np.zeros(NCOEF)
    u = u_from
    m = 0
    while u < u_to and m < cap:
        nxt = u_to
        for c in range(3):
            k = ptr[c]
            b = (t0[k] + dt[k] - delta[c]) if k < n - 1 else math.inf
            if b < nxt:
                nxt = b
        if nxt > u:
            k_lo = ptr[0]
            base = pa[k_lo, 0]
            for i in range(NCOEF):
                acc[i] = 0.0
            # walk the pieces k_lo..ptr[2], carrying Q(b_k) and Q'(b_k) (Q from b_{k_lo}, values − base)
            q0 = 0.0
            q1 = 0.0
            for k in range(k_lo, ptr[2] + 1):
                c0 = pa[k, 0] - base
                c1 = pa[k, 1]
                c2 = pa[k, 2]
                c3 = pa[k, 3]
                for c in range(3):
                    if ptr[c] != k:
                        continue
                    d = u + delta[c] - t0[k]
                    # Q(b_k + d + s) = q0 + q1·(d + s) + R_k(d + s)
                    r_c[0] = 0.0
                    r_c[1] = 0.0
                    r_c[2] = c0 * 0.5
                    r_c[3] = c1 / 6.0
                    r_c[4] = c2 / 12.0
                    r_c[5] = c3 / 20.0
                    _taylor_shift(r_c, NCOEF, d, sh)
                    w = wgt[c]
                    acc[0] += w * (q0 + q1 * d + sh[0])
                    acc[1] += w * (q1 + sh[1])
                    for i in range(2, NCOEF):
                        acc[i] += w * sh[i]
                if k < ptr[2]:
                    L = dt[k]
                    # Q(b_{k+1}) = Q(b_k) + Q'(b_k)·L + R_k(L); Q'(b_{k+1}) = Q'(b_k) + ∫0^L pa_k
                    rl = L * L * (c0 * 0.5 + L * (c1 / 6.0 + L * (c2 / 12.0 + L * c3 / 20.0)))
                    il = L * (c0 + L * (c1 * 0.5 + L * (c2 / 3.0 + L * c3 * 0.25)))
                    q0 = q0 + q1 * L + rl
                    q1 = q1 + il
            out_t0[m] = u
            out_dt[m] = nxt - u
            for i in range(NCOEF):
                out_c[m, i] = acc[i] * inv_h2
            out_c[m, 0] += base
            m += 1
        for c in range(3):
            k = ptr[c]
            b = (t0[k] + dt[k] - delta[c]) if k < n - 1 else math.inf
            if b <= nxt:
                ptr[c] = k + 1
        u = nxt
    return m


@njit(cache=True)
def advanced_coefficients(pe, ve, ae, je, k_pa, out):
    """pa = e + K·ė per piece in power basis: c0 = p + K·v, c1 = v + K·a, c2 = a/2 + K·j/2, c3 = j/6.

    ``k_pa[k]``: K (s) on piece k, already 0 where Klipper does not advance (its can_pressure_advance).
    """
    for k in range(pe.shape[0]):
        kk = k_pa[k]
        out[k, 0] = pe[k] + kk * ve[k]
        out[k, 1] = ve[k] + kk * ae[k]
        out[k, 2] = 0.5 * ae[k] + 0.5 * kk * je[k]
        out[k, 3] = je[k] / 6.0


class SmoothedStream:
    """Streams contiguous extruder pieces through Klipper's pressure advance, half window ``h`` (s).

    ``feed(t0, dt, pe, ve, ae, je, k_pa)`` returns (t0, dt, coef[n, 6]) for the times already complete
    (those whose window [t − h, t + h] lies inside the data seen); ``finish()`` the rest, the extruder at
    rest after the end. The extruder rests before the first piece. ``start_u``: no output before it.
    """

    def __init__(self, h: float, start_u: float = -math.inf):
        self.h = float(h)
        self.t0 = np.zeros(0)
        self.dt = np.zeros(0)
        self.pa = np.zeros((0, 4))
        self.u_done = start_u
        self.started = False

    def _append(self, t0, dt, pa):
        self.t0 = np.concatenate([self.t0, t0])
        self.dt = np.concatenate([self.dt, dt])
        self.pa = np.concatenate([self.pa, pa])

    def _emit(self, u_to):
        if not u_to > self.u_done or len(self.t0) == 0:
            return np.zeros(0), np.zeros(0), np.zeros((0, NCOEF))
        cap = 3 * len(self.t0) + 3
        out_t0 = np.empty(cap)
        out_dt = np.empty(cap)
        out_c = np.empty((cap, NCOEF))
        m = smooth_pieces(self.t0, self.dt, self.pa, self.h, self.u_done, u_to, out_t0, out_dt, out_c)
        self.u_done = u_to
        end = self.t0 + self.dt
        keep = min(int(np.searchsorted(end, self.u_done - self.h, side="right")), len(self.t0) - 1)
        self.t0, self.dt, self.pa = self.t0[keep:], self.dt[keep:], self.pa[keep:]
        return out_t0[:m].copy(), out_dt[:m].copy(), out_c[:m].copy()

    def feed(self, t0, dt, pe, ve, ae, je, k_pa):
        """Add contiguous pieces (E position coefficients, K per piece); the smoothed pieces now complete."""
        if len(t0) == 0:
            return self._emit(-math.inf)
        pa = np.empty((len(t0), 4))
        advanced_coefficients(pe, ve, ae, je, np.ascontiguousarray(k_pa, np.float64), pa)
        if not self.started:
            # rest before the first piece, long enough for the whole window
            start = float(t0[0])
            self._append(np.array([start - 4.0 * self.h]), np.array([4.0 * self.h]),
                         np.array([[pe[0], 0.0, 0.0, 0.0]]))
            self.u_done = max(self.u_done, start - self.h)
            self.started = True
        self._append(np.asarray(t0, np.float64), np.asarray(dt, np.float64), pa)
        end = float(self.t0[-1] + self.dt[-1])
        return self._emit(end - self.h)

    def finish(self):
        """The remaining smoothed pieces, the extruder at rest after its last piece."""
        if not self.started or len(self.t0) == 0:
            return np.zeros(0), np.zeros(0), np.zeros((0, NCOEF))
        k = len(self.t0) - 1
        L = self.dt[k]
        c = self.pa[k]
        # rest at the end position (K·ė is 0 at rest): e(end) from the unadvanced polynomial is not kept,
        # but pa at the end of a move that ends at rest equals e there
        e_end = c[0] + L * (c[1] + L * (c[2] + L * c[3]))
        end = float(self.t0[-1] + self.dt[-1])
        self._append(np.array([end]), np.array([4.0 * self.h]), np.array([[e_end, 0.0, 0.0, 0.0]]))
        return self._emit(end + self.h)

    @property
    def end_u(self) -> float:
        """Where the output emitted so far ends (s)."""
        return self.u_done
