"""Per-move limits and junction limits: MOVE rows → PREP rows (one per move).

This is Klipper's ``Move`` construction and ``calc_junction`` (see
docs/design.md, "Klipper's planner") generalised to the other junction policies. All
speeds are tracked squared (``_v2``). The arrays are computed by two numba kernels:

* ``_move_limits_kernel``: independent per move (cruise speed cap, acceleration, Δv² = 2·d·a);
* ``_junction_kernel``: sequential, the junction cap with the previous move, including the
  forward reach ``max_start_v2 ≤ prev.max_start_v2 + prev.delta_v2`` (so a single backward pass
  afterwards gives the maximal feasible speeds).

Rows that are not motion (dwell, wait, zero-length moves) have ``is_move = 0``: a dwell or wait row
forces a full stop (the next move has ``stop_before``), a zero-length move is dropped (Klipper
never queues it) and the junction is taken between its neighbours.
"""
from __future__ import annotations

import math

from .._jit import njit
import numpy as np

from ..errors import ConfigError, GcodeError
from ..machine import POLICIES
from ..schema import (KIND_DWELL, KIND_WAIT, MOVE_DTYPE, concat_rows, LIMIT_AXIS, LIMIT_EXTRUDER, LIMIT_FEED,
                      LIMIT_MAX_V, LIMIT_NONE, LIMITS_DTYPE)
from .junctions import (jd_junction_v2, klipper_centripetal_v2, klipper_extruder_corner_v2,
                        klipper_junction_deviation, marlin_jerk_junction_v, marlin_safe_v,
                        marlin_small_segment_v2)

# _move_limits_kernel error codes
ERR_NONE, ERR_LIMITS_ROW, ERR_FEED, ERR_ACCEL, ERR_COORD, ERR_DWELL, ERR_NO_ACCEL, ERR_NO_SPEED = range(8)
ERR_TINY_ACCEL = 8     # reported only when no other error: the kernel goes on past such a row
# mm/s²: every planner divides by the acceleration and squares speeds: below ~1e-150 mm/s² (M204 /
# SET_VELOCITY_LIMIT ACCEL=1e-320, found by tools/fuzz.py) that gives inf, NaN or 0 s instead of the
# astronomically long time it means (S-curves planned a 123 mm move in 0 s)
MIN_PLAN_ACCEL = 1e-150
_ERR_TEXT = {ERR_LIMITS_ROW: "move refers to a LIMITS row that does not exist",
             ERR_FEED: "feed rate must be > 0 (F0 or no F given?)",
             ERR_ACCEL: "acceleration must be finite and > 0",
             ERR_COORD: "a coordinate is not finite",
             ERR_DWELL: "dwell time must be >= 0",
             ERR_NO_ACCEL: "no acceleration limit applies to this move: set toolhead max_accel or the "
                           "max_accel of every axis it moves (machine file)",
             ERR_NO_SPEED: "no speed limit applies to this rapid move: set toolhead max_velocity, "
                           "rapid_velocity or the max_velocity of every axis it moves (machine file)"}

POLICY_KLIPPER, POLICY_JD, POLICY_CLASSIC_JERK, POLICY_BLEND, POLICY_EXACT_STOP, POLICY_LINUXCNC = range(6)
assert POLICIES == ("klipper", "junction-deviation", "classic-jerk", "blend", "exact-stop", "linuxcnc")

# Klipper: an extrude-only move starts with this acceleration before the extruder limits apply.
KLIPPER_EXTRUDE_ONLY_ACCEL = 99999999.9
# Klipper: an XYZ length below this is an extrude-only move.
KLIPPER_MIN_MOVE_D = 1e-9

