"""``Toolhead``: the planner fed incrementally, like a firmware's planner buffer.

G-code goes in a line or a file at a time; moves come out once their speeds can no longer change
(Klipper's lazy flush for the ``klipper`` policy, the equivalent rule of every other mode), and
everything becomes final at :meth:`Toolhead.flush` (a full stop, as Klipper's ``M400``) or
:meth:`Toolhead.close` (end of program). It is the very planner :func:`gcodeplan.plan` runs (same
scanner, interpreter and streaming planner), so its moves equal ``gp.plan`` on the same text bit
for bit, whatever the chunking.

Text is interpreted lazily, in blocks of ``block_lines`` lines (and at :meth:`Toolhead.flush` /
:meth:`Toolhead.close`), so that a firmware-style loop -- ``th.gcode(line)`` then ``th.committed()``
per line -- costs a few microseconds a line and planning runs over many moves at once (Klipper's own
look-ahead likewise plans only when its queue holds enough motion). ``committed()`` hands out what the
blocks interpreted so far made final: the same moves, bit for bit, whatever ``block_lines``; only how
soon they come out depends on it (``block_lines=1``: after the very line that made them final).

A Toolhead may be shared between threads: every public method holds the Toolhead's lock while it
runs, so calls never interleave inside the planner (lines fed from two threads are planned in the
order their calls took the lock). An uncontended lock costs well under a microsecond per call.
"""
from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from decimal import Decimal

import numpy as np

from .schema import KIND_NAMES, LIMIT_NAMES, MOVE_DTYPE, PLAN_DTYPE


@dataclass(frozen=True, slots=True)
class CommittedMove:
    """One planned row whose speeds are final. Speeds mm/s, times s (from the first move's start),
    positions mm (machine coordinates), ``accel`` mm/s²; ``kind``: 'travel', 'print', 'extrude_only',
    'dwell' or 'wait'; ``limit``: what bounded the cruise speed ('feed', 'max_velocity', 'accel',
    'junction', 'cruise_ratio', ...)."""

    index: int
    line: int
    kind: str
    x: float
    y: float
    z: float
    e: float
    move_d: float
    start_v: float
    cruise_v: float
    end_v: float
    accel: float
    start_time: float
    end_time: float
    limit: str


def _finite(v, name: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) and not hasattr(v, "__float__"):
        raise TypeError(f"Toolhead.move: {name} must be a number, got {type(v).__name__}")
    x = float(v)
    if not math.isfinite(x):
        raise ValueError(f"Toolhead.move: {name} must be a finite number, got {x!r}")
    return x


def gcode_number(v, name: str = "value") -> str:
    """``v`` as a G-code number: a plain decimal (no exponent: G-code reads ``1e-05`` as ``1`` followed by
    the word ``E-05``) with the shortest digits that read back as the same float (Python's ``repr``).
    Integers lose their ``.0``. NaN and ±inf are a ValueError naming ``name``."""
    x = _finite(v, name)
    text = repr(x)
    if "e" in text:                   # 1e-05, 1e+20: the same digits written out in full
        text = format(Decimal(text), "f")
    if text.endswith(".0"):
        text = text[:-2]
    return text


