"""Step compression into ``queue_step`` runs (interval, count, add), run for run as Klipper's stepcompress.c.

A run starting after the clock ``last`` (ticks) puts its k-th step (k = 1..count)
at ``last + k·interval + add·k(k−1)/2``: the MCU adds ``interval`` to its clock,
then ``add`` to ``interval``, before each further step (Klipper's src/stepper.c).
``last`` then becomes the run's final step. Clocks count from the first move's
start unless the compressor is given another ``start_clock``.

Each exact time t has the step clock c = floor(t·f + ½) (Klipper's
``stepcompress_append``). A step may be sent early but never late: the step at
the head of the queue may land in [c − e, c] with e = min(max_error, (c − last)/2),
every later step of the same run in [c − e, c] with e = min(max_error,
(c − c_prev)/2), c_prev being the previous exact clock (Klipper's
``minmax_point``; max_error = ⌊max_stepcompress_error·f⌋, 1250 ticks by default).

The search (Klipper's ``compress_bisect_add``, in our own words in
docs/design.md "Step compression"): for add = 0, then for adds bisected towards
the one that would reach further, the longest run whose integer interval fits
every window; the run that reaches furthest in time wins, add = 0 is preferred
when it covers nearly as many steps (zc + zc/16 ≥ best). Runs never span a
direction change; a step 3·2^28 ticks or more after the last sent one is sent
alone at its exact clock after the queue before it is flushed (Klipper's
``queue_append_far``).

What each run can see: Klipper compresses whatever is queued when it flushes.
:class:`Compressor` with ``hold_back=True`` keeps back the steps whose run could
still grow, so every run sees the whole rest of its direction run (at most 65535
steps) whatever the chunking; ``hold_back=False`` flushes at the end of every
chunk, as Klipper does at each of its step generation calls.
"""
from __future__ import annotations

import math

from .._jit import njit
import numpy as np

from . import DEFAULT_CLOCK_HZ, DEFAULT_MAX_ERROR_S  # noqa: F401  (re-exported)

MAX_COUNT = 65535                    # queue_step count is 16 bits (Klipper's compress_bisect_add look-ahead)
MIN_ADD = -32768                     # queue_step add is a signed 16-bit value
MAX_ADD = 32767
QUADRATIC_DEV = 11                   # Klipper stepcompress.c: two valid quadratics differ in add by < 11.66·err/n²
CLOCK_DIFF_MAX = 3 << 28             # ticks; a step this far after the last sent one is sent alone (stepcompress.c)
NO_IMPROVE_COUNT = 0x200             # Klipper stops bisecting once a best run covers more steps than this
_NO_LIMIT = np.int64(1) << np.int64(62)
_CLOCK_LIMIT = 2.0 ** 62             # ticks; a step clock beyond this is refused (int64 arithmetic stays exact)

RUN_DTYPE = np.dtype([("interval", "i8"), ("count", "i4"), ("add", "i8"), ("dir", "i1")])

SUB_CHUNK = 1 << 17                  # steps queued and compressed at a time: their clocks stay in the L2 cache


@njit(cache=True, inline="always", error_model="numpy")
def _floor_div(x, d):
    """floor(x/d) for |x|, |d| < 2^53 with one float division: exact (the quotient is correctly rounded and a
    non-integer quotient lies ≥ 1/|d| from any integer), and cheaper than a 64-bit integer division."""
    return np.int64(math.floor(np.float64(x) / np.float64(d)))


@njit(cache=True, inline="always", error_model="numpy")
def _ceil_div(x, d):
    """ceil(x/d), exact as :func:`_floor_div`."""
    return np.int64(math.ceil(np.float64(x) / np.float64(d)))


