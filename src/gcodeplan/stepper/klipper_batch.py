"""Klipper's step-generation windows in batch mode (``klippy.py printer.cfg -i file.gcode -o out.serial``).

Klipper's iterative step search restarts at the end of every step-generation window, so a step can land one
clock tick (or, on a slow angle motor, a few) apart depending on where the windows end. A printer's windows
follow its host's wall clock; in batch mode there is no clock (every estimated print time is 0) and the
schedule is a pure function of the input bytes and the plan. :func:`batch_flush_times` reproduces it; it is
what the reference step files of ``../shared/reference/klipper`` were made with.

How the schedule arises (Klipper v0.13, klippy: reactor.py, gcode.py GCodeIO, toolhead.py,
extras/motion_queuing.py; names below are Klipper's):

* The reactor's loop reads the input ``read_size`` = 4096 bytes at a time (GCodeIO._process_data) and runs
  every complete line of it at once; then it runs the timers that are due, among them the background flush
  timer (PrinterMotionQueuing._flush_handler_debug in batch mode).
* Each line adds its moves to the look-ahead queue (LookAheadQueue.add_move). When the queued moves' minimum
  durations use up the flush budget (1 s after a full flush, then 0.15 s) the queue is flushed lazily: the moves
  whose speeds can no longer change go to the motion queue, and ``need_flush_time`` becomes the end of the last
  of them plus kin_flush_delay (note_mcu_movequeue_activity), which wakes the flush timer.
* The flush timer makes windows ``batch_t`` = 0.700 − 0.450 s long (BGFLUSH_SG_HIGH_TIME − BGFLUSH_SG_LOW_TIME,
  a hair under 0.25 s in binary) from the last window end while that end is below need_flush_time − 1.5 s;
  after 100 windows in one timer call it jumps to the last whole batch below that bound. A file whose 4096-byte
  reads hold more than ~25 s of motion therefore skips windows (on the PrusaSlicer cube: from print time 25.25 s
  to 85.5 s, then a few seconds every ~30 s).
* SET_KINEMATIC_POSITION (and G28) flush the look-ahead and end a window at the last move's end plus
  kin_flush_delay (ToolHead.flush_step_generation); G4, M400 and waits flush the look-ahead only.
* While the print time is at most 1 s (the first moves) the toolhead yields to the reactor after each lazy flush
  (ToolHead._check_pause); the reactor then reads the next block while the current one is still being run, and
  runs the flush timer in between: the first blocks are merged for the timer.

The reference runs disabled Klipper's batch-mode run-out (its last catch-up window and the priming timer) so
that the plan does not depend on how the reads fall; this model is of that setup, which is also the plan
gcodeplan computes. The windows returned are the timer's and the position-set ones; the final flush at the end
of the input (the last move's end + kin_flush_delay) is left out, as the step generator ends the program itself.

Not modelled: homing moves (G28 is taken as an instant position set, as the references do), drip moves
(probing), heater waits (M109/M190 are taken as a look-ahead flush), input shaping's and pressure advance's
longer scan windows (pass ``kin_flush_delay``). Checked against every recorded schedule in
``../shared/reference/klipper/compression`` (tests/test_klipper_batch.py).
"""
from __future__ import annotations

import math

import numpy as np

from ..schema import KIND_DWELL, KIND_WAIT

KLIPPER_READ_BYTES = 4096           # GCodeIO._process_data: os.read(fd, 4096)
KLIPPER_BATCH_T = 0.700 - 0.450     # s, BGFLUSH_SG_HIGH_TIME − BGFLUSH_SG_LOW_TIME (0.24999999999999994)
KLIPPER_BATCH_LAG_T = 1.5           # s, the timer stays this far behind need_flush_time in batch mode
KLIPPER_BATCH_JUMP_AFTER = 100      # windows in one timer call before it jumps ahead
KLIPPER_FLUSH_LAG_T = 0.050         # s, STEPCOMPRESS_FLUSH_TIME: flush_time = window end − this
KLIPPER_SDS_CHECK_T = 0.001         # s, SDS_CHECK_TIME: the default kin_flush_delay
KLIPPER_BUFFER_HIGH_T = 1.0         # s, BUFFER_TIME_HIGH: flush budget after a full flush; pause threshold
KLIPPER_BUFFER_START_T = 0.250      # s, BUFFER_TIME_START: the first move's print time
KLIPPER_LOOKAHEAD_T = 0.150         # s, LOOKAHEAD_FLUSH_TIME: flush budget after a lazy flush
KLIPPER_MIN_KIN_T = 0.100           # s, MIN_KIN_TIME
_NEVER = math.inf
_POSITION_SET = ("SET_KINEMATIC_POSITION", "G28")


