"""StreamPlanner: plan a file chunk by chunk with a bounded look-ahead window.

Moves arrive in chunks (MOVE rows + the LIMITS table they index). The planner keeps only the
moves whose plan may still change and emits the others, so that the concatenation of everything
emitted is bit-identical to ``plan_moves`` on the whole file:

* trapezoid policies: a run of moves followed by a known full stop (dwell/wait row, exact-stop
  move) is flushed completely, as ``plan_moves`` does; the open run at the end is flushed lazily:
  Klipper's rule (up to the accelerating move before the 2nd "peak" from the end) for 'klipper',
  the last move whose start speed is pinned at its junction cap for the other trapezoid policies.
  Those moves' speeds depend only on moves that are already known.
* S-curves (``jerk`` or a finite ``max_jerk``): up to the last junction certain to sit at its cap
  whatever follows (a full stop, or enough distance ahead to brake from the cap to any speed:
  :func:`gcodeplan.planner.scurve.scurve_window_speeds_kernel`).
* 'blend': up to the last corner of the window that nothing after the window can lower: a full stop
  (reversal, extrude-only or dwell neighbour, exact stop, zero tolerance, a losing corner) or a corner
  with enough distance ahead to brake from its cap (:func:`gcodeplan.planner.blend.blend_settled_kernel`);
  the runs between such corners are planned in turn (:func:`gcodeplan.planner.blend.blend_runs_kernel`),
  so the window is bounded by the braking distance, even in a run that never stops.

Times continue from the previous emission (the first move starts at 0). ``segments_for`` gives the
SEGMENT rows of an emission: the blend / S-curve planner's own pieces, trapezoid pieces otherwise.
"""
from __future__ import annotations

import numpy as np

from ..errors import ConfigError
from ..machine import OWN_PLANNER_FIRMWARES, firmware_model
from ..schema import MOVE_DTYPE, PLAN_DTYPE, concat_rows, prepend_rows
from .passes import klipper_flush, layout_rows, plan_runs, speed_buffers, standard_flush
from .prepare import (POLICY_BLEND, POLICY_JD, POLICY_KLIPPER, POLICY_LINUXCNC, PREP_DTYPE, custom_cap,
                      kinematics_limits, policy_code, prepare_with_context, validate)
from .segments import to_segments

MODE_TRAPEZOID, MODE_SCURVE, MODE_BLEND = "trapezoid", "scurve", "blend"


class _Mode:
    """One planning mode: how a chunk is prepared, how much of the window can be planned for good, and
    the SEGMENT rows of what was emitted. The StreamPlanner owns the window; a mode owns its own state.

    What a mode may use of its planner ``sp`` (the interface; nothing private): ``sp.machine``,
    ``sp.pending_moves`` / ``sp.pending_prep`` (the window's MOVE and PREP rows), ``sp.clock`` (s, the end of
    what was emitted), ``sp.policy_code``, ``sp.jerk`` (mm/s³, S-curves), ``sp.stop_pending`` (a known full
    stop precedes the next move), ``sp.prepare_chunk`` (the shared preparation, continuing from the previous
    chunk) and ``sp.check_same_jerk``. A mode answers :meth:`plan` with (rows final, their PLAN rows, end time,
    context for :meth:`segments`)."""

    name = ""
    own_segments = False     # True: the mode's pieces are not trapezoids (to_segments cannot rebuild them)
    own_prepare = False      # True: the mode makes its own PREP rows (:meth:`prepare`); the others share the
    #                          planner's preparation, which writes straight into the window

    def __init__(self, sp: "StreamPlanner"):
        self.sp = sp

    def prepare(self, moves_chunk: np.ndarray, limits: np.ndarray) -> np.ndarray:
        """PREP rows of a chunk, continuing from what came before."""
        return self._prepare(moves_chunk, limits, None)

    def window_prep(self, moves_chunk: np.ndarray, limits: np.ndarray) -> np.ndarray:
        """The new window's PREP rows: the pending ones, then the chunk's. With the shared preparation the
        chunk's rows are made in place behind the pending ones (the chunk is not copied in afterwards)."""
        pending = self.sp.pending_prep
        if self.own_prepare:
            prep = self.prepare(moves_chunk, limits)
            return concat_rows(pending, prep) if len(pending) else prep
        window = np.zeros(len(pending) + len(moves_chunk), dtype=PREP_DTYPE)
        window[:len(pending)] = pending
        self._prepare(moves_chunk, limits, window[len(pending):])
        return window

    def _prepare(self, moves_chunk: np.ndarray, limits: np.ndarray, out: np.ndarray | None) -> np.ndarray:
        """PREP rows of a chunk into ``out`` (zeroed rows, None = new ones)."""
        return self.sp.prepare_chunk(moves_chunk, limits, out)

    def plan(self, final: bool):
        """(rows planned for good, their PLAN rows, end time, context for segments())."""
        raise NotImplementedError

    def drop(self, n_rows: int) -> None:
        """The first n_rows of the window were emitted."""

    def reset(self) -> None:
        """A full stop at finish(): the next move starts from rest."""

    def segments(self, moves: np.ndarray, plan: np.ndarray, prep: np.ndarray, ctx, first_index: int) -> np.ndarray:
        return to_segments(moves, plan, first_index)


