"""Numba kernels of the parser: the byte scanner (fast path) and the batch summariser.

The scanner walks the raw bytes of a chunk and fully handles the lines that make
up nearly all of a slicer's output (G0/G1 with X Y Z E F, G90/G91, M82/M83,
``G92 E``, M204, G4, fan/heater commands without motion, comments, ``;TYPE:``
names already seen; on the CNC dialects no M line: RS274NGC runs every word of it, see :mod:`.rs274`).
Any other line (arcs, offsets, Klipper extended commands,
unknown commands, anything odd or malformed) is handed back to the Python
interpreter (:mod:`.interp`) *before* the scanner changes any state, so the
interpreter is the single authority on rare lines and on every error message.

Both sides share the modal state through two small arrays (``st`` float64 and
``ist`` int64, indices below) and must compute a move with the very same floating
point operations in the same order: the test suite checks that a run with every
line sent through Python gives arrays identical to the kernel's.
"""
from __future__ import annotations

import math

import numpy as np

from .._jit import njit

from ..schema import KIND_DWELL, KIND_EXTRUDE_ONLY, KIND_PRINT, KIND_TRAVEL, FLAG_ARC, FLAG_RAPID, FLAG_RETRACT

# ------------------------------------------------------------------ float state (st)
S_X, S_Y, S_Z, S_E = 0, 1, 2, 3     # mm, machine position; S_E is the running machine E (G92 never resets it)
S_OX, S_OY, S_OZ = 4, 5, 6          # mm, program -> machine offset (work + G92 + tool length), per axis
S_ELOG = 7                          # mm, logical E: what the G-code's absolute E values are measured against
S_FEED = 8                          # mm/s, modal F (before the M220 factor)
S_SPEED_F = 9                       # M220 factor (1 = 100 %)
S_FLOW_F = 10                       # M221 factor, scales E
S_UNIT = 11                         # mm per program unit (1, or 25.4 under G20)
S_ACC_P, S_ACC_T, S_ACC_R = 12, 13, 14   # mm/s² print / travel / retract accel (all equal outside marlin/reprap)
S_BLEND_P = 15                      # mm, G64 P in force (nan = machine default, 0 = exact path)
S_MAXZ = 16                         # mm, highest Z of a printing move (layer detection by Z)
S_BLEND_Q = 17                      # mm, G64 Q naive-CAM tolerance in force (0 = none)
S_MAX_E = 18                        # mm, highest machine E a move reached since the exclude_object transform
                                    # last went dormant (gcode/objects.py: Klipper's max_position_extruded)
S_SOFT_LO = 19                      # mm, x y z at 19..21: Marlin's software endstops (min), see I_SOFT_CLAMP
S_SOFT_HI = 22                      # mm, x y z at 22..24: the same, max
S_GRBL_S = 25                       # rpm (laser power), grbl's spindle speed in force (gc_state.spindle_speed)
N_ST = 26

# ------------------------------------------------------------------ int state (ist)
I_LINE = 0          # number of the last line fully processed (1-based lines)
I_ABS_COORD = 1     # G90 (1) / G91 (0)
I_ABS_E = 2         # M82 (1) / M83 (0); E is relative when either flag is 0 (Klipper's rule), see I_G90_SETS_E
I_MOTION = 3        # modal motion: 0, 1, 2, 3 (G0..G3), 80 = none, 73/81..89 = canned cycle
I_DIALECT = 4       # DIALECT_*
I_LIMITS = 5        # LIMITS row in force
I_LAYER = 6         # layer index (-1 before the first)
I_FEATURE = 7       # feature index (-1 before the first)
I_EXACT_STOP = 8    # G61 (1) / G64 (0)
I_LAYER_BY_Z = 9    # 1 while no layer comment has been seen: a printing move above S_MAXZ starts a layer
I_LAYER_Z_TODO = 10  # 1 while the current layer's Z is unknown (the first printing move sets it)
I_NFEAT = 11        # rows in use in the ;TYPE: name table
I_M204_IGNORED = 12  # klipper dialect: M204 lines without S and without both P and T
I_STOPPED = 13      # 1 after a program end (M2/M30 on CNC flavors): nothing more is interpreted
I_G90_SETS_E = 14   # 1 on Marlin 2: G90/G91 also set the E mode (the last of G90/G91/M82/M83 rules E),
                    # 0 elsewhere (Klipper's rule: E is relative while G91 or M83 is in force)
I_OBJECT = 15       # object index (EXCLUDE_OBJECT_START, M486 S, slicer labels), -1 outside any object
I_TO_PYTHON = 16    # 1: every line goes to the Python interpreter (inside or just after an excluded object,
                    # a pending start wait): the scanner returns at once
I_F32_REL = 17      # 1 on a Marlin-model machine: a relative X/Y/Z/E target is current + value in float32, as
                    # Marlin's get_destination_from_command sums (its positions are floats)
I_GRBL_INERT = 18   # 1 on grbl (not --strict): the scanner rejects a grbl line of one M code grbl does not have
                    # and I J K L P R words (a printer's "M204 P1000") as gcode/rs274.py's fast path does,
                    # noting (line, M code) in the reader's note buffer (see scan_chunk)
I_SOFT_CLAMP = 19   # 1 on a Marlin machine with software endstops on (M211 S1): a G0/G1/G2/G3 target outside
                    # [S_SOFT_LO, S_SOFT_HI] is clamped to it (Marlin's apply_motion_limits); the scanner hands
                    # such a line to Python (commands_motion.py), which clamps and counts it
I_AXIS_LINES = 20   # 1 where a line led by an X Y Z E F word repeats the modal G0/G1 (grbl's implicit motion
                    # mode, RS274NGC; the reprap flavor as before); 0 on Marlin (no GCODE_MOTION_MODES, its default) and
                    # Klipper, which answer "Unknown command": the scanner hands such a line to the interpreter
