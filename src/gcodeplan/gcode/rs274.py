"""One line of a CNC program (``linuxcnc`` and ``grbl`` dialects) as RS274NGC executes it (a part of
:class:`.interp.Interpreter`).

Every word of a line takes effect, in LinuxCNC's documented order of execution (grbl follows the same
order): comments/messages, feed mode, F, S, T, M6, M3–M5, M7–M9, overrides, other M codes, dwell, plane,
units, cutter compensation, tool length offset, coordinate system, path mode, distance mode, retract mode,
G28/G30/G10/G92, motion, stop. Axis words on a line with a non-motion G or M code move in the modal motion
mode unless a G10/G28/G30/G43.1/G92 on the line uses them; nothing is dropped. Two codes of one modal group
on a line are refused as LinuxCNC ("Two G codes used from same modal group") and grbl (error:21) refuse
them. A word grbl does not accept is named with grbl's own error (error:20) and ignored (an error under
``--strict``).

LinuxCNC specifics kept: F is read before G20/G21 on the same line, so ``G20 F10`` keeps the old units
for its feed (interp_convert.cc convert_feed_rate runs before convert_length_units; grbl converts F
with the line's units). M3/M4/M5, M7/M8/M9, M6 and G43/G43.1/G49 wait for LinuxCNC's motion queue to
empty (full stops). G28/G30 rapid to the intermediate point (the axis words, in the current coordinate
system), then to the stored position (#5161–5163 / #5181–5183 of the .var file, machine coordinates;
zero when absent) for the named axes (all axes when none is named) — interp_convert.cc convert_home.
G28.1/G30.1 store the current machine position. M6 moves to ``[EMCIO]TOOL_CHANGE_POSITION`` at rapid
speed when the .ini has one. G43 H takes the tool length from ``[EMCIO]TOOL_TABLE`` (H omitted: the
tool in the spindle).
"""
from __future__ import annotations

import math
import re

from ..schema import FLAG_RAPID, KIND_TRAVEL
from . import scan as S
from .lexing import FREE_TEXT_M, QUIET_G, Word

