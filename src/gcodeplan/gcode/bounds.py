"""Where the program takes the machine: travel limits, absurd lengths, bounding boxes, speed caps.

One numba pass over each MOVE batch (called by :class:`~.reader.GcodeReader` as the batch is made):

* **Travel limits** (Klipper's cartesian.py / corexy.py ``check_move``): a move that changes an axis and
  ends outside that axis' ``[position_min, position_max]`` is refused with Klipper's own error text
  ``Move out of range: x y z [e]``. Only the end point and only the axes that move are checked, as
  Klipper does (a start point was the end of an earlier move; a ``G92`` does not move the machine).
  Klipper checks an axis only once it is homed; in gcodeplan's model the machine starts homed (at
  ``home``), so every move is checked. That is never stricter than Klipper, which refuses any move
  before homing ("Must home axis first"). Kinematics whose reach is not a box (delta: tower
  heights and ``print_radius``) add their own test with :func:`register_reach_check`; the per-axis
  test still applies to them.
* **Absurd numbers**: whatever the limits, a move longer than :data:`MAX_MOVE_MM` (1 km; no printer
  or mill travels that far in one move) is an error naming the line: a unit or typing error would
  otherwise give an estimate of billions of hours (the total-time rule is in report/summary.py).
* **Bounding boxes** of printing and of travel moves (start and end points, mm), and the number of
  moves whose requested feed rate is above the speed limit in force (toolhead max velocity, an
  axis' max velocity along the move, the extruder's limits): firmware caps them, so does the
  planner; the summary says so once and names the first line.
"""
from __future__ import annotations

import math
from collections.abc import Callable

from .._jit import njit
import numpy as np

from ..errors import GcodeError
from ..schema import KIND_EXTRUDE_ONLY, KIND_PRINT, KIND_TRAVEL, LIMITS_DTYPE

MAX_MOVE_MM = 1e6      # mm: one move longer than this is an error (see the module docstring)

# accumulator slots (float64 array)
ACC_PRINT_LO, ACC_PRINT_HI = 0, 3        # x, y, z minima at 0..2, maxima at 3..5
ACC_TRAVEL_LO, ACC_TRAVEL_HI = 6, 9
ACC_CAPPED = 12                          # moves whose feed was above the speed limit
ACC_CAPPED_LINE = 13                     # line of the first one (0 = none yet)
N_ACC = 14

# results of the kernel
OK, OUT_OF_RANGE, TOO_LONG = 0, 1, 2

# LIMITS columns the kernel reads, in this order
_LIM_COLS = ("max_v", "axis_v_x", "axis_v_y", "axis_v_z", "axis_v_e", "extrude_only_v")

# kinematics name -> fn(batch, machine) -> (row, message) of the first unreachable move, or None
_REACH_CHECKS: dict[str, Callable[[np.ndarray, object], tuple[int, str] | None]] = {}


def register_reach_check(kinematics: str, fn: Callable[[np.ndarray, object], tuple[int, str] | None]) -> None:
    """Add a reachability test for ``kinematics`` (e.g. ``"delta"``: tower heights, print radius).

    ``fn(batch, machine)`` gets each MOVE batch (mm, machine coordinates) and returns ``(row, message)``
    of the first move the machine cannot reach, or None; the reader raises it as an error at that
    row's line. The per-axis position limits are checked as well, before it.
    """
    _REACH_CHECKS[kinematics] = fn


def new_accumulator() -> np.ndarray:
    """Empty running state for :func:`motion_kernel`: boxes inverted (min = +inf), no capped move."""
    acc = np.zeros(N_ACC)
    for base in (ACC_PRINT_LO, ACC_TRAVEL_LO):
        acc[base:base + 3] = math.inf
        acc[base + 3:base + 6] = -math.inf
    return acc