PREP_DTYPE = np.dtype(
    [
        ("move_d", "f8"),            # mm: XYZ length, |dE| for extrude-only
        ("axes_r_x", "f8"), ("axes_r_y", "f8"), ("axes_r_z", "f8"), ("axes_r_e", "f8"),  # d_i / move_d
        ("max_cruise_v2", "f8"),     # mm²/s² after every speed limit
        ("accel", "f8"),             # mm/s² after every acceleration limit
        ("delta_v2", "f8"),          # 2·move_d·accel
        ("max_start_v2", "f8"),      # junction cap with the previous move (incl. forward reach)
        ("mcr_delta_v2", "f8"),      # 2·move_d·accel·(1 − mcr), capped by delta_v2 (Klipper)
        ("max_mcr_start_v2", "f8"),  # the same junction chain with mcr_delta_v2 (Klipper)
        ("limit", "u1"),             # LIMIT_* that bounded max_cruise_v2
        ("stop_before", "?"),        # a full stop (flush) precedes this move
        ("is_move", "?"),            # False for dwell / wait / zero-length rows
        ("kinematic", "?"),          # XYZ motion (False: extrude-only)
        ("junction_dev", "f8"),      # mm, δ used by this move (Klipper: from scv; JD: LIMITS.junction_dev)
        ("stop_v2", "f8"),           # speed² allowed next to a full stop (classic-jerk safe speed, else 0)
        # mm²/s², mm/s²: the caps when Klipper calls the kinematics' check_move (before the extruder's rule),
        # what a plug-in's limits hook sees (apply_kinematics_limits)
        ("kin_cruise_v2", "f8"), ("kin_accel", "f8"),
    ],
    align=True,
)

#: the one PREP row of :func:`unread_prep`
_ZERO_PREP = np.zeros(1, dtype=PREP_DTYPE)[0]


def unread_prep(n: int) -> np.ndarray:
    """n PREP rows for the window of a mode that never reads them (the firmware models plan from the MOVE rows
    alone; the stream keeps its PREP rows 1:1 with its MOVE rows): one zero row repeated, a read-only view of no
    memory. Zeroing and copying 128 bytes a row would cost such a mode a tenth of its time."""
    return np.broadcast_to(_ZERO_PREP, (n,))


# LIMITS columns, in the order handed to the kernel as one 2-D float array.
_LIM_FIELDS = tuple(LIMITS_DTYPE.names)
_L = {name: k for k, name in enumerate(_LIM_FIELDS)}
L_MAX_V, L_SCV, L_MCR, L_JD = _L["max_v"], _L["scv"], _L["mcr"], _L["junction_dev"]
L_JERK0, L_AXV0, L_AXA0 = _L["jerk_x"], _L["axis_v_x"], _L["axis_a_x"]
L_EO_V, L_EO_A, L_ICV = _L["extrude_only_v"], _L["extrude_only_a"], _L["icv"]
L_MIN_FEED, L_MIN_TRAVEL = _L["min_feed_v"], _L["min_travel_v"]
L_DELTA_SLOW_XY2, L_DELTA_VSLOW_XY2 = _L["delta_slow_xy2"], _L["delta_very_slow_xy2"]
L_DELTA_V, L_DELTA_A = _L["delta_slow_v"], _L["delta_slow_a"]


def policy_code(policy: str) -> int:
    """The kernel code of a policy: a built-in's own, a registered policy's ``moves_like`` built-in."""
    if policy in POLICIES:
        return POLICIES.index(policy)
    from .policies import get_policy

    return POLICIES.index(get_policy(policy).moves_like)


def custom_cap(policy: str):
    """The cap function of a registered (non built-in) policy, None for a built-in."""
    if policy in POLICIES:
        return None
    from .policies import get_policy

    return get_policy(policy).cap_v2


# --------------------------------------------------------------------------- per-move kernel
@njit(cache=True)
def _limit_speed(speed_v: float, accel: float, code: int, move_d: float,
                 max_cruise_v2: float, cur_accel: float, mcr_delta_v2: float, limit: int):
    """Klipper Move.limit_speed: v² cap (strictly lower wins), accel = min, Δv² recomputed,
    mcr Δv² ≤ Δv². Returns the updated (max_cruise_v2, accel, delta_v2, mcr_delta_v2, limit)."""
    speed_v2 = speed_v * speed_v
    if speed_v2 < max_cruise_v2:
        max_cruise_v2 = speed_v2
        limit = code
    cur_accel = min(cur_accel, accel)
    delta_v2 = 2.0 * move_d * cur_accel
    mcr_delta_v2 = min(mcr_delta_v2, delta_v2)
    return max_cruise_v2, cur_accel, delta_v2, mcr_delta_v2, limit