CYCLE_G = (73, 81, 82, 83, 85, 86, 89)
MOTION_G = {0.0, 1.0, 2.0, 3.0, 33.0, 38.2, 38.3, 38.4, 38.5, 73.0, 76.0, 80.0, 81.0, 82.0, 83.0, 84.0, 85.0,
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
GRBL_M = {0, 1, 2, 3, 4, 5, 7, 8, 9, 30, 56}
# codes modelled as having no effect on the motion
NO_EFFECT_G = {40.0, 94.0, 97.0, 17.1, 18.1, 19.1}
# a grbl line of one M code and words only G or M codes read (a slicer's "M204 P1000"):
# see Rs274Commands.grbl_inert_line
_INERT_LINE = re.compile(rb"[ \t]*[Mm]0*([0-9]{1,4})((?:[ \t]+[DHIJKLPQRdhijklpqr][-+]?"
                         rb"(?:[0-9]{1,9}(?:\.[0-9]{0,9})?|\.[0-9]{1,9}))*)[ \t]*\r?")
_INERT_MEMO_MAX = 256        # distinct inert lines remembered (a program has a handful: M204 P800, P1000 ...)


def _gname(g: float) -> str:
    return f"G{g:g}"


class Rs274Commands:
    """Mixed into :class:`.interp.Interpreter`: the CNC dialects' line execution."""

    # ------------------------------------------------------------------ set-up from the machine
    def _cnc_init(self) -> None:
        """Machine units for programs that state none ([TRAJ]LINEAR_UNITS), stored G28/G30 positions,
        tool table; then the .ini's [RS274NGC]RS274NGC_STARTUP_CODE as a line 0."""
        m = self.machine
        lc = getattr(m, "linuxcnc", None)
        self.g28_home = [0.0, 0.0, 0.0]
        self.g30_home = [0.0, 0.0, 0.0]
        self.tool_table: dict[int, float] = {}
        self.tool_change_position = None
        self.pending_tool = None
        if lc is None:
            return
        self.st[S.S_UNIT] = float(getattr(lc, "program_units_mm", 1.0))
        params = getattr(lc, "parameters", {}) or {}
        self.g28_home = [float(params.get(5161 + a, 0.0)) for a in range(3)]
        self.g30_home = [float(params.get(5181 + a, 0.0)) for a in range(3)]
        self.tool_table = dict(getattr(lc, "tool_table", {}) or {})
        self.tool_change_position = getattr(lc, "tool_change_position", None)
        startup = getattr(lc, "startup_code", "") or ""
        if startup.strip():
            self.line = 0
            self._classic(startup.strip())
            self.rows = []           # the start-up code makes no motion rows (it sets modes)

    # ------------------------------------------------------------------ fast path: lines that do nothing
    def grbl_inert_line(self, raw: bytes, lineno: int) -> bool:
        """Interpret line ``lineno`` (``raw``: its bytes, no newline) at once if it is a grbl line of one M code
        grbl does not have and words that only a G or M code would read (no G code, no F, S, T or axis word):
        a printer's ``M204 P1000`` in a program run on grbl. Such a line changes nothing; what the full path
        (:meth:`_execute_cnc`) makes of it, its error:20 and its ignored words, is replayed from a memo of the
        line's text. False (nothing done) for any other line, under ``--strict`` (the line is an error there),
        on LinuxCNC and before the machine's start time is counted: those go the full path."""
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
        name, unused = got
        self.line = lineno
        # as _grbl_unsupported, then the unused words' warning of _execute_cnc
        self.warn(f"{name}: grbl rejects it (error:20, unsupported command); ignored")
        self.unknown[name] = self.unknown.get(name, 0) + 1
        if unused:
            self.warn(unused)
        return True

    @staticmethod
    def _grbl_inert_effect(raw: bytes):
        """(M code name, its unused-words warning or "") when ``raw`` is an inert grbl line
        (:meth:`grbl_inert_line`), else False."""
        m = _INERT_LINE.fullmatch(raw)
        if m is None:
            return False
        mc = int(m.group(1))
        # grbl's own M codes act; free-text ones and M486 are read before the words (interp._classic)
        if mc in GRBL_M or mc in FREE_TEXT_M or mc == 486:
            return False
        letters = [w[:1].decode().upper() for w in m.group(2).split()]
        if len(set(letters)) != len(letters):
            return False              # a repeated word is an error: the full path names it
        return f"M{mc}", ("word(s) " + " ".join(letters) + " ignored" if letters else "")

    # ------------------------------------------------------------------ checks
    def _grbl_unsupported(self, name: str) -> None:
        msg = f"{name}: grbl rejects it (error:20, unsupported command); ignored"
        if self.strict:
            self.error(f"{name}: grbl error:20 (unsupported command)")
        self.warn(msg)
        self.unknown[name] = self.unknown.get(name, 0) + 1

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
        st, ist = self.st, self.ist
        lcnc = self.machine.flavor == "linuxcnc"
        used: set[str] = set()
        g_ok: list[float] = []
        for g in gs:
            if not lcnc and g not in GRBL_G:
                self._grbl_unsupported(_gname(g))
                continue
            if g not in KNOWN_G:
                self._unknown_or_macro(_gname(g))
                continue
            g_ok.append(g)
        m_ok: list[int] = []
        for mc in ms:
            if not lcnc and mc not in GRBL_M:
                self._grbl_unsupported(f"M{mc}")
                continue
            m_ok.append(mc)
        self._check_groups(g_ok, m_ok, lcnc)
        gset = set(g_ok)
        mset = set(m_ok)
        motion_codes = [g for g in g_ok if g in MOTION_G]

        # 1. feed rate mode
        if 93 in gset:
            self.error("G93 inverse-time feed is not supported")
        if 95 in gset:
            self.error("G95 feed per revolution is not supported")
        # 2. F (LinuxCNC: in the units in force before this line's G20/G21; grbl: in the line's units)
        f = self._value(params, "F")
        if f is not None:
            used.add("F")
            if not f > 0.0:
                self.error(f"feed rate F must be > 0, got {params['F'].text}")
        unit_before = float(st[S.S_UNIT])
        unit_line = 25.4 if 20 in gset else (1.0 if 21 in gset else unit_before)
        if f is not None:
            st[S.S_FEED] = f * (unit_before if lcnc else unit_line) / 60.0
        # 3. S (grbl: a speed change while the spindle turns, a spindle or a coolant change stop the motion,
        # in this order: gc_execute's steps 4, 7, 8; commands_state._grbl_syncs)
        if not lcnc:
            self._grbl_syncs(sorted(mset), params)
        if "S" in params:
            used.add("S")
            if not mset & {3, 4}:
                self.spindle_commands += 1
        # 4. T (select: the tool the next M6 loads)
        if "T" in params:
            used.add("T")
            t = params["T"].value
            if t is None or t != int(t) or t < 0:
                self.error("T needs a tool number")
            self.pending_tool = int(t)
        # 5. M6 / M61
        if 6 in mset:
            self._cnc_tool_change(lcnc)
        if 61 in mset:
            q = self._value(params, "Q")
            used.add("Q")
            if q is None or q != int(q) or q < 0:
                self.error("M61 needs Q<tool number>")
            self.tool = int(q)
        # 6. spindle
        for mc in (3, 4, 5):
            if mc in mset:
                self.spindle_commands += 1
                if lcnc:
                    self._wait(f"M{mc}")   # LinuxCNC's task waits for the motion queue to empty
        # 7. coolant
        for mc in (7, 8, 9):
            if mc in mset and lcnc:
                self._wait(f"M{mc}")
        # 8. overrides (no effect at 100 %), 9. other M codes (user M100-M199 and the rest)
        for mc in m_ok:
            if mc in (0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 30, 48, 49, 50, 51, 52, 53, 60, 61):
                continue
            self._m_command(mc, params, used)
        # 10. dwell
        if 4 in gset:
            self._dwell(params, used)
        # 11. plane
        for g in (17, 18, 19):
            if g in gset:
                self.plane = g
        # 12. units
        st[S.S_UNIT] = unit_line
        scale = unit_line
        # 13. cutter compensation
        for g in (41.0, 42.0, 41.1, 42.1):
            if g in gset:
                used.update(("D",))
                self.warn(f"{_gname(g)} cutter radius compensation is not modelled: the path is planned "
                          f"uncompensated")
        # 14. tool length offset
        axis_consumed = False
        if 49 in gset:
            self.tool_z = 0.0
            self._update_offsets()
            if lcnc:
                self._wait("G49")
        if 43 in gset:
            used.add("H")
            h = self._value(params, "H")
            tool = self.tool if h is None else h
            if tool != int(tool) or tool < 0:
                self.error(f"G43 H must be a tool number, got {params['H'].text}")
            tool = int(tool)
            if tool == 0:
                self.tool_z = 0.0
            elif tool in self.tool_table:
                self.tool_z = self.tool_table[tool]
            elif self.tool_table:
                self.error(f"G43 H{tool}: tool {tool} is not in the tool table")
            else:
                self.warn(f"G43 H{tool}: no tool table, tool length offset taken as 0")
                self.tool_z = 0.0
            self._update_offsets()
            if lcnc:
                self._wait("G43")      # LinuxCNC's task waits for the motion queue to empty
        if 43.1 in gset:
            z = self._value(params, "Z")
            if z is None:
                self.error("G43.1 needs Z (the tool length offset)")
            used.update(k for k in "XYZ" if k in params)
            axis_consumed = True
            self.tool_z = z * scale
            self._update_offsets()
            if lcnc:
                self._wait("G43.1")
        # 15. coordinate system
        for i, g in enumerate((54.0, 55.0, 56.0, 57.0, 58.0, 59.0, 59.1, 59.2, 59.3)):
            if g in gset:
                self.work_index = i
                self._update_offsets()
        # 16. path control
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
            used.add("Q")
        # 17. distance mode
        if 90 in gset or 91 in gset:
            ist[S.I_ABS_COORD] = 1 if 90 in gset else 0
        if 90.1 in gset:
            self.arc_abs_centre = True
        if 91.1 in gset:
            self.arc_abs_centre = False
        # 18. retract mode
        if 98 in gset or 99 in gset:
            self.retract_mode = 98 if 98 in gset else 99
            if self.cycle_state is not None:
                self.cycle_state.retract_mode = self.retract_mode
        # 19. G10 / G28 / G30 / G92
        machine_coords = 53 in gset
        if 10 in gset:
            self._g10(params, used)
            axis_consumed = True
        if 28 in gset or 30 in gset:
            self._cnc_home(28 if 28 in gset else 30, params, used)
            axis_consumed = True
        if 28.1 in gset or 30.1 in gset:
            pos = [float(st[S.S_X + a]) for a in range(3)]
            if 28.1 in gset:
                self.g28_home = pos
            else:
                self.g30_home = pos
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
        # 20. motion
        for g in motion_codes:
            if g == 80:
                self.cycle_state = None
            elif int(g) not in CYCLE_G or int(ist[S.I_MOTION]) not in CYCLE_G:
                self.cycle_state = None
            if g not in (0, 1, 2, 3, 80) and int(g) not in CYCLE_G:
                self.error(f"{_gname(g)} is not supported")
            ist[S.I_MOTION] = int(g)
        motion = int(ist[S.I_MOTION])
        if machine_coords and motion not in (0, 1):
            self.error("G53 needs G0 or G1" + ("" if lcnc else " (grbl error:30)"))
        has_axes = any(k in params for k in "XYZE") and not axis_consumed
        if motion_codes and motion_codes[0] != 80 and not has_axes and motion in (2, 3):
            if any(k in params for k in "IJKR"):
                self.error(f"G{motion} needs an end point (X/Y/Z)")
        if has_axes or (motion in CYCLE_G and motion_codes and not axis_consumed):
            if motion in (0, 1):
                self._linear(motion, params, used, None, machine_coords)
            elif motion in (2, 3):
                self._arc(motion == 2, params, used, None)
            elif motion == 80:
                self.error("axis words without a motion mode (G80 in force): "
                           + ("LinuxCNC: 'Cannot use axis values without a G code that uses them'" if lcnc
                              else "grbl error:31 (axis words without a command)"))
            else:
                self._cycle(motion, params, used, None)
        for k in ("A", "B", "C", "U", "V", "W"):
            if k in params:
                used.add(k)
                self.warn(f"axis {k} is not modelled: ignored")
        unused = [k for k in params if k not in used and k not in "XYZEFN"]
        if unused and not m_ok:
            self.warn("word(s) " + " ".join(unused) + " ignored")
        # 21. stop
        for mc in m_ok:
            if mc in (0, 1, 60):
                self._m_command(mc, params, used)     # pauses, each named (commands_state)
            elif mc in (2, 30):
                self.event(f"M{mc} program end")
                ist[S.I_STOPPED] = 1

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
        """LinuxCNC convert_home / grbl G28, G30: rapid to the intermediate point, then to the stored one."""
        axes = [k for k in "XYZ" if k in params]
        used.update(axes)
        x1, y1, z1 = self._targets(params, False)
        self._rapid_row(x1, y1, z1)
        home = self.g28_home if code == 28 else self.g30_home
        end = [float(self.st[S.S_X + a]) for a in range(3)]
        for a, k in enumerate("XYZ"):
            if k in axes or not axes:
                end[a] = home[a]
        self._rapid_row(*end)
        self.event(f"G{code} to the stored position " + ("".join(axes) or "XYZ"))

    # ------------------------------------------------------------------ M6
    def _cnc_tool_change(self, lcnc: bool) -> None:
        """M6: LinuxCNC waits for the queue to empty, moves to [EMCIO]TOOL_CHANGE_POSITION (machine
        coordinates, as a rapid) when the .ini has one, then changes the tool."""
        tool = self.pending_tool if self.pending_tool is not None else -1
        if lcnc and self.tool_change_position is not None:
            self._rapid_row(*self.tool_change_position)
        self._tool_change(tool)


__all__ = ["Rs274Commands", "KNOWN_G", "GRBL_G", "GRBL_M", "G_GROUPS", "M_GROUPS", "QUIET_G"]