I_GRBL_S_FREE = 21  # 1 on grbl where an S word on a G0/G1 line with axis words changes nothing but S_GRBL_S:
                    # laser mode under M4, and either mode with the spindle off (M5): gcode.c syncs no motion
                    # there (commands_state._grbl_syncs; _grbl_route sets it; laser M3 lines all go to Python)
I_S_WORDS = 22      # S words the scanner took that way (the parse summary's spindle commands)
N_IST = 23

DIALECT_KLIPPER = 0   # M204: S, else min(P, T) when both; one accel for every move
DIALECT_MARLIN = 1    # marlin / reprap: M204 S/P/T/R, accel chosen by the move's kind
DIALECT_CNC = 2       # grbl / linuxcnc: machine accel, G0 rapid, G4 P in seconds

# scanner results
ST_DONE = 0      # the chunk is consumed
ST_PYTHON = 1    # the line starting at pos needs the Python interpreter
ST_FULL = 2      # the output array is full; the line at pos is not processed yet

#: G92 E lines the scanner notes per call (line, logical E mm) for the reader to hand on (GcodeReader._scan):
#: firmware models re-round Marlin's E there (planner/marlin.py); a fuller buffer sends the line to Python
ESET_MAX = 256

# M codes grbl 1.1 runs (gcode/rs274.py GRBL_M) or that carry free text or object labels (lexing.FREE_TEXT_M,
# M486): never rejected by the scanner (tests/test_grbl_inert_lines.py checks the table against those sets)
GRBL_NOT_INERT_M = np.zeros(1000, np.bool_)
GRBL_NOT_INERT_M[[0, 1, 2, 3, 4, 5, 8, 9, 30, 23, 28, 32, 117, 118, 550, 929, 486]] = True
#: grbl's line buffer (protocol.c): a line of more bytes may overflow it (error:11), the interpreter decides
GRBL_LINE_MAX = 79

# the words an inert grbl line may carry after its M code (grbl_inert_words), each a bit of its "seen" mask
GRBL_INERT_WORD_BIT = np.zeros(256, np.int64)
for _bit, _letter in enumerate("ijklpr"):
    GRBL_INERT_WORD_BIT[ord(_letter)] = 1 << _bit
del _bit, _letter

FEAT_MAX = 64        # ;TYPE: name table rows
FEAT_NAME_MAX = 48   # bytes per name; longer names always go through Python

# ------------------------------------------------------------------ byte codes
# Module-level ints: numba compiles them in as constants, so naming them costs nothing in the kernels.
BYTE_TAB, BYTE_LF, BYTE_CR, BYTE_SPACE = ord("\t"), ord("\n"), ord("\r"), ord(" ")
BYTE_PLUS, BYTE_MINUS, BYTE_DOT, BYTE_SEMICOLON = ord("+"), ord("-"), ord("."), ord(";")
BYTE_0, BYTE_9 = ord("0"), ord("9")
BYTE_A, BYTE_Z, BYTE_LOWER_A, BYTE_LOWER_Z = ord("A"), ord("Z"), ord("a"), ord("z")
CASE_OFFSET = BYTE_LOWER_A - BYTE_A          # ASCII: a lower-case letter = its capital + 32
BYTE_L, BYTE_M, BYTE_T = ord("L"), ord("M"), ord("T")   # first letters of the comment markers (with BYTE_Z, ' ')
# word letters, compared after _lower (a G-code word's letter is case-blind)
LETTER_G, LETTER_M = ord("g"), ord("m")
LETTER_X, LETTER_Y, LETTER_Z, LETTER_E, LETTER_F = ord("x"), ord("y"), ord("z"), ord("e"), ord("f")
LETTER_S, LETTER_P, LETTER_T, LETTER_R = ord("s"), ord("p"), ord("t"), ord("r")

# the words scan_chunk reads, as bits of its ``has`` mask (each word at most once per line)
WORD_X, WORD_Y, WORD_Z, WORD_E, WORD_F = 1, 2, 4, 8, 16
WORD_S, WORD_P, WORD_T, WORD_R = 32, 64, 128, 256

# 10**k for k = 0..22 are exact doubles: mantissa (< 2**53) times or divided by one of them is
# correctly rounded, i.e. the same double as Python's float() (Clinger's fast path).
POW10 = np.array([10.0 ** k for k in range(23)])


@njit(cache=True, inline="always")
def _is_sep(c):
    # what may follow a number: blank, end of line, comment, or the next word's letter
    return (c == BYTE_SPACE or c == BYTE_TAB or c == BYTE_CR or c == BYTE_LF or c == BYTE_SEMICOLON
            or (BYTE_A <= c <= BYTE_Z) or (BYTE_LOWER_A <= c <= BYTE_LOWER_Z))


@njit(cache=True, error_model="numpy", inline="always")
def parse_decimal(buf, p, end):
    """Parse ``[+-]digits[.digits]`` at ``buf[p:]``.

    Returns ``(ok, value, p_after)``. ``ok`` is False when the text is not a number of this
    simple form, is not followed by a separator, or has more than 15 digits: the caller then lets
    Python decide (``float()`` or an error). When ok, value is mantissa / 10**decimals with the
    mantissa < 10**15 < 2**53 and 10**decimals exact, so one rounding: the same double as
    ``float(text)`` (Clinger's fast path).
    """
    while p < end and (buf[p] == BYTE_SPACE or buf[p] == BYTE_TAB):
        p += 1
    neg = False
    if p < end and (buf[p] == BYTE_MINUS or buf[p] == BYTE_PLUS):
        neg = buf[p] == BYTE_MINUS
        p += 1
    mant = 0
    ndig = 0
    frac = 0
    while p < end and BYTE_0 <= buf[p] <= BYTE_9:
        mant = mant * 10 + (buf[p] - BYTE_0)
        ndig += 1
        p += 1
    if p < end and buf[p] == BYTE_DOT:
        p += 1
        while p < end and BYTE_0 <= buf[p] <= BYTE_9:
            mant = mant * 10 + (buf[p] - BYTE_0)
            ndig += 1
            frac += 1
            p += 1
    # 15 digits keep the mantissa below 2**53 (and int64 cannot overflow); longer numbers go to Python
    if ndig == 0 or ndig > 15:
        return False, 0.0, p
    if p < end and not _is_sep(buf[p]):
        return False, 0.0, p
    v = float(mant)
    if frac > 0:
        v = v / POW10[frac]
    if neg:
        v = -v
    return True, v, p