class _TrapezoidMode(_Mode):
    """Trapezoids: Klipper's lazy flush for 'klipper', the pinned-start rule for the other policies."""

    name = MODE_TRAPEZOID

    def plan(self, final: bool):
        sp = self.sp
        prep = sp.pending_prep
        rows = np.nonzero(prep["is_move"])[0]
        m = len(rows)
        bufs = speed_buffers(m)
        # Moves before the open run (the one not yet followed by a known full stop) are final.
        if final or sp.stop_pending:
            closed = m
        else:
            starts = np.flatnonzero(prep["stop_before"][rows])
            closed = int(starts[-1]) if starts.size else 0
        plan_runs(sp.policy_code, prep, rows, 0, closed, *bufs)
        done = closed
        if closed < m:
            flush = klipper_flush if sp.policy_code == POLICY_KLIPPER else standard_flush
            done = flush(prep, rows, closed, m, True, *bufs)
        # Emit every row before the first move still pending (dwell / dropped rows included).
        n_rows = len(sp.pending_moves) if done == m else int(rows[done])
        if n_rows == 0:
            return 0, None, sp.clock, None
        plan, t_end = layout_rows(sp.pending_moves[:n_rows], prep, n_rows, *bufs, sp.clock)
        return n_rows, plan, t_end, None


class _SCurveMode(_Mode):
    """Jerk-limited S-curves: up to the last junction certain to sit at its cap."""

    name = MODE_SCURVE
    own_segments = True

    def __init__(self, sp):
        super().__init__(sp)
        self.start_v = 0.0        # final start speed of the first pending move

    def window_prep(self, moves_chunk, limits):
        self.sp.check_same_jerk(moves_chunk, limits)
        return super().window_prep(moves_chunk, limits)

    def plan(self, final: bool):
        from .scurve import scurve_plan_window

        sp = self.sp
        n_rows, plan, t_end, v_end, ctx = scurve_plan_window(sp.pending_moves, sp.pending_prep, sp.jerk, self.start_v,
                                                             sp.clock, lazy=not final)
        self.start_v = v_end
        return n_rows, plan, t_end, ctx

    def reset(self) -> None:
        self.start_v = 0.0

    def segments(self, moves, plan, prep, ctx, first_index):
        from .scurve import scurve_segments

        return scurve_segments(moves, prep, plan, ctx, self.sp.jerk, first_index)