@njit(cache=True)
def _box_add(acc, base, x0, y0, z0, x1, y1, z1):
    acc[base] = min(acc[base], x0, x1)
    acc[base + 1] = min(acc[base + 1], y0, y1)
    acc[base + 2] = min(acc[base + 2], z0, z1)
    acc[base + 3] = max(acc[base + 3], x0, x1)
    acc[base + 4] = max(acc[base + 4], y0, y1)
    acc[base + 5] = max(acc[base + 5], z0, z1)


@njit(cache=True)
def _speed_cap(L, dx, dy, dz, de, move_d, klipper):
    """mm/s: the highest path speed the limits row ``L`` allows for this move (the planner's
    prepare.py rules: toolhead, per axis v ≤ V_i·d/|d_i|, extruder limits for retractions and
    extrude-only moves; Klipper gives extrude-only moves no toolhead limit)."""
    xyz = dx != 0.0 or dy != 0.0 or dz != 0.0
    cap = math.inf
    if xyz or not klipper:
        cap = L[0]
    if dx != 0.0:
        cap = min(cap, L[1] * move_d / abs(dx))
    if dy != 0.0:
        cap = min(cap, L[2] * move_d / abs(dy))
    if dz != 0.0:
        cap = min(cap, L[3] * move_d / abs(dz))
    if de != 0.0:
        cap = min(cap, L[4] * move_d / abs(de))
        if (dx == 0.0 and dy == 0.0) or de < 0.0:
            cap = min(cap, L[5] * move_d / abs(de))
    return cap


# _nrt=False: the kernel allocates nothing, and without numba's reference counting the limits row taken per
# move and the accumulator handed to _box_add cost no atomic incref/decref (36 -> 9 ns per move)
@njit(cache=True, _nrt=False)
def motion_kernel(moves, lo, hi, lim, klipper, acc):
    """One pass over MOVE rows: (OK, -1, -1), or (OUT_OF_RANGE, row, axis) / (TOO_LONG, row, -1) for
    the first refused row; updates ``acc`` (boxes mm, capped-move count and first line)."""
    for i in range(moves.shape[0]):
        mv = moves[i]
        k = mv.kind
        if k != KIND_TRAVEL and k != KIND_PRINT and k != KIND_EXTRUDE_ONLY:
            continue
        dx = mv.x1 - mv.x0
        dy = mv.y1 - mv.y0
        dz = mv.z1 - mv.z0
        de = mv.e1 - mv.e0
        # Klipper's _check_endstops: an axis that moves must end inside its range
        if dx != 0.0 and (mv.x1 < lo[0] or mv.x1 > hi[0]):
            return OUT_OF_RANGE, i, 0
        if dy != 0.0 and (mv.y1 < lo[1] or mv.y1 > hi[1]):
            return OUT_OF_RANGE, i, 1
        if dz != 0.0 and (mv.z1 < lo[2] or mv.z1 > hi[2]):
            return OUT_OF_RANGE, i, 2
        if mv.move_d > MAX_MOVE_MM:
            return TOO_LONG, i, -1
        if mv.move_d == 0.0:
            continue
        if k == KIND_PRINT:
            _box_add(acc, ACC_PRINT_LO, mv.x0, mv.y0, mv.z0, mv.x1, mv.y1, mv.z1)
        elif k == KIND_TRAVEL:
            _box_add(acc, ACC_TRAVEL_LO, mv.x0, mv.y0, mv.z0, mv.x1, mv.y1, mv.z1)
        if mv.feed_v < math.inf and 0 <= mv.limits < lim.shape[0]:
            cap = _speed_cap(lim[mv.limits], dx, dy, dz, de, mv.move_d, klipper)
            if mv.feed_v > cap * (1.0 + 1e-12):
                if acc[ACC_CAPPED] == 0.0:
                    acc[ACC_CAPPED_LINE] = mv.line
                acc[ACC_CAPPED] += 1.0
    return OK, -1, -1