@njit(cache=True, inline="always")
def _lower(c):
    if BYTE_A <= c <= BYTE_Z:
        return c + CASE_OFFSET
    return c


@njit(cache=True, inline="always")
def _skip_blank(buf, p, end):
    while p < end and (buf[p] == BYTE_SPACE or buf[p] == BYTE_TAB or buf[p] == BYTE_CR):
        p += 1
    return p


@njit(cache=True, inline="always")
def _to_eol(buf, p, end):
    while p < end and buf[p] != BYTE_LF:
        p += 1
    return p


@njit(cache=True, inline="always")
def _starts(buf, p, end, pat):
    n = len(pat)
    if p + n > end:
        return False
    for k in range(n):
        if buf[p + k] != pat[k]:
            return False
    return True


def _pat(s: str) -> tuple:
    # a tuple of byte values: numba keeps it as a compile-time constant (no array object per use)
    return tuple(s.encode())


# comment prefixes (after the ';') that carry information: handled by Python
PAT_LAYER = _pat("LAYER")            # ;LAYER_CHANGE, ;LAYER:n, ;LAYER_COUNT:n
PAT_Z = _pat("Z:")
PAT_TIME = _pat("TIME:")
PAT_TYPE = _pat("TYPE:")
PAT_S3D_LAYER = _pat(" layer")
PAT_S3D_FEATURE = _pat(" feature")
PAT_ESTIMATED = _pat(" estimated printing time")
PAT_OBJECT = _pat(" printing object")          # PrusaSlicer's object labels
PAT_OBJECT_STOP = _pat(" stop printing object")
PAT_MESH = _pat("MESH:")                        # Cura's ;MESH:name / ;MESH:NONMESH


@njit(cache=True, inline="always")
def _comment_needs_python(buf, p, eol, ist, feat_raw, feat_len, feat_idx):
    """p is just after the ';' of a whole-line comment. True when Python must read it;
    a ``;TYPE:`` line whose name is already in the table is applied here."""
    if p >= eol:
        return False
    c = buf[p]
    if c != BYTE_T and c != BYTE_L and c != BYTE_Z and c != BYTE_SPACE and c != BYTE_M:   # the markers' first bytes
        return False
    if _starts(buf, p, eol, PAT_TYPE):
        a = p + 5
        b = eol
        while b > a and (buf[b - 1] == BYTE_CR or buf[b - 1] == BYTE_SPACE or buf[b - 1] == BYTE_TAB):
            b -= 1
        n = b - a
        if n > FEAT_NAME_MAX:
            return True
        for r in range(ist[I_NFEAT]):
            if feat_len[r] != n:
                continue
            same = True
            for k in range(n):
                if feat_raw[r, k] != buf[a + k]:
                    same = False
                    break
            if same:
                ist[I_FEATURE] = feat_idx[r]
                return False
        return True
    if (_starts(buf, p, eol, PAT_LAYER) or _starts(buf, p, eol, PAT_Z) or _starts(buf, p, eol, PAT_TIME)
            or _starts(buf, p, eol, PAT_S3D_LAYER) or _starts(buf, p, eol, PAT_S3D_FEATURE)
            or _starts(buf, p, eol, PAT_ESTIMATED) or _starts(buf, p, eol, PAT_OBJECT)
            or _starts(buf, p, eol, PAT_OBJECT_STOP) or _starts(buf, p, eol, PAT_MESH)):
        return True
    return False


@njit(cache=True, inline="always")
def write_row(out, n, line, kind, flags, ist, st, x0, y0, z0, e0, x1, y1, z1, e1, move_d, feed_v, accel,
               dwell_t):
    r = out[n]
    r.line = line
    r.kind = kind
    r.flags = flags
    r.feature = ist[I_FEATURE]
    r.layer = ist[I_LAYER]
    r.limits = ist[I_LIMITS]
    r.x0 = x0
    r.y0 = y0
    r.z0 = z0
    r.e0 = e0
    r.x1 = x1
    r.y1 = y1
    r.z1 = z1
    r.e1 = e1
    r.move_d = move_d
    r.feed_v = feed_v
    r.accel = accel
    r.dwell_t = dwell_t
    r.blend_p = st[S_BLEND_P]
    r.exact_stop = ist[I_EXACT_STOP]
    r.object = ist[I_OBJECT]
    r.blend_q = st[S_BLEND_Q]


@njit(cache=True, inline="always")
def move_accel(dialect, has_xyz, de, acc_p, acc_t, acc_r):
    """Acceleration of a move: Marlin's choice (planner.cpp: E-only -> retract accel, XYZ with
    E -> print accel, XYZ alone -> travel accel); the other dialects keep the three equal."""
    if not has_xyz:
        return acc_r
    if de != 0.0:
        return acc_p
    return acc_t


