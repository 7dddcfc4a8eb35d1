"""PrusaSlicer binary G-code: the decoder against libbgcode's own ASCII conversion, MeatPack against the
specification's table, and every kind of corruption as a one-line error naming the block.

The files under test are rebuilt here from the real one (its blocks re-compressed, re-encoded, split or
damaged) by a small writer that follows prusa3d/libbgcode ``doc/specifications.md``; it shares no code
with the decoder in ``gcodeplan.gcode.bgcode``.
"""
from __future__ import annotations

import gzip
import io
import json
import struct
import zlib

import heatshrink2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conftest import SAMPLES
from gcodeplan.cli import main
from gcodeplan.errors import GcodeError
from gcodeplan.gcode import read_moves
from gcodeplan.gcode.bgcode import meatpack_decode_bytes
from gcodeplan.gcode.sources import open_source
from gcodeplan.machine import Machine

BG = SAMPLES / "mini_cube_ps2.8.1.bgcode"
REF = SAMPLES / "mini_cube_ps2.8.1_ref.gcode"
NAMES = {0: "file metadata", 1: "G-code", 2: "slicer metadata", 3: "printer metadata", 4: "print metadata",
         5: "thumbnail"}


# ------------------------------------------------------------------ a small independent writer / splitter
def split_file(data: bytes):
    """(version, checksum type, blocks); each block a dict: type, comp, usize, csize, params, stored, offset,
    and ``payload`` (the data before compression), decompressed with zlib / heatshrink2 directly."""
    assert data[:4] == b"GCDE"
    version, checksum = struct.unpack_from("<IH", data, 4)
    off, blocks = 10, []
    while off < len(data):
        btype, comp, usize = struct.unpack_from("<HHI", data, off)
        hsize, csize = (8, usize) if comp == 0 else (12, struct.unpack_from("<I", data, off + 8)[0])
        psize = 6 if btype == 5 else 2
        params = data[off + hsize:off + hsize + psize]
        stored = data[off + hsize + psize:off + hsize + psize + csize]
        if comp == 0:
            payload = stored
        elif comp == 1:
            payload = zlib.decompress(stored)
        else:
            payload = heatshrink2.decompress(stored, window_sz2=11 if comp == 2 else 12, lookahead_sz2=4)
        assert len(payload) == usize
        blocks.append(dict(type=btype, comp=comp, usize=usize, csize=csize, params=params, stored=stored,
                           offset=off, payload=payload))
        off += hsize + psize + csize + (4 if checksum else 0)
    return version, checksum, blocks


def make_block(btype: int, comp: int, params: bytes, payload: bytes, checksum: int = 1, usize: int | None = None):
    """One block as the specification lays it out, compressed with ``comp``."""
    if comp == 0:
        stored = payload
    elif comp == 1:
        stored = zlib.compress(payload)
    else:
        stored = heatshrink2.compress(payload, window_sz2=11 if comp == 2 else 12, lookahead_sz2=4)
    usize = len(payload) if usize is None else usize
    head = struct.pack("<HHI", btype, comp, usize) + (b"" if comp == 0 else struct.pack("<I", len(stored)))
    body = head + params + stored
    return body + (struct.pack("<I", zlib.crc32(body)) if checksum else b"")


def make_file(blocks, checksum: int = 1, version: int = 1, comp=None) -> bytes:
    out = [b"GCDE" + struct.pack("<IH", version, checksum)]
    for b in blocks:
        c = b["comp"] if comp is None or b["type"] == 5 else comp    # thumbnails stay stored as they were
        out.append(make_block(b["type"], c, b["params"], b["payload"], checksum))
    return b"".join(out)


def with_crc(data: bytes, checksum: int = 1) -> bytes:
    """Recompute every block's CRC32 (after a deliberate edit of a header field)."""
    if not checksum:
        return data
    _, _, blocks = split_file_raw(data)
    buf = bytearray(data)
    for off, end in blocks:
        buf[end:end + 4] = struct.pack("<I", zlib.crc32(bytes(buf[off:end])))
    return bytes(buf)


def split_file_raw(data: bytes):
    """(version, checksum, [(block start, CRC position)]) from the headers alone (no decompression)."""
    version, checksum = struct.unpack_from("<IH", data, 4)
    off, out = 10, []
    while off < len(data):
        btype, comp, usize = struct.unpack_from("<HHI", data, off)
        hsize, csize = (8, usize) if comp == 0 else (12, struct.unpack_from("<I", data, off + 8)[0])
        end = off + hsize + (6 if btype == 5 else 2) + csize
        out.append((off, end))
        off = end + (4 if checksum else 0)
    return version, checksum, out


