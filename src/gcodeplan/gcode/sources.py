"""Where G-code comes from: any *source* turned into one binary stream for the reader.

A source is

- a path (``str`` or :class:`os.PathLike`); ``"-"`` is standard input, read as bytes;
- a file object, binary or text (read from where it stands; it is not closed);
- an iterable of lines, ``str`` or ``bytes``: each item is one line, with or without its newline.

Files and binary streams are recognised by their first bytes, not their names: gzip (``1f 8b``, e.g.
``.gcode.gz``) is decompressed as it is read (never whole, never to disk), PrusaSlicer's binary G-code
(``GCDE``, ``.bgcode``) is decoded block by block (:mod:`.bgcode`), anything else is G-code text.

:func:`open_source` returns a :class:`Source`: a display name for messages (the path, ``<stdin>``,
``<lines>``, a file object's name or ``<stream>``), a stream with ``readinto``, the input size in bytes
when known (``bytes_total``, for progress bars) and how many input bytes have been consumed so far
(``bytes_in``: compressed bytes for gzip and binary G-code, so a bar over ``bytes_total`` still ends at
100 %).

A regular file opened by path is checked when its end is reached: the same size, modification time and
inode as when it was opened, every byte of that size read, and the path still naming it. A file replaced,
truncated or rewritten while it was read is a :class:`GcodeError` naming it, never a plan of two versions
of it. A pass that reads the file again (``view``'s line texts, ``post-process``'s copy) opens it with
the first pass's :attr:`Source.identity`, so the two passes read the same bytes.

Inputs that cannot be read twice (standard input, a FIFO, ``<(…)``, file objects, iterables) are copied
once to a temporary file by :func:`spooled`, for the commands that need two passes.
"""
from __future__ import annotations

import gzip
import io
import os
import stat
import sys
import tempfile
import zlib
from contextlib import contextmanager
from collections.abc import Iterable

from ..errors import GcodeError

GZIP_MAGIC = b"\x1f\x8b"
_SNIFF_BYTES = 4
STDIN_NAME = "<stdin>"
LINES_NAME = "<lines>"
STREAM_NAME = "<stream>"
_CR, _LF = ord("\r"), ord("\n")


class _Input(io.RawIOBase):
    """A binary input that counts the bytes taken from it and can give back the few it sniffed."""

    def __init__(self, fh, name: str, path: str | None = None):
        super().__init__()
        self._fh = fh
        self._name = name
        self._head = b""
        self.count = 0                # bytes taken from the underlying object
        self._readinto = getattr(fh, "readinto", None)
        self._path = path
        self.st0 = None               # os.stat_result of a regular file opened by path, when opened
        self._checked = False
        if path is not None:
            try:
                st = os.fstat(fh.fileno())
                if stat.S_ISREG(st.st_mode):
                    self.st0, self._pos0 = st, fh.tell()
            except (AttributeError, OSError, ValueError, io.UnsupportedOperation):
                pass

    def changed(self, at_end: bool) -> str | None:
        """Why the regular file is not the one opened any more (None: it is, or it is no regular file).
        ``at_end``: the end was reached, so every byte of the size it had must have been read."""
        st0 = self.st0
        if st0 is None:
            return None
        try:
            st = os.fstat(self._fh.fileno())
        except (OSError, ValueError):
            return None
        if st.st_size != st0.st_size:
            return f"its size went from {st0.st_size} to {st.st_size} bytes"
        if st.st_mtime_ns != st0.st_mtime_ns:
            return "it was written to"
        if at_end and self.count != st0.st_size - self._pos0:
            return f"{self.count} of its {st0.st_size - self._pos0} bytes could be read"
        try:
            now = os.stat(self._path)
        except FileNotFoundError:
            return "it was removed"
        except OSError:
            return None
        if (now.st_dev, now.st_ino) != (st.st_dev, st.st_ino):
            return "another file was put in its place"
        return None

    def check_unchanged(self, at_end: bool = False) -> None:
        """Raise :class:`GcodeError` naming the file if it changed since it was opened (see :meth:`changed`)."""
        why = self.changed(at_end)
        if why is not None:
            raise GcodeError(f"the file changed while it was read ({why}): run gcodeplan again once it is "
                             "complete", self._name)

    def readable(self) -> bool:
        return True

    def _pull(self, b) -> int:
        try:
            if self._readinto is not None:
                got = self._readinto(b)
            else:
                data = self._fh.read(len(b))
                if not isinstance(data, (bytes, bytearray, memoryview)):
                    raise GcodeError(f"read() returned {type(data).__name__}, not bytes", self._name)
                got = len(data)
                b[:got] = data
        except OSError as err:
            raise GcodeError(f"cannot read: {err.strerror or err}", self._name) from None
        if got == 0 and len(b) and not self._checked and self.st0 is not None:
            self._checked = True      # the end of a regular file: is it still the file that was opened?
            self.check_unchanged(at_end=True)
        got = got or 0                # a non-blocking stream may answer None: treat as nothing yet
        self.count += got
        return got

    def readinto(self, b) -> int:
        if self._head:
            n = min(len(b), len(self._head))
            b[:n] = self._head[:n]
            self._head = self._head[n:]
            return n
        return self._pull(b)

    def sniff(self, n: int) -> bytes:
        """The first ``n`` bytes (fewer at the end of the input), left to be read again."""
        buf = bytearray(n)
        have = len(self._head)
        buf[:have] = self._head
        while have < n:
            with memoryview(buf) as mv:
                got = self._pull(mv[have:])
            if not got:
                break
            have += got
        self._head = bytes(buf[:have])
        return self._head