@njit(cache=True)
def piece_rows_kernel(ends, starts, es, e_starts, d, line, flags, feed_v, rapid, dwell, rapid_inf, st, ist, out):
    """MOVE rows of straight pieces (arc chords, canned-cycle moves) into the zeroed rows ``out``, skipping
    pieces that move nothing; returns how many were written.

    A piece with XYZ motion prints when E grows, else travels; without XYZ motion it is extrude-only; E going
    back sets FLAG_RETRACT. ``rapid`` / ``dwell``: per-piece masks (empty: none): a rapid piece gets
    FLAG_RAPID and, when ``rapid_inf`` (CNC dialects), an unlimited feed; a dwell piece is a KIND_DWELL row
    (its time is set by the caller). Acceleration, feature, layer, object and the rest come from the
    interpreter's state ``st`` / ``ist`` as for a G1. Here, beside :func:`write_row`, because numba's cache
    checks only the source file of the kernel it loads: an inlined helper must live in the same file.
    """
    k = 0
    has_rapid = rapid.shape[0] > 0
    has_dwell = dwell.shape[0] > 0
    for i in range(ends.shape[0]):
        de = es[i] - e_starts[i]
        xyz = d[i] > 0.0
        is_dwell = has_dwell and dwell[i]
        if not (xyz or de != 0.0 or is_dwell):
            continue
        if xyz:
            kind = KIND_PRINT if de > 0.0 else KIND_TRAVEL
            move_d = d[i]
        else:
            kind = KIND_EXTRUDE_ONLY
            move_d = abs(de)
        accel = move_accel(0, xyz, de, st[S_ACC_P], st[S_ACC_T], st[S_ACC_R])
        f = flags | (FLAG_RETRACT if de < 0.0 else 0)
        v = feed_v
        if has_rapid and rapid[i]:
            f |= FLAG_RAPID
            if rapid_inf:
                v = math.inf
        if is_dwell:
            kind = KIND_DWELL
            move_d = 0.0
            accel = 0.0
            v = 0.0
        write_row(out, k, line, kind, f, ist, st, starts[i, 0], starts[i, 1], starts[i, 2], e_starts[i],
                    ends[i, 0], ends[i, 1], ends[i, 2], es[i], move_d, v, accel, 0.0)
        k += 1
    return k


@njit(cache=True)
def relative_sum(current, value, f32):
    """A relative target: ``current + value`` (mm), in float32 when ``f32`` (Marlin's float positions:
    destination = current_position + value), else in double."""
    if f32:
        return np.float64(np.float32(np.float32(current) + np.float32(value)))
    return current + value


# ------------------------------------------------------------------ the scanner, in named parts
# Every part below is inline="always": numba pastes it into scan_chunk before compiling, so the kernel runs as
# one function (measured: the same parts as separate calls make the scanner ~45 % slower). Each part that may
# refuse a line returns ``ok`` (False: the line goes to Python) and changes no state before it is sure.

@njit(cache=True, inline="always")
def skip_comment_line(buf, p, end, ist, feat_raw, feat_len, feat_idx):
    """A whole-line comment, ``p`` at its ';'. Returns ``(ok, eol)``: ok False when Python must read it
    (a marker comment: layer, Z, time, a new ``;TYPE:`` name, object labels); eol is the index of its line
    feed (or ``end``)."""
    eol = _to_eol(buf, p, end)
    c1 = buf[p + 1] if p + 1 < eol else 0
    # every marker starts with 'T', 'L', 'Z', ' ' or 'M' (tested here: a call costs more than the test)
    if (c1 == BYTE_T or c1 == BYTE_L or c1 == BYTE_Z or c1 == BYTE_SPACE or c1 == BYTE_M) and \
            _comment_needs_python(buf, p + 1, eol, ist, feat_raw, feat_len, feat_idx):
        return False, eol
    return True, eol


@njit(cache=True, inline="always")
def command_word(buf, p, end, motion):
    """The command of a line, ``p`` at its first non-blank byte. Returns ``(letter, code, p_after)``:
    ``G``/``M`` with 1 to 3 digits, or a line starting with an X Y Z E F word, which repeats the modal
    ``motion`` when it is G0/G1. letter 0: anything else (Python's job)."""
    lc = _lower(buf[p])
    if lc == LETTER_G or lc == LETTER_M:
        p += 1
        code = 0
        nd = 0
        while p < end and BYTE_0 <= buf[p] <= BYTE_9 and nd < 4:
            code = code * 10 + (buf[p] - BYTE_0)
            nd += 1
            p += 1
        if nd == 0 or nd >= 4 or p >= end or not _is_sep(buf[p]):
            return 0, -1, p
        return lc, code, p
    if lc == LETTER_X or lc == LETTER_Y or lc == LETTER_Z or lc == LETTER_E or lc == LETTER_F:  # no G/M word
        if motion != 0 and motion != 1:
            return 0, -1, p
        return LETTER_G, motion, p
    return 0, -1, p


@njit(cache=True, inline="always")
def word_bit(w):
    """The ``has`` bit (WORD_*) of a lower-case word letter the scanner reads; 0 for any other letter."""
    if w == LETTER_X:
        return WORD_X
    if w == LETTER_Y:
        return WORD_Y
    if w == LETTER_Z:
        return WORD_Z
    if w == LETTER_E:
        return WORD_E
    if w == LETTER_F:
        return WORD_F
    if w == LETTER_S:
        return WORD_S
    if w == LETTER_P:
        return WORD_P
    if w == LETTER_T:
        return WORD_T
    if w == LETTER_R:
        return WORD_R
    return 0


