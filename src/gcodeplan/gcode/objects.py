"""Objects of a print: their names, and Klipper's ``exclude_object`` move transform.

Slicers label which object each move belongs to in four ways, all understood here (the interpreter calls
:meth:`ObjectTable.index` and sets ``ist[I_OBJECT]``, which tags every MOVE row's ``object`` field):

* Klipper: ``EXCLUDE_OBJECT_DEFINE NAME=…``, ``EXCLUDE_OBJECT_START NAME=…`` / ``EXCLUDE_OBJECT_END``;
* Marlin / Prusa firmware: ``M486 S<n>`` (``S-1`` = none), names from ``M486 A<name>``;
* PrusaSlicer / SuperSlicer / OrcaSlicer comments: ``; printing object …`` / ``; stop printing object …``;
* Cura: ``;MESH:<name>`` (``;MESH:NONMESH`` = none).

Names are matched case-insensitively (Klipper upper-cases them).

:class:`KlipperExclude` runs a print with some objects cancelled the way Klipper's
``klippy/extras/exclude_object.py`` does: a move inside an excluded object is not executed, but the
G-code position still follows it; the offset between the G-code position and the toolhead is carried
until the G-code moves away in XY (resp. Z), and the extruder offset (the filament the excluded moves
would have pushed, plus Klipper's retraction-state adjustment) is kept for the rest of the print, so
with absolute E the next object does not extrude the skipped filament. Units: mm.
"""
from __future__ import annotations

import math

import numpy as np

from ..schema import FLAG_HOMING, FLAG_RETRACT, KIND_DWELL, KIND_EXTRUDE_ONLY, KIND_PRINT, KIND_TRAVEL, KIND_WAIT

MAX_OBJECTS = 32000   # MOVE.object is an int16


class ObjectTable:
    """Object names in order of first appearance; ``index(name)`` gives (and adds) a name's index."""

    def __init__(self):
        self.names: list[str] = []
        self._index: dict[str, int] = {}

    def index(self, name: str) -> int:
        """The index of ``name`` (case-insensitive), added on first use. Raises ValueError when full."""
        key = name.casefold()
        i = self._index.get(key)
        if i is None:
            if len(self.names) >= MAX_OBJECTS:
                raise ValueError("too many object names")
            i = len(self.names)
            self.names.append(name)
            self._index[key] = i
        return i

    def find(self, name: str) -> int | None:
        """The index of ``name`` if known, else None."""
        return self._index.get(name.casefold())