@njit(cache=True, _nrt=False, inline="always")
def _clear_prep_row(out) -> None:
    """A PREP row with nothing in it (a dwell, a wait, a zero-length move)."""
    out.is_move = False
    out.kinematic = False
    out.stop_before = False
    out.limit = LIMIT_NONE
    out.move_d = 0.0
    out.axes_r_x = 0.0
    out.axes_r_y = 0.0
    out.axes_r_z = 0.0
    out.axes_r_e = 0.0
    out.max_cruise_v2 = 0.0
    out.accel = 0.0
    out.delta_v2 = 0.0
    out.mcr_delta_v2 = 0.0
    out.max_start_v2 = 0.0
    out.max_mcr_start_v2 = 0.0
    out.junction_dev = 0.0
    out.stop_v2 = 0.0
    out.kin_cruise_v2 = 0.0
    out.kin_accel = 0.0


@njit(cache=True, _nrt=False, inline="always")
def _requested_speed(policy: int, L, feed: float, accel: float, d, move_d: float):
    """The move's requested speed before the axis rules (Klipper Move.__init__): the feed (with Marlin's
    M205 S/T floor) capped by the machine's max velocity; a move under KLIPPER_MIN_MOVE_D (mm) is
    extrude-only (``d``'s x, y, z zeroed, its length |E|), at the requested speed and a huge accel on Klipper.
    Returns (kinematic, velocity mm/s, limit code, accel mm/s², move_d mm)."""
    if policy != POLICY_KLIPPER:
        # Marlin M205 S/T: a floor on the requested feed, S for every move that steps E (retractions
        # too: planner.cpp tests the E step count, not its sign), T for the others.
        floor_v = L[L_MIN_FEED] if d[3] != 0.0 else L[L_MIN_TRAVEL]
        if feed < floor_v:
            feed = floor_v
    kinematic = move_d >= KLIPPER_MIN_MOVE_D
    if kinematic:
        velocity = min(feed, L[L_MAX_V])
        limit = LIMIT_MAX_V if L[L_MAX_V] < feed else LIMIT_FEED
    else:
        d[0] = 0.0
        d[1] = 0.0
        d[2] = 0.0
        move_d = abs(d[3])
        if policy == POLICY_KLIPPER:
            # Klipper: extrude-only keeps the requested speed, huge accel, then extruder limits.
            velocity = feed
            limit = LIMIT_FEED
            accel = KLIPPER_EXTRUDE_ONLY_ACCEL
        else:
            velocity = min(feed, L[L_MAX_V])
            limit = LIMIT_MAX_V if L[L_MAX_V] < feed else LIMIT_FEED
    return kinematic, velocity, limit, accel, move_d


@njit(cache=True, _nrt=False, inline="always")
def _axis_limits(L, d, kinematic: bool, move_d: float, max_cruise_v2: float, accel: float, delta_v2: float,
                 mcr_delta_v2: float, limit: int):
    """Per-axis limits, v ≤ V_i·d/|d_i|, a ≤ A_i·d/|d_i| (Klipper's z_ratio form, exact; E's on an
    extrude-only move too). Returns the updated (max_cruise_v2, accel, delta_v2, mcr_delta_v2, limit)."""
    for a in range(4):
        if d[a] != 0.0 and (kinematic or a == 3):
            av = L[L_AXV0 + a]
            aa = L[L_AXA0 + a]
            if av < math.inf or aa < math.inf:
                ratio = move_d / abs(d[a])
                code = LIMIT_AXIS if a < 3 else LIMIT_EXTRUDER
                max_cruise_v2, accel, delta_v2, mcr_delta_v2, limit = _limit_speed(
                    av * ratio, aa * ratio, code, move_d, max_cruise_v2, accel, mcr_delta_v2, limit)
    return max_cruise_v2, accel, delta_v2, mcr_delta_v2, limit


@njit(cache=True, _nrt=False, inline="always")
def _delta_limits(mv, L, move_d: float, max_cruise_v2: float, accel: float, delta_v2: float,
                  mcr_delta_v2: float, limit: int):
    """Klipper's delta.py check_move: towers run fast far from the centre, so a move reaching past
    ratio_to_xy(3) gets half the config's max velocity / accel, past ratio_to_xy(6) a quarter
    (docs/design.md, "Delta"). Z is limited by the per-axis rule, as in Klipper. Returns the updated
    (max_cruise_v2, accel, delta_v2, mcr_delta_v2, limit)."""
    extreme_xy2 = max(mv.x1 * mv.x1 + mv.y1 * mv.y1, mv.x0 * mv.x0 + mv.y0 * mv.y0)
    if extreme_xy2 > L[L_DELTA_SLOW_XY2]:
        r = 0.25 if extreme_xy2 > L[L_DELTA_VSLOW_XY2] else 0.5
        max_cruise_v2, accel, delta_v2, mcr_delta_v2, limit = _limit_speed(
            L[L_DELTA_V] * r, L[L_DELTA_A] * r, LIMIT_MAX_V, move_d, max_cruise_v2, accel, mcr_delta_v2, limit)
    return max_cruise_v2, accel, delta_v2, mcr_delta_v2, limit


