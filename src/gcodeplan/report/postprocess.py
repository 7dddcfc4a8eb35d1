"""Rewrite a G-code file with gcodeplan's times, as a slicer post-processing step.

:func:`post_process` reads the file twice, never whole: pass 1 plans it (the streaming pipeline, with a
sink that keeps, per source line, the end time of the last row it made — moves, dwells and modelled
waits — and the first line of every layer); pass 2 copies it line by line into a temporary file beside
the target, which then replaces the target in one rename (:func:`gcodeplan.report.output.atomic_output`:
permissions kept, the original untouched on any error or interruption). Pass 2 reads the very file pass 1
planned (same inode, size and modification time, checked again at its end: :mod:`gcodeplan.gcode.sources`);
a file changed in between is an error and nothing is written. An input that cannot be read twice
(standard input, a FIFO, ``<(…)``) is copied once to a temporary file first; it needs ``out``.
Lines end at LF, CRLF or a lone CR, as the reader counts them.

What changes (everything else is copied byte for byte, line endings included):

* ``M73 P<percent> R<minutes>`` lines are inserted (PrusaSlicer's convention, read by Marlin, Prusa
  firmware and Klipper's ``display_status``): ``P0 R<total>`` before the first line that takes time,
  one before the first line of every layer and wherever 60 s of planned time have passed since the
  previous one, and ``M73 P100 R0`` after the last line that takes time. The time of an inserted line is
  the end of the last line before it that takes time; ``P`` = ⌊100·t/total⌋, ``R`` = ⌈(total − t)/60⌉.
  Every existing ``M73`` line (the slicer's, or an earlier run's) is dropped. ``m73=False`` leaves M73
  lines alone and inserts none.
* ``layer_info=True`` also inserts Klipper's ``SET_PRINT_STATS_INFO TOTAL_LAYER=<n>`` (with the first
  M73) and ``SET_PRINT_STATS_INFO CURRENT_LAYER=<k>`` (1-based, before each layer's first line), and
  drops the existing ``SET_PRINT_STATS_INFO`` lines.
* The slicer's own time lines get gcodeplan's figure, in the slicer's format (:data:`TIME_LINES`).
  PrusaSlicer's *silent mode* lines (``; estimated printing time (silent mode) = …`` and its first-layer
  line) are dropped: they are the slicer's figures for the printer's second set of limits (Prusa's
  stealth mode), which gcodeplan does not plan, and they would stand beside gcodeplan's normal-mode
  figure as if it were one plan (their ``M73 Q… S…`` progress lines go with every other M73 line).
* One ``; gcodeplan <version>: <total> (<machine>, <policy>)`` line is appended (an earlier one dropped).

A CNC program (the file read with the ``grbl`` or ``linuxcnc`` flavor — the machine's, or the one
:mod:`gcodeplan.gcode.dialect` detects on the default preset — or a file whose name or CAM header says it is
one, whatever machine plans it) gets no printer command at all: grbl stops
with ``error:20`` on M73 and LinuxCNC's M73 saves the modal state. Its M73 lines are left alone, none is
inserted (``layer_info`` is refused: SET_PRINT_STATS_INFO is Klipper's), and the one line appended is the
comment ``(gcodeplan <version>: <total>, machine <name>, policy <policy>)``.

So a second run with the same options gives the same bytes as the first.
"""
from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field

import numpy as np

from ..errors import GcodeError, GcodeplanError
from ..pipeline import Piece, Sink

MINUTE_S = 60.0     # the longest planned time between two inserted M73 lines (s)

_M73_RE = re.compile(rb"[ \t]*[Mm]0*73(?![0-9.])")
_STATS_RE = re.compile(rb"[ \t]*SET_PRINT_STATS_INFO(?![A-Za-z0-9_])", re.I)
_OURS_RE = re.compile(rb"; gcodeplan \S+: |\(gcodeplan \S+: ")
# PrusaSlicer's stealth-mode figures: not gcodeplan's plan, dropped with their M73 Q/S lines (module docstring)
_SILENT_RE = re.compile(rb"; estimated (first layer )?printing time \(silent mode\) = ")
_ORCA_RE = re.compile(rb"(model printing time: |total estimated time: )[^;\r\n]*")

