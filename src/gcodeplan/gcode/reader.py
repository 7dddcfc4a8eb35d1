"""Streaming G-code reader: source -> MOVE batches, LIMITS table, layer Z, feature names, summary.

The source (a path, ``-`` for stdin, a file object or an iterable of lines; gzip and PrusaSlicer binary
G-code recognised by their first bytes: :mod:`.sources`) is read in binary chunks cut at the last
newline; the numba scanner interprets the common lines and returns to :class:`~.interp.Interpreter` for
the rest, one line at a time. Memory is bounded by the chunk size and the batch size, whatever the file
size.

A line ends at LF, CRLF or a lone CR (old Mac files), as Marlin's and RepRapFirmware's line readers and
the slicers have it (:func:`.sources.cr_line_ends`). A line may be at most :data:`MAX_LINE_BYTES` (1 MiB)
long: interpreting a line costs up to ~85 times its length in Python objects, and a line without end on a
pipe would otherwise grow the buffer until memory runs out; a longer line is a :class:`GcodeError` naming
it. Real G-code lines are far shorter (a slicer's longest, a thumbnail or an object polygon, is a few kB).
"""
from __future__ import annotations

import math
from time import perf_counter

import numpy as np

from ..errors import GcodeError
from ..machine import Machine
from ..schema import KIND_NAMES, MOVE_DTYPE, rows_with_headroom
from . import scan as S
from .interp import Interpreter
from .sources import cr_line_ends, open_source
from .summary import ParseSummary

CHUNK_BYTES = 8 << 20
MAX_LINE_BYTES = 1 << 20     # longest line read (bytes, its line end excluded): see the module docstring
_BOM = b"\xef\xbb\xbf"
_LAYER_MARKS = (b"\n;LAYER_CHANGE", b"\n;LAYER:", b"\n; layer ")


def _long_line(buf, lo: int, hi: int) -> tuple[int, int]:
    """(start, length) of the first line of ``buf[lo:hi]`` (lines start at ``lo``) longer than
    :data:`MAX_LINE_BYTES`, or (-1, 0). A line that long holds a whole window of half that size starting on
    the grid stepped here, so a few searches per chunk find it: windows with a newline end at once."""
    w = MAX_LINE_BYTES // 2
    p = lo
    while p + w <= hi:
        if buf.find(b"\n", p, p + w) >= 0:
            p += w
            continue
        s = buf.rfind(b"\n", lo, p)
        s = lo if s < 0 else s + 1
        e = buf.find(b"\n", p + w, hi)
        e = hi if e < 0 else e
        n = e - s - (1 if e > s and buf[e - 1] == S.BYTE_CR else 0)     # a CRLF's CR is line end, not line
        if n > MAX_LINE_BYTES:
            return s, n
        p = e + 1
    return -1, 0


def _too_long(path: str, line: int, length: int | None) -> GcodeError:
    size = f"{length} bytes" if length is not None else "more than 1 MiB"
    return GcodeError(f"line too long ({size}; gcodeplan reads lines of at most {MAX_LINE_BYTES} bytes, "
                      f"far above any real G-code line): is this a G-code file?", path, line)


def _check_text(path: str, head: bytes, first_line: int = 0) -> None:
    """A binary file is refused before any line is interpreted (``first_line``: lines before ``head``)."""
    sample = head[:65536]
    if not sample:
        return
    nul = sample.find(b"\x00")
    if nul >= 0:
        raise GcodeError("not a text file (NUL byte): is this a binary file?", path,
                         first_line + sample.count(b"\n", 0, nul) + 1)
    ctrl = sum(sample.count(bytes([c])) for c in range(32) if c not in (9, 10, 11, 12, 13)) + sample.count(b"\x7f")
    if ctrl > 0.02 * len(sample):
        raise GcodeError("not a text file (control characters): is this a binary file?", path)
    text = sample.decode("utf-8", "replace")
    if text.count("\ufffd") > 0.3 * len(text):
        raise GcodeError("not a text file (mostly non-text bytes)", path)


