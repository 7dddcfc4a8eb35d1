"""The arrays that travel between stages.

Every stage speaks NumPy structured arrays with the dtypes below, so that numba
kernels can loop over them without Python objects. Units inside: mm, s, mm/s,
mm/s², mm/s³, whatever the G-code file said (G20 inches are converted by the
parser).

Data flow (docs/design.md §1)::

    gcode/   text  -> MOVE rows   (+ LIMITS table, layer/feature names, events)
    planner/ MOVE  -> PLAN rows   (one per MOVE row: speeds, phase times, start time)
    planner/ PLAN  -> SEGMENT rows (per-axis cubic pieces in time; what the stepper,
                                    the sampler and the plots consume)
"""
from __future__ import annotations

import weakref

import numpy as np

# --------------------------------------------------------------------------- units
# Names carry their units, as in Klipper's toolhead.py. The unit of a field (and of a variable in the
# code) is its name's suffix:
#   _d     mm        a distance                 move_d
#   _v     mm/s      a speed                    feed_v, cruise_v
#   _v2    mm²/s²    a speed squared            the junction caps of planner/prepare.py
#   _t     s         a time                     dwell_t, accel_t
#   _a     mm/s²     an acceleration            max_a, extrude_only_a
#   _xy2   mm²       a squared distance in XY   delta_slow_xy2
#   accel, decel: mm/s²; jerk: mm/s³ (the whole name or its last ``_`` part)
# A field whose name has none of them starts its comment with its unit (one of UNITS; on a line of several
# fields, one per field, comma-separated), or with what it is when it has none (UNITLESS: a code of the
# module's constants, a bit set, an index, a ratio). tests/test_structure.py checks every field here.
UNIT_SUFFIXES = {"_d": "mm", "_v": "mm/s", "_v2": "mm²/s²", "_t": "s", "_a": "mm/s²", "_xy2": "mm²",
                 "accel": "mm/s²", "decel": "mm/s²", "jerk": "mm/s³"}
UNITS = ("mm", "s", "mm/s", "mm/s²", "mm/s³", "mm²", "mm²/s²", "Hz")
UNITLESS = ("code", "bits", "index", "ratio")


def unit_of_name(name: str) -> str | None:
    """The unit a field's name declares by its suffix (:data:`UNIT_SUFFIXES`), or None."""
    last = name.rsplit("_", 1)[-1]
    if last in UNIT_SUFFIXES:
        return UNIT_SUFFIXES[last]
    for suffix in sorted((k for k in UNIT_SUFFIXES if k.startswith("_")), key=len, reverse=True):
        if name.endswith(suffix):
            return UNIT_SUFFIXES[suffix]
    return None


# --------------------------------------------------------------------------- moves
# MOVE.kind
KIND_TRAVEL = 0        # XYZ motion, no extrusion (or E not increasing with XYZ: see PRINT)
KIND_PRINT = 1         # XYZ motion with E increasing
KIND_EXTRUDE_ONLY = 2  # E only (retract / unretract / prime), move_d = |dE|
KIND_DWELL = 3         # G4: full stop, then dwell_t seconds (counted as motion time, as Klipper does)
KIND_WAIT = 4          # full stop + dwell_t seconds that are *not* motion: M109/M190 waits,
                       # G28 homing time, M400/M0/M1/tool change (dwell_t = 0). Reported as waits.
KIND_NAMES = ("travel", "print", "extrude_only", "dwell", "wait")

# MOVE.flags (bit set)
FLAG_RAPID = 1         # G0 (on CNC flavors: runs at the machine's rapid rate, feed_v = inf)
FLAG_ARC = 2           # a chord of a G2/G3 arc
FLAG_RETRACT = 4       # E decreasing (retraction, with or without XYZ)
FLAG_HOMING = 8        # KIND_WAIT row made by G28
FLAG_CANNED = 16       # a move expanded from a canned cycle (G73/G81/G82/G83...)
FLAG_FIRMWARE_RETRACT = 32  # made by G10/G11

MOVE_DTYPE = np.dtype(
    [
        ("line", "i8"),        # index: the 1-based source line number
        ("kind", "u1"),        # code: KIND_*
        ("flags", "u1"),       # bits: FLAG_*
        ("feature", "i2"),     # index into the feature-name list, -1 = none yet
        ("layer", "i4"),       # index of the layer, -1 = before the first layer change
        ("limits", "i4"),      # index: the row of the LIMITS table in force for this move
        ("x0", "f8"), ("y0", "f8"), ("z0", "f8"), ("e0", "f8"),   # mm: start, machine coordinates
        ("x1", "f8"), ("y1", "f8"), ("z1", "f8"), ("e1", "f8"),   # mm: end
        ("move_d", "f8"),      # mm: XYZ length; |dE| for extrude-only; 0 for dwell/wait
        ("feed_v", "f8"),      # mm/s requested (F/60 × M220 factor); inf = as fast as allowed (rapids)
        ("accel", "f8"),       # mm/s² acceleration in force (M204 resolved for this move's kind and dialect)
        ("dwell_t", "f8"),     # s, for KIND_DWELL / KIND_WAIT rows
        ("blend_p", "f8"),     # mm, path tolerance in force (G64 P); 0 = exact path; nan = machine default
        ("exact_stop", "u1"),  # code: 1 when G61.1 (or G61 outside LinuxCNC) is in force: this move ends at rest;
                               # 2 = LinuxCNC's G61 exact path (tangent joins pass, corners stop)
        ("blend_q", "f8"),     # mm, G64 Q naive-CAM tolerance (LinuxCNC; Q = P when only P is given); 0 = off
        ("object", "i2"),      # index into the object-name list (EXCLUDE_OBJECT, M486, slicer labels), -1 = none
    ],
    align=True,
)

