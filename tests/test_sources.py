"""Every kind of source gives the MOVE rows and totals of the file itself: stdin (the CLI with ``-``),
gzip, binary and text file objects, iterables of lines; errors name ``<stdin>`` / ``<lines>``."""
from __future__ import annotations

import gzip
import zlib
import io
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from conftest import SAMPLES
from gcodeplan.cli import main
from gcodeplan.errors import GcodeError
from gcodeplan.gcode import GcodeReader, read_moves
from gcodeplan.gcode.sources import open_source
from gcodeplan.machine import Machine

CUBE = SAMPLES / "prusaslicer25_cube20_marlin2.gcode"       # 7,718 lines, LF
PLASMA = SAMPLES / "linuxcnc_plasmatest.ngc"                 # CRLF line ends, arcs


def machine(flavor="klipper"):
    return Machine(flavor=flavor)


def assert_same(a, b):
    (ma, ra), (mb, rb) = a, b
    assert ma.dtype == mb.dtype and len(ma) == len(mb) > 0
    for f in ma.dtype.names:
        assert np.array_equal(ma[f], mb[f], equal_nan=True), f
    sa, sb = dict(ra.summary.to_json()), dict(rb.summary.to_json())
    sa.pop("file")
    sb.pop("file")
    # warnings name the source (a path, <stream>): compare what follows the name
    for d, r in ((sa, ra), (sb, rb)):
        d["warnings"] = [w.split(":", 1)[1] if w.startswith(str(r.path)) else w for w in d.get("warnings", [])]
    assert sa == sb
    assert ra.layer_z == rb.layer_z and ra.features == rb.features
    assert np.array_equal(ra.limits, rb.limits)


@pytest.fixture(scope="module")
def cube():
    return read_moves(CUBE, machine())


# ------------------------------------------------------------------ in-process sources
def test_a_pathlib_path_and_a_str_path_are_the_same(cube):
    assert_same(read_moves(str(CUBE), machine()), cube)


@pytest.mark.parametrize("chunk", [4096, 1 << 20])
def test_binary_file_objects_equal_the_file(cube, chunk):
    with open(CUBE, "rb") as fh:
        got = read_moves(fh, machine(), chunk_bytes=chunk)
        assert not fh.closed                                  # the caller's object is left open
    assert_same(got, cube)
    assert got[1].path == str(CUBE)                           # a named file object keeps its name
    got = read_moves(io.BytesIO(CUBE.read_bytes()), machine(), chunk_bytes=chunk)
    assert_same(got, cube)
    assert got[1].path == "<stream>"


def test_text_file_objects_equal_the_file(cube):
    with open(CUBE, encoding="utf-8") as fh:
        assert_same(read_moves(fh, machine()), cube)
    assert_same(read_moves(io.StringIO(CUBE.read_text()), machine()), cube)


@pytest.mark.parametrize("form", ["str with newline", "str without newline", "bytes with newline",
                                  "bytes without newline", "generator"])
def test_iterables_of_lines_equal_the_file(cube, form):
    raw = CUBE.read_bytes().split(b"\n")[:-1]                 # the file ends with a newline
    if form == "str with newline":
        lines = [ln.decode() + "\n" for ln in raw]
    elif form == "str without newline":
        lines = [ln.decode() for ln in raw]
    elif form == "bytes with newline":
        lines = [ln + b"\n" for ln in raw]
    elif form == "bytes without newline":
        lines = list(raw)
    else:
        lines = (ln.decode() for ln in raw)
    moves, reader = read_moves(lines, machine())
    assert_same((moves, reader), cube)
    assert reader.path == "<lines>"


def test_crlf_text_is_read_alike_through_every_source():
    ref = read_moves(PLASMA, machine("grbl"))
    assert PLASMA.read_bytes().count(b"\r\n") > 300
    assert_same(read_moves(io.BytesIO(PLASMA.read_bytes()), machine("grbl")), ref)
    assert_same(read_moves(PLASMA.read_bytes().split(b"\n")[:-1], machine("grbl")), ref)   # CR kept in each item


