"""The one driver every command, tool and test uses: reader → planner → sinks.

A *source* (path, ``-``, file object or iterable of lines: :mod:`gcodeplan.gcode.reader`) is parsed in
batches of MOVE rows; the streaming planner turns them into final (MOVE, PLAN) pieces with a bounded
look-ahead window; every piece goes to each *sink* in order. ``piece.segments`` gives its SEGMENT
rows, the planner's own pieces (blends and S-curve
phases are not trapezoids) on first access. Memory is bounded by the window and whatever the sinks keep.

    from gcodeplan.pipeline import run, Sink

    class Count(Sink):
        def __init__(self):
            self.moves = 0
        def add(self, piece):
            self.moves += len(piece.moves)

    result = run("part.gcode", machine, sinks=[Count()])

``result.reader`` holds what the parser learned (summary, layer heights, feature names, limits table).
"""
from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from . import _jit
from .errors import located


def small_input(source) -> bool:
    """True when ``source`` is a plain-text file or a list of lines of at most ``_jit.SMALL_INPUT_BYTES``:
    the run then executes its kernels as Python instead of paying numba's start-up (gcodeplan/_jit.py;
    identical results). Compressed, binary, streamed and unknown-size sources are never small."""
    if isinstance(source, (list, tuple)):
        total = 0
        for line in source:
            if not isinstance(line, (str, bytes)):
                return False
            total += len(line)
            if total > _jit.SMALL_INPUT_BYTES:
                return False
        return True
    size = _file_size(source)
    if size is None or size > _jit.SMALL_INPUT_BYTES:
        return False
    try:
        with open(source, "rb") as f:
            head = f.read(4)
    except (OSError, ValueError):
        return False
    return head[:2] != b"\x1f\x8b" and head != b"GCDE"     # gzip and binary G-code decode to more


def _file_size(source) -> int | None:
    """Bytes of the regular file ``source`` names (a path; never ``-``, stdin), None for anything else."""
    import os
    import stat

    if not isinstance(source, (str, os.PathLike)) or str(source) == "-":
        return None
    try:
        st = os.stat(source)
    except (OSError, ValueError):
        return None
    return st.st_size if stat.S_ISREG(st.st_mode) else None


#: path inputs of at least this many bytes are read and interpreted in a second thread while the planner and
#: the sinks work on earlier batches (:func:`read_ahead`); below it the thread is not worth starting
READ_AHEAD_BYTES = 1 << 20


def read_ahead_input(source) -> bool:
    """True when ``source`` is the path of a regular file of at least :data:`READ_AHEAD_BYTES` (never stdin,
    a file object or lines: those belong to the caller's thread)."""
    size = _file_size(source)
    return size is not None and size >= READ_AHEAD_BYTES


#: the reader thread hands its batches back to the main thread once more than this share of its time went to
#: lines interpreted in Python (arcs, canned cycles): two threads both running Python mostly wait for each
#: other's GIL (a 9,170-arc LinuxCNC program took 1.9-2.5 s in two threads, 1.5-1.6 s in one)
READ_AHEAD_MAX_PYTHON_SHARE = 0.3
#: s of reading before that share is judged (the first batch includes loading the reader's kernels)
READ_AHEAD_PROBE_S = 0.05

_END = object()


class _HandOver:
    """Queue item: the reader thread stops; the main thread goes on with the batches generator itself."""

    def __init__(self, batches):
        self.batches = batches


