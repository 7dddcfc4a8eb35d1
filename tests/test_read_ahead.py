"""Big files are read in a second thread (pipeline.read_ahead) while the planner and the sinks work.

Truth: the same run without the thread. Everything a sink sees (pieces, their LIMITS tables, progress) and
the run's result must be identical, an error midway must arrive after the same pieces with the same file and
line, and no reader thread may outlive the run, however it ends.
"""
from __future__ import annotations

import os
import threading

import numpy as np
import pytest

import gcodeplan as gp
from conftest import SAMPLES, shared_path
from gcodeplan import pipeline
from gcodeplan.errors import GcodeplanError

CUBE = SAMPLES / "prusaslicer25_cube20_marlin2.gcode"        # 174 kB: compiled kernels, many batches
ARCS = SAMPLES / "linuxcnc_arcspiral.ngc"


class Record(pipeline.Sink):
    """Every piece's rows, LIMITS table and segments, as copies."""

    def __init__(self, stop_after: int | None = None, fail_after: int | None = None):
        self.pieces = []
        self.stop_after = stop_after
        self.fail_after = fail_after

    def add(self, piece):
        if self.fail_after is not None and len(self.pieces) == self.fail_after:
            raise RuntimeError("a sink failed")
        self.pieces.append((piece.first_move, piece.moves.copy(), piece.plan.copy(), piece.limits.copy(),
                            piece.segments.copy()))
        return self.stop_after is not None and len(self.pieces) >= self.stop_after


def _reader_threads() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name == "gcodeplan-reader"]


def _open_fds(path) -> int:
    """This process's open file descriptors on ``path`` (Linux /proc)."""
    target = os.path.realpath(path)
    n = 0
    for fd in os.listdir("/proc/self/fd"):
        try:
            n += os.path.realpath(os.readlink(f"/proc/self/fd/{fd}")) == target
        except OSError:
            pass
    return n


def _mode(monkeypatch, mode) -> None:
    """'plain': one thread; 'threaded': the reader thread throughout; 'handover': the reader thread hands
    the reading back to the main thread after its first batch (as a Python-heavy reader does)."""
    monkeypatch.setattr(pipeline, "READ_AHEAD_BYTES", 1 << 62 if mode == "plain" else 0)
    monkeypatch.setattr(pipeline, "READ_AHEAD_PROBE_S", 0.0 if mode == "handover" else 0.05)
    monkeypatch.setattr(pipeline, "READ_AHEAD_MAX_PYTHON_SHARE", -1.0 if mode == "handover" else 1e9)


def _run(monkeypatch, path, mode, machine=None, **kw):
    _mode(monkeypatch, mode)
    sink, progress = Record(), []
    machine = machine or gp.load_machine("klipper")
    result = pipeline.run(str(path), machine, sinks=[sink], progress=progress.append, batch_moves=256, **kw)
    return sink, progress, result


def _same_pieces(a: Record, b: Record, at_least: int = 4) -> None:
    assert len(a.pieces) == len(b.pieces) >= at_least
    for pa, pb in zip(a.pieces, b.pieces):
        assert pa[0] == pb[0]
        for x, y in zip(pa[1:], pb[1:]):
            assert x.dtype == y.dtype and len(x) == len(y)
            for f in x.dtype.names:      # field by field, bit for bit (padding bytes are not data)
                assert np.ascontiguousarray(x[f]).tobytes() == np.ascontiguousarray(y[f]).tobytes(), f


@pytest.mark.parametrize("preset, kw", [("klipper", {}), ("klipper", {"policy": "blend"}),
                                        ("klipper", {"jerk": 20000.0}), ("marlin", {"policy": "classic-jerk"}),
                                        ("marlin", {"policy": "exact-stop"})])
@pytest.mark.parametrize("mode", ["threaded", "handover"])
def test_threaded_run_equals_the_plain_one(monkeypatch, preset, kw, mode):
    machine = gp.load_machine(preset)
    plain, p_progress, p_res = _run(monkeypatch, CUBE, "plain", machine, **kw)
    threaded, t_progress, t_res = _run(monkeypatch, CUBE, mode, machine, **kw)
    _same_pieces(plain, threaded)
    assert p_progress == t_progress and p_progress[-1] == os.path.getsize(CUBE)
    assert t_res.reader.summary.to_json() == p_res.reader.summary.to_json()
    assert t_res.rows == p_res.rows and not t_res.stopped_early
    assert not _reader_threads()