@njit(cache=True, _nrt=False, inline="always")
def _extruder_limits(L, d, axes_r_e: float, move_d: float, max_cruise_v2: float, accel: float, delta_v2: float,
                     mcr_delta_v2: float, limit: int):
    """Klipper extruder.check_move: an extrude-only move (no X/Y motion) or a retraction takes the
    extrude-only limits. Returns the updated (max_cruise_v2, accel, delta_v2, mcr_delta_v2, limit)."""
    if d[3] != 0.0 and ((d[0] == 0.0 and d[1] == 0.0) or axes_r_e < 0.0):
        if L[L_EO_V] < math.inf or L[L_EO_A] < math.inf:
            inv_extrude_r = 1.0 / abs(axes_r_e)
            max_cruise_v2, accel, delta_v2, mcr_delta_v2, limit = _limit_speed(
                L[L_EO_V] * inv_extrude_r, L[L_EO_A] * inv_extrude_r, LIMIT_EXTRUDER, move_d,
                max_cruise_v2, accel, mcr_delta_v2, limit)
    return max_cruise_v2, accel, delta_v2, mcr_delta_v2, limit


@njit(cache=True, _nrt=False, inline="always")
def _junction_settings(out, L, policy: int, req_accel: float) -> None:
    """The row's junction deviation (mm: Klipper's from square_corner_velocity and the requested accel, else
    the machine's) and, for classic jerk, Marlin's safe speed² (mm²/s²) to start and stop at."""
    if policy == POLICY_KLIPPER:
        out.junction_dev = klipper_junction_deviation(L[L_SCV], req_accel)
    else:
        out.junction_dev = L[L_JD]
    if policy == POLICY_CLASSIC_JERK:
        cruise_v = math.sqrt(out.max_cruise_v2)
        safe_v = marlin_safe_v(cruise_v, out.axes_r_x * cruise_v, out.axes_r_y * cruise_v,
                               out.axes_r_z * cruise_v, out.axes_r_e * cruise_v,
                               L[L_JERK0], L[L_JERK0 + 1], L[L_JERK0 + 2], L[L_JERK0 + 3])
        out.stop_v2 = safe_v * safe_v