class KlipperExclude:
    """Klipper's exclude_object transform applied to MOVE rows (see the module docstring).

    State, in Klipper's names: ``offset`` (x, y, z, e: G-code position minus toolhead position),
    ``last_position`` (the G-code position of the last move), ``last_extruded`` / ``last_excluded``
    (that of the last executed / skipped move), ``max_extruded`` / ``max_excluded`` (highest E of each),
    ``adj`` (Klipper's ``extruder_adj``). The E offset is folded into the interpreter's running machine E
    (``st[S_E]`` is always the toolhead's E), so only the XYZ offsets need the Python path; the
    interpreter sends lines through here only while :attr:`active`.
    """

    def __init__(self, names):
        self.wanted = {str(n).casefold(): str(n) for n in names}
        self.seen: set[str] = set()
        self.excluded_idx: set[int] = set()
        self.offset = [0.0, 0.0, 0.0, 0.0]
        self.last_position = [0.0, 0.0, 0.0, 0.0]
        self.last_extruded = [0.0, 0.0, 0.0, 0.0]
        self.last_excluded = [0.0, 0.0, 0.0, 0.0]
        self.max_extruded = 0.0     # Klipper starts both at 0
        self.max_excluded = 0.0
        self.adj = 0.0
        self.in_region = False
        self.active = False

    # ------------------------------------------------------------------ names
    def register(self, name: str, idx: int) -> None:
        """An object name met in the file (its index in the ObjectTable)."""
        key = name.casefold()
        if key in self.wanted:
            self.seen.add(key)
            self.excluded_idx.add(idx)

    def exclude(self, name: str, idx: int) -> None:
        """``EXCLUDE_OBJECT NAME=…`` in the file itself: cancel that object from here on."""
        self.wanted.setdefault(name.casefold(), name)
        self.register(name, idx)

    def missing(self) -> list[str]:
        """Names asked for that the file never labelled."""
        return [v for k, v in self.wanted.items() if k not in self.seen]

    # ------------------------------------------------------------------ activation
    def activate(self, x: float, y: float, z: float, e_real: float, max_e_since: float) -> None:
        """Start sending moves through the transform. (x, y, z): the G-code position, equal to the
        toolhead's while dormant; ``e_real``: the toolhead E; ``max_e_since``: the highest E the moves
        executed since the last :meth:`dormant` reached (toolhead E, -inf if none)."""
        k = self.offset[3]
        pos = [x, y, z, e_real + k]
        self.last_position = list(pos)
        self.last_extruded = list(pos)
        if max_e_since > -math.inf:
            self.max_extruded = max(self.max_extruded, max_e_since + k)
        self.active = True

    def can_sleep(self, current_object: int) -> bool:
        """True when the transform changes nothing until the next excluded object starts."""
        return (not self.in_region and current_object not in self.excluded_idx and self.adj == 0.0
                and self.offset[0] == 0.0 and self.offset[1] == 0.0 and self.offset[2] == 0.0)

    # ------------------------------------------------------------------ rows
    def apply(self, rows: np.ndarray, accel_of) -> np.ndarray:
        """The rows of one G-code line as the toolhead runs them. ``rows`` have G-code positions with
        E measured from the toolhead E before the line (the fold); ``accel_of(has_xyz, de)`` gives a
        move's acceleration by its kind. Returns the rows kept (positions rewritten)."""
        k0 = self.offset[3]
        keep = np.ones(len(rows), dtype=bool)
        off = self.offset
        for i in range(len(rows)):
            r = rows[i]
            kind = int(r["kind"])
            real = self._real()
            if kind == KIND_DWELL or kind == KIND_WAIT:
                if r["flags"] & FLAG_HOMING or (r["x1"], r["y1"], r["z1"]) != (r["x0"], r["y0"], r["z0"]):
                    # homing / SET_KINEMATIC_POSITION sets the toolhead where the G-code says
                    off[0] = off[1] = off[2] = 0.0
                    for a, f in enumerate(("x1", "y1", "z1")):
                        self.last_position[a] = float(r[f])
                    r["x0"], r["y0"], r["z0"] = real[0], real[1], real[2]
                else:
                    r["x0"] = r["x1"] = real[0]
                    r["y0"] = r["y1"] = real[1]
                    r["z0"] = r["z1"] = real[2]
                r["e0"] = r["e1"] = real[3]
                continue
            new = [float(r["x1"]), float(r["y1"]), float(r["z1"]), float(r["e1"]) + k0]
            if int(r["object"]) in self.excluded_idx:
                # Klipper's _ignore_move
                self.in_region = True
                for a in range(3):
                    off[a] = new[a] - self.last_extruded[a]
                off[3] += new[3] - self.last_position[3]
                self.last_position = new
                self.last_excluded = list(new)
                self.max_excluded = max(self.max_excluded, new[3])
                keep[i] = False
                continue
            if self.in_region:
                # Klipper's _move_from_excluded_region: compensate the retraction-state difference
                self.in_region = False
                self.adj = (self.max_excluded - self.last_excluded[3]
                            - (self.max_extruded - self.last_extruded[3]))
            # Klipper's _normal_move
            self.last_position = new
            self.last_extruded = list(new)
            self.max_extruded = max(self.max_extruded, new[3])
            ex = self.last_excluded
            if (off[0] != 0.0 or off[1] != 0.0) and (new[0] != ex[0] or new[1] != ex[1]):
                off[0] = off[1] = off[2] = 0.0
                off[3] += self.adj
                self.adj = 0.0
            if off[2] != 0.0 and new[2] != ex[2]:
                off[2] = 0.0
            if self.adj != 0.0 and new[3] != ex[3]:
                off[3] += self.adj
                self.adj = 0.0
            tx = [new[a] - off[a] for a in range(4)]
            if not self._rewrite(r, real, tx, accel_of):
                keep[i] = False
        return rows[keep]

    def _real(self) -> list[float]:
        """The toolhead position: the G-code position minus the offsets."""
        return [self.last_position[a] - self.offset[a] for a in range(4)]

    @staticmethod
    def _rewrite(r, start, end, accel_of) -> bool:
        """Set the row to run from ``start`` to ``end`` (toolhead x, y, z, e); False if it moves nothing."""
        dx, dy, dz = end[0] - start[0], end[1] - start[1], end[2] - start[2]
        de = end[3] - start[3]
        d = math.sqrt(dx * dx + dy * dy + dz * dz)
        if d == 0.0 and de == 0.0:
            return False
        r["x0"], r["y0"], r["z0"], r["e0"] = start
        r["x1"], r["y1"], r["z1"], r["e1"] = end
        if d > 0.0:
            kind = KIND_PRINT if de > 0.0 else KIND_TRAVEL
        else:
            kind = KIND_EXTRUDE_ONLY
            d = abs(de)
        if kind != int(r["kind"]):
            r["accel"] = accel_of(kind != KIND_EXTRUDE_ONLY, de)
        r["kind"] = kind
        r["move_d"] = d
        r["flags"] = (int(r["flags"]) & ~FLAG_RETRACT) | (FLAG_RETRACT if de < 0.0 else 0)
        return True

    def toolhead_e(self) -> float:
        """The toolhead E after the rows applied so far (what the interpreter's running E becomes)."""
        return self.last_position[3] - self.offset[3]


__all__ = ["ObjectTable", "KlipperExclude", "MAX_OBJECTS"]