class Toolhead:
    """An incremental planner: ``gcode(text)``/``move(...)`` in, ``committed()`` moves out.

    ``machine``: a :class:`~gcodeplan.machine.Machine` or preset name (None = ``klipper``);
    ``policy``, ``jerk`` as in :func:`gcodeplan.plan`; ``strict``: unknown commands are errors;
    ``steps``: keep the step times of the final moves for :meth:`steps` (``kinematics``, ``sds_filter``,
    ``ik_search`` as for :func:`gcodeplan.steps`); ``sinks``: pipeline sinks (:class:`gcodeplan.pipeline.Sink`)
    handed every final piece as :func:`gcodeplan.pipeline.run` hands them, and closed at :meth:`close`;
    ``block_lines``: lines buffered before they are interpreted and planned (``committed()`` sees moves
    made final by the blocks interpreted so far; 1 = by every line fed, each line planned alone).
    Thread-safe: every method holds the Toolhead's lock (a feeding thread and a draining thread see
    exactly the plan of the text fed).
    """

    def __init__(self, machine=None, policy: str | None = None, jerk: float | None = None, *,
                 strict: bool = False, block_lines: int = 512, name: str = "<toolhead>", steps: bool = False,
                 kinematics=None, sds_filter: float | None = None, ik_search: str = "klipper", sinks=()):
        from .api import as_machine
        from .gcode import GcodeReader
        from .planner import StreamPlanner

        self.machine = as_machine(machine)
        self.policy = policy or self.machine.junction_policy
        self._reader = GcodeReader([], self.machine, strict=strict)
        self._reader.path = self._reader.interp.path = name
        self._planner = StreamPlanner(self.machine, policy=self.policy, jerk=jerk)
        self._planner.e_position_sets = self._reader.interp.e_position_sets   # G92 E, for firmware models
        self.block_lines = max(1, int(block_lines))
        self._steps: dict[int, list] | None = None
        self._step_sink = None
        self._sinks = list(sinks)       # pipeline sinks (gcodeplan.pipeline.Sink): each final piece, as gp.run
        if steps:      # the step stage gp.steps runs, fed each final piece as it comes (stepper/source.py)
            from .stepper.source import StepSink, rails_from

            self._rails = rails_from(self.machine, kinematics)
            self._steps = {}
            self._step_sink = StepSink(self._rails, self._collect_steps, sds_filter_t=sds_filter,
                                       machine=self.machine, ik_search=ik_search)
            self._sinks.append(self._step_sink)
        if any(getattr(sk, "wants_firmware_steps", False) for sk in self._sinks):
            self._planner.want_firmware_steps = True
        self._text: list[bytes] = []
        self._lines_waiting = 0
        self._out: list[tuple[np.ndarray, np.ndarray]] = []   # final (moves, plan) not yet handed out
        self._rows = 0            # rows made final so far
        self._handed = 0          # rows handed out by committed()
        self._closed = False
        # one lock for all state: a Toolhead fed from two threads would otherwise interleave the
        # reader's and planner's updates (wrong row counts, divisions by a half-updated clock)
        self._lock = threading.Lock()

    # ------------------------------------------------------------------ input
    def gcode(self, text: str | bytes) -> None:
        """Queue G-code: one or many lines (a str or bytes-like; a missing last newline is added).
        Anything else (a number, None, a list) is a TypeError."""
        if isinstance(text, str):
            data = text.encode("utf-8")
        elif isinstance(text, (bytes, bytearray, memoryview)):
            data = bytes(text)
        else:
            raise TypeError(f"Toolhead.gcode() takes G-code text (str or bytes), got {type(text).__name__}")
        with self._lock:
            self._queue(data)

    def _queue(self, data: bytes) -> None:
        if self._closed:
            raise RuntimeError("Toolhead.gcode() after close()")
        if not data.endswith(b"\n"):
            data += b"\n"
        self._text.append(data)
        self._lines_waiting += data.count(b"\n")
        if self._lines_waiting >= self.block_lines:
            self._interpret()

    def move(self, x: float | None = None, y: float | None = None, z: float | None = None, e: float | None = None,
             speed: float | None = None, rapid: bool = False) -> None:
        """Queue one linear move to (x, y, z, e) mm (None = unchanged) at ``speed`` mm/s (None = the modal
        feed rate). It is written as a ``G1``/``G0`` line in the current modes (G90/G91, M82/M83, G20
        units), so it behaves exactly like the same G-code line. Every number is written as a plain
        decimal that reads back as the same float (never ``1e-05``, which G-code reads as X1 E-05);
        a value that is not a finite number (NaN, ±inf) is a ValueError, a speed must be > 0."""
        words = ["G0" if rapid else "G1"]
        for letter, v in (("X", x), ("Y", y), ("Z", z), ("E", e)):
            if v is not None:
                words.append(letter + gcode_number(v, letter.lower()))
        if speed is not None:
            mm_s = _finite(speed, "speed")
            if not mm_s > 0.0:
                raise ValueError(f"Toolhead.move: speed must be > 0 mm/s, got {mm_s!r}")
            words.append("F" + gcode_number(mm_s * 60.0, "speed·60 (mm/min)"))
        self.gcode(" ".join(words))

    # ------------------------------------------------------------------ planning
    def _interpret(self) -> None:
        if not self._text:
            return
        data = b"".join(self._text)
        self._text.clear()
        self._lines_waiting = 0
        for rows in self._reader.feed(data):
            self._plan(self._planner.feed(rows, self._reader.limits))

    def _plan(self, pairs) -> None:
        for moves, plan in pairs:
            if self._sinks:
                self._to_sinks(moves, plan)
            if len(moves):
                self._out.append((moves, plan))
                self._rows += len(moves)

    def _to_sinks(self, moves: np.ndarray, plan: np.ndarray) -> None:
        """Hand a final (moves, plan) pair to the sinks as the pipeline's Run does (gp.steps' step stage
        among them), while the planner still holds its segments."""
        from .pipeline import Piece

        sp = self._planner
        piece = Piece(moves, plan, self._rows, sp.mode, make_segments=sp.segments_for,
                      own_segments=sp.own_segments, limits=self._reader.limits)
        piece.firmware_steps = sp.firmware_steps()
        for sink in self._sinks:
            sink.add(piece)

    def _collect_steps(self, stepper: int, times_s: np.ndarray, dirs: np.ndarray) -> None:
        self._steps.setdefault(stepper, []).append((times_s.copy(), dirs.copy()))

    def flush(self) -> None:
        """A full stop: everything queued is planned to rest and becomes final (Klipper's ``M400``)."""
        with self._lock:
            self._interpret()
            self._plan(self._planner.finish())

    def close(self) -> None:
        """End of program: interpret a last line without a newline, plan everything to rest."""
        with self._lock:
            if self._closed:
                return
            self._interpret()
            for rows in self._reader.end():
                self._plan(self._planner.feed(rows, self._reader.limits))
            self._plan(self._planner.finish())
            self._closed = True
            if self._sinks:
                from .pipeline import RunResult

                result = RunResult(self._reader, self.machine, self.policy, self._planner.mode, self._rows, False,
                                   self._reader.path)
                for sink in self._sinks:
                    sink.close(result)      # the step sink: the last steps (StepGenerator.finish)

    # ------------------------------------------------------------------ output
    def committed_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """(MOVE rows, PLAN rows) made final since the last ``committed()`` / ``committed_arrays()`` call,
        by the text interpreted so far (whole blocks of ``block_lines`` lines; everything after
        :meth:`flush` / :meth:`close`). The PLAN rows' times continue across calls."""
        with self._lock:
            return self._take()

    def _take(self) -> tuple[np.ndarray, np.ndarray]:
        out = self._out
        if not out:
            return np.zeros(0, MOVE_DTYPE), np.zeros(0, PLAN_DTYPE)
        if len(out) == 1:
            moves, plan = out[0]
        else:
            moves = np.concatenate([m for m, _ in out])
            plan = np.concatenate([p for _, p in out])
        out.clear()
        self._handed += len(moves)
        return moves, plan

    def committed(self) -> list[CommittedMove]:
        """The rows made final since the last call, as :class:`CommittedMove` objects (see
        :meth:`committed_arrays`: by the text interpreted so far)."""
        with self._lock:
            if not self._out:           # the per-line case of a firmware loop: nothing new, no arrays made
                return []
            first = self._handed
            moves, plan = self._take()
        # whole columns to Python floats at once: per-row field access of a structured array costs µs each
        t_start = plan["t_start"]
        cols = zip(range(first, first + len(moves)), moves["line"].tolist(), moves["kind"].tolist(),
                   moves["x1"].tolist(), moves["y1"].tolist(), moves["z1"].tolist(), moves["e1"].tolist(),
                   moves["move_d"].tolist(), plan["start_v"].tolist(), plan["cruise_v"].tolist(),
                   plan["end_v"].tolist(), plan["accel"].tolist(), t_start.tolist(),
                   (t_start + plan["duration"]).tolist(), plan["limit"].tolist())
        kinds, limits = KIND_NAMES, LIMIT_NAMES
        return [CommittedMove(i, ln, kinds[k], x, y, z, e, d, sv, cv, ev, a, t0, t1, limits[lim])
                for i, ln, k, x, y, z, e, d, sv, cv, ev, a, t0, t1, lim in cols]

    def steps(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Step times of the final moves since the last call: ``{stepper name: (times_s float64, dirs int8)}``,
        times from the first move's start, as :func:`gcodeplan.steps` gives them (Klipper's step convention);
        the concatenation of every call's arrays equals ``gp.steps`` on the same program bit for bit. Steps
        come out as the step generator computes them (it may hold a move's last steps until the next move is
        known, and shaped or pressure-advanced motors lag by the smoothing window; all after :meth:`close`). Needs ``Toolhead(..., steps=True)`` (``kinematics``,
        ``sds_filter`` as for :func:`gcodeplan.steps`)."""
        with self._lock:
            if self._steps is None:
                raise RuntimeError("Toolhead.steps() needs Toolhead(..., steps=True): the step stage must see "
                                   "every move from the first")
            if not self._closed:
                self._step_sink.generator.release()
            parts, self._steps = self._steps, {}
        out = {}
        for si, rail in enumerate(self._rails):
            chunks = parts.get(si)
            if not chunks:
                out[rail.name] = (np.empty(0, np.float64), np.empty(0, np.int8))
            elif len(chunks) == 1:
                out[rail.name] = chunks[0]
            else:
                out[rail.name] = (np.concatenate([c[0] for c in chunks]), np.concatenate([c[1] for c in chunks]))
        return out

    @property
    def pending(self) -> int:
        """Rows planned but not final yet (held in the look-ahead window; lines queued but not interpreted
        yet, fewer than ``block_lines``, are not counted)."""
        with self._lock:
            return self._planner.pending

    @property
    def print_time(self) -> float:
        """End time (s) of the last final move: the planned time so far."""
        with self._lock:
            return self._planner.clock

    @property
    def summary(self):
        """The parser's running summary (complete after :meth:`close`)."""
        return self._reader.summary


__all__ = ["Toolhead", "CommittedMove", "gcode_number"]