@pytest.mark.parametrize("mode", ["threaded", "handover"])
def test_threaded_linuxcnc_run_equals_the_plain_one(monkeypatch, mode):
    mill = gp.load_machine(linuxcnc_ini=str(shared_path("reference", "linuxcnc", "config", "mill.ini")))
    plain, _, _ = _run(monkeypatch, ARCS, "plain", machine=mill, policy="linuxcnc")
    threaded, _, _ = _run(monkeypatch, ARCS, mode, machine=mill, policy="linuxcnc")
    _same_pieces(plain, threaded, at_least=2)      # LinuxCNC's planner holds the spiral until its end


def test_a_python_heavy_reader_hands_the_reading_back(monkeypatch):
    """A reader that spends most of its time on lines interpreted in Python (arcs here) stops its thread
    once it has read for READ_AHEAD_PROBE_S: two threads running Python mostly wait for each other."""
    monkeypatch.setattr(pipeline, "READ_AHEAD_BYTES", 0)
    monkeypatch.setattr(pipeline, "READ_AHEAD_PROBE_S", 0.0)
    mill = gp.load_machine(linuxcnc_ini=str(shared_path("reference", "linuxcnc", "config", "mill.ini")))
    pipeline.run(str(ARCS), mill)       # kernels loaded: the thread's first batch is the arcs' own work
    drive = pipeline.Run(str(ARCS), mill, batch_moves=256)
    seen_threads = []
    for _ in drive:
        seen_threads.append(len(_reader_threads()))
    assert drive.reader.python_s > 0.0
    # the arc spiral is Python-heavy: the reader thread ends at its first hand-over (on a loaded machine it may
    # still be exiting when the first piece arrives), and no thread reads after that
    assert len(seen_threads) >= 2 and set(seen_threads[1:]) == {0}


def _bad_file(tmp_path) -> tuple[str, int]:
    """The cube with an absurd move (refused: longer than 10⁶ mm) two thirds in."""
    lines = CUBE.read_bytes().split(b"\n")
    bad = 2 * len(lines) // 3
    lines.insert(bad, b"G1 X1000000000 F3000")
    path = tmp_path / "bad.gcode"
    path.write_bytes(b"\n".join(lines))
    return str(path), bad + 1


def test_an_error_midway_arrives_after_the_same_pieces(monkeypatch, tmp_path):
    path, line = _bad_file(tmp_path)
    seen = {}
    for threaded in ("plain", "threaded", "handover"):
        _mode(monkeypatch, threaded)
        sink = Record()
        with pytest.raises(GcodeplanError) as err:
            pipeline.run(path, gp.load_machine("klipper"), sinks=[sink], batch_moves=256)
        assert err.value.file == path and err.value.line == line, str(err.value)
        seen[threaded] = (str(err.value), sink)
        assert not _reader_threads()
    for mode in ("threaded", "handover"):
        assert seen["plain"][0] == seen[mode][0]
        _same_pieces(seen["plain"][1], seen[mode][1])


@pytest.mark.parametrize("mode", ["threaded", "handover"])
@pytest.mark.parametrize("how", ["sink done", "sink raises", "loop left"])
def test_no_reader_thread_outlives_the_run(monkeypatch, how, mode):
    _mode(monkeypatch, mode)
    machine = gp.load_machine("klipper")
    if how == "sink done":
        sink = Record(stop_after=2)
        res = pipeline.run(str(CUBE), machine, sinks=[sink], batch_moves=64)
        assert res.stopped_early and len(sink.pieces) == 2
    elif how == "sink raises":
        with pytest.raises(RuntimeError, match="a sink failed"):
            pipeline.run(str(CUBE), machine, sinks=[Record(fail_after=3)], batch_moves=64)
    else:
        drive = pipeline.Run(str(CUBE), machine, batch_moves=64)
        assert drive.threaded
        for k, _ in enumerate(drive):
            if k == 2:
                break
        assert drive.result.stopped_early
        drive = None
    assert not _reader_threads()
    assert _open_fds(CUBE) == 0          # the reader closed the file, whichever thread was reading it