# The slicer time lines rewritten, each with what it holds. Formats as each slicer writes them
# (PrusaSlicer's GCodeProcessor and OrcaSlicer/BambuStudio's header, CuraEngine, ideaMaker) and as
# Moonraker's metadata.py and klipper_estimator's post-process read them.
TIME_LINES = (
    ("; estimated printing time (normal mode) = ", "total, as 1d 2h 3m 4s (PrusaSlicer, SuperSlicer, OrcaSlicer)"),
    ("; estimated first layer printing time (normal mode) = ", "the first layer's time, same format"),
    ("; model printing time: …; total estimated time: …", "both values, total (OrcaSlicer, BambuStudio header)"),
    (";TIME:", "total, whole seconds (Cura)"),
    (";PRINT.TIME:", "total, whole seconds (Cura, Griffin header)"),
    (";TIME_ELAPSED:", "elapsed time at that line, s with 6 decimals (Cura, each layer)"),
    (";Print Time: ", "total, whole seconds (ideaMaker)"),
    (";PRINTING_TIME: ", "elapsed at that line, whole seconds (ideaMaker, each layer)"),
    (";REMAINING_TIME: ", "remaining at that line, whole seconds (ideaMaker, each layer)"),
)


def dhms(seconds: float) -> str:
    """Seconds as PrusaSlicer writes a duration: ``1d 2h 3m 4s``, leading zero units left out, whole
    seconds (rounded)."""
    s = max(0, int(round(seconds)))
    d, s = divmod(s, 86400)
    h, s = divmod(s, 3600)
    m, s = divmod(s, 60)
    if d:
        return f"{d}d {h}h {m}m {s}s"
    if h:
        return f"{h}h {m}m {s}s"
    if m:
        return f"{m}m {s}s"
    return f"{s}s"


def m73_values(t: float, total: float) -> tuple[int, int]:
    """(P, R) of an M73 line at planned time ``t`` (s) of ``total`` (s): percent of planned time
    rounded down, minutes remaining rounded up."""
    if total <= 0.0:
        return 0, 0
    p = int(math.floor(100.0 * t / total))
    r = int(math.ceil(max(total - t, 0.0) / MINUTE_S))
    return min(max(p, 0), 100), r


class ProgressSink(Sink):
    """Pass 1: per source line, the end (s) of the last row it made (any kind: moves, dwells, waits), the
    first line of every layer, the first layer's time and the total. Memory: 16 bytes per line that
    makes a row."""

    def __init__(self):
        self._lines: list[np.ndarray] = []
        self._ends: list[np.ndarray] = []
        self.layer_starts: list[tuple[int, int]] = []    # (line, layer index), in order
        self._layer = -1
        self.first_layer_s = 0.0
        self.total_s = 0.0

    def add(self, piece: Piece) -> None:
        m, p = piece.moves, piece.plan
        if len(m) == 0:
            return
        end = p["t_start"] + p["duration"]
        line = m["line"]
        last = np.r_[line[1:] != line[:-1], True]
        self._lines.append(line[last].astype(np.int64))
        self._ends.append(end[last])
        self.total_s = max(self.total_s, float(end.max()))
        lay = m["layer"]
        prev = np.r_[self._layer, lay[:-1]]
        for i in np.flatnonzero((lay != prev) & (lay >= 0)):
            self.layer_starts.append((int(line[i]), int(lay[i])))
        self._layer = int(lay[-1])
        self.first_layer_s += float(p["duration"][lay == 0].sum())

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """(line int64, end s float64), lines increasing, one row per line that made a row."""
        if not self._lines:
            return np.zeros(0, np.int64), np.zeros(0)
        line = np.concatenate(self._lines)
        end = np.concatenate(self._ends)
        last = np.r_[line[1:] != line[:-1], True]      # a line cut between two pieces: its last end
        return line[last], end[last]


