"""One line of a CNC program (``linuxcnc`` and ``grbl`` dialects) as RS274NGC executes it (a part of
:class:`.interp.Interpreter`).

Every word of a line takes effect, in LinuxCNC's documented order of execution (grbl follows the same
order): comments/messages, feed mode, F, S, T, M6, M3–M5, M7–M9, overrides, other M codes, dwell, plane,
units, cutter compensation, tool length offset, coordinate system, path mode, distance mode, retract mode,
G28/G30/G10/G92, motion, stop. Axis words on a line with a non-motion G or M code move in the modal motion
mode unless a G10/G28/G30/G43.1/G92 on the line uses them; nothing is dropped. Two codes of one modal group
on a line stop a LinuxCNC program ("Two G codes used from same modal group"), as its other block errors do.

grbl checks a whole line before it executes any of it (gcode.c gc_execute_line, steps 2 and 3) and answers
the first error with ``error:N``; a sender shows it and sends the next line. So on grbl a line that fails
one of those checks is rejected whole — a code or word grbl does not have (20), a fraction (23), a modal
group twice (21), two commands wanting the axis words (24), a repeated word (25), a negative F N P S T (4),
T above 255 (38), a missing P or L (28), G10 P above 6 (29), no axis words (26), G53 outside G0/G1 (30),
axis words under G80 (31), a feed move with no feed rate (22: before the first F, or after F0), an arc without its plane's words (32, 35), an R too
short (34) or an end off the circle (33), a probe to where it is (33), G43.1 with other than Z (37), a
value word no command of the line reads (36) — by :meth:`Rs274Commands._grbl_block_error`, run before
anything of the line, word by word in the line's order as gcode.c reads them (:func:`grbl_word_error`): no
mode, offset, feed, spindle or position changes, one warning names the line and grbl's error (an error under
``--strict``), and the program goes on. Before that the line is read as grbl reads it (gcode/grbl_line.py):
its 79-byte line buffer (error:11), its word lexer (error:1, error:2), its line numbers (error:27), its ``$``
lines (jogs, settings).

LinuxCNC specifics kept: F is read before G20/G21 on the same line, so ``G20 F10`` keeps the old units
for its feed (interp_convert.cc convert_feed_rate runs before convert_length_units; grbl converts F
with the line's units). M3/M4/M5, M7/M8/M9, M6 and G43/G43.1/G43.2/G49 wait for LinuxCNC's motion queue
to empty (full stops). M6 moves to ``[EMCIO]TOOL_CHANGE_POSITION`` at rapid speed when the .ini has one.

One parameter table per program (:class:`.ngc.NgcParams`, ``self.params``), in the machine's ("user")
units as LinuxCNC stores them, started from the .var file: G28/G30 rapid to the intermediate point (the
axis words, in the current coordinate system), then to #5161-5163 / #5181-5183 (machine coordinates) for
the named axes (all axes when none is named) — convert_home; G28.1/G30.1 write the machine position there
(convert_savehome); G92 writes #5210-5213, G92.1/G92.2/G92.3 clear or restore from them
(convert_axis_offsets); G10 L2/L20 write #5221 + 20·(P − 1) … and a coordinate system's origin is read
from the table when G54..G59.3 selects it (convert_setup, convert_coordinate_system); the start-up takes
#5220 and #5210 from the .var as LinuxCNC's init does. The tool table ([EMCIO]TOOL_TABLE, Z lengths)
serves G43 H (H0 or none: the tool in the spindle), G43.2 H adds a tool's length, G43.1 / G43.2 take Z;
G10 L1 / L10 / L11 write the table (L10: the length that makes the current Z read the word with the current
offsets, L11: in G59.3 without G92 — convert_setup_tool), the offset in force changes at the next G43.

Motion LinuxCNC has that depends on the machine's sensors is timed as it runs when nothing stops it early:
G38.2-G38.5 (probe) run in full to their target at the feed rate from rest to rest, with one named warning
per file; G33 runs at K·S/60 (S: the last S word) from rest (the spindle index) to rest, G33.1 in and out
(at K·S·I/60), G76 as LinuxCNC's threading passes (gcode/cycles.py ``threading_passes``). G41/G42 are
warned about and planned uncompensated.
"""
from __future__ import annotations

import math
import re

import numpy as np

from ..schema import FLAG_RAPID, KIND_TRAVEL
from . import scan as S
from .lexing import FREE_TEXT_M, MAX_WARNINGS, QUIET_G, Word

CYCLE_G = (73, 81, 82, 83, 85, 86, 89)
MOTION_G = {0.0, 1.0, 2.0, 3.0, 33.0, 33.1, 38.2, 38.3, 38.4, 38.5, 73.0, 76.0, 80.0, 81.0, 82.0, 83.0, 84.0, 85.0,
            86.0, 87.0, 88.0, 89.0}
# modal groups of G codes (LinuxCNC's G-code reference, "Modal Groups"); group 0 (non-modal) below
G_GROUPS = {
    "motion": MOTION_G,
    "plane": {17.0, 18.0, 19.0, 17.1, 18.1, 19.1},
    "distance": {90.0, 91.0},
    "arc distance": {90.1, 91.1},
    "feed rate mode": {93.0, 94.0, 95.0},
    "units": {20.0, 21.0},
    "cutter compensation": {40.0, 41.0, 42.0, 41.1, 42.1},
    "tool length offset": {43.0, 43.1, 43.2, 49.0},
    "canned cycle return": {98.0, 99.0},
    "coordinate system": {54.0, 55.0, 56.0, 57.0, 58.0, 59.0, 59.1, 59.2, 59.3},
    "path control": {61.0, 61.1, 64.0},
    "spindle speed mode": {96.0, 97.0},
    "non-modal": {4.0, 10.0, 28.0, 28.1, 30.0, 30.1, 92.0, 92.1, 92.2, 92.3},
}
M_GROUPS = {
    "stopping": {0, 1, 2, 30, 60},
    "tool change": {6, 61},
    "spindle": {3, 4, 5},
    "coolant": {7, 8, 9},
    "override": {48, 49, 50, 51, 52, 53},
}
# group-0 codes that take the line's axis words (no motion with them)
AXIS_USERS = {10.0, 28.0, 30.0, 92.0}
KNOWN_G = set().union(*G_GROUPS.values()) | {53.0}
# grbl 1.1's G and M codes (grbl's gcode.c); anything else is its error:20
GRBL_G = {0.0, 1.0, 2.0, 3.0, 4.0, 10.0, 17.0, 18.0, 19.0, 20.0, 21.0, 28.0, 28.1, 30.0, 30.1, 38.2, 38.3, 38.4,
          38.5, 40.0, 43.1, 49.0, 53.0, 54.0, 55.0, 56.0, 57.0, 58.0, 59.0, 61.0, 80.0, 90.0, 91.0, 91.1, 92.0,
          92.1, 93.0, 94.0}
# (M7 needs ENABLE_M7, M56 ENABLE_PARKING_OVERRIDE_CONTROL: both off in grbl's default config.h, so gcode.c
# answers them error:20 like any M code it lacks)
GRBL_M = {0, 1, 2, 3, 4, 5, 8, 9, 30}
# the value words grbl 1.1 reads (gcode.c); any other letter is its error:20. E is kept for the grbl model,
# which refuses an E move by name (planner/grbl.py)
GRBL_WORDS = frozenset("EFIJKLNPRSTXYZ")
# grbl 1.1's status texts of the errors a block can fail with (report.h, the grbl wiki's error table)
GRBL_ERRORS = {1: "expected command letter", 2: "bad number format", 3: "invalid statement", 4: "negative value",
               8: "not idle",
               11: "line overflow", 16: "invalid jog command", 20: "unsupported command",
               21: "modal group violation", 22: "undefined feed rate", 23: "command value not integer",
               24: "axis command conflict", 25: "word repeated", 26: "no axis words", 27: "invalid line number",
               28: "value word missing",
               29: "unsupported coordinate system", 30: "G53 invalid motion mode", 31: "axis words exist",
               32: "no axis words in plane", 33: "invalid target", 34: "arc radius error",
               35: "no offsets in plane", 36: "unused words", 37: "G43 dynamic axis error",
               38: "max value exceeded"}
