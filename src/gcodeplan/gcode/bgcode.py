"""PrusaSlicer binary G-code (``.bgcode``): a streaming decoder, block by block.

The format is specified in prusa3d/libbgcode ``doc/specifications.md`` (format version 1; summary and the
choices made here in ``docs/design.md``, "Binary G-code"). A file is a 10-byte header (magic ``GCDE``,
version, checksum type) and a sequence of blocks: file metadata (optional), printer metadata, thumbnails,
print metadata, slicer metadata, then G-code blocks. Every block is a header (type, compression,
uncompressed size, compressed size when compressed), type-specific parameters, the data and, when the file
header asks for it, a CRC32 of header + parameters + data. Data is stored plain, deflated (zlib), or
heatshrink-compressed (window 2^11 or 2^12, look-ahead 2^4); G-code data is plain text or MeatPack-encoded.

:class:`BgcodeStream` reads the metadata blocks when it is opened (they all precede the G-code) and then
decodes one G-code block per refill, so memory stays at one block (libbgcode writes at most 64 KiB of
G-code per block) whatever the file size. Only the G-code reaches the reader. Its text is the text
libbgcode's converter (``bgcode`` tool, PrusaSlicer's "export as ASCII") writes for the same file, empty
lines dropped as that converter drops them, and :attr:`BgcodeStream.first_line` counts the lines that
converter writes before the G-code (metadata and thumbnails as comments): line numbers in messages and
MOVE rows are those of the ASCII conversion, so a user can look them up there.

Anything inconsistent (CRC mismatch, truncated block, unknown block type / compression / encoding, sizes
that cannot be right, data that does not decompress to the stated size) raises
:class:`~gcodeplan.errors.GcodeError` naming the file and the block (index, type, byte offset).
"""
from __future__ import annotations

import io
import re
import struct
import zlib
from dataclasses import dataclass, field

from .._jit import njit
import numpy as np

from ..errors import GcodeError

MAGIC = b"GCDE"
VERSION = 1                       # the only format version the specification defines
FILE_HEADER_BYTES = 10            # magic u32, version u32, checksum type u16

CHECKSUM_NONE, CHECKSUM_CRC32 = 0, 1

BLOCK_FILE_METADATA = 0
BLOCK_GCODE = 1
BLOCK_SLICER_METADATA = 2
BLOCK_PRINTER_METADATA = 3
BLOCK_PRINT_METADATA = 4
BLOCK_THUMBNAIL = 5
BLOCK_NAMES = {
    BLOCK_FILE_METADATA: "file metadata",
    BLOCK_GCODE: "G-code",
    BLOCK_SLICER_METADATA: "slicer metadata",
    BLOCK_PRINTER_METADATA: "printer metadata",
    BLOCK_PRINT_METADATA: "print metadata",
    BLOCK_THUMBNAIL: "thumbnail",
}
# parameter bytes per block type: an encoding (u16), or format, width, height (3 × u16) for thumbnails
PARAM_BYTES = {t: (6 if t == BLOCK_THUMBNAIL else 2) for t in BLOCK_NAMES}

COMPRESSION_NONE, COMPRESSION_DEFLATE, COMPRESSION_HEATSHRINK_11_4, COMPRESSION_HEATSHRINK_12_4 = 0, 1, 2, 3
COMPRESSION_NAMES = {0: "none", 1: "deflate", 2: "heatshrink 11,4", 3: "heatshrink 12,4"}

ENCODING_NONE, ENCODING_MEATPACK, ENCODING_MEATPACK_COMMENTS = 0, 1, 2
GCODE_ENCODING_NAMES = {0: "none", 1: "MeatPack", 2: "MeatPack with comments"}
METADATA_ENCODING_INI, METADATA_ENCODING_JSON = 0, 1   # JSON: libbgcode's later slicer metadata variant
THUMBNAIL_FORMATS = {0: "PNG", 1: "JPG", 2: "QOI"}

# A block larger than this is refused as corrupt: libbgcode writes G-code blocks of at most 64 KiB and
# thumbnails of a few hundred KiB, and a bad size must not make us allocate gigabytes.
MAX_BLOCK_BYTES = 256 << 20
_READ_PIECE = 1 << 20


def _crc32_hex(value: int) -> str:
    return f"0x{value:08x}"


