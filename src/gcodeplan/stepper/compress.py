"""Step compression into Klipper-style ``queue_step`` runs of (interval, count, add).

A run starting after the clock ``last`` (ticks) puts its k-th step (k = 1..count)
at ``last + k·interval + add·k(k−1)/2`` (klipper-planner.md §8); ``last`` then
becomes the run's final step. Each exact time t has Klipper's step clock
c = floor(t·f + ½); its decompressed step lies in ``[c − min(max_error·f, Δc/2), c]``
with Δc the gap to the previous step's clock: never after c, at most
``max_error`` early (Klipper's rule, ``max_stepcompress_error`` = 25 µs by
default), and never before the previous step. Against the exact float time the
error is therefore within [−max_error − ½ tick, +½ tick]; ``max_error = 0``
reproduces Klipper's exact-mode clocks.

The search is greedy: for a few candidate ``add`` values (0, then second
differences of the step clocks at scales 1, 4, 16, 64, 256 steps and their
neighbours) the run is extended while an
integer interval fits every window, and the longest run wins. Each run is checked
against its windows as it is built, so the bound holds whatever the candidates.
A run never spans a direction change.
"""
from __future__ import annotations

import math

import numba
import numpy as np

from . import DEFAULT_CLOCK_HZ, DEFAULT_MAX_ERROR_S  # noqa: F401  (re-exported)

MAX_COUNT = 65535                    # queue_step count is 16 bits in Klipper
MAX_ADD = 32767                      # queue_step add is a signed 16-bit value

RUN_DTYPE = np.dtype([("interval", "i8"), ("count", "i4"), ("add", "i8"), ("dir", "i1")])