# --------------------------------------------------------------------------- limits
# One row per distinct limit state. Row 0 comes from the machine; the parser adds
# a row each time the G-code changes a limit (SET_VELOCITY_LIMIT, M201, M203,
# M205, ...). inf means "no limit".
LIMITS_DTYPE = np.dtype(
    [
        ("max_v", "f8"),        # mm/s toolhead velocity limit (Klipper max_velocity)
        ("max_a", "f8"),        # mm/s² toolhead accel limit (the default accel when M204 has not spoken)
        ("scv", "f8"),          # mm/s square corner velocity (Klipper)
        ("mcr", "f8"),          # ratio 0..1: minimum cruise ratio (Klipper)
        ("junction_dev", "f8"), # mm junction deviation (grbl $11 / Marlin M205 J)
        ("jerk_x", "f8"), ("jerk_y", "f8"), ("jerk_z", "f8"), ("jerk_e", "f8"),   # mm/s classic jerk (M205 XYZE)
        ("axis_v_x", "f8"), ("axis_v_y", "f8"), ("axis_v_z", "f8"), ("axis_v_e", "f8"),  # mm/s per-axis (M203)
        ("axis_a_x", "f8"), ("axis_a_y", "f8"), ("axis_a_z", "f8"), ("axis_a_e", "f8"),  # mm/s² per-axis (M201)
        ("extrude_only_v", "f8"),  # mm/s of filament for extrude-only moves and retractions (Klipper)
        ("extrude_only_a", "f8"),  # mm/s² of filament, same moves
        ("icv", "f8"),          # mm/s extruder instantaneous corner velocity (Klipper)
        ("min_feed_v", "f8"),   # mm/s Marlin M205 S (printing moves), 0 = none
        ("min_travel_v", "f8"), # mm/s Marlin M205 T (travel moves), 0 = none
        ("max_jerk", "f8"),     # mm/s³ path jerk limit for S-curves; inf/0 = trapezoids
        # step-stream settings: the planner ignores them, the stepper reads them per move
        ("pa_k", "f8"),         # s, pressure advance (Klipper pressure_advance, Marlin M900 K, RRF M572 S)
        ("pa_smooth_t", "f8"),  # s, pressure_advance_smooth_time
        ("shaper_type_x", "f8"), ("shaper_type_y", "f8"),    # code: index in stepper.shaping.SHAPER_TYPES
        ("shaper_freq_x", "f8"), ("shaper_freq_y", "f8"),    # Hz, 0 = no shaping on that axis
        ("damping_x", "f8"), ("damping_y", "f8"),            # ratio: the shaper's damping
        # delta slow zones (Klipper's delta.py check_move): a move reaching beyond √delta_slow_xy2 from the
        # centre gets speed / accel ≤ ½·(delta_slow_v, delta_slow_a), beyond √delta_very_slow_xy2 ≤ ¼ of them;
        # delta_slow_v = 0: not a delta (no rule)
        ("delta_slow_xy2", "f8"), ("delta_very_slow_xy2", "f8"),   # mm²
        ("delta_slow_v", "f8"), ("delta_slow_a", "f8"),   # mm/s, mm/s²: Klipper's config max_velocity / max_accel
    ],
    align=True,
)

# --------------------------------------------------------------------------- plan
# PLAN.limit: what bounded the cruise speed of the move
LIMIT_FEED = 0          # the requested feed rate
LIMIT_MAX_V = 1         # toolhead max velocity
LIMIT_AXIS = 2          # a per-axis velocity limit (incl. Z)
LIMIT_EXTRUDER = 3      # extruder limits
LIMIT_ACCEL = 4         # too short to reach the speed under the acceleration limit (incl. junctions)
LIMIT_MCR = 5           # Klipper minimum_cruise_ratio smoothing
LIMIT_JUNCTION = 6      # corner speed at both ends (the move cannot speed up)
LIMIT_NONE = 7          # dwell / wait rows
LIMIT_NAMES = ("feed", "max_velocity", "axis", "extruder", "accel", "cruise_ratio", "junction", "none")

