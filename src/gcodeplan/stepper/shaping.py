"""Input shaping: the commanded X/Y position as Klipper's input shaper turns it before the kinematics.

Klipper's kin_shaper.c replaces an axis position x(t) by a weighted sum of
time-shifted copies, ``x_s(t) = Σ a_i · x(t + τ_i)`` (Σ a_i = 1). The pulses come
from the shaper's amplitudes A and delays T (Klipper's shaper_defs.py, formulas
in :func:`shaper_coefficients`) in three steps (kin_shaper.c ``init_shaper``):
normalise (a_i = A_(n−1−i)/ΣA), reverse (τ_i = −T_(n−1−i)) and centre
(τ_i −= Σ a_j τ_j), so the shaped motion neither leads nor lags on average.

x(t) is the planner's piecewise-cubic path, at rest before the first piece and
after the last (Klipper's trapq holds zero-velocity moves there), so x_s is
again piecewise cubic with breakpoints at every original breakpoint shifted by
every −τ_i: :func:`shape_pieces` merges them and sums the re-based cubics, and
the exact step kernel steps the result. Z and E are not shaped (Klipper shapes
X and Y only unless its shaper_freq_z is set, which gcodeplan refuses).

Planned times are not touched: shaping acts between the plan and the steps.
"""
from __future__ import annotations

import math

from .._jit import njit
import numpy as np

from ..errors import ConfigError
from ..schema import SEGMENT_DTYPE

# numeric codes of the shaper types (LIMITS.shaper_type_x/_y), 0 = no shaping on that axis
from ..machine import SHAPER_TYPE_CODES as SHAPER_CODES  # noqa: E402
from ..machine import SHAPER_TYPES  # noqa: E402,F401
DEFAULT_SHAPER = "mzv"           # Klipper's input_shaper.py default shaper_type
DEFAULT_DAMPING = 0.1            # Klipper's shaper_defs DEFAULT_DAMPING_RATIO
VIBRATION_TOLERANCE = 1.0 / 20.0  # Klipper's 1 / SHAPER_VIBRATION_REDUCTION (ei shapers)
MAX_PULSES = 5

# Klipper's 2hump_ei / 3hump_ei shapers: delays (in units of 1/f) and amplitudes as cubic polynomials
# in the damping ratio (coefficients of ζ⁰..ζ³, one row per pulse): shaper_defs.py
_HUMP2_T = ((0.0, 0.0, 0.0, 0.0), (0.49890, 0.16270, -0.54262, 6.16180), (0.99748, 0.18382, -1.58270, 8.17120),
            (1.49920, -0.09297, -0.28338, 1.85710))
_HUMP2_A = ((0.16054, 0.76699, 2.26560, -1.22750), (0.33911, 0.45081, -2.58080, 1.73650),
            (0.34089, -0.61533, -0.68765, 0.42261), (0.15997, -0.60246, 1.00280, -0.93145))
_HUMP3_T = ((0.0, 0.0, 0.0, 0.0), (0.49974, 0.23834, 0.44559, 12.4720), (0.99849, 0.29808, -2.36460, 23.3990),
            (1.49870, 0.10306, -2.01390, 17.0320), (1.99960, -0.28231, 0.61536, 5.40450))
_HUMP3_A = ((0.11275, 0.76632, 3.29160, -1.44380), (0.23698, 0.61164, -2.57850, 4.85220),
            (0.30008, -0.19062, -2.14560, 0.13744), (0.23775, -0.73297, 0.46885, -2.08650),
            (0.11244, -0.45439, 0.96382, -1.46000))
# Klipper's limits: max damping ratio per shaper (shaper_defs.INPUT_SHAPERS)
MAX_DAMPING = {"zv": 0.99, "mzv": 0.99, "zvd": 0.99, "ei": 0.4, "2hump_ei": 0.3, "3hump_ei": 0.2}


def _poly_in_damping(c: tuple[float, ...], zeta: float) -> float:
    """c0 + c1·ζ + c2·ζ² + c3·ζ³ (Horner)."""
    out = 0.0
    for coef in reversed(c):
        out = out * zeta + coef
    return out