@njit(cache=True, inline="always", error_model="numpy")
def _longest_run(clocks, pos, qlast, last, max_err, add, lo_i, hi_i):
    """Longest run from ``pos`` with this ``add`` whose integer interval stays in [lo_i, hi_i] and fits every window.

    Returns (count, interval, failed, n, lo_i, hi_i, f, minp, maxp): when
    ``failed``, step n (1-based in the run) is the first that does not fit,
    [lo_i, hi_i] the (empty) range with it, f = n(n−1)/2 and [minp, maxp] its
    window relative to ``last``. Otherwise the queue ended after ``count``
    steps. Step n at last + n·interval + add·f must lie in its window, so the
    interval range narrows to [⌈(minp − add·f)/n⌉, ⌊(maxp − add·f)/n⌋]; the
    interval kept is the top of the range (the latest steps).
    """
    interval = hi_i
    n = 1
    f = 0
    prev = clocks[pos]
    while True:
        n += 1
        j = pos + n - 1
        if j >= qlast:
            return n - 1, interval, False, 0, lo_i, hi_i, 0, 0, 0
        f += n - 1
        shift = add * f
        c = clocks[j]
        maxp = c - last
        minp = maxp - min((c - prev) >> 1, max_err)      # half the gap to the previous step, at most max_err
        prev = c
        if lo_i * n < minp - shift:
            lo_i = _ceil_div(minp - shift, n)
        if hi_i * n > maxp - shift:
            hi_i = _floor_div(maxp - shift, n)
        if lo_i > hi_i:
            return n - 1, interval, True, n, lo_i, hi_i, f, minp, maxp
        interval = hi_i


@njit(cache=True, error_model="numpy")
def bisect_add(clocks, pos, qend, last, max_err, max_count):
    """One run for the queued step clocks ``clocks[pos:qend]`` (ticks, one direction, non-decreasing) after ``last``.

    Klipper's ``compress_bisect_add``. ``max_err`` is in ticks. Returns
    (interval, count, add, at_end) with ``at_end`` true when the search stopped
    at the end of the queue (or of its ``max_count`` look-ahead), where more
    queued steps could have made the run longer.
    """
    qlast = min(qend, pos + max_count)
    # window of the head step: its half-gap is measured from the last step sent
    c0 = clocks[pos] - last
    outer_min = c0 - min(c0 >> 1, max_err)
    outer_max = c0
    add = 0
    min_add = MIN_ADD
    max_add = MAX_ADD
    best_interval = 0
    best_count = 1
    best_add = 1
    best_reach = -_NO_LIMIT
    zero_interval = 0
    zero_count = 0
    while True:
        count, interval, failed, n, lo_i, hi_i, f, next_minp, next_maxp = _longest_run(
            clocks, pos, qlast, last, max_err, add, outer_min, outer_max)
        if not failed:
            return interval, count, add, True
        reach = add * ((count * (count - 1)) >> 1) + interval * count
        if reach > best_reach or (reach == best_reach and interval > best_interval):
            best_interval = interval
            best_count = count
            best_add = add
            best_reach = reach
            if add == 0:
                zero_interval = interval
                zero_count = count
            if count > NO_IMPROVE_COUNT:
                break
        # the failing step n tells whether a larger or a smaller add could reach it
        next_reach = add * f + interval * n
        if next_reach < next_minp:
            min_add = add + 1
            outer_max = hi_i
        else:
            max_add = add - 1
            outer_min = lo_i
        if count > 1:
            # two quadratics both valid over `count` steps differ in add by at most QUADRATIC_DEV·err/count²
            dev = _floor_div(max_err * QUADRATIC_DEV, count * count)
            min_add = max(min_add, add - dev)
            max_add = min(max_add, add + dev)
        # the failing step must stay reachable with an interval of the outer range
        if min_add * f < next_minp - outer_max * n:
            min_add = _ceil_div(next_minp - outer_max * n, f)
        if max_add * f > next_maxp - outer_min * n:
            max_add = _floor_div(next_maxp - outer_min * n, f)
        if min_add > max_add:
            break
        add = max_add - ((max_add - min_add) >> 2)
    if zero_count + (zero_count >> 4) >= best_count:
        return zero_interval, zero_count, 0, False
    return best_interval, best_count, best_add, False


@njit(cache=True, error_model="numpy")
def _flush_queue(clocks, pos, qend, last, max_err, max_count, move_clock, only_final, direction,
                 o_interval, o_count, o_add, o_dir, nout):
    """Runs for ``clocks[pos:qend]`` while ``last < move_clock`` (Klipper's ``queue_flush``).

    With ``only_final`` a run whose search reached the end of the queue is not
    sent: more steps could still change it. Returns (pos, last, nout).
    """
    while pos < qend and last < move_clock:
        interval, count, add, at_end = bisect_add(clocks, pos, qend, last, max_err, max_count)
        if only_final and at_end and qend - pos < max_count:
            break
        o_interval[nout] = interval
        o_count[nout] = count
        o_add[nout] = add
        o_dir[nout] = direction
        nout += 1
        last += interval * count + add * ((count * (count - 1)) >> 1)
        pos += count
    return pos, last, nout