GRBL_MAX_TOOL = 255          # gcode.c MAX_TOOL_NUMBER (T is a uint8)
GRBL_LINE_BUFFER_SIZE = 80   # protocol.h LINE_BUFFER_SIZE: the bytes of grbl's line buffer, its NUL included
GRBL_MAX_LINE_NUMBER = 10000000    # gcode.c MAX_LINE_NUMBER: a larger N is error:27 (invalid line number)
GRBL_N_COORD = 6             # G54..G59 (nuts_bolts.h N_COORDINATE_SYSTEM)
GRBL_MOTION_G = {0.0, 1.0, 2.0, 3.0, 38.2, 38.3, 38.4, 38.5, 80.0}
# grbl's M modal groups (gcode.h): stopping, spindle, coolant (M7 and M8 one group), override
GRBL_M_GROUP = {0: 4, 1: 4, 2: 4, 30: 4, 3: 7, 4: 7, 5: 7, 7: 8, 8: 8, 9: 8, 56: 9}
# modal motion codes with a fraction are kept in I_MOTION as ten times the code (G38.2 -> 382, G33.1 -> 331)
MOTION_CODE = {38.2: 382, 38.3: 383, 38.4: 384, 38.5: 385, 33.1: 331}
PROBE_MOTION = (382, 383, 384, 385)
MOTION_G33, MOTION_G33_1, MOTION_G76 = 33, 331, 76
SPECIAL_MOTION = PROBE_MOTION + (MOTION_G33, MOTION_G33_1, MOTION_G76)
# codes modelled as having no effect on the motion
NO_EFFECT_G = {40.0, 94.0, 97.0, 17.1, 18.1, 19.1}
# a grbl line of one M code and words only G or M codes read (a slicer's "M204 P1000"):
# see Rs274Commands.grbl_inert_line
_INERT_LINE = re.compile(rb"[ \t]*[Mm]0*([0-9]{1,4})((?:[ \t]+[DHIJKLPQRdhijklpqr][-+]?"
                         rb"(?:[0-9]{1,9}(?:\.[0-9]{0,9})?|\.[0-9]{1,9}))*)[ \t]*\r?")
_INERT_MEMO_MAX = 256        # distinct inert lines remembered (a program has a handful: M204 P800, P1000 ...)


def _gname(g: float) -> str:
    return f"G{g:g}"


def _grbl_g_word(g: float) -> tuple[int, int, str | None]:
    """gcode.c step 2 for one G word: (grbl's modal group, error number or 0, the axis command it makes or
    None). ``g`` has one decimal (the interpreter rounds G words so)."""
    iv = int(g)
    frac = round((g - iv) * 10)
    if g < 0:
        return -1, 20, None
    if iv in (10, 28, 30, 92, 4, 53):
        axis_use = "non-modal" if iv in (10, 28, 30, 92) and frac == 0 else None
        if iv in (28, 30, 92):
            return 0, (0 if frac in (0, 1) else 20), axis_use
        return 0, (23 if frac else 0), axis_use
    if iv in (0, 1, 2, 3, 38):
        if iv == 38:
            return 1, (0 if frac in (2, 3, 4, 5) else 20), "motion"
        return 1, (23 if frac else 0), "motion"
    if iv == 80:
        return 1, (23 if frac else 0), None
    if iv in (90, 91):
        if frac == 0:
            return 3, 0, None
        return 4, (20 if frac != 1 or iv == 90 else 0), None
    if iv in (43, 49):
        ok = (iv == 49 and frac == 0) or (iv == 43 and frac == 1)
        status = 23 if iv == 49 and frac else (0 if ok else 20)
        return 8, status, "tlo"
    if iv == 61:
        return 13, (20 if frac else 0), None
    group = {17: 2, 18: 2, 19: 2, 93: 5, 94: 5, 20: 6, 21: 6, 40: 7, 54: 12, 55: 12, 56: 12, 57: 12, 58: 12,
             59: 12}.get(iv)
    if group is None:
        return -1, 20, None
    return group, (23 if frac else 0), None


def _grbl_reject_warning(bad: list[str]) -> str:
    """The warning of a line grbl rejects with error:20 (``bad``: the codes and words it does not have)."""
    return f"{' '.join(bad)}: grbl rejects it (error:20, unsupported command); the line is skipped"


def _grbl_axis_command(words: list[Word]) -> str | None:
    """gcode.c's axis command of a line: the first G code that takes the axis words ("motion", "non-modal",
    "tlo"), else "motion" when the line has axis words (implicit motion mode), else None."""
    for w in words:
        if w.letter == "G" and w.value is not None:
            use = _grbl_g_word(round(w.value, 1))[2]
            if use is not None:
                return use
    return "motion" if any(w.letter in "XYZE" for w in words) else None


def grbl_word_error(words: list[Word]):
    """gcode.c step 2 on the words of a line in their order: ``((error number, what, codes to count as
    unknown), axis command)`` of the first word grbl refuses (an unsupported code or letter 20, a fraction 23,
    a modal group twice 21, two axis commands 24, T above 255 38, a repeated word 25, a negative F N P S T 4),
    or ``(None, axis command)``. error:20 names everything on the line grbl lacks. E is no grbl word: on a
    line that moves (E alone moves too, as the scanner reads it) the grbl model refuses the E move by name (a
    printer's file is not for this machine); with a G code that takes the axis words (G92 E0, G10, G28) it
    is error:20 like any other letter."""
    moving = _grbl_axis_command(words) == "motion"
    axis_cmd = None              # "non-modal" (G10/28/30/92), "motion", "tlo" (G43.1/49)
    groups: set[int] = set()
    mgroups: dict[int, int] = {}
    seen: set[str] = set()
    first = None
    for w in words:
        k = w.letter
        if k == "G" and w.value is not None:
            g = round(w.value, 1)
            group, status, axis_use = _grbl_g_word(g)
            if status == 0 and axis_use is not None:
                if axis_cmd is not None:
                    status = 24
                axis_cmd = axis_use
            if status == 0 and group in groups:
                status = 21
            groups.add(group)
            first = (status, _gname(g)) if status else None
        elif k == "M" and w.value is not None:
            mc = int(w.value)
            group = GRBL_M_GROUP.get(mc) if mc in GRBL_M else None
            if w.value != mc:
                first = (23, f"M{w.text}")
            elif group is None:
                first = (20, f"M{mc}")
            elif group in mgroups:
                first = (21, f"M{mgroups[group]} M{mc}")
            mgroups.setdefault(group, mc)
        elif k not in GRBL_WORDS or (k == "E" and not moving):
            first = (20, f"word {k}")
        elif w.value is None:
            first = (2, f"word {k} without a number")
        elif k == "T" and w.value > GRBL_MAX_TOOL:
            first = (38, f"T{w.text} (tools 0..{GRBL_MAX_TOOL})")
        elif k in seen:
            first = (25, f"word {k} repeated")
        elif k in "FNPST" and w.value < 0.0:
            first = (4, f"{k}{w.text}")
        seen.add(k)
        if first is not None:
            break
    if first is None:
        return None, axis_cmd
    if first[0] != 20:
        return (first[0], first[1], ()), axis_cmd
    # error:20 names everything on the line grbl does not have, and counts its codes as unknown
    bad = []
    for w in words:
        if w.value is None or w.letter not in "GM":
            continue
        if w.letter == "G" and _grbl_g_word(round(w.value, 1))[1] == 20:
            bad.append(_gname(round(w.value, 1)))
        elif w.letter == "M" and w.value == int(w.value) and int(w.value) not in GRBL_M:
            bad.append(f"M{int(w.value)}")
    letters = [k for k in dict.fromkeys(w.letter for w in words)
               if k not in "GM" and (k not in GRBL_WORDS or (k == "E" and not moving))]
    return (20, " ".join(bad + [f"word {k}" for k in letters]), bad), axis_cmd