def read_ahead(reader, depth: int = 3):
    """``reader.batches()`` run in a second thread: yields (MOVE batch, LIMITS table so far, bytes read so
    far), the values the reader had right after making that batch, in file order.

    The kernels release the GIL (``nogil``), so parsing overlaps planning on a second core. A reader that
    spends more than :data:`READ_AHEAD_MAX_PYTHON_SHARE` of its time in Python hands the rest of the
    reading back to this thread. An error raised while reading is raised here, after the batches before it,
    as it would be without the thread. Leaving the loop early (or an exception in the caller: a signal, a
    sink's error) stops the reader at its next batch; the thread is joined before this generator finishes,
    so no reading outlives it.
    """
    import queue
    import threading
    from time import perf_counter

    items: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()

    def put(item) -> bool:
        while not stop.is_set():
            try:
                items.put(item, timeout=0.05)
                return True
            except queue.Full:
                continue
        return False

    def produce():
        batches = reader.batches()
        t_start = perf_counter()
        try:
            for moves in batches:
                if not put((moves, reader.limits, reader.bytes_read)):
                    return
                spent_s = perf_counter() - t_start
                if spent_s > READ_AHEAD_PROBE_S and reader.python_s > READ_AHEAD_MAX_PYTHON_SHARE * spent_s:
                    if put(_HandOver(batches)):
                        batches = None               # the main thread owns it now
                    return
            put(_END)
        except BaseException as err:          # handed to the consumer, which raises it in its own thread
            put(err)
        finally:
            if batches is not None:
                batches.close()

    _jit.activate()          # once, here, not raced by two threads' first kernel calls
    worker = threading.Thread(target=produce, name="gcodeplan-reader", daemon=True)
    handed = None
    try:
        worker.start()           # inside: a signal interrupting start() must still stop the thread
        while True:
            try:
                # a short wait: a signal that the OS delivered to the reader thread is handled by this one
                # only when it runs again
                item = items.get(timeout=0.1)
            except queue.Empty:          # never wait on a reader that is gone (it always says how it ended)
                if worker.is_alive() or not items.empty():
                    continue
                raise RuntimeError("gcodeplan's reader thread ended without a result") from None
            if item is _END:
                return
            if isinstance(item, BaseException):
                raise item
            if isinstance(item, _HandOver):
                _join_through_signals(worker)
                handed = item.batches
                for moves in handed:
                    yield moves, reader.limits, reader.bytes_read
                return
            yield item
    finally:
        stop.set()
        if worker.ident is not None:     # started
            _join_through_signals(worker)
        if handed is not None:
            handed.close()


def _join_through_signals(worker) -> None:
    """``worker.join()``, finished even when a signal's exception (raised again each second until the command
    has caught it: gcodeplan/signals.py) interrupts it: a reader thread left running in a nogil kernel while
    the interpreter shuts down can crash the process on its way out. The interruption is raised again once the
    thread is gone."""
    pending = None
    while True:
        try:
            worker.join()
            break
        except KeyboardInterrupt as err:
            pending = err
    if pending is not None:
        raise pending


def open_reader(source, machine, *, strict: bool = False, batch_moves: int = 8192):
    """(GcodeReader over ``source``, small): ``small`` when :func:`small_input` says the kernels should run as
    Python (wrap the reading in ``gcodeplan._jit.interpreted(small)``); the reader then reads in short pieces,
    since an interpreted kernel copies its arrays."""
    from .gcode import GcodeReader

    small = small_input(source)
    extra = {}
    if small:
        batch_moves = min(batch_moves, 512)
        extra["chunk_bytes"] = 2 * _jit.SMALL_INPUT_BYTES
    # what the file says it is (gcode/dialect.py): a CNC program on the default printer preset is read with CNC
    # G-code meanings, a mismatch with a named machine is a warning; the planner keeps ``machine``
    from .gcode.dialect import apply_note, reading_machine

    read_machine, note, warnings = reading_machine(source, machine)
    reader = GcodeReader(source, read_machine, strict=strict, batch_moves=batch_moves, **extra)
    apply_note(reader, note, warnings)
    return reader, small