@dataclass
class PostProcessResult:
    """What :func:`post_process` did: the planned total (s), the file written, counts of lines inserted,
    dropped and rewritten, and the M73 lines as (line number in the output, P, R)."""

    path: str
    total_time_s: float
    machine: str
    policy: str
    inserted: int = 0
    dropped: int = 0
    rewritten: int = 0
    m73: list = field(default_factory=list)
    cnc_flavor: str | None = None      # 'grbl' / 'linuxcnc' when the file was a CNC program (no M73 written)

    def counts_text(self) -> str:
        """What was done, for the one summary line: ``12 M73 lines, 1 slicer time line rewritten``."""
        def n(k: int, what: str) -> str:
            return f"{k} {what}{'' if k == 1 else 's'}"

        text = f"{n(len(self.m73), 'M73 line')}, {n(self.rewritten, 'slicer time line')} rewritten"
        if self.cnc_flavor:
            text += f" (a {self.cnc_flavor} program: no printer commands written, only a comment)"
        return text


def _refuse_unsupported(path, in_place: bool) -> None:
    """``path``: a regular file or a spool (:func:`gcodeplan.gcode.sources.spooled`), read here for 4 bytes."""
    from ..gcode.sources import SpooledPath, rereadable, source_name

    name = source_name(path)
    if in_place and (not rereadable(path) or isinstance(path, SpooledPath)):
        what = "standard input is not a file" if name == "<stdin>" else f"{name} is not a regular file"
        raise GcodeplanError(f"post-process rewrites a G-code file in place, and {what}: give -o OUT to write "
                             "the result elsewhere")
    try:
        with open(path, "rb") as fh:
            head = fh.read(4)
    except IsADirectoryError:
        raise GcodeError("is a directory, not a G-code file", name) from None
    except FileNotFoundError:
        raise GcodeError("no such file", name) from None
    except OSError as err:
        raise GcodeError(f"cannot read: {err.strerror or err}", name) from None
    if head == b"GCDE":
        raise GcodeError("binary G-code (.bgcode) cannot be post-processed: turn binary G-code off in the "
                         "slicer (PrusaSlicer: Printer Settings > General > Firmware > Supports binary G-code) "
                         "or convert it to text first", name)
    if head[:2] == b"\x1f\x8b":
        raise GcodeError("gzip-compressed G-code cannot be post-processed in place: decompress it first", name)


def _schedule(lines: np.ndarray, ends: np.ndarray, layer_starts: list[tuple[int, int]], total: float,
              n_layers: int, m73: bool, layer_info: bool) -> tuple[list[int], dict[int, list[str]]]:
    """Where the inserted lines go: {source line they go before: [texts]} and the sorted keys."""
    out: dict[int, list[str]] = {}
    if len(lines) == 0 or not (m73 or layer_info):
        return [], out
    # t[i]: planned time when line lines[i] starts = end of the line before it that takes time
    t = np.r_[0.0, ends[:-1]]
    layer_at = {ln: k for ln, k in layer_starts}
    layer_idx = np.searchsorted(lines, np.array(sorted(layer_at), dtype=np.int64))
    layer_idx = [int(i) for i in layer_idx if i < len(lines)]

    def put(i: int) -> None:
        texts = out.setdefault(int(lines[i]), [])
        if m73:
            p, r = m73_values(float(t[i]), total)
            texts.append(f"M73 P{p} R{r}")
        k = layer_at.get(int(lines[i]))
        if layer_info and k is not None:
            texts.append(f"SET_PRINT_STATS_INFO CURRENT_LAYER={k + 1}")

    first = out.setdefault(int(lines[0]), [])
    if layer_info:
        first.append(f"SET_PRINT_STATS_INFO TOTAL_LAYER={n_layers}")
    put(0)
    i, t_last, li = 0, 0.0, 0
    while True:
        # the next point: the next layer's first line, or 60 s of planned time after the last M73
        while li < len(layer_idx) and layer_idx[li] <= i:
            li += 1
        nxt = layer_idx[li] if li < len(layer_idx) else len(lines)
        if m73:
            j = int(np.searchsorted(t, t_last + MINUTE_S, side="left"))
            nxt = min(nxt, max(j, i + 1))
        if nxt >= len(lines):
            break
        put(nxt)
        i, t_last = nxt, float(t[nxt])
    if m73:
        out.setdefault(int(lines[-1]) + 1, []).append("M73 P100 R0")
    return sorted(out), out


