"""Inputs are read once, or read twice only when they are the same file both times.

- ``view``, ``report`` and ``post-process -o`` read a FIFO, ``<(…)`` and standard input by copying it once
  to a temporary file (removed afterwards): they do not hang on the FIFO's second opening, the page holds
  the G-code text, and ``post-process`` writes what it writes for the regular file. In place, a pipe is
  refused with a clear message.
- A file replaced, truncated or written to while it is read is an error naming it, for every command and
  between the two passes of ``view`` / ``post-process``; nothing is written from two versions of a file.
"""
from __future__ import annotations

import base64
import gzip
import io
import os
import re
import subprocess
import sys
import threading

import pytest

from conftest import SAMPLES
from gcodeplan.errors import GcodeError, GcodeplanError
from gcodeplan.gcode import GcodeReader
from gcodeplan.machine import Machine

CUBE = SAMPLES / "prusaslicer25_cube20_marlin2.gcode"
ENV = {**os.environ, "PYTHONWARNINGS": "ignore"}


def cli(*args, stdin=None, cwd=None, timeout=240):
    return subprocess.run([sys.executable, "-m", "gcodeplan.cli", *map(str, args)], stdin=stdin, cwd=cwd,
                          capture_output=True, timeout=timeout, env=ENV)


def feed_fifo(path, data: bytes, times: int = 1):
    """Write ``data`` into the FIFO ``path`` ``times`` times (each a new opening), in a thread."""
    def run():
        for _ in range(times):
            try:
                with open(path, "wb") as fh:
                    fh.write(data)
            except OSError:
                return

    t = threading.Thread(target=run, daemon=True)
    t.start()
    return t


def spools_left():
    import tempfile

    return [n for n in os.listdir(tempfile.gettempdir()) if n.startswith("gcodeplan-") and n.endswith(".spool")]


# ------------------------------------------------------------------ FIFOs and <(…)
@pytest.fixture(scope="module")
def ref_pp(tmp_path_factory):
    d = tmp_path_factory.mktemp("ref")
    out = cli("post-process", CUBE, "-o", d / "ref.gcode", "--quiet")
    assert out.returncode == 0, out.stderr
    return (d / "ref.gcode").read_bytes()


def test_post_process_reads_a_fifo_once(tmp_path, ref_pp):
    fifo = tmp_path / "in.gcode"
    os.mkfifo(fifo)
    feed_fifo(fifo, CUBE.read_bytes())           # one writer: a second opening would wait forever
    out = cli("post-process", fifo, "-o", tmp_path / "out.gcode", "--quiet", timeout=120)
    assert out.returncode == 0, out.stderr
    assert (tmp_path / "out.gcode").read_bytes() == ref_pp


def test_post_process_of_process_substitution_and_stdin(tmp_path, ref_pp):
    out = subprocess.run(["bash", "-c", f'{sys.executable} -m gcodeplan.cli post-process <(cat "{CUBE}") '
                          f'-o "{tmp_path / "a.gcode"}" --quiet'], capture_output=True, timeout=240, env=ENV)
    assert out.returncode == 0, out.stderr
    assert (tmp_path / "a.gcode").read_bytes() == ref_pp
    with open(CUBE, "rb") as fh:
        out = cli("post-process", "-", "-o", tmp_path / "b.gcode", "--quiet", stdin=fh)
    assert out.returncode == 0, out.stderr
    assert (tmp_path / "b.gcode").read_bytes() == ref_pp


def test_post_process_in_place_refuses_a_pipe(tmp_path):
    with open(CUBE, "rb") as fh:
        out = cli("post-process", "-", stdin=fh)
    assert out.returncode == 2
    err = out.stderr.decode()
    assert err.count("\n") == 1 and "-o OUT" in err and "standard input" in err
    from gcodeplan.report.postprocess import post_process

    fifo = tmp_path / "p.gcode"
    os.mkfifo(fifo)
    with pytest.raises(GcodeplanError, match=r"p\.gcode is not a regular file.*-o OUT"):
        post_process(fifo)                       # refused before opening: no writer needed


def _page_texts(html: str) -> bytes:
    """The G-code text the viewer page holds (its zstd blocks)."""
    import zstandard

    blocks = re.findall(r'id="gpv-text-\d+">([^<]*)<', html)
    return b"".join(zstandard.ZstdDecompressor().decompress(base64.b64decode(b)) for b in blocks)