@njit(cache=True, error_model="numpy", inline="always")
def scan_words(buf, q, end):
    """The words after the command, up to the end of the line (a ';' comment ends it): only X Y Z E F S P
    T R, each at most once, with numbers :func:`parse_decimal` takes. Returns ``(ok, has, vx, vy, vz, ve,
    vf, vs, vp, vt, vr, eol)``: ``has`` the WORD_* bits present, the values in program units (0 when
    absent), eol the index of the line feed (or ``end``). ok False: another word, a repeated word or a
    number left to Python. A second G or M word on the line is "another word": such a line is always the
    interpreter's (each flavor's reading of it, e.g. Marlin's and Klipper's first command only: interp.py
    _printer_one_command)."""
    has = 0
    vx = vy = vz = ve = vf = vs = vp = vt = vr = 0.0
    while True:
        q = _skip_blank(buf, q, end)
        if q >= end:
            break
        b = buf[q]
        if b == BYTE_LF:
            break
        if b == BYTE_SEMICOLON:
            q = _to_eol(buf, q, end)
            break
        bit = word_bit(_lower(b))
        if bit == 0 or (has & bit):
            return False, has, vx, vy, vz, ve, vf, vs, vp, vt, vr, q
        ok, v, q = parse_decimal(buf, q + 1, end)
        if not ok:
            return False, has, vx, vy, vz, ve, vf, vs, vp, vt, vr, q
        has |= bit
        if bit == WORD_X:
            vx = v
        elif bit == WORD_Y:
            vy = v
        elif bit == WORD_Z:
            vz = v
        elif bit == WORD_E:
            ve = v
        elif bit == WORD_F:
            vf = v
        elif bit == WORD_S:
            vs = v
        elif bit == WORD_P:
            vp = v
        elif bit == WORD_T:
            vt = v
        else:
            vr = v
    return True, has, vx, vy, vz, ve, vf, vs, vp, vt, vr, q


@njit(cache=True, error_model="numpy", inline="always")
def linear_target(st, ist, has, vx, vy, vz, ve, vf):
    """End of a G0/G1 from its words and the modal state (nothing changed). Returns ``(x1, y1, z1, e1,
    elog, feed)``: machine position mm, machine E mm (M221 flow applied), the new logical E mm and the
    modal feed mm/s. Absolute: value × unit + offset; relative: :func:`relative_sum`; E is absolute only
    under M82 with G90 (or on Marlin 2, where the last of G90/G91/M82/M83 rules E)."""
    scale = st[S_UNIT]
    x1 = st[S_X]
    y1 = st[S_Y]
    z1 = st[S_Z]
    e1 = st[S_E]
    absc = ist[I_ABS_COORD] != 0
    f32 = ist[I_F32_REL] != 0
    if has & WORD_X:
        x1 = vx * scale + st[S_OX] if absc else relative_sum(x1, vx * scale, f32)
    if has & WORD_Y:
        y1 = vy * scale + st[S_OY] if absc else relative_sum(y1, vy * scale, f32)
    if has & WORD_Z:
        z1 = vz * scale + st[S_OZ] if absc else relative_sum(z1, vz * scale, f32)
    elog = st[S_ELOG]
    if has & WORD_E:
        ev = ve * scale
        if ist[I_ABS_E] != 0 and (absc or ist[I_G90_SETS_E] != 0):
            de_log = ev - elog
            elog = ev
        else:
            new_elog = relative_sum(elog, ev, f32)
            de_log = new_elog - elog if f32 else ev
            elog = new_elog
        e1 = e1 + de_log * st[S_FLOW_F]
    feed = st[S_FEED]
    if has & WORD_F:
        feed = vf * scale / 60.0
    return x1, y1, z1, e1, elog, feed


@njit(cache=True, error_model="numpy", inline="always")
def emit_move(out, n_out, line, code, dialect, st, ist, x0, y0, z0, e0, x1, y1, z1, e1, move_d, feed):
    """Write the MOVE row of a committed G0/G1 that moves something (``move_d`` mm, > 0, or E changes):
    print / travel / extrude-only, FLAG_RETRACT when E goes back, FLAG_RAPID on G0 (unlimited feed on the
    CNC dialects), the dialect's accel; the feed mm/s gets the M220 factor. Also raises S_MAX_E."""
    de = e1 - e0
    flags = 0
    if move_d > 0.0:
        kind = KIND_PRINT if de > 0.0 else KIND_TRAVEL
    else:
        kind = KIND_EXTRUDE_ONLY
        move_d = abs(de)
    if de < 0.0:
        flags |= FLAG_RETRACT
    if e1 > st[S_MAX_E]:
        st[S_MAX_E] = e1
    feed_v = feed * st[S_SPEED_F]
    if code == 0:
        flags |= FLAG_RAPID
        if dialect == DIALECT_CNC:
            feed_v = np.inf
    accel = move_accel(dialect, kind != KIND_EXTRUDE_ONLY, de, st[S_ACC_P], st[S_ACC_T], st[S_ACC_R])
    write_row(out, n_out, line, kind, flags, ist, st, x0, y0, z0, e0, x1, y1, z1, e1, move_d, feed_v, accel, 0.0)


