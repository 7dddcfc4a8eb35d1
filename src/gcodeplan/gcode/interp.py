"""The Python interpreter of G-code lines: every command, every dialect, every error message.

Three modules: this one (modal state, lexing of a line, comments, dispatch), :mod:`.commands_state`
(commands that change the machine's state) and :mod:`.commands_motion` (commands that move or set the
position); :mod:`.lexing` holds the word syntax they share.

The numba scanner (:mod:`.scan`) handles the common lines itself and hands the rest here, one line at a
time, sharing the modal state arrays ``st``/``ist``. This module can also interpret *every* line (the
reader's ``force_python`` mode); the tests check that both give identical MOVE arrays, so the move
arithmetic below repeats the scanner's operation for operation.

Conventions (see also the package docstring):

* MOVE ``e0``/``e1`` are a running machine E: ``G92 E`` changes the logical E only, so ``e1 − e0`` is
  always the commanded extrusion after the M221 flow factor.
* E is relative when G91 or M83 is in force (Klipper's rule: G90 does not undo M83); on Marlin 2 the last of
  G90/G91/M82/M83 decides E (G90/G91 set every axis, E included: Marlin PR #15218).
* Words are ``letter number``; a number is ``[+-]digits[.digits]`` (no exponent: ``E`` is a word letter,
  so ``X1E5`` is X1 E5).
"""
from __future__ import annotations

import math
import re
from collections import deque

import numpy as np

from ..errors import ConfigError, GcodeError, quote
from ..machine import OWN_PLANNER_FIRMWARES, Machine
from ..schema import KIND_EXTRUDE_ONLY, KIND_WAIT, LIMITS_DTYPE
from . import scan as S
from .lexing import (CHECKSUM_RE, EXT_RE, FREE_TEXT_M, FREE_TEXT_RE, HMS_RE, M486_RE, M486_WORD_RE, MAX_EVENTS,
                     MAX_WARNINGS, OBJECT_COMMENT_RE, PLACEHOLDER_RE, QUIET_G, QUIET_M, S3D_LAYER_RE, SEP_OK, WORD_RE,
                     Word, parse_number)
from .ngc import expand_line, needs_expansion
from .objects import KlipperExclude, ObjectTable
from ..marlin_build import MODELLED as BUILD_MODELLED, UNMODELLED as BUILD_UNMODELLED, build_options

from .commands_motion import MotionCommands
from .commands_state import StateCommands
from .grbl_line import GrblLines
from .rs274 import Rs274Commands


#: letters a printer line may start with (after its N line number): G, M and T commands, and the X Y Z E F words
#: read as a repeat of the modal G0/G1 where the firmware does so (CNC flavors; reprap kept so; not
#: UNKNOWN_AXIS_LINE_FLAVORS)
PRINTER_LINE_LETTERS = frozenset("GMTXYZEF")
#: flavors whose firmware answers "Unknown command" to a line led by an axis word (``X10 Y10``, ``E5 F300``) and
#: does nothing: Marlin's parser takes such a letter as a command only with GCODE_MOTION_MODES (off by default:
#: parser.cpp), Klipper's gcode.py takes the first word as the command name ("X10")
UNKNOWN_AXIS_LINE_FLAVORS = frozenset(("marlin", "klipper"))
#: CNC G codes (by their whole number: G59.1 is G59) a printer firmware has not, per flavor. Marlin 2.1's default
#: build (gcode.cpp's dispatch): G17-G19 need CNC_WORKSPACE_PLANES, G20 INCH_MODE_SUPPORT, G53-G59
#: CNC_COORDINATE_SYSTEMS, G60/G61 SAVED_POSITIONS (and mean saved positions there), G80 GCODE_MOTION_MODES, all off
#: by default; G40, G43, G49, G64, G73, G81-G89, G93, G94, G98, G99 it has in no build; without a subcode feature its
#: parser drops the ".1" of G59.1. Klipper (klippy/gcode.py, extras/gcode_move.py, gcode_arcs.py) registers
#: none of them (G17-G19 come with [gcode_arcs]; G20 is an error there, see PRINTER_G20_ERROR). The firmware
#: answers "Unknown command" to a line led by one and does nothing; later on a line it is a parameter of the
#: line's command, which reads no G parameter. A Marlin machine's ``marlin_build`` switches add some back
#: (gcodeplan/marlin_build.py: Interpreter._init_build).
PRINTER_CNC_G = {
    "marlin": frozenset((17, 18, 19, 20, 40, 43, 49, 53, 54, 55, 56, 57, 58, 59, 61, 64, 73, 80, 81, 82, 83, 84,
                         85, 86, 87, 88, 89, 93, 94, 98, 99)),
    "klipper": frozenset((20, 40, 43, 49, 53, 54, 55, 56, 57, 58, 59, 61, 64, 73, 80, 81, 82, 83, 84, 85, 86, 87,
                          88, 89, 93, 94, 98, 99)),
}
#: flavors whose firmware runs a line's first command only, the rest of the line being its parameters (Marlin's
#: parser.cpp GCodeParser::parse, Klipper's gcode.py _process_commands): ``G90 G1 X50`` is G90 alone, no move
ONE_COMMAND_FLAVORS = frozenset(("marlin", "klipper"))
#: Klipper's answer to G20 (gcode_move.py cmd_G20 raises it): an error, which ends a virtual_sdcard print
PRINTER_G20_ERROR = "Machine does not support G20 (inches) command"

