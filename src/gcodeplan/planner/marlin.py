"""The ``marlin-2.1.2`` and ``marlin-bugfix`` firmware models: plan and time a program as Marlin runs it.

``marlin-2.1.2`` is Marlin 2.1.2.4; ``marlin-bugfix`` is Marlin bugfix-2.1.x as of 2024-07-30 (after 2.1.2.4): its
start/stop speed from the acceleration (√(a/2) steps/s instead of a 120 steps/s floor), speed-based trapezoids
rounded to nearest, a different classic jerk, one look-ahead pass folded into the trapezoid sweep, and a stepper
interrupt that reads each rate half a step later (:mod:`gcodeplan.planner.marlin_kernels`, the ``*_bugfix``
functions). A machine whose ``firmware`` is one of them is planned by this module instead of a junction policy:
every MOVE row goes through Marlin's own host loop, planner and stepper interrupt
(:mod:`gcodeplan.planner.marlin_kernels`, :mod:`gcodeplan.stepper.marlin_isr`), and its PLAN row carries the
firmware's real start and end time: the tick its block was picked up and the tick of its last step, on the
25 MHz stepper timer. The trapezoid fields of the PLAN row are the block's as executed (entry and exit
speeds from its step rates, phase times from the interrupt), with the cruise speed fitted so that the
row's distance is covered in its time.

Rows that make no block (under 6 steps: Marlin carries them into the next move) last 0 s at the end of
the block before them; their steps are issued with the block they merge into. With ``want_steps`` the model
also hands on each settled stretch's step pulses as the interrupt issues them (:func:`block_pulses`): the
leading axis at every interrupt tick, X/Y/Z/E on those ticks by Bresenham; under a linear-advance K factor
the extruder's pulses come from Marlin's advance interrupt instead (:mod:`gcodeplan.stepper.marlin_la`, fed
the blocks' :func:`advance_fields`). Waits (M400, G4, G28, heater waits) drain the buffer; the next block is picked up
at the stepper's next 1 ms idle poll after the wait (the dwell rounded up to whole ms).

Reference: ``shared/reference/marlin`` (Marlin 2.1.2.4's planner.cpp / stepper.cpp on a simulated clock);
``tools/compare_marlin.py`` prints the agreement.

``MarlinModel(..., buffer_blocks=N, quantised=False)``: another buffer size (None: unbounded), and the plan without
quantisation (:mod:`gcodeplan.planner.marlin_ideal`): issue 21's proof that an unbounded buffer and no quantisation
give the ideal look-ahead plan back (tests/test_marlin_ideal.py).
"""
from __future__ import annotations


import numpy as np

from .._jit import njit
from ..errors import ConfigError
from ..schema import (KIND_DWELL, KIND_EXTRUDE_ONLY, KIND_WAIT, LIMIT_ACCEL, LIMIT_FEED, LIMIT_NONE, PLAN_DTYPE)
from ..stepper.marlin_isr import MARLIN_TIMER_HZ
from . import marlin_ideal as mi
from . import marlin_kernels as mk

F32 = np.float32

#: firmware names this module models (machine TOML ``firmware``, CLI ``--firmware``)
FIRMWARES = ("marlin-2.1.2", "marlin-bugfix")
#: the kernels' version code of each firmware name
_VERSIONS = {"marlin-2.1.2": mk.VERSION_2_1_2, "marlin-bugfix": mk.VERSION_BUGFIX}
#: µs, Marlin's DEFAULT_MINSEGMENTTIME (SLOWDOWN)
MIN_SEGMENT_TIME_US = 20000
_AXES = ("x", "y", "z", "e")
# machine kinematics → Marlin's Core build (COREXY, COREXZ: Klipper's corexy/corexz motors, A = X + Y, B = X − Y)
_CORE_KINDS = {"corexy": mk.CORE_XY, "corexz": mk.CORE_XZ}
#: junction policies a Marlin build has: CLASSIC_JERK on, or off (junction deviation)
JUNCTIONS = ("classic-jerk", "junction-deviation")
_UINT32_MAX = 4294967295
_FLOAT_MAX = float(np.finfo(np.float64).max)       # numpy's nan_to_num bound for an infinite dwell
#: the window's per-row arrays (MarlinModel._row_arrays): name, dtype, shape of one row
_WINDOW = (("kind", np.int64, ()), ("tgt", np.float32, (4,)), ("reset_bits", np.int64, ()),
           ("reset_pos", np.float32, (4,)), ("fr", np.float32, ()), ("acc_p", np.float32, ()),
           ("acc_t", np.float32, ()), ("acc_r", np.float32, ()), ("lim", np.int64, ()), ("wait_ticks", np.int64, ()),
           ("line", np.int64, ()), ("move_kind", np.uint8, ()), ("move_d", np.float64, ()))


@njit(cache=True)
def _mark_beyond(v, reach, bad, c, r):
    """``bad[c] = r`` for the first row ``r`` whose ``v`` (mm) is beyond ``reach`` or not a number."""
    if not abs(v) < reach and bad[c] < 0:
        bad[c] = r