def line_end_offsets(data: bytes) -> np.ndarray:
    """Byte offset just after each line's newline (int64; entry i is line i + 1). A last line without a newline
    is left out: Klipper's reader keeps it as a partial line and never runs it."""
    nl = np.flatnonzero(np.frombuffer(data, np.uint8) == 10)
    return nl.astype(np.int64) + 1


def position_set_lines(text_lines) -> set[int]:
    """1-based numbers of the lines that set the position (SET_KINEMATIC_POSITION, G28): Klipper ends a step
    window there (flush_step_generation)."""
    out = set()
    for i, ln in enumerate(text_lines):
        words = ln.split(";", 1)[0].split()
        if words and words[0].upper() in _POSITION_SET:
            out.add(i + 1)
    return out


class _MotionQueuing:
    """PrinterMotionQueuing's flush bookkeeping: need_flush_time, the flush timer and the windows made."""

    def __init__(self, kin_flush_delay: float):
        self.kin_flush_delay = kin_flush_delay
        self.need_flush_t = 0.0           # s, print time
        self.need_step_gen_t = 0.0
        self.last_flush_t = 0.0
        self.last_step_gen_t = 0.0
        self.kick_timer = True            # do_kick_flush_timer
        self.timer_due = False            # the flush timer waits to run (waketime NOW)
        self.windows: list[float] = []    # step_gen_time of every steppersyncmgr_gen_steps call

    def note_activity(self, mq_t: float) -> None:
        """note_mcu_movequeue_activity for step generation: both bounds move to mq_t + kin_flush_delay."""
        mq_t += self.kin_flush_delay
        self.need_step_gen_t = max(self.need_step_gen_t, mq_t)
        self.need_flush_t = max(self.need_flush_t, mq_t)
        if self.kick_timer:
            self.kick_timer = False
            self.timer_due = True

    def advance_flush_time(self, want_flush_t: float, want_step_gen_t: float = 0.0) -> None:
        """One step-generation call (window end step_gen_time)."""
        flush_t = max(want_flush_t, self.last_flush_t, want_step_gen_t - KLIPPER_FLUSH_LAG_T)
        step_gen_t = max(want_step_gen_t, self.last_step_gen_t, flush_t)
        self.windows.append(step_gen_t)
        self.last_flush_t = flush_t
        self.last_step_gen_t = step_gen_t

    def flush_all_steps(self) -> None:
        """Every step up to need_step_gen_time (a position set; can_pause is False in batch mode)."""
        self.advance_flush_time(self.need_step_gen_t)

    def flush_timer(self) -> None:
        """The batch-mode flush timer, without its final catch-up window (the references' setup)."""
        bound = self.need_flush_t - KLIPPER_BATCH_LAG_T
        made = 0
        while self.last_step_gen_t < bound:
            target = self.last_step_gen_t + KLIPPER_BATCH_T
            if made > KLIPPER_BATCH_JUMP_AFTER and bound > target:
                target += int((bound - target) / KLIPPER_BATCH_T) * KLIPPER_BATCH_T
            self.advance_flush_time(0.0, target)
            made += 1
        if made:
            return                        # runs again at the next reactor turn
        self.kick_timer = True
        self.timer_due = False