class Interpreter(StateCommands, MotionCommands, Rs274Commands, GrblLines):
    """Modal state and the Python side of the interpretation of a file."""

    def __init__(self, machine: Machine, path: str, strict: bool = False):
        self.machine = machine
        self.path = path
        self.strict = strict
        m = machine
        self.dialect = (S.DIALECT_KLIPPER if m.flavor == "klipper" else
                        S.DIALECT_CNC if m.is_cnc else S.DIALECT_MARLIN)
        self._init_build(m)
        self.st, self.ist = self._power_up_state(m)
        #: Marlin clamps a target to its software endstops (apply_motion_limits) where Klipper refuses the move
        self.soft_endstops = (m.flavor == "marlin" and m.kinematics in ("cartesian", "corexy", "corexz")
                              and any(math.isfinite(self.st[S.S_SOFT_LO + a]) or
                                      math.isfinite(self.st[S.S_SOFT_HI + a]) for a in range(3)))
        self.ist[S.I_SOFT_CLAMP] = 1 if self.soft_endstops else 0
        self.soft_clamped = 0               # moves (and arc chords) clamped to them
        self.soft_clamped_first_line: int | None = None
        self._init_labels(m)
        self._init_offsets()
        self._init_summary(machine)
        self.line = 0
        # RS274NGC program language (gcode/ngc.py): made by the first line that needs it
        self.ngc = None
        self._ngc_on = m.flavor == "linuxcnc"
        self._cnc_init()

    def _init_build(self, m: Machine) -> None:
        """The CNC G codes this printer's firmware lacks (PRINTER_CNC_G less those a Marlin build's switches add,
        marlin_build.py) and the codes refused by name (a switch whose codes gcodeplan does not model)."""
        try:
            build = build_options(m.marlin_build) if m.flavor == "marlin" else frozenset()
        except ValueError as err:           # a Machine made in Python (a TOML's is checked on loading)
            raise ConfigError(f"marlin_build: {err}") from None
        added = {g for name in build if name in BUILD_MODELLED for g in BUILD_MODELLED[name][0]}
        self._printer_cnc_g = PRINTER_CNC_G.get(m.flavor, frozenset()) - added
        self._build_refused = {g: (name, BUILD_UNMODELLED[name][1]) for name in build if name in BUILD_UNMODELLED
                               for g in BUILD_UNMODELLED[name][0]}
        #: Marlin's GCODE_MOTION_MODES: a line led by an axis word repeats the last G0-G3 (none at power-up)
        self._motion_modes = "GCODE_MOTION_MODES" in build

    def _power_up_state(self, m: Machine) -> tuple[np.ndarray, np.ndarray]:
        """The modal state arrays ``st`` / ``ist`` (scan.py's indices) as the firmware powers up: feed,
        factors, accelerations (mm/s²), absolute modes, the modal motion, software endstops (mm)."""
        st = np.zeros(S.N_ST)
        ist = np.zeros(S.N_IST, dtype=np.int64)
        st[S.S_FEED] = 25.0                 # Klipper's and Marlin's initial 1500 mm/min
        if m.flavor == "grbl":
            st[S.S_FEED] = 0.0              # grbl's feed is undefined until an F (a feed move before: error:22)
        st[S.S_SPEED_F] = 1.0
        st[S.S_FLOW_F] = 1.0
        st[S.S_UNIT] = 1.0
        if self.dialect == S.DIALECT_MARLIN:
            st[S.S_ACC_P] = m.max_accel if m.accel_print is None else m.accel_print
            st[S.S_ACC_T] = m.max_accel if m.accel_travel is None else m.accel_travel
            st[S.S_ACC_R] = m.max_accel if m.accel_retract is None else m.accel_retract
        else:
            st[S.S_ACC_P] = st[S.S_ACC_T] = st[S.S_ACC_R] = m.max_accel
        st[S.S_BLEND_P] = math.nan
        st[S.S_MAXZ] = -math.inf
        ist[S.I_ABS_COORD] = 1
        ist[S.I_ABS_E] = 1
        ist[S.I_F32_REL] = 1 if m.firmware.startswith("marlin") else 0
        # modal motion at start: grbl powers up in G0, LinuxCNC with no motion mode (G80), printers in G1
        ist[S.I_MOTION] = {"grbl": 0, "linuxcnc": 80}.get(m.flavor, 1)
        if self._motion_modes:
            ist[S.I_MOTION] = 80           # parser.cpp: motion_mode_codenum = -1 until a G0-G3
        # a line led by an axis word: a modal G0/G1 on CNC controls (and reprap, as before), an unknown command on
        # Marlin (without GCODE_MOTION_MODES, its default) and Klipper (see PRINTER_LINE_LETTERS)
        ist[S.I_AXIS_LINES] = 0 if m.flavor in UNKNOWN_AXIS_LINE_FLAVORS and not self._motion_modes else 1
        ist[S.I_DIALECT] = self.dialect
        ist[S.I_LAYER] = -1
        ist[S.I_FEATURE] = -1
        ist[S.I_LAYER_BY_Z] = 1
        ist[S.I_G90_SETS_E] = 1 if m.flavor == "marlin" else 0
        ist[S.I_OBJECT] = -1
        st[S.S_MAX_E] = -math.inf
        for a, k in enumerate("xyz"):
            st[S.S_SOFT_LO + a] = m.axes[k].position_min
            st[S.S_SOFT_HI + a] = m.axes[k].position_max
        return st, ist

    def _init_labels(self, m: Machine) -> None:
        """Feature names (;TYPE:), layers, objects, the time the G-code does not show (machine [time]: the
        start time, macros), the planner limits rows."""
        self.feat_raw = np.zeros((S.FEAT_MAX, S.FEAT_NAME_MAX), dtype=np.uint8)
        self.feat_len = np.zeros(S.FEAT_MAX, dtype=np.int64)
        self.feat_idx = np.zeros(S.FEAT_MAX, dtype=np.int64)
        self.features: list[str] = []
        self.layer_z: list[float] = []
        # objects (gcode/objects.py): names, the exclude_object transform when objects are cancelled
        self.objects = ObjectTable()
        self.exclude: KlipperExclude | None = None
        self._m486_idx: dict[int, int] = {}          # M486 object number -> object index
        # time the G-code does not show (machine [time]): waits by name (s), current tool
        self.wait_time_s: dict[str, float] = {}
        self.tool = 0
        self._macros = {str(k).upper(): float(v) for k, v in getattr(m, "macros", {}).items()}
        self._start_pending = getattr(m, "start_time", 0.0) > 0.0
        if self._start_pending:
            self.ist[S.I_TO_PYTHON] = 1       # the first line comes here, to put the start wait before it
        self._limits_rows: list[np.ndarray] = [m.limits_row()[0].copy()]

    def _init_offsets(self) -> None:
        """Offsets (mm) at power-up: 9 work systems G54..G59.3, G92, tool length (Z); plane, arc centre
        mode, canned-cycle and firmware-retraction state."""
        self.work = np.zeros((9, 3))
        self.work_index = 0
        self.g92 = np.zeros(3)
        self.g92_saved = np.zeros(3)
        self.tool_z = 0.0
        self.plane = 17
        self.arc_abs_centre = False        # G90.1 (absolute IJK) / G91.1 (incremental, the default)
        self.retract_mode = 98
        self.cycle_state = None
        self.retracted = False             # firmware retraction (G10/G11)
        self.percent_seen = 0

    def _init_summary(self, machine: Machine) -> None:
        """The rows a line makes, and the summary material: counts, waits, events, warnings."""
        self.rows: list[tuple] = []        # rows made by the current Python line
        self.row_arrays: list[np.ndarray] = []   # rows in bulk (arc chords, cycles), in order with rows
        self.unknown: dict[str, int] = {}
        self.ignored: dict[str, int] = {}
        self.waits: dict[str, int] = {}
        self.events: list[tuple[int, str]] = []
        # (line, logical E in mm) of each "G92 E": a firmware model (planner/marlin.py) takes them in order, as
        # Marlin resets its E position there; kept only for such machines, and emptied as they are used
        self.e_position_sets: deque[tuple[int, float]] = deque()
        #: True when ``e_position_sets`` is kept (a firmware model that plans on its own, e.g. Marlin's, reads it)
        self.keeps_e_sets: bool = getattr(machine, "firmware", "generic") in OWN_PLANNER_FIRMWARES
        self.warnings: list[str] = []
        self.warning_count = 0
        self.arcs = 0
        self.canned_cycles = 0
        self.spindle_commands = 0
        self.tool_changes = 0
        self.skipped_lines = 0
        self.g64_q_ignored = 0
        self.header_layer_count: int | None = None
        self.slicer_estimate_s: float | None = None

    # ------------------------------------------------------------------ helpers
    @property
    def limits(self) -> np.ndarray:
        return np.array(self._limits_rows, dtype=LIMITS_DTYPE)

    def error(self, msg: str):
        raise GcodeError(msg, self.path, self.line)

    def warn(self, msg: str) -> None:
        self.warning_count += 1
        if len(self.warnings) < MAX_WARNINGS:
            self.warnings.append(f"{self.path}:{self.line}: {msg}")

    def event(self, text: str) -> None:
        if len(self.events) < MAX_EVENTS:
            self.events.append((self.line, text))

    def unknown_command(self, name: str) -> None:
        if self.strict:
            self.error(f"unknown command {name}")
        name = quote(name)      # counted under at most 40 characters: a 1 MiB name is not kept whole
        self.unknown[name] = self.unknown.get(name, 0) + 1

    def ignore(self, name: str) -> None:
        self.ignored[name] = self.ignored.get(name, 0) + 1

    def _row(self, kind, flags, x0, y0, z0, e0, x1, y1, z1, e1, move_d, feed_v, accel, dwell_t):
        st, ist = self.st, self.ist
        self.rows.append((self.line, kind, flags, int(ist[S.I_FEATURE]), int(ist[S.I_LAYER]),
                          int(ist[S.I_LIMITS]), x0, y0, z0, e0, x1, y1, z1, e1, move_d, feed_v, accel,
                          dwell_t, float(st[S.S_BLEND_P]), int(ist[S.I_EXACT_STOP]), float(st[S.S_BLEND_Q]),
                          int(ist[S.I_OBJECT])))

    def _flush_rows_to_arrays(self) -> None:
        if self.rows:
            from ..schema import MOVE_DTYPE
            self.row_arrays.append(np.array(self.rows, dtype=MOVE_DTYPE))
            self.rows = []

    def take_rows(self) -> list[np.ndarray]:
        """The rows made since the last call, as MOVE arrays in file order."""
        self._flush_rows_to_arrays()
        out, self.row_arrays = self.row_arrays, []
        if self.exclude is not None:
            out = self._exclude_rows(out)
        return out

    # ------------------------------------------------------------------ objects
    def exclude_objects(self, names) -> None:
        """Plan the print with the objects ``names`` cancelled, as Klipper's exclude_object runs it."""
        names = [str(n) for n in names]
        if not names:
            return
        if self.exclude is None:
            self.exclude = KlipperExclude(names)
        else:
            for n in names:
                self.exclude.wanted.setdefault(n.casefold(), n)
        for i, name in enumerate(self.objects.names):
            self.exclude.register(name, i)

    def check_excluded(self) -> None:
        """After the whole file: an excluded name the file never labelled is an error, not a no-op."""
        missing = self.exclude.missing() if self.exclude is not None else []
        if missing:
            known = ", ".join(repr(n) for n in self.objects.names) or "none"
            raise GcodeError(f"--exclude-object: no object named {', '.join(repr(n) for n in missing)} "
                             f"in this file (objects: {known})", self.path)

    def _set_object(self, name: str | None) -> int:
        """Enter the object ``name`` (None: outside any object); returns its index (-1 for None)."""
        idx = -1
        if name is not None:
            try:
                idx = self.objects.index(name)
            except ValueError:
                self.error("too many object names")
            if self.exclude is not None:
                self.exclude.register(self.objects.names[idx], idx)
        self.ist[S.I_OBJECT] = idx
        self._exclude_wake()
        return idx

    def _exclude_wake(self) -> None:
        """Send lines through the transform from now on if the current object is cancelled."""
        xf, st = self.exclude, self.st
        if xf is None or xf.active or int(self.ist[S.I_OBJECT]) not in xf.excluded_idx:
            return
        xf.activate(float(st[S.S_X]), float(st[S.S_Y]), float(st[S.S_Z]), float(st[S.S_E]), float(st[S.S_MAX_E]))
        self.ist[S.I_TO_PYTHON] = 1

    def _exclude_rows(self, out: list[np.ndarray]) -> list[np.ndarray]:
        xf, st = self.exclude, self.st
        if not xf.active:
            # dormant: only keep Klipper's max_position_extruded up to date (the scanner does the same)
            for a in out:
                mv = a["e1"][a["kind"] <= KIND_EXTRUDE_ONLY]
                if mv.size:
                    st[S.S_MAX_E] = max(float(st[S.S_MAX_E]), float(mv.max()))
            return out
        res = [xf.apply(a, self._accel) for a in out]
        st[S.S_E] = xf.toolhead_e()
        if xf.can_sleep(int(self.ist[S.I_OBJECT])):
            xf.active = False
            st[S.S_MAX_E] = -math.inf
            self.ist[S.I_TO_PYTHON] = 0
        return [a for a in res if len(a)]

    def _m486(self, args: str) -> None:
        """Marlin's object labels: ``M486 S<n>`` enters object n (-1: none), ``A<name>`` names it."""
        words = {}
        body = args.split(";", 1)[0].strip()
        if body[:1] in ("A", "a"):
            words["A"] = body[1:].strip().strip("\"'")    # PrusaSlicer: "M486 A<name>", the name may hold blanks
        else:
            for m in M486_WORD_RE.finditer(body):
                words[m.group(1).upper()] = m.group(2).strip("\"'")
        n = None
        if "S" in words:
            try:
                n = int(float(words["S"]))
            except (ValueError, OverflowError):     # OverflowError: S-inf / Sinf (found by tools/fuzz.py)
                self.error(f"M486 S needs an object number, got {words['S']!r}")
            if n < 0:
                self._set_object(None)
                n = None
            else:
                if n not in self._m486_idx:
                    self._m486_idx[n] = self.objects.index(str(n))
                self._set_object(self.objects.names[self._m486_idx[n]])
        if words.get("A"):
            idx = self._m486_idx.get(n) if n is not None else int(self.ist[S.I_OBJECT])
            if idx is not None and idx >= 0:
                name = words["A"]
                self.objects.names[idx] = name
                self.objects._index[name.casefold()] = idx
                if self.exclude is not None:
                    self.exclude.register(name, idx)
                self._exclude_wake()

    def _stop_row(self, kind: int, flags: int, dwell_t: float) -> None:
        st = self.st
        x, y, z, e = float(st[S.S_X]), float(st[S.S_Y]), float(st[S.S_Z]), float(st[S.S_E])
        self._row(kind, flags, x, y, z, e, x, y, z, e, 0.0, 0.0, 0.0, dwell_t)

    def _wait(self, name: str, dwell_t: float = 0.0, flags: int = 0) -> None:
        self.waits[name] = self.waits.get(name, 0) + 1
        if dwell_t > 0.0:
            self.wait_time_s[name] = self.wait_time_s.get(name, 0.0) + dwell_t
        self._stop_row(KIND_WAIT, flags, dwell_t)

    def _update_offsets(self) -> None:
        off = self.work[self.work_index] + self.g92
        self.st[S.S_OX] = off[0]
        self.st[S.S_OY] = off[1]
        self.st[S.S_OZ] = off[2] + self.tool_z

    def _offset(self, axis: int) -> float:
        return float(self.st[S.S_OX + axis])

    def _new_limits(self, **changes: float) -> None:
        cur = self._limits_rows[int(self.ist[S.I_LIMITS])]
        new = cur.copy()
        for k, v in changes.items():
            new[k] = v
        if new.tobytes() == cur.tobytes():
            return
        self._limits_rows.append(new)
        self.ist[S.I_LIMITS] = len(self._limits_rows) - 1

    def _feature(self, raw: bytes) -> None:
        raw = raw.rstrip(b"\r \t")
        name = raw.decode("utf-8", "replace").strip().lower()
        if name in self.features:
            idx = self.features.index(name)
        else:
            if len(self.features) >= 32000:
                self.error("too many feature names")
            self.features.append(name)
            idx = len(self.features) - 1
        n = int(self.ist[S.I_NFEAT])
        if len(raw) <= S.FEAT_NAME_MAX and n < S.FEAT_MAX:
            self.feat_raw[n, :len(raw)] = np.frombuffer(raw, dtype=np.uint8)
            self.feat_len[n] = len(raw)
            self.feat_idx[n] = idx
            self.ist[S.I_NFEAT] = n + 1
        self.ist[S.I_FEATURE] = idx

    def _new_layer(self, z: float = math.nan) -> None:
        self.ist[S.I_LAYER] += 1
        self.layer_z.append(z)
        self.ist[S.I_LAYER_Z_TODO] = 1 if math.isnan(z) else 0

    # ------------------------------------------------------------------ entry point
    def handle(self, raw: bytes, lineno: int) -> None:
        """Interpret one line (bytes without the newline). Rows go to :meth:`take_rows`."""
        self.line = lineno
        if self._start_pending:
            # the machine's fixed start time ([time] start_time), a wait before the first line
            self._start_pending = False
            self._wait("start", float(self.machine.start_time))
            self.ist[S.I_TO_PYTHON] = 1 if (self.exclude is not None and self.exclude.active) else 0
        if self.ist[S.I_STOPPED]:
            return
        text = raw.decode("utf-8", "replace").strip()
        if self._ngc_on and (self.ngc is not None or needs_expansion(text)):
            expand_line(self, text, lineno)     # O-words, parameters, expressions: gcode/ngc.py
            return
        self._handle_text(raw, text)

    def _handle_text(self, raw: bytes, text: str) -> None:
        """Interpret one line's text (``raw``: its bytes, for whole-line comments)."""
        if not text:
            return
        if text[0] == ";":
            self._comment(raw.lstrip(b" \t\r")[1:])
            return
        if text[0] == "%":
            self.percent_seen += 1
            if self.percent_seen >= 2 and self.machine.is_cnc:
                self.event("% program end")
                self.ist[S.I_STOPPED] = 1
            return
        if self._grbl_reads:
            # grbl's own reading first: its line buffer, its lexer, its $ lines (grbl_line.py)
            text = self.grbl_line(raw)
            if text is None:
                return
        elif text[0] == "$":
            # grbl system commands ($H homing, $X unlock, $$ settings) on another flavor: unknown
            self.unknown_command(text.split()[0][:12])
            return
        code, paren = self._strip_comments(text)
        if "\x00" in code:
            self.error("binary data (NUL byte) in a G-code line")
        for c in paren:
            if c[:4].upper() == "MSG,":
                self.event("MSG " + c[4:].strip())
        code = code.strip()
        if not code:
            return
        m = CHECKSUM_RE.search(code)
        if "*" in code:
            if not m:
                self.error("malformed checksum (expected '*<number>' at the end of the line)")
            body = code[:m.start()]
            star = text.index("*")
            want = int(m.group(1))
            got = 0
            for ch in text[:star].encode("utf-8", "replace"):
                got ^= ch
            if got != want:
                self.error(f"checksum mismatch: line says {want}, computed {got}")
            code = body.strip()
        if code[:1] in "Nn" and len(code) > 1 and (code[1].isdigit() or code[1] in " \t"):
            mm = re.match(r"[Nn]\s*\d+", code)
            if mm:
                code = code[mm.end():].strip()
                if not code:
                    return
        if "{" in code:
            ph = PLACEHOLDER_RE.search(code).group(0)
            msg = f"unexpanded slicer placeholder '{ph}': line skipped"
            if self.strict:
                self.error(msg)
            self.warn(msg)
            self.skipped_lines += 1
            return
        m = EXT_RE.match(code)
        if m and not self._is_classic(code):
            self._extended(m.group(1), m.group(2))
            return
        self._classic(code)

    @staticmethod
    def _is_classic(code: str) -> bool:
        """``G1 X2``, ``x1 y2``, ``T0``, ``M117 hi``: a letter then a number (or a bare letter)."""
        if not code[0].isalpha():
            return False
        rest = code[1:].lstrip()
        if not rest:
            return True
        return rest[0].isdigit() or rest[0] in "+-."

    def _strip_comments(self, text: str) -> tuple[str, list[str]]:
        if "(" not in text and ";" not in text:
            if ")" in text:
                self.error("unmatched ')'")
            return text, []
        out = []
        comments = []
        i = 0
        n = len(text)
        while i < n:
            ch = text[i]
            if ch == ";":
                break
            if ch == "(":
                j = text.find(")", i + 1)
                if j < 0:
                    self.error("unclosed '(' comment")
                comments.append(text[i + 1:j])
                out.append(" ")
                i = j + 1
                continue
            if ch == ")":
                self.error("unmatched ')'")
            out.append(ch)
            i += 1
        return "".join(out), comments

    # ------------------------------------------------------------------ comments
    def _comment(self, body: bytes) -> None:
        """``body`` is the text after the ';' of a whole-line comment."""
        if body.startswith(b"TYPE:"):
            self._feature(body[5:])
        elif body.startswith(b"LAYER_CHANGE"):
            self.ist[S.I_LAYER_BY_Z] = 0
            self._new_layer()
        elif body.startswith(b"LAYER_COUNT:"):
            try:
                self.header_layer_count = int(body[12:].strip())
            except ValueError:
                self.warn("unreadable ;LAYER_COUNT: comment")
        elif body.startswith(b"LAYER:"):
            self.ist[S.I_LAYER_BY_Z] = 0
            self._new_layer()
        elif body.startswith(b"Z:"):
            try:
                z = float(body[2:].strip())
            except ValueError:
                return
            layer = int(self.ist[S.I_LAYER])
            if layer >= 0 and math.isnan(self.layer_z[layer]) and math.isfinite(z):
                self.layer_z[layer] = z
                self.ist[S.I_LAYER_Z_TODO] = 0
        elif body.startswith(b"TIME:"):
            if self.slicer_estimate_s is None:
                try:
                    self.slicer_estimate_s = float(body[5:].strip())
                except ValueError:
                    pass
        elif body.startswith(b" estimated printing time"):
            txt = body.decode("utf-8", "replace")
            if self.slicer_estimate_s is None and "=" in txt and ("normal" in txt or "(" not in txt):
                hms = txt.split("=", 1)[1].strip()
                m = HMS_RE.fullmatch(hms)
                if m and any(m.groups()):
                    d, h, mi, s = (int(g) if g else 0 for g in m.groups())
                    self.slicer_estimate_s = float(((d * 24 + h) * 60 + mi) * 60 + s)
        elif body.startswith(b" layer"):
            m = S3D_LAYER_RE.match(body.decode("utf-8", "replace"))
            if m:
                self.ist[S.I_LAYER_BY_Z] = 0
                z = float(m.group(2)) if m.group(2) else math.nan
                self._new_layer(z)
        elif body.startswith(b" feature"):
            self._feature(body[8:].strip())
        elif body.startswith(b"MESH:"):
            name = body[5:].decode("utf-8", "replace").strip()
            self._set_object(None if name in ("NONMESH", "") else name)
        elif body.startswith((b" printing object", b" stop printing object")):
            m = OBJECT_COMMENT_RE.match(body)
            stop, name = m.group(1), m.group(2).decode("utf-8", "replace").strip()
            self._set_object(None if stop or not name else name)

    # ------------------------------------------------------------------ classic words
    def _words(self, code: str) -> list[Word]:
        words = []
        pos = 0
        n = len(code)
        while pos < n:
            m = WORD_RE.match(code, pos)
            if not m:
                if code[pos:].strip() == "":
                    break
                self.error(f"unexpected text {code[pos:].strip()[:20]!r}")
            letter = m.group(1).upper()
            num = m.group(2)
            end = m.end()
            if end < n and not SEP_OK.match(code, end):
                bad = code[m.start(1):].split()[0][:20]
                self.error(f"malformed number in {bad!r}")
            if num is None:
                words.append(Word(letter, None, ""))
            else:
                words.append(Word(letter, parse_number(num, letter, self), num))
            pos = end
        return words

    def _classic(self, code: str) -> None:
        if not self.machine.is_cnc and code[:1].upper() not in PRINTER_LINE_LETTERS:
            # Marlin's and Klipper's parsers take a line's first word as its command: a line led by another
            # letter (a CNC post's ``O100 call``, ``O100 sub``) is an unknown command, reported and ignored
            self._unknown_or_macro(code.split(None, 1)[0][:40].upper())
            return
        if code[:1].upper() in "XYZEF" and (not self.ist[S.I_AXIS_LINES] or (self._motion_modes and
                                                                            self.ist[S.I_MOTION] == 80)):
            self._axis_led_line(code)       # Marlin with GCODE_MOTION_MODES: no motion mode yet, or after G80
            return
        m486 = None if self._grbl_reads else M486_RE.match(code)
        if m486:
            self._m486(m486.group(1))
            return
        head = None if self._grbl_reads else FREE_TEXT_RE.match(code)     # grbl: M117 … is its error:20
        # M30 takes a file name on printers (delete an SD file) but ends the program on CNC flavors
        if head and int(head.group(1)) in FREE_TEXT_M and not (self.machine.is_cnc and int(head.group(1)) == 30):
            return
        try_words_error = None
        try:
            words = self._words(code)
        except GcodeError as err:
            words = None
            try_words_error = err
        if words is None:
            # an unknown M/G command with free text (M117 Hello 1.2.3) is not ours to validate
            m = re.match(r"([MmGg])\s*(\d{1,9})(?!\d)", code)     # longer: not a command number
            if m:
                name = f"{m.group(1).upper()}{int(m.group(2))}"
                num = int(m.group(2))
                if m.group(1) in "Mm" and (num in QUIET_M or (num in FREE_TEXT_M and not (
                        self.machine.is_cnc and num == 30))):
                    return
                if not self._known(m.group(1).upper(), num):
                    self._unknown_or_macro(name)
                    return
            raise try_words_error

        if self._build_refused:
            self._refuse_build_code(words)
        if self.machine.flavor in PRINTER_CNC_G:
            words = self._printer_cnc_words(words)
            if words is None:
                return
        if self.machine.flavor in ONE_COMMAND_FLAVORS:
            words = self._printer_one_command(words)
        gs: list[float] = []
        ms: list[int] = []
        params: dict[str, Word] = {}
        tool = None
        grbl = self._grbl_reads      # grbl checks the words in their order (grbl_line.py, rs274.py)
        for w in words:
            if w.letter == "G":
                if w.value is None:
                    self.error("G needs a number")
                gs.append(round(w.value, 1))
            elif w.letter == "M":
                if w.value is None:
                    self.error("M needs a number")
                if w.value != int(w.value) and not grbl:
                    self.unknown_command(f"M{w.text}")
                    return
                ms.append(int(w.value))
            elif w.letter == "T" and not ms:
                tool = w
                params["T"] = w
            else:
                if w.letter in params:
                    if grbl:
                        continue     # grbl's error:25, found in its order
                    self.error(f"word {w.letter} repeated")
                params[w.letter] = w
        self._execute(gs, ms, params, tool)

    def _printer_cnc_words(self, words: list[Word]) -> list[Word] | None:
        """The words of a line on Marlin or Klipper as the firmware reads its CNC G codes (PRINTER_CNC_G): a line
        led by one is an unknown command that does nothing, its axis words included (None returned); Klipper's G20
        is an error naming its answer; a CNC G code after the line's command is a parameter the command does not
        read, dropped from the words returned. One named warning per code and file."""
        flavor = self.machine.flavor
        cnc = self._printer_cnc_g
        firmware = "Klipper" if flavor == "klipper" else "Marlin"
        first = words[0] if words else None
        if first is not None and first.letter == "G" and first.value is not None and int(first.value) in cnc:
            name = f"G{round(first.value, 1):g}"
            if flavor == "klipper" and int(first.value) == 20:
                self.error(f"{name}: Klipper answers '{PRINTER_G20_ERROR}', an error, which stops a print from "
                           "its virtual SD card (a printer's program must be in mm; a CNC program needs a CNC "
                           "--machine or --flavor)")
            who = "Marlin's default build" if flavor == "marlin" else firmware
            self._note_once(f"printer-cnc {name}", f"{name}: a CNC command {who} does not have: it answers 'Unknown "
                            "command' and the line does nothing, its axis words included (each such line is "
                            "counted as an unknown command)")
            self._unknown_or_macro(name)
            return None
        kept = [words[0]] if words else []
        for w in words[1:]:
            if w.letter == "G" and w.value is not None and int(w.value) in cnc:
                name = f"G{round(w.value, 1):g}"
                self._note_once(f"printer-cnc-param {name}", f"{name} after the line's command: {firmware} reads it "
                                "as a parameter of that command, which ignores it: G-code ignored")
                continue
            kept.append(w)
        return kept

    def _refuse_build_code(self, words: list[Word]) -> None:
        """A line led by a G code a Marlin build's switch adds and gcodeplan does not model: an error naming the
        switch (marlin_build.py UNMODELLED)."""
        first = words[0] if words else None
        if first is None or first.letter != "G" or first.value is None or int(first.value) not in self._build_refused:
            return
        name, why = self._build_refused[int(first.value)]
        self.error(f"G{round(first.value, 1):g}: this Marlin build has {name} (marlin_build): {why}")

    def _printer_one_command(self, words: list[Word]) -> list[Word]:
        """The words of a Marlin or Klipper line as its firmware runs them: the first G/M/T word is the command
        and every later word its parameter (Marlin's parser.cpp GCodeParser::parse, Klipper's gcode.py
        _process_commands). A later G or M word (or a T word after a G or T command, which none of them reads)
        is a parameter the command does not read: dropped, counted, one named warning per file. A letter given
        twice on such a line keeps its last value, as both parsers store parameters (Marlin's
        FASTER_GCODE_PARSER, on by default, keeps the last offset per letter; Klipper's params dict the last
        value); a line of one command keeps gcodeplan's "word repeated" error."""
        if len(words) < 2:
            return words
        first = words[0]
        reads_t = first.letter == "M"           # M104 T1, M109 T0: the M code's own parameter
        extra = [i for i, w in enumerate(words) if i and (w.letter in "GM" or (w.letter == "T" and not reads_t))]
        if not extra:
            return words
        firmware = "Klipper" if self.machine.flavor == "klipper" else "Marlin"
        command = f"{first.letter}{first.text}"
        rest = " ".join(f"{w.letter}{w.text}" for w in words[extra[0]:])
        self._note_once("one command per line", f"{firmware} runs {command} only; {rest} are its parameters (a "
                        "printer's firmware runs a line's first command alone: each later command is counted as "
                        "ignored)")
        kept: dict[str, Word] = {}
        for i, w in enumerate(words[1:], 1):
            if i in extra:
                self.ignore(f"{w.letter}{w.text} after a line's command")
                continue
            kept.pop(w.letter, None)                 # the last value wins, in the order of the line
            kept[w.letter] = w
        return [first, *kept.values()]

    def _axis_led_line(self, code: str) -> None:
        """A line led by an axis or F word (``X10 Y10``, ``E5 F300``) on Marlin or Klipper: no modal G1 there
        (Marlin's parser takes it as a command only with GCODE_MOTION_MODES, off by default; Klipper's takes
        "X10" as the command's name): the firmware answers "Unknown command" and the line does nothing. One
        named warning per file, each line counted as an unknown command (an error under ``--strict``)."""
        head = code.split(None, 1)[0][:40].upper()
        if head in self._macros:         # a [time] macro of that name (the scanner never sees such lines)
            self._unknown_or_macro(head)
            return
        firmware = "Klipper" if self.machine.flavor == "klipper" else "Marlin"
        if self.strict:
            self.error(f"unknown command {head}: a line without G is no move on {firmware} "
                       f"('Unknown command')")
        why = ("no motion mode in force: none since power-up or G80, GCODE_MOTION_MODES" if self._motion_modes
               else "no modal G1 there")
        self._note_once("axis-led line", f"{code[:40]}: {firmware} answers 'Unknown command' to a line led by "
                                         f"{code[:1].upper()} ({why}): the line does nothing (each such "
                                         f"line is counted as an unknown command)")
        name = f"{code[:1].upper()}... without G"
        self.unknown[name] = self.unknown.get(name, 0) + 1

    def _known(self, letter: str, num: int) -> bool:
        if letter == "M":
            return num in (0, 1, 2, 30, 60, 3, 4, 5, 6, 82, 83, 109, 190, 191, 116, 400, 201, 203, 204, 205, 220, 221)
        return num in (0, 1, 2, 3, 4, 10, 11, 17, 18, 19, 20, 21, 28, 43, 49, 53, 54, 55, 56, 57, 58, 59,
                       61, 64, 73, 80, 81, 82, 83, 85, 86, 89, 90, 91, 92, 93, 94, 98, 99)

    def _value(self, params: dict[str, Word], letter: str) -> float | None:
        w = params.get(letter)
        if w is None:
            return None
        if w.value is None:
            self.error(f"{letter} needs a number")
        return w.value

    # ------------------------------------------------------------------ execution of one classic line
    def _settings_g(self, gset: set, params: dict[str, Word], used: set[str], scale: float) -> tuple[bool, bool]:
        """The G codes of a line that set modes and offsets rather than move (G4 dwell, planes, tool length,
        work offsets, G61/G64 path control, G90/G91, G98/G99, G10/G11, G28, G92…), before its motion. Returns
        (the axis words were taken by one of them, G53 machine coordinates)."""
        axis_consumed = False       # axis words taken by G10/G28/G43.1/G92 (no motion)
        if 4 in gset:
            self._dwell(params, used)
        self._set_plane(gset)
        if 49 in gset:
            self.tool_z = 0.0
            self._update_offsets()
        if 43 in gset:
            h = self._value(params, "H")
            used.add("H")
            self.warn(f"G43 H{h if h is not None else ''}: no tool table, tool length offset taken as 0")
            self.tool_z = 0.0
            self._update_offsets()
            if self.machine.flavor == "linuxcnc":
                self._wait("G43")      # LinuxCNC's task waits for the motion queue to empty
        if 43.1 in gset:
            z = self._value(params, "Z")
            if z is None:
                self.error("G43.1 needs Z (the tool length offset)")
            used.add("Z")
            axis_consumed = True
            self.tool_z = z * scale
            self._update_offsets()
        # coordinate system, path control, distance modes, retract mode: shared with RS274 (gcode/rs274.py)
        self._modal_modes(gset, params, used, self.machine.flavor == "linuxcnc")
        machine_coords = 53 in gset
        if 10 in gset:
            axis_consumed = self._g10(params, used)
        if 11 in gset:
            self._g11()
        if 28 in gset:
            self._g28(params, used)
            axis_consumed = True
        if 92 in gset:
            self._g92(params, used)
            axis_consumed = True
        self._g92_family(gset)
        return axis_consumed, machine_coords

    def _execute(self, gs: list[float], ms: list[int], params: dict[str, Word], tool: Word | None) -> None:
        if self.dialect == S.DIALECT_CNC:
            self._execute_cnc(gs, ms, params)      # RS274NGC's order of execution (gcode/rs274.py)
            return
        st, ist = self.st, self.ist
        used: set[str] = set()
        motion_codes = [g for g in gs if g in (0, 1, 2, 3, 80) or g in (73, 81, 82, 83, 85, 86, 89)]
        if len(motion_codes) > 1:
            self.error("two motion commands on one line: " + " ".join(f"G{g:g}" for g in motion_codes))
        gset = set(gs)
        for g in gs:
            if g in QUIET_G:
                continue
            if not self._known("G", int(g)) or (g != int(g) and g not in (43.1, 59.1, 59.2, 59.3, 61.1, 90.1,
                                                                           91.1, 92.1, 92.2, 92.3)):
                self._unknown_or_macro(f"G{g:g}")
                gset.discard(g)
        if 93 in gset:
            self.error("G93 inverse-time feed is not supported")
        # units first, so that F and coordinates on the line use them
        if 20 in gset:
            st[S.S_UNIT] = 25.4
        if 21 in gset:
            st[S.S_UNIT] = 1.0
        scale = float(st[S.S_UNIT])
        # Marlin and Klipper read F only on moves: on an M-code line it is that command's parameter (as X Y Z E
        # are, below). CNC controls take F as a modal word on any line.
        f = None
        # Marlin and Klipper: a line's command is its first word, so without a motion G code X Y Z E F are the
        # parameters of whatever command leads it (G90 X50, G21 F600: no move, no feed; G28 and G92 read them)
        params_only = not motion_codes and (bool(ms) or (self.machine.flavor in ONE_COMMAND_FLAVORS
                                                         and (bool(gs) or tool is not None)))
        if params_only and not self.machine.is_cnc:
            used.add("F")
        else:
            f = self._value(params, "F")
        if f is not None:
            used.add("F")
            if not f > 0.0:
                self.error(f"feed rate F must be > 0, got {params['F'].text}")
        # M commands
        for mc in ms:
            self._m_command(mc, params, used)
        if tool is not None and not ms:
            used.add("T")
            if tool.value is None or tool.value != int(tool.value) or tool.value < 0:
                self.error("T needs a tool number")
            if not self.machine.is_cnc:
                self._tool_change(int(tool.value))
        if "S" in params and not ms and 4 not in gset:
            used.add("S")   # laser power / spindle speed (grbl: on a motion line): no motion effect
            self.spindle_commands += 1
        axis_consumed, machine_coords = self._settings_g(gset, params, used, scale)

        # motion
        for g in motion_codes:
            self._set_motion(g)
        # on a line with an M code and no motion G code, X Y Z E are the M code's parameters (M201 X1000)
        axis_consumed = axis_consumed or params_only
        has_axes = any(k in params for k in "XYZE") and not axis_consumed
        motion = int(ist[S.I_MOTION])
        if motion_codes and motion_codes[0] != 80 and not has_axes and motion in (2, 3):
            if any(k in params for k in "IJKR"):
                if not self.machine.firmware.startswith("marlin"):
                    self.error(f"G{motion} needs an end point (X/Y/Z)")
                has_axes = True          # Marlin: G2/G3 I J without X Y is a full circle (G2_G3.cpp)
        if has_axes or (motion in (73, 81, 82, 83, 85, 86, 89) and motion_codes and not axis_consumed):
            if motion == 80:
                self.error("axis words without a motion command (G80 in force)")
            self._motion(motion, params, used, f, machine_coords)
        elif f is not None:
            st[S.S_FEED] = f * scale / 60.0
        self._warn_unused_words(params, used, ms, "XYZEF")
        for mc in ms:
            if mc in (2, 30):
                self.event(f"M{mc} program end")
                if self.machine.is_cnc:
                    ist[S.I_STOPPED] = 1
                else:
                    self.ignore(f"M{mc}")