class _BlendMode(_Mode):
    """Parabolic blends: up to the last corner of the window that nothing after it can lower."""

    name = MODE_BLEND
    own_segments = True
    own_prepare = True

    def __init__(self, sp):
        super().__init__(sp)
        self.aux = np.zeros((0, 5))     # per-row tolerance and axis accelerations
        self.head = None                # the corner the window starts from (blend.blend_plan_window)

    def prepare(self, moves_chunk, limits):
        from .blend import blend_row_limits

        prep, aux = blend_row_limits(moves_chunk, limits, self.sp.machine)
        self.aux = np.concatenate([self.aux, aux]) if len(self.aux) else aux
        return prep

    def plan(self, final: bool):
        from .blend import blend_plan_window

        sp = self.sp
        n_rows, plan, t_end, ctx = blend_plan_window(sp.pending_moves, sp.pending_prep, self.aux, sp.clock,
                                                     lazy=not final, head=self.head)
        self.head = ctx["head"]
        return n_rows, plan, t_end, ctx

    def drop(self, n_rows: int) -> None:
        self.aux = self.aux[n_rows:].copy()

    def reset(self) -> None:
        self.head = None

    def segments(self, moves, plan, prep, ctx, first_index):
        from .blend import blend_segments

        return blend_segments(moves, plan, ctx, first_index)