@njit(cache=True, error_model="numpy", inline="always")
def linear_move(out, n_out, line, code, dialect, st, ist, has, vx, vy, vz, ve, vf):
    """G0/G1 (``code``) with X Y Z E F words: commits the move to ``st``/``ist`` and writes its row when it
    moves something. Returns ``(ok, n_out)``; ok False (nothing changed): another word, F <= 0, a printing
    move that starts a layer by Z or must set the layer's Z, or a non-finite target."""
    if has & (WORD_S | WORD_P | WORD_T | WORD_R):
        return False, n_out
    if (has & WORD_F) and not vf > 0.0:
        return False, n_out
    x0 = st[S_X]
    y0 = st[S_Y]
    z0 = st[S_Z]
    e0 = st[S_E]
    x1, y1, z1, e1, elog, feed = linear_target(st, ist, has, vx, vy, vz, ve, vf)
    if code == 1 and not feed > 0.0:
        return False, n_out      # grbl before its first F (feed 0): its error:22, gcode/rs274.py
    dx = x1 - x0
    dy = y1 - y0
    dz = z1 - z0
    de = e1 - e0
    move_d = np.sqrt(dx * dx + dy * dy + dz * dz)
    if move_d > 0.0 and de > 0.0:
        # a printing move that starts a layer (by Z) or must set the layer's Z: Python's job
        if ist[I_LAYER_Z_TODO] != 0 or (ist[I_LAYER_BY_Z] != 0 and z1 > st[S_MAXZ]):
            return False, n_out
    if not (np.isfinite(x1) and np.isfinite(y1) and np.isfinite(z1) and np.isfinite(e1)
            and np.isfinite(move_d)):
        return False, n_out
    if ist[I_SOFT_CLAMP] != 0 and not (st[S_SOFT_LO] <= x1 <= st[S_SOFT_HI]
                                       and st[S_SOFT_LO + 1] <= y1 <= st[S_SOFT_HI + 1]
                                       and st[S_SOFT_LO + 2] <= z1 <= st[S_SOFT_HI + 2]):
        return False, n_out     # beyond Marlin's software endstops: clamped by the interpreter
    # commit
    st[S_X] = x1
    st[S_Y] = y1
    st[S_Z] = z1
    st[S_E] = e1
    st[S_ELOG] = elog
    st[S_FEED] = feed
    ist[I_MOTION] = code
    if move_d > 0.0 or de != 0.0:
        emit_move(out, n_out, line, code, dialect, st, ist, x0, y0, z0, e0, x1, y1, z1, e1, move_d, feed)
        n_out += 1
    return True, n_out


@njit(cache=True, inline="always")
def grbl_free_s(ist, has, vs):
    """True when the S word of a G0/G1 line with these words only sets grbl's spindle speed (I_GRBL_S_FREE: laser
    mode with M4, or the spindle off): the line moves (an axis word), has no word grbl would refuse with S here
    (E, P, T, R) and S is not negative (error:4, the interpreter's)."""
    return (ist[I_GRBL_S_FREE] != 0 and (has & (WORD_X | WORD_Y | WORD_Z)) != 0
            and (has & (WORD_E | WORD_P | WORD_T | WORD_R)) == 0 and vs >= 0.0)


@njit(cache=True, inline="always")
def set_logical_e(line, dialect, st, has, ve, eset_line, eset_v, eset_n):
    """``G92 E`` alone on a printer (a slicer's "G92 E0" every layer or so): sets the logical E (mm) and
    notes (line, E) for the firmware models (planner/marlin.py), as the interpreter's _g92 notes it.
    Returns ok; False for any other G92 (positions and offsets: the interpreter's job), on the CNC dialects,
    or when the note buffer is full."""
    if dialect == DIALECT_CNC or has != WORD_E or eset_n[0] >= eset_line.shape[0]:
        return False
    st[S_ELOG] = ve * st[S_UNIT]
    k = eset_n[0]
    eset_line[k] = line
    eset_v[k] = st[S_ELOG]
    eset_n[0] = k + 1
    return True


@njit(cache=True, error_model="numpy", inline="always")
def dwell(out, n_out, line, dialect, st, ist, has, vs, vp):
    """G4 on a printer: a KIND_DWELL row of ``dwell_t`` s: P in ms; S in s (refused on Klipper, which has no
    G4 S). Returns ``(ok, n_out)``; ok False: another word, a negative or NaN time, or a CNC dialect (the
    interpreter runs G4 there: on grbl a sync, after which a ``$`` setting applies, gcode/grbl_line.py)."""
    if dialect == DIALECT_CNC or has & ~(WORD_S | WORD_P):
        return False, n_out
    dwell_t = 0.0
    if has & WORD_P:
        dwell_t = vp / 1000.0
    if has & WORD_S:
        if dialect == DIALECT_KLIPPER:
            return False, n_out
        dwell_t = vs
    if not dwell_t >= 0.0:
        return False, n_out
    write_row(out, n_out, line, KIND_DWELL, 0, ist, st, st[S_X], st[S_Y], st[S_Z], st[S_E],
              st[S_X], st[S_Y], st[S_Z], st[S_E], 0.0, 0.0, 0.0, dwell_t)
    return True, n_out + 1


@njit(cache=True, inline="always")
def set_accel(dialect, st, ist, has, vs, vp, vt, vr):
    """M204 on a printer: sets the print / travel / retract accels (mm/s²). Klipper: S, else min(P, T) only
    when both are given, else the line is counted as ignored ("Invalid M204"); Marlin: S sets print and
    travel, then P print, R retract, T travel. Returns ok; False: another word or a value <= 0."""
    if dialect == DIALECT_CNC or (has & ~(WORD_S | WORD_P | WORD_T | WORD_R)):
        return False
    if dialect == DIALECT_KLIPPER:
        a = vs
        if not (has & WORD_S):
            a = min(vp, vt)
        if not (has & WORD_S) and not ((has & WORD_P) and (has & WORD_T)):
            ist[I_M204_IGNORED] += 1
        else:
            if not a > 0.0:
                return False
            st[S_ACC_P] = a
            st[S_ACC_T] = a
            st[S_ACC_R] = a
        return True
    if ((has & WORD_S) and not vs > 0.0) or ((has & WORD_P) and not vp > 0.0) or \
            ((has & WORD_T) and not vt > 0.0) or ((has & WORD_R) and not vr > 0.0):
        return False
    if has & WORD_S:
        st[S_ACC_P] = vs
        st[S_ACC_T] = vs
    if has & WORD_P:
        st[S_ACC_P] = vp
    if has & WORD_R:
        st[S_ACC_R] = vr
    if has & WORD_T:
        st[S_ACC_T] = vt
    return True