PLAN_DTYPE = np.dtype(
    [
        ("t_start", "f8"),     # s, absolute start time of the move (0 = start of the first move)
        ("start_v", "f8"),     # mm/s at the start
        ("cruise_v", "f8"),    # mm/s peak / cruise
        ("end_v", "f8"),       # mm/s at the end
        ("accel", "f8"),       # mm/s² used while accelerating
        ("decel", "f8"),       # mm/s² used while decelerating
        ("jerk", "f8"),        # mm/s³ (0 = trapezoid)
        ("accel_t", "f8"),     # s
        ("cruise_t", "f8"),    # s
        ("decel_t", "f8"),     # s
        ("duration", "f8"),    # s (incl. dwell_t for dwell/wait rows)
        ("limit", "u1"),       # code: LIMIT_*
    ],
    align=True,
)

# --------------------------------------------------------------------------- segments
# Per-axis polynomial pieces in time: for t in [t0, t0+dt],
#   q(t) = p + v·τ + a·τ²/2 + j·τ³/6 with τ = t − t0, for each of x, y, z, e.
# Straight moves, blends (parabolas) and S-curve phases all fit.
PHASE_ACCEL = 0
PHASE_CRUISE = 1
PHASE_DECEL = 2
PHASE_BLEND = 3
PHASE_DWELL = 4
PHASE_NAMES = ("accel", "cruise", "decel", "blend", "dwell")

SEGMENT_DTYPE = np.dtype(
    [
        ("t0", "f8"), ("dt", "f8"),                                # s: start, duration
        ("px", "f8"), ("py", "f8"), ("pz", "f8"), ("pe", "f8"),    # mm: position at t0
        ("vx", "f8"), ("vy", "f8"), ("vz", "f8"), ("ve", "f8"),    # mm/s: velocity at t0
        ("ax", "f8"), ("ay", "f8"), ("az", "f8"), ("ae", "f8"),    # mm/s²: acceleration at t0
        ("jx", "f8"), ("jy", "f8"), ("jz", "f8"), ("je", "f8"),    # mm/s³: jerk (constant over the piece)
        ("move", "i8"),        # index: the row of the MOVE this piece belongs to (global, 0-based)
        ("phase", "u1"),       # code: PHASE_*
    ],
    align=True,
)


def empty_moves(n: int = 0) -> np.ndarray:
    return np.zeros(n, dtype=MOVE_DTYPE)


def empty_limits(n: int = 0) -> np.ndarray:
    return np.zeros(n, dtype=LIMITS_DTYPE)


#: spare rows the reader leaves in front of each MOVE batch, so that the streaming planner can put the few
#: rows still pending in its window there instead of copying the batch behind them (:func:`prepend_rows`)
HEADROOM_ROWS = 64
#: id(buffer) -> (weak reference to the buffer, its spare rows), until the spare rows are used once
_headroom: dict[int, tuple[weakref.ref, int]] = {}


def rows_with_headroom(n: int, dtype: np.dtype, headroom: int = HEADROOM_ROWS) -> np.ndarray:
    """``np.empty(n, dtype)`` with ``headroom`` spare rows in front of it in the same buffer, usable once by
    :func:`prepend_rows`."""
    buf = np.empty(headroom + n, dtype=dtype)
    key = id(buf)
    _headroom[key] = (weakref.ref(buf, lambda _ref, key=key: _headroom.pop(key, None)), headroom)
    return buf[headroom:]


def prepend_rows(head: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``concat_rows(head, rows)``; when ``rows`` starts exactly where the spare rows of a buffer from
    :func:`rows_with_headroom` end, and they can hold ``head``, ``head`` is written there and the result is a
    view of that buffer (``rows`` itself is not copied). Any other slice of such a buffer is copied (the rows
    in front of it are somebody's data), and each buffer's spare rows serve once, so no window is overwritten."""
    base = rows.base
    if len(head) and base is not None and head.dtype == rows.dtype and rows.flags.c_contiguous:
        entry = _headroom.get(id(base))
        if entry is not None and entry[0]() is base and base.flags.c_contiguous and base.flags.writeable:
            spare = entry[1]
            if rows.ctypes.data - base.ctypes.data == spare * rows.itemsize and len(head) <= spare:
                del _headroom[id(base)]
                window = base[spare - len(head):spare + len(rows)]
                window[:len(head)] = head
                return window
    return concat_rows(head, rows)


def concat_rows(*arrays: np.ndarray) -> np.ndarray:
    """np.concatenate for same-dtype structured arrays, as one byte copy.

    NumPy concatenates structured arrays field by field (about 2 GB/s for MOVE rows); copying the raw
    bytes is ~10× faster, which matters in the streaming planner that appends every chunk to its window.
    """
    dtype = arrays[0].dtype
    if any(a.dtype != dtype for a in arrays):
        return np.concatenate(arrays)
    out = np.empty(sum(len(a) for a in arrays), dtype=dtype)
    raw = out.view(np.uint8)
    pos = 0
    for a in arrays:
        n = a.nbytes
        raw[pos:pos + n] = np.ascontiguousarray(a).view(np.uint8)
        pos += n
    return out
