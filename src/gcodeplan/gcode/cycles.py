"""Drilling canned cycles (G73, G81, G82, G83, G85, G86, G89) expanded into plain moves.

Semantics are LinuxCNC's (G-code manual "Canned Cycles", interpreter interp_cycles.cc), XY plane (G17) only:

* Sticky words: R, Z (as written), Q, P. R and Z must be on the first line of a cycle (any line whose cycle
  code differs from the previous line's); Q on the first G73/G83 line; P on the first G82/G86/G89 line.
  L (repeats, default 1) is not sticky, as in LinuxCNC.
* G90: X, Y, R, Z absolute. G91: X, Y are increments applied once per repeat, R is relative to the initial
  level (the Z when the cycle series started, ``initial_z``; LinuxCNC 2.8+), Z is relative to R.
* Preliminary motion: if the tool is below R, a rapid straight up to R. Then, for each repeat, a rapid in XY
  at the current height (the first repeat) or at the clear height (later repeats), and a rapid down to R if
  above it. LinuxCNC tests the initial level rather than the current Z for the first step; the two differ
  only when R is raised between G99 lines, where going up first is the safe reading of the manual.
* Clear height after each hole: G99 → R; G98 → the initial level if it is above R, else R.
* G73 and G83 peck from R downwards by Q (depths R−Q, R−2Q, … while above the bottom, then the bottom), the
  depth accumulated by repeated subtraction in program units as LinuxCNC does (:func:`_peck_list`).
  G73 backs off ``peck_retract_mm`` after each peck (chip break); G83 rapids out to R and back down to
  ``peck_retract_mm`` above the last depth (LinuxCNC's G83_RAPID_DELTA, 0.010 inch = 0.254 mm).
* G85 feeds out to R then rapids to the clear height; G86 dwells P at the bottom and rapids out (the spindle
  stop is not motion); G89 dwells P and feeds out to the clear height (both as LinuxCNC).

Moves of zero length are left out; a dwell row is written only when P > 0.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

__all__ = ["CycleError", "CycleState", "expand_cycle", "threading_passes", "CYCLE_CODES", "MOTION_RAPID",
           "MOTION_FEED", "MOTION_DWELL", "MAX_CYCLE_ROWS", "THREAD_RAPID", "THREAD_CUT_FROM_INDEX", "THREAD_CUT"]

CYCLE_CODES = (73, 81, 82, 83, 85, 86, 89)
PECK_CODES = (73, 83)
DWELL_CODES = (82, 86, 89)

# Column "motion" of the rows expand_cycle returns.
MOTION_RAPID = 0
MOTION_FEED = 1
MOTION_DWELL = 2

# A cycle needing more rows than this is a typo (Q of a micron over a metre, L of a million), not a part.
MAX_CYCLE_ROWS = 1_000_000     # a real hole: a few thousand rows (1 mm pecks over 1 m); fuzzing found slower typos

# Two depths closer than this are one: stops r − k·Q landing a rounding error above the bottom from making
# a sliver of a peck.
DEPTH_EPS_MM = 1e-9


class CycleError(ValueError):
    """A canned-cycle line that cannot be executed. No file:line in the message: the parser adds it."""


@dataclass
class CycleState:
    """Where the tool is and what the cycle words are, carried from one cycle line to the next.

    Create it with :meth:`enter` when a cycle series starts (the first G73/G8x line after another motion mode
    or G80); after each line pass the returned state back, with ``retract_mode``/``incremental`` updated if
    the line changed them. NaN in r/q/p/z_word means "not given yet".
    """

    x: float                    # mm, current position (absolute, work frame)
    y: float
    z: float
    initial_z: float            # mm, Z when the cycle series started (the G98 level)
    retract_mode: int           # 98 or 99
    incremental: bool           # G91 in force
    r: float                    # sticky R word as written (mm; relative to initial_z under G91)
    q: float                    # sticky Q word (mm, peck depth)
    p: float                    # sticky P word (s, dwell)
    l: int                      # L of the last line (not sticky: a line without L does one hole)
    z_word: float = math.nan    # sticky Z word as written (mm; relative to R under G91)
    code: int = 0               # cycle code of the last line (0 = none yet): a change requires R and Z again

    @classmethod
    def enter(cls, x: float, y: float, z: float, retract_mode: int = 98, incremental: bool = False
              ) -> "CycleState":
        """State at the start of a cycle series, the tool at (x, y, z)."""
        nan = math.nan
        return cls(x=float(x), y=float(y), z=float(z), initial_z=float(z), retract_mode=retract_mode,
                   incremental=incremental, r=nan, q=nan, p=nan, l=1)


def _word(words: dict, key: str) -> float | None:
    """The line's value for a word (upper or lower case), None when absent; non-finite is an error."""
    value = words.get(key, words.get(key.lower()))
    if value is None:
        return None
    value = float(value)
    if not math.isfinite(value):
        raise CycleError(f"canned cycle word {key} is not a finite number ({value})")
    return value


