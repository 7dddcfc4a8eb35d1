"""The grbl model without quantisation (``grbl.run(..., quantised=False)``): grbl 1.1's plan in float64 and
continuous time.

What stays grbl's (its plan, not its arithmetic), after planner.c and protocol.c:

* the block: the straight move from the last queued target to the op's target (mm, X Y Z); its acceleration and
  rapid rate the largest the axes allow along it (``limit_value_by_axis_maximum``: min over moving axes of the
  axis limit / |unit vector component|, $120-$122 and $110-$112); the nominal speed the feed (a rapid: the rapid
  rate) within the rapid rate and at least MINIMUM_FEED_RATE (1 mm/min);
* the junction rule (``plan_buffer_line``): behind an empty planner the entry is 0; else the junction cap
  a_j · δ · sin(θ/2) / (1 − sin(θ/2)) with a_j the acceleration the axes allow along the junction vector
  (unit vector minus the previous one) and δ the junction deviation ($11), 0 for a reversal (cos θ > 0.999999)
  and unlimited for a straight line on (cos θ < −0.999999); the entry also within the smaller of the two
  nominal speeds; the newest block planned to stop (exit 0);
* the ring of ``buffer_blocks`` slots (one always empty; None: unbounded) and grbl-sim's lock-step main loop: the
  host queues until the ring is full, the cycle starts when it is full or at a sync, a sync (G4, M2/M30, spindle
  and coolant changes, laser mode's syncs: KIND_DWELL / KIND_WAIT rows) waits for the motion to stop; G4 then
  dwells; ``$1`` (stepper idle delay, unless 255) at every stop delays the next motion (st_go_idle).

What it turns off: whole-step targets (``lround(target · steps/mm)``; a block is any move whose float64 deltas
are not all 0, no sub-step move is dropped or merged into the next); grbl's float32 (its settings read as the
machine gives them, its targets as gcodeplan read them, not ``read_float``'s); the segment generator (10 ms
segments, its ramp state machine, AMASS), Timer1 and the stepper interrupt (a block's time is its trapezoid's in
closed form, ``OCR1A + 1`` periods and rounded-up cycles gone); G4 P rounded up to 50 ms steps (a dwell lasts its
own P). A block holds its slot until it has run (grbl frees it when its last segment is *prepared*, ≤ 5
segments earlier), and the block that runs is planned with what is queued when it starts: its entry is the
exit the block before it ran to, its exit the next block's planned entry. The look-ahead is the textbook one
(docs/design.md §1, "Data flow"): backward from the newest, v_entry² = min(cap, v_next² + 2·a·d), then forward,
v_entry² ≤ v_prev² + 2·a·d. Equal to planner.c's reverse/forward passes and its *planned* pointer in exact
arithmetic: a block the pointer has passed cannot rise any more. With an unbounded ring the cycle only starts
at a sync or at the end, so each stretch between syncs is planned whole: the ideal full look-ahead plan.
"""
from __future__ import annotations

import math

import numpy as np

from .._jit import njit
from ..profiles.trapezoid import block_trapezoid_kernel
from ..schema import FLAG_RAPID, KIND_DWELL, KIND_WAIT
#: mm/s, grbl 1.1h planner.h MINIMUM_FEED_RATE (1 mm/min)
MINIMUM_FEED_V = 1.0 / 60.0
#: planner.c SOME_LARGE_VALUE: no limit
SOME_LARGE_VALUE = 1.0e38
#: Hz, the ATmega328P's clock: the unit of ``GrblSettings.idle_lock_ticks``
F_CPU = 16_000_000
# per-block ring fields (rf[slot, ...]): length mm, acceleration mm/s², nominal mm/s, max entry² and entry²
# mm²/s², op index
RF_MM, RF_ACCEL, RF_NOMINAL, RF_MAX_ENTRY_SQR, RF_ENTRY_SQR, RF_OP = range(6)
N_RF = 6
# global state (g[...]): ring head, tail, blocks queued since the last passes (1/0), clock s, motion started,
# last position X Y Z mm, previous unit vector X Y Z, previous nominal speed mm/s
G_HEAD, G_TAIL, G_DIRTY, G_CLOCK, G_STARTED, G_POS, G_PREV_U, G_PREV_NOMINAL = 0, 1, 2, 3, 4, 5, 8, 11
N_G = 12
# per-op outputs (out[op, ...]): 1 a block ran / 2 a sync, pick-up and end (s), entry, cruise (or peak) and exit
# speed (mm/s), accelerating, cruising and braking time (s), acceleration (mm/s²), length (mm), nominal speed
# (mm/s), junction cap (mm²/s², before the nominal speeds), max entry (mm²/s²)
(OT_HAS, OT_T_PICK, OT_T_END, OT_V0, OT_VC, OT_V1, OT_TA, OT_TC, OT_TD, OT_ACCEL, OT_MM, OT_NOMINAL, OT_JUNCTION_SQR,
 OT_MAX_ENTRY_SQR) = range(14)