@dataclass
class BlockInfo:
    """One block as found in the file: its index (0 = first block after the file header), type,
    compression, sizes in bytes and the byte offset of its header from the start of the file."""

    index: int
    type: int
    compression: int
    uncompressed_size: int
    compressed_size: int
    offset: int

    @property
    def type_name(self) -> str:
        return BLOCK_NAMES.get(self.type, f"type {self.type}")

    def where(self) -> str:
        return f"binary G-code block {self.index} ({self.type_name}) at byte {self.offset}"


@dataclass
class Thumbnail:
    """A thumbnail block's parameters: image format name, width and height in pixels, data bytes."""

    format: str
    width: int
    height: int
    size: int


@dataclass
class BgcodeMetadata:
    """The metadata blocks of a binary G-code file as ``{key: value}`` text dictionaries (INI encoding;
    a JSON-encoded slicer block is kept whole under the key ``""``), the thumbnails, and the slicer's
    own print-time estimate (s) read from the print (else printer) metadata."""

    version: int = VERSION
    checksum: int = CHECKSUM_NONE
    file: dict[str, str] = field(default_factory=dict)
    printer: dict[str, str] = field(default_factory=dict)
    print: dict[str, str] = field(default_factory=dict)
    slicer: dict[str, str] = field(default_factory=dict)
    thumbnails: list[Thumbnail] = field(default_factory=list)
    slicer_estimate_s: float | None = None


# ------------------------------------------------------------------ MeatPack
# MeatPack (Scott Mudge's packing, used by Prusa firmware and libbgcode): two 4-bit codes per byte for the
# 15 commonest G-code characters, low nibble first; code 0b1111 says "this character follows as a full
# byte". 0xFF 0xFF <cmd> is a command: 251 packing on, 250 packing off, 249 reset (packing off), 247 / 246
# "no spaces" on / off (then code 0b1011 means 'E' instead of ' ', and the encoder removed the spaces of
# G lines, which the decoder puts back before every parameter letter).
MP_SIGNAL = 0xFF
MP_ENABLE_PACKING = 251
MP_DISABLE_PACKING = 250
MP_RESET_ALL = 249
MP_ENABLE_NO_SPACES = 247
MP_DISABLE_NO_SPACES = 246
MP_TABLE = b"0123456789. \nGX"          # codes 0..14; 15 = full byte follows
_MP_CODES = np.frombuffer(MP_TABLE, dtype=np.uint8).copy()
# Letters before which libbgcode's decoder re-inserts the space the no-spaces encoder removed, on lines
# that start with 'G' (G0/G1 X Y Z E F, G2/G3 I J R, G29 G P W H C A).
_MP_PARAMS = np.zeros(256, dtype=np.uint8)
for _c in b"XYZEFIJRGPWHCA":
    _MP_PARAMS[_c] = 1
_NL, _SP, _TAB, _SEMICOLON, _G, _E = ord("\n"), ord(" "), ord("\t"), ord(";"), ord("G"), ord("E")
MP_CODE_SPACE = MP_TABLE.index(b" ")   # 11, the code of ' ': 'E' while "no spaces" is on