def shaper_coefficients(name: str, freq_hz: float, damping: float = DEFAULT_DAMPING) -> tuple[list[float], list[float]]:
    """Klipper's shaper (amplitudes A, delays T in s) for ``name`` at ``freq_hz`` with damping ratio ζ.

    With d = √(1 − ζ²), t_d = 1/(f·d) the damped period:

    * zv: K = exp(−ζπ/d); A = 1, K; T = 0, t_d/2.
    * mzv: K = exp(−¾ζπ/d); A = 1 − 1/√2, (√2 − 1)·K, (1 − 1/√2)·K²; T = 0, ⅜t_d, ¾t_d.
    * zvd: K = exp(−ζπ/d); A = 1, 2K, K²; T = 0, t_d/2, t_d.
    * ei (vibration tolerance V = 5 %): amplitudes and middle delay as Klipper's fitted polynomials
      in V and ζ; T = 0, t2·t_d, t_d.
    * 2hump_ei, 3hump_ei: delays (×1/f) and amplitudes as Klipper's cubic polynomials in ζ.

    Source: Klipper's klippy/extras/shaper_defs.py (as of v0.13); ``freq_hz`` ≤ 0 gives no pulses.
    """
    if name not in SHAPER_CODES or name == "none":
        raise ConfigError(f"shaper type {name!r} is not one of {', '.join(SHAPER_TYPES[1:])}")
    if not (freq_hz > 0.0 and math.isfinite(freq_hz)):
        return [], []
    z = damping
    df = math.sqrt(1.0 - z * z)
    t_d = 1.0 / (freq_hz * df)
    if name == "zv":
        k = math.exp(-z * math.pi / df)
        return [1.0, k], [0.0, 0.5 * t_d]
    if name == "mzv":
        k = math.exp(-0.75 * z * math.pi / df)
        a1 = 1.0 - 1.0 / math.sqrt(2.0)
        return [a1, (math.sqrt(2.0) - 1.0) * k, a1 * k * k], [0.0, 0.375 * t_d, 0.75 * t_d]
    if name == "zvd":
        k = math.exp(-z * math.pi / df)
        return [1.0, 2.0 * k, k * k], [0.0, 0.5 * t_d, t_d]
    if name == "ei":
        v = VIBRATION_TOLERANCE
        a1 = (0.24968 + 0.24961 * v) + ((0.80008 + 1.23328 * v) + (0.49599 + 3.17316 * v) * z) * z
        a3 = (0.25149 + 0.21474 * v) + ((-0.83249 + 1.41498 * v) + (0.85181 - 4.90094 * v) * z) * z
        t2 = 0.4999 + (((0.46159 + 8.57843 * v) * v)
                       + (((4.26169 - 108.644 * v) * v) + ((1.75601 + 336.989 * v) * v) * z) * z) * z
        return [a1, 1.0 - a1 - a3, a3], [0.0, t2 * t_d, t_d]
    tt, aa = (_HUMP2_T, _HUMP2_A) if name == "2hump_ei" else (_HUMP3_T, _HUMP3_A)
    period = 1.0 / freq_hz
    return [_poly_in_damping(c, z) for c in aa], [_poly_in_damping(c, z) * period for c in tt]


def shaper_pulses(name: str, freq_hz: float, damping: float = DEFAULT_DAMPING) -> tuple[np.ndarray, np.ndarray]:
    """(weights a_i, time shifts τ_i in s) with x_s(t) = Σ a_i·x(t + τ_i): Klipper's kin_shaper.c init_shaper.

    Normalised (Σ a = 1), reversed (τ_i = −T_(n−1−i)) and centred (Σ a_i τ_i = 0). Empty for no shaping.
    """
    amps, delays = shaper_coefficients(name, freq_hz, damping)
    n = len(amps)
    if n == 0:
        return np.zeros(0), np.zeros(0)
    inv = 1.0 / sum(amps)
    a = np.array([amps[n - 1 - i] * inv for i in range(n)])
    tau = np.array([-delays[n - 1 - i] for i in range(n)])
    centre = 0.0
    for i in range(n):
        centre += a[i] * tau[i]
    return a, tau - centre