@njit(cache=True, inline="always")
def modal_g(code, out, n_out, line, dialect, st, ist, has, ve, vs, vp, eset_line, eset_v, eset_n):
    """The G commands other than G0/G1 the scanner runs: G90/G91 (alone; on Marlin 2 they also set the E
    mode), ``G92 E`` (:func:`set_logical_e`), G4 (:func:`dwell`). Returns ``(ok, n_out)``."""
    if code == 90 or code == 91:
        if has != 0:
            return False, n_out
        ist[I_ABS_COORD] = 1 if code == 90 else 0
        if ist[I_G90_SETS_E] != 0:
            ist[I_ABS_E] = ist[I_ABS_COORD]
        return True, n_out
    if code == 92:
        return set_logical_e(line, dialect, st, has, ve, eset_line, eset_v, eset_n), n_out
    if code == 4:
        return dwell(out, n_out, line, dialect, st, ist, has, vs, vp)
    return False, n_out


@njit(cache=True, inline="always")
def printer_m(code, dialect, st, ist, has, vs, vp, vt, vr):
    """The M commands the scanner runs on printers: M82/M83 (alone), M104/M105/M106/M107/M140 (no motion:
    nothing to do), M204 (:func:`set_accel`). Returns ok; always False on the CNC dialects, whose lines
    run every word in RS274NGC's order (gcode/rs274.py)."""
    if dialect == DIALECT_CNC:
        return False
    if code == 82 or code == 83:
        if has != 0:
            return False
        ist[I_ABS_E] = 1 if code == 82 else 0
        return True
    if code == 104 or code == 105 or code == 106 or code == 107 or code == 140:
        # heaters / fan / temperature report: an F here is the command's own parameter on printers
        return True
    if code == 204:
        return set_accel(dialect, st, ist, has, vs, vp, vt, vr)
    return False


@njit(cache=True, inline="always")
def grbl_inert_words(buf, p, end):
    """The rest of a grbl line after its M code (``p`` just past the code's digits): blank-separated I J K L P
    R words, each at most once, a letter directly followed by ``[+-]`` and 1-9 digits with an optional
    fraction of 0-9 digits (or ``.`` and 1-9 digits), then blanks, an optional CR and the line's end; no
    comment. A subset of gcode/rs274.py's _INERT_LINE, so the scanner rejects no line the Python path would
    not. Returns ``(ok, eol)``, eol the index of the line feed (or ``end``)."""
    seen = 0
    while True:
        q = p
        while p < end and (buf[p] == BYTE_SPACE or buf[p] == BYTE_TAB):
            p += 1
        if p >= end or buf[p] == BYTE_LF:
            return True, p
        if buf[p] == BYTE_CR:
            if p + 1 >= end or buf[p + 1] == BYTE_LF:
                return True, p + 1
            return False, p
        if p == q:
            return False, p               # a word must follow blanks
        bit = GRBL_INERT_WORD_BIT[_lower(buf[p])]
        if bit == 0 or (seen & bit):
            return False, p
        seen |= bit
        p += 1
        if p < end and (buf[p] == BYTE_PLUS or buf[p] == BYTE_MINUS):
            p += 1
        n_int = 0
        while p < end and BYTE_0 <= buf[p] <= BYTE_9:
            n_int += 1
            p += 1
        n_frac = -1
        if p < end and buf[p] == BYTE_DOT:
            p += 1
            n_frac = 0
            while p < end and BYTE_0 <= buf[p] <= BYTE_9:
                n_frac += 1
                p += 1
        if n_int > 9 or n_frac > 9 or (n_int == 0 and n_frac < 1):
            return False, p
        if p < end and not (buf[p] == BYTE_SPACE or buf[p] == BYTE_TAB or buf[p] == BYTE_CR
                            or buf[p] == BYTE_LF):
            return False, p


# _nrt=False: the scanner allocates nothing, and without numba's reference counting the inlined helpers
# that take arrays cost no atomic incref/decref per word (measured: 66 -> 52 ns per "G1 X Y E" line,
# 24 -> 2 ns per comment line). error_model="numpy": no zero-division checks in the hot loop.
@njit(cache=True, error_model="numpy", _nrt=False)
def scan_chunk(buf, pos, end, st, ist, out, n_out, feat_raw, feat_len, feat_idx, eset_line, eset_v, eset_n):
    """Interpret lines of ``buf[pos:end]`` until the chunk ends, the output is full, or a line
    needs Python. Returns ``(status, pos, n_out)``; for ST_PYTHON/ST_FULL ``pos`` is the start
    of the line not processed (its number is ``ist[I_LINE] + 1``). Each ``G92 E`` line it interprets
    is appended to ``eset_line`` / ``eset_v`` (its line, the logical E set in mm; ``eset_n[0]``: how many,
    at most :data:`ESET_MAX`); on grbl (no G92 E there) they note instead each line it rejects as grbl does
    (its line, its M code; see :data:`I_GRBL_INERT`)."""
    cap = out.shape[0]
    dialect = ist[I_DIALECT]
    while pos < end:
        if n_out >= cap:
            return ST_FULL, pos, n_out
        if ist[I_TO_PYTHON] != 0:
            return ST_PYTHON, pos, n_out
        line_start = pos
        line = ist[I_LINE] + 1
        p = _skip_blank(buf, pos, end)
        if p >= end:
            ist[I_LINE] = line
            return ST_DONE, end, n_out
        c = buf[p]
        if c == BYTE_LF:
            ist[I_LINE] = line
            pos = p + 1
            continue
        if c == BYTE_SEMICOLON:
            ok, eol = skip_comment_line(buf, p, end, ist, feat_raw, feat_len, feat_idx)
            if not ok:
                return ST_PYTHON, line_start, n_out
            ist[I_LINE] = line
            pos = eol + 1
            continue
        # motion -1 (no modal repeat): a line led by an axis word goes to the interpreter (I_AXIS_LINES)
        letter, code, p = command_word(buf, p, end, ist[I_MOTION] if ist[I_AXIS_LINES] != 0 else -1)
        if letter == 0:
            return ST_PYTHON, line_start, n_out
        if letter == LETTER_M and ist[I_GRBL_INERT] != 0 and not GRBL_NOT_INERT_M[code]:
            # grbl rejects the line whole (error:20): noted for the reader, which warns as rs274.py does
            ok, eol = grbl_inert_words(buf, p, end)
            if not ok or eset_n[0] >= eset_line.shape[0] or eol - line_start > GRBL_LINE_MAX:
                return ST_PYTHON, line_start, n_out
            k = eset_n[0]
            eset_line[k] = line
            eset_v[k] = code
            eset_n[0] = k + 1
            ist[I_LINE] = line
            pos = eol + 1 if eol < end else end
            continue
        ok, has, vx, vy, vz, ve, vf, vs, vp, vt, vr, eol = scan_words(buf, p, end)
        if not ok or (dialect == DIALECT_CNC and eol - line_start > GRBL_LINE_MAX):
            return ST_PYTHON, line_start, n_out
        if letter == LETTER_G and (code == 0 or code == 1):
            s_free = (has & WORD_S) != 0 and grbl_free_s(ist, has, vs)
            ok, n_out = linear_move(out, n_out, line, code, dialect, st, ist, has & ~WORD_S if s_free else has,
                                    vx, vy, vz, ve, vf)
            if ok and s_free:
                st[S_GRBL_S] = vs
                ist[I_S_WORDS] += 1
        elif letter == LETTER_G:
            ok, n_out = modal_g(code, out, n_out, line, dialect, st, ist, has, ve, vs, vp, eset_line, eset_v,
                                eset_n)
        else:
            ok = printer_m(code, dialect, st, ist, has, vs, vp, vt, vr)
        if not ok:
            return ST_PYTHON, line_start, n_out
        ist[I_LINE] = line
        pos = eol + 1 if eol < end else end
    return ST_DONE, pos, n_out