class WorkBytes:
    """How far the *work* has got, in input bytes: the bytes up to the line of the last move that every
    sink has handled, for progress bars. The reader reads ahead in chunks of megabytes (and in a second
    thread), so the bytes it has read say little about the work; a MOVE row knows its line, not its byte
    offset, so lines are turned into bytes with the bytes per line of the chunks read before (the first
    chunk: of the lines seen in it so far), never past the bytes read."""

    __slots__ = ("marks", "cur_b", "cur_line", "done_line", "line_bytes", "last")

    def __init__(self, line_bytes: float | None = None):
        self.marks: list[tuple[int, int]] = [(0, 0)]   # (bytes read, last line seen) at each chunk's end
        self.cur_b = 0
        self.cur_line = 0
        self.done_line = 0
        self.line_bytes = line_bytes    # bytes per line in the first chunk, when known (:func:`line_bytes`)
        self.last = 0

    def read(self, bytes_read: int, line: int) -> None:
        """The reader handed over a batch whose last move came from ``line`` after ``bytes_read`` bytes."""
        if bytes_read != self.cur_b:
            if self.cur_line > self.marks[-1][1]:
                self.marks.append((self.cur_b, self.cur_line))
            self.cur_b = bytes_read
        self.cur_line = max(self.cur_line, line)

    def done(self, line: int) -> None:
        """Every sink has handled the moves up to source line ``line``."""
        self.done_line = max(self.done_line, line)

    def bytes_done(self) -> int:
        line = self.done_line
        marks = self.marks
        k = len(marks) - 1
        while k > 0 and marks[k][1] >= line:      # a chunk read before: interpolate inside it
            k -= 1
        b0, l0 = marks[k]
        if k + 1 < len(marks):
            b1, l1 = marks[k + 1]
            return int(b0 + (line - l0) * (b1 - b0) / max(l1 - l0, 1))
        if l0 > 0:
            rate = b0 / l0                         # bytes per line of the chunks before
        elif self.line_bytes:
            rate = self.line_bytes
        else:
            rate = self.cur_b / max(self.cur_line, 1)
        self.last = max(self.last, int(min(self.cur_b, b0 + (line - l0) * rate)))
        return self.last


#: bytes read from the start of a file to guess its bytes per line (:func:`line_bytes`)
LINE_BYTES_PROBE = 1 << 16


def line_bytes(source) -> float | None:
    """Bytes per line of the first :data:`LINE_BYTES_PROBE` bytes of a plain-text regular file (None for
    anything else: streams are read once, compressed files have other bytes): how :class:`WorkBytes` turns
    lines into bytes before the reader's first chunk ends."""
    if _file_size(source) is None:
        return None
    try:
        with open(source, "rb") as f:
            head = f.read(LINE_BYTES_PROBE)
    except (OSError, ValueError):
        return None
    if head[:2] == b"\x1f\x8b" or head[:4] == b"GCDE":
        return None
    lines = head.count(b"\n") or head.count(b"\r")
    return len(head) / lines if lines else None


class Piece:
    """One final stretch of the plan, in program order.

    ``moves`` (MOVE rows) and ``plan`` (PLAN rows) are aligned 1:1; ``first_move`` is the index of
    ``moves[0]`` in the whole program (0-based); ``mode`` is the planning mode ('trapezoid', 'scurve',
    'blend'); ``limits`` the LIMITS table so far (``MOVE.limits`` indexes it: the step stage reads the
    input shaper and pressure advance settings there). ``segments``: the SEGMENT rows (time-ordered, ``SEGMENT.move`` global), made on first
    access — the planner's own pieces for blends and S-curves, which exist only while the sinks are
    being called: read them in ``add``, not later.
    """

    __slots__ = ("moves", "plan", "first_move", "mode", "own_segments", "limits", "_segments", "_make",
                 "firmware_steps")

    def __init__(self, moves: np.ndarray, plan: np.ndarray, first_move: int, mode: str | None = None,
                 segments: np.ndarray | None = None, make_segments=None, own_segments: bool = False,
                 limits: np.ndarray | None = None):
        self.moves = moves
        self.limits = limits               # the LIMITS table so far: every row these moves index
        self.plan = plan
        self.first_move = first_move
        self.mode = mode
        self.own_segments = own_segments   # the mode's own pieces (blends, S-curves), not rebuilt trapezoids
        self._segments = segments
        self._make = make_segments
        # a firmware model's own step pulses of these rows ({axis 0..2: (times s, dirs)}), or None
        self.firmware_steps = None

    @property
    def segments(self) -> np.ndarray:
        if self._segments is None:
            if self._make is None:
                from .planner import to_segments

                self._segments = to_segments(self.moves, self.plan, self.first_move)
            else:
                self._segments = self._make(self.moves, self.plan, self.first_move)
            self._make = None
        return self._segments


class Sink:
    """Receives the plan piece by piece. Subclass and override :meth:`add` (and :meth:`close`).

    ``add`` may return True to say it needs nothing more: when every sink has said so, reading stops
    early (a plot of the first layers does not plan the rest of a 50 MB file).

    ``interpretable``: False for a sink whose kernels do work per step or per sample rather than per move;
    a run with such a sink never runs its kernels as Python, however small the input (gcodeplan/_jit.py).
    """

    interpretable = True

    def add(self, piece: Piece) -> bool | None:  # pragma: no cover - interface
        raise NotImplementedError

    def close(self, result: "RunResult") -> None:
        """Called once after the last piece (not called when the run failed)."""