@pytest.mark.parametrize("command", ["view", "report"])
def test_view_and_report_read_a_fifo_once_and_keep_the_text(tmp_path, command):
    ref = tmp_path / "ref.html"
    out = cli(command, CUBE, "-o", ref, "--quiet" if command == "view" else "--slowest=0")
    assert out.returncode == 0, out.stderr
    fifo = tmp_path / "in.gcode"
    os.mkfifo(fifo)
    feed_fifo(fifo, CUBE.read_bytes())
    got = tmp_path / "got.html"
    out = cli(command, fifo, "-o", got, "--quiet" if command == "view" else "--slowest=0", timeout=120)
    assert out.returncode == 0, out.stderr
    text = _page_texts(got.read_text())
    assert len(text) > 100_000 and text == _page_texts(ref.read_text())
    assert b"G1 X" in text
    assert not [n for n in spools_left() if n.startswith("gcodeplan-")
                and not os.path.exists(f"/proc/{n.split('-')[1]}")]


def test_view_of_process_substitution_keeps_the_text(tmp_path):
    ref = tmp_path / "ref.html"
    assert cli("view", CUBE, "-o", ref, "--quiet").returncode == 0
    got = tmp_path / "got.html"
    out = subprocess.run(["bash", "-c", f'{sys.executable} -m gcodeplan.cli view <(gzip -c "{CUBE}") '
                          f'-o "{got}" --quiet'], capture_output=True, timeout=240, env=ENV)
    assert out.returncode == 0, out.stderr
    assert _page_texts(got.read_text()) == _page_texts(ref.read_text()) != b""


def test_the_spool_is_removed_after_an_error_and_names_the_input(tmp_path):
    from gcodeplan.gcode.sources import SpooledPath, spooled

    before = set(spools_left())
    with pytest.raises(GcodeError, match="boom"):
        with spooled(iter(["G1 X1\n"])) as src:
            assert isinstance(src, SpooledPath) and str(src) == "<lines>"
            assert open(src, "rb").read() == b"G1 X1\n"
            path = os.fspath(src)
            raise GcodeError("boom")
    assert not os.path.exists(path) and set(spools_left()) == before
    with spooled(CUBE) as src:                   # a regular file is read as it is
        assert src == CUBE


# ------------------------------------------------------------------ files changing underneath
def _reader_over(path, **kw):
    r = GcodeReader(path, Machine(flavor="klipper"), chunk_bytes=4096, batch_moves=100, **kw)
    it = r.batches()
    next(it)
    return it


def _finish(it):
    for _ in it:
        pass


def _replace(p, data):
    tmp = p.with_name(p.name + ".new")
    tmp.write_bytes(data)
    os.replace(tmp, p)