# ------------------------------------------------------------------ summary of a batch
# acc (float64) indices
A_ROWS_TRAVEL, A_ROWS_PRINT, A_ROWS_EXTRUDE, A_ROWS_DWELL, A_ROWS_WAIT = 0, 1, 2, 3, 4
A_TRAVEL_MM, A_PRINT_MM, A_FILAMENT_MM, A_NAIVE_T, A_DWELL_T, A_WAIT_T = 5, 6, 7, 8, 9, 10
A_RETRACTS, A_RAPIDS, A_ARC_CHORDS = 11, 12, 13
A_MIN_X, A_MIN_Y, A_MIN_Z, A_MAX_X, A_MAX_Y, A_MAX_Z = 14, 15, 16, 17, 18, 19
N_ACC = 20


@njit(cache=True)
def summarise_rows(moves, acc, rapid_v):
    """Add a batch of MOVE rows to the running totals in ``acc``.

    naive time = Σ move_d / feed_v (rapids with feed_v = inf at ``rapid_v``) + Σ G4 dwell_t.
    """
    for i in range(moves.shape[0]):
        r = moves[i]
        k = r.kind
        acc[k] += 1.0
        acc[A_FILAMENT_MM] += r.e1 - r.e0
        if k == KIND_TRAVEL or k == KIND_PRINT or k == KIND_EXTRUDE_ONLY:
            if k == KIND_TRAVEL:
                acc[A_TRAVEL_MM] += r.move_d
            elif k == KIND_PRINT:
                acc[A_PRINT_MM] += r.move_d
            f = r.feed_v
            if f == np.inf:
                f = rapid_v
            if f > 0.0:
                acc[A_NAIVE_T] += r.move_d / f
            if r.flags & FLAG_RETRACT:
                acc[A_RETRACTS] += 1.0
            if r.flags & FLAG_RAPID:
                acc[A_RAPIDS] += 1.0
            if r.flags & FLAG_ARC:
                acc[A_ARC_CHORDS] += 1.0
            if k != KIND_EXTRUDE_ONLY:
                acc[A_MIN_X] = min(acc[A_MIN_X], r.x1)
                acc[A_MIN_Y] = min(acc[A_MIN_Y], r.y1)
                acc[A_MIN_Z] = min(acc[A_MIN_Z], r.z1)
                acc[A_MAX_X] = max(acc[A_MAX_X], r.x1)
                acc[A_MAX_Y] = max(acc[A_MAX_Y], r.y1)
                acc[A_MAX_Z] = max(acc[A_MAX_Z], r.z1)
        elif k == KIND_DWELL:
            acc[A_DWELL_T] += r.dwell_t
            acc[A_NAIVE_T] += r.dwell_t
        else:
            acc[A_WAIT_T] += r.dwell_t


@njit(cache=True)
def count_lines(buf, start, end):
    """Lines in buf[start:end] (a last line without a newline counts)."""
    n = 0
    for i in range(start, end):
        if buf[i] == BYTE_LF:
            n += 1
    if end > start and buf[end - 1] != BYTE_LF:
        n += 1
    return n


def warm_up() -> None:
    """Load (or compile) the kernels every file needs (count_lines, rarely needed, loads on first use)."""
    from ..schema import MOVE_DTYPE

    buf = np.frombuffer(b"G1 X1\n", dtype=np.uint8)
    st = np.zeros(N_ST)
    st[S_UNIT] = st[S_SPEED_F] = st[S_FLOW_F] = 1.0
    ist = np.zeros(N_IST, dtype=np.int64)
    out = np.zeros(2, dtype=MOVE_DTYPE)
    scan_chunk(buf, 0, buf.shape[0], st, ist, out, 0, np.zeros((FEAT_MAX, FEAT_NAME_MAX), np.uint8),
               np.zeros(FEAT_MAX, np.int64), np.zeros(FEAT_MAX, np.int64), np.zeros(ESET_MAX, np.int64),
               np.zeros(ESET_MAX), np.zeros(1, np.int64))
    summarise_rows(out, np.zeros(N_ACC), 1.0)