def check_shaper(name: str, freq_hz: float, damping: float, where: str) -> None:
    """ConfigError unless Klipper's input_shaper would accept the setting (type known, f ≥ 0, ζ in its range)."""
    if name not in SHAPER_CODES or name == "none":
        raise ConfigError(f"{where}: shaper type {name!r} is not supported (known: {', '.join(SHAPER_TYPES[1:])})")
    if not (freq_hz >= 0.0 and math.isfinite(freq_hz)):
        raise ConfigError(f"{where}: shaper frequency must be ≥ 0 Hz (0 = off), got {freq_hz!r}")
    if not (0.0 <= damping < 1.0):
        raise ConfigError(f"{where}: damping ratio must be in [0, 1), got {damping!r}")
    if freq_hz > 0.0 and damping > MAX_DAMPING[name]:
        raise ConfigError(f"{where}: damping ratio {damping:g} is above {MAX_DAMPING[name]:g}, the maximum of "
                          f"Klipper's {name} shaper")


# ------------------------------------------------------------------------ the shaped path (numba)

@njit(cache=True)
def shape_pieces(t0, dt, pc, vc, ac, jc, ch_axis, ch_w, ch_tau, u_from, u_to, rest_before, rest_after,
                 out_t0, out_dt, out_p, out_v, out_a, out_j, out_move, moves):
    """Shaped pieces of the path for u in [u_from, u_to): returns how many were written.

    Input pieces (time order, contiguous): axis q of piece k is ``pc[k,q] + vc[k,q]·τ + ac[k,q]·τ²/2 +
    jc[k,q]·τ³/6`` for τ = t − t0[k] in [0, dt[k]] (mm, s). Channel c adds ``ch_w[c]·q(u + ch_tau[c])`` to
    axis ``ch_axis[c]`` (an unshaped axis is one channel of weight 1 and shift 0). Before the first piece
    the path rests at its start when ``rest_before`` (else the first piece is extended), after the last at its
    end when ``rest_after``. An output piece ends at every shifted input breakpoint, so each is the sum
    of the channels' cubics re-based at its start: exact, not sampled. ``out_move`` gets the ``moves``
    entry of the piece the first unshifted channel (z or e) reads, for bookkeeping.
    """
    n = t0.shape[0]
    n_ch = ch_axis.shape[0]
    cap = out_t0.shape[0]
    ptr = np.empty(n_ch, np.int64)
    bnd = np.empty(n_ch)          # where each channel's current piece ends (u), shared by both passes below
    end_t = t0[n - 1] + dt[n - 1]
    for c in range(n_ch):
        x = u_from + ch_tau[c]
        k = np.searchsorted(t0, x, side="right") - 1
        if k < 0:
            k = -1 if rest_before else 0
        elif k >= n - 1 and x >= end_t and rest_after:
            k = n
        ptr[c] = k
    u = u_from
    m = 0
    while u < u_to and m < cap:
        nxt = u_to
        for c in range(n_ch):
            k = ptr[c]
            if k == -1:
                b = t0[0] - ch_tau[c]
            elif k < n:
                b = (t0[k] + dt[k] - ch_tau[c]) if (k < n - 1 or rest_after) else math.inf
            else:
                b = math.inf
            bnd[c] = b
            if b < nxt:
                nxt = b
        if nxt > u:
            for q in range(4):
                out_p[m, q] = 0.0
                out_v[m, q] = 0.0
                out_a[m, q] = 0.0
                out_j[m, q] = 0.0
            src = -1
            for c in range(n_ch):
                k = ptr[c]
                q = ch_axis[c]
                w = ch_w[c]
                if k == -1:
                    out_p[m, q] += w * pc[0, q]
                    if src < 0 and ch_tau[c] == 0.0:
                        src = 0
                    continue
                if k >= n:
                    s = dt[n - 1]
                    out_p[m, q] += w * (pc[n - 1, q] + s * (vc[n - 1, q] + s * (0.5 * ac[n - 1, q]
                                                                               + s * jc[n - 1, q] / 6.0)))
                    if src < 0 and ch_tau[c] == 0.0:
                        src = n - 1
                    continue
                s = u + ch_tau[c] - t0[k]
                p = pc[k, q]
                v = vc[k, q]
                a = ac[k, q]
                j = jc[k, q]
                out_p[m, q] += w * (p + s * (v + s * (0.5 * a + s * j / 6.0)))
                out_v[m, q] += w * (v + s * (a + 0.5 * j * s))
                out_a[m, q] += w * (a + j * s)
                out_j[m, q] += w * j
                if src < 0 and ch_tau[c] == 0.0:
                    src = k
            out_t0[m] = u
            out_dt[m] = nxt - u
            out_move[m] = moves[src] if src >= 0 else -1
            m += 1
        # every channel whose piece ends here moves on to the next piece
        for c in range(n_ch):
            if bnd[c] <= nxt:
                ptr[c] = ptr[c] + 1
        u = nxt
    return m