N_OT = 14


@njit(cache=True)
def limit_by_axis_maximum(max_value, unit_vec):
    """planner.c limit_value_by_axis_maximum in float64: the largest value along ``unit_vec`` that keeps every
    moving axis within its ``max_value`` (mm/s or mm/s²)."""
    limit = SOME_LARGE_VALUE
    for i in range(3):
        if unit_vec[i] != 0:
            limit = min(limit, abs(max_value[i] / unit_vec[i]))
    return limit


@njit(cache=True)
def junction_sqr(prev_u, unit_vec, max_a, junction_dev, junction_u):
    """planner.c plan_buffer_line's junction speed² (mm²/s²) between the previous block's unit vector
    ``prev_u`` and ``unit_vec``, in float64 (``junction_u``: scratch, 3)."""
    cos_theta = 0.0
    for i in range(3):
        cos_theta -= prev_u[i] * unit_vec[i]
        junction_u[i] = unit_vec[i] - prev_u[i]
    if cos_theta > 0.999999:
        return 0.0                            # a reversal (or nearly): a full stop
    if cos_theta < -0.999999:
        return SOME_LARGE_VALUE               # straight on: no junction limit
    mag = math.sqrt(junction_u[0] ** 2 + junction_u[1] ** 2 + junction_u[2] ** 2)
    for i in range(3):
        junction_u[i] /= mag
    junction_a = limit_by_axis_maximum(max_a, junction_u)
    sin_half = math.sqrt(0.5 * (1.0 - cos_theta))
    return max(0.0, junction_a * junction_dev * sin_half / (1.0 - sin_half))


@njit(cache=True)
def queue_block(rf, g, op, target, rate_v, rapid, max_v, max_a, junction_dev, out, scratch):
    """Queue op ``op``'s straight move to ``target`` (mm) at the ring's head, grbl's block parameters in
    float64; False (no block) when it does not move. ``scratch``: (2, 3)."""
    n = rf.shape[0]
    unit_vec = scratch[0]
    for i in range(3):
        unit_vec[i] = target[i] - g[G_POS + i]
    mm = math.sqrt(unit_vec[0] ** 2 + unit_vec[1] ** 2 + unit_vec[2] ** 2)
    if mm == 0.0:
        return False
    for i in range(3):
        unit_vec[i] /= mm
    accel = limit_by_axis_maximum(max_a, unit_vec)
    rapid_v = limit_by_axis_maximum(max_v, unit_vec)
    nominal = max(rapid_v if rapid else min(rate_v, rapid_v), MINIMUM_FEED_V)
    h = int(g[G_HEAD])
    if h == int(g[G_TAIL]):
        cap = 0.0                            # behind an empty planner: from rest
    else:
        cap = junction_sqr(g[G_PREV_U:G_PREV_U + 3], unit_vec, max_a, junction_dev, scratch[1])
    v_max = min(nominal, g[G_PREV_NOMINAL])
    rf[h, RF_MM] = mm
    rf[h, RF_ACCEL] = accel
    rf[h, RF_NOMINAL] = nominal
    rf[h, RF_MAX_ENTRY_SQR] = min(cap, v_max * v_max)
    rf[h, RF_ENTRY_SQR] = 0.0
    rf[h, RF_OP] = op
    out[op, OT_JUNCTION_SQR] = cap
    g[G_PREV_NOMINAL] = nominal
    for i in range(3):
        g[G_PREV_U + i] = unit_vec[i]
        g[G_POS + i] = target[i]
    g[G_HEAD] = (h + 1) % n
    g[G_DIRTY] = 1.0
    return True


