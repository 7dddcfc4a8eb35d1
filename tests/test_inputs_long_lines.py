"""A single line may take at most MAX_LINE_BYTES (1 MiB): a longer one is a GcodeError naming the file and
the line, found without holding more than about that much of it (a line without end on a pipe is not read
to its end). Interpreting a line costs up to ~85x its length in Python objects: unbounded, a 10 MB line
took 863 MB and a 1 GB line on standard input spun in malloc."""
from __future__ import annotations

import io

import numpy as np
import pytest

from gcodeplan.errors import GcodeError
from gcodeplan.gcode import GcodeReader, read_moves
from gcodeplan.machine import Machine

LIMIT = 1 << 20      # the documented limit; the module constant must agree


def words(n_bytes: int) -> bytes:
    return b"G1" + b" X1" * ((n_bytes - 2) // 3)


def test_the_limit_is_one_mebibyte():
    from gcodeplan.gcode import reader

    assert reader.MAX_LINE_BYTES == LIMIT


@pytest.mark.parametrize("chunk", [4096, 1 << 20, 8 << 20])
def test_a_line_of_millions_of_words_is_refused_naming_it(chunk):
    data = b"G28\nG1 X5 F600\n" + words(2 * LIMIT + 5) + b"\nG1 X10\n"
    with pytest.raises(GcodeError) as err:
        read_moves(io.BytesIO(data), Machine(flavor="klipper"), chunk_bytes=chunk)
    assert err.value.line == 3 and err.value.file == "<stream>"
    assert "line too long" in err.value.message


def test_the_length_is_told_when_the_line_ends_in_the_chunk():
    n = len(words(3 * LIMIT))
    data = b"G28\r" + words(3 * LIMIT) + b"\r\n"          # CR-only line 1, then the long one
    with pytest.raises(GcodeError, match=rf"<stream>:2: line too long \({n} bytes"):
        # the chunk named: tools/fuzz.py, run in the same process by tests/test_fuzz.py, shrinks the default
        read_moves(io.BytesIO(data), Machine(flavor="klipper"), chunk_bytes=8 << 20)


@pytest.mark.parametrize("tail", [b"", b"\n"])
def test_lines_up_to_the_limit_are_read(tail):
    comment = b";" + b"c" * (LIMIT - 1)                   # exactly the limit
    data = b"G28\n" + comment + b"\nG1 X5 F600\n" + comment + tail
    moves, r = read_moves(io.BytesIO(data), Machine(flavor="klipper"), chunk_bytes=4096)
    assert r.summary.lines == 4 and moves["x1"][-1] == 5.0
    with pytest.raises(GcodeError) as err:
        over = b"G28\n" + comment + b"\nG1 X5 F600\n" + comment + b"c" + tail      # one byte over
        read_moves(io.BytesIO(over), Machine(flavor="klipper"), chunk_bytes=4096)
    assert err.value.line == 4


class Endless(io.RawIOBase):
    """A pipe that never sends a newline (a 1 GB line on standard input): counts what was taken."""

    def __init__(self, head: bytes, total: int):
        self.head, self.left, self.taken = head, total, 0

    def readable(self):
        return True

    def readinto(self, b):
        n = min(len(b), 65536, self.left)
        if self.head:
            n = min(n, len(self.head))
            b[:n] = self.head[:n]
            self.head = self.head[n:]
        else:
            b[:n] = b"X" * n
        self.left -= n
        self.taken += n
        return n


@pytest.mark.parametrize("chunk", [4096, 8 << 20])
def test_a_line_without_end_is_not_read_to_its_end(chunk):
    src = Endless(b"G28\nG1 X1 F600\n;", 32 << 20)
    with pytest.raises(GcodeError) as err:
        read_moves(src, Machine(flavor="klipper"), chunk_bytes=chunk)
    assert err.value.line == 3 and "line too long" in err.value.message
    assert src.taken <= 2 * max(chunk, LIMIT) + 65536         # stopped soon after the limit, not at 32 MiB


def test_earlier_lines_are_interpreted_first():
    # the long line is refused only after the lines before it: an error there comes first
    data = b"G28\nFOO_BAR\n" + words(2 * LIMIT) + b"\n"
    with pytest.raises(GcodeError) as err:
        read_moves(io.BytesIO(data), Machine(flavor="klipper"), strict=True)
    assert err.value.line == 2 and "FOO_BAR" in err.value.message


def test_push_mode_bounds_a_line_too():
    r = GcodeReader(iter(()), Machine(flavor="klipper"))
    rows = r.feed(b"G90\nG1 X1 F600\n")
    assert np.concatenate(rows)["x1"].tolist() == [1.0]
    with pytest.raises(GcodeError) as err:
        r.feed(words(LIMIT + 10) + b"\n")
    assert err.value.line == 3
    r2 = GcodeReader(iter(()), Machine(flavor="klipper"))
    with pytest.raises(GcodeError):
        r2.feed(b";" + b"c" * (LIMIT + 1))                 # no newline yet: the tail is bounded as well