# ------------------------------------------------------------------------ streaming driver

_AX = ("x", "y", "z", "e")


def _columns(segments: np.ndarray, prefix: str) -> np.ndarray:
    return np.ascontiguousarray(np.column_stack([segments[prefix + a] for a in _AX]), dtype=np.float64)


class ShapedStream:
    """Shapes a stream of contiguous SEGMENT batches with fixed pulses.

    ``pulses_x``/``pulses_y``: (weights, shifts) from :func:`shaper_pulses` (empty = unshaped axis).
    ``feed(batch)`` returns the shaped pieces it can already compute (those whose every shifted copy falls
    inside the data seen so far); ``finish()`` the rest, with the path at rest after its end. The path is
    at rest before its first piece. ``start_u``: no output before this time (s) (the previous stream's
    end after a shaper change: Klipper generates each step once). Output: :class:`Pieces` (or SEGMENT
    rows with :func:`as_segments`).
    """

    def __init__(self, pulses_x, pulses_y, start_u: float = -math.inf):
        axes, w, tau = [], [], []
        for q, (a, t) in enumerate((pulses_x, pulses_y)):
            if len(a) == 0:
                axes.append(q), w.append(1.0), tau.append(0.0)
            else:
                axes += [q] * len(a)
                w += list(a)
                tau += list(t)
        # z and e pass through; e first so that out_move follows the unshifted path
        axes += [3, 2]
        w += [1.0, 1.0]
        tau += [0.0, 0.0]
        self.ch_axis = np.array(axes, np.int64)
        self.ch_w = np.array(w, np.float64)
        self.ch_tau = np.array(tau, np.float64)
        self.tau_max = float(self.ch_tau.max())
        self.tau_min = float(self.ch_tau.min())
        self.buf: Pieces | None = None
        self.u_done = start_u
        self.started = False

    @property
    def reach_s(self) -> float:
        """How far (s) the shaped motion can run ahead of or behind the commanded one."""
        return max(self.tau_max, -self.tau_min)

    def _emit(self, u_to: float, rest_after: bool) -> "Pieces":
        buf = self.buf
        if buf is None or len(buf.t0) == 0:
            return Pieces.empty()
        if not self.started:
            self.u_done = max(self.u_done, float(buf.t0[0]) - self.tau_max)
            self.started = True
        if not u_to > self.u_done:
            return Pieces.empty()
        cap = len(buf.t0) * len(self.ch_axis) + 2
        out = Pieces(np.empty(cap), np.empty(cap), np.empty((cap, 4)), np.empty((cap, 4)), np.empty((cap, 4)),
                     np.empty((cap, 4)), np.empty(cap, np.int64))
        m = shape_pieces(buf.t0, buf.dt, buf.p, buf.v, buf.a, buf.j, self.ch_axis, self.ch_w, self.ch_tau,
                         self.u_done, u_to, True, rest_after, out.t0, out.dt, out.p, out.v, out.a, out.j, out.move,
                         buf.move)
        self.u_done = u_to
        # keep what later output still reads: pieces ending after u_done + τ_min (at least the last one)
        keep = int(np.searchsorted(buf.t0 + buf.dt, self.u_done + self.tau_min, side="right"))
        self.buf = buf.tail(min(keep, len(buf.t0) - 1))
        return out.head(m)

    def feed(self, segments: np.ndarray) -> "Pieces":
        """Add a batch of SEGMENT rows (continuing the previous one); the shaped pieces now complete."""
        if len(segments) == 0:
            return Pieces.empty()
        new = Pieces.from_segments(segments)
        self.buf = new if self.buf is None else self.buf.concat(new)
        end = float(self.buf.t0[-1] + self.buf.dt[-1])
        return self._emit(end - self.tau_max, rest_after=False)

    def finish(self) -> "Pieces":
        """The remaining shaped pieces, the path at rest after its last piece."""
        if self.buf is None or len(self.buf.t0) == 0:
            return Pieces.empty()
        end = float(self.buf.t0[-1] + self.buf.dt[-1])
        return self._emit(end - self.tau_min, rest_after=True)

    @property
    def end_u(self) -> float:
        """Where the output emitted so far ends (s)."""
        return self.u_done