# _nrt=False: the kernel allocates nothing (``d`` is the caller's scratch), and without numba's reference
# counting the limits row taken per move costs no atomic incref/decref (25 -> 14 ns per move)
@njit(cache=True, _nrt=False)
def _move_limits_kernel(moves, lim, policy, prep, d):
    """Per-move limits (Klipper Move.__init__, kinematics and extruder check_move) into ``prep``; ``d`` is a
    scratch float array of 4 (the move's x, y, z, e lengths, mm).
    Returns (error code, row) of the first row the planner cannot use, (ERR_NONE, -1) if none; a move whose
    acceleration is below MIN_PLAN_ACCEL is (ERR_TINY_ACCEL, its row) when no row has another error."""
    n = moves.shape[0]
    n_lim = lim.shape[0]
    tiny_row = -1
    for i in range(n):
        mv = moves[i]
        out = prep[i]
        _clear_prep_row(out)
        k = mv.kind
        if k == KIND_DWELL or k == KIND_WAIT:
            if not mv.dwell_t >= 0.0:
                return ERR_DWELL, i
            continue
        if mv.limits < 0 or mv.limits >= n_lim:
            return ERR_LIMITS_ROW, i
        if not mv.feed_v > 0.0:
            return ERR_FEED, i
        # inf is allowed here: a grbl machine has only per-axis limits, which bound the move below.
        if not mv.accel > 0.0:
            return ERR_ACCEL, i
        L = lim[mv.limits]
        d[0] = mv.x1 - mv.x0
        d[1] = mv.y1 - mv.y0
        d[2] = mv.z1 - mv.z0
        d[3] = mv.e1 - mv.e0
        for a in range(4):
            if not abs(d[a]) < math.inf:
                return ERR_COORD, i
        # Klipper: sum of squares in x, y, z order, then sqrt (bit-identical move_d).
        move_d = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        kinematic, velocity, limit, accel, move_d = _requested_speed(policy, L, mv.feed_v, mv.accel, d, move_d)
        if move_d == 0.0:
            continue  # zero-length: dropped, as Klipper's toolhead.move does
        inv_move_d = 1.0 / move_d
        max_cruise_v2 = velocity * velocity
        delta_v2 = 2.0 * move_d * accel
        mcr_pseudo_accel = mv.accel * (1.0 - L[L_MCR])
        mcr_delta_v2 = 2.0 * move_d * mcr_pseudo_accel
        max_cruise_v2, accel, delta_v2, mcr_delta_v2, limit = _axis_limits(
            L, d, kinematic, move_d, max_cruise_v2, accel, delta_v2, mcr_delta_v2, limit)
        if kinematic and L[L_DELTA_V] > 0.0:
            max_cruise_v2, accel, delta_v2, mcr_delta_v2, limit = _delta_limits(
                mv, L, move_d, max_cruise_v2, accel, delta_v2, mcr_delta_v2, limit)
        out.kin_cruise_v2 = max_cruise_v2
        out.kin_accel = accel
        axes_r_e = d[3] * inv_move_d
        max_cruise_v2, accel, delta_v2, mcr_delta_v2, limit = _extruder_limits(
            L, d, axes_r_e, move_d, max_cruise_v2, accel, delta_v2, mcr_delta_v2, limit)
        if not accel < math.inf:
            return ERR_NO_ACCEL, i
        if not max_cruise_v2 < math.inf:
            return ERR_NO_SPEED, i
        out.is_move = True
        out.kinematic = kinematic
        out.move_d = move_d
        out.axes_r_x = d[0] * inv_move_d
        out.axes_r_y = d[1] * inv_move_d
        out.axes_r_z = d[2] * inv_move_d
        out.axes_r_e = axes_r_e
        out.max_cruise_v2 = max_cruise_v2
        out.accel = accel
        if tiny_row < 0 and not accel >= MIN_PLAN_ACCEL:
            tiny_row = i
        out.delta_v2 = delta_v2
        out.mcr_delta_v2 = mcr_delta_v2
        out.limit = limit
        _junction_settings(out, L, policy, mv.accel)
    if tiny_row >= 0:
        return ERR_TINY_ACCEL, tiny_row
    return ERR_NONE, -1


# --------------------------------------------------------------------------- a plug-in kinematics' limits
KIN_BAD_CAP = -1     # _kinematics_limits_kernel: the hook returned a cap that is no speed / accel


@njit(cache=True)
def _kinematics_limits_kernel(moves, prep, check_move, params, mv, caps):
    """A kinematics plug-in's check_move on every kinematic move of ``prep`` (gcodeplan.kinematics.plugin):
    its speed / accel caps go through Klipper's limit_speed onto the move's (the caps are minima, so taking
    them after the extruder's rule gives Klipper's result; the hook sees the move as Klipper's check_move
    does, ``kin_cruise_v2``/``kin_accel``). ``check_move`` is the hook as a cfunc
    (:func:`gcodeplan.kinematics.plugin.hook_cfunc`); ``mv``: scratch float array of 9, ``caps`` of 2.
    Returns (row, error code) of the first refused move, (-1, 0) if none."""
    for i in range(moves.shape[0]):
        out = prep[i]
        if not (out.is_move and out.kinematic):
            continue
        m = moves[i]
        mv[0] = m.x0
        mv[1] = m.y0
        mv[2] = m.z0
        mv[3] = m.x1
        mv[4] = m.y1
        mv[5] = m.z1
        mv[6] = out.move_d
        mv[7] = out.kin_cruise_v2
        mv[8] = out.kin_accel
        caps[0] = math.inf
        caps[1] = math.inf
        err = check_move(mv, params, caps)
        v_cap = caps[0]
        a_cap = caps[1]
        if err != 0:
            return i, err
        if not (v_cap > 0.0 and a_cap > 0.0):
            return i, KIN_BAD_CAP        # NaN or <= 0: a bug in the hook, not a speed
        if v_cap < math.inf or a_cap < math.inf:
            if not a_cap < math.inf:
                a_cap = out.accel
            out.max_cruise_v2, out.accel, out.delta_v2, out.mcr_delta_v2, out.limit = _limit_speed(
                v_cap, a_cap, LIMIT_MAX_V, out.move_d, out.max_cruise_v2, out.accel, out.mcr_delta_v2, out.limit)
    return -1, 0


