"""CR-only line ends (old Mac files) are line ends, as Marlin's and RepRapFirmware's line readers and the
slicers read them; CRLF stays one line end. The truth: the same file with LF line ends, read by every path
(numba scanner, Python interpreter, gzip, standard input, small reads that cut a CRLF in two)."""
from __future__ import annotations

import gzip
import io
import os
import subprocess
import sys

import numpy as np
import pytest

from conftest import SAMPLES
from gcodeplan.errors import GcodeError
from gcodeplan.gcode import GcodeReader, read_moves
from gcodeplan.machine import Machine

CUBE = SAMPLES / "prusaslicer25_cube20_marlin2.gcode"        # 7,718 lines, LF
PLASMA = SAMPLES / "linuxcnc_plasmatest.ngc"                  # CRLF, arcs: lines for the Python interpreter


def assert_same(a, b):
    (ma, ra), (mb, rb) = a, b
    assert len(ma) == len(mb) > 0
    for f in ma.dtype.names:
        assert np.array_equal(ma[f], mb[f], equal_nan=True), f
    sa, sb = dict(ra.summary.to_json()), dict(rb.summary.to_json())
    sa.pop("file")
    sb.pop("file")
    assert sa == sb
    assert ra.layer_z == rb.layer_z and ra.features == rb.features


@pytest.fixture(scope="module")
def cube_lf():
    return read_moves(CUBE, Machine(flavor="klipper"))


@pytest.fixture(scope="module")
def cube_cr(tmp_path_factory):
    p = tmp_path_factory.mktemp("cr") / "cube_cr.gcode"
    p.write_bytes(CUBE.read_bytes().replace(b"\n", b"\r"))
    return p


@pytest.mark.parametrize("chunk", [4096, 4097, 1 << 20])
def test_cr_only_file_reads_as_the_lf_file(cube_lf, cube_cr, chunk):
    got = read_moves(cube_cr, Machine(flavor="klipper"), chunk_bytes=chunk)
    assert_same(got, cube_lf)
    assert got[1].summary.lines == 7718
    assert got[0]["line"].max() == cube_lf[0]["line"].max() > 7000     # line numbers count CR-only lines


def test_cr_only_gzip_and_stream_read_as_the_lf_file(cube_lf, cube_cr):
    data = cube_cr.read_bytes()
    assert_same(read_moves(io.BytesIO(gzip.compress(data)), Machine(flavor="klipper")), cube_lf)
    assert_same(read_moves(io.BytesIO(data), Machine(flavor="klipper"), chunk_bytes=5000), cube_lf)


def test_cr_only_through_the_python_interpreter_equals_the_scanner():
    # arcs and LinuxCNC words: many lines go to Python; force_python sends them all
    m = Machine(flavor="linuxcnc")
    lf = PLASMA.read_bytes().replace(b"\r\n", b"\n")
    ref = read_moves(io.BytesIO(lf), m)
    cr = lf.replace(b"\n", b"\r")
    assert_same(read_moves(io.BytesIO(cr), m), ref)
    assert_same(read_moves(io.BytesIO(cr), m, force_python=True), ref)
    assert_same(read_moves(io.BytesIO(cr), m, force_python=True, chunk_bytes=4096), ref)


@pytest.mark.parametrize("chunk", range(4090, 4100))
def test_crlf_cut_between_reads_stays_one_line_end(chunk):
    # chunk sizes around a CRLF that straddles a read: its CR must not become a line end of its own
    m = Machine(flavor="linuxcnc")
    ref = read_moves(io.BytesIO(PLASMA.read_bytes().replace(b"\r\n", b"\n")), m)
    got = read_moves(PLASMA, m, chunk_bytes=chunk)
    assert_same(got, ref)
    assert got[1].summary.lines == ref[1].summary.lines