class Pieces:
    """Cubic pieces of the four axes as plain arrays: ``t0``, ``dt`` (n,), ``p v a j`` (n, 4) over x y z e
    (the SEGMENT convention), ``move`` (n,)."""

    __slots__ = ("t0", "dt", "p", "v", "a", "j", "move")

    def __init__(self, t0, dt, p, v, a, j, move):
        self.t0, self.dt, self.p, self.v, self.a, self.j, self.move = t0, dt, p, v, a, j, move

    @staticmethod
    def empty() -> "Pieces":
        z = np.zeros((0, 4))
        return Pieces(np.zeros(0), np.zeros(0), z, z, z, z, np.zeros(0, np.int64))

    @staticmethod
    def from_segments(seg: np.ndarray) -> "Pieces":
        return Pieces(np.ascontiguousarray(seg["t0"], np.float64), np.ascontiguousarray(seg["dt"], np.float64),
                      _columns(seg, "p"), _columns(seg, "v"), _columns(seg, "a"), _columns(seg, "j"),
                      np.ascontiguousarray(seg["move"], np.int64))

    def __len__(self) -> int:
        return len(self.t0)

    def head(self, m: int) -> "Pieces":
        return Pieces(self.t0[:m], self.dt[:m], self.p[:m], self.v[:m], self.a[:m], self.j[:m], self.move[:m])

    def tail(self, k: int) -> "Pieces":
        return Pieces(self.t0[k:], self.dt[k:], self.p[k:], self.v[k:], self.a[k:], self.j[k:], self.move[k:])

    def concat(self, other: "Pieces") -> "Pieces":
        return Pieces(*(np.concatenate([getattr(self, f), getattr(other, f)]) for f in self.__slots__))

    def rail(self, weights) -> tuple[np.ndarray, ...]:
        """(t0, dt, p, v, a, j) of a linear motor Σ weights[q]·axis[q]."""
        out = []
        for arr in (self.p, self.v, self.a, self.j):
            acc = None
            for q, w in enumerate(weights):
                if w == 0.0:
                    continue
                term = arr[:, q] if w == 1.0 else w * arr[:, q]
                acc = term.copy() if acc is None else acc + term
            out.append(np.zeros(len(self.t0)) if acc is None else np.ascontiguousarray(acc))
        return (self.t0, self.dt, *out)


def as_segments(pieces: Pieces) -> np.ndarray:
    """:class:`Pieces` as SEGMENT rows (for tests, plots and sampling)."""
    out = np.zeros(len(pieces), SEGMENT_DTYPE)
    out["t0"] = pieces.t0
    out["dt"] = pieces.dt
    for q, ax in enumerate(_AX):
        out["p" + ax] = pieces.p[:, q]
        out["v" + ax] = pieces.v[:, q]
        out["a" + ax] = pieces.a[:, q]
        out["j" + ax] = pieces.j[:, q]
    out["move"] = pieces.move
    return out