class _Toolhead:
    """ToolHead + LookAheadQueue timing over gcodeplan's plan: which moves are flushed when, and the print time."""

    def __init__(self, prep, rows, move_end_t, mq: _MotionQueuing):
        from ..planner.passes import speed_buffers

        self.prep = prep
        self.rows = rows                  # MOVE row of each queued move (compact index k)
        self.move_end_t = move_end_t      # s, print time at the end of compact move k
        self.min_move_t = prep["move_d"][rows] / np.sqrt(prep["max_cruise_v2"][rows])
        self.mq = mq
        self.bufs = speed_buffers(len(rows))
        self.lo = 0                       # first compact move still in the look-ahead queue
        self.flush_budget = KLIPPER_BUFFER_HIGH_T   # junction_flush
        self.print_t = 0.0
        self.special = True               # "NeedPrime" / "Priming"
        self.check_pause_t = -1.0         # need_check_pause

    def add_move(self, k: int) -> bool:
        """Queue compact move k (LookAheadQueue.add_move, then ToolHead.move's checks); True when the
        toolhead yields to the reactor (ToolHead._check_pause)."""
        if k > self.lo:                   # the first move of an empty queue spends no budget
            self.flush_budget -= self.min_move_t[k]
            if self.flush_budget <= 0.0:
                self.process_lookahead(k + 1, lazy=True)
        if self.print_t > self.check_pause_t:
            return self.check_pause(k + 1)
        return False

    def process_lookahead(self, hi: int, lazy: bool) -> None:
        """Flush the queue [lo, hi) (lazily: only the moves that cannot change) into the motion queue."""
        from ..planner.passes import klipper_flush

        self.flush_budget = KLIPPER_LOOKAHEAD_T
        if hi <= self.lo:
            return
        done = klipper_flush(self.prep, self.rows, self.lo, hi, True, *self.bufs) if lazy else hi
        if done <= self.lo:
            return
        if self.special:
            self.special = False
            self.check_pause_t = -1.0
            self.calc_print_time()
        self.lo = done
        self.print_t = max(self.print_t, self.move_end_t[done - 1])
        self.mq.note_activity(self.print_t)

    def calc_print_time(self) -> None:
        """The print time a move may start at after a stop (estimated print time 0 in batch mode)."""
        kin_t = max(KLIPPER_MIN_KIN_T, self.mq.last_step_gen_t) + self.mq.kin_flush_delay
        self.print_t = max(self.print_t, KLIPPER_BUFFER_START_T, kin_t)

    def flush_lookahead(self, hi: int) -> None:
        """Full flush (G4, M400, position set, end of input)."""
        self.process_lookahead(hi, lazy=False)
        self.special = True
        self.check_pause_t = -1.0
        self.flush_budget = KLIPPER_BUFFER_HIGH_T

    def check_pause(self, queued_hi: int) -> bool:
        """True when the toolhead yields (the buffer holds ≤ BUFFER_TIME_HIGH of motion, in the main state)."""
        if self.special and queued_hi > self.lo:
            self.check_pause_t = -1.0     # "Priming" (its timer is off in the references' setup)
        if self.print_t - KLIPPER_BUFFER_HIGH_T > 0.0:
            self.check_pause_t = _NEVER   # batch mode cannot pause
            return False
        if self.special:
            return False
        self.check_pause_t = self.print_t
        return True

    def dwell(self, hi: int, delay_t: float) -> None:
        self.flush_lookahead(hi)
        self.print_t += delay_t
        if self.print_t > self.check_pause_t:
            self.check_pause(hi)


def batch_flush_times(line_ends, moves, prep, plan, set_lines=(), *, read_size: int = KLIPPER_READ_BYTES,
                      kin_flush_delay: float = KLIPPER_SDS_CHECK_T,
                      first_move_t: float = KLIPPER_BUFFER_START_T) -> np.ndarray:
    """Klipper's batch-mode step-generation window ends (s from the first move's start, increasing; for
    :class:`gcodeplan.stepper.generate.StepGenerator` ``flush_times``) for a program and its plan.

    ``line_ends``: :func:`line_end_offsets` of the bytes Klipper reads (after any preprocessing; only the
    offsets matter); ``moves``, ``prep``, ``plan``: the program's MOVE, PREP and PLAN rows (1:1, Klipper's
    junction policy, the plan Klipper makes); ``set_lines``: :func:`position_set_lines`; ``read_size``: bytes
    per read (4096); ``kin_flush_delay`` (s): Klipper's step-generation scan window (0.001 s without input
    shaping / pressure-advance smoothing); ``first_move_t`` (s): the first move's print time. The final flush
    at the end of the input is not included.
    """
    line_ends = np.asarray(line_ends, np.int64)
    rows = np.flatnonzero(prep["is_move"])
    move_end_t = first_move_t + (plan["t_start"] + plan["duration"])[rows]
    mq = _MotionQueuing(kin_flush_delay)
    th = _Toolhead(prep, rows, move_end_t, mq)
    set_lines = set(set_lines)
    # per line: its MOVE rows (with their compact move index, or -1), in order
    compact = np.full(len(moves), -1, np.int64)
    compact[rows] = np.arange(len(rows))
    first_row = np.searchsorted(moves["line"], np.arange(len(line_ends) + 2), side="left")

    def run_line(line: int):
        """The line's commands (a generator: it yields where the toolhead yields to the reactor)."""
        for i in range(first_row[line], first_row[line + 1]):
            k = int(compact[i])
            if k >= 0:
                if th.add_move(k):
                    yield
            elif moves["kind"][i] in (KIND_DWELL, KIND_WAIT):
                hi = int(np.searchsorted(rows, i))
                if line in set_lines:
                    th.flush_lookahead(hi)
                    mq.flush_all_steps()
                elif moves["kind"][i] == KIND_DWELL:
                    th.dwell(hi, float(moves["dwell_t"][i]))
                else:
                    th.flush_lookahead(hi)

    _reactor(line_ends, read_size, run_line, mq)
    t = np.asarray(mq.windows, np.float64) - first_move_t
    return t