# The two short per-batch kernels keep the GIL (nogil=False): released, the reader thread takes it, and taking it
# back waits for the reader to give it up (up to the 5 ms switch interval) — longer than the kernels run.
@njit(cache=True, nogil=False)
def row_inputs_kernel(line, kind, x0, y0, z0, e0, x1, y1, z1, e1, feed_v, accel, dwell_t, timer_hz, set_line, set_v,
                      carry, row_kind, wait_ticks, tgt, reset_pos, reset_bits, fr, acc_p, acc_t, acc_r, reach, bad):
    """Per MOVE row, what Marlin's planner is handed (out: ``row_kind``, ``wait_ticks``, ``tgt``, ``reset_pos``,
    ``reset_bits``, ``fr``, ``acc_p``/``acc_t``/``acc_r``).

    ``row_kind``: ROW_WAIT for a wait or dwell (the buffer drains first), else ROW_MOVE; ``wait_ticks``: a
    wait's dwell (``dwell_t`` s, NaN as 0) in ticks of ``timer_hz``, rounded up (0 for a move).

    ``tgt``: the target in Marlin's float32 mm, E logical (machine E minus the offset of the G92 E lines before
    the row); ``reset_bits``: X/Y/Z (bits 0..2) jumped between rows (homing sets the position), E (bit 3) set by a
    G92 E that changes it (``gcode/feature/G92``: not within NEAR_ZERO, 1e-6), to ``reset_pos``; ``fr``: F (mm/min)
    in float32, /60, then Marlin's MMS_SCALED (·0.01·100 %), an absurd or infinite F taken as 1e9 mm/min (the
    axes' M203 limits decide: Marlin's uint32 rate arithmetic cannot overflow); ``acc`` (3 × rows): the M204
    P / T / R in force (``acc_p``, ``acc_t``, ``acc_r``), each the accel of the last row of its class (print,
    travel, retract) up to the row.
    ``set_line``/``set_v``: the G92 E lines before the batch's last row and their logical E (mm). ``carry``
    (in/out): the previous row's end X/Y/Z/E (mm), the E offset (mm), the three accels (mm/s²). ``reach``
    (4, mm): Marlin's int32 step positions' reach per axis; ``bad`` (out, 8: x0, x1, y0, y1, z0, z1, e0, e1):
    the first row whose value in that column is beyond it or not a number, −1 for none."""
    n = len(line)
    # the E offset in force at each row, and the G92 E lines that change Marlin's E
    e_offs = np.empty(n)
    e_reset = np.zeros(n)
    e_set = np.zeros(n, np.int64)
    off = carry[4]
    j = 0
    for s in range(len(set_line)):
        while j < n and line[j] <= set_line[s]:        # the first row after the G92 E line
            e_offs[j] = off
            j += 1
        cur = F32(e0[j] - off)                         # Marlin's current (logical) E, float
        off = e0[j] - set_v[s]
        if abs(F32(F32(set_v[s]) - cur)) >= F32(0.000001):
            e_set[j] = 1
            e_reset[j] = set_v[s]
    while j < n:
        e_offs[j] = off
        j += 1
    carry[4] = off
    for c in range(8):
        bad[c] = -1
    px, py, pz = carry[0], carry[1], carry[2]
    for r in range(n):
        k = kind[r]
        if k == KIND_WAIT or k == KIND_DWELL:
            row_kind[r] = mk.ROW_WAIT
            dw = dwell_t[r]
            if dw != dw:
                dw = 0.0
            wait_ticks[r] = np.int64(np.ceil(max(min(dw, _FLOAT_MAX), -_FLOAT_MAX) * timer_hz))
        else:
            row_kind[r] = mk.ROW_MOVE
            wait_ticks[r] = 0
        _mark_beyond(x0[r], reach[0], bad, 0, r)
        _mark_beyond(x1[r], reach[0], bad, 1, r)
        _mark_beyond(y0[r], reach[1], bad, 2, r)
        _mark_beyond(y1[r], reach[1], bad, 3, r)
        _mark_beyond(z0[r], reach[2], bad, 4, r)
        _mark_beyond(z1[r], reach[2], bad, 5, r)
        _mark_beyond(e0[r], reach[3], bad, 6, r)
        _mark_beyond(e1[r], reach[3], bad, 7, r)
        reset_bits[r] = ((1 if x0[r] != px else 0) | (2 if y0[r] != py else 0) | (4 if z0[r] != pz else 0)
                         | (8 if e_set[r] else 0))
        px, py, pz = x1[r], y1[r], z1[r]
        tgt[r, 0] = F32(x1[r])
        tgt[r, 1] = F32(y1[r])
        tgt[r, 2] = F32(z1[r])
        tgt[r, 3] = F32(e1[r] - e_offs[r])
        reset_pos[r, 0] = F32(x0[r])
        reset_pos[r, 1] = F32(y0[r])
        reset_pos[r, 2] = F32(z0[r])
        reset_pos[r, 3] = F32(e_reset[r])
        fv = feed_v[r]
        f_mm_min = F32(min(fv * 60.0, 1e9)) if np.isfinite(fv) else F32(1e9)
        f = F32(f_mm_min / F32(60))
        fr[r] = F32(F32(f * F32(0.01)) * F32(100))
        if k != KIND_WAIT and k != KIND_DWELL and np.isfinite(accel[r]):
            c = 2 if k == KIND_EXTRUDE_ONLY else (0 if e1[r] != e0[r] else 1)
            carry[5 + c] = accel[r]
        acc_p[r] = F32(carry[5])
        acc_t[r] = F32(carry[6])
        acc_r[r] = F32(carry[7])
    if n:
        carry[0], carry[1], carry[2], carry[3] = x1[n - 1], y1[n - 1], z1[n - 1], e1[n - 1]


@njit(cache=True, nogil=False)
def window_rows_kernel(limits, line, kind, move_d, fr, acc_p, acc_t, acc_r, lim_out, line_out, kind_out, move_d_out,
                       out_i, out_f):
    """What the window keeps of a batch's MOVE rows besides :func:`row_inputs_kernel`'s (out: ``lim_out``,
    ``line_out``, ``kind_out``, ``move_d_out`` (mm)), and the run kernel's output rows for them cleared (``out_i``,
    ``out_f``: a row without a block keeps zeros). Returns True when a feed rate ``fr`` or one of the accelerations
    ``acc_p``/``acc_t``/``acc_r`` handed on is 0 or less (:meth:`MarlinModel._check_zero_limits` then looks for
    the row). One pass instead of six array operations a batch: each of those lets the reader thread take the GIL."""
    nonpos = False
    for r in range(len(line)):
        lim_out[r] = limits[r]
        line_out[r] = line[r]
        kind_out[r] = kind[r]
        move_d_out[r] = move_d[r]
        for c in range(out_i.shape[1]):
            out_i[r, c] = 0
        for c in range(out_f.shape[1]):
            out_f[r, c] = 0
        if fr[r] <= 0 or acc_p[r] <= 0 or acc_t[r] <= 0 or acc_r[r] <= 0:
            nonpos = True
    return nonpos


def check_firmware(name: str | None) -> str | None:
    """``name`` if it is a firmware model gcodeplan runs (None passes), else a ConfigError."""
    if name is None or name in FIRMWARES:
        return name
    raise ConfigError(f"firmware: unknown value {name!r} (one of {', '.join(FIRMWARES)})")


