"""The interpreter's state commands: Klipper extended commands, M codes, accelerations and limits,
pressure advance and input shaper settings, tool changes and dwells (a part of :class:`.interp.Interpreter`)."""
from __future__ import annotations

import math


from ..schema import KIND_DWELL, KIND_WAIT
from . import scan as S
from .lexing import KV_RE, QUIET_EXT, QUIET_M, WAIT_M, Word
from .objects import KlipperExclude



class StateCommands:
    """Mixed into :class:`.interp.Interpreter`: commands that change the machine's state, not the position."""

    # ------------------------------------------------------------------ Klipper extended commands
    def _extended(self, name: str, rest: str) -> None:
        uname = name.upper()
        if uname == "SET_VELOCITY_LIMIT" and self.machine.firmware == "grbl-1.1":
            # grbl has no such command (it rejects the line): its limits are its $ settings, unchanged
            self.unknown_command(uname)
            return
        params: dict[str, str] = {}
        pos = 0
        rest = rest.rstrip()
        while pos < len(rest):
            m = KV_RE.match(rest, pos)
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
            self._set_velocity_limit(num)
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
        elif uname in QUIET_EXT:
            pass
        else:
            self.unknown_command(uname)

    def _set_velocity_limit(self, num) -> None:
        """Klipper's SET_VELOCITY_LIMIT (toolhead.py cmd_SET_VELOCITY_LIMIT): VELOCITY mm/s, ACCEL mm/s² (also the
        accel of the moves that follow), SQUARE_CORNER_VELOCITY mm/s, MINIMUM_CRUISE_RATIO, or the legacy
        ACCEL_TO_DECEL mm/s²; a new LIMITS row. ``num(key)``: the parameter as a checked number, None if absent."""
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

    # ------------------------------------------------------------------ grbl: syncs, laser mode, idle state
    def _grbl_state_init(self) -> None:
        """grbl's parser state the syncs depend on (gcode.c gc_state: spindle M5, coolant M9, S0), laser mode
        ($32, the machine's ``grbl_laser_mode``) and whether the machine is idle (grbl is idle at the program's
        start: system.c runs a ``$`` setting then, gcode/grbl_line.py)."""
        self.grbl_laser = int(getattr(self.machine, "grbl_laser_mode", 0)) != 0
        self.grbl_spindle = 5
        self.grbl_coolant = frozenset()
        self.grbl_s = 0.0                   # (in the scanner's state: it takes S words too, _grbl_route)
        self.grbl_idle = True
        self.grbl_jogging = False           # after a $J= until the next G-code line (system.c: JOG state)
        self._grbl_route()

    @property
    def grbl_s(self) -> float:
        """grbl's spindle speed in force (rpm; laser power in laser mode): the scanner's S_GRBL_S, since the scanner
        sets it on the lines it takes (scan.grbl_free_s)."""
        return float(self.st[S.S_GRBL_S])

    @grbl_s.setter
    def grbl_s(self, rpm: float) -> None:
        self.st[S.S_GRBL_S] = rpm

    def _grbl_route(self) -> None:
        """Which lines the Python interpreter must see on grbl (scan.I_TO_PYTHON): every line while the machine
        is idle (the first motion line ends that, :meth:`_grbl_syncs`) and while an M3 laser is on (a G0 / G1
        without axis words, or a move of no length, syncs there: gcode.c LASER_FORCE_SYNC, motion_control.c
        mc_line), which the scanner does not know; otherwise what the excluded objects need."""
        grbl_needs = self.grbl_idle or (self.grbl_laser and self.grbl_spindle == 3)
        exclude = getattr(self, "exclude", None)       # (set after the CNC state at start-up)
        excluded = exclude is not None and exclude.active
        self.ist[S.I_TO_PYTHON] = 1 if (grbl_needs or excluded) else 0
        # an S word on a moving G0/G1 syncs nothing in laser mode under M4, nor with the spindle off: the scanner
        # takes such lines (their S into grbl_s)
        self.ist[S.I_GRBL_S_FREE] = 1 if (self.grbl_spindle == 5 or (self.grbl_laser and self.grbl_spindle == 4)) \
            else 0

    def _grbl_line_shape(self, params: dict[str, Word]):
        """(motion mode after the line, axis words move in the motion mode, the line's G codes) from the grbl
        words of the line being run (gcode.c step 3: axis_command)."""
        words = self.grbl_words or ()
        gs = {round(w.value, 1) for w in words if w.letter == "G"}
        motion = int(self.ist[S.I_MOTION])
        for g in (0.0, 1.0, 2.0, 3.0, 38.2, 38.3, 38.4, 38.5, 80.0):
            if g in gs:
                motion = int(g) if g < 38 or g == 80.0 else int(round(g * 10))
        axes = any(k in params for k in "XYZ")
        axis_motion = axes and not gs & {10.0, 28.0, 30.0, 92.0, 43.1} and motion != 80
        return motion, axis_motion, gs

    def _grbl_syncs(self, ms, params: dict[str, Word]) -> None:
        """grbl 1.1's gc_execute stops the motion (``spindle_sync`` / ``coolant_sync``: the planner drains, the
        cycle ends) for a spindle speed change while the spindle turns (step 4), a spindle state change M3 / M4
        / M5 (step 7, in laser mode too) and a coolant change M7 / M8 / M9 (step 8); a repeated command that
        changes nothing does not stop. Each stop is a wait row (zero time: what it costs is the stop itself).

        In laser mode ($32=1, gcode.c "If in laser mode"): an S change on a line whose axis words move in the
        motion mode (GC_PARSER_LASER_ISMOTION; G0 too) does not stop; on a line without motion it still stops
        while the laser is on; under M3 a line without motion that changes the motion mode from G1/G2/G3 to
        another, or from another to G1/G2/G3 (a bare ``G1`` after ``G0``), stops even without an S change
        (LASER_FORCE_SYNC); and a G0 / G1 of no steps stops under M3 (motion_control.c mc_line, the empty
        block). Then the idle state of the machine after the line (:meth:`_grbl_idle_after`)."""
        spindle = self.grbl_spindle
        coolant = self.grbl_coolant
        motion, axis_motion, gs = self._grbl_line_shape(params)
        laser = self.grbl_laser
        if laser and ("S" in params or 3 in ms or 4 in ms):
            self._note_once("grbl laser", "grbl laser mode ($32=1): an S change on a line that moves does not "
                                          "stop the motion; M3 / M4 / M5 and S changes without motion still do")
        synced = False
        s_word = params.get("S")
        s_new = s_word.value if (s_word is not None and s_word.value is not None) else self.grbl_s
        force = False
        if laser and not axis_motion and spindle == 3:
            was_cut, is_cut = int(self.ist[S.I_MOTION]) in (1, 2, 3), motion in (1, 2, 3)
            force = was_cut != is_cut
        if (s_new != self.grbl_s or force) and spindle != 5 and not (laser and axis_motion):
            self._wait("S" if s_new != self.grbl_s else f"laser M3 G{motion}")
            synced = True
        self.grbl_s = s_new
        new_spindle, new_coolant = spindle, set(coolant)
        for mc in ms:
            if mc in (3, 4, 5):
                new_spindle = mc
            elif mc == 7 or mc == 8:
                new_coolant.add(mc)
            elif mc == 9:
                new_coolant.clear()
        if new_spindle != spindle:
            self._wait(f"M{new_spindle}")
            self.grbl_spindle = new_spindle
            synced = True
        if new_coolant != coolant:
            self._wait("M9" if not new_coolant else f"M{max(new_coolant)}")
            self.grbl_coolant = frozenset(new_coolant)
            synced = True
        offsets = self._grbl_offset_change(gs, params)
        if offsets is not None:
            self._wait(offsets)
            synced = True
        moves = axis_motion and motion != 80
        laser_m3 = laser and new_spindle == 3
        if moves and motion in (0, 1) and (laser_m3 or synced or self.grbl_idle):
            moves = self._grbl_line_moves(gs, params, laser_m3)
        probe = axis_motion and motion in (382, 383, 384, 385)
        self._grbl_idle_after(ms, gs, moves or bool(gs & {28.0, 30.0}), synced, probe)

    def _grbl_offset_change(self, gs: set, params: dict[str, Word]) -> str | None:
        """The code of a grbl line that stops the motion before its own because it changes the work offset or
        writes the EEPROM (None if none): grbl 1.1h's default build (config.h FORCE_BUFFER_SYNC_DURING_WCO_CHANGE,
        FORCE_BUFFER_SYNC_DURING_EEPROM_WRITE) drains the planner in gc_execute_line's steps 14, 15 and 19 —
        a G43.1 / G49 that changes the tool length offset, a G54-G59 other than the one in force, and every G10
        L2 / L20, G28.1 / G30.1 (EEPROM writes), G92 and G92.1, even when the values do not change. G28 / G30
        themselves do not stop."""
        for g in (10.0, 28.1, 30.1, 92.0, 92.1):
            if g in gs:
                return f"G{g:g}"
        for i, g in enumerate((54.0, 55.0, 56.0, 57.0, 58.0, 59.0)):
            if g in gs and i != self.work_index:
                return f"G{g:g}"
        if 49.0 in gs and self.tool_z != 0.0:
            return "G49"
        z = params.get("Z")
        if 43.1 in gs and z is not None and z.value is not None:
            unit = 25.4 if 20.0 in gs else (1.0 if 21.0 in gs else float(self.st[S.S_UNIT]))
            if z.value * unit != self.tool_z:
                return "G43.1"
        return None

    def _grbl_line_moves(self, gs: set, params: dict[str, Word], laser_m3: bool) -> bool:
        """Whether a G0 / G1 makes a planner block (planner.c: some axis changes by a step, its target
        ``lround(target·steps/mm)`` in grbl's floats); under an M3 laser a move of no steps stops the motion
        (motion_control.c mc_line on PLAN_EMPTY_BLOCK: spindle_sync)."""
        from ..planner.grbl import grbl_steps_of

        here = [float(self.st[S.S_X + a]) for a in range(3)]
        target = self._grbl_block_target(gs, params)
        spm = self._grbl_steps_per_mm()
        if (grbl_steps_of(target, spm) != grbl_steps_of(here, spm)).any():
            return True
        if laser_m3:
            self._wait("laser M3 move of no steps")
        return False

    def _grbl_steps_per_mm(self):
        """grbl's steps/mm ($100-$102) as the firmware holds them (float32)."""
        spm = getattr(self, "_grbl_spm", None)
        if spm is None:
            from ..planner.grbl import steps_per_mm_of

            spm = self._grbl_spm = steps_per_mm_of(self.machine)
        return spm

    def _grbl_idle_after(self, ms, gs: set, moves: bool, synced: bool, probe: bool) -> None:
        """The machine's state after a grbl line, for the ``$`` settings that follow (system.c runs them only
        when idle): a line that plans motion leaves it moving (a sender that waits for each ``ok``, grbl's
        simple_stream.py, lets grbl start the cycle at once); a sync with no motion after it (a spindle or
        coolant change, G4: mc_dwell) leaves it idle, and so do a probe (mc_probe_cycle waits for it to end)
        and M0 / M2 / M30 after the line's motion (gcode.c step 21: protocol_buffer_synchronize; M1 is ignored);
        any other line leaves it as it was."""
        self.grbl_jogging = False       # a G-code line: no more jog state (see grbl_line._grbl_jog)
        if probe:
            self.grbl_idle = True
        elif moves:
            self.grbl_idle = False
        elif synced or 4.0 in gs:
            self.grbl_idle = True
        if any(mc in (0, 2, 30) for mc in ms):
            self.grbl_idle = True
        self._grbl_route()

    # ------------------------------------------------------------------ M commands
    def _m_command(self, mc: int, params: dict[str, Word], used: set[str]) -> None:
        st, ist = self.st, self.ist
        m = self.machine
        if mc in (82, 83):
            ist[S.I_ABS_E] = 1 if mc == 82 else 0
        elif mc in QUIET_M:
            used.update(params)
        elif mc in WAIT_M:
            used.update(params)
            self._wait(f"M{mc}", m.heat_wait_time if mc in (109, 190, 191) else 0.0)
        elif mc == 400:
            self._wait("M400")
        elif mc == 1 and m.flavor == "grbl":
            used.update(params)     # grbl 1.1 (gcode.c): "Optional stop not supported. Ignore." — no stop
        elif mc in (0, 1, 60):     # M60: LinuxCNC's pallet-change pause, a pause like M0
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
                if mc == 220:
                    st[S.S_SPEED_F] = s / 100.0
                else:
                    self._flow_factor = s / 100.0
                    self._set_e_scale()
        elif mc == 200 and self.dialect == S.DIALECT_MARLIN:
            self._m200(params, used)
        elif mc == 211 and m.flavor == "marlin":
            used.update(params)
            s = self._value(params, "S")
            if s is not None:
                # M211 S0 / S1: Marlin's software endstops off / on (on: targets beyond them are clamped)
                self.ist[S.I_SOFT_CLAMP] = 1 if (s != 0.0 and self.soft_endstops) else 0
                self.event(f"M211 software endstops {'on' if s != 0.0 else 'off'}")
        elif mc == 600:
            used.update(params)
            self._wait("M600", self._macros.get("M600", float(getattr(m, "filament_change_time", 0.0))))
        else:
            used.update(params)
            self._unknown_or_macro(f"M{mc}")

    # ------------------------------------------------------------------ volumetric E (M200, UltiGCode)
    # E words are mm³ of plastic while volumetric mode is on; the machine moves E / (π·d²/4) mm of filament of
    # diameter d (Marlin's planner.calculate_volumetric_multipliers, RepRapFirmware's M200). The factor joins
    # M221's in S_FLOW_F, which scales every E change (scanner and interpreter alike).
    _flow_factor = 1.0               # M221 S / 100
    volumetric_d = None              # mm, filament diameter while E is in mm³; None = E in mm of filament
    _filament_d = None               # mm, M200 D last given (Marlin keeps it across M200 S0 / S1)

    def _set_e_scale(self) -> None:
        scale = self._flow_factor
        if self.volumetric_d is not None:
            scale = scale / (math.pi * self.volumetric_d * self.volumetric_d / 4.0)
        self.st[S.S_FLOW_F] = scale

    def set_volumetric(self, diameter_mm: float | None) -> None:
        """E in mm³ from now on, for filament of ``diameter_mm`` (None: E in mm of filament again)."""
        if diameter_mm is not None:
            self._filament_d = float(diameter_mm)
        self.volumetric_d = None if diameter_mm is None else float(diameter_mm)
        self._set_e_scale()

    @property
    def filament_diameter_mm(self) -> float:
        """mm: the filament the E figures are in (the volumetric diameter when E was in mm³)."""
        d = self.volumetric_d if self.volumetric_d is not None else self._filament_d
        return float(d) if d is not None else float(self.machine.filament_diameter)

    def _m200(self, params: dict[str, Word], used: set[str]) -> None:
        """M200 [D<mm>] [S<0|1>]: Marlin 2 / RepRapFirmware volumetric extrusion. D > 0 sets the diameter and
        turns volumetric E on, D0 turns it off; S1 / S0 turn it on / off (with the last D, else the machine's
        filament diameter). Without D or S it reports (no change)."""
        used.update(params)
        on = self.volumetric_d is not None
        can = True
        d = self._value(params, "D")
        if d is not None:
            d_mm = d * float(self.st[S.S_UNIT])
            # a filament is a few mm thick: outside 0.05 … 50 mm a D is a typo (and a tiny one would make 1/d² inf)
            if not (d_mm == 0.0 or 0.05 <= d_mm <= 50.0):
                self.error("M200 D must be a filament diameter of 0.05 to 50 mm, or 0 (volumetric off)")
            if d_mm > 0.0:
                self._filament_d = d_mm
                on = True
            else:
                can = False
        s = self._value(params, "S")
        if s is not None:
            on = s != 0.0
        if d is None and s is None:
            return
        diameter = self._filament_d if self._filament_d is not None else float(self.machine.filament_diameter)
        self.volumetric_d = diameter if (on and can) else None
        self._set_e_scale()
        self.event("M200 volumetric E " + (f"on (filament {diameter:g} mm)" if self.volumetric_d else "off"))

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
            if str(getattr(self.machine, "firmware", "")).startswith("marlin"):
                # the Marlin models run it as Marlin does: its acceleration cap, its advance interrupt
                self.warn(f"M{mc} {letter}{k:g}: Marlin's linear advance (K = {k:g} s): its acceleration cap "
                          "and, for steps, its extruder interrupt")
            else:
                self.warn(f"M{mc} {letter}{k:g}: planned as Klipper's pressure advance (K = {k:g} s, smoothed "
                          f"over {float(self._limits_rows[0]['pa_smooth_t']):g} s)")
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