@njit(cache=True)
def lookahead_passes(rf, g):
    """The textbook look-ahead over the queued blocks: backward from the newest (exit 0) down to the block after
    the tail, v² = min(max entry², v_next² + 2·a·d); then forward from the tail (its entry fixed: 0 from rest, or
    the exit the block before it ran to), v² ≤ v_prev² + 2·a·d."""
    n = rf.shape[0]
    tail, head = int(g[G_TAIL]), int(g[G_HEAD])
    nxt_sqr = 0.0
    idx = head
    while True:
        idx = (idx - 1) % n
        if idx == tail:
            break
        rf[idx, RF_ENTRY_SQR] = min(rf[idx, RF_MAX_ENTRY_SQR], nxt_sqr + 2.0 * rf[idx, RF_ACCEL] * rf[idx, RF_MM])
        nxt_sqr = rf[idx, RF_ENTRY_SQR]
    prv = tail
    idx = (tail + 1) % n
    while idx != head:
        reach = rf[prv, RF_ENTRY_SQR] + 2.0 * rf[prv, RF_ACCEL] * rf[prv, RF_MM]
        if reach < rf[idx, RF_ENTRY_SQR]:
            rf[idx, RF_ENTRY_SQR] = reach
        prv = idx
        idx = (idx + 1) % n


@njit(cache=True)
def run_tail_block(rf, g, out, ph):
    """Run the block at the tail from the clock: after the passes (when blocks came since the last), its
    trapezoid from its entry to the next block's planned entry (0 for the newest) in closed form; the next
    block's entry is then its exit (no pass changes the tail's). Frees its slot."""
    n = rf.shape[0]
    if g[G_DIRTY] != 0:
        lookahead_passes(rf, g)
        g[G_DIRTY] = 0.0
    t = int(g[G_TAIL])
    nb = (t + 1) % n
    exit_sqr = 0.0 if nb == int(g[G_HEAD]) else rf[nb, RF_ENTRY_SQR]
    block_trapezoid_kernel(rf[t, RF_ENTRY_SQR], exit_sqr, rf[t, RF_NOMINAL], rf[t, RF_ACCEL], rf[t, RF_MM], ph)
    op = int(rf[t, RF_OP])
    out[op, OT_HAS] = 1
    out[op, OT_T_PICK] = g[G_CLOCK]
    g[G_CLOCK] += ph[3] + ph[4] + ph[5]
    out[op, OT_T_END] = g[G_CLOCK]
    for k in range(6):
        out[op, OT_V0 + k] = ph[k]
    out[op, OT_ACCEL] = rf[t, RF_ACCEL]
    out[op, OT_MM] = rf[t, RF_MM]
    out[op, OT_NOMINAL] = rf[t, RF_NOMINAL]
    out[op, OT_MAX_ENTRY_SQR] = rf[t, RF_MAX_ENTRY_SQR]
    g[G_TAIL] = nb
    g[G_STARTED] = 1.0


@njit(cache=True)
def ideal_run_kernel(is_sync, target, rate_v, rapid, dwell_s, max_v, max_a, junction_dev, idle_s, rf, out):
    """grbl-sim's lock-step main loop over the continuous blocks, the whole program: a line op waits while the
    ring (``rf``, its row count the ring's size) is full, running the block at its tail; a sync op and the end
    drain it (the newest block exits at 0), then the idle delay ``idle_s`` (s) after motion and the dwell
    ``dwell_s`` (s, once motion has started). Times are s from the first block's start, per op in ``out``."""
    n = rf.shape[0]
    g = np.zeros(N_G)
    ph = np.zeros(6)
    scratch = np.zeros((2, 3))
    for j in range(is_sync.shape[0] + 1):
        if j < is_sync.shape[0] and not is_sync[j]:
            if (int(g[G_HEAD]) + 1) % n == int(g[G_TAIL]):
                run_tail_block(rf, g, out, ph)     # the ring is full: the cycle runs until a slot is free
            queue_block(rf, g, j, target[j], rate_v[j], rapid[j], max_v, max_a, junction_dev, out, scratch)
            continue
        ran = False
        while int(g[G_HEAD]) != int(g[G_TAIL]):
            run_tail_block(rf, g, out, ph)
            ran = True
        if j == is_sync.shape[0]:
            break
        motion_end = g[G_CLOCK]
        if ran:
            g[G_CLOCK] += idle_s                   # st_go_idle's $1 delay inside the stepper interrupt
        out[j, OT_HAS] = 2
        out[j, OT_T_PICK] = motion_end
        if dwell_s[j] > 0 and g[G_STARTED] != 0:
            g[G_CLOCK] += dwell_s[j]
            out[j, OT_T_END] = g[G_CLOCK]
        else:
            out[j, OT_T_END] = motion_end