class GcodeReader:
    """Read G-code from ``source`` as MOVE batches (see the package docstring for the API contract).

    ``source``: a path (``-`` = standard input), a binary or text file object, or an iterable of lines;
    gzip and binary G-code are recognised by their first bytes (:func:`.sources.open_source`). Messages
    name :attr:`path`, the source's display name (the path, ``<stdin>``, ``<lines>``). The source is
    opened here (a missing file or a corrupt binary G-code header fails at once) and closed when
    :meth:`batches` ends or :meth:`close` is called; a file object given by the caller is never closed.
    ``bytes_read`` counts input bytes (compressed ones for gzip / binary G-code), ``bytes_total`` is
    the input size when known: progress is ``bytes_read / bytes_total``.

    ``force_python`` sends every line through the Python interpreter (slow; the tests compare it with
    the scanner). ``chunk_bytes`` is the read size. Layers: when the first chunk holds a layer comment
    (``;LAYER_CHANGE``, ``;LAYER:``, ``; layer``) layers follow the comments only; otherwise a printing
    move above every earlier printing move's Z starts a layer, until a layer comment appears.
    """

    def __init__(self, source, machine: Machine, *, strict: bool = False, batch_moves: int = 8192,
                 force_python: bool = False, chunk_bytes: int = CHUNK_BYTES):
        if batch_moves < 1:
            raise ValueError("batch_moves must be >= 1")
        self.machine = machine
        self.strict = strict
        self.batch_moves = int(batch_moves)
        self.bytes_read = 0          # for progress bars: input bytes read so far
        self.python_s = 0.0          # s spent on lines the scanner hands to Python (arcs, cycles, rare commands)
        self.force_python = force_python
        self.chunk_bytes = int(chunk_bytes)
        self.source = open_source(source)
        self.path = self.source.name
        self.bytes_total = self.source.bytes_total
        self.bytes_read = self.source.bytes_in
        self.interp = Interpreter(machine, self.path, strict)
        # binary G-code: line numbers continue those of the metadata libbgcode's converter writes first,
        # and the slicer's estimate comes from the metadata block (ASCII files state it in a comment)
        self.interp.ist[S.I_LINE] = self.source.first_line
        if self.source.slicer_estimate_s is not None:
            self.interp.slicer_estimate_s = self.source.slicer_estimate_s
        self.summary = ParseSummary(file=self.path)
        self._acc = np.zeros(S.N_ACC)
        for i in (S.A_MIN_X, S.A_MIN_Y, S.A_MIN_Z):
            self._acc[i] = math.inf
        for i in (S.A_MAX_X, S.A_MAX_Y, S.A_MAX_Z):
            self._acc[i] = -math.inf
        rv = machine.rapid_velocity if machine.rapid_velocity is not None else machine.max_velocity
        self._rapid_v = float(rv)
        self._started = False

    def close(self) -> None:
        """Close the source if this reader opened it (idempotent)."""
        self.source.close()

    def __del__(self):
        src = getattr(self, "source", None)
        if src is not None:
            src.close()

    # ------------------------------------------------------------------ public state
    @property
    def limits(self) -> np.ndarray:
        return self.interp.limits

    @property
    def layer_z(self) -> list[float]:
        return self.interp.layer_z

    @property
    def features(self) -> list[str]:
        return self.interp.features

    # ------------------------------------------------------------------ streaming
    def _chunks(self):
        """(buffer, start, end): the source piece by piece in one reused bytearray, each piece ending at a
        newline (the last one may not). A line longer than the buffer makes it grow. Each read fills
        the buffer (or reaches the end), so pipes, gzip and binary G-code give the chunks a file gives."""
        src = self.source
        fh = src.stream
        # the source stays open until batches() closes it, after a last check_rest()
        store = bytearray(self.chunk_bytes)
        filled = 0
        start = 0
        first = True
        while True:
            if filled == len(store):
                # the buffer holds one unfinished line (every earlier one was handed out): bound it
                if filled - start > MAX_LINE_BYTES:
                    raise _too_long(self.path, int(self.interp.ist[S.I_LINE]) + 1, None)
                bigger = bytearray(2 * len(store))
                bigger[:filled] = store
                store = bigger
            got = 0
            try:
                with memoryview(store) as mv:
                    while filled + got < len(store):
                        k = fh.readinto(mv[filled + got:])
                        if not k:
                            break
                        got += k
            except OSError as err:
                raise GcodeError(f"cannot read: {err.strerror or err}", self.path) from None
            self.bytes_read = src.bytes_in
            # CR-only line ends become LF (the CR of a CRLF stays): one line end each, as firmware reads them;
            # a CR left by the last read may have been waiting for its LF
            cr_line_ends(store, max(start, filled - 1), filled + got, got == 0)
            if first:
                first = False
                if store.startswith(_BOM):
                    start = 3
                _check_text(self.path, bytes(store[start:min(got, start + 65536)]), src.first_line)
                if store.startswith((b";LAYER_CHANGE", b";LAYER:", b"; layer "), start) or \
                        any(store.find(m, start, got) >= 0 for m in _LAYER_MARKS):
                    self.interp.ist[S.I_LAYER_BY_Z] = 0
            filled += got
            if got == 0:
                if filled > start:
                    yield from self._checked(store, start, filled)
                return
            cut = store.rfind(b"\n", start, filled)
            if cut < 0:
                continue
            yield from self._checked(store, start, cut + 1)
            rest = filled - (cut + 1)
            store[0:rest] = store[cut + 1:filled]
            filled = rest
            start = 0

    def _checked(self, store, start: int, end: int):
        """``(store, start, end)``, or the lines before the first one too long and then its error (after
        those lines were interpreted, so that the line count and any earlier error are right)."""
        bad, length = _long_line(store, start, end)
        if bad < 0:
            yield store, start, end
            return
        if bad > start:
            yield store, start, bad
        raise _too_long(self.path, int(self.interp.ist[S.I_LINE]) + 1, length)

    def batches(self):
        """MOVE arrays in file order, each at most ``batch_moves`` rows."""
        if self._started:
            raise RuntimeError("GcodeReader.batches() can run once")
        self._started = True
        self._out = rows_with_headroom(self.batch_moves, MOVE_DTYPE)   # batches() hands each buffer out once
        self._n = 0
        try:
            for data, pos, end in self._chunks():
                yield from self._scan(data, pos, end)
            if self.interp.ngc is not None:
                self.interp.ngc.end()    # an O-word block left open (gcode/ngc.py)
        except GcodeError:
            self.source.check_unchanged()   # a file rewritten while read explains a broken line best
            self.source.check_rest()   # a corrupt gzip member explains a garbage line better than the line does
            raise
        finally:
            self.source.close()
        if self._n:
            yield self._finish(self._out, self._n)
        self._complete_summary()

    # ------------------------------------------------------------------ push mode (gcodeplan.Toolhead)
    def feed(self, data: bytes) -> list[np.ndarray]:
        """Push mode: interpret ``data`` (whole lines; a last line without a newline waits for the next
        call or :meth:`end`) and return the MOVE rows it made. Same scanner and interpreter, so the rows
        equal those :meth:`batches` makes from the same text."""
        if self._started and not hasattr(self, "_tail"):
            raise RuntimeError("GcodeReader.feed() cannot follow batches()")
        if not self._started:
            self._started = True
            self._tail = b""
            self._out = np.empty(self.batch_moves, dtype=MOVE_DTYPE)
            self._n = 0
        data = bytearray(self._tail + bytes(data))
        cr_line_ends(data, 0, len(data), False)      # a last CR waits in the tail for a possible LF
        cut = data.rfind(b"\n") + 1
        bad, length = _long_line(data, 0, cut)
        if bad >= 0 or len(data) - cut > MAX_LINE_BYTES:
            line = int(self.interp.ist[S.I_LINE]) + 1 + (data.count(b"\n", 0, bad) if bad >= 0 else
                                                         data.count(b"\n"))
            raise _too_long(self.path, line, length if bad >= 0 else None)
        self._tail = bytes(data[cut:])
        out = list(self._scan(data, 0, cut)) if cut else []
        if self._n:
            out.append(self._finish(self._out[:self._n].copy(), self._n))
            self._n = 0
        return out

    def end(self) -> list[np.ndarray]:
        """Push mode: interpret a pending last line and complete the summary."""
        out = []
        if getattr(self, "_tail", b""):
            tail, self._tail = self._tail, b""
            out = self.feed(tail + b"\n")
        if self.interp.ngc is not None:
            self.interp.ngc.end()
        self._complete_summary()
        return out

    def _scan(self, data, pos: int, end: int):
        """Interpret ``data[pos:end]`` (whole lines), yielding every full batch; rows of a batch not yet
        full stay in ``self._out[:self._n]``."""
        interp = self.interp
        st, ist = interp.st, interp.ist
        cap = self.batch_moves
        out, n = self._out, self._n
        buf = np.frombuffer(data, dtype=np.uint8)
        cnc = interp.dialect == S.DIALECT_CNC
        # G92 E lines the scanner interprets: handed on to interp.e_position_sets in file order (firmware models)
        eset_line = np.empty(S.ESET_MAX, np.int64)
        eset_v = np.empty(S.ESET_MAX)
        eset_n = np.zeros(1, np.int64)
        keep_e_sets = interp.keeps_e_sets
        while True:
            if ist[S.I_STOPPED]:
                ist[S.I_LINE] += S.count_lines(buf, pos, end)
                break
            if self.force_python:
                status = S.ST_PYTHON
                if pos >= end:
                    break
            else:
                status, pos, n = S.scan_chunk(buf, pos, end, st, ist, out, n, interp.feat_raw,
                                              interp.feat_len, interp.feat_idx, eset_line, eset_v, eset_n)
                if eset_n[0]:
                    k = int(eset_n[0])
                    if cnc:      # grbl lines the scanner rejected (scan.I_GRBL_INERT): warned in file order
                        interp.grbl_rejected_lines(eset_line[:k], eset_v[:k])
                    elif keep_e_sets:
                        interp.e_position_sets.extend(zip(eset_line[:k].tolist(), eset_v[:k].tolist()))
                    eset_n[0] = 0
                if status == S.ST_DONE:
                    break
                if status == S.ST_FULL:
                    yield self._finish(out, n)
                    out = self._out = rows_with_headroom(cap, MOVE_DTYPE)
                    n = 0
                    continue
            # one line through Python
            eol = data.find(b"\n", pos, end)
            if eol < 0:
                eol = end
            lineno = int(ist[S.I_LINE]) + 1
            t0 = perf_counter()
            raw = bytes(data[pos:eol])
            if not (cnc and interp.grbl_inert_line(raw, lineno)):    # a grbl line that does nothing: at once
                interp.handle(raw, lineno)
            self.python_s += perf_counter() - t0
            ist[S.I_LINE] = lineno
            pos = eol + 1
            for arr in interp.take_rows():
                k0 = 0
                while k0 < len(arr):
                    k = min(cap - n, len(arr) - k0)
                    out[n:n + k] = arr[k0:k0 + k]
                    n += k
                    k0 += k
                    if n == cap:
                        yield self._finish(out, n)
                        out = self._out = rows_with_headroom(cap, MOVE_DTYPE)
                        n = 0
        self._n = n
        del buf

    def _finish(self, out: np.ndarray, n: int) -> np.ndarray:
        batch = out[:n] if n < len(out) else out
        S.summarise_rows(batch, self._acc, self._rapid_v)
        self._check_extrusion(batch)
        self._check_motion(batch)
        return batch

    def _check_motion(self, batch: np.ndarray) -> None:
        """Travel limits, absurd move lengths, bounding boxes, speed caps (gcode/bounds.py)."""
        from .bounds import MotionChecker

        checker = self.__dict__.get("_motion")
        if checker is None:
            self._load_reach_check()
            checker = self._motion = MotionChecker(self.machine, self.path)
        checker.check(batch, self.interp._limits_rows)
        checker.fill(self.summary)

    def _load_reach_check(self) -> None:
        """Import the machine's kinematics module: one whose reach is not a box (delta: print radius, tower
        heights) registers its own test with bounds.register_reach_check, which the checker then runs."""
        from ..kinematics import KINEMATICS_MODULES, kinematics_module

        if self.machine.kinematics in KINEMATICS_MODULES:
            kinematics_module(self.machine.kinematics)

    def _check_extrusion(self, batch: np.ndarray) -> None:
        """Klipper's extruder.check_move: a move with X/Y motion that extrudes more filament per mm of
        path than max_extrude_ratio (from max_extrude_cross_section) stops the print with an error,
        unless the amount is tiny (≤ nozzle_diameter·max_extrude_ratio). Klipper would not run such a
        file, so neither do we estimate it."""
        ratio_max = self.machine.max_extrude_ratio
        if not np.isfinite(ratio_max) or batch.size == 0:
            return
        de = batch["e1"] - batch["e0"]
        # the rare rows above the tiny amount first: the other tests run on those alone (this runs per batch)
        rows = np.flatnonzero(de > self.machine.nozzle_diameter * ratio_max)
        if rows.size == 0:
            return
        cand = batch[rows]
        xy = (cand["x1"] != cand["x0"]) | (cand["y1"] != cand["y0"])
        bad = xy & (de[rows] > ratio_max * cand["move_d"])
        if np.any(bad):
            i = int(rows[np.argmax(bad)])
            area = de[i] / batch["move_d"][i] * np.pi * (self.machine.filament_diameter / 2) ** 2
            limit = ratio_max * np.pi * (self.machine.filament_diameter / 2) ** 2
            raise GcodeError(f"move exceeds maximum extrusion ({area:.3f} mm² vs {limit:.3f} mm²): Klipper stops "
                             f"the print here; raise [extruder] max_extrude_cross_section if this is intended",
                             self.path, int(batch["line"][i]))

    def _complete_summary(self) -> None:
        s, a, it = self.summary, self._acc, self.interp
        s.lines = int(it.ist[S.I_LINE]) + self.source.trailing_lines
        by_kind = {name: int(a[i]) for i, name in enumerate(KIND_NAMES)}
        s.moves_by_kind = by_kind
        s.moves = by_kind["travel"] + by_kind["print"] + by_kind["extrude_only"]
        s.rows = sum(by_kind.values())
        s.layer_count = len(it.layer_z)
        s.header_layer_count = it.header_layer_count
        s.travel_mm = float(a[S.A_TRAVEL_MM])
        s.print_mm = float(a[S.A_PRINT_MM])
        s.filament_mm = float(a[S.A_FILAMENT_MM])
        s.retracts = int(a[S.A_RETRACTS])
        s.naive_time_s = float(a[S.A_NAIVE_T])
        s.dwell_s = float(a[S.A_DWELL_T])
        s.wait_s = float(a[S.A_WAIT_T])
        s.waits = dict(it.waits)
        s.arcs = it.arcs
        s.arc_chords = int(a[S.A_ARC_CHORDS])
        s.canned_cycles = it.canned_cycles
        s.spindle_commands = it.spindle_commands + int(it.ist[S.I_S_WORDS])     # (S words the scanner took)
        s.tool_changes = it.tool_changes
        s.unknown_commands = dict(it.unknown)
        ignored = dict(it.ignored)
        m204 = int(it.ist[S.I_M204_IGNORED])
        if m204:
            ignored["M204 without S or P+T"] = m204
        if it.g64_q_ignored:
            ignored["G64 Q"] = it.g64_q_ignored
        s.ignored_commands = ignored
        s.skipped_lines = it.skipped_lines
        s.soft_clamped_moves = it.soft_clamped
        s.soft_clamped_first_line = it.soft_clamped_first_line
        s.events = list(it.events)
        s.warnings = list(it.warnings)
        s.warning_count = it.warning_count
        s.slicer_estimate_s = it.slicer_estimate_s
        s.features = list(it.features)
        s.limits_rows = len(it._limits_rows)
        if math.isfinite(a[S.A_MIN_X]):
            s.bounds_mm = {k: [float(a[lo]), float(a[hi])] for k, lo, hi in
                           (("x", S.A_MIN_X, S.A_MAX_X), ("y", S.A_MIN_Y, S.A_MAX_Y), ("z", S.A_MIN_Z, S.A_MAX_Z))}


def read_moves(source, machine: Machine, **kw) -> tuple[np.ndarray, GcodeReader]:
    """The whole source's MOVE rows as one array, and the reader (for limits, layers, summary).
    ``source``: as for :class:`GcodeReader`."""
    r = GcodeReader(source, machine, **kw)
    parts = list(r.batches())
    moves = np.concatenate(parts) if parts else np.empty(0, dtype=MOVE_DTYPE)
    return moves, r


__all__ = ["GcodeReader", "read_moves", "ParseSummary", "CHUNK_BYTES"]