CHANGES = {
    "truncated": lambda p, data: os.truncate(p, len(data) // 3),
    "rewritten shorter": lambda p, data: p.write_bytes(data[: len(data) // 2]),
    "appended to": lambda p, data: p.open("ab").write(b"G1 X1\n"),
    "replaced by rename": _replace,
    "removed": lambda p, data: os.unlink(p),
}


@pytest.mark.parametrize("change", sorted(CHANGES))
def test_a_file_changed_while_it_is_read_is_an_error_naming_it(tmp_path, change):
    p = tmp_path / "part.gcode"
    data = CUBE.read_bytes()
    p.write_bytes(data)
    it = _reader_over(p)
    CHANGES[change](p, data)
    with pytest.raises(GcodeError, match=r"the file changed while it was read") as err:
        _finish(it)
    assert err.value.file == str(p)


def test_same_size_rewrite_is_caught_by_its_modification_time(tmp_path):
    p = tmp_path / "part.gcode"
    data = CUBE.read_bytes()
    p.write_bytes(data)
    st = os.stat(p)
    it = _reader_over(p)
    with open(p, "r+b") as fh:                   # same size, other content, a later mtime
        fh.write(data.replace(b"G1 X", b"G1 Y", 50)[:4096])
    os.utime(p, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000_000))
    with pytest.raises(GcodeError, match="written to"):
        _finish(it)


def test_gzip_replaced_while_read_is_an_error(tmp_path):
    p = tmp_path / "part.gcode.gz"
    p.write_bytes(gzip.compress(CUBE.read_bytes()))
    it = _reader_over(p)
    _replace(p, gzip.compress(CUBE.read_bytes()[:50_000]))
    with pytest.raises(GcodeError, match="another file was put in its place"):
        _finish(it)


def test_an_unchanged_file_reads_as_before(tmp_path):
    p = tmp_path / "part.gcode"
    p.write_bytes(CUBE.read_bytes())
    it = _reader_over(p)
    _finish(it)                                  # no error: the checks see the same file


def test_a_second_pass_over_another_file_is_refused(tmp_path):
    from gcodeplan.gcode.sources import iter_lines, open_source

    p = tmp_path / "part.gcode"
    p.write_bytes(CUBE.read_bytes())
    with open_source(p) as src:
        ident = src.identity
    assert ident is not None and ident[2] == CUBE.stat().st_size
    with open_source(p, identity=ident) as src:  # the same file: fine
        assert list(iter_lines(src.stream)) == CUBE.read_bytes().splitlines(keepends=True)
    _replace(p, CUBE.read_bytes())               # same bytes, another file: not what was planned
    with pytest.raises(GcodeError, match="changed between two passes"):
        open_source(p, identity=ident)


def test_post_process_writes_nothing_from_two_versions(tmp_path, monkeypatch):
    """The file changes between the planning pass and the copying pass: error, target untouched."""
    from gcodeplan import pipeline
    from gcodeplan.report import postprocess

    p = tmp_path / "part.gcode"
    original = CUBE.read_bytes()
    p.write_bytes(original)
    real_run = pipeline.run

    def run_then_change(*a, **kw):
        res = real_run(*a, **kw)
        _replace(p, original.replace(b";TYPE:", b";TYPE: ", 3))     # a slicer writing the file again
        return res

    monkeypatch.setattr(pipeline, "run", run_then_change)
    with pytest.raises(GcodeError, match="changed between two passes"):
        postprocess.post_process(p)
    assert p.read_bytes() == original.replace(b";TYPE:", b";TYPE: ", 3)
    out = tmp_path / "out.gcode"
    p.write_bytes(original)
    with pytest.raises(GcodeError, match="changed"):
        postprocess.post_process(p, out)
    assert not out.exists()
    assert not [n for n in os.listdir(tmp_path) if ".gcodeplan-" in n]


def test_view_refuses_texts_from_another_version(tmp_path, monkeypatch):
    from gcodeplan import pipeline
    from gcodeplan.report.viewer import build_viewer

    p = tmp_path / "part.gcode"
    original = CUBE.read_bytes()
    p.write_bytes(original)
    real_run = pipeline.run

    def run_then_change(*a, **kw):
        res = real_run(*a, **kw)
        p.write_bytes(original[: len(original) // 2])
        return res

    monkeypatch.setattr(pipeline, "run", run_then_change)
    with pytest.raises(GcodeError, match="changed between two passes"):
        build_viewer(p, Machine(flavor="klipper"))


def test_a_signal_while_spooling_standard_input_leaves_no_copy(tmp_path):
    """SIGTERM while ``view -`` copies a pipe that is still open: exit 143, one line, the copy removed."""
    import signal
    import time

    spool_dir = tmp_path / "tmp"
    spool_dir.mkdir()
    proc = subprocess.Popen([sys.executable, "-m", "gcodeplan.cli", "view", "-", "-o", str(tmp_path / "v.html")],
                            stdin=subprocess.PIPE, stderr=subprocess.PIPE, stdout=subprocess.PIPE,
                            env={**ENV, "TMPDIR": str(spool_dir)})
    proc.stdin.write(CUBE.read_bytes()[:100_000])
    proc.stdin.flush()
    deadline = time.monotonic() + 120
    while not list(spool_dir.iterdir()) and time.monotonic() < deadline:     # the copy has started
        time.sleep(0.05)
    assert [p.suffix for p in spool_dir.iterdir()] == [".spool"]
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    proc.stdin.close()
    assert proc.returncode == 128 + signal.SIGTERM
    assert err.decode().count("\n") == 1
    assert list(spool_dir.iterdir()) == [] and not (tmp_path / "v.html").exists()


def test_a_full_temporary_directory_is_one_line(tmp_path, monkeypatch):
    from gcodeplan.gcode.sources import spooled

    if not os.path.exists("/dev/full"):
        pytest.skip("no /dev/full")
    import tempfile

    class Full(io.RawIOBase):
        def readable(self):
            return True

        def readinto(self, b):
            b[:1] = b"G"
            return 1

    real = tempfile.mkstemp

    def mkstemp_on_full(*a, **kw):
        fd, name = real(*a, **kw)
        os.dup2(os.open("/dev/full", os.O_WRONLY), fd)     # writes fail with ENOSPC
        return fd, name

    monkeypatch.setattr(tempfile, "mkstemp", mkstemp_on_full)
    with pytest.raises(GcodeError, match=r"cannot keep a copy of the input in .*No space left"):
        with spooled(Full()):
            pass


def test_report_reads_standard_input_once(tmp_path):
    ref, got = tmp_path / "ref.html", tmp_path / "got.html"
    assert cli("report", CUBE, "-o", ref, "--slowest=0").returncode == 0
    with open(CUBE, "rb") as fh:
        out = cli("report", "-", "-o", got, "--slowest=0", stdin=fh)
    assert out.returncode == 0, out.stderr
    assert _page_texts(got.read_text()) == _page_texts(ref.read_text()) != b""