def check_buffer_blocks(buffer_blocks, unbounded_ok: bool = False):
    """The planner ring's size (slots; one always empty) as an int, or None for an unbounded ring (``None`` or
    ``math.inf``, only where ``unbounded_ok``); a :class:`~gcodeplan.errors.ConfigError` naming the value
    otherwise (grbl's ring needs 2 slots for 1 block)."""
    from ..errors import ConfigError

    if unbounded_ok and (buffer_blocks is None or buffer_blocks == math.inf):
        return None
    if isinstance(buffer_blocks, bool) or not isinstance(buffer_blocks, (int, np.integer)) or buffer_blocks < 2:
        what = "an int of at least 2, or None / math.inf (unbounded, quantised=False only)" if unbounded_ok \
            else "an int of at least 2"
        raise ConfigError(f"buffer_blocks: {buffer_blocks!r} is not {what} (grbl's BLOCK_BUFFER_SIZE)")
    return int(buffer_blocks)


class IdealRun:
    """What :func:`run_ideal` returns, as :class:`gcodeplan.planner.grbl.GrblRun`: ``row_end_s`` per MOVE row the
    end of its block (s from the first block's start; NaN for a row without one), ``total_s`` the last block's
    end, ``steps`` None; ``out`` (per op, the ``OT_*`` columns) and ``rows`` (the MOVE row of each op)."""

    def __init__(self, row_end_s, total_s, out, rows):
        self.row_end_s = row_end_s
        self.total_s = total_s
        self.steps = None
        self.out = out
        self.rows = rows


def ideal_operations(moves: np.ndarray):
    """MOVE rows → the continuous model's operations, as :func:`gcodeplan.planner.grbl.operations` picks them
    (motion rows are lines, dwells and waits syncs, E-only rows skipped) but with the targets as gcodeplan read
    them (float64 mm), the feed in mm/s (a rapid for G0 or an infinite feed) and the dwell in s (NaN as 0):
    (is_sync, target (n, 3), rate_v, rapid, dwell_s, MOVE row of each)."""
    kind = moves["kind"]
    rows = np.flatnonzero((kind <= 1) | (kind == KIND_DWELL) | (kind == KIND_WAIT))
    m = moves[rows]
    is_sync = (m["kind"] == KIND_DWELL) | (m["kind"] == KIND_WAIT)
    target = np.stack([m["x1"], m["y1"], m["z1"]], axis=1).astype(np.float64)
    feed = m["feed_v"].astype(np.float64)
    rapid = ((m["flags"] & FLAG_RAPID) != 0) | ~np.isfinite(feed)
    rate_v = np.where(rapid, 0.0, feed)
    dwell = m["dwell_t"].astype(np.float64)
    dwell_s = np.where((m["kind"] == KIND_DWELL) & (dwell == dwell), dwell, 0.0)
    return is_sync, target, rate_v, rapid, dwell_s, rows


def run_ideal(moves: np.ndarray, settings, buffer_blocks=16) -> IdealRun:
    """grbl's plan of MOVE rows without quantisation (see the module docstring). ``settings``: a
    :class:`gcodeplan.planner.grbl.GrblSettings`, of which the exact (float64) max rates, accelerations and
    junction deviation and the idle delay are used; ``buffer_blocks``: the ring's slots (None or math.inf:
    unbounded)."""
    n = check_buffer_blocks(buffer_blocks, unbounded_ok=True)
    is_sync, target, rate_v, rapid, dwell_s, rows = ideal_operations(moves)
    if n is None:
        n = int((~is_sync).sum()) + 2              # room for every block: the ring never fills
    rf = np.zeros((n, N_RF))
    out = np.zeros((len(rows), N_OT))
    ideal_run_kernel(is_sync, target, rate_v, rapid, dwell_s, np.asarray(settings.exact_max_v, np.float64),
                     np.asarray(settings.exact_max_a, np.float64), float(settings.exact_junction_deviation),
                     settings.idle_lock_ticks / F_CPU, rf, out)
    row_end = np.full(len(moves), np.nan)
    ran = out[:, OT_HAS] == 1
    row_end[rows[ran]] = out[ran, OT_T_END]
    total = float(out[ran, OT_T_END].max()) if ran.any() else 0.0
    return IdealRun(row_end, total, out, rows)