def machine():
    return Machine(flavor="klipper")


def assert_same_moves(a, b):
    assert a.dtype == b.dtype and len(a) == len(b) > 1000
    for f in a.dtype.names:
        assert np.array_equal(a[f], b[f], equal_nan=True), f


@pytest.fixture(scope="module")
def real():
    return BG.read_bytes()


@pytest.fixture(scope="module")
def reference():
    return read_moves(REF, machine())


# ------------------------------------------------------------------ the real file
def test_the_real_file_has_the_layout_the_specification_describes(real):
    version, checksum, blocks = split_file(real)
    assert (version, checksum) == (1, 1)
    assert [b["type"] for b in blocks] == [0, 3, 5, 5, 4, 2, 1]
    assert {b["comp"] for b in blocks} == {0, 1, 3}          # none, deflate, heatshrink 12,4
    assert struct.unpack("<H", blocks[-1]["params"])[0] == 2  # MeatPack with comments


def test_bgcode_moves_equal_those_of_its_ascii_reference_field_by_field(reference):
    ref_moves, ref_reader = reference
    moves, reader = read_moves(BG, machine())
    assert_same_moves(moves, ref_moves)                      # line numbers included: those of the conversion
    assert np.array_equal(reader.limits, ref_reader.limits)
    assert reader.layer_z == ref_reader.layer_z and reader.features == ref_reader.features
    s, r = reader.summary, ref_reader.summary
    assert s.lines == r.lines == REF.read_bytes().count(b"\n")
    assert s.slicer_estimate_s == r.slicer_estimate_s == 3 * 60 + 41   # "3m 41s" in the print metadata
    assert s.unknown_commands == r.unknown_commands and s.naive_time_s == r.naive_time_s


def test_decoded_text_is_the_gcode_part_of_the_reference_byte_for_byte():
    with open_source(BG) as src:
        text = src.stream.read()
        first, trailing = src.first_line, src.trailing_lines
    ref = REF.read_bytes().split(b"\n")[:-1]                  # file ends with a newline
    got = text.split(b"\n")[:-1]
    assert first == 226 and ref[first] == b"M73 P0 R3"        # the first G-code line of the conversion
    assert got == ref[first:first + len(got)]
    assert first + len(got) + trailing == len(ref)


def test_metadata_blocks_are_exposed():
    with open_source(BG) as src:
        md = src.bgcode.metadata
    assert md.file["Producer"] == "PrusaSlicer 2.8.1"
    assert md.printer["printer_model"] == "MK4S"
    assert md.print["estimated printing time (normal mode)"] == "3m 41s"
    assert md.slicer["layer_height"] == "0.2"
    assert [(t.format, t.width, t.height) for t in md.thumbnails] == [("QOI", 16, 16), ("QOI", 313, 173)]
    assert md.slicer_estimate_s == 221.0 and src.slicer_estimate_s == 221.0


def test_estimate_json_equals_the_reference(capsys):
    totals = []
    for path in (BG, REF):
        assert main(["estimate", "--json", "--quiet", str(path)]) == 0
        d = json.loads(capsys.readouterr().out)
        totals.append((d["total_time_s"], d["moves"], d["layer_count"], d.get("slicer_estimate_s")))
    assert totals[0] == totals[1]
    assert totals[0][3] == 221.0


def test_progress_counts_the_file_bytes():
    moves, reader = read_moves(BG, machine())
    assert reader.bytes_total == reader.bytes_read == BG.stat().st_size


# ------------------------------------------------------------------ every compression, encoding, block size
@pytest.mark.parametrize("comp", [0, 1, 2, 3])
@pytest.mark.parametrize("checksum", [0, 1])
def test_every_compression_and_checksum_gives_the_same_moves(real, reference, tmp_path, comp, checksum):
    _, _, blocks = split_file(real)
    p = tmp_path / "x.bgcode"
    p.write_bytes(make_file(blocks, checksum=checksum, comp=comp))
    moves, reader = read_moves(p, machine())
    assert_same_moves(moves, reference[0])
    assert reader.summary.slicer_estimate_s == 221.0