@njit(cache=True)
def meatpack_decode(src, out):
    """Decode MeatPack bytes ``src`` (uint8) into ``out`` (uint8, at least ``4·len(src) + 16`` long);
    returns the number of bytes written, or -1 if ``out`` was too small (cannot happen at that size:
    a byte yields at most two characters, each with at most one re-inserted space).

    The decoder state starts afresh, as libbgcode decodes each G-code block on its own. As libbgcode's
    decoder does, a repeated newline is written once and, on lines starting with 'G', a space goes back
    before every parameter letter not already preceded by one (the no-spaces encoder removed them)."""
    codes = _MP_CODES
    params = _MP_PARAMS
    pending = np.empty(2, dtype=np.int64)
    n = 0
    packing = False
    no_spaces = False
    full_due = 0          # characters still to come as full bytes
    held = 0              # packed second character waiting for the full first one (0 = none)
    signals = 0           # 0xFF bytes seen in a row (two start a command)
    command = False
    add_space = False     # inside a G line
    for i in range(src.shape[0]):
        b = src[i]
        if b == MP_SIGNAL:
            if signals > 0:
                command = True
                signals = 0
            else:
                signals += 1
            continue
        if command:
            command = False
            if b == MP_ENABLE_PACKING:
                packing = True
            elif b == MP_DISABLE_PACKING or b == MP_RESET_ALL:
                packing = False
            elif b == MP_ENABLE_NO_SPACES:
                no_spaces = True
            elif b == MP_DISABLE_NO_SPACES:
                no_spaces = False
            continue
        k = 0
        if signals > 0:   # a lone 0xFF was data (both characters as full bytes follow)
            signals = 0
            pending[k] = MP_SIGNAL
            k += 1
        pending[k] = b
        k += 1
        for j in range(k):
            r = pending[j]
            c0 = -1
            c1 = -1
            if not packing:
                c0 = r
            elif full_due > 0:
                c0 = r
                if held > 0:
                    c1 = held
                    held = 0
                full_due -= 1
            else:
                lo = r & 0xF
                hi = r >> 4
                if lo == 0xF:
                    full_due += 1
                    if hi == 0xF:
                        full_due += 1
                    else:
                        held = _E if (hi == MP_CODE_SPACE and no_spaces) else codes[hi]
                else:
                    c0 = _E if (lo == MP_CODE_SPACE and no_spaces) else codes[lo]
                    if c0 != _NL:          # an odd line's last character is padded with '\n': ignored
                        if hi == 0xF:
                            full_due += 1
                        else:
                            c1 = _E if (hi == MP_CODE_SPACE and no_spaces) else codes[hi]
            for c in (c0, c1):
                if c < 0:
                    continue
                if n + 2 > out.shape[0]:
                    return -1
                new_line = False
                if c == _G and (n == 0 or out[n - 1] == _NL):
                    add_space = True
                    new_line = True
                elif c == _NL:
                    add_space = False
                if (not new_line) and add_space and (n == 0 or out[n - 1] != _SP) and params[c] == 1:
                    out[n] = _SP
                    n += 1
                if c != _NL or n == 0 or out[n - 1] != _NL:
                    out[n] = c
                    n += 1
    return n


@njit(cache=True)
def drop_empty_lines(buf, n):
    """Compact ``buf[:n]`` in place, dropping the lines that are empty once spaces/tabs and a leading
    ';' are stripped (libbgcode's converter drops them from the G-code it writes), and end the last
    line with a newline (``buf`` needs one spare byte). Returns the new length (bytes)."""
    w = 0
    s = 0
    while s < n:
        e = s
        while e < n and buf[e] != _NL:
            e += 1
        a = s
        b = e
        while a < b and (buf[a] == _SP or buf[a] == _TAB):
            a += 1
        while b > a and (buf[b - 1] == _SP or buf[b - 1] == _TAB):
            b -= 1
        if a < b and buf[a] == _SEMICOLON:
            a += 1
            while a < b and (buf[a] == _SP or buf[a] == _TAB):
                a += 1
        if a < b:
            for k in range(s, e):
                buf[w] = buf[k]
                w += 1
            buf[w] = _NL
            w += 1
        s = e + 1
    return w


def meatpack_decode_bytes(data: bytes) -> bytes:
    """MeatPack-decode ``data`` (one block, decoder state fresh) to G-code text bytes."""
    src = np.frombuffer(data, dtype=np.uint8)
    out = np.empty(4 * len(src) + 16, dtype=np.uint8)
    n = meatpack_decode(src, out)
    if n < 0:  # pragma: no cover - excluded by the buffer size
        raise ValueError("MeatPack output buffer too small")
    return out[:n].tobytes()


# ------------------------------------------------------------------ metadata helpers
_DURATION_RE = re.compile(r"\s*(?:(\d+)d)?\s*(?:(\d+)h)?\s*(?:(\d+)m)?\s*(?:(\d+)s)?\s*")


def parse_duration_s(text: str) -> float | None:
    """PrusaSlicer's ``1d 2h 3m 4s`` (any part optional) in seconds; None when unreadable."""
    m = _DURATION_RE.fullmatch(text)
    if not m or not any(m.groups()):
        return None
    d, h, mi, s = (int(g) if g else 0 for g in m.groups())
    return float(((d * 24 + h) * 60 + mi) * 60 + s)


