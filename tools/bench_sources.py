"""``python tools/bench.py sources [FILE] [--runs N]``: reading G-code from gzip and binary G-code.

From FILE (default: the 50 MB corpus file when ../shared is there, else the sample cube) it writes, in a
temporary folder, a ``.gcode.gz`` and a ``.bgcode`` (plain G-code in 64 KiB blocks, heatshrink 12,4 as
PrusaSlicer writes for Prusa printers, CRC32), then measures, best of N:

- decoding alone: MB/s of G-code text out of each source (plain, gzip, bgcode) and of the MeatPack kernel
  on the sample ``.bgcode``'s G-code block;
- ``gcodeplan estimate --json`` in a fresh process on the plain file, the gzip, the bgcode and stdin
  (``-``): wall seconds, and the totals, which must be identical.
"""
from __future__ import annotations

import argparse
import gzip
import json
import struct
import subprocess
import sys
import tempfile
import time
import zlib
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
BIG = REPO.parent / "shared" / "gcode" / "prusaslicer25_plate150_gyroid_big.gcode"
SAMPLE = REPO / "gcode_samples" / "prusaslicer25_cube20_marlin2.gcode"
SAMPLE_BG = REPO / "gcode_samples" / "mini_cube_ps2.8.1.bgcode"


def _block(btype: int, comp: int, params: bytes, payload: bytes) -> bytes:
    import heatshrink2

    stored = payload if comp == 0 else heatshrink2.compress(payload, window_sz2=12, lookahead_sz2=4)
    head = struct.pack("<HHI", btype, comp, len(payload)) + (b"" if comp == 0 else struct.pack("<I", len(stored)))
    body = head + params + stored
    return body + struct.pack("<I", zlib.crc32(body))


def write_bgcode(text: bytes, path: Path) -> None:
    """A version-1 file: printer and print metadata, then plain G-code cut at line ends into 64 KiB blocks."""
    out = [b"GCDE" + struct.pack("<IH", 1, 1),
           _block(3, 0, b"\0\0", b"printer_model=bench\n"),
           _block(4, 0, b"\0\0", b"estimated printing time (normal mode)=1h\n"),
           _block(2, 0, b"\0\0", b"bench=1\n")]
    cur, size = [], 0
    for line in text.splitlines(keepends=True):
        if cur and size + len(line) > 65536:
            out.append(_block(1, 3, b"\0\0", b"".join(cur)))
            cur, size = [], 0
        cur.append(line)
        size += len(line)
    if cur:
        out.append(_block(1, 3, b"\0\0", b"".join(cur)))
    path.write_bytes(b"".join(out))


def decode_rate(path: Path, runs: int) -> tuple[float, int]:
    from gcodeplan.gcode.sources import open_source

    best, n = float("inf"), 0
    for i in range(runs + 1):                    # the first run loads numba's cached kernels: not counted
        t = time.perf_counter()
        n = 0
        with open_source(path) as src:
            buf = bytearray(8 << 20)
            while k := src.stream.readinto(buf):
                n += k
        if i:
            best = min(best, time.perf_counter() - t)
    return n / best / 1e6, n


def meatpack_rate(runs: int) -> float:
    import numpy as np

    from gcodeplan.gcode.bgcode import meatpack_decode

    data = SAMPLE_BG.read_bytes()
    off = 10
    payload = b""
    while off < len(data):                       # find the sample's (MeatPack) G-code block
        btype, comp, usize = struct.unpack_from("<HHI", data, off)
        hsize, csize = (8, usize) if comp == 0 else (12, struct.unpack_from("<I", data, off + 8)[0])
        if btype == 1:
            import heatshrink2

            stored = data[off + hsize + 2:off + hsize + 2 + csize]
            payload = heatshrink2.decompress(stored, window_sz2=12, lookahead_sz2=4) if comp == 3 else stored
        off += hsize + (6 if btype == 5 else 2) + csize + 4
    src = np.frombuffer(payload * 64, dtype=np.uint8)
    out = np.empty(4 * len(src) + 16, dtype=np.uint8)
    meatpack_decode(src, out)
    best = float("inf")
    for _ in range(runs):
        t = time.perf_counter()
        meatpack_decode(src, out)
        best = min(best, time.perf_counter() - t)
    return len(src) / best / 1e6


def estimate_wall(arg: str, stdin: Path | None, runs: int) -> tuple[float, float]:
    best, total = float("inf"), float("nan")
    for _ in range(runs):
        t = time.perf_counter()
        with open(stdin, "rb") if stdin else open("/dev/null", "rb") as fh:
            out = subprocess.run(["gcodeplan", "estimate", "--json", "--quiet", arg], stdin=fh,
                                 capture_output=True, check=True)
        best = min(best, time.perf_counter() - t)
        total = json.loads(out.stdout)["total_time_s"]
    return best, total


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="bench.py sources", description=__doc__.splitlines()[0])
    ap.add_argument("file", nargs="?", type=Path, default=BIG if BIG.exists() else SAMPLE)
    ap.add_argument("--runs", type=int, default=3)
    args = ap.parse_args(argv)
    text = args.file.read_bytes()
    with tempfile.TemporaryDirectory() as tmp:
        gz = Path(tmp) / (args.file.name + ".gz")
        gz.write_bytes(gzip.compress(text, 6))
        bg = Path(tmp) / (args.file.stem + ".bgcode")
        write_bgcode(text, bg)
        print(f"{args.file.name}: {len(text) / 1e6:.2f} MB text, gzip {gz.stat().st_size / 1e6:.2f} MB, "
              f"bgcode (heatshrink 12,4) {bg.stat().st_size / 1e6:.2f} MB; best of {args.runs}\n")
        print("| source | decode MB/s (text out) | estimate wall s | total_time_s |")
        print("|---|---:|---:|---:|")
        totals = set()
        for label, path, arg, stdin in (("plain file", args.file, str(args.file), None),
                                        ("stdin (-)", args.file, "-", args.file),
                                        ("gzip", gz, str(gz), None),
                                        ("bgcode", bg, str(bg), None)):
            rate, _ = decode_rate(path, args.runs)
            wall, total = estimate_wall(arg, stdin, args.runs)
            totals.add(total)
            print(f"| {label} | {rate:,.0f} | {wall:.2f} | {total:.6f} |")
        print(f"\nMeatPack kernel: {meatpack_rate(args.runs):,.0f} MB/s of packed input")
        print("totals identical:", len(totals) == 1)
    return 0 if len(totals) == 1 else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