@pytest.mark.parametrize("chunk", [4096, 1 << 20])
def test_gzip_is_recognised_by_its_magic_bytes_and_streamed(cube, tmp_path, chunk):
    data = gzip.compress(CUBE.read_bytes())
    for name in ("cube.gcode.gz", "cube.gcode"):              # the name does not matter, the bytes do
        p = tmp_path / name
        p.write_bytes(data)
        got = read_moves(p, machine(), chunk_bytes=chunk)
        assert_same(got, cube)
        assert got[1].bytes_read == got[1].bytes_total == len(data)   # progress counts compressed bytes


def test_gzip_is_read_piece_by_piece_not_whole(tmp_path):
    """Streaming: after the first chunk only a part of the compressed file has been taken."""
    p = tmp_path / "big.gcode.gz"
    text = b"".join(b"G1 X%d Y%d F6000\n" % (i % 200, (i * 7) % 200) for i in range(400_000))
    p.write_bytes(gzip.compress(text, 1))
    r = GcodeReader(p, machine(), chunk_bytes=1 << 16, batch_moves=1024)
    it = r.batches()
    next(it)
    assert 0 < r.bytes_read < 0.25 * p.stat().st_size
    for _ in it:
        pass
    assert r.bytes_read == p.stat().st_size and r.summary.lines == 400_000


def test_bytes_read_counts_the_plain_file(cube):
    assert cube[1].bytes_read == cube[1].bytes_total == CUBE.stat().st_size