@pytest.mark.parametrize("block_bytes", [300, 4096, 65536])
def test_plain_gcode_blocks_split_anywhere_between_lines_give_the_same_moves(real, reference, tmp_path,
                                                                             block_bytes):
    """G-code encoding 0 (plain text), cut into blocks at line ends as libbgcode's writer cuts them."""
    _, _, blocks = split_file(real)
    text = b"".join(line + b"\n" for line in REF.read_bytes().split(b"\n")[226:2767])
    assert text.startswith(b"M73 P0 R3\n") and text.endswith(b"M73 Q100 S0\n")
    pieces, cur = [], b""
    for line in text.splitlines(keepends=True):
        if cur and len(cur) + len(line) > block_bytes:
            pieces.append(cur)
            cur = b""
        cur += line
    pieces.append(cur)
    gblocks = [dict(type=1, comp=1, params=struct.pack("<H", 0), payload=pc) for pc in pieces]
    p = tmp_path / "split.bgcode"
    p.write_bytes(make_file(blocks[:-1] + gblocks))
    moves, _ = read_moves(p, machine())
    assert_same_moves(moves, reference[0])


def test_gzipped_bgcode_is_read_through_both(real, reference, tmp_path):
    p = tmp_path / "x.bgcode.gz"
    p.write_bytes(gzip.compress(real))
    moves, reader = read_moves(p, machine())
    assert_same_moves(moves, reference[0])
    assert reader.bytes_read == reader.bytes_total == p.stat().st_size


def test_a_binary_file_object_is_read_like_the_file(real, reference):
    moves, reader = read_moves(io.BytesIO(real), machine())
    assert_same_moves(moves, reference[0])
    assert reader.path == "<stream>"


# ------------------------------------------------------------------ MeatPack against the table of the spec
# code: 0-9 digits, 10 '.', 11 ' ' ('E' in no-spaces mode), 12 '\n', 13 'G', 14 'X', 15 "full byte follows";
# low nibble first. Commands: FF FF FB packing on, FF FF FA off, FF FF F9 reset, FF FF F7 no-spaces on.
ON, OFF, RESET, NOSP = b"\xff\xff\xfb", b"\xff\xff\xfa", b"\xff\xff\xf9", b"\xff\xff\xf7"


def _pack(a: int, b: int) -> bytes:
    return bytes([(b << 4) | a])


@pytest.mark.parametrize("data,text", [
    # "G1 X10.5\n", spaces packed: (G,1) (' ',X) (1,0) (.,5) (\n, \n padding)
    (ON + _pack(13, 1) + _pack(11, 14) + _pack(1, 0) + _pack(10, 5) + _pack(12, 12), b"G1 X10.5\n"),
    # same line in no-spaces mode: the encoder dropped the space, the decoder puts it back before X
    (ON + NOSP + _pack(13, 1) + _pack(14, 1) + _pack(0, 10) + _pack(5, 12), b"G1 X10.5\n"),
    # 'Y' is not in the table: low nibble 15, the full byte follows, then the packed high character
    (ON + NOSP + _pack(13, 1) + _pack(15, 2) + b"Y" + _pack(12, 12), b"G1 Y2\n"),
    # second character not in the table: high nibble 15, the full byte follows
    (ON + _pack(13, 1) + _pack(11, 15) + b"F" + _pack(6, 12), b"G1 F6\n"),
    # neither packable: 0xFF then both characters as full bytes
    (ON + b"\xffM8" + _pack(12, 12), b"M8\n"),
    # code 11 is 'E' in no-spaces mode
    (ON + NOSP + _pack(13, 1) + _pack(11, 5) + _pack(12, 12), b"G1 E5\n"),
    # packing off: bytes are text (a comment line kept by "MeatPack with comments"), back on afterwards
    (OFF + b";LAYER_CHANGE\n" + ON + _pack(13, 0) + _pack(12, 12), b";LAYER_CHANGE\nG0\n"),
    # reset turns packing off; before any command the data is plain text
    (b"M17\n" + ON + _pack(13, 1) + _pack(12, 12) + RESET + b"M84\n", b"M17\nG1\nM84\n"),
    # an empty line is not written twice
    (ON + _pack(13, 1) + _pack(12, 12) + _pack(12, 12) + _pack(13, 0) + _pack(12, 12), b"G1\nG0\n"),
])
def test_meatpack_decodes_hand_made_bytes_by_the_table(data, text):
    assert meatpack_decode_bytes(data) == text


def test_meatpack_of_the_real_block_is_the_reference_text(real):
    _, _, blocks = split_file(real)
    decoded = meatpack_decode_bytes(blocks[-1]["payload"])
    lines = [ln for ln in decoded.split(b"\n") if ln.strip(b" \t").lstrip(b";").strip(b" \t")]
    assert lines == REF.read_bytes().split(b"\n")[226:226 + len(lines)]