class _GzipInput(io.RawIOBase):
    """gzip decompressed as it is read; corrupt data is a :class:`GcodeError` naming the file."""

    def __init__(self, raw: _Input, name: str):
        super().__init__()
        self._gz = gzip.GzipFile(fileobj=raw, mode="rb")
        self._name = name

    def readable(self) -> bool:
        return True

    def readinto(self, b) -> int:
        try:
            return self._gz.readinto(b)
        except GcodeError:
            raise
        except (OSError, EOFError, zlib.error) as err:
            raise GcodeError(f"corrupt gzip data: {err}", self._name) from None

    def check_rest(self) -> None:
        """Read the rest of the stream only to check it: a flipped byte inside deflate data decodes to
        garbage text first and fails the CRC check only at the end of the member."""
        buf = bytearray(1 << 16)
        try:
            while self.readinto(buf):
                pass
        except (ValueError, OSError):   # closed or unreadable: nothing more to say than the first error
            pass

    def read(self, n: int = -1) -> bytes:
        try:
            return self._gz.read(n)
        except GcodeError:
            raise
        except (OSError, EOFError, zlib.error) as err:
            raise GcodeError(f"corrupt gzip data: {err}", self._name) from None


class _TextInput(io.RawIOBase):
    """A text file object read as UTF-8 bytes."""

    def __init__(self, fh, name: str):
        super().__init__()
        self._fh = fh
        self._name = name
        self._rest = b""
        self.count = 0

    def readable(self) -> bool:
        return True

    def readinto(self, b) -> int:
        while not self._rest:
            try:
                text = self._fh.read(max(1, len(b) // 4))
            except OSError as err:
                raise GcodeError(f"cannot read: {err.strerror or err}", self._name) from None
            except UnicodeDecodeError as err:
                raise GcodeError(f"cannot decode the text: {err}", self._name) from None
            if not text:
                return 0
            self._rest = text.encode("utf-8", "surrogateescape")
        n = min(len(b), len(self._rest))
        b[:n] = self._rest[:n]
        self._rest = self._rest[n:]
        self.count += n
        return n


class _LinesInput(io.RawIOBase):
    """An iterable of lines (str or bytes, newline optional) as one byte stream."""

    def __init__(self, lines: Iterable, name: str):
        super().__init__()
        self._it = iter(lines)
        self._name = name
        self._rest = b""
        self._item = 0
        self.count = 0

    def readable(self) -> bool:
        return True

    def _next_piece(self) -> bytes | None:
        parts = []
        size = 0
        for item in self._it:
            self._item += 1
            if isinstance(item, str):
                item = item.encode("utf-8", "surrogateescape")
            elif isinstance(item, (bytearray, memoryview)):
                item = bytes(item)
            elif not isinstance(item, bytes):
                raise GcodeError(f"line {self._item} of the iterable is {type(item).__name__}, not str or bytes",
                                 self._name)
            parts.append(item if item.endswith(b"\n") else item + b"\n")
            size += len(parts[-1])
            if size >= 1 << 16:
                break
        return b"".join(parts) if parts else None

    def readinto(self, b) -> int:
        if not self._rest:
            piece = self._next_piece()
            if piece is None:
                return 0
            self._rest = piece
        n = min(len(b), len(self._rest))
        b[:n] = self._rest[:n]
        self._rest = self._rest[n:]
        self.count += n
        return n


class Source:
    """An opened source (see the module docstring). Use as a context manager or call :meth:`close`.

    ``name``: display name for messages; ``stream``: binary, ``readinto`` gives G-code text bytes;
    ``bytes_total``: input size in bytes, None when unknown (pipes, file objects that cannot tell,
    iterables); ``bytes_in``: input bytes consumed so far; ``kind``: ``"text"``, ``"gzip"``,
    ``"bgcode"`` or ``"lines"``; ``bgcode``: the :class:`~.bgcode.BgcodeStream` (its ``metadata``)
    for binary G-code, else None; ``first_line`` / ``trailing_lines``: lines of the file's text
    before / after what the stream gives (the metadata libbgcode's converter writes as comments);
    ``slicer_estimate_s``: the slicer's own total time (s) when the container states it (binary G-code).
    """

    def __init__(self, name: str, stream, counter, bytes_total: int | None, kind: str, closers=()):
        self.name = name
        self.stream = stream
        self._counter = counter
        self.bytes_total = bytes_total
        self.kind = kind
        self.bgcode = None
        self.first_line = 0
        self.trailing_lines = 0
        self.slicer_estimate_s: float | None = None
        self.container = None          # the compressed layer under the stream (gzip), if any
        self._closers = list(closers)

    @property
    def identity(self) -> tuple | None:
        """(device, inode, size in bytes, modification time in ns) of a regular file opened by path, as
        it was when opened; None for anything else. :func:`open_source` takes it back to make sure a
        second pass reads the same file."""
        st = getattr(self._counter, "st0", None)
        return None if st is None else (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)

    def check_unchanged(self) -> None:
        """Raise :class:`GcodeError` if the regular file read has changed since it was opened (called when a
        line fails: a truncated or rewritten file explains a broken line better than the line does)."""
        check = getattr(self._counter, "check_unchanged", None)
        if check is not None:
            check()

    @property
    def bytes_in(self) -> int:
        """Input bytes consumed so far (compressed bytes for gzip / binary G-code)."""
        return self._counter.count

    def check_rest(self) -> None:
        """Raise the container's own error (corrupt gzip data) if the rest of the input has one: called when
        a line failed, since corrupt compressed data decodes to garbage lines before its checksum fails."""
        check = getattr(self.container, "check_rest", None)
        if check is not None:
            check()

    def close(self) -> None:
        """Close what this source opened (never a file object or stdin it was given)."""
        closers, self._closers = self._closers, []
        for fh in closers:
            try:
                fh.close()
            except OSError:
                pass

    def __enter__(self) -> "Source":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _open_path(path: str):
    try:
        fh = open(path, "rb")
    except IsADirectoryError:
        raise GcodeError("is a directory, not a G-code file", path) from None
    except FileNotFoundError:
        raise GcodeError("no such file", path) from None
    except OSError as err:
        raise GcodeError(f"cannot read: {err.strerror or err}", path) from None
    return fh


def _size_of(fh) -> int | None:
    """Bytes from the current position to the end, when the object is a regular file."""
    try:
        st = os.fstat(fh.fileno())
        if not stat.S_ISREG(st.st_mode):
            return None
        return max(0, st.st_size - fh.tell())
    except (AttributeError, OSError, ValueError, io.UnsupportedOperation):
        return None


def _is_text(fh) -> bool:
    if isinstance(fh, io.TextIOBase):
        return True
    if isinstance(fh, (io.RawIOBase, io.BufferedIOBase)):
        return False
    try:
        return isinstance(fh.read(0), str)
    except Exception:  # noqa: BLE001 - an odd object: let reading it tell
        return False


def _binary(raw: _Input, name: str, size: int | None, closers: list) -> Source:
    """Recognise gzip / binary G-code / text by the first bytes of ``raw``."""
    head = raw.sniff(_SNIFF_BYTES)
    if name.lower().endswith(".bgcode") and head[:4] != b"GCDE" and head[:2] != GZIP_MAGIC:
        # named as binary G-code but not one: say so rather than "not a text file"
        raise GcodeError(f"not a binary G-code file: it starts with {head!r}, not the GCDE magic", name)
    stream = raw
    kind = "text"
    if head[:2] == GZIP_MAGIC:
        stream = _GzipInput(raw, name)
        kind = "gzip"
        inner = _Input(stream, name)          # a gzip holding a .bgcode is a .bgcode
        if inner.sniff(_SNIFF_BYTES)[:4] == b"GCDE":
            from .bgcode import BgcodeStream

            bg = BgcodeStream(inner, name)
            src = Source(name, bg, raw, size, "bgcode", closers)
            return _with_bgcode(src, bg)
        src = Source(name, inner, raw, size, kind, closers)
        src.container = stream                # the gzip layer: check_rest() asks it about the rest
        return src
    elif head[:4] == b"GCDE":
        from .bgcode import BgcodeStream

        bg = BgcodeStream(raw, name)
        return _with_bgcode(Source(name, bg, raw, size, "bgcode", closers), bg)
    return Source(name, stream, raw, size, kind, closers)


def _with_bgcode(src: Source, bg) -> Source:
    src.bgcode = bg
    src.first_line = bg.first_line
    src.trailing_lines = bg.trailing_lines
    src.slicer_estimate_s = bg.metadata.slicer_estimate_s
    return src


def open_source(source, *, identity: tuple | None = None) -> Source:
    """Open ``source`` (path, ``"-"``, file object or iterable of lines) for reading G-code.

    Raises :class:`GcodeError` naming the source when it cannot be read or its container is corrupt
    (a missing file, a bad binary G-code header or metadata block); :class:`TypeError` for an object
    that is none of these (a ``bytes`` object is not a source: wrap it in :class:`io.BytesIO`).
    ``identity``: a first pass's :attr:`Source.identity`; the path must still name that very file, unchanged.
    """
    if isinstance(source, (str, os.PathLike)):
        if isinstance(source, SpooledPath):
            fh = _open_path(source.path)
            try:
                return _binary(_Input(fh, source.name, source.path), source.name, _size_of(fh), [fh])
            except BaseException:
                fh.close()
                raise
        path = os.fsdecode(source)
        if path == "-":
            if sys.stdin is None:
                raise GcodeError("no standard input to read", STDIN_NAME)
            fh = sys.stdin.buffer if hasattr(sys.stdin, "buffer") else sys.stdin
            if _is_text(fh):
                counter = _TextInput(fh, STDIN_NAME)
                return Source(STDIN_NAME, counter, counter, None, "text")
            return _binary(_Input(fh, STDIN_NAME), STDIN_NAME, None, [])
        fh = _open_path(path)
        try:
            size = _size_of(fh)
            raw = _Input(fh, path, path)
            if identity is not None:
                st = raw.st0
                now = None if st is None else (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)
                if now != identity:
                    raise GcodeError("the file changed between two passes over it (replaced or written to): run "
                                     "gcodeplan again once it is complete", path)
            return _binary(raw, path, size, [fh])
        except BaseException:
            fh.close()
            raise
    if isinstance(source, (bytes, bytearray, memoryview)):
        raise TypeError("a bytes object is not a G-code source: pass a path, '-', a file object "
                        "(io.BytesIO(data)) or an iterable of lines")
    if hasattr(source, "read"):
        name = getattr(source, "name", None)
        name = name if isinstance(name, str) and name else STREAM_NAME
        if _is_text(source):
            counter = _TextInput(source, name)
            return Source(name, counter, counter, None, "text")
        return _binary(_Input(source, name), name, _size_of(source), [])
    if isinstance(source, Iterable):
        counter = _LinesInput(source, LINES_NAME)
        return Source(LINES_NAME, counter, counter, None, "lines")
    raise TypeError(f"{type(source).__name__} is not a G-code source: pass a path, '-', a file object or an "
                    "iterable of lines")


def source_name(source) -> str:
    """The display name :func:`open_source` would give ``source``, without opening it."""
    if isinstance(source, SpooledPath):
        return source.name
    if isinstance(source, (str, os.PathLike)):
        path = os.fsdecode(source)
        return STDIN_NAME if path == "-" else path
    if hasattr(source, "read"):
        name = getattr(source, "name", None)
        return name if isinstance(name, str) and name else STREAM_NAME
    return LINES_NAME


# ------------------------------------------------------------------ inputs read twice
class SpooledPath(os.PathLike):
    """The temporary copy :func:`spooled` made of a source that cannot be read twice: opened by its path
    (``os.fspath``), named in messages as the source (``name``, also ``str()``)."""

    def __init__(self, path: str, name: str):
        self.path = path
        self.name = name

    def __fspath__(self) -> str:
        return self.path

    def __str__(self) -> str:
        return self.name

    def __repr__(self) -> str:
        return f"SpooledPath({self.path!r}, name={self.name!r})"


def _raw_input(source):
    """(binary stream with ``readinto`` giving the source's bytes as they are, file to close or None)."""
    if isinstance(source, (str, os.PathLike)):
        path = os.fsdecode(source)
        if path == "-":
            if sys.stdin is None:
                raise GcodeError("no standard input to read", STDIN_NAME)
            fh = sys.stdin.buffer if hasattr(sys.stdin, "buffer") else sys.stdin
            return (_TextInput(fh, STDIN_NAME) if _is_text(fh) else _Input(fh, STDIN_NAME)), None
        fh = _open_path(path)
        return _Input(fh, path, path), fh
    if hasattr(source, "read"):
        name = source_name(source)
        return (_TextInput(source, name) if _is_text(source) else _Input(source, name)), None
    if isinstance(source, (bytes, bytearray, memoryview)) or not isinstance(source, Iterable):
        open_source(source)           # the TypeError it gives for what is no source
    return _LinesInput(source, LINES_NAME), None


def rereadable(source) -> bool:
    """True when ``source`` can be read twice as it is: the path of a regular file (or of something that
    is not there, for :func:`open_source` to report), or a spool already."""
    if isinstance(source, SpooledPath):
        return True
    if not isinstance(source, (str, os.PathLike)) or os.fsdecode(source) == "-":
        return False
    try:
        st = os.stat(source)
    except (OSError, ValueError):
        return True
    return stat.S_ISREG(st.st_mode) or stat.S_ISDIR(st.st_mode)


@contextmanager
def spooled(source):
    """``with spooled(source) as src:`` ``src`` can be read twice: ``source`` itself when it is the path of a
    regular file, else a :class:`SpooledPath`, a copy of its bytes as they are (gzip stays gzip) in a
    temporary file that is removed when the block ends, on an error or a signal too (the registry of
    :mod:`gcodeplan.report.output`). Standard input ``-``, a FIFO, ``<(…)``, a character device, file
    objects and iterables of lines are copied. A full temporary directory is a one-line error."""
    if rereadable(source):
        yield source
        return
    from ..report.output import register, unregister
    from ..signals import held

    name = source_name(source)
    raw, fh = _raw_input(source)
    tmp = None
    try:
        folder = tempfile.gettempdir()
        try:
            with held():        # no signal between creating the file and registering it
                fd, tmp = tempfile.mkstemp(prefix=f"gcodeplan-{os.getpid()}-", suffix=".spool", dir=folder)
                register(tmp)
        except OSError as err:
            raise GcodeError(f"cannot keep a copy of the input in {folder} (it is read twice): "
                             f"{err.strerror or err}", name) from None
        buf = bytearray(1 << 20)
        try:
            with os.fdopen(fd, "wb") as out, memoryview(buf) as mv:
                while True:
                    n = raw.readinto(mv)          # a read error is a GcodeError naming the input
                    if not n:
                        break
                    out.write(mv[:n])
        except OSError as err:                    # writing: a full or read-only temporary directory
            raise GcodeError(f"cannot keep a copy of the input in {folder} (it is read twice): "
                             f"{err.strerror or err}", name) from None
        if fh is not None:
            fh.close()
            fh = None
        yield SpooledPath(tmp, name)
    finally:
        if fh is not None:
            fh.close()
        if tmp is not None:
            try:
                os.unlink(tmp)
            except OSError:
                pass
            unregister(tmp)


# ------------------------------------------------------------------ line ends
def cr_line_ends(buf: bytearray, lo: int, hi: int, final: bool) -> None:
    """Turn, in place, every CR of ``buf[lo:hi]`` that ends a line by itself (old Mac files) into LF.

    Marlin's and RepRapFirmware's line readers end a line at CR or LF, and slicers and editors read a
    file with CR-only line ends as lines; CRLF stays one line end (its CR is a blank to the parser).
    A CR at ``hi - 1`` is left alone unless ``final``: the LF that would make it a CRLF may come with the
    next read. Cost on files without lone CRs: one search for CR (two counts on CRLF files)."""
    i = buf.find(b"\r", lo, hi)
    if i < 0:
        return
    n_cr = buf.count(b"\r", i, hi)
    n_crlf = buf.count(b"\r\n", i, hi)
    pending = not final and buf[hi - 1] == _CR
    if n_cr == n_crlf + (1 if pending else 0):
        return
    import numpy as np

    end = hi - 1 if pending else hi
    # in place on the buffer's memory (a regex substitution made ~2 objects per line: +95 MB on 50 MB)
    arr = np.frombuffer(buf, np.uint8, count=end - i, offset=i)
    lone = arr == _CR
    lone[:-1] &= arr[1:] != _LF           # the last byte: a CR there is lone (a waiting one was left out)
    arr[lone] = _LF
    del arr, lone


def iter_lines(stream, chunk_bytes: int = 1 << 20):
    """The lines of a binary ``stream``, each with its own line end (LF, CRLF or a lone CR; the last line
    may have none): the lines the reader numbers (:func:`cr_line_ends`), for passes that copy the text."""
    rest = b""
    while True:
        chunk = stream.read(chunk_bytes)
        if not chunk:
            if rest:
                yield from rest.splitlines(keepends=True)
            return
        lines = (rest + chunk).splitlines(keepends=True)
        # the last piece may be a line not yet ended, or a CR whose LF comes with the next read
        rest = lines.pop() if lines else b""
        if rest.endswith(b"\n"):
            lines.append(rest)
            rest = b""
        yield from lines


__all__ = ["cr_line_ends", "iter_lines", "spooled", "rereadable", "SpooledPath", "Source", "open_source", "source_name", "GZIP_MAGIC", "STDIN_NAME", "LINES_NAME", "STREAM_NAME"]
