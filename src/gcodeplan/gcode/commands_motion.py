"""The interpreter's motion commands: G0/G1, arcs, canned cycles, G10/G11 retraction, G28 homing and G92
(a part of :class:`.interp.Interpreter`)."""
from __future__ import annotations

import math

import numpy as np

from .._jit import njit
from ..schema import (FLAG_ARC, FLAG_CANNED, FLAG_FIRMWARE_RETRACT, FLAG_HOMING, FLAG_RAPID, FLAG_RETRACT,
                      KIND_DWELL, KIND_EXTRUDE_ONLY, KIND_PRINT, KIND_TRAVEL, KIND_WAIT)
from . import scan as S
from .lexing import Word

_NO_MASK = np.zeros(0, dtype=np.bool_)


@njit(cache=True)
def pieces_through_kernel(ends, x0, y0, z0, e0, e1):
    """Straight pieces from (x0, y0, z0) through the points ``ends`` (float64[n, 3], mm), E going linearly by
    piece count from e0 to exactly e1 (arc chords, canned-cycle moves).

    Returns (starts float64[n, 3], lengths mm, E at each end, E at each start). Lengths are
    sqrt((dx² + dy²) + dz²), the order NumPy's row sum and Klipper's move length use.
    """
    n = ends.shape[0]
    starts = np.empty((n, 3))
    d = np.empty(n)
    es = np.empty(n)
    e_starts = np.empty(n)
    de = e1 - e0
    px, py, pz, pe = x0, y0, z0, e0
    for i in range(n):
        starts[i, 0] = px
        starts[i, 1] = py
        starts[i, 2] = pz
        dx = ends[i, 0] - px
        dy = ends[i, 1] - py
        dz = ends[i, 2] - pz
        d[i] = math.sqrt(dx * dx + dy * dy + dz * dz)
        e = e1 if i == n - 1 else e0 + de * ((i + 1) / n)
        es[i] = e
        e_starts[i] = pe
        px, py, pz, pe = ends[i, 0], ends[i, 1], ends[i, 2], e
    return starts, d, es, e_starts