class StreamPlanner:
    """``for moves_out, plan_out in sp.feed(chunk, limits): ...`` then the same with ``sp.finish()``."""

    def __init__(self, machine, policy: str | None = None, jerk: float | None = None):
        from .scurve import check_jerk

        self.machine = machine
        self.policy = policy or machine.junction_policy
        self._pcode = policy_code(self.policy)
        self._cap_v2 = custom_cap(self.policy)            # a registered policy's rule, None for built-ins
        self._kin_hook = kinematics_limits(machine)       # a plug-in kinematics' check_move, None for none
        self._jerk = None if jerk is None else check_jerk(jerk)
        self._jerk_from_limits = False
        self._mode: _Mode | None = None                   # decided by the first chunk with rows
        self._moves = np.zeros(0, dtype=MOVE_DTYPE)      # pending rows (not emitted yet)
        self._prep = np.zeros(0, dtype=PREP_DTYPE)
        self._last_move: np.ndarray | None = None         # the last real move prepared (1 row)
        self._last_prep: np.ndarray | None = None
        self._limits_checked: tuple | None = None         # (policy code, LIMITS bytes) that passed validate()
        self._stop_pending = True                         # a full stop precedes the next move
        self._clock = 0.0
        self._emitted: list[tuple[np.ndarray, np.ndarray, np.ndarray, object]] = []  # last call's pieces
        # a firmware model (machine.firmware) plans with the junction rules the firmware has (Marlin: classic
        # jerk or junction deviation; grbl: junction deviation); another policy asked for plans without the model.
        # Klipper's and LinuxCNC's models are their policies: they plan as "generic" here.
        firmware = firmware_model(machine, self.policy)
        self.firmware = firmware if firmware in OWN_PLANNER_FIRMWARES else "generic"
        self.e_position_sets = None                       # G92 E positions for a firmware model (pipeline sets)
        self.want_firmware_steps = False                  # a firmware model keeps its own step pulses

    # ------------------------------------------------------------------ public
    @property
    def mode(self) -> str | None:
        """'trapezoid', 'scurve' or 'blend' once the first rows arrived (None before)."""
        return None if self._mode is None else self._mode.name

    @property
    def own_segments(self) -> bool:
        """True when the plan's pieces are the mode's own (blends, S-curves), not rebuilt trapezoids."""
        return self._mode is not None and self._mode.own_segments

    def feed(self, moves_chunk: np.ndarray, limits: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """Add MOVE rows; return the (moves, plan) pieces whose plan can no longer change."""
        moves_chunk = np.asarray(moves_chunk)
        limits = np.asarray(limits)
        self._emitted = []
        if len(moves_chunk) == 0:
            return []
        if self._mode is None:
            self._mode = self._choose_mode(moves_chunk, limits)
            self._check_kinematics_limits_apply()
        self._prep = self._mode.window_prep(moves_chunk, limits)
        self._moves = prepend_rows(self._moves, moves_chunk)    # the reader's batch is not copied
        return self._emit(final=False)

    def finish(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """Plan everything still pending, ending at rest."""
        self._emitted = []
        out = self._emit(final=True)
        self._last_move = self._last_prep = None
        self._stop_pending = True
        if self._mode is not None:
            self._mode.reset()
        return out

    def segments_for(self, moves: np.ndarray, plan: np.ndarray, first_index: int = 0) -> np.ndarray:
        """SEGMENT rows of an emitted (moves, plan) pair, SEGMENT.move = first_index + row: the blend /
        S-curve planner's own pieces (ask before the next feed()/finish()), trapezoid pieces otherwise."""
        if self.own_segments:
            for moves_out, plan_out, prep_out, ctx in self._emitted:
                if plan_out is plan:
                    return self._mode.segments(moves_out, plan_out, prep_out, ctx, first_index)
            if len(plan) == 0:
                return to_segments(moves, plan, first_index)
            raise ConfigError("segments_for: blend and S-curve pieces exist only for the (moves, plan) pairs the "
                              "last feed()/finish() returned")
        return to_segments(moves, plan, first_index)

    def firmware_steps(self):
        """A firmware model's own step pulses for the rows the last feed()/finish() emitted ({axis index 0..2:
        (times s, dirs)}), when ``want_firmware_steps`` was set before the first feed; else None."""
        mode = self._mode
        steps = getattr(mode, "last_steps", None)
        if mode is not None and steps is not None:
            mode.last_steps = None
        return steps

    @property
    def pending(self) -> int:
        """Rows held in the look-ahead window."""
        return len(self._moves)

    # ------------------------------------------------------------------ what a planning mode uses (_Mode)
    @property
    def pending_moves(self) -> np.ndarray:
        """The window's MOVE rows (not emitted yet)."""
        return self._moves

    @property
    def pending_prep(self) -> np.ndarray:
        """The window's PREP rows, 1:1 with :attr:`pending_moves`."""
        return self._prep

    @property
    def clock(self) -> float:
        """s: the end time of everything emitted so far (the next emitted row starts there)."""
        return self._clock

    @property
    def policy_code(self) -> int:
        """The junction policy's kernel code (planner/prepare.py POLICY_*)."""
        return self._pcode

    @property
    def jerk(self) -> float | None:
        """mm/s³: the S-curve jerk, None for trapezoids."""
        return self._jerk

    @property
    def stop_pending(self) -> bool:
        """A known full stop precedes the next move (after a dwell/wait row, an exact stop, at the start)."""
        return self._stop_pending

    def prepare_chunk(self, moves_chunk: np.ndarray, limits: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """PREP rows of a chunk (into ``out``: zeroed rows, None = new ones), continuing the junctions from the
        last move prepared before it; the planner keeps that context between chunks."""
        pcode = POLICY_JD if self._pcode == POLICY_BLEND else self._pcode   # S-curves with blend: refused earlier
        # the same LIMITS table passes the same checks: checked again only when it has changed
        key = (pcode, limits.tobytes())
        if moves_chunk.dtype != MOVE_DTYPE or key != self._limits_checked:
            validate(moves_chunk, limits, pcode)
            self._limits_checked = key
        prep, self._stop_pending = prepare_with_context(moves_chunk, limits, pcode, self._last_move, self._last_prep,
                                                        self._stop_pending, cap_v2=self._cap_v2, out=out,
                                                        kinematics_hook=self._kin_hook)
        real = np.nonzero(prep["is_move"])[0]      # not flatnonzero: that copies the strided field first
        if real.size:
            self._last_move = moves_chunk[real[-1]:real[-1] + 1].copy()
            self._last_prep = prep[real[-1]:real[-1] + 1].copy()
        return prep

    # ------------------------------------------------------------------ internals
    def _check_kinematics_limits_apply(self) -> None:
        """A plug-in kinematics' speed limits (its check_move hook) are applied by the shared preparation; a mode
        that prepares its own rows (blend, LinuxCNC, the firmware models) would plan without them: an error, not
        a plan the machine cannot run."""
        if self._kin_hook is None or not getattr(self._mode, "own_prepare", False):
            return
        what = self.firmware if self.firmware != "generic" else f"the {self._mode.name} planner"
        raise ConfigError(f"kinematics {self.machine.kinematics!r}: its speed limits (Klipper's check_move) are "
                          f"applied by the look-ahead policies (klipper, junction-deviation, classic-jerk, "
                          f"exact-stop, S-curves), not by {what} yet: plan with one of those")

    def _choose_mode(self, moves: np.ndarray, limits: np.ndarray) -> _Mode:
        """plan_moves' dispatch: a jerk (argument, else the limits in force) selects S-curves, then 'blend'."""
        from .scurve import scurve_jerk

        if self.firmware != "generic":
            if self._jerk is not None:
                raise ConfigError(f"firmware {self.firmware}: --jerk / max_jerk do not apply (the firmware's own "
                                  "acceleration profile is modelled)")
            if self.firmware == "grbl-1.1":
                from .grbl import make_stream_mode as grbl_mode

                return grbl_mode(_Mode)(self)
            from .marlin import make_stream_mode as marlin_mode

            return marlin_mode(_Mode)(self)
        if self._jerk is None:
            self._jerk = scurve_jerk(moves, limits, None)
            self._jerk_from_limits = self._jerk is not None
        if self._jerk is not None:
            no_blend_with_jerk(self._pcode)
            return _SCurveMode(self)
        if self._pcode == POLICY_LINUXCNC:
            from .linuxcnc import make_stream_mode

            return make_stream_mode(_Mode)(self)
        return _BlendMode(self) if self._pcode == POLICY_BLEND else _TrapezoidMode(self)

    def check_same_jerk(self, moves: np.ndarray, limits: np.ndarray) -> None:
        """Whole-file planning takes the least max_jerk of the limits rows the program uses; a stream cannot
        know later rows, so a jerk from the limits must not change along the program."""
        if not self._jerk_from_limits:
            return
        from .scurve import scurve_jerk

        j = scurve_jerk(moves, limits, None)
        if j is not None and j != self._jerk:
            line = int(moves["line"][0])
            raise ConfigError(f"max_jerk changes from {self._jerk:g} to {j:g} mm/s³ near line {line}: "
                              "S-curve planning needs one jerk for the whole program (give --jerk)")

    def _emit(self, final: bool) -> list[tuple[np.ndarray, np.ndarray]]:
        if len(self._moves) == 0:
            return []
        n_rows, plan, t_end, ctx = self._mode.plan(final)
        if n_rows == 0:
            return []
        moves_out = self._moves[:n_rows]
        self._clock = t_end
        self._moves = self._moves[n_rows:].copy()
        prep_out = self._prep[:n_rows]
        self._prep = self._prep[n_rows:].copy()
        self._mode.drop(n_rows)
        if self._mode.own_segments:
            self._emitted.append((moves_out, plan, prep_out, ctx))
        return [(moves_out, plan)]


def plan_stream(chunks, limits_for_chunk, machine, policy: str | None = None, jerk: float | None = None):
    """Convenience: run a StreamPlanner over an iterable of MOVE chunks; (moves, plan) concatenated."""
    sp = StreamPlanner(machine, policy, jerk=jerk)
    outs = []
    for chunk in chunks:
        outs.extend(sp.feed(chunk, limits_for_chunk))
    outs.extend(sp.finish())
    if not outs:
        return np.zeros(0, dtype=MOVE_DTYPE), np.zeros(0, dtype=PLAN_DTYPE)
    return np.concatenate([o[0] for o in outs]), np.concatenate([o[1] for o in outs])


def no_blend_with_jerk(pcode: int) -> None:
    """Blends are constant-acceleration parabolas: a jerk limit cannot hold in them, and S-curve moves
    would silently fall back to junction-deviation corners while the result claimed 'blend'."""
    if pcode == POLICY_BLEND:
        raise ConfigError("the blend policy and S-curves (--jerk / max_jerk) cannot be combined: blends are "
                          "constant-acceleration parabolas; choose one")
    if pcode == POLICY_LINUXCNC:
        raise ConfigError("the linuxcnc policy plans trapezoids as LinuxCNC 2.9 does: --jerk / max_jerk do not apply")