def apply_kinematics_limits(moves: np.ndarray, prep: np.ndarray, hook) -> None:
    """Apply a plug-in kinematics' limits hook (``hook`` = (check_move, params, plug-in) from
    :func:`gcodeplan.kinematics.plugin.limits_hook`) to the PREP rows of ``moves``, in place; a refused move
    is a GcodeError at its line with the plug-in's text (Klipper's "Move out of range: x y z [e]")."""
    fn, params, plugin = hook
    row, err = _kinematics_limits_kernel(moves, prep, fn, params, np.empty(9), np.empty(2))
    if row >= 0 and err == KIN_BAD_CAP:
        raise _line_error(moves, row, f"kinematics {plugin.name!r}: its check_move returned a speed or accel cap "
                                      f"that is NaN or <= 0 (return inf for no cap)")
    if row >= 0:
        mv = moves[row]
        text = plugin.move_error(err)
        raise _line_error(moves, row, f"{text}: {mv['x1']:.3f} {mv['y1']:.3f} {mv['z1']:.3f} [{mv['e1']:.3f}] "
                                      f"(kinematics {plugin.name!r} refuses this move)")


# --------------------------------------------------------------------------- junction kernel
@njit(cache=True)
def _junction_kernel(moves, lim, policy, prev_prep, stop_pending, prep):
    """Sequential junction caps for the rows of ``prep``; ``prev_prep`` = the PREP row of the move before
    them (one row, or none: a chunk's predecessor is passed alone, so that a chunk is never copied to
    sit behind it), ``stop_pending`` = a full stop happened since it. Returns (prev, stop_pending), prev =
    the row of the last move in ``prep`` (-1: none)."""
    n = moves.shape[0]
    prev = -1
    has_prev = prev_prep.shape[0] > 0
    for i in range(n):
        cur = prep[i]
        k = moves[i].kind
        if k == KIND_DWELL or k == KIND_WAIT:
            cur.stop_before = True
            stop_pending = True
            continue
        if not cur.is_move:
            continue
        if (prev < 0 and not has_prev) or stop_pending or policy == POLICY_EXACT_STOP:
            cur.stop_before = True
            cur.max_start_v2 = cur.stop_v2
            cur.max_mcr_start_v2 = 0.0
        else:
            cur.stop_before = False
            pm = prep[prev] if prev >= 0 else prev_prep[0]
            v2 = 0.0
            reach_v2 = pm.max_start_v2 + pm.delta_v2
            if cur.kinematic and pm.kinematic:
                junction_cos_theta = -(cur.axes_r_x * pm.axes_r_x + cur.axes_r_y * pm.axes_r_y
                                       + cur.axes_r_z * pm.axes_r_z)
                if policy == POLICY_KLIPPER:
                    L = lim[moves[i].limits]
                    e_v2 = klipper_extruder_corner_v2(L[L_ICV], cur.axes_r_e, pm.axes_r_e, cur.max_cruise_v2)
                    # Klipper's caps: extruder, both cruise speeds, next_junction_v2, previous reach.
                    v2 = min(e_v2, cur.max_cruise_v2, pm.max_cruise_v2, 999999999.9, reach_v2)
                    v2 = min(v2, klipper_centripetal_v2(junction_cos_theta, cur.junction_dev, cur.accel,
                                                        cur.delta_v2, pm.junction_dev, pm.accel, pm.delta_v2))
                else:
                    # grbl/Marlin: the junction's block (this move) acceleration.
                    v2 = min(cur.max_cruise_v2, pm.max_cruise_v2, reach_v2,
                             jd_junction_v2(junction_cos_theta, cur.accel, cur.junction_dev))
                    if policy == POLICY_JD:
                        v2 = min(v2, marlin_small_segment_v2(junction_cos_theta, cur.move_d, cur.accel))
            if policy == POLICY_CLASSIC_JERK:
                # Per-axis velocity jumps, E included; applies to extrude-only neighbours as well.
                L = lim[moves[i].limits]
                jv = marlin_jerk_junction_v(math.sqrt(pm.max_cruise_v2), math.sqrt(cur.max_cruise_v2),
                                            pm.axes_r_x, pm.axes_r_y, pm.axes_r_z, pm.axes_r_e,
                                            cur.axes_r_x, cur.axes_r_y, cur.axes_r_z, cur.axes_r_e,
                                            L[L_JERK0], L[L_JERK0 + 1], L[L_JERK0 + 2], L[L_JERK0 + 3],
                                            math.sqrt(pm.stop_v2), math.sqrt(cur.stop_v2))
                v2 = min(jv * jv, cur.max_cruise_v2, pm.max_cruise_v2, reach_v2)
            cur.max_start_v2 = v2
            cur.max_mcr_start_v2 = min(v2, pm.max_mcr_start_v2 + pm.mcr_delta_v2)
        prev = i
        stop_pending = moves[i].exact_stop != 0
    return prev, stop_pending