def _rewrite(body: bytes, t_here: float, total: float, first_layer_s: float) -> bytes | None:
    """The slicer time line ``body`` (no line ending) with gcodeplan's figures, or None if it is none."""
    if body.startswith(b"; estimated printing time (normal mode) = "):
        return b"; estimated printing time (normal mode) = " + dhms(total).encode()
    if body.startswith(b"; estimated first layer printing time (normal mode) = "):
        return b"; estimated first layer printing time (normal mode) = " + dhms(first_layer_s).encode()
    if body.startswith(b"; ") and (b"model printing time: " in body or b"total estimated time: " in body):
        return _ORCA_RE.sub(lambda m: m.group(1) + dhms(total).encode(), body)
    if body.startswith(b";TIME:") and re.fullmatch(rb";TIME:\s*[0-9.]+\s*", body):
        return b";TIME:%d" % int(round(total))
    if body.startswith(b";PRINT.TIME:"):
        return b";PRINT.TIME:%d" % int(round(total))
    if body.startswith(b";TIME_ELAPSED:"):
        return b";TIME_ELAPSED:%.6f" % t_here
    if body.startswith(b";Print Time: "):
        return b";Print Time: %d" % int(round(total))
    if body.startswith(b";PRINTING_TIME: "):
        return b";PRINTING_TIME: %d" % int(round(t_here))
    if body.startswith(b";REMAINING_TIME: "):
        return b";REMAINING_TIME: %d" % int(round(max(total - t_here, 0.0)))
    return None


def _split_eol(line: bytes) -> tuple[bytes, bytes]:
    if line.endswith(b"\r\n"):
        return line[:-2], b"\r\n"
    if line.endswith(b"\n"):
        return line[:-1], b"\n"
    if line.endswith(b"\r"):            # an old Mac file's line end
        return line[:-1], b"\r"
    return line, b""


def post_process(path, out=None, machine=None, policy: str | None = None, jerk: float | None = None, *,
                 strict: bool = False, m73: bool = True, layer_info: bool = False, progress=None,
                 exclude_objects=()) -> PostProcessResult:
    """Rewrite the G-code file ``path`` (or write ``out``) with gcodeplan's times (see the module
    docstring). ``machine``: a Machine, a preset name or TOML path (None = the klipper preset);
    ``policy``/``jerk``/``strict`` as :func:`gcodeplan.estimate`. Binary G-code and gzip are refused;
    standard input (``-``) and FIFOs are read once into a temporary copy and need ``out``. Returns a
    :class:`PostProcessResult` (times in s)."""
    from ..gcode.sources import spooled

    if not isinstance(path, os.PathLike):
        path = str(path)
    if out is None:
        _refuse_unsupported(path, True)        # before copying a pipe that cannot be rewritten anyway
    with spooled(path) as src:
        return _post_process(src, path, out, machine, policy, jerk, strict=strict, m73=m73, layer_info=layer_info,
                             progress=progress, exclude_objects=exclude_objects)


def _cnc_flavor(path, machine) -> tuple[bool, str]:
    """(the program is for a CNC controller, the flavor to name): the flavor the pipeline reads the file with,
    or "CNC" for a CNC program (its name or CAM header says so) planned on a printer machine the user named, which
    is planned as asked but must get no printer command written into it."""
    from ..gcode.dialect import reading_machine

    read_machine, note, _ = reading_machine(path, machine)
    flavor = read_machine.flavor
    cnc = flavor in ("grbl", "linuxcnc")
    if not cnc and note and note["kind"] == "cnc":
        cnc, flavor = True, "CNC"
    return cnc, flavor


def _note_insert(result, out_line: int, text: str) -> None:
    """Count an inserted line in ``result``; an ``M73 P<percent> R<minutes>`` is noted with its output line."""
    result.inserted += 1
    if text.startswith("M73"):
        pv, rv = text[5:].split(" R")
        result.m73.append((out_line, int(pv), int(rv)))