class MotionCommands:
    """Mixed into :class:`.interp.Interpreter`: commands that move the head or set its position."""

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
                if self.keeps_e_sets:
                    self.e_position_sets.append((self.line, v * scale))
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
        f32 = ist[S.I_F32_REL] != 0
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
                out[a] = float(S.relative_sum(out[a], v * scale, f32))
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
            f32 = ist[S.I_F32_REL] != 0
            new_elog = float(S.relative_sum(elog, ev, f32))
            de_log = new_elog - elog if f32 else ev
            elog = new_elog
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

    def _soft_clamp(self, x: float, y: float, z: float) -> tuple[float, float, float]:
        """Marlin's apply_motion_limits: a target beyond the software endstops goes to them instead (every
        axis, moving or not). Counted, and the first one is a warning naming its line."""
        st = self.st
        out = [x, y, z]
        for a in range(3):
            lo, hi = float(st[S.S_SOFT_LO + a]), float(st[S.S_SOFT_HI + a])
            v = out[a]
            if v < lo or v > hi:
                out[a] = lo if v < lo else hi
                if self.soft_clamped_first_line is None:
                    name = "XYZ"[a]
                    self.warn(f"{name} {v:.3f} is beyond the software endstop ({name} {'min' if v < lo else 'max'} "
                              f"{out[a]:g}): Marlin moves to {out[a]:g} instead (apply_motion_limits), and so does "
                              f"gcodeplan; the summary counts such moves (M211 S0 turns the endstops off)")
                    self.soft_clamped_first_line = int(self.line)
        if out[0] != x or out[1] != y or out[2] != z:
            self.soft_clamped += 1
        return out[0], out[1], out[2]

    def _soft_clamp_points(self, pts: np.ndarray) -> None:
        """:meth:`_soft_clamp` on each row of ``pts`` (x, y, z in its first columns; Marlin's plan_arc clamps
        every segment end), in place."""
        if not self.ist[S.I_SOFT_CLAMP]:
            return
        xyz = pts[:, :3]
        if ((xyz >= self.st[S.S_SOFT_LO:S.S_SOFT_LO + 3]) & (xyz <= self.st[S.S_SOFT_HI:S.S_SOFT_HI + 3])).all():
            return          # the usual arc, inside the travel: no per-point Python loop
        for i in range(pts.shape[0]):
            pts[i, 0], pts[i, 1], pts[i, 2] = self._soft_clamp(float(pts[i, 0]), float(pts[i, 1]),
                                                               float(pts[i, 2]))

    def _linear(self, code: int, params: dict[str, Word], used: set[str], f: float | None,
                machine_coords: bool) -> None:
        st = self.st
        used.update("XYZEF")
        scale = float(st[S.S_UNIT])
        x0, y0, z0, e0 = float(st[S.S_X]), float(st[S.S_Y]), float(st[S.S_Z]), float(st[S.S_E])
        x1, y1, z1 = self._targets(params, machine_coords)
        if self.ist[S.I_SOFT_CLAMP] and all(math.isfinite(v) for v in (x1, y1, z1)):
            x1, y1, z1 = self._soft_clamp(x1, y1, z1)
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
            bad = [f"{k} {v:g}" for k, v in zip("XYZE", (x1, y1, z1, e1)) if not math.isfinite(v)]
            self.error("coordinate out of range: " + (", ".join(bad) if bad else
                       f"the move from X{x0:g} Y{y0:g} Z{z0:g} to X{x1:g} Y{y1:g} Z{z1:g} has no finite length"))
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
        from .arcs_grbl import grbl_arc_chords

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
        if flavor == "klipper":
            self._klipper_arc_refusals(clockwise, centre, r)
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
        if m.firmware.startswith("marlin"):     # Marlin's ARC_SUPPORT segments in its floats (arcs_marlin.py)
            return self._marlin_arc(clockwise, (x0, y0, z0, e0), (x1, y1, z1, e1), elog, ijk, r, turns - 1)
        try:
            if flavor == "grbl":        # grbl's own chord count and single-precision chords (arcs_grbl.py)
                pts = grbl_arc_chords((x0, y0, z0), (x1, y1, z1), ijk, r, self.plane, clockwise, m.arc_tolerance)
            else:
                pts = arc_chords((x0, y0, z0), (x1, y1, z1), ijk=ijk, r=r, plane=self.plane, clockwise=clockwise,
                                 turns=int(turns), tolerance=m.arc_tolerance, resolution=m.arc_resolution,
                                 units_mm=float(st[S.S_UNIT]) == 1.0)
        except (ArcError, ValueError) as err:
            self.error(str(err))
        self._soft_clamp_points(pts)
        self.arcs += 1
        n = pts.shape[0]
        de = e1 - e0
        starts, d, es, e_starts = pieces_through_kernel(pts, x0, y0, z0, e0, e1)
        if n and de > 0.0 and d.max() > 0.0:
            self._layer_check(float(pts[0, 2]))
        st[S.S_X], st[S.S_Y], st[S.S_Z] = x1, y1, z1
        if n:
            st[S.S_X], st[S.S_Y], st[S.S_Z] = float(pts[-1, 0]), float(pts[-1, 1]), float(pts[-1, 2])
        st[S.S_E] = e1
        st[S.S_ELOG] = elog
        self._bulk(pts, starts, es, e_starts, d, FLAG_ARC, float(st[S.S_FEED]) * float(st[S.S_SPEED_F]))

    def _klipper_arc_refusals(self, clockwise: bool, centre: list, r: float | None) -> None:
        """The G2/G3 Klipper's gcode_arcs refuses, in its order: relative coordinates (G91), an R word, no centre
        offset in the plane (I J for G17, I K for G18, J K for G19; a 0 is none). Each is an error there,
        which stops a print from its virtual SD card: here an error quoting Klipper's answer."""
        answer = None
        if not int(self.ist[S.I_ABS_COORD]):
            answer = "G2/G3 does not support relative move mode"
        elif r is not None:
            answer = "G2/G3 does not support R moves"
        else:
            a, b = {17: (0, 1), 18: (0, 2), 19: (1, 2)}[self.plane]
            if not (centre[a] or centre[b]):
                answer = "G2/G3 requires IJ, IK or JK parameters"
        if answer is not None:
            self.error(f"G{2 if clockwise else 3}: Klipper answers '{answer}', an error, which stops a print from "
                       "its virtual SD card")

    def _marlin_arc(self, clockwise, start, end, elog1, ijk, r, circles) -> None:
        """G2/G3 on a Marlin-model machine: plan_arc's segments (gcode/arcs_marlin.py), E by Marlin's equal
        float steps of the logical E; an arc Marlin plans nothing for leaves the position where it was."""
        from .arcs_marlin import PLANE_AXES, arc_settings, marlin_arc_points, marlin_r_offset

        st = self.st
        settings = arc_settings(self.machine)
        if not settings.enabled:
            self.error("G2/G3: this Marlin build has ARC_SUPPORT off; the firmware ignores the line (unknown "
                       "command) and every move after it starts elsewhere")
        if circles and not settings.p_circles:
            self.warn("G2/G3 P: this Marlin build has ARC_P_CIRCLES off (Marlin's default): it ignores P")
            circles = 0
        elif circles > 100:
            self.error("G2/G3 P: Marlin refuses more than 100 circles (\"Invalid arc args\")")
        p, q, _ = PLANE_AXES[self.plane]
        if ijk is not None:
            offset = (ijk[p], ijk[q])
        else:
            offset = marlin_r_offset(start, end, r, clockwise)    # Marlin takes R's chord in X/Y whatever the plane
        if offset is None or offset[0] == 0 and offset[1] == 0:
            self.error("G2/G3: Marlin refuses this arc (\"Invalid arc args\": no centre offset, R0, or R with the "
                       "end at the start)")
        elog0 = float(st[S.S_ELOG])
        # the feed as Marlin scales it (MMS_SCALED), only for ARC_SEGMENTS_PER_SEC
        fr = np.float32(np.float32(np.float32(float(st[S.S_FEED]) * 60.0) / np.float32(60.0)) * np.float32(0.01))
        fr = float(fr * np.float32(float(st[S.S_SPEED_F]) * 100.0))
        try:
            pts = marlin_arc_points(start[:3] + (elog0,), end[:3] + (elog1,), offset, clockwise, self.plane, fr,
                                    settings, circles=int(circles))
        except ValueError as err:
            self.error(str(err))
        self.arcs += 1
        n = pts.shape[0]
        if n == 0:
            return
        x0, y0, z0, e0 = start
        e1 = end[3]
        ends = np.ascontiguousarray(pts[:, :3])
        ends[-1] = end[:3]               # the target as the file gives it (the model rounds it as Marlin does)
        self._soft_clamp_points(ends)
        end = (float(ends[-1, 0]), float(ends[-1, 1]), float(ends[-1, 2])) + tuple(end[3:])
        starts, d, es, e_starts = pieces_through_kernel(ends, x0, y0, z0, e0, e1)
        # E at each segment end: Marlin's float steps of the logical E, carried into the machine's E
        es[:-1] = e0 + (pts[:-1, 3] - elog0) * float(st[S.S_FLOW_F])
        e_starts[1:] = es[:-1]
        if e1 - e0 > 0.0 and d.max() > 0.0:
            self._layer_check(float(pts[0, 2]))
        st[S.S_X], st[S.S_Y], st[S.S_Z] = end[:3]
        st[S.S_E] = e1
        st[S.S_ELOG] = elog1
        self._bulk(ends, starts, es, e_starts, d, FLAG_ARC, float(st[S.S_FEED]) * float(st[S.S_SPEED_F]))

    def _bulk(self, ends, starts, es, e_starts, d, flags, feed_v, rapid_mask=None, dwell=None) -> None:
        """Rows for a sequence of straight pieces (arc chords, cycle moves)."""
        from ..schema import MOVE_DTYPE

        self._flush_rows_to_arrays()
        a = np.zeros(ends.shape[0], dtype=MOVE_DTYPE)
        k = S.piece_rows_kernel(ends, starts, es, e_starts, d, int(self.line), int(flags), float(feed_v),
                                _NO_MASK if rapid_mask is None else rapid_mask,
                                _NO_MASK if dwell is None else dwell, self.dialect == S.DIALECT_CNC,
                                self.st, self.ist, a)
        self.row_arrays.append(a[:k])

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
            rows, new_state = expand_cycle(code, words, state, 0.254, plane=self.plane, unit=scale)
        except CycleError as err:
            self.error(str(err))
        self.cycle_state = new_state
        self.canned_cycles += 1
        if rows.shape[0] == 0:
            return
        ends = np.ascontiguousarray(rows[:, :3] + np.array(off))
        e = float(st[S.S_E])
        starts, d, _, _ = pieces_through_kernel(ends, float(st[S.S_X]), float(st[S.S_Y]), float(st[S.S_Z]), e, e)
        es = np.full(rows.shape[0], e)
        motion = rows[:, 3]
        dwell = motion == 2
        self._bulk(ends, starts, es, es, d, FLAG_CANNED, float(st[S.S_FEED]) * float(st[S.S_SPEED_F]),
                   rapid_mask=motion == 0, dwell=dwell)
        if dwell.any():
            self.row_arrays[-1]["dwell_t"][self.row_arrays[-1]["kind"] == KIND_DWELL] = rows[dwell, 4]
        st[S.S_X], st[S.S_Y], st[S.S_Z] = float(ends[-1, 0]), float(ends[-1, 1]), float(ends[-1, 2])