# --------------------------------------------------------------------------- Python layer
# every LIMITS field is a float64 at offset 8·k: a row's bytes are already the table's row
_LIM_PACKED = LIMITS_DTYPE.itemsize == 8 * len(_LIM_FIELDS) and all(
    LIMITS_DTYPE.fields[name][:2] == (np.dtype(np.float64), 8 * k) for k, name in enumerate(_LIM_FIELDS))


def limits_table(limits: np.ndarray) -> np.ndarray:
    """LIMITS rows → contiguous (n, n_fields) float array in LIMITS_DTYPE field order."""
    limits = np.asarray(limits)
    if limits.dtype != LIMITS_DTYPE:
        raise ConfigError("limits: table does not have LIMITS_DTYPE")
    if _LIM_PACKED:   # one copy instead of one per field (this runs for every chunk of a file)
        return np.ascontiguousarray(limits).view(np.float64).reshape(len(limits), len(_LIM_FIELDS)).copy()
    out = np.empty((len(limits), len(_LIM_FIELDS)), dtype=np.float64)
    for k, name in enumerate(_LIM_FIELDS):
        out[:, k] = limits[name]
    return out


def _line_error(moves: np.ndarray, row: int, message: str) -> GcodeError:
    """The MOVE rows do not know their file name: the caller (CLI) adds it; the line is in the text."""
    line = int(moves["line"][row])
    return GcodeError(message, line=line)


def validate(moves: np.ndarray, limits: np.ndarray, policy: int) -> None:
    """Reject limits the planner cannot give a true answer for (per-row checks are in the kernel)."""
    if moves.dtype != MOVE_DTYPE:
        raise ConfigError("moves: array does not have MOVE_DTYPE")
    if len(limits) == 0:
        raise ConfigError("limits: the LIMITS table is empty (row 0 comes from the machine)")
    mcr = limits["mcr"]
    bad = ~((mcr >= 0.0) & (mcr < 1.0))
    if np.any(bad):
        raise ConfigError(f"minimum_cruise_ratio must be in [0, 1), got {float(mcr[bad][0])}")
    if policy == POLICY_KLIPPER and np.any(~(limits["scv"] >= 0.0)):
        raise ConfigError("square_corner_velocity must be >= 0")
    if policy in (POLICY_JD, POLICY_BLEND) and np.any(~(limits["junction_dev"] >= 0.0)):
        raise ConfigError("junction_deviation must be >= 0")
    # "> 0" for the planner means that v² and 1/a are still numbers: a positive speed below ~1e-154 mm/s squares
    # to 0 and divides by zero later (SET_VELOCITY_LIMIT VELOCITY=1e-320, found by tools/fuzz.py)
    def positive(v):
        return v >= 1e-150      # inf (no limit) passes, nan fails

    if np.any(~positive(limits["max_v"])):
        raise ConfigError(f"max_velocity must be > 0, got {float(limits['max_v'][~positive(limits['max_v'])][0])!r}")
    for a in "xyze":
        if np.any(~positive(limits["axis_v_" + a])) or np.any(~positive(limits["axis_a_" + a])):
            raise ConfigError(f"max velocity / accel of axis {a} must be > 0")
    if np.any(~positive(limits["extrude_only_v"])) or np.any(~positive(limits["extrude_only_a"])):
        raise ConfigError("max_extrude_only_velocity / max_extrude_only_accel must be > 0")
    if policy == POLICY_CLASSIC_JERK:
        jerks = np.stack([limits["jerk_" + a] for a in "xyze"], axis=1)
        if np.any(jerks < 0.0) or np.any(~np.isfinite(jerks)):
            raise ConfigError("jerk (M205 X/Y/Z/E) must be finite and >= 0")
        if np.any(np.all(jerks == 0.0, axis=1)):
            raise ConfigError("classic-jerk policy needs a jerk per axis (M205 X/Y/Z/E, [axis] jerk); all are 0")