def box(acc: np.ndarray, base: int) -> dict[str, list[float]] | None:
    """{"x": [min, max], "y": …, "z": …} (mm) from an accumulator slot, None when empty."""
    if not math.isfinite(acc[base]):
        return None
    return {a: [float(acc[base + k]), float(acc[base + 3 + k])] for k, a in enumerate("xyz")}


def firmware_refusal(machine) -> str:
    """What the machine's firmware does with a move past its travel, for the out-of-range error."""
    if machine.flavor == "klipper" or machine.firmware == "klipper":
        return "Klipper refuses this move"
    if machine.flavor == "linuxcnc":
        return "LinuxCNC refuses it: the move exceeds the axis' soft limit"
    if machine.flavor == "grbl":
        return ("grbl halts there with ALARM:2 when its soft limits are on ($20=1), else the machine runs into the "
                "end of its travel")
    if machine.flavor == "marlin":
        return ("Marlin's software endstops would clamp the move to them, but they are off (M211 S0, or not "
                "modelled for this kinematics): the machine would run into the end of its travel")
    return "the machine cannot go there"


class MotionChecker:
    """Running checks of one file (see the module docstring); :meth:`check` per MOVE batch."""

    def __init__(self, machine, path: str):
        self.machine = machine
        self.path = path
        self.lo = np.array([machine.axes[a].position_min for a in "xyz"], dtype=np.float64)
        self.hi = np.array([machine.axes[a].position_max for a in "xyz"], dtype=np.float64)
        self.klipper = machine.flavor == "klipper"
        self.acc = new_accumulator()
        self._lim = np.zeros((0, len(_LIM_COLS)))
        self._reach = _REACH_CHECKS.get(machine.kinematics)

    def _limits(self, rows: list) -> np.ndarray:
        """The LIMITS columns the kernel reads, converted again only when the table has grown."""
        if len(rows) != len(self._lim):
            table = np.array(rows, dtype=LIMITS_DTYPE)
            self._lim = np.ascontiguousarray(np.stack([table[c] for c in _LIM_COLS], axis=1), dtype=np.float64)
        return self._lim

    def check(self, batch: np.ndarray, limit_rows: list) -> None:
        """Raise GcodeError at the first refused move of ``batch``; fold the rest into the totals."""
        if batch.size == 0:
            return
        code, row, axis = motion_kernel(batch, self.lo, self.hi, self._limits(limit_rows), self.klipper, self.acc)
        if code == OUT_OF_RANGE:
            mv = batch[row]
            name = "xyz"[axis]
            v = float(mv[name + "1"])
            raise GcodeError(
                f"Move out of range: {mv['x1']:.3f} {mv['y1']:.3f} {mv['z1']:.3f} [{mv['e1']:.3f}] "
                f"({name.upper()} {v:.3f} is outside position_min {self.lo[axis]:g} … position_max "
                f"{self.hi[axis]:g}: {firmware_refusal(self.machine)}; --no-bounds turns the check off)",
                self.path, int(mv["line"]))
        if code == TOO_LONG:
            mv = batch[row]
            raise GcodeError(f"a move of {float(mv['move_d']):.6g} mm: no machine travels over {MAX_MOVE_MM:g} mm "
                             f"(1 km) in one move; a unit or number error?", self.path, int(mv["line"]))
        if self._reach is not None:
            bad = self._reach(batch, self.machine)
            if bad is not None:
                raise GcodeError(bad[1], self.path, int(batch["line"][bad[0]]))

    def fill(self, summary) -> None:
        """Copy the totals into a ParseSummary (mm boxes, capped-move count and first line)."""
        summary.print_bounds_mm = box(self.acc, ACC_PRINT_LO)
        summary.travel_bounds_mm = box(self.acc, ACC_TRAVEL_LO)
        summary.speed_capped_moves = int(self.acc[ACC_CAPPED])
        summary.speed_capped_first_line = int(self.acc[ACC_CAPPED_LINE]) or None


__all__ = ["MAX_MOVE_MM", "MotionChecker", "register_reach_check", "motion_kernel"]