@njit(cache=True, error_model="numpy")
def _first_bad_step(times, dirs, clock_hz, prev_clock):
    """Index of the first step whose time is not finite or goes backwards, or whose direction is not ±1; else −1."""
    prev = prev_clock
    for k in range(times.shape[0]):
        x = times[k] * clock_hz + 0.5
        d = dirs[k]
        if not (abs(x) < _CLOCK_LIMIT) or (d != 1 and d != -1):
            return k
        c = np.int64(math.floor(x))
        if c < prev:
            return k
        prev = c
    return -1


@njit(cache=True, error_model="numpy")
def queue_clocks(times, dirs, clock_hz, prev_clock, direction, clocks, changes):
    """Step clocks floor(t·f + ½) of ``times`` (s) into ``clocks``, and where the direction changes.

    ``prev_clock`` and ``direction`` are those of the step before ``times[0]``.
    Writes the indices of the steps whose direction differs from the step
    before into ``changes``. Returns (number of changes, index of the first
    bad step or −1: clock not finite or beyond 2^62, going backwards,
    direction not ±1).
    """
    m = times.shape[0]
    if m == 0:
        return 0, -1
    # separate simple loops: the first two vectorise
    bad = 0
    for k in range(m):
        x = times[k] * clock_hz + 0.5
        ok = abs(x) < _CLOCK_LIMIT                        # false for NaN
        clocks[k] = np.int64(math.floor(x if ok else 0.0))
        bad += not ok
    bad += clocks[0] < prev_clock
    for k in range(1, m):
        bad += clocks[k] < clocks[k - 1]
    # direction changes, eight directions (bytes) at a time while they equal the current one
    nch = 0
    words = dirs[: m - m % 8].view(np.int64)
    same = np.int64(0x0101010101010101) * np.int64(direction & 0xFF)
    for w in range(words.shape[0]):
        if words[w] == same and direction != 0:
            continue
        for k in range(8 * w, 8 * w + 8):
            d = dirs[k]
            if d != direction:
                bad += d * d != 1
                changes[nch] = k
                nch += 1
                direction = d
        same = np.int64(0x0101010101010101) * np.int64(direction & 0xFF)
    for k in range(m - m % 8, m):
        d = dirs[k]
        if d != direction:
            bad += d * d != 1
            changes[nch] = k
            nch += 1
            direction = d
    if bad:
        return nch, _first_bad_step(times, dirs, clock_hz, prev_clock)
    return nch, -1


@njit(cache=True, error_model="numpy")
def compress_queue(clocks, dirs, changes, new_from, last, direction, max_err, max_count, final,
                   o_interval, o_count, o_add, o_dir):
    """Compress the queue ``clocks[:new_from]`` (pending, one direction) with the steps ``clocks[new_from:]`` appended.

    Klipper's ``queue_append`` for each new step: a direction change (at the
    indices ``changes``, relative to ``new_from``; ``dirs`` the new steps'
    directions) first flushes the whole queue (``set_next_step_dir``); a step
    CLOCK_DIFF_MAX or more after the last one sent flushes the queue up to its
    clock − CLOCK_DIFF_MAX + 1 and, if still that far, goes alone at its exact
    clock (``queue_append_far``). At the end the runs that more steps could not
    change are sent; with ``final`` all of them. Returns (number of runs, queue
    head index, last, direction).
    """
    n = clocks.shape[0]
    pos = 0
    nout = 0
    i = new_from
    ci = 0
    while True:
        seg_end = new_from + changes[ci] if ci < changes.shape[0] else n
        # far steps in [i, seg_end): the clocks are sorted, and `last` only moves at such events
        while i < seg_end:
            k = i + np.searchsorted(clocks[i:seg_end], last + CLOCK_DIFF_MAX)
            if k >= seg_end:
                break
            c = clocks[k]
            # runs that do not depend on the queue's end are Klipper's whenever they are sent
            pos, last, nout = _flush_queue(clocks, pos, k, last, max_err, max_count, _NO_LIMIT, True,
                                           direction, o_interval, o_count, o_add, o_dir, nout)
            if c - last >= CLOCK_DIFF_MAX:
                pos, last, nout = _flush_queue(clocks, pos, k, last, max_err, max_count,
                                               c - CLOCK_DIFF_MAX + 1, False, direction,
                                               o_interval, o_count, o_add, o_dir, nout)
                if c - last >= CLOCK_DIFF_MAX:
                    o_interval[nout] = c - last
                    o_count[nout] = 1
                    o_add[nout] = 0
                    o_dir[nout] = direction
                    nout += 1
                    last = c
                    pos = k + 1
            i = k + 1
        if seg_end >= n:
            break
        # direction change: Klipper flushes every queued step of the old direction first
        pos, last, nout = _flush_queue(clocks, pos, seg_end, last, max_err, max_count, _NO_LIMIT, False,
                                       direction, o_interval, o_count, o_add, o_dir, nout)
        pos = seg_end
        direction = dirs[seg_end - new_from]
        i = seg_end
        ci += 1
    pos, last, nout = _flush_queue(clocks, pos, n, last, max_err, max_count, _NO_LIMIT, not final,
                                   direction, o_interval, o_count, o_add, o_dir, nout)
    return nout, pos, last, direction