class Rs274Commands:
    """Mixed into :class:`.interp.Interpreter`: the CNC dialects' line execution."""

    # ------------------------------------------------------------------ set-up from the machine
    def _cnc_init(self) -> None:
        """Machine units for programs that state none ([TRAJ]LINEAR_UNITS), the parameter table (the .var
        file's values: stored G28/G30 positions, coordinate systems, G92), tool table; then the .ini's
        [RS274NGC]RS274NGC_STARTUP_CODE as a line 0."""
        m = self.machine
        lc = getattr(m, "linuxcnc", None)
        self.tool_table: dict[int, float] = {}
        self.tool_change_position = None
        self.pending_tool = None
        self.params = None           # the one parameter table of a CNC program (gcode/ngc.py NgcParams)
        self.user_mm = 1.0           # mm per "user" unit: the unit of the .var and tool table (the machine's)
        self.spindle_dir = 5         # M3 / M4 / M5 in force
        self.spindle_rpm = 0.0       # the last S word (rpm)
        self._noted: set[str] = set()   # named warnings given once per file
        self._grbl_reads = m.flavor == "grbl"   # lines read as grbl reads them first (grbl_line.py)
        self.grbl_words: list[Word] | None = None    # the words of the grbl line being run, in order (step 2)
        self.grbl_line_number: int | None = None     # its N (gcode.c: a larger N than 10,000,000 is error:27)
        if self._grbl_reads:
            self._grbl_state_init()      # spindle, coolant, laser mode, idle (commands_state.py)
        if not m.is_cnc:
            return
        # grbl: the scanner rejects inert lines itself (scan.I_GRBL_INERT, grbl_rejected_lines); --strict and a
        # pending start wait take the full path (the scanner hands every line over while one is pending)
        self.ist[S.I_GRBL_INERT] = 1 if (m.flavor != "linuxcnc" and not self.strict) else 0
        self._inert_warnings: dict[int, str] = {}
        from .ngc import NgcParams

        self.params = NgcParams()
        if lc is None:
            return
        self.st[S.S_UNIT] = float(getattr(lc, "program_units_mm", 1.0))
        self.user_mm = float(getattr(lc, "user_units_mm", getattr(lc, "program_units_mm", 1.0)))
        self.params.update(getattr(lc, "parameters", {}) or {})
        self._restore_offsets()
        self.tool_table = dict(getattr(lc, "tool_table", {}) or {})
        self.tool_change_position = getattr(lc, "tool_change_position", None)
        startup = getattr(lc, "startup_code", "") or ""
        if startup.strip():
            self.line = 0
            self._classic(startup.strip())
            self.rows = []           # the start-up code makes no motion rows (it sets modes)

    def _restore_offsets(self) -> None:
        """LinuxCNC's start-up (rs274ngc_pre.cc init): the coordinate system #5220 (1..9, else 1) with its
        origin from the table, and the G92 offsets #5211-5213 when #5210 says they were applied."""
        p = self.params
        k = int(p.numbered[5220] + 0.0001)
        if not 1 <= k <= 9:
            k = 1
            p.numbered[5220] = 1.0
        self.work_index = k - 1
        self.work[k - 1] = self._origin_from_params(k - 1)
        if p.numbered[5210]:
            self.g92[:] = [p.numbered[5211 + a] * self.user_mm for a in range(3)]
        self._update_offsets()

    # ------------------------------------------------------------------ the parameter table
    def _origin_from_params(self, idx: int) -> list[float]:
        """Origin (mm) of coordinate system ``idx`` (0 = G54) as the table holds it (#5221 + 20·idx …)."""
        base = 5221 + 20 * idx
        return [self.params.numbered[base + a] * self.user_mm for a in range(3)]

    def _set_param_mm(self, index: int, value_mm: float) -> None:
        """Store a length (mm) into ``#index`` in user units, as LinuxCNC's PROGRAM_TO_USER_LEN does."""
        if self.params is not None:
            self.params.numbered[index] = value_mm / self.user_mm

    def _select_origin(self, idx: int) -> None:
        """G54..G59.3: coordinate system ``idx`` (0..8); a new one loads its origin from the table
        (convert_coordinate_system), the one in use stays as it is."""
        if idx == self.work_index:
            return
        self.work_index = idx
        if self.params is not None:
            self.params.numbered[5220] = float(idx + 1)
            self.work[idx] = self._origin_from_params(idx)
        self._update_offsets()

    def _store_g92(self) -> None:
        """G92 writes its offsets to #5211-5213 and sets #5210 (convert_axis_offsets)."""
        if self.params is not None:
            self.params.numbered[5210] = 1.0
            for a in range(3):
                self._set_param_mm(5211 + a, float(self.g92[a]))

    def _g92_family(self, gset: set) -> None:
        """G92.1 (offsets and #5211.. zeroed), G92.2 (offsets zeroed, parameters kept), G92.3 (offsets from
        #5211-5213); a table-less (printer) interpreter keeps the G92.2 values itself."""
        p = self.params
        if 92.1 in gset or 92.2 in gset:
            self.g92_saved = self.g92.copy()
            self.g92[:] = 0.0
            if p is not None:
                p.numbered[5210] = 0.0
                if 92.1 in gset:
                    for a in range(9):
                        p.numbered[5211 + a] = 0.0
            self._update_offsets()
        if 92.3 in gset:
            if p is not None:
                p.numbered[5210] = 1.0
                self.g92[:] = [p.numbered[5211 + a] * self.user_mm for a in range(3)]
            else:
                self.g92 = self.g92_saved.copy()
            self._update_offsets()

    def _note_once(self, key: str, msg: str) -> None:
        """A named warning given once per file."""
        if key not in self._noted:
            self._noted.add(key)
            self.warn(msg)

    # ------------------------------------------------------------------ fast path: lines that do nothing
    def grbl_inert_line(self, raw: bytes, lineno: int) -> bool:
        """Interpret line ``lineno`` (``raw``: its bytes, no newline) at once if it is a grbl line of one M code
        grbl does not have and words that only a G or M code would read (no G code, no F, S, T or axis word):
        a printer's ``M204 P1000`` in a program run on grbl. grbl rejects such a line whole (error:20); what
        the full path (:meth:`_grbl_check_block`) makes of it, one warning and the code counted, is replayed
        from a memo of the line's text. False (nothing done) for any other line, under ``--strict`` (the line
        is an error there), on LinuxCNC and before the machine's start time is counted: those go the full
        path."""
        memo = self.__dict__.get("_inert_memo")
        if memo is None:
            memo = self._inert_memo = {}
        got = memo.get(raw)
        if got is None:
            got = self._grbl_inert_effect(raw)
            if len(memo) < _INERT_MEMO_MAX:
                memo[raw] = got
        if not got or self.strict or self._start_pending or self.dialect != S.DIALECT_CNC or \
                self.machine.flavor == "linuxcnc" or self.ist[S.I_STOPPED]:
            return False
        name, warning = got
        self.line = lineno
        self.warn(warning)           # as _grbl_check_block
        self.unknown[name] = self.unknown.get(name, 0) + 1
        return True

    def grbl_rejected_lines(self, lines: np.ndarray, codes: np.ndarray) -> None:
        """The inert grbl lines the scanner skipped (scan.py ``grbl_inert_words``; ``lines`` their numbers,
        ``codes`` their M codes), each warned about and counted as :meth:`grbl_inert_line` does (``warn``'s
        arithmetic in bulk: tens of thousands of such lines in a printer's file)."""
        texts = self._inert_warnings
        codes_l = codes.astype(np.int64).tolist()
        lines_l = lines.tolist()
        room = MAX_WARNINGS - len(self.warnings)
        if room > 0:
            path = self.path
            for line, code in zip(lines_l[:room], codes_l[:room]):
                warning = texts.get(code)
                if warning is None:
                    warning = texts[code] = _grbl_reject_warning([f"M{code}"])
                self.warnings.append(f"{path}:{line}: {warning}")
        self.warning_count += len(lines_l)
        unknown = self.unknown
        for code in dict.fromkeys(codes_l):      # first appearance first, as line by line
            name = f"M{code}"
            unknown[name] = unknown.get(name, 0) + codes_l.count(code)
        self.line = lines_l[-1]

    @staticmethod
    def _grbl_inert_effect(raw: bytes):
        """(M code name, the warning of its rejected line) when ``raw`` is an inert grbl line
        (:meth:`grbl_inert_line`), else False."""
        m = _INERT_LINE.fullmatch(raw)
        if m is None or len(raw) > GRBL_LINE_BUFFER_SIZE - 1:
            return False              # (a longer line may overflow grbl's buffer: error:11, the full path)
        mc = int(m.group(1))
        # grbl's own M codes act; free-text ones and M486 are read before the words (interp._classic)
        if mc in GRBL_M or mc in FREE_TEXT_M or mc == 486:
            return False
        letters = [w[:1].decode().upper() for w in m.group(2).split()]
        if len(set(letters)) != len(letters):
            return False              # a repeated word is an error: the full path names it
        bad = [f"M{mc}"] + [f"word {k}" for k in letters if k not in GRBL_WORDS]
        return f"M{mc}", _grbl_reject_warning(bad)

    # ------------------------------------------------------------------ checks
    def _grbl_check_block(self, gs: list[float], ms: list[int], params: dict[str, Word]) -> bool:
        """grbl's gc_execute_line checks every word of a line before it executes any (gcode.c, steps 1-3) and
        on the first error answers ``error:N`` and executes nothing of the line: no mode, offset, feed or
        position changes, as if the line were absent; a sender shows the error and sends the next line. Such
        a line is skipped with one warning naming the line and grbl's error (an error under ``--strict``);
        returns True then. E words are left to the grbl model, which names them (a printer's file is not for
        this machine)."""
        err = self._grbl_block_error(gs, ms, params)
        if err is None:
            return False
        self.grbl_reject(*err)
        return True

    def grbl_reject(self, code: int, what: str, unknown=()) -> None:
        """A line grbl answers with ``error:<code>`` (``what``: the words at fault) is skipped whole: one
        warning naming the line and the error, the codes in ``unknown`` counted as unknown commands; an
        error naming file and line under ``--strict``."""
        text = GRBL_ERRORS[code]
        if self.strict:
            self.error(f"{what.split(' word ')[0] if code == 20 else what}: grbl error:{code} ({text})")
        self.warn(f"{what}: grbl rejects it (error:{code}, {text}); the line is skipped")
        for name in unknown:
            self.unknown[name] = self.unknown.get(name, 0) + 1

    def _grbl_block_error(self, gs: list[float], ms: list[int], params: dict[str, Word]):
        """The first error grbl's gc_execute_line finds in a line, in its order (gcode.c step 2, word by word in
        the line's order: :func:`grbl_word_error`; then step 3, the checks of the block against the modal
        state, line number first), as ``(error number, what, codes to count as unknown)``; None for a line grbl
        runs. The words in order are ``self.grbl_words`` (set by the interpreter's reading of the line), else
        the G codes, M codes and value words of the arguments in that order."""
        words = self.grbl_words
        if words is None:
            words = ([Word("G", g, f"{g:g}") for g in gs] + [Word("M", float(mc), str(mc)) for mc in ms]
                     + list(params.values()))
        first, axis_cmd = grbl_word_error(words)
        if first is not None:
            return first
        n = self.grbl_line_number
        if n is not None and n > GRBL_MAX_LINE_NUMBER:
            return 27, f"N{n} (line numbers up to {GRBL_MAX_LINE_NUMBER})", ()
        return self._grbl_block_check(set(gs), params, axis_cmd)

    def _grbl_block_check(self, gset: set, params: dict[str, Word], axis_cmd):
        """gcode.c step 3 on a line whose words passed step 2: (error number, what, codes counted as unknown)
        or None."""
        axes = [k for k in "XYZ" if k in params]
        if axes and axis_cmd is None:
            axis_cmd = "motion"           # axis words alone move in the modal motion mode
        used = set("NFSTE")               # single-meaning words (E: the grbl model names it)
        if 4.0 in gset:
            if "P" not in params:
                return 28, "G4 without P", ()
            used.add("P")
        if axis_cmd == "tlo" and 43.1 in gset and axes != ["Z"]:
            return 37, "G43.1 " + " ".join(axes) + " (the tool length offset takes Z alone)", ()
        motion = next((MOTION_CODE.get(g, int(g)) for g in gset if g in GRBL_MOTION_G),
                      int(self.ist[S.I_MOTION]))
        if 10.0 in gset:
            if not axes:
                return 26, "G10 without axis words", ()
            if "P" not in params and "L" not in params:
                return 28, "G10 without P and L", ()
            p_sys = int(params["P"].value) if "P" in params else 0
            if p_sys > GRBL_N_COORD:
                return 29, f"G10 P{params['P'].text} (coordinate systems 1..{GRBL_N_COORD}, 0: the one in use)", ()
            ell = int(params["L"].value) if "L" in params else 0
            if ell == 2 and "R" in params:
                return 20, "G10 L2 R", ["G10 L2 R"]
            if ell not in (2, 20):
                name = f"G10 L{params['L'].text}" if "L" in params else "G10 without L"   # read as L0
                return 20, name, [name]
            used.update("LP")
        elif 92.0 in gset:
            if not axes:
                return 26, "G92 without axis words", ()
        elif 53.0 in gset and motion not in (0, 1):
            return 30, "G53 needs G0 or G1 in force", ()
        if motion == 80:
            if axes:
                return 31, " ".join(axes) + " with G80 in force (axis words without a motion)", ()
        elif axis_cmd == "motion" and motion != 0:
            feed = params["F"].value if "F" in params else float(self.st[S.S_FEED])
            if feed == 0.0:
                name = "F0" if "F" in params else f"G{motion if motion < 100 else motion / 10:g} without F"
                return 22, name + " (no feed rate in force)", ()
            if motion in (2, 3):
                err = self._grbl_arc_check(motion, gset, params, axes, used)
                if err is not None:
                    return err
            elif motion in PROBE_MOTION:
                if not axes:
                    return 26, f"G38.{motion - 380} without axis words", ()
                from ..planner.grbl import grbl_floats
                here = [float(self.st[S.S_X + a]) for a in range(3)]
                if (grbl_floats(self._grbl_block_target(gset, params)) == grbl_floats(here)).all():
                    return 33, f"G38.{motion - 380} to where the probe is", ()
        if axis_cmd is not None:
            used.update("XYZ")
        unused = [k for k in params if k not in used]
        if unused:
            return 36, "word(s) " + " ".join(unused) + " unused", ()
        return None

    def _grbl_arc_check(self, motion: int, gset: set, params: dict[str, Word], axes: list[str], used: set):
        """gcode.c's G2/G3 checks (step 3, motion modes): axis words, in the plane; the radius (R) or the
        centre offsets (I J K) against the end point, in grbl's floats (arcs_grbl.py). Adds the words the
        arc uses to ``used``; returns (error number, what, ()) or None."""
        from .arcs_grbl import PLANE_AXES, grbl_arc_error

        name = f"G{motion}"
        if not axes:
            return 26, f"{name} without axis words", ()
        plane = next((int(g) for g in (17.0, 18.0, 19.0) if g in gset), self.plane)
        a0, a1, _ = PLANE_AXES[plane]
        if not any("XYZ"[a] in params for a in (a0, a1)):
            return 32, f"{name} without axis words in the G{plane} plane", ()
        scale = 25.4 if 20.0 in gset else 1.0 if 21.0 in gset else float(self.st[S.S_UNIT])
        here = [float(self.st[S.S_X + a]) for a in range(3)]
        target = self._grbl_block_target(gset, params)
        if "R" in params:
            used.add("R")
            err = grbl_arc_error(here, target, None, params["R"].value * scale, plane, motion == 2,
                                 self.machine.arc_tolerance)
        else:
            if not any("IJK"[a] in params for a in (a0, a1)):
                return 35, f"{name} without centre offsets in the G{plane} plane", ()
            used.update("IJK")
            ijk = [params[k].value * scale if k in params else 0.0 for k in "IJK"]
            err = grbl_arc_error(here, target, ijk, None, plane, motion == 2, self.machine.arc_tolerance)
        if err == 34:
            return 34, f"{name} R{params['R'].text} (shorter than half the chord)", ()
        if err == 33:
            return 33, f"{name} (the end point is not on the circle)", ()
        return None

    def _grbl_block_target(self, gset: set, params: dict[str, Word]) -> list[float]:
        """The end point (machine mm) of the line's motion with the line's own units, distance mode and
        coordinate system, as gcode.c computes it before anything runs (the executor's :meth:`_targets`
        arithmetic once those modes are in force)."""
        st, ist = self.st, self.ist
        scale = 25.4 if 20.0 in gset else 1.0 if 21.0 in gset else float(st[S.S_UNIT])
        absc = 90.0 in gset or (91.0 not in gset and ist[S.I_ABS_COORD] != 0)
        idx = next((i for i, g in enumerate((54.0, 55.0, 56.0, 57.0, 58.0, 59.0)) if g in gset), self.work_index)
        origin = (self.work[idx].tolist() if idx == self.work_index or self.params is None
                  else self._origin_from_params(idx))
        off = [origin[a] + float(self.g92[a]) for a in range(3)]
        off[2] += self.tool_z
        out = [float(st[S.S_X + a]) for a in range(3)]
        for a, k in enumerate("XYZ"):
            if k not in params:
                continue
            v = params[k].value * scale
            if 53.0 in gset:
                out[a] = v
            elif absc:
                out[a] = v + off[a]
            else:
                out[a] = float(S.relative_sum(out[a], v, ist[S.I_F32_REL] != 0))
        return out

    def _check_groups(self, gs: list[float], ms: list[int], lcnc: bool) -> None:
        for name, codes in G_GROUPS.items():
            got = [g for g in gs if g in codes]
            if len(got) > 1:
                if lcnc:
                    self.error(f"{' '.join(_gname(g) for g in got)}: two G codes of one modal group ({name}); "
                               f"LinuxCNC: 'Two G codes used from same modal group'")
                self.error(f"{' '.join(_gname(g) for g in got)}: two G codes of one modal group ({name}); "
                           f"grbl error:21 (modal group violation)")
        for name, codes in M_GROUPS.items():
            got = [m for m in ms if m in codes]
            if name == "coolant" and sorted(got) == [7, 8]:
                continue            # LinuxCNC: M7 and M8 may be turned on together
            if len(got) > 1:
                tail = ("LinuxCNC: 'Two M codes used from same modal group'" if lcnc
                        else "grbl error:21 (modal group violation)")
                self.error(f"{' '.join(f'M{m}' for m in got)}: two M codes of one modal group ({name}); {tail}")
        if lcnc and len(ms) > 5:
            self.error("more than 5 M codes on one line (LinuxCNC: 'Too many M codes on line')")
        users = [g for g in gs if g in AXIS_USERS]
        motions = [g for g in gs if g in MOTION_G and g != 80.0]
        if users and motions:
            tail = ("LinuxCNC: 'Cannot use two G codes that both use axis values'" if lcnc
                    else "grbl error:24 (axis command conflict)")
            self.error(f"{_gname(users[0])} and {_gname(motions[0])} both use the axis words; {tail}")

    # ------------------------------------------------------------------ the line
    def _execute_cnc(self, gs: list[float], ms: list[int], params: dict[str, Word]) -> None:
        """One line of a CNC program: on grbl, a line with a code or word grbl does not have is rejected
        whole (:meth:`_grbl_check_block`); then LinuxCNC's checks and execute_block's order."""
        lcnc = self.machine.flavor == "linuxcnc"
        if not lcnc and self._grbl_check_block(gs, ms, params):
            return
        g_ok: list[float] = []
        for g in gs:
            if g not in KNOWN_G:
                self._unknown_or_macro(_gname(g))
                continue
            g_ok.append(g)
        self._check_groups(g_ok, ms, lcnc)
        self._execute_block(g_ok, ms, params, lcnc)

    def _execute_block(self, gs: list[float], ms: list[int], params: dict[str, Word], lcnc: bool) -> None:
        """Every word of a checked line in RS274NGC's order (interp_execute.cc execute_block): feed mode, F,
        S, T, the M codes (convert_m), the G codes (convert_g, motion last), then the stops (convert_stop)."""
        used: set[str] = set()
        gset = set(gs)
        mset = set(ms)
        self._convert_feed_mode(gset)
        self._convert_feed_rate(gset, params, used, lcnc)
        # grbl: a speed change while the spindle turns, a spindle or a coolant change stop the motion, in
        # this order: gc_execute's steps 4, 7, 8 (commands_state._grbl_syncs)
        if not lcnc:
            self._grbl_syncs(sorted(mset), params)
        self._convert_speed(mset, params, used, lcnc)
        self._convert_tool_select(params, used)
        self._convert_m(ms, mset, params, used, lcnc)
        self._convert_g(gs, gset, params, used, lcnc)
        self._warn_unused_words(params, used, ms, "XYZEFN")
        self._convert_stop(ms, params, used)

    def _warn_unused_words(self, params: dict, used: set, ms, known: str) -> None:
        """Name what the line's executor did not use: rotary/extra axes (not modelled) and, on a line without an M
        code (whose parameters are its own), any other word outside ``known``."""
        for k in ("A", "B", "C", "U", "V", "W"):
            if k in params:
                used.add(k)
                self.warn(f"axis {k} is not modelled: ignored")
        unused = [k for k in params if k not in used and k not in known]
        if unused and not ms:
            self.warn("word(s) " + " ".join(unused) + " ignored")

    def _convert_feed_mode(self, gset: set) -> None:
        """G93 / G95 are refused by name; G94 (units per minute) is the only mode modelled."""
        if 93 in gset:
            self.error("G93 inverse-time feed is not supported")
        if 95 in gset:
            self.error("G95 feed per revolution is not supported")

    def _convert_feed_rate(self, gset: set, params: dict[str, Word], used: set[str], lcnc: bool) -> None:
        """F (mm/s kept): LinuxCNC reads it in the units in force before this line's G20/G21, grbl in the
        line's own units."""
        st = self.st
        f = self._value(params, "F")
        if f is None:
            return
        used.add("F")
        if not f > 0.0 and (lcnc or f != 0.0):
            self.error(f"feed rate F must be > 0, got {params['F'].text}")
        # grbl: F0 is a feed like any other (the next feed move without F is its error:22)
        unit_before = float(st[S.S_UNIT])
        unit_line = 25.4 if 20 in gset else (1.0 if 21 in gset else unit_before)
        st[S.S_FEED] = f * (unit_before if lcnc else unit_line) / 60.0

    def _convert_speed(self, mset: set, params: dict[str, Word], used: set[str], lcnc: bool) -> None:
        """S (rpm): the spindle speed; an S without M3/M4 on its line counts as a spindle command."""
        if "S" not in params:
            return
        used.add("S")
        rpm = self._value(params, "S")
        if rpm < 0.0:
            self.error("S must be >= 0 " + ("(LinuxCNC: 'Negative spindle speed used')" if lcnc
                                            else "(grbl error:4, negative value)"))
        self.spindle_rpm = rpm
        if not mset & {3, 4}:
            self.spindle_commands += 1

    def _convert_tool_select(self, params: dict[str, Word], used: set[str]) -> None:
        """T: the tool the next M6 loads."""
        if "T" not in params:
            return
        used.add("T")
        t = params["T"].value
        if t is None or t != int(t) or t < 0:
            self.error("T needs a tool number")
        self.pending_tool = int(t)

    def _convert_m(self, ms: list[int], mset: set, params: dict[str, Word], used: set[str], lcnc: bool) -> None:
        """The M codes but the stops, in convert_m's order: M6 / M61, spindle, coolant, overrides (no
        effect at 100 %), then the other M codes (user M100-M199 and the rest)."""
        if 6 in mset:
            self._cnc_tool_change(lcnc)
        if 61 in mset:
            q = self._value(params, "Q")
            used.add("Q")
            if q is None or q != int(q) or q < 0:
                self.error("M61 needs Q<tool number>")
            self.tool = int(q)
        for mc in (3, 4, 5):
            if mc in mset:
                self.spindle_commands += 1
                self.spindle_dir = mc
                if lcnc:
                    self._wait(f"M{mc}")   # LinuxCNC's task waits for the motion queue to empty
        for mc in (7, 8, 9):
            if mc in mset and lcnc:
                self._wait(f"M{mc}")
        for mc in ms:
            if mc in (0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 30, 48, 49, 50, 51, 52, 53, 60, 61):
                continue
            self._m_command(mc, params, used)

    def _convert_g(self, gs: list[float], gset: set, params: dict[str, Word], used: set[str], lcnc: bool) -> None:
        """The G codes in convert_g's order: dwell, plane, units, cutter compensation, tool length offset,
        coordinate system, path control, distance and retract modes, the non-modal group (convert_modal_0),
        motion."""
        st = self.st
        if 4 in gset:
            if lcnc:
                self._dwell(params, used)
            else:       # grbl: G4 P seconds; an S on the line is the spindle speed (read above), not a time
                self._dwell({"P": params["P"]}, used)
        self._set_plane(gset)
        st[S.S_UNIT] = 25.4 if 20 in gset else (1.0 if 21 in gset else float(st[S.S_UNIT]))
        for g in (41.0, 42.0, 41.1, 42.1):
            if g in gset:
                used.update(("D",))
                self.warn(f"{_gname(g)} cutter radius compensation is not modelled: the path is planned "
                          f"uncompensated")
        axis_consumed = self._tool_length(gset, params, used, lcnc)
        self._modal_modes(gset, params, used, lcnc)
        axis_consumed = self._convert_modal_0(gset, params, used, lcnc) or axis_consumed
        self._convert_motion([g for g in gs if g in MOTION_G], 53 in gset, axis_consumed, params, used, lcnc)

    def _convert_modal_0(self, gset: set, params: dict[str, Word], used: set[str], lcnc: bool) -> bool:
        """G10, G28 / G30, G28.1 / G30.1, G92 and G92.1-G92.3; True when one of them took the axis words."""
        axis_consumed = False
        if 10 in gset:
            self._cnc_g10(params, used, lcnc)
            axis_consumed = True
        if 28 in gset or 30 in gset:
            self._cnc_home(28 if 28 in gset else 30, params, used)
            axis_consumed = True
        if 28.1 in gset or 30.1 in gset:
            # convert_savehome: the machine position (tool length and offsets included) in user units
            base = 5161 if 28.1 in gset else 5181
            for a in range(3):
                self._set_param_mm(base + a, float(self.st[S.S_X + a]))
        if 92 in gset:
            self._g92(params, used)
            self._store_g92()
            axis_consumed = True
        self._g92_family(gset)
        return axis_consumed

    def _convert_motion(self, motion_codes: list[float], machine_coords: bool, axis_consumed: bool,
                        params: dict[str, Word], used: set[str], lcnc: bool) -> None:
        """The line's motion code sets the modal motion mode; axis words not taken by a non-modal code move
        in it (a canned cycle runs without them)."""
        for g in motion_codes:
            self._set_motion(g)
        motion = int(self.ist[S.I_MOTION])
        if machine_coords and motion not in (0, 1):
            self.error("G53 needs G0 or G1" + ("" if lcnc else " (grbl error:30)"))
        has_axes = any(k in params for k in "XYZE") and not axis_consumed
        if motion_codes and motion_codes[0] != 80 and not has_axes and motion in (2, 3):
            if any(k in params for k in "IJKR"):
                self.error(f"G{motion} needs an end point (X/Y/Z)")
        if has_axes or (motion in CYCLE_G and motion_codes and not axis_consumed):
            if motion == 80:
                self.error("axis words without a motion mode (G80 in force): "
                           + ("LinuxCNC: 'Cannot use axis values without a G code that uses them'" if lcnc
                              else "grbl error:31 (axis words without a command)"))
            elif motion in SPECIAL_MOTION:
                self._cnc_special_motion(motion, params, used, lcnc)
            else:
                self._motion(motion, params, used, None, machine_coords)
        elif motion_codes and motion_codes[0] in (33.0, 33.1, 38.2, 38.3, 38.4, 38.5) and not axis_consumed:
            self.error(f"{_gname(motion_codes[0])} needs at least one axis word"
                       + (" (grbl error:26)" if not lcnc else ""))
        elif motion_codes and motion_codes[0] == 76.0 and not axis_consumed:
            self._cnc_special_motion(MOTION_G76, params, used, lcnc)

    def _convert_stop(self, ms: list[int], params: dict[str, Word], used: set[str]) -> None:
        """M0 / M1 / M60 pause (each named, commands_state); M2 / M30 end the program."""
        for mc in ms:
            if mc in (0, 1, 60):
                self._m_command(mc, params, used)
            elif mc in (2, 30):
                self.event(f"M{mc} program end")
                self.ist[S.I_STOPPED] = 1

    # ------------------------------------------------------------------ tool length offset
    def _tool_length(self, gset: set, params: dict[str, Word], used: set[str], lcnc: bool) -> bool:
        """G49, G43 [H], G43.1 axes, G43.2 H|axes (convert_tool_length_offset); Z offsets are modelled, an X
        or Y offset is refused by name. LinuxCNC's task waits for the motion queue to empty for each.
        Returns True when the axis words were taken (G43.1; G43.2 under G80), G43.2's axis words else
        move too."""
        consumed = False
        code = next((g for g in (49.0, 43.0, 43.1, 43.2) if g in gset), None)
        if code is None:
            return False
        scale = float(self.st[S.S_UNIT])
        if code == 49.0:
            self.tool_z = 0.0
        elif code == 43.0:
            used.add("H")
            h = self._value(params, "H")
            if h is not None and (h != int(h) or h < 0):
                self.error(f"G43 H must be a tool number, got {params['H'].text}")
            # H0 and no H: the tool in the spindle (a nonrandom changer's index 0)
            tool = self.tool if h is None or h == 0 else int(h)
            self.tool_z = self._tool_length_of(tool, "G43", h is not None and h != 0)
        else:
            name = _gname(code)
            axes = [k for k in "XYZ" if k in params]
            used.update(axes)
            # G43.1 takes the axis words; G43.2's also move in the modal motion mode (LinuxCNC's
            # enhance_block sets motion_to_be for every tool length code but G43.1), none under G80
            consumed = code == 43.1 or int(self.ist[S.I_MOTION]) == 80
            for k in axes:
                if k != "Z" and self._value(params, k) != 0.0:
                    self.error(f"{name} {k}: tool offsets in X and Y are not modelled (Z only)")
            if code == 43.1:
                if "H" in params:
                    self.error("G43.1 takes axis words, not H")
                if "Z" in axes:            # no axis word: the offsets stay (convert_tool_length_offset)
                    self.tool_z = self._value(params, "Z") * scale
            else:
                h = self._value(params, "H")
                used.add("H")
                if h is not None and axes:
                    self.error("G43.2: Can not have both H and axis words")
                if h is None and not axes:
                    self.error("G43.2: No axes specified and H word missing")
                if h is not None:
                    if h != int(h) or h < 0:
                        self.error(f"G43.2 H must be a tool number, got {params['H'].text}")
                    self.tool_z += self._tool_length_of(int(h), "G43.2", True)
                elif "Z" in axes:
                    self.tool_z += self._value(params, "Z") * scale
        self._update_offsets()
        if lcnc:
            self._wait(_gname(code))
        return consumed

    def _tool_length_of(self, tool: int, name: str, named: bool) -> float:
        """Z length (mm) of ``tool`` in the tool table (0 for no tool; an unknown tool is LinuxCNC's error;
        a machine without a tool table warns and takes 0)."""
        if tool == 0 and not named:
            return self.tool_table.get(0, 0.0)
        if tool in self.tool_table:
            return self.tool_table[tool]
        if self.tool_table:
            self.error(f"{name} H{tool}: tool {tool} is not in the tool table")
        self.warn(f"{name} H{tool}: no tool table, tool length offset taken as 0")
        return 0.0

    # ------------------------------------------------------------------ G10
    def _cnc_g10(self, params: dict[str, Word], used: set[str], lcnc: bool) -> None:
        """G10 L2 / L20 (coordinate system origins, convert_setup) and G10 L1 / L10 / L11 (tool table
        entries, convert_setup_tool); grbl accepts L2 and L20 only (error:20 for the rest)."""
        used.update(("L", "P", "R", "X", "Y", "Z", "I", "J", "Q"))
        ell = self._value(params, "L")
        if ell is None:
            self.error("G10 needs L" + (" (grbl error:20)" if not lcnc else ""))
        if ell in (2, 20):
            self._g10_origin(int(ell), params, lcnc)
        elif ell in (1, 10, 11) and lcnc:
            self._g10_tool(int(ell), params)
        else:               # grbl: rejected before the line runs (_grbl_check_block)
            self.error(f"G10 L{ell:g} is not supported (L1, L2, L10, L11, L20 are)")

    def _g10_origin(self, ell: int, params: dict[str, Word], lcnc: bool) -> None:
        """G10 L2 P axes: origin of system P (0: the active one) = the words; L20: the origin that makes the
        current position read the words. Written to #5221 + 20·(P − 1) …; takes effect at once when P is
        the system in use."""
        st = self.st
        if "I" in params or "J" in params:
            self.error(f"I J words not allowed with G10 L{ell}")
        p = self._value(params, "P")
        if p is None:
            if lcnc:
                self.error(f"G10 L{ell} needs P (the coordinate system)")
            p = 0.0         # grbl reads an absent P as 0, the system in use (gcode.c)
        # grbl truncates P (its block check has refused P > 6 already)
        p_int = int(p + 0.0001) if lcnc else int(p)
        n_sys = 9 if lcnc else GRBL_N_COORD
        if not 0 <= p_int <= n_sys or (lcnc and abs(p - p_int) > 0.0001):
            self.error(f"G10 L{ell} P must be 0..{n_sys} (the coordinate system)"
                       + ("" if lcnc else " (grbl error:29)"))
        idx = self.work_index if p_int == 0 else p_int - 1
        r = self._value(params, "R")
        if r is not None:
            if ell == 20:
                self.error("R not allowed in G10 L20")
            if r != 0.0:
                self.error("G10 L2 R: a rotated coordinate system is not modelled")
        scale = float(st[S.S_UNIT])
        origin = (self.work[idx].tolist() if idx == self.work_index or self.params is None
                  else self._origin_from_params(idx))
        for a, k in enumerate("XYZ"):
            v = self._value(params, k)
            if v is None:
                continue
            if ell == 2:
                origin[a] = v * scale
            else:   # L20: make the current position read v in that system
                extra = self.tool_z if a == 2 else 0.0
                origin[a] = float(st[S.S_X + a]) - v * scale - self.g92[a] - extra
            self._set_param_mm(5221 + 20 * idx + a, origin[a])
        if idx == self.work_index or self.params is None:
            self.work[idx] = origin
        self._update_offsets()

    def _g10_tool(self, ell: int, params: dict[str, Word]) -> None:
        """G10 L1 P<tool> Z: the tool's length is Z; L10: the length that makes the current Z read the word
        with the current coordinate system and G92 offsets; L11: the same in G59.3 without G92
        (convert_setup_tool). The tool table changes; the offset in force changes at the next G43."""
        st = self.st
        p = self._value(params, "P")
        if p is None:
            self.error(f"G10 L{ell} needs P (the tool number)")
        tool = int(round(p))
        if abs(p - tool) > 0.0001 or tool <= 0:
            self.error(f"G10 L{ell} P must be a tool number > 0, got {params['P'].text}")
        if tool not in self.tool_table:
            if self.tool_table:
                self.error(f"G10 L{ell} P{tool}: tool {tool} is not in the tool table "
                           "(LinuxCNC: 'Requested tool not found in the tool table')")
            self._note_once("G10 L1", f"G10 L{ell} P{tool}: no tool table, the entry is made for this program")
        if not any(k in params for k in "XYZRQIJ"):
            self.error(f"G10 L{ell} without offsets has no effect")
        for k in "XY":
            if k in params and self._value(params, k) != 0.0 and ell == 1:
                self.error(f"G10 L1 {k}: tool offsets in X and Y are not modelled (Z only)")
            if k in params and ell != 1:
                self.error(f"G10 L{ell} {k}: tool offsets in X and Y are not modelled (Z only)")
        z = self._value(params, "Z")
        if z is None:
            self.tool_table.setdefault(tool, 0.0)
            return
        scale = float(st[S.S_UNIT])
        if ell == 1:
            length = z * scale
        elif ell == 10:
            # the current Z in the current system without the tool length offset (G92 included)
            here = float(st[S.S_Z]) - float(self.work[self.work_index][2]) - float(self.g92[2])
            length = here - z * scale
        else:
            origin9 = (self._origin_from_params(8)[2] if self.params is not None and self.work_index != 8
                       else float(self.work[8][2]))
            length = float(st[S.S_Z]) - origin9 - z * scale
        self.tool_table[tool] = length

    # ------------------------------------------------------------------ modal modes shared by every dialect
    def _set_plane(self, gset: set) -> None:
        """G17 / G18 / G19."""
        for g in (17, 18, 19):
            if g in gset:
                self.plane = g

    def _modal_modes(self, gset: set, params: dict[str, Word], used: set[str], lcnc: bool) -> None:
        """Coordinate system (G54..G59.3), path control (G61, G61.1, G64 P Q), distance modes (G90/G91,
        G90.1/G91.1), canned-cycle retract mode (G98/G99), in RS274NGC's order; the classic executor of
        the printer dialects uses the same code (``lcnc``: LinuxCNC's G61 exact path and G64 Q)."""
        st, ist = self.st, self.ist
        scale = float(st[S.S_UNIT])
        for i, g in enumerate((54.0, 55.0, 56.0, 57.0, 58.0, 59.0, 59.1, 59.2, 59.3)):
            if g in gset:
                self._select_origin(i)
        if 61 in gset or 61.1 in gset:
            # LinuxCNC's G61 is exact *path* (tangent joins pass without stopping): 2; G61.1 exact stop: 1
            ist[S.I_EXACT_STOP] = 2 if (61 in gset and lcnc) else 1
        if 64 in gset:
            ist[S.I_EXACT_STOP] = 0
            p = self._value(params, "P")
            used.add("P")
            if p is not None and p < 0:
                self.error("G64 P must be >= 0")
            st[S.S_BLEND_P] = math.nan if p is None else p * scale
            q = self._value(params, "Q")
            if q is not None and q < 0:
                self.error("G64 Q must be >= 0")
            # LinuxCNC (interp_convert.cc): Q is the naive-CAM tolerance; P without Q sets Q = P
            st[S.S_BLEND_Q] = q * scale if q is not None else (p * scale if p is not None else 0.0)
            if "Q" in params:
                used.add("Q")
                if not lcnc:
                    self.g64_q_ignored += 1
        if 90 in gset or 91 in gset:
            ist[S.I_ABS_COORD] = 1 if 90 in gset else 0
            if ist[S.I_G90_SETS_E]:
                ist[S.I_ABS_E] = ist[S.I_ABS_COORD]
        if 90.1 in gset:
            self.arc_abs_centre = True
        if 91.1 in gset:
            self.arc_abs_centre = False
        if 98 in gset or 99 in gset:
            self.retract_mode = 98 if 98 in gset else 99
            if self.cycle_state is not None:
                self.cycle_state.retract_mode = self.retract_mode

    # ------------------------------------------------------------------ motion
    def _set_motion(self, g: float) -> None:
        """A motion code of the line becomes the modal motion mode (a new cycle series unless the code is
        a cycle continuing a cycle)."""
        ist = self.ist
        code = MOTION_CODE.get(g, int(g))
        if g == 80 or int(g) not in CYCLE_G or int(ist[S.I_MOTION]) not in CYCLE_G:
            self.cycle_state = None
        if g not in (0, 1, 2, 3, 80) and int(g) not in CYCLE_G and code not in SPECIAL_MOTION:
            self.error(f"{_gname(g)} is not supported")
        ist[S.I_MOTION] = code

    def _motion(self, motion: int, params: dict[str, Word], used: set[str], f: float | None,
                machine_coords: bool) -> None:
        """Axis words in the motion mode ``motion``: G0/G1, G2/G3 or a drilling cycle."""
        if motion in (0, 1):
            self._linear(motion, params, used, f, machine_coords)
        elif motion in (2, 3):
            self._arc(motion == 2, params, used, f)
        else:
            self._cycle(motion, params, used, f)

    # ------------------------------------------------------------------ G28 / G30
    def _rapid_row(self, x1: float, y1: float, z1: float, flags: int = 0) -> None:
        """A G0 from the current position to machine (x1, y1, z1) mm (none when it does not move)."""
        st = self.st
        x0, y0, z0, e0 = float(st[S.S_X]), float(st[S.S_Y]), float(st[S.S_Z]), float(st[S.S_E])
        dx, dy, dz = x1 - x0, y1 - y0, z1 - z0
        move_d = math.sqrt(dx * dx + dy * dy + dz * dz)
        if not all(math.isfinite(v) for v in (x1, y1, z1, move_d)):
            self.error("coordinate out of range")
        st[S.S_X], st[S.S_Y], st[S.S_Z] = x1, y1, z1
        if move_d > 0.0:
            self._row(KIND_TRAVEL, FLAG_RAPID | flags, x0, y0, z0, e0, x1, y1, z1, e0, move_d, math.inf,
                      float(st[S.S_ACC_T]), 0.0)

    def _cnc_home(self, code: int, params: dict[str, Word], used: set[str]) -> None:
        """LinuxCNC convert_home / grbl G28, G30: rapid to the intermediate point, then to the stored one
        (#5161-5163 / #5181-5183 of the parameter table, machine coordinates in user units)."""
        axes = [k for k in "XYZ" if k in params]
        used.update(axes)
        x1, y1, z1 = self._targets(params, False)
        self._rapid_row(x1, y1, z1)
        base = 5161 if code == 28 else 5181
        end = [float(self.st[S.S_X + a]) for a in range(3)]
        for a, k in enumerate("XYZ"):
            if k in axes or not axes:
                end[a] = self.params.numbered[base + a] * self.user_mm
        self._rapid_row(*end)
        self.event(f"G{code} to the stored position " + ("".join(axes) or "XYZ"))

    # ------------------------------------------------------------------ probe, spindle-synchronised motion
    def _cnc_special_motion(self, motion: int, params: dict[str, Word], used: set[str], lcnc: bool) -> None:
        """G38.2-G38.5 (probe), G33 (spindle-synchronised), G33.1 (rigid tap), G76 (threading cycle)."""
        if motion in PROBE_MOTION:
            self._probe(motion, params, used, lcnc)
        elif motion == MOTION_G33:
            self._spindle_synced(params, used)
        elif motion == MOTION_G33_1:
            self._rigid_tap(params, used)
        else:
            self._threading_cycle(params, used)

    def _exact_feed_row(self, target, feed_v: float, name: str, wait: bool = True) -> None:
        """A feed move to ``target`` (machine mm) at ``feed_v`` mm/s that starts from rest (``wait``: a
        zero-time wait named ``name`` before it, the motion queue empties) and ends at rest (exact stop)."""
        st, ist = self.st, self.ist
        if wait:
            self._wait(name)
        x0, y0, z0, e0 = float(st[S.S_X]), float(st[S.S_Y]), float(st[S.S_Z]), float(st[S.S_E])
        x1, y1, z1 = target
        dx, dy, dz = x1 - x0, y1 - y0, z1 - z0
        move_d = math.sqrt(dx * dx + dy * dy + dz * dz)
        if not all(math.isfinite(v) for v in (x1, y1, z1, move_d, feed_v)):
            self.error("coordinate out of range")
        st[S.S_X], st[S.S_Y], st[S.S_Z] = x1, y1, z1
        if move_d > 0.0:
            mode = int(ist[S.I_EXACT_STOP])
            ist[S.I_EXACT_STOP] = 1
            self._row(KIND_TRAVEL, 0, x0, y0, z0, e0, x1, y1, z1, e0, move_d, feed_v, float(st[S.S_ACC_T]), 0.0)
            ist[S.I_EXACT_STOP] = mode

    def _probe(self, motion: int, params: dict[str, Word], used: set[str], lcnc: bool) -> None:
        """G38.n (convert_probe): where the probe trips is not known before the program runs, so the move is
        timed in full to its target at the feed rate, from rest to rest (the queue empties before and after
        it), as LinuxCNC runs it when no contact happens (G38.2 / G38.4 then stop with an error, G38.3 /
        G38.5 go on); a named warning says so once per file."""
        name = f"G38.{motion - 380}"
        used.update("XYZF")
        target = self._targets(params, False)
        here = [float(self.st[S.S_X + a]) for a in range(3)]
        if target == here and motion in (382, 384):
            self.error(f"{name}: start point too close to probe point"
                       + (" (LinuxCNC: 'Start point too close to probe point')" if lcnc else " (grbl error:37)"))
        failure = ("LinuxCNC stops with 'Probe move finished without making contact'" if lcnc
                   else "grbl stops with ALARM:5 (probe fail)")
        self._note_once("probe", f"{name}: probe moves are timed to their target (where contact happens is not "
                                 f"known); without contact G38.2 / G38.4 {failure}, G38.3 / G38.5 go on")
        self._exact_feed_row(target, float(self.st[S.S_FEED]) * float(self.st[S.S_SPEED_F]), name)
        # the interpreter reads the probed position back before the next line (LinuxCNC's probe_flag sync,
        # grbl's mc_probe_cycle waits for the cycle to end): the queue empties after it too
        self._wait(name)

    def _synced_feed(self, name: str, params: dict[str, Word], used: set[str]) -> float:
        """mm/s of a spindle-synchronised move: K (distance per revolution) × S (rpm) / 60; LinuxCNC's
        errors for a missing K, an F on the line, a spindle that does not turn."""
        used.update("K")
        if "F" in params:
            self.error(f"{name}: F word used with a G33/G33.1 (the feed follows from K and S)")
        k = self._value(params, "K")
        if k is None:
            self.error(f"{name}: K word missing (distance per spindle revolution)")
        if self.spindle_dir not in (3, 4):
            self.error(f"{name}: spindle not turning (M3 or M4 must be in force)")
        if not k > 0.0 or not self.spindle_rpm > 0.0:
            self.error(f"{name}: K and the spindle speed S must be > 0")
        return k * float(self.st[S.S_UNIT]) * self.spindle_rpm / 60.0

    def _spindle_synced(self, params: dict[str, Word], used: set[str]) -> None:
        """G33 X Y Z K: a straight feed move at K·S/60 that waits for the spindle index (starts from rest)
        and ends at its end point; the axes' limits cap the speed as the planner applies them."""
        feed_v = self._synced_feed("G33", params, used)
        used.update("XYZ")
        self._exact_feed_row(self._targets(params, False), feed_v, "G33")

    def _rigid_tap(self, params: dict[str, Word], used: set[str]) -> None:
        """G33.1 X Y Z K [I]: in to the end point at K·S/60, back to the start at K·S·I/60 (I < 1 is 1). The
        spindle's reversal overrun past each end depends on the spindle's deceleration: not modelled
        (named warning)."""
        feed_v = self._synced_feed("G33.1", params, used)
        used.update("XYZI")
        i = self._value(params, "I")
        back_v = feed_v * max(1.0, i if i is not None else 1.0)
        start = [float(self.st[S.S_X + a]) for a in range(3)]
        self._exact_feed_row(self._targets(params, False), feed_v, "G33.1")
        self._exact_feed_row(start, back_v, "G33.1")
        self._note_once("G33.1", "G33.1: rigid tapping is timed in and out at K·S/60 without the spindle's "
                                 "reversal overrun past each end")

    def _threading_cycle(self, params: dict[str, Word], used: set[str]) -> None:
        """G76 P Z I J K [R Q H E L]: LinuxCNC's threading passes (convert_threading_cycle, gcode/cycles.py
        :func:`threading_passes`): rapids back and in, spindle-synchronised cuts at pitch·S/60 from rest,
        the last pass repeated H times, then a rapid to the end of the drive line."""
        from .cycles import CycleError, threading_passes

        st = self.st
        used.update("PZIJKRQHELX")
        if self.plane != 18:
            self.error("G76: the active plane must be the ZX plane (G18)")
        if "X" in params or "Y" in params:
            self.error("G76: X and Y words are not allowed (the drive line is the current X)")
        if self.spindle_dir not in (3, 4):
            self.error("G76: spindle not turning (M3 or M4 must be in force)")
        words = {k: self._value(params, k) for k in "PZIJKRQHEL" if k in params}
        if "P" not in words:
            self.error("G76: P word missing (thread pitch)")
        if not all(k in words for k in "IJK"):
            self.error("G76: I J or K words missing")
        scale = float(st[S.S_UNIT])
        off = [float(st[S.S_OX + a]) for a in range(3)]
        start = [float(st[S.S_X + a]) - off[a] for a in range(3)]
        end_z = self._targets(params, False)[2] - off[2]
        try:
            moves = threading_passes(start[0], start[1], start[2], end_z, words, scale)
        except CycleError as err:
            self.error(f"G76: {err}")
        pitch_mm = words["P"] * scale
        for x, y, z, kind, pitch_ratio in moves:
            target = [x + off[0], y + off[1], z + off[2]]
            if kind == 0:
                self._rapid_row(*target)
            else:
                v = pitch_mm * pitch_ratio * self.spindle_rpm / 60.0
                if not v > 0.0:
                    self.error("G76: the spindle speed S must be > 0")
                # a cut after a rapid waits for the spindle index (from rest); the next cut follows it
                self._exact_feed_row(target, v, "G76", wait=kind == 2)
        self.canned_cycles += 1

    # ------------------------------------------------------------------ M6
    def _cnc_tool_change(self, lcnc: bool) -> None:
        """M6: LinuxCNC waits for the queue to empty, moves to [EMCIO]TOOL_CHANGE_POSITION (machine
        coordinates, as a rapid) when the .ini has one, then changes the tool."""
        tool = self.pending_tool if self.pending_tool is not None else -1
        if lcnc and self.tool_change_position is not None:
            self._rapid_row(*self.tool_change_position)
        self._tool_change(tool)


__all__ = ["Rs274Commands", "KNOWN_G", "GRBL_G", "GRBL_M", "G_GROUPS", "M_GROUPS", "QUIET_G"]