def slicer_estimate_from(meta: dict[str, str]) -> float | None:
    """The slicer's total print time (s) from metadata keys, by the rule the ASCII reader applies to
    ``; estimated printing time`` comments: the first key in order that starts with ``estimated
    printing time`` and names the normal mode (or no mode at all)."""
    for key, value in meta.items():
        if key.startswith("estimated printing time") and ("normal" in key or "(" not in key):
            t = parse_duration_s(value)
            if t is not None:
                return t
    return None


def _parse_ini(data: bytes) -> list[tuple[str, str]]:
    """``key=value`` lines as pairs, in order (a line without '=' is not an entry)."""
    out = []
    for line in data.decode("utf-8", "replace").split("\n"):
        key, sep, value = line.partition("=")
        if sep:
            out.append((key, value))
    return out


def _b64_len(n: int) -> int:
    return 4 * ((n + 2) // 3)


# ------------------------------------------------------------------ the stream
class BgcodeStream(io.RawIOBase):
    """The G-code text of a binary G-code file, decoded block by block as it is read.

    ``raw`` is a readable binary object positioned at the file's first byte; ``name`` names the file in
    errors. Opening reads the file header and every block before the first G-code block (metadata and
    thumbnails, each CRC-checked); :attr:`metadata` holds them. :meth:`readinto` then serves the decoded
    G-code, one block at a time. :attr:`first_line` is the number of lines libbgcode's ASCII converter
    writes before the G-code, :attr:`trailing_lines` the number it writes after it (print and slicer
    metadata as comments), so that line numbers match that conversion.
    """

    def __init__(self, raw, name: str):
        super().__init__()
        self._raw = raw
        self.name = name
        self._pos = 0                 # bytes of the file consumed (offset of the next byte)
        self._index = 0               # index of the next block
        self._buf = b""
        self._off = 0
        self._gcode_blocks = 0
        self._done = False
        self._pending: tuple[BlockInfo, bytes] | None = None   # first G-code block header, already read
        self.metadata = BgcodeMetadata()
        self._entries: dict[int, int] = {}     # metadata entries per block type (the converter writes each)
        self.first_line = 0
        self.trailing_lines = 0
        self._read_file_header()
        self._read_metadata_blocks()

    # -------------------------------------------------------------- low level
    def _fail(self, msg: str, block: BlockInfo | None = None):
        where = f"{block.where()}: " if block is not None else ""
        raise GcodeError(f"{where}{msg}", self.name)

    def _read(self, n: int) -> bytes:
        """Up to ``n`` bytes (fewer only at the end of the file)."""
        parts = []
        left = n
        while left > 0:
            try:
                got = self._raw.read(min(left, _READ_PIECE))
            except OSError as err:
                raise GcodeError(f"cannot read: {err.strerror or err}", self.name) from None
            if not got:
                break
            parts.append(got)
            left -= len(got)
        data = b"".join(parts)
        self._pos += len(data)
        return data

    def _read_exact(self, n: int, what: str, block: BlockInfo | None = None) -> bytes:
        at = self._pos
        data = self._read(n)
        if len(data) != n:
            self._fail(f"truncated file: {what} needs {n} bytes at byte {at}, only {len(data)} left", block)
        return data

    def _read_file_header(self) -> None:
        head = self._read(FILE_HEADER_BYTES)
        if len(head) < 4 or head[:4] != MAGIC:
            self._fail("not a binary G-code file (no GCDE magic)")
        if len(head) < FILE_HEADER_BYTES:
            self._fail(f"truncated file: the file header needs {FILE_HEADER_BYTES} bytes, the file has {len(head)}")
        version, checksum = struct.unpack_from("<IH", head, 4)
        if version != VERSION:
            self._fail(f"binary G-code version {version} is not supported (this reader knows version {VERSION})")
        if checksum not in (CHECKSUM_NONE, CHECKSUM_CRC32):
            self._fail(f"unknown checksum type {checksum} in the file header (0 = none, 1 = CRC32)")
        self.metadata.version = version
        self.metadata.checksum = checksum

    def _read_block_header(self) -> tuple[BlockInfo, bytes] | None:
        """The next block's header (and its raw bytes), or None at the end of the file."""
        offset = self._pos
        first = self._read(8)
        if not first:
            return None
        index = self._index
        self._index += 1
        if len(first) < 8:
            raise GcodeError(f"binary G-code block {index} at byte {offset}: truncated file: the block header "
                             f"needs 8 bytes, only {len(first)} left", self.name)
        btype, comp, usize = struct.unpack("<HHI", first)
        info = BlockInfo(index, btype, comp, usize, usize, offset)
        if btype not in BLOCK_NAMES:
            self._fail(f"unknown block type {btype} (corrupt file?)", info)
        if comp not in COMPRESSION_NAMES:
            self._fail(f"unknown compression {comp} (0 none, 1 deflate, 2 heatshrink 11,4, 3 heatshrink 12,4)", info)
        head = first
        if comp != COMPRESSION_NONE:
            more = self._read_exact(4, "the compressed size", info)
            info.compressed_size = struct.unpack("<I", more)[0]
            head = first + more
        if info.uncompressed_size > MAX_BLOCK_BYTES or info.compressed_size > MAX_BLOCK_BYTES:
            self._fail(f"implausible block size ({info.uncompressed_size} bytes uncompressed, "
                       f"{info.compressed_size} stored; corrupt file?)", info)
        if comp != COMPRESSION_NONE and info.uncompressed_size == 0 and info.compressed_size > 0:
            self._fail("compressed data that claims to decompress to nothing (corrupt sizes)", info)
        return info, head

    def _read_block_body(self, info: BlockInfo, head: bytes) -> tuple[bytes, bytes]:
        """(parameters, stored data) of a block, CRC-checked."""
        params = self._read_exact(PARAM_BYTES[info.type], "the block parameters", info)
        data = self._read_exact(info.compressed_size, "the block data", info)
        if self.metadata.checksum == CHECKSUM_CRC32:
            stored = struct.unpack("<I", self._read_exact(4, "the block checksum", info))[0]
            computed = zlib.crc32(data, zlib.crc32(params, zlib.crc32(head)))
            if stored != computed:
                self._fail(f"CRC32 mismatch (stored {_crc32_hex(stored)}, computed {_crc32_hex(computed)}): "
                           "the file is corrupt", info)
        return params, data

    def _decompress(self, info: BlockInfo, data: bytes) -> bytes:
        comp = info.compression
        if comp == COMPRESSION_NONE:
            return data
        if comp == COMPRESSION_DEFLATE:
            try:
                d = zlib.decompressobj()
                out = d.decompress(data, info.uncompressed_size + 1)
                ok = d.eof and not d.unconsumed_tail
            except zlib.error as err:
                self._fail(f"deflate data does not decompress ({err})", info)
        else:
            import heatshrink2

            window = 11 if comp == COMPRESSION_HEATSHRINK_11_4 else 12
            try:
                out = heatshrink2.decompress(data, window_sz2=window, lookahead_sz2=4)
            except (ValueError, RuntimeError) as err:  # pragma: no cover - heatshrink2 accepts any bytes
                self._fail(f"heatshrink data does not decompress ({err})", info)
            ok = True
        if not ok or len(out) != info.uncompressed_size:
            self._fail(f"{COMPRESSION_NAMES[comp]} data decompresses to {len(out)}"
                       f"{'+' if len(out) > info.uncompressed_size else ''} bytes, the header says "
                       f"{info.uncompressed_size}", info)
        return out

    # -------------------------------------------------------------- metadata
    def _read_metadata_blocks(self) -> None:
        md = self.metadata
        while True:
            got = self._read_block_header()
            if got is None:
                break
            info, head = got
            if info.type == BLOCK_GCODE:
                self._pending = got
                break
            params, data = self._read_block_body(info, head)
            if info.type == BLOCK_FILE_METADATA and info.index != 0:
                self._fail("a file metadata block must be the first block", info)
            if info.type == BLOCK_THUMBNAIL:
                fmt, width, height = struct.unpack("<HHH", params)
                if info.compression != COMPRESSION_NONE:
                    self._decompress(info, data)
                md.thumbnails.append(Thumbnail(THUMBNAIL_FORMATS.get(fmt, f"format {fmt}"), width, height,
                                               info.uncompressed_size))
                continue
            (encoding,) = struct.unpack("<H", params)
            raw = self._decompress(info, data)
            if encoding == METADATA_ENCODING_INI:
                pairs = _parse_ini(raw)
            elif encoding == METADATA_ENCODING_JSON and info.type == BLOCK_SLICER_METADATA:
                pairs = [("", raw.decode("utf-8", "replace"))]
            else:
                self._fail(f"unknown metadata encoding {encoding} (0 = INI)", info)
            target = {BLOCK_FILE_METADATA: md.file, BLOCK_PRINTER_METADATA: md.printer,
                      BLOCK_PRINT_METADATA: md.print, BLOCK_SLICER_METADATA: md.slicer}[info.type]
            target.update(pairs)
            self._entries[info.type] = self._entries.get(info.type, 0) + len(pairs)
        md.slicer_estimate_s = slicer_estimate_from(md.print)
        if md.slicer_estimate_s is None:
            md.slicer_estimate_s = slicer_estimate_from(md.printer)
        self._count_ascii_lines()

    def _count_ascii_lines(self) -> None:
        """Lines libbgcode's converter writes around the G-code (see the module docstring): before it,
        ``; generated by …`` and two empty lines (plus ``; prepared by`` when present), one comment per
        printer metadata entry, per thumbnail an empty line, ``;``, the begin line, its base64 in rows of
        78 characters, the end line and ``;``, then one empty line; after it, one empty line, the print
        metadata, and the slicer configuration between ``begin``/``end`` lines with an empty line on
        each side."""
        md = self.metadata
        entries = self._entries
        before = 0
        if BLOCK_FILE_METADATA in entries:
            before += 3 + (1 if "Prepared by" in md.file else 0)
        before += entries.get(BLOCK_PRINTER_METADATA, 0)
        for th in md.thumbnails:
            before += 3 + -(-_b64_len(th.size) // 78) + 2
        self.first_line = before + 1
        after = 1 + entries.get(BLOCK_PRINT_METADATA, 0)
        json_block = "" in md.slicer
        legacy = entries.get(BLOCK_SLICER_METADATA, 0) - (1 if json_block else 0)
        if json_block:
            after += 4
        if legacy or not json_block:
            after += 4 + legacy
        self.trailing_lines = after

    # -------------------------------------------------------------- G-code
    def _next_gcode_block(self) -> bytes | None:
        if self._pending is not None:
            got, self._pending = self._pending, None
        else:
            got = self._read_block_header()
        if got is None:
            if self._gcode_blocks == 0:
                self._fail(f"no G-code block after {self._index} blocks (truncated file?)")
            return None
        info, head = got
        if info.type != BLOCK_GCODE:
            self._read_block_body(info, head)
            self._fail(f"a {info.type_name} block after the G-code blocks (corrupt file?)", info)
        params, data = self._read_block_body(info, head)
        (encoding,) = struct.unpack("<H", params)
        if encoding not in GCODE_ENCODING_NAMES:
            self._fail(f"unknown G-code encoding {encoding} (0 none, 1 MeatPack, 2 MeatPack with comments)", info)
        raw = self._decompress(info, data)
        self._gcode_blocks += 1
        src = np.frombuffer(raw, dtype=np.uint8)
        if encoding == ENCODING_NONE:
            out = np.empty(len(src) + 1, dtype=np.uint8)
            out[:len(src)] = src
            n = len(src)
        else:
            out = np.empty(4 * len(src) + 16, dtype=np.uint8)
            n = meatpack_decode(src, out)
            if n < 0:  # pragma: no cover - excluded by the buffer size
                self._fail("MeatPack data does not decode", info)
        n = drop_empty_lines(out, n)
        return out[:n].tobytes()

    def readable(self) -> bool:
        return True

    def readinto(self, b) -> int:
        """Copy decoded G-code into ``b``; 0 at the end of the file."""
        while self._off >= len(self._buf):
            if self._done:
                return 0
            nxt = self._next_gcode_block()
            if nxt is None:
                self._done = True
                self._buf = b""
                self._off = 0
                return 0
            self._buf, self._off = nxt, 0
        n = min(len(b), len(self._buf) - self._off)
        b[:n] = self._buf[self._off:self._off + n]
        self._off += n
        return n


def is_bgcode(head: bytes) -> bool:
    """True when ``head`` (the first bytes of a file) starts with the binary G-code magic."""
    return head[:4] == MAGIC


__all__ = ["BgcodeStream", "BgcodeMetadata", "BlockInfo", "Thumbnail", "MAGIC", "VERSION", "is_bgcode",
           "meatpack_decode", "meatpack_decode_bytes", "drop_empty_lines", "parse_duration_s",
           "slicer_estimate_from"]
