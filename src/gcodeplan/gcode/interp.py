"""The Python interpreter of G-code lines: every command, every dialect, every error message.

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
from dataclasses import dataclass

import numpy as np

from ..errors import GcodeError
from ..machine import Machine
from ..schema import (FLAG_ARC, FLAG_CANNED, FLAG_FIRMWARE_RETRACT, FLAG_HOMING, FLAG_RAPID, FLAG_RETRACT,
                      KIND_DWELL, KIND_EXTRUDE_ONLY, KIND_PRINT, KIND_TRAVEL, KIND_WAIT, LIMITS_DTYPE)
from . import scan as S
from .objects import KlipperExclude, ObjectTable

MAX_EVENTS = 200
MAX_WARNINGS = 100

_NUM = r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)"
_WORD_RE = re.compile(r"\s*([A-Za-z])\s*(" + _NUM + r")?")
_SEP_OK = re.compile(r"(?:\s|[A-Za-z]|$)")
_EXT_RE = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)(.*)$", re.S)
_KV_RE = re.compile(r"\s*([A-Za-z_][A-Za-z0-9_]*)\s*=\s*(\"[^\"]*\"|'[^']*'|\S*)")
_PLACEHOLDER_RE = re.compile(r"\{[^}]*\}?")
_CHECKSUM_RE = re.compile(r"\*\s*(\d+)\s*$")
_S3D_LAYER_RE = re.compile(r"\s*layer\s+(-?\d+)(?:\s*,\s*Z\s*=\s*(" + _NUM + r"))?", re.I)
_HMS_RE = re.compile(r"(?:(\d+)d)?\s*(?:(\d+)h)?\s*(?:(\d+)m)?\s*(?:(\d+)s)?")

# no motion, no effect on the plan: accepted quietly. Coolant M7-M9, PSU M80/M81, motors M17/M18/M84,
# progress M73, heaters and fans M104-M107/M140/M141, reports and messages M105/M110-M119, beeper M300,
# bed levelling state M420, objects M486, motor current M907 (linear advance M900 / M572: _pressure_advance)
_QUIET_M = {7, 8, 9, 17, 18, 73, 80, 81, 84, 104, 105, 106, 107, 110, 111, 114, 115, 117, 118, 119, 140, 141,
            300, 420, 486, 907}
# commands whose argument is free text (M23 file name, M117 message...): not tokenised
_FREE_TEXT_M = {23, 28, 30, 32, 117, 118, 550, 929}
_FREE_TEXT_RE = re.compile(r"[Mm]\s*0*(\d{1,4})(?:\s|$)")
_QUIET_G = {40, 94, 98, 99, 17, 18, 19, 20, 21, 49, 80}  # handled below or no effect
# Klipper extended commands with no effect on motion
_QUIET_EXT = {"EXCLUDE_OBJECT_START", "EXCLUDE_OBJECT_END", "EXCLUDE_OBJECT_DEFINE", "SET_PRINT_STATS_INFO",
              "M486", "SET_FAN_SPEED", "SET_HEATER_TEMPERATURE", "SET_GCODE_VARIABLE", "RESPOND",
              "SET_RETRACTION", "SET_DISPLAY_TEXT", "SET_LED", "SET_PIN"}
_WAIT_M = {109, 190, 191, 116}
_M486_RE = re.compile(r"[Mm]\s*0*486(?![0-9.])(.*)$", re.S)
_M486_WORD_RE = re.compile(r"\s*([A-Za-z])\s*(\"[^\"]*\"|'[^']*'|[^\s]*)")
_OBJECT_COMMENT_RE = re.compile(rb"\s*(stop )?printing object\s*(.*)$", re.S)


def _num(text: str, letter: str, interp: "Interpreter") -> float:
    v = float(text)
    if not math.isfinite(v):
        interp.error(f"number out of range: {letter}{text}")
    return v


@dataclass
class Word:
    letter: str        # upper case
    value: float | None
    text: str


class Interpreter:
    """Modal state and the Python side of the interpretation of a file."""

    def __init__(self, machine: Machine, path: str, strict: bool = False):
        self.machine = machine
        self.path = path
        self.strict = strict
        m = machine
        self.dialect = (S.DIALECT_KLIPPER if m.flavor == "klipper" else
                        S.DIALECT_CNC if m.is_cnc else S.DIALECT_MARLIN)
        st = np.zeros(S.N_ST)
        ist = np.zeros(S.N_IST, dtype=np.int64)
        st[S.S_FEED] = 25.0                 # Klipper's and Marlin's initial 1500 mm/min
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
        # modal motion at start: grbl powers up in G0, LinuxCNC with no motion mode (G80), printers in G1
        ist[S.I_MOTION] = {"grbl": 0, "linuxcnc": 80}.get(m.flavor, 1)
        ist[S.I_DIALECT] = self.dialect
        ist[S.I_LAYER] = -1
        ist[S.I_FEATURE] = -1
        ist[S.I_LAYER_BY_Z] = 1
        ist[S.I_G90_SETS_E] = 1 if m.flavor == "marlin" else 0
        ist[S.I_OBJECT] = -1
        st[S.S_MAX_E] = -math.inf
        self.st, self.ist = st, ist

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
            ist[S.I_TO_PYTHON] = 1       # the first line comes here, to put the start wait before it
        self._limits_rows: list[np.ndarray] = [m.limits_row()[0].copy()]

        # offsets (mm): 9 work systems G54..G59.3, G92, tool length (Z)
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

        self.rows: list[tuple] = []        # rows made by the current Python line
        self.row_arrays: list[np.ndarray] = []   # rows in bulk (arc chords, cycles), in order with rows
        # summary material
        self.unknown: dict[str, int] = {}
        self.ignored: dict[str, int] = {}
        self.waits: dict[str, int] = {}
        self.events: list[tuple[int, str]] = []
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
        self.line = 0

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
            for m in _M486_WORD_RE.finditer(body):
                words[m.group(1).upper()] = m.group(2).strip("\"'")
        n = None
        if "S" in words:
            try:
                n = int(float(words["S"]))
            except ValueError:
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
        if text[0] == "$":
            # grbl system commands ($H homing, $X unlock, $$ settings): no motion model here
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
        m = _CHECKSUM_RE.search(code)
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
            ph = _PLACEHOLDER_RE.search(code).group(0)
            msg = f"unexpanded slicer placeholder '{ph}': line skipped"
            if self.strict:
                self.error(msg)
            self.warn(msg)
            self.skipped_lines += 1
            return
        m = _EXT_RE.match(code)
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
                m = _HMS_RE.fullmatch(hms)
                if m and any(m.groups()):
                    d, h, mi, s = (int(g) if g else 0 for g in m.groups())
                    self.slicer_estimate_s = float(((d * 24 + h) * 60 + mi) * 60 + s)
        elif body.startswith(b" layer"):
            m = _S3D_LAYER_RE.match(body.decode("utf-8", "replace"))
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
            m = _OBJECT_COMMENT_RE.match(body)
            stop, name = m.group(1), m.group(2).decode("utf-8", "replace").strip()
            self._set_object(None if stop or not name else name)

    # ------------------------------------------------------------------ Klipper extended commands
    def _extended(self, name: str, rest: str) -> None:
        uname = name.upper()
        params: dict[str, str] = {}
        pos = 0
        rest = rest.rstrip()
        while pos < len(rest):
            m = _KV_RE.match(rest, pos)
            if not m:
                break
            params[m.group(1).upper()] = m.group(2).strip("\"'")
            pos = m.end()
        if pos < len(rest) and uname in ("SET_VELOCITY_LIMIT", "SET_KINEMATIC_POSITION"):
            # Klipper refuses parameters that are not NAME=value ("Malformed command"); dropping them would
            # silently skip the limit or position change
            self.error(f"{uname}: malformed parameter {rest[pos:].strip()[:30]!r} (expected NAME=value)")

        def num(key: str) -> float | None:
            if key not in params:
                return None
            try:
                v = float(params[key])
            except ValueError:
                self.error(f"{uname}: {key}={params[key]!r} is not a number")
            if not math.isfinite(v):
                self.error(f"{uname}: {key}={params[key]} is out of range")
            return v

        if uname == "SET_VELOCITY_LIMIT":
            changes = {}
            v = num("VELOCITY")
            if v is not None:
                if not v > 0:
                    self.error("SET_VELOCITY_LIMIT: VELOCITY must be > 0")
                changes["max_v"] = v
            a = num("ACCEL")
            if a is not None:
                if not a > 0:
                    self.error("SET_VELOCITY_LIMIT: ACCEL must be > 0")
                changes["max_a"] = a
                self.st[S.S_ACC_P] = self.st[S.S_ACC_T] = self.st[S.S_ACC_R] = a
            scv = num("SQUARE_CORNER_VELOCITY")
            if scv is not None:
                if scv < 0:
                    self.error("SET_VELOCITY_LIMIT: SQUARE_CORNER_VELOCITY must be >= 0")
                changes["scv"] = scv
            mcr = num("MINIMUM_CRUISE_RATIO")
            if mcr is not None:
                if not 0 <= mcr < 1:
                    self.error("SET_VELOCITY_LIMIT: MINIMUM_CRUISE_RATIO must be in [0, 1)")
                changes["mcr"] = mcr
            a2d = num("ACCEL_TO_DECEL")
            if a2d is not None and mcr is None:   # Klipper: MINIMUM_CRUISE_RATIO wins when both are given
                if not a2d > 0:
                    self.error("SET_VELOCITY_LIMIT: ACCEL_TO_DECEL must be > 0")
                # Klipper's legacy setting: max_accel_to_decel = accel·(1 − mcr)
                accel = float(self.st[S.S_ACC_P])
                changes["mcr"] = max(0.0, 1.0 - a2d / accel)
            self._new_limits(**changes)
        elif uname == "SET_KINEMATIC_POSITION":
            st = self.st
            x0, y0, z0, e0 = (float(st[i]) for i in (S.S_X, S.S_Y, S.S_Z, S.S_E))
            for i, k in enumerate("XYZ"):
                v = num(k)
                if v is not None:
                    st[S.S_X + i] = v
            self.waits["SET_KINEMATIC_POSITION"] = self.waits.get("SET_KINEMATIC_POSITION", 0) + 1
            self._row(KIND_WAIT, 0, x0, y0, z0, e0, float(st[S.S_X]), float(st[S.S_Y]), float(st[S.S_Z]), e0,
                      0.0, 0.0, 0.0, 0.0)
        elif uname == "SET_PRESSURE_ADVANCE":
            ext = params.get("EXTRUDER", "extruder").lower()
            if ext != "extruder":
                self.unknown_command(f"SET_PRESSURE_ADVANCE EXTRUDER={ext}")   # one extruder is modelled
                return
            k, smooth = num("ADVANCE"), num("SMOOTH_TIME")
            if k is not None and k < 0:
                self.error("SET_PRESSURE_ADVANCE: ADVANCE must be >= 0")
            if smooth is not None and not 0 <= smooth <= 0.2:
                self.error("SET_PRESSURE_ADVANCE: SMOOTH_TIME must be in [0, 0.2] s")
            self._pressure_advance(k, smooth)
        elif uname == "SET_INPUT_SHAPER":
            self._set_input_shaper(params, num)
        elif uname == "EXCLUDE_OBJECT_START":
            self._set_object(params.get("NAME") or None)
        elif uname == "EXCLUDE_OBJECT_END":
            self._set_object(None)
        elif uname == "EXCLUDE_OBJECT_DEFINE" and params.get("NAME"):
            idx = self.objects.index(params["NAME"])
            if self.exclude is not None:
                self.exclude.register(params["NAME"], idx)
        elif uname == "EXCLUDE_OBJECT" and params.get("NAME"):
            # cancelled from inside the file: from here on, as on the printer
            if self.exclude is None:
                self.exclude = KlipperExclude([])
            self.exclude.exclude(params["NAME"], self.objects.index(params["NAME"]))
            self._exclude_wake()
        elif uname in self._macros:
            self._wait(uname, self._macros[uname])
        elif uname in _QUIET_EXT:
            pass
        else:
            self.unknown_command(uname)

    # ------------------------------------------------------------------ classic words
    def _words(self, code: str) -> list[Word]:
        words = []
        pos = 0
        n = len(code)
        while pos < n:
            m = _WORD_RE.match(code, pos)
            if not m:
                if code[pos:].strip() == "":
                    break
                self.error(f"unexpected text {code[pos:].strip()[:20]!r}")
            letter = m.group(1).upper()
            num = m.group(2)
            end = m.end()
            if end < n and not _SEP_OK.match(code, end):
                bad = code[m.start(1):].split()[0][:20]
                self.error(f"malformed number in {bad!r}")
            if num is None:
                words.append(Word(letter, None, ""))
            else:
                words.append(Word(letter, _num(num, letter, self), num))
            pos = end
        return words

    def _classic(self, code: str) -> None:
        m486 = _M486_RE.match(code)
        if m486:
            self._m486(m486.group(1))
            return
        head = _FREE_TEXT_RE.match(code)
        # M30 takes a file name on printers (delete an SD file) but ends the program on CNC flavors
        if head and int(head.group(1)) in _FREE_TEXT_M and not (self.machine.is_cnc and int(head.group(1)) == 30):
            return
        try_words_error = None
        try:
            words = self._words(code)
        except GcodeError as err:
            words = None
            try_words_error = err
        if words is None:
            # an unknown M/G command with free text (M117 Hello 1.2.3) is not ours to validate
            m = re.match(r"([MmGg])\s*(\d+)", code)
            if m:
                name = f"{m.group(1).upper()}{int(m.group(2))}"
                num = int(m.group(2))
                if m.group(1) in "Mm" and (num in _QUIET_M or (num in _FREE_TEXT_M and not (
                        self.machine.is_cnc and num == 30))):
                    return
                if not self._known(m.group(1).upper(), num):
                    self._unknown_or_macro(name)
                    return
            raise try_words_error

        gs: list[float] = []
        ms: list[int] = []
        params: dict[str, Word] = {}
        tool = None
        for w in words:
            if w.letter == "G":
                if w.value is None:
                    self.error("G needs a number")
                gs.append(round(w.value, 1))
            elif w.letter == "M":
                if w.value is None:
                    self.error("M needs a number")
                if w.value != int(w.value):
                    self.unknown_command(f"M{w.text}")
                    return
                ms.append(int(w.value))
            elif w.letter == "T" and not ms:
                tool = w
                params["T"] = w
            else:
                if w.letter in params:
                    self.error(f"word {w.letter} repeated")
                params[w.letter] = w
        self._execute(gs, ms, params, tool)

    def _known(self, letter: str, num: int) -> bool:
        if letter == "M":
            return num in (0, 1, 2, 30, 3, 4, 5, 6, 82, 83, 109, 190, 191, 116, 400, 201, 203, 204, 205, 220, 221)
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
    def _execute(self, gs: list[float], ms: list[int], params: dict[str, Word], tool: Word | None) -> None:
        st, ist = self.st, self.ist
        used: set[str] = set()
        axis_consumed = False       # axis words taken by G10/G28/G43.1/G92 (no motion)
        motion_codes = [g for g in gs if g in (0, 1, 2, 3, 80) or g in (73, 81, 82, 83, 85, 86, 89)]
        if len(motion_codes) > 1:
            self.error("two motion commands on one line: " + " ".join(f"G{g:g}" for g in motion_codes))
        gset = set(gs)
        for g in gs:
            if g in _QUIET_G:
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
        if ms and not motion_codes and not self.machine.is_cnc:
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
        if 4 in gset:
            self._dwell(params, used)
        for g in (17, 18, 19):
            if g in gset:
                self.plane = g
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
        for i, g in enumerate((54, 55, 56, 57, 58, 59, 59.1, 59.2, 59.3)):
            if g in gset:
                self.work_index = i
                self._update_offsets()
        if 61 in gset or 61.1 in gset:
            # LinuxCNC's G61 is exact *path* (tangent joins pass without stopping): 2; G61.1 exact stop: 1
            ist[S.I_EXACT_STOP] = 2 if (61 in gset and self.machine.flavor == "linuxcnc") else 1
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
                if self.machine.flavor != "linuxcnc":
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
        if 92.1 in gset or 92.2 in gset:
            self.g92_saved = self.g92.copy()
            self.g92[:] = 0.0
            self._update_offsets()
        if 92.3 in gset:
            self.g92 = self.g92_saved.copy()
            self._update_offsets()

        # motion
        for g in motion_codes:
            if g == 80:
                ist[S.I_MOTION] = 80
                self.cycle_state = None
            else:
                if int(g) not in (73, 81, 82, 83, 85, 86, 89):
                    self.cycle_state = None
                elif int(ist[S.I_MOTION]) not in (73, 81, 82, 83, 85, 86, 89):
                    self.cycle_state = None
                ist[S.I_MOTION] = int(g)
        # on a line with an M code and no motion G code, X Y Z E are the M code's parameters (M201 X1000)
        axis_consumed = axis_consumed or (bool(ms) and not motion_codes)
        has_axes = any(k in params for k in "XYZE") and not axis_consumed
        motion = int(ist[S.I_MOTION])
        if motion_codes and motion_codes[0] != 80 and not has_axes and motion in (2, 3):
            if any(k in params for k in "IJKR"):
                self.error(f"G{motion} needs an end point (X/Y/Z)")
        if has_axes or (motion in (73, 81, 82, 83, 85, 86, 89) and motion_codes and not axis_consumed):
            if motion in (0, 1):
                self._linear(motion, params, used, f, machine_coords)
            elif motion in (2, 3):
                self._arc(motion == 2, params, used, f)
            elif motion == 80:
                self.error("axis words without a motion command (G80 in force)")
            else:
                self._cycle(motion, params, used, f)
        elif f is not None:
            st[S.S_FEED] = f * scale / 60.0
        for k in ("A", "B", "C", "U", "V", "W"):
            if k in params:
                used.add(k)
                self.warn(f"axis {k} is not modelled: ignored")
        unused = [k for k in params if k not in used and k not in "XYZEF"]
        if unused and not ms:
            self.warn("word(s) " + " ".join(unused) + " ignored")
        for mc in ms:
            if mc in (2, 30):
                self.event(f"M{mc} program end")
                if self.machine.is_cnc:
                    ist[S.I_STOPPED] = 1
                else:
                    self.ignore(f"M{mc}")

    # ------------------------------------------------------------------ M commands
    def _m_command(self, mc: int, params: dict[str, Word], used: set[str]) -> None:
        st, ist = self.st, self.ist
        m = self.machine
        if mc in (82, 83):
            ist[S.I_ABS_E] = 1 if mc == 82 else 0
        elif mc in _QUIET_M:
            used.update(params)
        elif mc in _WAIT_M:
            used.update(params)
            self._wait(f"M{mc}", m.heat_wait_time if mc in (109, 190, 191) else 0.0)
        elif mc == 400:
            self._wait("M400")
        elif mc in (0, 1):
            used.update(params)
            self.event(f"M{mc} pause")
            self._wait(f"M{mc}")
        elif mc in (2, 30):
            pass   # after the motion of the line
        elif mc in (3, 4, 5):
            used.add("S")
            self.spindle_commands += 1
            if m.flavor == "linuxcnc":
                self._wait(f"M{mc}")   # LinuxCNC's task waits for the motion queue to empty
        elif mc == 6:
            t = params.get("T")
            used.add("T")
            self._tool_change(int(t.value) if t is not None and t.value is not None else -1)
        elif mc == 204:
            self._m204(params, used)
        elif mc in (201, 203, 205):
            used.update(params)
            if self.dialect == S.DIALECT_KLIPPER:
                self.ignore(f"M{mc}")   # Klipper: "Unknown command"
            elif self.dialect == S.DIALECT_CNC:
                self.unknown_command(f"M{mc}")
            else:
                self._marlin_limits(mc, params)
        elif mc in (900, 572):
            used.update(params)
            self._m_linear_advance(mc, params)
        elif mc in (220, 221):
            used.add("S")
            s = self._value(params, "S")
            if s is None and self.dialect == S.DIALECT_KLIPPER:
                s = 100.0    # Klipper: S defaults to 100 (a bare M220/M221 resets the factor); Marlin: no change
            if s is not None:
                if not s > 0:
                    self.error(f"M{mc} S must be > 0 (percent)")
                st[S.S_SPEED_F if mc == 220 else S.S_FLOW_F] = s / 100.0
        elif mc == 600:
            used.update(params)
            self._wait("M600", self._macros.get("M600", float(getattr(m, "filament_change_time", 0.0))))
        else:
            used.update(params)
            self._unknown_or_macro(f"M{mc}")

    def _unknown_or_macro(self, name: str) -> None:
        """A command the machine's [time] macros time (G29 = 90: a wait of 90 s), else unknown."""
        if name.upper() in self._macros:
            self._wait(name.upper(), self._macros[name.upper()])
        else:
            self.unknown_command(name)

    def _m204(self, params: dict[str, Word], used: set[str]) -> None:
        st = self.st
        used.update(params)
        if self.dialect == S.DIALECT_CNC:
            self.unknown_command("M204")
            return
        vals = {}
        for k in "SPTR":
            v = self._value(params, k)
            if v is not None:
                vals[k] = v
        if self.dialect == S.DIALECT_KLIPPER:
            if "S" in vals:
                a = vals["S"]
            elif "P" in vals and "T" in vals:
                a = min(vals["P"], vals["T"])
            else:
                self.ist[S.I_M204_IGNORED] += 1
                return
            if not a > 0.0:
                self.error("M204 acceleration must be > 0")
            st[S.S_ACC_P] = a
            st[S.S_ACC_T] = a
            st[S.S_ACC_R] = a
            return
        for k, v in vals.items():
            if not v > 0.0:
                self.error(f"M204 {k} must be > 0")
        if "S" in vals:
            st[S.S_ACC_P] = vals["S"]
            st[S.S_ACC_T] = vals["S"]
        if "P" in vals:
            st[S.S_ACC_P] = vals["P"]
        if "R" in vals:
            st[S.S_ACC_R] = vals["R"]
        if "T" in vals:
            st[S.S_ACC_T] = vals["T"]

    def _marlin_limits(self, mc: int, params: dict[str, Word]) -> None:
        changes = {}
        for k in params:
            v = self._value(params, k)
            if mc == 203 and k in "XYZE":
                if not v > 0:
                    self.error(f"M203 {k} must be > 0")
                # Marlin's M203 is in units/s, RepRapFirmware's in units/min (config.g: M203 X6000 ...)
                changes["axis_v_" + k.lower()] = v / 60.0 if self.machine.flavor == "reprap" else v
            elif mc == 201 and k in "XYZE":
                if not v > 0:
                    self.error(f"M201 {k} must be > 0")
                changes["axis_a_" + k.lower()] = v
            elif mc == 205:
                if v < 0:
                    self.error(f"M205 {k} must be >= 0")
                if k in "XYZE":
                    changes["jerk_" + k.lower()] = v
                elif k == "J":
                    changes["junction_dev"] = v
                elif k == "S":
                    changes["min_feed_v"] = v
                elif k == "T":
                    changes["min_travel_v"] = v
                else:
                    self.warn(f"M205 {k} ignored")
            else:
                self.warn(f"M{mc} {k} ignored")
        self._new_limits(**changes)

    # ------------------------------------------------------------------ step-stream settings
    def _pressure_advance(self, k: float | None, smooth: float | None, klipper_flush: bool = True) -> None:
        """New pressure advance K (s) and/or smoothing time (s) from here on (LIMITS pa_k, pa_smooth_t).

        Klipper (kinematics/extruder.py) flushes the step generation, a full stop, when the smoothing
        window in effect changes (turning pressure advance on or off included); a new K alone takes
        effect with the next move, without a stop. Marlin's M900 and RepRapFirmware's M572 plan no stop
        (``klipper_flush`` False): their times do not change.
        """
        cur = self._limits_rows[int(self.ist[S.I_LIMITS])]
        old_k, old_s = float(cur["pa_k"]), float(cur["pa_smooth_t"])
        new_k = old_k if k is None else k
        new_s = old_s if smooth is None else smooth
        if klipper_flush and (new_s if new_k else 0.0) != (old_s if old_k else 0.0):
            self._wait("SET_PRESSURE_ADVANCE")
        self._new_limits(pa_k=new_k, pa_smooth_t=new_s)

    def _m_linear_advance(self, mc: int, params: dict[str, Word]) -> None:
        """Marlin M900 K (linear advance, mm per mm/s = s) and RepRapFirmware M572 D S (s): the same physics
        as Klipper's pressure advance, smoothed with the machine's pressure_advance_smooth_time."""
        if self.dialect == S.DIALECT_KLIPPER or self.dialect == S.DIALECT_CNC:
            self.ignore(f"M{mc}")       # Klipper: "Unknown command"; CNC controllers have no extruder
            return
        letter = "K" if mc == 900 else "S"
        k = self._value(params, letter)
        if mc == 572:
            d = self._value(params, "D")
            if d is not None and d != 0:
                self.unknown_command(f"M572 D{d:g}")     # one extruder is modelled
                return
        if k is None:
            return
        if k < 0:
            self.error(f"M{mc} {letter} must be >= 0")
        if "linear_advance" not in self.ignored:
            self.ignore("linear_advance")
            self.warn(f"M{mc} {letter}{k:g}: planned as Klipper's pressure advance (K = {k:g} s, smoothed over "
                      f"{float(self._limits_rows[0]['pa_smooth_t']):g} s)")
        self._pressure_advance(k, None, klipper_flush=False)

    def _set_input_shaper(self, params: dict[str, str], num) -> None:
        """Klipper's SET_INPUT_SHAPER: new shaper types / frequencies / damping ratios for X and Y.

        Klipper (extras/input_shaper.py) flushes the step generation first: a full stop.
        """
        from ..machine import SHAPER_TYPE_CODES

        changes = {}
        for a in ("x", "y"):
            for key in (f"SHAPER_TYPE_{a.upper()}", "SHAPER_TYPE"):
                if key in params:
                    name = params[key].lower()
                    if name not in SHAPER_TYPE_CODES or name == "none":
                        self.error(f"SET_INPUT_SHAPER: {key}={params[key]} is not a modelled shaper "
                                   f"(zv, mzv, zvd, ei, 2hump_ei, 3hump_ei)")
                    changes["shaper_type_" + a] = float(SHAPER_TYPE_CODES[name])
                    break
            f = num(f"SHAPER_FREQ_{a.upper()}")
            if f is not None:
                if f < 0:
                    self.error(f"SET_INPUT_SHAPER: SHAPER_FREQ_{a.upper()} must be >= 0")
                changes["shaper_freq_" + a] = f
            z = num(f"DAMPING_RATIO_{a.upper()}")
            if z is not None:
                if not 0 <= z < 1:
                    self.error(f"SET_INPUT_SHAPER: DAMPING_RATIO_{a.upper()} must be in [0, 1)")
                changes["damping_" + a] = z
        for key in params:
            if key.endswith("_Z") or key.startswith(("SHAPER_A_", "SHAPER_T_")):
                self.error(f"SET_INPUT_SHAPER: {key} is not modelled (X and Y named shapers only)")
        self._wait("SET_INPUT_SHAPER")
        self._new_limits(**changes)

    def _tool_change(self, tool: int) -> None:
        self.tool_changes += 1
        self.event(f"tool change T{tool}" if tool >= 0 else "tool change")
        # [time] tool_change_time: only when the tool changes (T0 at the start of a print selects the tool
        # already in use, as Marlin and Klipper start with tool 0); M6 without T is a change
        changed = tool < 0 or tool != self.tool
        if tool >= 0:
            self.tool = tool
        self._wait("tool_change", float(getattr(self.machine, "tool_change_time", 0.0)) if changed else 0.0)

    def _dwell(self, params: dict[str, Word], used: set[str]) -> None:
        used.update(("P", "S"))
        p = self._value(params, "P")
        s = self._value(params, "S")
        t = 0.0
        if p is not None:
            t = p if self.dialect == S.DIALECT_CNC else p / 1000.0
        if s is not None:
            if self.dialect == S.DIALECT_KLIPPER:
                self.warn("G4 S is not supported by Klipper (only P, in ms): ignored")
            else:
                t = s
        if not t >= 0.0:
            self.error("G4 dwell must be >= 0")
        self._stop_row(KIND_DWELL, 0, t)

    # ------------------------------------------------------------------ G10/G11/G28/G92
    def _g10(self, params: dict[str, Word], used: set[str]) -> bool:
        """Work offsets (L2/L20) or firmware retraction. True when the axis words were consumed."""
        ell = self._value(params, "L")
        if ell is not None:
            used.update(("L", "P", "R"))
            if ell not in (2, 20):
                self.unknown_command(f"G10 L{ell:g}")
                return True
            p = self._value(params, "P")
            idx = self.work_index if p is None or p == 0 else int(p) - 1
            if p is not None and (p != int(p) or not 0 <= idx < 9):
                self.error("G10 P must be 0..9 (the coordinate system)")
            scale = float(self.st[S.S_UNIT])
            for a, k in enumerate("XYZ"):
                v = self._value(params, k)
                if v is None:
                    continue
                if ell == 2:
                    self.work[idx, a] = v * scale
                else:   # L20: make the current position read v
                    extra = self.tool_z if a == 2 else 0.0
                    self.work[idx, a] = float(self.st[S.S_X + a]) - v * scale - self.g92[a] - extra
            self._update_offsets()
            return True
        if self.machine.is_cnc:
            self.error("G10 needs L2 or L20")
        if "P" in params or "S" in params or "R" in params:
            used.update(params)    # RepRapFirmware G10 P<tool> S<temp>: tool temperatures
            return True
        self._firmware_retract(True)
        return True

    def _g11(self) -> None:
        if self.machine.is_cnc:
            self.unknown_command("G11")
            return
        self._firmware_retract(False)

    def _firmware_retract(self, retract: bool) -> None:
        m = self.machine
        if retract == self.retracted:
            return    # Marlin and Klipper ignore a repeated G10 / a G11 without G10
        self.retracted = retract
        length = m.retract_length if retract else m.retract_length + m.unretract_extra_length
        speed = m.retract_speed if retract else m.unretract_speed
        if length <= 0.0:
            return
        st = self.st
        e0 = float(st[S.S_E])
        e1 = e0 - length if retract else e0 + length
        st[S.S_E] = e1
        x, y, z = float(st[S.S_X]), float(st[S.S_Y]), float(st[S.S_Z])
        flags = FLAG_FIRMWARE_RETRACT | (FLAG_RETRACT if retract else 0)
        # the firmware's own retraction speed: M220 scales G0/G1 feeds, not this one (Marlin fwretract)
        self._row(KIND_EXTRUDE_ONLY, flags, x, y, z, e0, x, y, z, e1, length, speed, float(st[S.S_ACC_R]), 0.0)

    def _g28(self, params: dict[str, Word], used: set[str]) -> None:
        st = self.st
        axes = [k for k in "XYZ" if k in params]
        used.update(axes)
        if not axes:
            axes = ["X", "Y", "Z"]
        x0, y0, z0, e0 = (float(st[i]) for i in (S.S_X, S.S_Y, S.S_Z, S.S_E))
        for k in axes:
            a = "XYZ".index(k)
            st[S.S_X + a] = self.machine.axes[k.lower()].home
            if not self.machine.is_cnc:
                # homing drops the G92 offset of the axis (Marlin set_axis_is_at_home, Klipper's
                # base_position = homing_position); CNC G28 is a move to a stored point, offsets kept
                self.g92[a] = 0.0
        self._update_offsets()
        self.event("G28 home " + "".join(axes))
        self.waits["G28"] = self.waits.get("G28", 0) + 1
        if self.machine.homing_time > 0.0:
            self.wait_time_s["G28"] = self.wait_time_s.get("G28", 0.0) + self.machine.homing_time
        self._row(KIND_WAIT, FLAG_HOMING, x0, y0, z0, e0, float(st[S.S_X]), float(st[S.S_Y]), float(st[S.S_Z]),
                  e0, 0.0, 0.0, 0.0, self.machine.homing_time)

    def _g92(self, params: dict[str, Word], used: set[str]) -> None:
        st = self.st
        scale = float(st[S.S_UNIT])
        given = {k: self._value(params, k) for k in "XYZE" if k in params}
        used.update(given)
        if not given:
            if self.dialect == S.DIALECT_KLIPPER:
                given = {k: 0.0 for k in "XYZE"}   # Klipper: bare G92 zeroes every axis
            elif self.dialect == S.DIALECT_CNC:
                self.error("G92 needs at least one axis word")
            else:
                return                              # Marlin: nothing to set
        for k, v in given.items():
            if k == "E":
                st[S.S_ELOG] = v * scale
            else:
                a = "XYZ".index(k)
                extra = self.tool_z if a == 2 else 0.0
                self.g92[a] = float(st[S.S_X + a]) - v * scale - self.work[self.work_index, a] - extra
        self._update_offsets()

    # ------------------------------------------------------------------ motion
    def _targets(self, params: dict[str, Word], machine_coords: bool):
        """End point (machine mm) of a straight move; the scanner's arithmetic exactly."""
        st, ist = self.st, self.ist
        scale = float(st[S.S_UNIT])
        x0, y0, z0 = float(st[S.S_X]), float(st[S.S_Y]), float(st[S.S_Z])
        absc = ist[S.I_ABS_COORD] != 0
        out = [x0, y0, z0]
        for a, k in enumerate("XYZ"):
            v = self._value(params, k)
            if v is None:
                continue
            if machine_coords:
                out[a] = v * scale
            elif absc:
                out[a] = v * scale + float(st[S.S_OX + a])
            else:
                out[a] = out[a] + v * scale
        return out

    def _e_target(self, params: dict[str, Word]):
        """(machine e1, new logical E) after the line's E word (or unchanged)."""
        st, ist = self.st, self.ist
        e0 = float(st[S.S_E])
        elog = float(st[S.S_ELOG])
        v = self._value(params, "E")
        if v is None:
            return e0, elog
        ev = v * float(st[S.S_UNIT])
        if ist[S.I_ABS_E] != 0 and (ist[S.I_ABS_COORD] != 0 or ist[S.I_G90_SETS_E] != 0):
            de_log = ev - elog
            elog = ev
        else:
            de_log = ev
            elog = elog + ev
        return e0 + de_log * float(st[S.S_FLOW_F]), elog

    def _accel(self, has_xyz: bool, de: float) -> float:
        st = self.st
        if not has_xyz:
            return float(st[S.S_ACC_R])
        if de != 0.0:
            return float(st[S.S_ACC_P])
        return float(st[S.S_ACC_T])

    def _layer_check(self, z1: float) -> None:
        """A printing move: start a layer by Z when the file has no layer comments; set the layer's Z."""
        st, ist = self.st, self.ist
        if ist[S.I_LAYER_BY_Z] and z1 > float(st[S.S_MAXZ]):
            st[S.S_MAXZ] = z1
            self._new_layer(z1)
        elif ist[S.I_LAYER_Z_TODO]:
            layer = int(ist[S.I_LAYER])
            if layer >= 0:
                self.layer_z[layer] = z1
            ist[S.I_LAYER_Z_TODO] = 0

    def _linear(self, code: int, params: dict[str, Word], used: set[str], f: float | None,
                machine_coords: bool) -> None:
        st = self.st
        used.update("XYZEF")
        scale = float(st[S.S_UNIT])
        x0, y0, z0, e0 = float(st[S.S_X]), float(st[S.S_Y]), float(st[S.S_Z]), float(st[S.S_E])
        x1, y1, z1 = self._targets(params, machine_coords)
        e1, elog = self._e_target(params)
        feed = float(st[S.S_FEED])
        if f is not None:
            feed = f * scale / 60.0
        dx = x1 - x0
        dy = y1 - y0
        dz = z1 - z0
        de = e1 - e0
        move_d = math.sqrt(dx * dx + dy * dy + dz * dz)
        if not all(math.isfinite(v) for v in (x1, y1, z1, e1, move_d)):
            self.error("coordinate out of range")
        if move_d > 0.0 and de > 0.0:
            self._layer_check(z1)
        st[S.S_X] = x1
        st[S.S_Y] = y1
        st[S.S_Z] = z1
        st[S.S_E] = e1
        st[S.S_ELOG] = elog
        st[S.S_FEED] = feed
        if move_d > 0.0 or de != 0.0:
            flags = 0
            if move_d > 0.0:
                kind = KIND_PRINT if de > 0.0 else KIND_TRAVEL
            else:
                kind = KIND_EXTRUDE_ONLY
                move_d = abs(de)
            if de < 0.0:
                flags |= FLAG_RETRACT
            feed_v = feed * float(st[S.S_SPEED_F])
            if code == 0:
                flags |= FLAG_RAPID
                if self.dialect == S.DIALECT_CNC:
                    feed_v = math.inf
            accel = self._accel(kind != KIND_EXTRUDE_ONLY, de)
            self._row(kind, flags, x0, y0, z0, e0, x1, y1, z1, e1, move_d, feed_v, accel, 0.0)

    def _arc(self, clockwise: bool, params: dict[str, Word], used: set[str], f: float | None) -> None:
        from .arcs import ArcError, arc_chords

        st = self.st
        used.update("XYZEFIJKRP")
        scale = float(st[S.S_UNIT])
        if f is not None:
            st[S.S_FEED] = f * scale / 60.0
        x0, y0, z0, e0 = float(st[S.S_X]), float(st[S.S_Y]), float(st[S.S_Z]), float(st[S.S_E])
        x1, y1, z1 = self._targets(params, False)
        e1, elog = self._e_target(params)
        centre = [self._value(params, k) for k in "IJK"]
        r = self._value(params, "R")
        p = self._value(params, "P")
        flavor = self.machine.flavor
        if p is not None and flavor == "klipper":
            self.warn("G2/G3 P is not supported by Klipper: ignored")
            p = None
        turns = 1 if p is None else p
        if p is not None and flavor == "marlin":
            # Marlin (ARC_P_CIRCLES): P complete circles in addition to the arc; LinuxCNC: P turns in all
            if p != int(p) or p < 0:
                self.error(f"arc circle count P must be a whole number >= 0, got {params['P'].text}")
            turns = p + 1
        elif p is not None and (p != int(p) or p < 1):
            self.error(f"arc turn count P must be a whole number >= 1, got {params['P'].text}")
        ijk = None
        if any(c is not None for c in centre):
            if r is not None:
                self.error("arc has both I/J/K and R")
            start = (x0, y0, z0)
            ijk = []
            for a, c in enumerate(centre):
                if c is None:
                    ijk.append(0.0)
                elif self.arc_abs_centre:
                    ijk.append(c * scale + float(st[S.S_OX + a]) - start[a])
                else:
                    ijk.append(c * scale)
        elif r is None:
            self.error(f"G{2 if clockwise else 3} needs I/J/K (centre) or R (radius)")
        else:
            r = r * scale
        m = self.machine
        try:
            pts = arc_chords((x0, y0, z0), (x1, y1, z1), ijk=ijk, r=r, plane=self.plane, clockwise=clockwise,
                             turns=int(turns), tolerance=m.arc_tolerance, resolution=m.arc_resolution,
                             units_mm=float(st[S.S_UNIT]) == 1.0)
        except ArcError as err:
            self.error(str(err))
        self.arcs += 1
        n = pts.shape[0]
        de = e1 - e0
        starts = np.vstack([[x0, y0, z0], pts[:-1]]) if n else np.empty((0, 3))
        d = np.sqrt(((pts - starts) ** 2).sum(axis=1)) if n else np.empty(0)
        es = e0 + de * (np.arange(1, n + 1) / n) if n else np.empty(0)
        if n:
            es[-1] = e1
        e_starts = np.concatenate([[e0], es[:-1]]) if n else np.empty(0)
        if n and de > 0.0 and d.max() > 0.0:
            self._layer_check(float(pts[0, 2]))
        st[S.S_X], st[S.S_Y], st[S.S_Z] = x1, y1, z1
        if n:
            st[S.S_X], st[S.S_Y], st[S.S_Z] = float(pts[-1, 0]), float(pts[-1, 1]), float(pts[-1, 2])
        st[S.S_E] = e1
        st[S.S_ELOG] = elog
        self._bulk(pts, starts, es, e_starts, d, FLAG_ARC, float(st[S.S_FEED]) * float(st[S.S_SPEED_F]))

    def _bulk(self, ends, starts, es, e_starts, d, flags, feed_v, rapid_mask=None, dwell=None) -> None:
        """Rows for a sequence of straight pieces (arc chords, cycle moves)."""
        from ..schema import MOVE_DTYPE

        self._flush_rows_to_arrays()
        st, ist = self.st, self.ist
        n = ends.shape[0]
        a = np.zeros(n, dtype=MOVE_DTYPE)
        a["line"] = self.line
        a["feature"] = ist[S.I_FEATURE]
        a["layer"] = ist[S.I_LAYER]
        a["limits"] = ist[S.I_LIMITS]
        a["x0"], a["y0"], a["z0"], a["e0"] = starts[:, 0], starts[:, 1], starts[:, 2], e_starts
        a["x1"], a["y1"], a["z1"], a["e1"] = ends[:, 0], ends[:, 1], ends[:, 2], es
        de = es - e_starts
        xyz = d > 0.0
        a["kind"] = np.where(xyz, np.where(de > 0.0, KIND_PRINT, KIND_TRAVEL), KIND_EXTRUDE_ONLY)
        a["flags"] = flags | np.where(de < 0.0, FLAG_RETRACT, 0)
        a["move_d"] = np.where(xyz, d, np.abs(de))
        a["feed_v"] = feed_v
        if rapid_mask is not None:
            a["flags"] |= np.where(rapid_mask, FLAG_RAPID, 0).astype(np.uint8)
            if self.dialect == S.DIALECT_CNC:
                a["feed_v"] = np.where(rapid_mask, math.inf, feed_v)
        a["accel"] = np.where(xyz, np.where(de != 0.0, st[S.S_ACC_P], st[S.S_ACC_T]), st[S.S_ACC_R])
        a["blend_p"] = st[S.S_BLEND_P]
        a["blend_q"] = st[S.S_BLEND_Q]
        a["object"] = ist[S.I_OBJECT]
        a["exact_stop"] = ist[S.I_EXACT_STOP]
        keep = xyz | (de != 0.0)
        if dwell is not None:
            a["kind"][dwell] = KIND_DWELL
            a["move_d"][dwell] = 0.0
            a["accel"][dwell] = 0.0
            a["feed_v"][dwell] = 0.0
            keep = keep | dwell
        self.row_arrays.append(a[keep])

    def _cycle(self, code: int, params: dict[str, Word], used: set[str], f: float | None) -> None:
        from .cycles import CycleError, CycleState, expand_cycle

        st, ist = self.st, self.ist
        scale = float(st[S.S_UNIT])
        used.update("XYZRQPLF")
        if f is not None:
            st[S.S_FEED] = f * scale / 60.0
        off = [float(st[S.S_OX + a]) for a in range(3)]
        pos = [float(st[S.S_X + a]) - off[a] for a in range(3)]
        words = {}
        for k in "XYZRQL":
            v = self._value(params, k)
            if v is not None:
                words[k] = v if k == "L" else v * scale
        p = self._value(params, "P")
        if p is not None:
            words["P"] = p        # seconds (LinuxCNC)
        if self.cycle_state is None:
            self.cycle_state = CycleState.enter(pos[0], pos[1], pos[2], self.retract_mode,
                                                ist[S.I_ABS_COORD] == 0)
        state = self.cycle_state
        state.x, state.y, state.z = pos
        state.incremental = ist[S.I_ABS_COORD] == 0
        state.retract_mode = self.retract_mode
        try:
            rows, new_state = expand_cycle(code, words, state, 0.254, plane=self.plane)
        except CycleError as err:
            self.error(str(err))
        self.cycle_state = new_state
        self.canned_cycles += 1
        if rows.shape[0] == 0:
            return
        ends = rows[:, :3] + np.array(off)
        starts = np.vstack([[float(st[S.S_X]), float(st[S.S_Y]), float(st[S.S_Z])], ends[:-1]])
        d = np.sqrt(((ends - starts) ** 2).sum(axis=1))
        e = float(st[S.S_E])
        es = np.full(rows.shape[0], e)
        motion = rows[:, 3]
        dwell = motion == 2
        self._bulk(ends, starts, es, es, d, FLAG_CANNED, float(st[S.S_FEED]) * float(st[S.S_SPEED_F]),
                   rapid_mask=motion == 0, dwell=dwell)
        if dwell.any():
            self.row_arrays[-1]["dwell_t"][self.row_arrays[-1]["kind"] == KIND_DWELL] = rows[dwell, 4]
        st[S.S_X], st[S.S_Y], st[S.S_Z] = float(ends[-1, 0]), float(ends[-1, 1]), float(ends[-1, 2])