def prepare_with_context(moves: np.ndarray, limits: np.ndarray, policy: int,
                         prev_moves: np.ndarray | None = None, prev_prep: np.ndarray | None = None,
                         stop_pending: bool = True, cap_v2=None, out: np.ndarray | None = None,
                         kinematics_hook=None) -> tuple[np.ndarray, bool]:
    """PREP rows for ``moves``, continuing from one previous move (the streaming case).

    ``prev_moves``/``prev_prep``: the last real move already prepared (one row each) or None;
    ``stop_pending``: a full stop happened after it; ``cap_v2``: a registered policy's cap function
    (:mod:`gcodeplan.planner.policies`), None for the built-in kernel of ``policy``; ``out``: zeroed
    contiguous PREP rows, one per move, to fill (the tail of the streaming planner's window, so that the
    chunk is not copied there afterwards), None = new ones.
    ``kinematics_hook``: the machine's plug-in limits (:func:`gcodeplan.kinematics.plugin.limits_hook`), None
    for none. Returns (prep, stop_pending after the chunk).
    """
    moves = np.ascontiguousarray(moves)
    lim = limits_table(limits)
    prep = np.zeros(len(moves), dtype=PREP_DTYPE) if out is None else out
    err, row = _move_limits_kernel(moves, lim, policy, prep, np.empty(4))
    if err == ERR_TINY_ACCEL:
        raise _line_error(moves, row, f"acceleration {float(prep['accel'][row])!r} mm/s² is too small to plan with")
    if err != ERR_NONE:
        raise _line_error(moves, row, _ERR_TEXT[err])
    if kinematics_hook is not None:
        apply_kinematics_limits(moves, prep, kinematics_hook)
    if cap_v2 is None:
        before = np.zeros(0, PREP_DTYPE) if prev_prep is None else np.ascontiguousarray(prev_prep)
        _, stop_pending = _junction_kernel(moves, lim, policy, before, bool(stop_pending), prep)
        return prep, bool(stop_pending)
    from .policies import cap_junction_kernel

    if prev_prep is not None:
        ctx = concat_rows(prev_prep, prep)
        ctx_moves = concat_rows(prev_moves, moves)
        i_start, prev = 1, 0
    else:
        ctx, ctx_moves = prep, moves
        i_start, prev = 0, -1
    _, stop_pending = cap_junction_kernel(ctx_moves, lim, cap_v2, policy == POLICY_EXACT_STOP, i_start, prev,
                                          bool(stop_pending), ctx)
    if prev_prep is not None:
        prep[...] = ctx[1:]      # into ``out`` when given
    return prep, bool(stop_pending)


def prepare(moves: np.ndarray, limits: np.ndarray, machine, policy: str | None = None) -> np.ndarray:
    """PREP_DTYPE rows, one per MOVE row: per-move speed/accel limits and junction caps.

    ``policy`` None = ``machine.junction_policy``. The first move starts from rest
    (``stop_before``); so does every move after a dwell/wait row or an ``exact_stop`` move.
    Policy 'blend' computes the junction caps of 'junction-deviation' (the blend planner uses
    the per-move limits and does its own corners).
    """
    name = policy or machine.junction_policy
    pcode = policy_code(name)
    moves = np.asarray(moves)
    limits = np.asarray(limits)
    validate(moves, limits, pcode)
    if pcode == POLICY_BLEND:
        pcode = POLICY_JD
    prep, _ = prepare_with_context(moves, limits, pcode, cap_v2=custom_cap(name),
                                   kinematics_hook=kinematics_limits(machine))
    return prep


def kinematics_limits(machine):
    """The machine's plug-in limits hook for :func:`prepare_with_context`, None when its kinematics has none."""
    if machine is None or machine.kinematics in ("cartesian", "corexy", "corexz", "delta"):
        return None
    from ..kinematics.plugin import limits_hook

    return limits_hook(machine)