def _post_process(path, given, out, machine, policy, jerk, *, strict, m73, layer_info, progress,
                  exclude_objects) -> PostProcessResult:
    """:func:`post_process` on ``path``, a regular file or a spool of ``given`` (the input as named)."""
    from .. import __version__
    from ..api import as_machine
    from ..gcode.sources import iter_lines, open_source, source_name
    from ..pipeline import run
    from .output import atomic_output

    _refuse_unsupported(path, out is None)
    name = source_name(path)
    machine = as_machine(machine)
    cnc, flavor = _cnc_flavor(path, machine)
    if cnc:
        if layer_info:
            raise GcodeplanError(f"--layer-info writes Klipper's SET_PRINT_STATS_INFO: not into a {flavor} "
                                 f"program", path)
        m73 = False          # printer-only: grbl stops with error:20, LinuxCNC's M73 saves modal state
    sink = ProgressSink()
    res = run(path, machine, policy=policy, jerk=jerk, strict=strict, sinks=[sink], progress=progress,
              exclude_objects=exclude_objects)
    identity = res.reader.source.identity
    lines, ends = sink.arrays()
    total = sink.total_s
    keys, inserts = _schedule(lines, ends, sink.layer_starts, total, len(res.reader.layer_z), m73, layer_info)
    ours = f"; gcodeplan {__version__}: {dhms(total)} = {total:.3f} s ({machine.name}, {res.policy})"
    if cnc:       # an RS274 comment (no nested parentheses), which grbl and LinuxCNC both skip
        mname = machine.name.translate(str.maketrans("()", "[]"))
        ours = f"(gcodeplan {__version__}: {dhms(total)} = {total:.3f} s, machine {mname}, policy {res.policy})"
    target = str(out) if out is not None else os.fspath(given)
    result = PostProcessResult(target, total, machine.name, res.policy, cnc_flavor=flavor if cnc else None)

    def time_at(n: int) -> float:
        # planned time when source line n is reached: the end of the last line before it that takes time
        k = int(np.searchsorted(lines, n, side="left"))
        return float(ends[k - 1]) if k > 0 else 0.0

    eol = b"\n"
    try:
        # pass 2 reads the file pass 1 planned, or fails (sources.py: identity at open, checked at the end)
        with open_source(path, identity=identity) as fin, atomic_output(target, "wb") as fout:
            write = fout.write
            ki = 0
            next_ins = keys[0] if keys else -1
            out_line = 0
            line = b""
            n = dropped_at = 0
            last_eol = b"\n"
            first_eol = None
            for n, line in enumerate(iter_lines(fin.stream), 1):
                if n == next_ins:
                    ins_eol = _split_eol(line)[1] or last_eol
                    for text in inserts[n]:
                        write(text.encode() + ins_eol)
                        out_line += 1
                        _note_insert(result, out_line, text)
                    ki += 1
                    next_ins = keys[ki] if ki < len(keys) else -1
                c = line[:1]
                if c == b"G" or c == b"g":       # most lines: moves, copied as they are
                    write(line)
                    out_line += 1
                    continue
                body, le = _split_eol(line)
                if le:
                    last_eol = le
                    if first_eol is None:
                        first_eol = le
                if (m73 and _M73_RE.match(body)) or (layer_info and _STATS_RE.match(body)) or _OURS_RE.match(body) \
                        or _SILENT_RE.match(body):
                    result.dropped += 1
                    dropped_at = n
                    continue
                if c == b";":
                    new = _rewrite(body, time_at(n) if body[1:2] in (b"T", b"P", b"R") else 0.0, total,
                                   sink.first_layer_s)
                    if new is not None and new != body:
                        result.rewritten += 1
                        line = new + le
                write(line)
                out_line += 1
            ended = line.endswith((b"\n", b"\r")) or dropped_at == n or n == 0
            eol = first_eol or b"\n"
            tail = []
            if next_ins != -1:                    # after the last line: the final M73
                tail.extend(inserts[next_ins])
            tail.append(ours)
            if not ended:
                # the file's last line had no line ending: it gets one, so that our lines follow it
                write(eol)
            for text in tail:
                write(text.encode() + eol)
                out_line += 1
                _note_insert(result, out_line, text)
    except OSError as err:
        raise GcodeError(f"cannot read: {err.strerror or err}", name) from None
    return result


__all__ = ["post_process", "PostProcessResult", "ProgressSink", "dhms", "m73_values", "TIME_LINES"]