def step_clocks(times: np.ndarray, clock_hz: float) -> np.ndarray:
    """Klipper's step clock of each exact time (s): floor(t·f + ½) ticks."""
    return np.floor(np.asarray(times, np.float64) * clock_hz + 0.5).astype(np.int64)


def max_error_ticks(max_error_s: float, clock_hz: float) -> int:
    """The error bound in ticks, truncated as Klipper's ``seconds_to_clock`` does (25 µs at 50 MHz = 1250)."""
    return int(max_error_s * clock_hz)


class Compressor:
    """Streaming compressor for one stepper: feed (times s, dirs ±1) chunks, collect RUN_DTYPE runs.

    ``start_clock`` is the clock (ticks) the first run counts from; Klipper's
    ``last_step_clock`` starts at 0. ``hold_back=True`` keeps back the runs that
    more steps could still lengthen, so that the result does not depend on the
    chunking (call :meth:`finish` at the end); ``hold_back=False`` sends every
    queued step at the end of each :meth:`feed`, like Klipper's flush at each
    step generation call.
    """

    def __init__(self, clock_hz: float = DEFAULT_CLOCK_HZ, max_error_s: float = DEFAULT_MAX_ERROR_S,
                 max_count: int = MAX_COUNT, *, start_clock: int = 0, hold_back: bool = False):
        if not (math.isfinite(clock_hz) and clock_hz > 0 and math.isfinite(max_error_s) and max_error_s >= 0):
            raise ValueError("clock_hz must be > 0 and max_error_s ≥ 0")
        if not 1 <= max_count <= MAX_COUNT:
            raise ValueError(f"max_count must be in 1..{MAX_COUNT}")
        self.clock_hz = float(clock_hz)
        self.max_error_s = float(max_error_s)
        self.max_err = max_error_ticks(max_error_s, clock_hz)
        if self.max_err * 2 >= CLOCK_DIFF_MAX:
            raise ValueError("max_error_s is absurdly large for this clock")
        self.max_count = int(max_count)
        self.hold_back = bool(hold_back)
        self.last_clock = int(start_clock)     # clock of the last step sent (Klipper's last_step_clock)
        self.direction = 0                     # direction of the queued steps (0 = none yet)
        # step clocks; the queue held back (one direction) is [_head, _head + _pending)
        self._clocks = np.zeros(0, np.int64)
        self._head = 0
        self._pending = 0
        self._prev_clock = int(start_clock)    # clock of the last step fed

    def _workspace(self, m: int) -> np.ndarray:
        """Buffer holding the pending queue at its start and room for m more steps (reused across feeds)."""
        p, h = self._pending, self._head
        need = p + m
        if len(self._clocks) < need:
            clocks = np.empty(max(need, 2 * len(self._clocks), 1024), np.int64)
            clocks[:p] = self._clocks[h:h + p]
            self._clocks = clocks
        elif h:
            self._clocks[:p] = self._clocks[h:h + p].copy()
        self._head = 0
        return self._clocks[:need]

    def _compress(self, times: np.ndarray, dirs: np.ndarray, final: bool) -> np.ndarray:
        """Queue and compress the steps in pieces of SUB_CHUNK steps, so that their clocks stay in the cache."""
        if len(times) <= SUB_CHUNK:
            return self._compress_piece(times, dirs, final)
        pieces = [self._compress_piece(times[i:i + SUB_CHUNK], dirs[i:i + SUB_CHUNK],
                                       final and i + SUB_CHUNK >= len(times))
                  for i in range(0, len(times), SUB_CHUNK)]
        return np.concatenate(pieces)

    def _compress_piece(self, times: np.ndarray, dirs: np.ndarray, final: bool) -> np.ndarray:
        pending = self._pending
        m = len(times)
        clocks = self._workspace(m)
        changes = np.empty(m, np.int64)
        nch, bad = queue_clocks(times, dirs, self.clock_hz, np.int64(self._prev_clock), np.int8(self.direction),
                                clocks[pending:], changes)
        if bad < 0 and m and clocks[pending] < self.last_clock:
            bad = 0
        if bad >= 0:
            raise ValueError(f"step t = {times[bad]!r} s, dir {dirs[bad]}: step times must be finite, never "
                             "decrease nor come before the start clock; directions ±1")
        n = pending + m
        itv = np.empty(n, np.int64)
        cnt = np.empty(n, np.int32)
        add = np.empty(n, np.int64)
        rdir = np.empty(n, np.int8)
        nrun, pos, last, direction = compress_queue(
            clocks, dirs, changes[:nch], pending, np.int64(self.last_clock), np.int8(self.direction),
            np.int64(self.max_err), np.int64(self.max_count), final, itv, cnt, add, rdir)
        self.last_clock = int(last)
        self.direction = int(direction)
        if m:
            self._prev_clock = int(clocks[-1])
        self._head = int(pos)
        self._pending = int(n - pos)
        runs = np.empty(nrun, RUN_DTYPE)
        runs["interval"] = itv[:nrun]
        runs["count"] = cnt[:nrun]
        runs["add"] = add[:nrun]
        runs["dir"] = rdir[:nrun]
        return runs

    def feed(self, times: np.ndarray, dirs: np.ndarray) -> np.ndarray:
        """Runs (RUN_DTYPE) ready after this chunk of step times (s, non-decreasing) and directions (±1).

        Without ``hold_back`` every step fed is in the runs returned. Raises
        ValueError on a time that is not finite, goes backwards or comes
        before ``start_clock``, or a direction other than ±1; the compressor is
        not to be used after that.
        """
        times = np.ascontiguousarray(times, np.float64)
        dirs = np.ascontiguousarray(dirs, np.int8)
        if times.shape != dirs.shape or times.ndim != 1:
            raise ValueError("times and dirs must be 1-D arrays of the same length")
        if len(times) == 0:
            return np.zeros(0, RUN_DTYPE)
        return self._compress(times, dirs, final=not self.hold_back)

    def finish(self) -> np.ndarray:
        """The runs still held back (``hold_back=True``); empty otherwise."""
        if self._pending == 0:
            return np.zeros(0, RUN_DTYPE)
        return self._compress(np.zeros(0, np.float64), np.zeros(0, np.int8), final=True)


def compress_steps(times: np.ndarray, dirs: np.ndarray, clock_hz: float = DEFAULT_CLOCK_HZ,
                   max_error_s: float = DEFAULT_MAX_ERROR_S, start_clock: int = 0) -> np.ndarray:
    """All runs of one stepper's steps (times s, dirs ±1), each seeing its whole direction run, from ``start_clock``."""
    return Compressor(clock_hz, max_error_s, start_clock=start_clock).feed(times, dirs)


@njit(cache=True, error_model="numpy")
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
    """(step clocks int64 ticks, dirs int8) of a run list, the inverse of :func:`compress_steps`."""
    total = int(runs["count"].sum())
    clocks = np.empty(total, np.int64)
    _expand(np.ascontiguousarray(runs["interval"]), np.ascontiguousarray(runs["count"]).astype(np.int64),
            np.ascontiguousarray(runs["add"]), int(start_clock), clocks)
    dirs = np.repeat(runs["dir"], runs["count"]).astype(np.int8)
    return clocks, dirs