def _sticky(line_value: float | None, state_value: float, key: str, code: int, first: bool,
            required: bool) -> float:
    if line_value is not None:
        return line_value
    if (first and required) or (required and math.isnan(state_value)):
        raise CycleError(f"G{code} needs {key} on the first line of the cycle")
    return state_value


def _peck_list(r_abs: float, bottom: float, q: float, unit: float) -> list[float]:
    """The peck depths (mm) as LinuxCNC's convert_cycle_g83/g73 make them: ``for (d = r − q; d > bottom;
    d = d − q)`` in program units (``unit`` mm each), the depth accumulated by repeated subtraction. A hole
    whose depth is an exact multiple of Q usually ends with one more peck a rounding error above the
    bottom (the accumulated depth lands just above it), then the feed to the bottom."""
    rp, bp, qp = r_abs / unit, bottom / unit, q / unit
    out = []
    d = rp - qp
    while d > bp and len(out) <= MAX_CYCLE_ROWS:
        out.append(d * unit)
        d = d - qp
    return out


def _peck_depths(r_abs: float, bottom: float, q: float) -> int:
    """Number of intermediate peck depths r − k·q (k ≥ 1) strictly above the bottom (+ DEPTH_EPS_MM)."""
    span = r_abs - bottom
    if span <= DEPTH_EPS_MM:
        return 0
    count = span / q
    if not count <= MAX_CYCLE_ROWS:     # the caller refuses it (too many moves): no settling at that size, where
        # k·q can sit below the resolution of r and the loops below would not move (tools/fuzz.py: R1e16 Q0.001)
        if not math.isfinite(count):
            raise CycleError(f"peck depth Q {q:g} mm is too small for a {span:g} mm hole: check Q")
        return int(count)
    k = math.ceil(count) - 1
    # Settle rounding at the boundary: r − k·q must stay above the bottom, r − (k+1)·q must not. The closed
    # form is off by a step at most; a few steps bound the loops where r's resolution hides q.
    for _ in range(4):
        if not (k > 0 and r_abs - k * q <= bottom + DEPTH_EPS_MM):
            break
        k -= 1
    for _ in range(4):
        if not (r_abs - (k + 1) * q > bottom + DEPTH_EPS_MM):
            break
        k += 1
    return k


def _check_cycle_modes(code: int, state: CycleState, peck_retract_mm: float, plane: int) -> None:
    """The modes a canned cycle needs before its words are read: a supported code, the XY plane (G17), a
    retract mode (G98 / G99) and a finite peck retract (mm >= 0); CycleError otherwise."""
    if code not in CYCLE_CODES:
        raise CycleError(f"G{code} is not a supported canned cycle (G73, G81, G82, G83, G85, G86, G89)")
    if plane != 17:
        raise CycleError(f"canned cycles only in G17 (XY plane); G{plane} is in force")
    if state.retract_mode not in (98, 99):
        raise CycleError(f"canned cycle retract mode must be G98 or G99, got {state.retract_mode}")
    if not (math.isfinite(peck_retract_mm) and peck_retract_mm >= 0.0):
        raise CycleError(f"peck retract must be a finite distance >= 0 mm, got {peck_retract_mm}")