def test_error_line_numbers_count_cr_only_lines(tmp_path):
    # line 1 CRLF, line 2 LF, lines 3-4 CR only, bad line 5
    p = tmp_path / "mixed.gcode"
    p.write_bytes(b"G28\r\nG1 X1 F600\nG1 X2\rG1 X3\rG1 X1.2.3\rG1 X4\r")
    for force in (False, True):
        with pytest.raises(GcodeError) as err:
            read_moves(p, Machine(flavor="klipper"), force_python=force)
        assert err.value.line == 5, force
    p.write_bytes(b"G90\r\nG1 X1 F600\nG1 X2\rG1 X3\r\rG1 X4\r")
    moves, r = read_moves(p, Machine(flavor="klipper"))
    assert moves["line"].tolist() == [2, 3, 4, 6] and r.summary.lines == 6
    assert moves["x1"].tolist() == [1.0, 2.0, 3.0, 4.0]


def test_cr_only_on_standard_input(cube_cr, tmp_path):
    with open(cube_cr, "rb") as fh:
        out = subprocess.run([sys.executable, "-m", "gcodeplan.cli", "estimate", "-", "--json"], stdin=fh,
                             capture_output=True, timeout=300, env={**os.environ, "PYTHONWARNINGS": "ignore"})
    assert out.returncode == 0, out.stderr
    import json

    d = json.loads(out.stdout)
    ref = read_moves(CUBE, Machine(flavor="klipper"))[1].summary
    assert d["moves"] == ref.moves > 1000 and d["lines"] == 7718


def test_push_mode_reads_cr_only_lines():
    m = Machine(flavor="klipper")
    r = GcodeReader(iter(()), m)
    rows = r.feed(b"G90\rG1 X1 F600\r")      # the last CR may be the start of a CRLF: it waits
    rows += r.feed(b"\nG1 X2\r")
    rows += r.end()
    moves = np.concatenate(rows)
    assert moves["line"].tolist() == [2, 3] and moves["x1"].tolist() == [1.0, 2.0]


def test_cr_line_ends_and_iter_lines_agree_with_splitlines():
    from gcodeplan.gcode.sources import cr_line_ends, iter_lines

    text = b"a\r\nb\rc\n\r\rd\r\r\ne"
    buf = bytearray(text)
    cr_line_ends(buf, 0, len(buf), True)
    assert bytes(buf) == b"a\r\nb\nc\n\n\nd\n\r\ne"
    assert buf.count(b"\n") + 1 == len(text.splitlines())
    for size in range(1, len(text) + 1):          # every cut, a CRLF split included
        assert list(iter_lines(io.BytesIO(text), size)) == text.splitlines(keepends=True)
    pending = bytearray(b"x\ry\r")
    cr_line_ends(pending, 0, len(pending), False)
    assert bytes(pending) == b"x\ny\r"             # the last CR waits for the next read


def _page_texts(html: str) -> bytes:
    import base64
    import re

    import zstandard

    blocks = re.findall(r'id="gpv-text-\d+">([^<]*)<', html)
    return b"".join(zstandard.ZstdDecompressor().decompress(base64.b64decode(b)) for b in blocks)


def test_the_viewer_shows_the_lines_of_a_cr_only_file(cube_cr):
    from gcodeplan.report.viewer import build_viewer

    m = Machine(flavor="klipper")
    ref = _page_texts(build_viewer(CUBE, m))
    got = _page_texts(build_viewer(cube_cr, m))
    assert len(ref) > 100_000 and got == ref


def test_post_process_keeps_cr_only_line_ends(cube_cr, tmp_path):
    from gcodeplan.report.postprocess import post_process

    ref, out = tmp_path / "ref.gcode", tmp_path / "out.gcode"
    r_ref = post_process(CUBE, ref)
    r_out = post_process(cube_cr, out)
    data = out.read_bytes()
    assert b"\n" not in data                          # the file's own line ends, inserted lines too
    assert data.replace(b"\r", b"\n") == ref.read_bytes()
    assert r_out.m73 == r_ref.m73 and len(r_out.m73) > 50