@dataclass
class RunResult:
    """What a run leaves behind: the reader (``summary``, ``layer_z``, ``features``, ``limits``), the
    policy and planning mode used, the number of MOVE rows planned, and whether it stopped early."""

    reader: object
    machine: object
    policy: str
    mode: str | None
    rows: int
    stopped_early: bool
    name: str


class FunctionSink(Sink):
    """A sink from a function ``fn(piece) -> bool | None``."""

    def __init__(self, fn: Callable[[Piece], bool | None]):
        self._fn = fn

    def add(self, piece: Piece) -> bool | None:
        return self._fn(piece)


class Run:
    """The driver as an iterator: ``for piece in Run(source, machine): ...`` yields the final pieces in
    order; afterwards ``.result`` is the :class:`RunResult`. Leaving the loop early stops reading.
    Arguments as :func:`run`. Read ``piece.segments`` before asking for the next piece."""

    def __init__(self, source, machine, *, policy: str | None = None, jerk: float | None = None,
                 strict: bool = False, progress: Callable[[int], None] | None = None, batch_moves: int = 8192,
                 exclude_objects: Sequence[str] = ()):
        from .planner import StreamPlanner

        self.machine = machine
        self.policy = policy or machine.junction_policy
        self.reader, self.small = open_reader(source, machine, strict=strict, batch_moves=batch_moves)
        if exclude_objects:   # objects cancelled as Klipper's exclude_object runs them (gcode/objects.py)
            self.reader.interp.exclude_objects(exclude_objects)
        self.planner = StreamPlanner(machine, policy=self.policy, jerk=jerk)
        self.planner.e_position_sets = self.reader.interp.e_position_sets   # G92 E, for firmware models
        if self.planner.firmware != "generic":
            self.policy = self.planner.firmware       # the summary names the firmware model that planned
        self.progress = progress
        self.rows = 0
        self.finished = False
        self.threaded = not self.small and read_ahead_input(source)
        self._limits = None
        self._work = WorkBytes(line_bytes(source) if progress is not None else None)

    def _pieces(self, pairs: Iterable[tuple[np.ndarray, np.ndarray]]):
        for moves, plan in pairs:
            piece = Piece(moves, plan, self.rows, self.planner.mode, make_segments=self.planner.segments_for,
                          own_segments=self.planner.own_segments, limits=self._limits)
            piece.firmware_steps = self.planner.firmware_steps()
            self.rows += len(moves)
            yield piece
            if len(moves):          # resumed: every sink has handled this piece
                self._work.done(int(moves["line"][-1]))
                if self.progress is not None:
                    self.progress(self._work.bytes_done())

    def _batches(self):
        """(MOVE batch, LIMITS so far, bytes read so far) from the reader, in a second thread for big files."""
        reader = self.reader
        if self.threaded:
            yield from read_ahead(reader)
            return
        for moves in reader.batches():
            yield moves, reader.limits, reader.bytes_read

    def __iter__(self):
        reader, planner = self.reader, self.planner
        with located(reader.path), _jit.interpreted(self.small):
            for moves, limits, bytes_read in self._batches():
                self._limits = limits
                if len(moves):
                    self._work.read(bytes_read, int(moves["line"][-1]))
                # the pieces are the sinks' work: they have done it when the generator resumes in _pieces
                yield from self._pieces(planner.feed(moves, limits))
            self._limits = reader.limits
            yield from self._pieces(planner.finish())
            reader.interp.check_excluded()
            if self.progress is not None:       # all done: all that was read
                self.progress(max(self._work.last, reader.bytes_read))
        self.finished = True

    @property
    def result(self) -> RunResult:
        return RunResult(self.reader, self.machine, self.policy, self.planner.mode, self.rows, not self.finished,
                         self.reader.path)