def _axis_accel_steps(limits: np.ndarray, spm32: np.ndarray) -> np.ndarray:
    """max_acceleration_steps_per_s2 per LIMITS row and axis: M201 values are whole mm/s² in Marlin
    (uint32), times steps/mm in float32, truncated."""
    out = np.empty((len(limits), 4), dtype=np.int64)
    for a, name in enumerate(_AXES):
        v = np.asarray(limits["axis_a_" + name], dtype=np.float64)
        ok = np.isfinite(v) & (v * float(spm32[a]) < _UINT32_MAX)
        whole = np.trunc(np.where(ok, v, 0.0)).astype(np.float32)
        prod = (whole * spm32[a]).astype(np.float32)
        out[:, a] = np.where(ok, np.trunc(prod).astype(np.int64), _UINT32_MAX // 4)
    return out


class MarlinModel:
    """Marlin 2.1.2's host loop, planner and stepper over a stream of MOVE rows.

    ``feed(moves, limits)`` then ``finish()`` return PLAN rows for the rows they settle, in order:
    ``(n_rows, plan)`` pieces whose concatenation is one PLAN row per MOVE row.

    ``buffer_blocks``: the planner's ring, BLOCK_BUFFER_SIZE (a power of 2, one slot always free; 16 by default,
    the firmware's), or None (or ``math.inf``) for an unbounded buffer (nothing runs until the input ends or a
    wait drains it, and SLOWDOWN never acts). ``quantised=False`` (Marlin 2.1.2 only) plans in float64 and times
    in continuous time: no whole-step targets, no 6-step minimum block, no float32 / integer rates or step
    boundaries, no 120 steps/s floor, no stepper interrupt, 25 MHz ticks or 1 ms idle poll; Marlin's junction
    rule, MINIMUM_PLANNER_SPEED, limits, SLOWDOWN and buffer stay (:mod:`gcodeplan.planner.marlin_ideal` lists both
    sides). With both, the plan is the full look-ahead trapezoid plan on Marlin's junction caps
    (tests/test_marlin_ideal.py). It has no step pulses (``want_steps`` is an error)."""

    def __init__(self, machine, timer_hz: int = MARLIN_TIMER_HZ, e_position_sets=None,
                 junction: str | None = None, buffer_blocks: int | None = mk.BLOCK_BUFFER_SIZE,
                 quantised: bool = True):
        self.machine = machine
        # BLOCK_BUFFER_SIZE: a power of 2 (Marlin's SanityCheck.h), one slot always free; None (or inf) = unbounded
        if buffer_blocks == float("inf"):
            buffer_blocks = None
        if buffer_blocks is not None and (not isinstance(buffer_blocks, (int, np.integer)) or isinstance(
                buffer_blocks, bool) or buffer_blocks < 2 or int(buffer_blocks) & (int(buffer_blocks) - 1)):
            raise ConfigError(f"buffer_blocks: {buffer_blocks!r} is not a power of 2 of at least 2 (Marlin's "
                              f"BLOCK_BUFFER_SIZE), nor None (unbounded)")
        self.buffer_blocks = None if buffer_blocks is None else int(buffer_blocks)
        # quantised=False: the plan in float64 and continuous time (planner.marlin_ideal says what it turns off)
        self.quantised = bool(quantised)
        self._window = _WINDOW if self.quantised else _WINDOW + mi.WINDOW
        # the firmware version whose rules run (a machine of another firmware gets 2.1.2's, as before)
        self.firmware = getattr(machine, "firmware", FIRMWARES[0])
        if self.firmware not in _VERSIONS:
            self.firmware = FIRMWARES[0]
        self.version = _VERSIONS[self.firmware]
        # the build's junction rule: CLASSIC_JERK (the reference) or junction deviation (CLASSIC_JERK off)
        junction = junction or machine.junction_policy
        if junction not in JUNCTIONS:
            raise ConfigError(f"firmware {self.firmware}: junction policy {junction!r} is not one of Marlin's "
                              f"({', '.join(JUNCTIONS)})")
        self.junction_mode = mk.JUNCTION_DEVIATION if junction == "junction-deviation" else mk.JUNCTION_CLASSIC_JERK
        # S_CURVE_ACCELERATION: the same blocks, Bézier speed ramps in the stepper interrupt
        self.s_curve = getattr(machine, "acceleration_profile", "trapezoid") == "s-curve"
        if self.s_curve and self.version == mk.VERSION_BUGFIX:
            raise ConfigError("firmware marlin-bugfix: S-curve acceleration is not modelled for bugfix-2.1.x (its "
                              "stepper interrupt changed and no reference covers it); use marlin-2.1.2")
        # (line, logical E) of each G92 E, in file order (GcodeReader.interp.e_position_sets): Marlin's E is
        # logical (G92 E0 resets it, and its step position is re-rounded there); None = E never reset
        self.e_position_sets = e_position_sets
        self._e_off = 0.0                        # mm, machine E − Marlin's logical E
        self.timer_hz = int(timer_hz)
        self.spm = np.array([machine.axes[a].steps_per_mm for a in _AXES], dtype=np.float32)
        if not np.all(self.spm > 0):
            raise ConfigError(f"{self.firmware}: every axis needs steps_per_mm > 0")
        self.mm_per_step = (np.float32(1) / self.spm).astype(np.float32)
        self.acc_rate_scale = np.float32(np.float32(16777216.0) / np.float32(self.timer_hz))
        self.state = mk.new_state(self.buffer_blocks)
        if not self.quantised:
            if self.version != mk.VERSION_2_1_2:
                raise ConfigError(f"firmware {self.firmware}: quantised=False runs Marlin 2.1.2's plan only (bugfix's "
                                  f"start/stop speed and look-ahead are defined in steps); use marlin-2.1.2")
            self._ideal = mi.new_state(self.buffer_blocks)
            self._ideal[2][mk.GI_CORE] = _CORE_KINDS.get(getattr(machine, "kinematics", "cartesian"), mk.CORE_NONE)
            self._ideal_last = np.zeros(2)       # s, mm/s: the end and exit speed of the last settled row
            self._scratch64 = np.zeros((2, 4))
            self._scratch32 = np.zeros((8, 4), np.float32)
        # COREXY / COREXZ builds: blocks, limits and pulses per motor (A, B / A, C), the length the head's
        kinematics = getattr(machine, "kinematics", "cartesian")
        if kinematics == "delta":            # (a plug-in kinematics is refused with its limits: stream.py)
            raise ConfigError(f"firmware {self.firmware}: kinematics {kinematics!r} is not modelled (the Marlin model "
                              f"runs cartesian, CoreXY and CoreXZ builds; Marlin cuts a delta's or SCARA's moves "
                              f"into segments, which it does not); --firmware generic plans the machine with its "
                              f"junction policy")
        self.state[2][mk.GI_CORE] = _CORE_KINDS.get(kinematics, mk.CORE_NONE)
        self._scratch = mk.new_scratch()
        # mm, the reach of Marlin's int32 step positions per axis (_check_reach)
        self._reach = np.array([2.0 ** 31 / float(v) for v in self.spm])
        self.row_base = 0                        # absolute number of the window's first row
        # the window: per-row arrays of the rows read and not settled (_row_arrays), and the kernel's outputs
        # for them, in buffers reused from batch to batch (the first _n rows are the window's)
        self._arrays = None
        self._n = 0
        self._out_i = np.zeros((0, mk.N_OI), dtype=np.int64)
        self._out_f = np.zeros((0, mk.N_OF), dtype=np.float32)
        self._last_end = np.zeros(4)             # mm, where the previous row ended (Marlin boots at 0)
        self._acc = [machine.accel_print or machine.max_accel, machine.accel_travel or machine.max_accel,
                     machine.accel_retract or machine.max_accel]
        self._clock_done = 0                     # tick the last settled block ended
        self._last_v = 0.0                       # mm/s, the exit speed of the last settled block
        self._tables = None                      # (key, per-LIMITS-row settings): _limit_tables
        self._nonpos = False                     # the last batch hands on a feed rate or acceleration <= 0
        self.blocks = []                          # (out_i, out_f) of settled rows, when keep_blocks
        self.keep_blocks = False
        # the stepper's own pulses of the settled rows ({axis 0..3: (times s, dirs)}), when want_steps
        self.want_steps = False
        self.last_steps = None
        # linear advance (K > 0 on some row): the interrupt's state across stretches, and the planner's
        # position_float after the last settled row (its use_advance_lead test needs it)
        self._la_state = None
        self._la_pos = np.zeros(4, np.float32)

    # ------------------------------------------------------------------ inputs
    def _row_arrays(self, moves: np.ndarray, limits: np.ndarray) -> dict:
        """The batch's per-row arrays (:data:`_WINDOW`), written into the window's buffers after its rows
        (:meth:`_reserve`); returns views of them. The window's row count is not advanced here."""
        n = len(moves)
        a = self._reserve(n)
        k = moves["kind"]
        if not self.quantised:
            mi.ideal_row_inputs_kernel(k, moves["x0"], moves["y0"], moves["z0"], moves["e0"], moves["x1"], moves["y1"],
                                       moves["z1"], moves["e1"], moves["feed_v"], moves["accel"], moves["dwell_t"],
                                       np.array(self._acc, np.float64), a["d"], a["fr64"], a["acc64"], a["dwell64"])
            a["out_t"][:] = 0
        # the G92 E lines before the batch's last row (the others wait for the rows after them)
        sets = self.e_position_sets
        set_line, set_v = [], []
        if sets is not None and n:
            last_line = moves["line"][-1]
            while sets and sets[0][0] < last_line:
                line, v = sets.popleft()
                set_line.append(line)
                set_v.append(v)
        carry = np.array([*self._last_end, self._e_off, *self._acc], dtype=np.float64)
        bad = np.empty(8, np.int64)
        row_inputs_kernel(moves["line"], k, moves["x0"], moves["y0"], moves["z0"], moves["e0"], moves["x1"],
                          moves["y1"], moves["z1"], moves["e1"], moves["feed_v"], moves["accel"], moves["dwell_t"],
                          float(self.timer_hz), np.array(set_line, np.int64), np.array(set_v, np.float64), carry,
                          a["kind"], a["wait_ticks"], a["tgt"], a["reset_pos"], a["reset_bits"], a["fr"], a["acc_p"],
                          a["acc_t"], a["acc_r"], self._reach, bad)
        if (bad >= 0).any():
            if sets is not None:
                sets.extendleft(reversed(list(zip(set_line, set_v))))     # the model's state stays as it was
            self._check_reach(moves, bad)
        self._last_end = carry[:4].copy()
        self._e_off = float(carry[4])
        self._acc = [float(carry[5]), float(carry[6]), float(carry[7])]
        self._limit_tables(limits)       # the settings of each row: its LIMITS row in these tables (they only grow)
        # the window keeps what the PLAN rows and the steps need of the MOVE rows, not the rows themselves
        n0 = self._n
        self._nonpos = window_rows_kernel(moves["limits"], moves["line"], k, moves["move_d"], a["fr"], a["acc_p"],
                                          a["acc_t"], a["acc_r"], a["lim"], a["line"], a["move_kind"], a["move_d"],
                                          self._out_i[n0:n0 + n], self._out_f[n0:n0 + n])
        return a

    def _check_reach(self, moves: np.ndarray, bad: np.ndarray) -> None:
        """Marlin keeps positions as int32 steps (planner.position, count_position): an end point beyond ±2³¹
        steps, or not a number, has no meaning on the printer; an error naming the line, not a wrapped
        position (tools/fuzz.py found E1e20 and Y1e308 crashing the model). ``bad``: per column (x0, x1, y0,
        … e1) the first such row or −1 (:func:`row_inputs_kernel`); the first column's is reported."""
        from ..errors import GcodeError

        for k, axis in enumerate(_AXES):
            for j, col in enumerate((axis + "0", axis + "1")):
                i = int(bad[2 * k + j])
                if i >= 0:
                    raise GcodeError(f"{axis.upper()} {moves[col][i]:g} mm is beyond Marlin's reach (±2³¹ steps at "
                                     f"{float(self.spm[k]):g} steps/mm)", line=int(moves["line"][i]))

    def _check_zero_limits(self, moves: np.ndarray, a: dict) -> None:
        """A feed rate, acceleration or axis limit that is 0 in Marlin's own numbers (a float under 1.4e-45,
        an M201 under 1 mm/s² kept as a whole 0, M220 at 0 %) makes the firmware divide by zero: an error
        naming the move's line, never a traceback (tools/fuzz.py: SET_VELOCITY_LIMIT ACCEL=1e-320)."""
        from ..errors import GcodeError

        tab = self._tables[1]
        if not (self._nonpos or tab["nonpos"]):
            return                                    # nothing is 0: no row to look for
        li = moves["limits"]
        vmax, amax = tab["vmax"][li], tab["amax"][li]
        move = a["kind"] == mk.ROW_MOVE
        d = np.stack([moves[ax + "1"] - moves[ax + "0"] for ax in _AXES], axis=1) != 0
        cls = np.where(~d[:, :3].any(axis=1), a["acc_r"], np.where(d[:, 3], a["acc_p"], a["acc_t"]))
        tiny = "a float holds nothing under 1.4e-45"
        checks = (("feed rate (F × M220)", tiny, a["fr"] <= 0),
                  ("acceleration (M204 / SET_VELOCITY_LIMIT)", tiny, cls <= 0),
                  ("axis speed limit (M203)", tiny, ((vmax <= 0) & d).any(axis=1)),
                  ("axis acceleration limit (M201)", "Marlin keeps whole mm/s², and whole × steps/mm as whole "
                   "steps/s²", ((amax <= 0) & d).any(axis=1)))
        for what, why, bad in checks:
            rows = np.nonzero(move & bad)[0]
            if rows.size:
                raise GcodeError(f"the {what} in force is 0 in Marlin's own numbers ({why}): the firmware's "
                                 "planner would divide by it", line=int(moves["line"][rows[0]]))

    def _limit_tables(self, limits: np.ndarray) -> dict:
        """Per LIMITS row, the firmware's settings (float32 / integer as Marlin stores them); the table only
        grows, so it is rebuilt when its length or last row changes."""
        key = (len(limits), limits[-1:].tobytes())
        if self._tables is not None and self._tables[0] == key:
            return self._tables[1]
        vmax = np.stack([limits["axis_v_" + a] for a in _AXES], axis=1)
        amax_mm = np.stack([limits["axis_a_" + a] for a in _AXES], axis=1)
        amax = _axis_accel_steps(limits, self.spm)
        tab = dict(
            vmax=np.ascontiguousarray(np.where(np.isfinite(vmax), vmax, 1e30).astype(np.float32)),
            jerk=np.ascontiguousarray(np.stack([limits["jerk_" + a] for a in _AXES], axis=1).astype(np.float32)),
            # M201 values are whole mm/s² in Marlin (uint32)
            amax_mm=np.ascontiguousarray(np.where(np.isfinite(amax_mm), np.floor(np.minimum(amax_mm, 4e9)),
                                                  3e38).astype(np.float32)),
            amax=amax,
            cutoff=(_UINT32_MAX // np.maximum(amax.max(axis=1), 1)).astype(np.int64),
            jdev=limits["junction_dev"].astype(np.float32), advance_k=limits["pa_k"].astype(np.float32),
            min_feed=limits["min_feed_v"].astype(np.float32), min_travel=limits["min_travel_v"].astype(np.float32))
        tab["nonpos"] = bool((tab["vmax"] <= 0).any() or (tab["amax"] <= 0).any())    # _check_zero_limits
        if not self.quantised:
            # quantised=False: the settings as given (float64; no limit where unbounded)
            tab.update(vmax64=np.ascontiguousarray(np.where(np.isfinite(vmax), vmax, 1e300)),
                       amax64=np.ascontiguousarray(np.where(np.isfinite(amax_mm), amax_mm, 1e300)),
                       advance_k64=limits["pa_k"].astype(np.float64),
                       min_feed64=limits["min_feed_v"].astype(np.float64),
                       min_travel64=limits["min_travel_v"].astype(np.float64))
        self._tables = (key, tab)
        return tab

    # ------------------------------------------------------------------ running
    def feed(self, moves: np.ndarray, limits: np.ndarray):
        """Add MOVE rows; return ``(n_rows, plan)`` pieces whose times are final."""
        if len(moves) == 0:
            return []
        with np.errstate(over="ignore", invalid="ignore"):    # 1e308 is Marlin's float inf: no numpy warning
            arr = self._row_arrays(moves, np.asarray(limits))
        self._check_zero_limits(moves, arr)
        self._n += len(moves)
        return self._run(final=False)

    def _reserve(self, m: int) -> dict:
        """Room for ``m`` more rows in the window's buffers (grown to twice when short): views of the rows
        after the window's (the kernel's output rows for them are cleared by :func:`window_rows_kernel`)."""
        n = self._n
        if self._arrays is None or n + m > len(self._out_i):
            cap = max(2 * len(self._out_i), n + m)
            grown = {k: np.empty((cap,) + shape, dtype) for k, dtype, shape in self._window}
            out_i = np.empty((cap, mk.N_OI), dtype=np.int64)
            out_f = np.empty((cap, mk.N_OF), dtype=np.float32)
            if self._arrays is not None:
                for k, v in grown.items():
                    v[:n] = self._arrays[k][:n]
                out_i[:n] = self._out_i[:n]
                out_f[:n] = self._out_f[:n]
            self._arrays, self._out_i, self._out_f = grown, out_i, out_f
        return {k: v[n:n + m] for k, v in self._arrays.items()}

    def finish(self):
        """Run everything still queued; the buffer ends empty."""
        if self._n == 0:
            return []
        return self._run(final=True)

    def _run(self, final: bool):
        if not self.quantised:
            return self._run_ideal(final)
        a = {k: v[:self._n] for k, v in self._arrays.items()}
        bf, bi, gi, gf = self.state
        if self.buffer_blocks is None:
            # unbounded: room for every row still to read (a G92 among them may add a sync block)
            pending = self._n - (int(gi[mk.GI_NEXT_ROW]) - self.row_base)
            bf, bi = mk.grow_ring(bf, bi, gi, 2 * pending + 1)
            self.state = (bf, bi, gi, gf)
        tab = self._tables[1]
        out_i, out_f = self._out_i[:self._n], self._out_f[:self._n]
        first = mk.marlin_run_kernel(a["kind"], a["tgt"], a["reset_bits"], a["reset_pos"], a["fr"], a["acc_p"],
                                     a["acc_t"], a["acc_r"], a["lim"], tab["vmax"], tab["amax"], tab["cutoff"],
                                     tab["jerk"], tab["min_feed"], tab["min_travel"], a["wait_ticks"], self.spm,
                                     self.mm_per_step, MIN_SEGMENT_TIME_US, self.timer_hz, self.acc_rate_scale,
                                     final, self.row_base, bf, bi, gi, gf, out_i, out_f,
                                     self.junction_mode, tab["amax_mm"], tab["jdev"], tab["advance_k"],
                                     self.s_curve, *self._scratch, self.version)
        n_done = int(first) - self.row_base
        if final:
            n_done = self._n
        if n_done <= 0:
            return []
        oi, of = out_i[:n_done], out_f[:n_done]
        plan = self._plan_rows(a["move_d"][:n_done], a["move_kind"][:n_done], oi, of)
        if self.keep_blocks:
            self.blocks.append((oi.copy(), of.copy(), a["line"][:n_done].copy()))
        if self.want_steps:
            la = None
            k = tab["advance_k"][a["lim"][:n_done]]
            lead = advance_lead(oi, a["tgt"][:n_done], a["reset_bits"][:n_done], a["reset_pos"][:n_done], k,
                                self._la_pos)
            if lead.any() or self._la_state is not None:
                from ..stepper.marlin_la import new_state

                if self._la_state is None:
                    self._la_state = new_state()
                la = advance_fields(oi, lead, k)
            self.last_steps = block_pulses(oi, self.timer_hz, self.s_curve, la, self._la_state,
                                           bugfix=self.version == mk.VERSION_BUGFIX)
        self._settle(n_done)
        return [(n_done, plan)]

    def _settle(self, n_done: int) -> None:
        """The rows not settled move to the front of the buffers (a few: the blocks still queued)."""
        rest = self._n - n_done
        for v in (*self._arrays.values(), self._out_i, self._out_f):
            v[:rest] = v[n_done:self._n].copy()
        self._n = rest
        self.row_base += n_done

    def _run_ideal(self, final: bool):
        """:meth:`_run` with ``quantised=False``: :func:`gcodeplan.planner.marlin_ideal.ideal_run_kernel`."""
        if self.want_steps:
            raise ConfigError(f"firmware {self.firmware}: quantised=False has no step pulses (no stepper "
                              f"interrupt runs); leave it on for steps")
        a = {k: v[:self._n] for k, v in self._arrays.items()}
        rf, ri, gi, gf, gd = self._ideal
        if self.buffer_blocks is None:
            pending = self._n - (int(gi[mk.GI_NEXT_ROW]) - self.row_base)
            rf, ri = mk.grow_ring(rf, ri, gi, 2 * pending + 1)
            self._ideal = (rf, ri, gi, gf, gd)
        tab = self._tables[1]
        first = mi.ideal_run_kernel(a["kind"], a["d"], a["fr64"], a["acc64"], a["dwell64"], a["reset_bits"], a["lim"],
                                    tab["vmax64"], tab["amax64"], tab["amax_mm"], tab["jerk"], tab["min_feed64"],
                                    tab["min_travel64"], tab["jdev"], tab["advance_k64"], float(MIN_SEGMENT_TIME_US),
                                    self.junction_mode, final, self.row_base, rf, ri, gi, gf, gd, a["out_t"],
                                    self._scratch64, self._scratch32)
        n_done = self._n if final else int(first) - self.row_base
        if n_done <= 0:
            return []
        out_t = a["out_t"][:n_done]
        plan = np.zeros(n_done, dtype=PLAN_DTYPE)
        mi.ideal_plan_rows_kernel(out_t, a["move_d"][:n_done], a["move_kind"][:n_done], self._ideal_last,
                                  *(plan[f] for f in _PLAN_FIELDS))
        if self.keep_blocks:
            self.blocks.append((out_t.copy(), None, a["line"][:n_done].copy()))
        self._settle(n_done)
        return [(n_done, plan)]

    def _plan_rows(self, move_d: np.ndarray, move_kind: np.ndarray, oi: np.ndarray, of: np.ndarray) -> np.ndarray:
        """PLAN rows of settled rows (their MOVE rows' ``move_d`` (mm) and ``kind``): blocks as executed; rows
        without a block last 0 s where the previous one ended."""
        plan = np.zeros(len(move_d), dtype=PLAN_DTYPE)
        carry = np.array([self._clock_done], np.int64)
        last_v = np.array([self._last_v])
        plan_rows_kernel(oi, of, move_d, move_kind, float(self.timer_hz), carry, last_v,
                         *(plan[f] for f in _PLAN_FIELDS))
        self._clock_done = int(carry[0])
        self._last_v = float(last_v[0])
        return plan


#: the PLAN fields :func:`plan_rows_kernel` fills, in its argument order
_PLAN_FIELDS = ("t_start", "duration", "start_v", "cruise_v", "end_v", "accel", "decel", "accel_t", "cruise_t",
                "decel_t", "limit")


@njit(cache=True)
def _nominal_ramp_factor(v0, vn, v1, ta, tc, td, move_d):
    """The factor k by which a row's ramps (accel ``ta``, decel ``td``; s) shrink when, read as straight, they
    would peak above the block's nominal speed ``vn`` (mm/s): the interrupt holds the nominal rate once it
    reaches it (stepper.cpp block_phase_isr: ``NOMORE(acc_step_rate, nominal_rate)``) inside what the block counts
    as its ramps. The cruise takes the time the ramps give up, so the row keeps its duration and its length
    ``move_d`` (mm) and peaks at ``vn``: k = (vn·T − d) / ((vn − v0)·ta/2 + (vn − v1)·td/2). Outside (0, 1] (a
    row that covers more than vn allows: moves merged into its block) the row keeps its straight ramps."""
    den = (vn - v0) * ta / 2 + (vn - v1) * td / 2
    return (vn * (ta + tc + td) - move_d) / den if den > 0.0 else -1.0


@njit(cache=True, nogil=False)
def plan_rows_kernel(oi, of, move_d, kind, hz, clock_done, last_v, t_start, duration, start_v, cruise_v, end_v,
                     accel, decel, accel_t, cruise_t, decel_t, limit):
    """PLAN fields of settled rows from the kernel's per-row outputs ``oi``/``of``: a block's pick-up and end tick
    (``hz``: the timer), entry and exit speed from its initial and final rates (mm per leading-axis step), phase
    times from the interrupt and the cruise speed that covers the row's ``move_d`` in them. A row without a
    block (merged into the next, or a wait) lasts 0 s at the end of the last timed row (``clock_done[0]``, in/out,
    ticks) at the exit speed of the last block before it (``last_v[0]``, in/out, mm/s; at rest after a wait)."""
    t_done = clock_done[0]
    v_carry = last_v[0]
    for r in range(len(move_d)):
        hb = oi[r, mk.OI_HAS_BLOCK]
        timed = hb != 0                                  # a block or a wait
        has = hb == 1
        wait = kind[r] == KIND_WAIT or kind[r] == KIND_DWELL
        if timed:
            t_done = oi[r, mk.OI_T_END]
            t_pick = oi[r, mk.OI_T_PICK]
        else:
            t_pick = t_done
        t_start[r] = t_pick / hz
        duration[r] = (t_done - t_pick) / hz
        sec = np.float64(max(oi[r, mk.OI_SEC], 1))
        per_step = np.float64(of[r, mk.OF_MM]) / sec if has else 0.0     # mm per leading-axis step
        v0 = oi[r, mk.OI_INITIAL_RATE] * per_step
        v1 = oi[r, mk.OI_FINAL_RATE] * per_step
        ta = oi[r, mk.OI_ACC_T] / hz
        tc = oi[r, mk.OI_CRUISE_T] / hz
        td = oi[r, mk.OI_DEC_T] / hz
        den = ta / 2 + tc + td / 2
        vc = (move_d[r] - v0 * ta / 2 - v1 * td / 2) / den if den > 0 else 0.0
        if has:
            if vc < 0.0:
                vc = 0.0
            vn = oi[r, mk.OI_NOMINAL_RATE] * per_step
            if vc > vn > 0.0:
                k = _nominal_ramp_factor(v0, vn, v1, ta, tc, td, move_d[r])
                if 0.0 < k <= 1.0:
                    tc += (1.0 - k) * (ta + td)
                    ta *= k
                    td *= k
                    vc = vn
        else:
            vc = 0.0
        accel[r] = (vc - v0) / ta if ta > 0 else 0.0
        decel[r] = (vc - v1) / td if td > 0 else 0.0
        if has:
            start_v[r] = v0
            cruise_v[r] = vc
            end_v[r] = v1
            accel_t[r] = ta
            cruise_t[r] = tc
            decel_t[r] = td
            v_carry = v1
        elif wait:
            v_carry = 0.0                                # the buffer ran empty: at rest
        else:
            # a row without a block passes in no time at the speed the block before it ended with
            start_v[r] = v_carry
            cruise_v[r] = v_carry
            end_v[r] = v_carry
        limit[r] = LIMIT_NONE if wait else (LIMIT_ACCEL if oi[r, mk.OI_ACCEL_UNTIL] > 0 else LIMIT_FEED)
    clock_done[0] = t_done
    last_v[0] = v_carry


def advance_lead(oi: np.ndarray, tgt: np.ndarray, reset_bits: np.ndarray, reset_pos: np.ndarray,
                 advance_k: np.ndarray, pos_float: np.ndarray) -> np.ndarray:
    """Which rows' blocks run with linear advance (planner.cpp ``use_advance_lead``): K > 0, E steps
    forward, some X/Y/Z steps (an E-only move is a retract or recover), and ``e_D_ratio`` (E mm per X/Y/Z mm
    from the float target and ``position_float``, float32) not above 3 (a retract merged into a print
    move). ``pos_float`` (4 float32, in/out) is ``position_float`` before the first row; rows are the model's
    settled rows in order (``tgt``/``reset_*``: the kernel's row arrays)."""
    n = len(oi)
    has = oi[:, mk.OI_HAS_BLOCK] == 1
    # position_float before each row's block: a G92 on the row sets its axes first, a block sets all four
    before = np.empty((n, 4), np.float32)
    after = np.empty((n, 4), np.float32)
    for a in range(4):
        reset = (reset_bits >> a) & 1 == 1
        val = np.where(has, tgt[:, a], reset_pos[:, a]).astype(np.float32)
        ev = has | reset
        idx = np.arange(n)
        last = np.maximum.accumulate(np.where(ev, idx, -1)) if n else idx
        after[:, a] = np.where(last >= 0, val[np.maximum(last, 0)], pos_float[a])
        prev = np.concatenate([[pos_float[a]], after[:-1, a]]).astype(np.float32)
        before[:, a] = np.where(reset, reset_pos[:, a], prev)
    if n:
        pos_float[:] = after[-1]
    d = (tgt - before).astype(np.float32)
    dxyz = np.sqrt(((d[:, 0] * d[:, 0]).astype(np.float32) + (d[:, 1] * d[:, 1]).astype(np.float32)).astype(
        np.float32) + (d[:, 2] * d[:, 2]).astype(np.float32)).astype(np.float32)
    with np.errstate(divide="ignore", invalid="ignore"):
        e_d_ratio = (d[:, 3] / dxyz).astype(np.float32)
    steps = oi[:, mk.OI_SX:mk.OI_SE + 1]
    forward_e = (oi[:, mk.OI_DIR_BITS] & 8) == 0
    return (has & (advance_k > 0) & (steps[:, 3] > 0) & forward_e & (steps[:, :3].sum(axis=1) > 0)
            & ~(e_d_ratio > np.float32(3)))


def advance_fields(oi: np.ndarray, lead: np.ndarray, advance_k: np.ndarray) -> np.ndarray:
    """The block's linear-advance fields (planner.cpp ``_populate_block`` and
    ``calculate_trapezoid_for_block``), an int64 array of rows × 4: ``la_advance_rate`` = K · acceleration
    (steps/s², float32, truncated; 0 without advance), ``la_scaling`` (doublings of ``2·e_steps`` while it is
    at most a quarter of the events: at most about four E steps per advance event), ``max_adv_steps`` =
    cruise rate · K · e_steps / events and ``final_adv_steps`` the same from the final rate (uint16)."""
    n = len(oi)
    out = np.zeros((n, 4), np.int64)
    k = advance_k.astype(np.float32)
    rate = (k * oi[:, mk.OI_ACCEL_STEPS].astype(np.float32)).astype(np.float32)
    out[:, 0] = np.where(lead, np.trunc(rate).astype(np.int64), 0)
    e2 = 2 * oi[:, mk.OI_SE]
    quarter = oi[:, mk.OI_SEC] >> 2
    scaling = np.zeros(n, np.int64)
    grow = lead & (e2 > 0) & (e2 <= quarter)
    while grow.any():
        scaling += grow
        e2 = np.where(grow, e2 << 1, e2)
        grow = grow & (e2 <= quarter)
    out[:, 1] = scaling
    with np.errstate(divide="ignore", invalid="ignore"):
        comp = ((k * oi[:, mk.OI_SE].astype(np.float32)).astype(np.float32)
                / np.maximum(oi[:, mk.OI_SEC], 1).astype(np.float32)).astype(np.float32)
    mx = (oi[:, mk.OI_CRUISE_RATE].astype(np.float32) * comp).astype(np.float32)
    fin = (oi[:, mk.OI_FINAL_RATE].astype(np.float32) * comp).astype(np.float32)
    out[:, 2] = np.where(lead, np.trunc(mx).astype(np.int64) & 0xFFFF, 0)
    out[:, 3] = np.where(lead, np.trunc(fin).astype(np.int64) & 0xFFFF, 0)
    return out


def block_pulses(oi: np.ndarray, timer_hz: int, s_curve: bool, la: np.ndarray | None = None,
                 la_state: np.ndarray | None = None, bugfix: bool = False) -> dict:
    """The step pulses of the blocks in per-row outputs ``oi`` (rows without a block are skipped), as
    Marlin's stepper interrupt issues them (:func:`gcodeplan.stepper.marlin_isr.blocks_pulses_kernel`):
    {axis 0..3 (X, Y, Z, E): (times s from the first pick-up, int8 directions)}.

    ``la`` (rows × 4, :func:`advance_fields`) with any advance block: the linear-advance interrupt
    (:func:`gcodeplan.stepper.marlin_la.la_blocks_pulses_kernel`) issues E, carrying ``la_state``
    (:func:`gcodeplan.stepper.marlin_la.new_state`) from one call to the next. ``bugfix``: bugfix-2.1.x's
    interrupt timing (its linear advance is not modelled: an error)."""
    from ..stepper.marlin_isr import acceleration_rate, blocks_pulses_kernel

    sel = oi[:, mk.OI_HAS_BLOCK] == 1
    b = oi[sel]
    axis_steps = np.ascontiguousarray(b[:, mk.OI_SX:mk.OI_SE + 1])
    n_axis = axis_steps.sum(axis=0)
    cap = int(n_axis.max()) if len(b) else 0
    col = lambda k: np.ascontiguousarray(b[:, k])        # noqa: E731
    args = (col(mk.OI_T_PICK), col(mk.OI_SEC), axis_steps, col(mk.OI_DIR_BITS), col(mk.OI_INITIAL_RATE),
            col(mk.OI_NOMINAL_RATE), col(mk.OI_FINAL_RATE), col(mk.OI_ACCEL_UNTIL), col(mk.OI_DECEL_AFTER),
            acceleration_rate(col(mk.OI_ACCEL_STEPS), timer_hz), col(mk.OI_CRUISE_RATE),
            col(mk.OI_ACCELERATION_TIME), col(mk.OI_DECELERATION_TIME), col(mk.OI_ACC_TIME_INV),
            col(mk.OI_DEC_TIME_INV), bool(s_curve), int(timer_hz))
    hz = float(timer_hz)
    if la is not None and la_state is not None and len(b) and np.any(la[sel, 0] != 0):
        if bugfix:
            raise ConfigError("firmware marlin-bugfix: step pulses with linear advance are not modelled (its "
                              "advance interrupt changed after 2.1.2; times are bugfix's, set the K factor to 0 "
                              "for the other pulses or use marlin-2.1.2)")
        from ..stepper.marlin_la import isr_ticks, la_blocks_pulses_kernel

        lb = la[sel]
        lcol = lambda k: np.ascontiguousarray(lb[:, k])    # noqa: E731
        # E: the blocks' steps plus the advance pulses, both ways (unknown ahead: retried with more room)
        room = cap + int(n_axis[3]) + 64
        while True:
            out_t = np.empty((4, room), np.int64)
            out_d = np.empty((4, room), np.int8)
            n_out = np.zeros(4, np.int64)
            st = la_state.copy()
            la_blocks_pulses_kernel(*args, lcol(0), lcol(1), lcol(2), lcol(3), *isr_ticks(timer_hz), st, out_t, out_d,
                                    n_out)
            if n_out.max() <= room:
                break
            room = int(n_out.max())
        la_state[:] = st
        if not np.array_equal(n_out[:3], n_axis[:3]):
            raise RuntimeError("marlin model: pulses issued differ from the blocks' step counts (a model bug)")
        return {a: (out_t[a, :n_out[a]] / hz, out_d[a, :n_out[a]].copy()) for a in range(4)}
    out_t = np.empty((4, cap), np.int64)
    out_d = np.empty((4, cap), np.int8)
    n_out = np.zeros(4, np.int64)
    if len(b):
        blocks_pulses_kernel(*args, out_t, out_d, n_out, bool(bugfix))
    if not np.array_equal(n_out, n_axis):
        raise RuntimeError("marlin model: pulses issued differ from the blocks' step counts (a model bug)")
    return {a: (out_t[a, :n_out[a]] / hz, out_d[a, :n_out[a]].copy()) for a in range(4)}


def run_marlin(moves: np.ndarray, limits: np.ndarray, machine, keep_blocks: bool = False, e_position_sets=None,
               junction: str | None = None, buffer_blocks: int | None = mk.BLOCK_BUFFER_SIZE, quantised: bool = True):
    """Whole-program convenience: PLAN rows for ``moves`` (and the model, for its ``blocks``; with
    ``quantised=False`` each is (per-row ``out_t`` of :mod:`gcodeplan.planner.marlin_ideal`, None, lines))."""
    m = MarlinModel(machine, e_position_sets=e_position_sets, junction=junction, buffer_blocks=buffer_blocks,
                    quantised=quantised)
    m.keep_blocks = keep_blocks
    outs = m.feed(moves, limits) + m.finish()
    plan = np.concatenate([p for _, p in outs]) if outs else np.zeros(0, dtype=PLAN_DTYPE)
    return plan, m


def make_stream_mode(base_cls):
    """The StreamPlanner mode of a Marlin firmware machine (``base_cls``: planner.stream._Mode): the model
    settles rows as the firmware's buffer lets them go; their PLAN rows carry the firmware's times."""

    class MarlinMode(base_cls):
        name = FIRMWARES[0]
        own_segments = False          # PLAN rows are trapezoids: planner.segments rebuilds the pieces
        own_prepare = True

        def __init__(self, sp):
            super().__init__(sp)
            # the stepper's own pulses go with the rows (StreamPlanner.firmware_steps) when a sink wants them
            self.want_steps = bool(getattr(sp, "want_firmware_steps", False))
            self.last_steps = None
            self.model = self._new_model()
            self.name = self.model.firmware
            self._ready: list[np.ndarray] = []
            self._ready_steps: list[dict] = []

        def _new_model(self):
            sp = self.sp
            m = MarlinModel(sp.machine, e_position_sets=getattr(sp, "e_position_sets", None), junction=sp.policy,
                            buffer_blocks=int(getattr(sp.machine, "marlin_block_buffer", mk.BLOCK_BUFFER_SIZE)))
            m.want_steps = self.want_steps
            return m

        def _take(self, pieces) -> None:
            for _, p in pieces:
                self._ready.append(p)
                if self.want_steps:
                    self._ready_steps.append(self.model.last_steps)

        def prepare(self, moves_chunk, limits):
            from .prepare import unread_prep

            self._take(self.model.feed(np.asarray(moves_chunk), np.asarray(limits)))
            return unread_prep(len(moves_chunk))

        def window_prep(self, moves_chunk, limits):
            """The model plans from the MOVE rows alone: the window's PREP rows are one zero row repeated
            (:func:`gcodeplan.planner.prepare.unread_prep`), not a copy of the pending ones and the chunk's."""
            from .prepare import unread_prep

            self.prepare(moves_chunk, limits)
            return unread_prep(len(self.sp.pending_prep) + len(moves_chunk))

        def plan(self, final: bool):
            sp = self.sp
            if final:
                self._take(self.model.finish())
            if not self._ready:
                return 0, None, sp.clock, None
            plan = np.concatenate(self._ready) if len(self._ready) > 1 else self._ready[0]
            self._ready = []
            if self.want_steps:
                got = self._ready_steps
                self.last_steps = got[0] if len(got) == 1 else {
                    a: (np.concatenate([g[a][0] for g in got]), np.concatenate([g[a][1] for g in got]))
                    for a in range(4)}
                self._ready_steps = []
            t_end = float(plan["t_start"][-1] + plan["duration"][-1])
            return len(plan), plan, t_end, None

        def reset(self) -> None:
            # finish(): the buffer ran empty; a later feed() starts a new program on the same model
            self.model = self._new_model()

    return MarlinMode