# ------------------------------------------------------------------ corruption: one clear line, never an estimate
def _cli_error(capsys, path) -> str:
    assert main(["estimate", "--quiet", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


@pytest.mark.parametrize("index", range(7))
def test_a_flipped_byte_in_each_block_kind_is_a_crc_error_naming_the_block(real, tmp_path, capsys, index):
    _, _, blocks = split_file(real)
    b = blocks[index]
    at = b["offset"] + (8 if b["comp"] == 0 else 12) + len(b["params"]) + b["csize"] // 2
    bad = bytearray(real)
    bad[at] ^= 0x20
    p = tmp_path / "flip.bgcode"
    p.write_bytes(bytes(bad))
    msg = _cli_error(capsys, p)
    assert str(p) in msg and "CRC32 mismatch" in msg
    assert f"block {index} ({NAMES[b['type']]}) at byte {b['offset']}" in msg


@pytest.mark.parametrize("cut,needle", [
    (3, "not a binary G-code file"),                       # not even the magic
    (7, "truncated file: the file header"),
    (10, "no G-code block"),                               # header only
    (50, "block 0 (file metadata) at byte 10: truncated file"),
    (704 + 4, "block 2 at byte 704: truncated file: the block header"),
    (996 + 200, "block 3 (thumbnail) at byte 996: truncated file: the block data"),
    (16727 + 10, "block 6 (G-code) at byte 16727: truncated file: the compressed size"),
    (16727 + 14, "block 6 (G-code) at byte 16727: truncated file: the block data"),
    (26843 - 2, "block 6 (G-code) at byte 16727: truncated file: the block checksum"),
])
def test_truncation_anywhere_is_an_error_naming_the_block(real, tmp_path, capsys, cut, needle):
    p = tmp_path / "cut.bgcode"
    p.write_bytes(real[:cut])
    msg = _cli_error(capsys, p)
    assert needle in msg and str(p) in msg


@pytest.mark.parametrize("fix_crc", [False, True])
def test_unknown_compression_is_named(real, tmp_path, capsys, fix_crc):
    bad = bytearray(real)
    bad[11823 + 2:11823 + 4] = struct.pack("<H", 7)        # print metadata block: compression 7
    data = with_crc(bytes(bad)) if fix_crc else bytes(bad)
    p = tmp_path / "comp.bgcode"
    p.write_bytes(data)
    assert "block 4 (print metadata) at byte 11823: unknown compression 7" in _cli_error(capsys, p)


def test_unknown_block_type_checksum_version_and_encoding_are_named(real, tmp_path, capsys):
    cases = []
    bad = bytearray(real)
    bad[11823:11825] = struct.pack("<H", 9)
    cases.append((bytes(bad), "block 4 (type 9) at byte 11823: unknown block type 9"))
    bad = bytearray(real)
    bad[4:8] = struct.pack("<I", 2)
    cases.append((bytes(bad), "binary G-code version 2 is not supported"))
    bad = bytearray(real)
    bad[8:10] = struct.pack("<H", 5)
    cases.append((bytes(bad), "unknown checksum type 5"))
    bad = bytearray(real)
    bad[16727 + 12:16727 + 14] = struct.pack("<H", 3)       # G-code encoding 3
    cases.append((with_crc(bytes(bad)), "block 6 (G-code) at byte 16727: unknown G-code encoding 3"))
    # metadata but no G-code at all (a file cut at a block boundary): never an estimate of nothing
    cases.append((b"GCDE" + struct.pack("<IH", 1, 0) + make_block(3, 0, b"\0\0", b"a=b\n", 0),
                  "no G-code block after 1 blocks"))
    # an unknown metadata encoding
    cases.append((b"GCDE" + struct.pack("<IH", 1, 1) + make_block(3, 0, b"\4\0", b"a=b\n"),
                  "block 0 (printer metadata) at byte 10: unknown metadata encoding 4"))
    for i, (data, needle) in enumerate(cases):
        p = tmp_path / f"bad{i}.bgcode"
        p.write_bytes(data)
        assert needle in _cli_error(capsys, p), needle


def test_sizes_that_do_not_match_the_data_are_named(real, tmp_path, capsys):
    _, _, blocks = split_file(real)
    head = b"GCDE" + struct.pack("<IH", 1, 1)
    meta = b"".join(make_block(b["type"], b["comp"], b["params"], b["payload"]) for b in blocks[:-1])
    g = blocks[-1]
    offset = len(head) + len(meta)
    for comp in (1, 3):
        for usize in (g["usize"] - 1, g["usize"] + 5):
            p = tmp_path / f"size{comp}_{usize}.bgcode"
            p.write_bytes(head + meta + make_block(1, comp, g["params"], g["payload"], usize=usize))
            msg = _cli_error(capsys, p)
            assert f"block 6 (G-code) at byte {offset}:" in msg and f"the header says {usize}" in msg
    p = tmp_path / "huge.bgcode"
    p.write_bytes(with_crc(head + meta + struct.pack("<HHII", 1, 1, 0xFFFFFFF0, 100) + b"\0" * 106))
    assert "implausible block size" in _cli_error(capsys, p)


def test_a_metadata_block_after_the_gcode_is_refused(real, tmp_path, capsys):
    p = tmp_path / "late.bgcode"
    p.write_bytes(real + make_block(4, 0, b"\0\0", b"x=1\n"))
    assert "block 7 (print metadata) at byte 26843: a print metadata block after the G-code" in _cli_error(capsys, p)


def test_wrong_magic_in_a_bgcode_named_file(real, tmp_path, capsys):
    p = tmp_path / "magic.bgcode"
    p.write_bytes(b"GCDF" + real[4:])
    assert "not a binary G-code file" in _cli_error(capsys, p)


def _read_or_gcode_error(data: bytes) -> None:
    try:
        read_moves(io.BytesIO(data), machine())
    except GcodeError:
        pass


@settings(max_examples=150, deadline=None)
@given(checksum=st.sampled_from([0, 1]), tail=st.binary(min_size=0, max_size=400))
def test_random_bytes_after_a_valid_header_raise_nothing_but_gcode_error(checksum, tail):
    _read_or_gcode_error(b"GCDE" + struct.pack("<IH", 1, checksum) + tail)


_random_block = st.tuples(st.integers(0, 6), st.integers(0, 4), st.integers(0, 600), st.integers(0, 600),
                          st.integers(0, 3), st.binary(max_size=600))


@settings(max_examples=300, deadline=None)
@given(blocks=st.lists(_random_block, min_size=1, max_size=4), tail=st.binary(max_size=20))
def test_random_blocks_without_checksums_raise_nothing_but_gcode_error(blocks, tail):
    """Plausible headers (known types and compressions, small sizes) over random data, no CRC to stop
    them: every decoder (deflate, heatshrink, MeatPack) and then the G-code reader see garbage."""
    out = [b"GCDE" + struct.pack("<IH", 1, 0)]
    for btype, comp, usize, csize, enc, data in blocks:
        out.append(struct.pack("<HHI", btype, comp, usize) + (struct.pack("<I", csize) if comp else b""))
        out.append(struct.pack("<HHH", enc, 16, 16) if btype == 5 else struct.pack("<H", enc))
        out.append(data)
    _read_or_gcode_error(b"".join(out) + tail)


# packed pairs only (codes 0..14): decodes to lines of digits, '.', ' ', 'G', 'X' that the reader must judge
_packed_text = st.lists(st.tuples(st.integers(0, 14), st.integers(0, 14)), max_size=600).map(
    lambda pairs: ON + bytes((hi << 4) | lo for lo, hi in pairs))


@settings(max_examples=200, deadline=None)
@given(enc=st.sampled_from([1, 2]), payload=st.one_of(st.binary(max_size=2000), _packed_text))
def test_random_meatpack_payloads_reach_the_reader_without_tracebacks(enc, payload):
    """A well-formed G-code block whose MeatPack payload is random: decoded garbage goes to the reader."""
    data = b"GCDE" + struct.pack("<IH", 1, 1) + make_block(1, 0, struct.pack("<H", enc), payload)
    _read_or_gcode_error(data)


@settings(max_examples=150, deadline=None)
@given(pos=st.integers(min_value=10, max_value=26842), value=st.integers(min_value=0, max_value=255))
def test_any_changed_byte_of_the_real_file_is_caught(pos, value):
    real = BG.read_bytes()
    if real[pos] == value:
        return
    bad = bytearray(real)
    bad[pos] = value
    with pytest.raises(GcodeError, match="binary G-code block"):
        read_moves(io.BytesIO(bytes(bad)), machine())


def test_a_bad_gcode_line_is_named_by_its_line_in_the_ascii_conversion(real, tmp_path, capsys):
    _, _, blocks = split_file(real)
    lines = REF.read_bytes().split(b"\n")[226:2767]
    lines[100] = b"G1 X1.2.3"                                  # line 327 of the conversion
    payload = b"".join(ln + b"\n" for ln in lines)
    p = tmp_path / "badline.bgcode"
    p.write_bytes(make_file(blocks[:-1] + [dict(type=1, comp=1, params=b"\0\0", payload=payload)]))
    assert f"{p}:327: " in _cli_error(capsys, p)