def _reactor(line_ends: np.ndarray, read_size: int, run_line, mq: _MotionQueuing) -> None:
    """The reactor's loop in batch mode until the end of the input: read a block, run its complete lines (the
    reader's handler, GCodeIO._process_data), then the flush timer if due. When the lines yield, a new turn of
    the loop reads the next block without running it (it is queued behind the running ones; reading stops
    once 20 lines wait), runs the timer, and resumes them."""
    n_bytes = int(line_ends[-1]) if len(line_ends) else 0
    state = {"read": 0, "lines": 0, "fd": True, "queued": []}

    def read_block() -> list[int] | None:
        """The lines completed by the next read, None at the end of the input."""
        if state["read"] >= n_bytes:
            return None
        state["read"] = min(state["read"] + read_size, n_bytes)
        done = int(np.searchsorted(line_ends, state["read"], side="right"))
        new = list(range(state["lines"] + 1, done + 1))
        state["lines"] = done
        return new

    def process_data(lines: list[int]):
        while lines:
            state["queued"] = []
            for ln in lines:
                yield from run_line(ln)
            lines = state["queued"]
        state["fd"] = True

    running = None                        # the paused reader handler (a generator), if any
    while True:
        if state["fd"]:
            block = read_block()
            if block is None:
                if running is None:
                    return                # end of input: klippy exits (final flush not returned)
                state["fd"] = False
            elif running is None:
                gen = process_data(block)
                if next(gen, StopIteration) is not StopIteration:
                    running = gen         # yielded: a new turn of the loop starts at once
                    continue
            else:
                state["queued"].extend(block)
                if len(state["queued"]) >= 20:
                    state["fd"] = False
        if mq.timer_due:
            mq.flush_timer()
        if running is not None and next(running, StopIteration) is StopIteration:
            running = None


def klipper_batch_flush_times(source, machine, *, read_size: int = KLIPPER_READ_BYTES,
                              kin_flush_delay: float = KLIPPER_SDS_CHECK_T) -> np.ndarray:
    """:func:`batch_flush_times` of a G-code file (path) or text (str / bytes), planned for ``machine``
    (Klipper's policy): the windows ``klippy.py -i file -o out`` uses for exactly these bytes.

    Refused (ConfigError) for a machine that does not plan as Klipper does, and for input shaping or pressure
    advance at any point of the program: Klipper then widens its scan window (kin_flush_delay) by the shaper's
    or the smoothing's reach, which this model does not compute (give ``kin_flush_delay`` to
    :func:`batch_flush_times` instead)."""
    import gcodeplan.api as gp
    from ..errors import ConfigError
    from ..planner.prepare import prepare

    if getattr(machine, "junction_policy", None) != "klipper":
        raise ConfigError("Klipper's batch windows need Klipper's planner (a printer.cfg machine, policy klipper)")

    if isinstance(source, (bytes, bytearray)):
        data = bytes(source)
    elif isinstance(source, str) and "\n" not in source:
        with open(source, "rb") as f:
            data = f.read()
    else:
        data = str(source).encode()
    text = data.decode("utf-8", errors="replace").split("\n")
    if text and text[-1] == "":
        text.pop()
    p = gp.plan(text, machine)
    lim = p.limits
    if kin_flush_delay == KLIPPER_SDS_CHECK_T and len(lim) and (
            np.any(lim["shaper_freq_x"] > 0) or np.any(lim["shaper_freq_y"] > 0) or np.any(lim["pa_k"] > 0)):
        raise ConfigError("Klipper's batch windows with input shaping or pressure advance depend on their scan "
                          "window (kin_flush_delay), which is not modelled: give it to batch_flush_times")
    prep = prepare(p.moves, lim, machine)
    return batch_flush_times(line_end_offsets(data), p.moves, prep, p.plan, position_set_lines(text),
                             read_size=read_size, kin_flush_delay=kin_flush_delay)


__all__ = ["batch_flush_times", "klipper_batch_flush_times", "line_end_offsets", "position_set_lines",
           "KLIPPER_READ_BYTES", "KLIPPER_BATCH_T"]