def expand_cycle(code: int, words: dict[str, float], state: CycleState, peck_retract_mm: float = 0.254,
                 *, plane: int = 17, unit: float = 1.0) -> tuple[np.ndarray, CycleState]:
    """Moves of one canned-cycle line, and the state after it.

    ``code`` ∈ {73, 81, 82, 83, 85, 86, 89}; ``words`` the line's X Y Z R Q P L values (absent keys absent;
    mm and seconds, already converted from inches). Returns rows (N, 5) float64 ``[x, y, z, motion, dwell_s]``
    in order: motion 0 = rapid, 1 = feed, 2 = dwell (xyz unchanged, dwell_s seconds). Raises
    :class:`CycleError`. ``unit``: mm per program unit (25.4 under G20), for LinuxCNC's peck arithmetic.
    """
    _check_cycle_modes(code, state, peck_retract_mm, plane)
    first = state.code != code
    x_word, y_word = _word(words, "X"), _word(words, "Y")
    r_word = _sticky(_word(words, "R"), state.r, "R", code, first, True)
    z_word = _sticky(_word(words, "Z"), state.z_word, "Z", code, first, True)
    q_word = _sticky(_word(words, "Q"), state.q, "Q", code, first, code in PECK_CODES)
    p_word = _sticky(_word(words, "P"), state.p, "P", code, first, code in DWELL_CODES)
    l_word = _word(words, "L")
    repeats = 1 if l_word is None else l_word
    if repeats != int(repeats) or repeats < 1:
        raise CycleError(f"canned cycle repeat count L must be a whole number >= 1, got {l_word:g}")
    repeats = int(repeats)
    if code in PECK_CODES and not q_word > 0.0:
        raise CycleError(f"G{code} peck depth Q must be > 0 mm, got {q_word:g}")
    if code in DWELL_CODES and not p_word >= 0.0:
        raise CycleError(f"G{code} dwell P must be >= 0 s, got {p_word:g}")

    if state.incremental:
        r_abs = state.initial_z + r_word
        bottom = r_abs + z_word
        step_x = 0.0 if x_word is None else x_word
        step_y = 0.0 if y_word is None else y_word
        hole_x, hole_y = state.x, state.y
    else:
        r_abs = r_word
        bottom = z_word
        step_x = step_y = 0.0
        hole_x = state.x if x_word is None else x_word
        hole_y = state.y if y_word is None else y_word
    if r_abs < bottom:
        raise CycleError(f"G{code}: the R plane ({r_abs:.4f} mm) is below the hole bottom Z ({bottom:.4f} mm)")
    clear_z = r_abs if state.retract_mode == 99 else max(state.initial_z, r_abs)

    peck_list: list[float] = []
    pecks = 0
    if code in PECK_CODES:
        pecks = _peck_depths(r_abs, bottom, q_word)        # closed form first: refuses absurd counts cheaply
        if (6 + 3 * pecks) * repeats + 1 <= MAX_CYCLE_ROWS:
            peck_list = _peck_list(r_abs, bottom, q_word, unit)
            pecks = len(peck_list)
    rows_per_hole = 6 + (3 if code == 83 else 2) * pecks
    if rows_per_hole * repeats + 1 > MAX_CYCLE_ROWS:
        raise CycleError(f"G{code} would make {rows_per_hole * repeats + 1:.4g} moves "
                         f"(limit {MAX_CYCLE_ROWS}): check Q and L")

    rows = np.empty((rows_per_hole * repeats + 1, 5), dtype=np.float64)
    count = 0
    x, y, z = state.x, state.y, state.z

    def add(nx: float, ny: float, nz: float, motion: int, dwell_s: float = 0.0) -> None:
        nonlocal count, x, y, z
        if motion != MOTION_DWELL and nx == x and ny == y and nz == z:
            return
        rows[count] = (nx, ny, nz, motion, dwell_s)
        count += 1
        x, y, z = nx, ny, nz

    if z < r_abs:
        add(x, y, r_abs, MOTION_RAPID)
    for _ in range(repeats):
        hole_x += step_x
        hole_y += step_y
        add(hole_x, hole_y, z, MOTION_RAPID)   # z is the current height, then the clear height
        if z > r_abs:
            add(hole_x, hole_y, r_abs, MOTION_RAPID)
        if code in PECK_CODES:
            for depth in peck_list:
                add(x, y, depth, MOTION_FEED)
                if code == 83:
                    add(x, y, r_abs, MOTION_RAPID)
                # LinuxCNC: back to G83_RAPID_DELTA above this depth, not clamped to R
                add(x, y, depth + peck_retract_mm, MOTION_RAPID)
        add(x, y, bottom, MOTION_FEED)
        if code in DWELL_CODES and p_word > 0.0:
            add(x, y, z, MOTION_DWELL, p_word)
        if code == 85:
            add(x, y, r_abs, MOTION_FEED)
            add(x, y, clear_z, MOTION_RAPID)
        elif code == 89:
            add(x, y, clear_z, MOTION_FEED)
        else:
            add(x, y, clear_z, MOTION_RAPID)

    new_state = replace(state, x=x, y=y, z=z, r=r_word, q=q_word, p=p_word, l=repeats, z_word=z_word,
                        code=code)
    return rows[:count].copy(), new_state


# --------------------------------------------------------------------------- G76 threading
# kinds of the moves threading_passes returns
THREAD_RAPID = 0
THREAD_CUT = 1                 # spindle-synchronised, following the previous cut
THREAD_CUT_FROM_INDEX = 2      # spindle-synchronised, the first after a rapid: waits for the spindle index