def test_which_inputs_are_read_ahead(tmp_path, monkeypatch):
    monkeypatch.setattr(pipeline, "READ_AHEAD_BYTES", 1000)
    big = tmp_path / "big.gcode"
    big.write_bytes(b"G1 X1 F600\n" * 200)
    small = tmp_path / "small.gcode"
    small.write_bytes(b"G1 X1 F600\n")
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    assert pipeline.read_ahead_input(str(big)) and pipeline.read_ahead_input(big)
    assert not pipeline.read_ahead_input(str(small))
    assert not pipeline.read_ahead_input(str(fifo))          # a pipe belongs to the caller's thread
    assert not pipeline.read_ahead_input("-")
    assert not pipeline.read_ahead_input([b"G1 X1"] * 1000)
    assert not pipeline.read_ahead_input(str(tmp_path / "missing.gcode"))
    with open(big, "rb") as fh:
        assert not pipeline.read_ahead_input(fh)
    # a small input runs interpreted in the caller's thread, never read ahead (gcodeplan/_jit.py)
    assert not pipeline.Run(str(big), gp.load_machine("klipper")).threaded


def test_a_reader_thread_that_vanishes_is_an_error_not_a_hang(monkeypatch):
    """If the reader thread ended without handing over a batch, an error or its end (a bug, not a case the
    code knows), the main thread must not wait for ever."""
    import queue

    monkeypatch.setattr(pipeline, "READ_AHEAD_BYTES", 0)
    monkeypatch.setattr(queue.Queue, "put", lambda self, item, block=True, timeout=None: None)   # items lost
    with pytest.raises(RuntimeError, match="reader thread ended without a result"):
        pipeline.run(str(CUBE), gp.load_machine("klipper"), sinks=[Record()])
    assert not _reader_threads()


def test_a_signal_while_the_reader_thread_starts_still_stops_it(monkeypatch):
    """A KeyboardInterrupt (or gcodeplan's SIGTERM exception) can arrive while Thread.start() waits for the new
    thread: the reader must still be stopped and its file closed (found in review with random interrupts)."""
    monkeypatch.setattr(pipeline, "READ_AHEAD_BYTES", 0)
    start = threading.Thread.start

    def start_then_signal(self):
        start(self)
        if self.name == "gcodeplan-reader":
            raise KeyboardInterrupt

    monkeypatch.setattr(threading.Thread, "start", start_then_signal)
    with pytest.raises(KeyboardInterrupt):
        pipeline.run(str(CUBE), gp.load_machine("klipper"), sinks=[Record()], batch_moves=64)
    assert not _reader_threads()
    assert _open_fds(CUBE) == 0


def test_the_planner_writes_pending_rows_only_into_spare_rows():
    """prepend_rows puts the planner's pending rows into a batch's spare rows, once, and only when the rows fed
    start exactly there: a later slice of the same buffer is copied, the caller's rows before it untouched."""
    from gcodeplan.schema import MOVE_DTYPE, concat_rows, prepend_rows, rows_with_headroom

    def _fields(rows):         # every field's bytes (padding between fields is not data)
        return [np.ascontiguousarray(rows[f]).tobytes() for f in rows.dtype.names]

    rng = np.random.default_rng(3)
    head = np.zeros(3, MOVE_DTYPE)
    head["x1"] = [1.0, 2.0, 3.0]
    batch = rows_with_headroom(100, MOVE_DTYPE, headroom=8)
    batch[:] = np.zeros(100, MOVE_DTYPE)
    batch["x1"] = rng.random(100)
    kept = batch.copy()

    later = prepend_rows(head, batch[10:])                 # not at the spare rows: a copy
    assert not np.shares_memory(later, batch)
    assert _fields(later) == _fields(concat_rows(head, kept[10:]))
    assert _fields(batch) == _fields(kept)

    window = prepend_rows(head, batch)                     # at the spare rows: no copy of the batch
    assert np.shares_memory(window, batch) and len(window) == 103
    assert _fields(window) == _fields(concat_rows(head, kept))
    again = prepend_rows(head[::-1].copy(), batch)         # the spare rows served once
    assert not np.shares_memory(again, batch)
    assert _fields(window) == _fields(concat_rows(head, kept))
    too_long = rows_with_headroom(5, MOVE_DTYPE, headroom=2)
    too_long[:] = np.zeros(5, MOVE_DTYPE)
    assert not np.shares_memory(prepend_rows(head, too_long), too_long)