def run(source, machine, *, policy: str | None = None, jerk: float | None = None, strict: bool = False,
        sinks: Sequence[Sink] = (), progress: Callable[[int], None] | None = None,
        batch_moves: int = 8192, exclude_objects: Sequence[str] = ()) -> RunResult:
    """Parse and plan ``source`` for ``machine``, handing every final piece to ``sinks``.

    ``policy``: junction policy name (None = the machine's); ``jerk``: mm/s³ for S-curves (None =
    trapezoids unless the machine sets max_jerk); ``strict``: unknown commands are errors;
    ``progress(bytes_done)`` after every piece the sinks have handled, with the input bytes whose moves are
    done (:class:`WorkBytes`: the work's progress, not the reading's); ``exclude_objects``: names of objects cancelled
    (Klipper's exclude_object; a name the file never labels is an error); ``batch_moves``: MOVE rows per
    reader batch. Errors name the file and line (:class:`gcodeplan.errors.GcodeplanError`). Reading stops
    early once every sink said it is done.
    """
    sinks = list(sinks)
    done = [False] * len(sinks)
    drive = Run(source, machine, policy=policy, jerk=jerk, strict=strict, progress=progress,
                batch_moves=batch_moves, exclude_objects=exclude_objects)
    drive.small = drive.small and all(getattr(s, "interpretable", True) for s in sinks)
    drive.planner.want_firmware_steps = any(getattr(s, "wants_firmware_steps", False) for s in sinks)
    pieces = iter(drive)
    with _jit.interpreted(drive.small):
        try:
            with located(drive.reader.path):     # a sink's error (e.g. an absurd total) names the file too
                for piece in pieces:
                    for k, sink in enumerate(sinks):
                        if not done[k] and sink.add(piece):
                            done[k] = True
                    if sinks and all(done):
                        break
        finally:
            pieces.close()
        result = drive.result
        for sink in sinks:
            sink.close(result)
    return result


class Collect(Sink):
    """Keeps every piece: the whole plan in memory (for small programs, tests and notebooks)."""

    def __init__(self, segments: bool = True):
        self.keep_segments = segments
        self.pieces: list[Piece] = []

    def add(self, piece: Piece) -> None:
        if self.keep_segments:
            piece.segments   # made now: blend / S-curve pieces are gone after this call
        self.pieces.append(piece)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """(MOVE rows, PLAN rows, SEGMENT rows or None), concatenated."""
        from .schema import MOVE_DTYPE, PLAN_DTYPE, SEGMENT_DTYPE

        if not self.pieces:
            empty_s = np.zeros(0, SEGMENT_DTYPE) if self.keep_segments else None
            return np.zeros(0, MOVE_DTYPE), np.zeros(0, PLAN_DTYPE), empty_s
        moves = np.concatenate([p.moves for p in self.pieces])
        plan = np.concatenate([p.plan for p in self.pieces])
        segs = np.concatenate([p.segments for p in self.pieces]) if self.keep_segments else None
        return moves, plan, segs


class LineTimes(Sink):
    """End time of the last move (or dwell) each source line made: Klipper's per-line CSV.

    ``arrays()`` → (line int64, end_time_s float64), lines increasing, one row per line that made a
    move or dwell (waits such as M109 or G28 make no row, as in Klipper's reference files).
    """

    def __init__(self):
        self._lines: list[np.ndarray] = []
        self._ends: list[np.ndarray] = []

    def add(self, piece: Piece) -> None:
        from .schema import KIND_WAIT

        m, p = piece.moves, piece.plan
        keep = (m["kind"] != KIND_WAIT) & ((p["duration"] > 0) | (m["move_d"] > 0))
        if not np.any(keep):
            return
        line = m["line"][keep]
        end = (p["t_start"] + p["duration"])[keep]
        last = np.r_[line[1:] != line[:-1], True]
        self._lines.append(line[last].astype(np.int64))
        self._ends.append(end[last])

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        if not self._lines:
            return np.zeros(0, np.int64), np.zeros(0, np.float64)
        line = np.concatenate(self._lines)
        end = np.concatenate(self._ends)
        if line.size > 1 and np.any(line[1:] < line[:-1]):
            # lines run more than once (RS274NGC subroutines and loops, gcode/ngc.py): each line's last end
            order = np.lexsort((end, line))
            line, end = line[order], end[order]
        # a line whose moves straddle two pieces appears twice: keep its last end
        last = np.r_[line[1:] != line[:-1], True]
        return line[last], end[last]


__all__ = ["run", "Run", "Sink", "Piece", "RunResult", "FunctionSink", "Collect", "LineTimes", "open_reader",
           "small_input"]