def test_corrupt_and_truncated_gzip_are_one_clear_error(tmp_path):
    data = gzip.compress(CUBE.read_bytes(), mtime=0)
    p = tmp_path / "cut.gcode.gz"
    # a flipped byte decodes to garbage lines before the member's CRC fails: whatever byte is hit (gzip's
    # header holds the time, so each run flips other text), the error must be the container's
    p.write_bytes(data[: len(data) // 2])
    with pytest.raises(GcodeError, match="corrupt gzip data") as e:
        read_moves(p, machine())
    assert str(p) in str(e.value)
    for k in range(20):
        bad = bytearray(data)
        bad[(len(bad) // 3 + 997 * k) % (len(bad) - 20) + 10] ^= 0xFF
        try:
            gzip.decompress(bytes(bad))
            continue                       # a flip gzip itself cannot see: nothing for us to report
        except (OSError, EOFError, zlib.error):
            pass
        p.write_bytes(bytes(bad))
        for chunk in (4096, 1 << 23):     # the garbage reaches the interpreter before or after the end is read
            with pytest.raises(GcodeError, match="corrupt gzip data"):
                read_moves(p, machine(), chunk_bytes=chunk)


def test_errors_name_the_lines_source_and_the_line():
    with pytest.raises(GcodeError) as e:
        read_moves(["G1 X10", "G1 X1.2.3"], machine())
    assert str(e.value).startswith("<lines>:2: ")
    with pytest.raises(GcodeError, match=r"^<lines>: line 2 of the iterable is int"):
        read_moves(["G1 X1", 5], machine())


def test_a_missing_file_fails_when_the_reader_is_made(tmp_path):
    with pytest.raises(GcodeError, match="no such file"):
        GcodeReader(tmp_path / "nope.gcode", machine())
    with pytest.raises(GcodeError, match="is a directory"):
        GcodeReader(tmp_path, machine())


def test_bytes_and_other_objects_are_not_sources():
    with pytest.raises(TypeError, match="io.BytesIO"):
        open_source(b"G1 X1\n")
    with pytest.raises(TypeError):
        open_source(42)


def test_an_opened_path_is_closed_after_reading(tmp_path):
    p = tmp_path / "a.gcode"
    p.write_text("G1 X10 F600\n")
    r = GcodeReader(p, machine())
    fh = r.source._closers[0]
    list(r.batches())
    assert fh.closed


# ------------------------------------------------------------------ the command line with '-'
def _run(args, stdin_path):
    with open(stdin_path, "rb") as fh:
        out = subprocess.run([sys.executable, "-m", "gcodeplan.cli", *args], stdin=fh, capture_output=True,
                             timeout=300, env={**os.environ, "PYTHONWARNINGS": "ignore"})
    return out


def test_estimate_reads_stdin_with_dash(capsys, tmp_path):
    assert main(["estimate", "--json", "--quiet", str(CUBE)]) == 0
    ref = json.loads(capsys.readouterr().out)
    gz = tmp_path / "cube.gcode.gz"
    gz.write_bytes(gzip.compress(CUBE.read_bytes()))
    for src in (CUBE, gz):
        out = _run(["estimate", "-", "--json"], src)
        assert out.returncode == 0, out.stderr
        d = json.loads(out.stdout)
        assert d["total_time_s"] == ref["total_time_s"]
        assert d["moves"] == ref["moves"] and d["layers"] == ref["layers"] and d["features"] == ref["features"]


def test_parse_reads_stdin_with_dash(capsys):
    assert main(["parse", "--json", str(CUBE)]) == 0
    ref = json.loads(capsys.readouterr().out)
    out = _run(["parse", "-", "--json"], CUBE)
    assert out.returncode == 0, out.stderr
    d = json.loads(out.stdout)
    assert d.pop("file") == "<stdin>"
    ref.pop("file")
    # a named file's slicer/CAM program is detected from its head (gcode/dialect.py); standard input is not
    # peeked at (it can be read once)
    assert d.pop("dialect") is None and ref.pop("dialect")["program"] == "PrusaSlicer"
    assert d == ref


def test_a_bad_line_on_stdin_is_one_line_naming_stdin(tmp_path):
    p = tmp_path / "bad.gcode"
    p.write_text("G1 X10\nG1 X1.2.3\n")
    out = _run(["estimate", "-"], p)
    assert out.returncode == 2
    err = out.stderr.decode().strip().splitlines()
    assert len(err) == 1 and "<stdin>:2: " in err[0]


@pytest.mark.slow
def test_every_corpus_file_gives_the_same_rows_through_gzip_and_a_pipe_like_stream(tmp_path):
    from conftest import shared_path

    corpus = shared_path("gcode")
    files = sorted(p for p in corpus.iterdir() if p.suffix in (".gcode", ".ngc"))
    assert len(files) >= 9
    for path in files:
        gz = tmp_path / (path.name + ".gz")
        gz.write_bytes(gzip.compress(path.read_bytes(), 1))

        class Pipe(io.RawIOBase):                             # no fileno, no seek, short reads: like a pipe
            def __init__(self, fh):
                self.fh = fh

            def readable(self):
                return True

            def readinto(self, b):
                return self.fh.readinto(memoryview(b)[:65536])

        # an RS274NGC program read as one (on Klipper its lines led by an axis word do nothing)
        flavor = "linuxcnc" if path.suffix == ".ngc" else "klipper"
        with open(gz, "rb") as fh:
            readers = [GcodeReader(path, machine(flavor)), GcodeReader(Pipe(fh), machine(flavor))]
            for a, b in zip(readers[0].batches(), readers[1].batches(), strict=True):
                assert len(a) == len(b), path.name
                for f in a.dtype.names:                       # field by field (padding bytes are undefined)
                    assert np.array_equal(a[f], b[f], equal_nan=True), (path.name, f)
        sa, sb = readers[0].summary.to_json(), readers[1].summary.to_json()
        sa.pop("file")
        sb.pop("file")
        sa["warnings"] = [w.replace(str(path), "<stream>", 1) for w in sa["warnings"]]   # messages name the source
        assert sa == sb, path.name
        assert readers[1].bytes_total is None and readers[1].bytes_read == gz.stat().st_size
