"""Progress bars follow the work, not the reading (issue 19): on a terminal only, never with --quiet.

The reader reads megabytes ahead (in a second thread), so a bar of bytes read reaches 100 % long before the
planner and the sinks are done. The bar is fed :class:`gcodeplan.pipeline.WorkBytes`: the input bytes
up to the line of the last move every sink has handled.
"""
from __future__ import annotations

import os
import re
import select
import subprocess
import sys

import numpy as np
import pytest

from gcodeplan import pipeline


def _uniform_gcode(path, n_moves: int) -> int:
    """A printer program of ``n_moves`` equal-length lines (each about 30 bytes): bytes and moves in step."""
    rng = np.random.default_rng(7)
    xy = rng.uniform(10.0, 190.0, size=(n_moves, 2))
    body = "".join(f"G1 X{x:07.3f} Y{y:07.3f} F6000\n" for x, y in xy)
    text = "G28\nG90\n" + body
    path.write_text(text)
    return len(text.encode())


class _CountSink(pipeline.Sink):
    def __init__(self):
        self.moves = 0

    def add(self, piece):
        self.moves += len(piece.moves)


def test_progress_is_the_share_of_moves_the_sinks_have_handled(tmp_path):
    """Every progress value is within 5 % of the share of moves done (the lines are equal, so bytes and
    moves go together); with the reader's 8 MB chunks, bytes *read* said 100 % after the first batch."""
    path = tmp_path / "uniform.gcode"
    n = 120_000
    total = _uniform_gcode(path, n)
    sink = _CountSink()
    seen = []

    def progress(done):
        seen.append((sink.moves, done))

    pipeline.run(str(path), _machine(), sinks=[sink], progress=progress)
    assert len(seen) >= 5
    moves_share = np.array([m for m, _ in seen]) / n
    bytes_share = np.array([d for _, d in seen]) / total
    assert np.all(np.diff(bytes_share) >= 0)                 # a bar never goes back
    assert np.max(np.abs(bytes_share - moves_share)) < 0.05, list(zip(moves_share, bytes_share))[:5]


def test_work_bytes_interpolates_inside_a_chunk_read_before():
    """Hand-worked: chunk 1 = bytes 0–1000, lines 1–100; chunk 2 = bytes 1000–1500 read; the work at
    line 50 is at byte 500, at line 100 at byte 1000; past the chunks read before, the bytes per line of
    those chunks (10) carry on, never past the bytes read."""
    from gcodeplan.pipeline import WorkBytes

    w = WorkBytes()
    w.read(1000, 60)
    w.read(1000, 100)
    w.read(1500, 120)
    w.done(50)
    assert w.bytes_done() == 500
    w.done(100)
    assert w.bytes_done() == 1000
    w.done(130)
    assert w.bytes_done() == 1300
    w.done(400)
    assert w.bytes_done() == 1500


def test_work_bytes_uses_the_first_lines_bytes_per_line_in_the_first_chunk():
    from gcodeplan.pipeline import WorkBytes

    w = WorkBytes(line_bytes=30.0)
    w.read(8_000_000, 5000)
    w.done(1000)
    assert w.bytes_done() == 30_000
    assert pipeline.line_bytes(os.devnull) is None         # not a regular file: not read


def _machine():
    from gcodeplan.config import load_machine

    return load_machine("klipper")


# ----------------------------------------------------------------------------- on a terminal
def _in_pty(argv, env):
    """Run ``argv`` with stdin/stdout/stderr on a pseudo-terminal 100 columns wide; (exit code, output)."""
    import fcntl
    import struct
    import termios

    master, slave = os.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 100, 0, 0))
    proc = subprocess.Popen(argv, stdin=slave, stdout=slave, stderr=slave, env=env, close_fds=True)
    os.close(slave)
    out = b""
    try:
        while True:
            ready, _, _ = select.select([master], [], [], 1.0)
            if ready:
                try:
                    data = os.read(master, 65536)
                except OSError:          # EIO: the child closed the terminal
                    break
                if not data:
                    break
                out += data
            elif proc.poll() is not None:
                break
    finally:
        os.close(master)
    return proc.wait(timeout=300), out.decode("utf-8", "replace")


BAR = re.compile(r"(\d+)%\|")


def _env():
    env = dict(os.environ)
    env["GCODEPLAN_PROGRESS_DELAY"] = "0"      # the bar at once: no test waits a second
    return env


def _commands(path, tmp_path):
    return {
        "estimate": ["estimate", str(path)],
        "report": ["report", str(path), "-o", str(tmp_path / "r.html"), "--slowest", "0"],
        "view": ["view", str(path), "-o", str(tmp_path / "v.html")],
        "plot": ["plot", str(path), "--what", "velocity", "--lines", "3:40", "-o", str(tmp_path / "p.png")],
        "steps": ["steps", str(path), "-o", str(tmp_path / "s.npz")],
    }


@pytest.fixture(scope="module")
def big_uniform(tmp_path_factory):
    path = tmp_path_factory.mktemp("progress") / "uniform.gcode"
    _uniform_gcode(path, 80_000)
    return path


@pytest.mark.parametrize("command", ["estimate", "report", "view", "plot", "steps"])
def test_a_terminal_shows_the_work_progressing(command, big_uniform, tmp_path):
    argv = [sys.executable, "-m", "gcodeplan.cli", *_commands(big_uniform, tmp_path)[command]]
    rc, out = _in_pty(argv, _env())
    assert rc == 0, out[-2000:]
    shares = [int(p) for p in BAR.findall(out)]
    assert shares, f"no progress bar on a terminal: {out[-500:]!r}"
    assert shares == sorted(shares)
    if command != "plot":     # the plot stops reading after its window: its bar ends early
        assert any(0 < p < 100 for p in shares), shares      # the bar moved with the work


@pytest.mark.parametrize("command", ["estimate", "view"])
def test_quiet_or_no_terminal_prints_no_bar(command, big_uniform, tmp_path):
    argv = [sys.executable, "-m", "gcodeplan.cli", *_commands(big_uniform, tmp_path)[command]]
    rc, out = _in_pty(argv + ["--quiet"], _env())
    assert rc == 0 and not BAR.search(out), out[-500:]
    done = subprocess.run(argv, capture_output=True, text=True, env=_env(), timeout=300)
    assert done.returncode == 0 and not BAR.search(done.stderr) and not BAR.search(done.stdout), done.stderr