def threading_passes(start_x: float, start_y: float, start_z: float, end_z: float, words: dict,
                     unit: float) -> list[tuple[float, float, float, int, float]]:
    """The moves of LinuxCNC's G76 threading cycle (interp_convert.cc convert_threading_cycle and its
    threading_pass; G-code manual "G76 Threading Cycle"), XZ plane, radius mode.

    ``start_*`` and ``end_z`` are program coordinates in mm (the drive line is X = ``start_x``);
    ``words`` holds the line's P Z I J K [R Q H E L] in program units (``unit`` mm each; Q in degrees).
    Returns (x, y, z, kind, pitch ratio) per move: kind :data:`THREAD_RAPID`, :data:`THREAD_CUT_FROM_INDEX`
    or :data:`THREAD_CUT`; a cut runs at (pitch ratio × P) per spindle revolution along its path (the
    taper moves' pitch makes Z advance by P per revolution).
    """
    pitch = words["P"]
    i_num, j_num, k_num = words["I"] * unit, words["J"] * unit, words["K"] * unit
    if pitch < 0 or words.get("H", 0.0) < 0:
        raise CycleError("P and H must not be negative")
    if not pitch > 0:
        raise CycleError("P (thread pitch) must be > 0")
    if i_num == 0.0:
        raise CycleError("In G76, I must not be 0")
    if j_num <= 0.0:
        raise CycleError("In G76, J must be greater than 0")
    if k_num <= j_num:
        raise CycleError("In G76, K must be greater than J")
    boring = i_num > 0.0
    safe_x = start_x
    full_dia_depth = abs(i_num)
    start_depth = abs(i_num) + abs(j_num)
    cut_increment = abs(j_num)
    full_threadheight = abs(k_num)
    end_depth = abs(k_num) + abs(i_num)
    angle = math.radians(words.get("Q", 0.0))
    if end_z > start_z:
        angle = -angle
    spring_cuts = int(words.get("H", 0.0))
    degression = words.get("R", 1.0)
    if degression < 1.0:
        degression = 1.0
    taper_dist = max(words.get("E", 0.0) * unit, 0.0)
    if taper_dist > abs(end_z - start_z) / 2.0:
        raise CycleError("E (taper length) is greater than half the drive line length")
    taper_ratio = math.hypot(taper_dist, full_threadheight) / taper_dist if taper_dist > 0.0 else 1.0
    if end_z > start_z:
        taper_dist = -taper_dist
    flags = max(int(words.get("L", 0.0)), 0)
    entry_taper, exit_taper = bool(flags & 1), bool(flags & 2)
    target_z = end_z + abs(k_num) * math.tan(angle)
    y = start_y
    out: list[tuple[float, float, float, int, float]] = []

    def at(depth: float) -> float:
        """X of the tool tip ``depth`` beyond the drive line (into the work)."""
        return safe_x + depth if boring else safe_x - depth

    clear = end_depth          # the back and out moves stand clear by the full depth: at(depth - clear)

    def one_pass(depth: float, zoff: float) -> None:
        out.append((at(depth - clear), y, start_z - zoff, THREAD_RAPID, 1.0))                # back
        if taper_dist and entry_taper:
            out.append((at(depth - full_threadheight), y, start_z - zoff, THREAD_CUT_FROM_INDEX,
                        taper_ratio))                                                          # in
            out.append((at(depth), y, start_z - zoff - taper_dist, THREAD_CUT, taper_ratio))  # angled in
            first = THREAD_CUT
        else:
            out.append((at(depth), y, start_z - zoff, THREAD_RAPID, 1.0))                     # in
            first = THREAD_CUT_FROM_INDEX
        if taper_dist and exit_taper:
            out.append((at(depth), y, target_z - zoff + taper_dist, first, 1.0))              # over
            out.append((at(depth - full_threadheight), y, target_z - zoff, THREAD_CUT, taper_ratio))  # angled out
        else:
            out.append((at(depth), y, target_z - zoff, first, 1.0))                           # over
        out.append((at(depth - clear), y, target_z - zoff, THREAD_RAPID, 1.0))               # out
        if len(out) > MAX_CYCLE_ROWS:
            raise CycleError("more than a million moves (J far smaller than K, or R very large)")

    depth = start_depth
    n_pass = 1
    zoff = (depth - full_dia_depth) * math.tan(angle)
    while depth < end_depth:
        one_pass(depth, zoff)
        n_pass += 1
        depth = full_dia_depth + cut_increment * n_pass ** (1.0 / degression)
        zoff = (depth - full_dia_depth) * math.tan(angle)
    depth = end_depth
    zoff = (depth - full_dia_depth) * math.tan(angle)
    for _ in range(spring_cuts + 1):
        one_pass(depth, zoff)
    out.append((start_x, start_y, end_z, THREAD_RAPID, 1.0))
    return out