@numba.njit(cache=True, inline="always")
def _ceil_div(x, k):
    return -((-x) // k)


@numba.njit(cache=True)
def _extend(lo, hi, pos, n, last, add, max_count):
    """Longest run from index ``pos`` with this ``add``: (count, interval)."""
    i_min = -(1 << 62)
    i_max = 1 << 62
    best_count = 0
    best_i = 0
    k = 1
    while pos + k - 1 < n and k <= max_count:
        idx = pos + k - 1
        c = add * (k * (k - 1) // 2)
        a = _ceil_div(lo[idx] - last - c, k)
        b = (hi[idx] - last - c) // k
        if a > i_min:
            i_min = a
        if b < i_max:
            i_max = b
        if i_min > i_max:
            break
        best_count = k
        best_i = i_max        # the latest steps that fit: closest to the exact (never late) times
        k += 1
    return best_count, best_i


@numba.njit(cache=True)
def compress_block(lo, hi, last, max_count, out_interval, out_count, out_add):
    """Runs covering the windows [lo[k], hi[k]] (ticks, one direction) starting after clock ``last``.

    Returns (number of runs written, clock of the last step).
    """
    n = lo.shape[0]
    nrun = 0
    pos = 0
    cand = np.empty(32, dtype=np.int64)
    while pos < n:
        # candidate adds: 0, then the second difference of the window tops at scales m = 1, 4, 16, 64, 256
        # steps and its neighbours
        nc = 0
        cand[nc] = 0
        nc += 1
        m = 1
        while m <= 256 and pos + 2 * m - 1 < n:
            first = hi[pos + m - 1] - last
            second = hi[pos + 2 * m - 1] - hi[pos + m - 1]
            base = int(np.floor((second - first) / (m * m)))
            for d in range(-1, 3):
                cand[nc] = base + d
                nc += 1
            m *= 4
        best_count = 1
        best_i = hi[pos] - last
        best_add = 0
        for ci in range(nc):
            add = cand[ci]
            if add > MAX_ADD or add < -MAX_ADD:
                continue
            dup = False
            for cj in range(ci):
                if cand[cj] == add:
                    dup = True
                    break
            if dup:
                continue
            cnt, itv = _extend(lo, hi, pos, n, last, add, max_count)
            if cnt > best_count:
                best_count = cnt
                best_i = itv
                best_add = add
                if cnt == n - pos or cnt == max_count:
                    break
        out_interval[nrun] = best_i
        out_count[nrun] = best_count
        out_add[nrun] = best_add
        nrun += 1
        last = last + best_count * best_i + best_add * (best_count * (best_count - 1) // 2)
        pos += best_count
    return nrun, last


@numba.njit(cache=True)
def compress_chunk(lo, hi, dirs, last, max_count, out_interval, out_count, out_add, out_dir):
    """:func:`compress_block` over each stretch of one direction; runs never span a reversal.

    Returns (number of runs written, clock of the last step).
    """
    n = lo.shape[0]
    nrun = 0
    s = 0
    while s < n:
        e = s + 1
        while e < n and dirs[e] == dirs[s]:
            e += 1
        k, last = compress_block(lo[s:e], hi[s:e], last, max_count,
                                 out_interval[nrun:], out_count[nrun:], out_add[nrun:])
        for r in range(nrun, nrun + k):
            out_dir[r] = dirs[s]
        nrun += k
        s = e
    return nrun, last


def step_clocks(times: np.ndarray, clock_hz: float) -> np.ndarray:
    """Klipper's step clock of each exact time: floor(t·f + ½) (klipper-planner.md §8)."""
    return np.floor(np.asarray(times, np.float64) * clock_hz + 0.5).astype(np.int64)


def step_windows(times: np.ndarray, prev_clock: int, clock_hz: float,
                 max_error_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Tick windows [lo, hi] of each step: hi = its clock c, lo = c − min(err·f, (c − c_prev)/2)."""
    hi = step_clocks(times, clock_hz)
    gaps = np.diff(hi, prepend=np.int64(prev_clock))
    early = np.minimum(np.int64(math.floor(max_error_s * clock_hz)), gaps // 2)
    lo = hi - np.maximum(early, 0)
    return lo, hi


class Compressor:
    """Streaming compressor for one stepper: feed (times, dirs) chunks, collect runs.

    ``last_clock`` is the clock the next run starts from (0 = the plan's start).
    """

    def __init__(self, clock_hz: float = DEFAULT_CLOCK_HZ, max_error_s: float = DEFAULT_MAX_ERROR_S,
                 max_count: int = MAX_COUNT):
        if not (clock_hz > 0 and max_error_s >= 0):
            raise ValueError("clock_hz must be > 0 and max_error_s ≥ 0")
        self.clock_hz = float(clock_hz)
        self.max_error_s = float(max_error_s)
        self.max_count = int(max_count)
        self.last_clock = 0
        self.prev_clock = 0

    def feed(self, times: np.ndarray, dirs: np.ndarray) -> np.ndarray:
        """Runs (RUN_DTYPE) for this chunk, continuing from the previous one."""
        n = len(times)
        if n == 0:
            return np.zeros(0, RUN_DTYPE)
        lo, hi = step_windows(times, self.prev_clock, self.clock_hz, self.max_error_s)
        self.prev_clock = int(hi[-1])
        dirs = np.ascontiguousarray(dirs, np.int8)
        itv = np.empty(n, np.int64)
        cnt = np.empty(n, np.int32)
        add = np.empty(n, np.int64)
        rdir = np.empty(n, np.int8)
        nrun, last = compress_chunk(lo, hi, dirs, self.last_clock, self.max_count, itv, cnt, add, rdir)
        self.last_clock = int(last)
        runs = np.empty(nrun, RUN_DTYPE)
        runs["interval"] = itv[:nrun]
        runs["count"] = cnt[:nrun]
        runs["add"] = add[:nrun]
        runs["dir"] = rdir[:nrun]
        return runs


def compress_steps(times: np.ndarray, dirs: np.ndarray, clock_hz: float = DEFAULT_CLOCK_HZ,
                   max_error_s: float = DEFAULT_MAX_ERROR_S) -> np.ndarray:
    """All runs of one stepper's steps, starting from clock 0."""
    return Compressor(clock_hz, max_error_s).feed(times, dirs)


@numba.njit(cache=True)
def _expand(interval, count, add, start_clock, out):
    last = start_clock
    m = 0
    for r in range(interval.shape[0]):
        itv = interval[r]
        ad = add[r]
        for k in range(count[r]):
            last += itv + ad * k       # step k+1 = previous + interval + add·k
            out[m] = last
            m += 1
    return m


def decompress_runs(runs: np.ndarray, start_clock: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(step clocks int64, dirs int8) of a run list, the inverse of :func:`compress_steps`."""
    total = int(runs["count"].sum())
    clocks = np.empty(total, np.int64)
    _expand(np.ascontiguousarray(runs["interval"]), np.ascontiguousarray(runs["count"]).astype(np.int64),
            np.ascontiguousarray(runs["add"]), int(start_clock), clocks)
    dirs = np.repeat(runs["dir"], runs["count"]).astype(np.int8)
    return clocks, dirs
