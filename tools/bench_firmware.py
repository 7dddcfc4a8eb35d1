"""``python tools/bench.py firmware [--file F] [--repeat N]``

The firmware models as a user runs them: ``gcodeplan estimate`` in a fresh process (start-up and numba's
cache included), best of N wall times, each model beside the ``klipper`` policy on the same file, in the same
run, the two taking turns (the issue's target: at most 2× the klipper policy's time); then ``gcodeplan steps``
on the grbl model, in step pulses per second of wall time.

grbl has no E axis (an E word is its error:20), so the grbl rows run on a copy of the file without E words
(the same motion) beside the klipper policy on that copy; the Marlin rows run on the file as sliced beside the
klipper policy on it. The file defaults to the 50 MB PrusaSlicer plate in ../shared/gcode.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
CORPUS = Path(os.environ.get("GCODEPLAN_SHARED", REPO.parent / "shared")) / "gcode"
E_WORD = re.compile(rb"\s*[Ee][-+]?[0-9.]+")


def best_wall(cmd: list[str], repeat: int) -> tuple[float, str]:
    best, out = float("inf"), ""
    for _ in range(repeat):
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True)
        wall = time.perf_counter() - t0
        if proc.returncode != 0:
            raise SystemExit(f"{' '.join(cmd)}: exit {proc.returncode}: {proc.stderr.decode()[-400:]}")
        best, out = min(best, wall), proc.stdout.decode()
    return best, out


def without_e(src: Path, dst: Path) -> None:
    """Copy src to dst without E words (keeping every line, so line numbers stay)."""
    with open(src, "rb") as fi, open(dst, "wb") as fo:
        for line in fi:
            body, sep, comment = line.partition(b";")
            body = E_WORD.sub(b"", body)
            if body.strip().upper() in (b"G92", b"G1", b"G0"):    # only E moved: nothing left to do
                body = b""
            fo.write(body + sep + comment + (b"\n" if not (sep + comment).endswith(b"\n") and
                                               not body.endswith(b"\n") else b""))


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="bench.py firmware")
    ap.add_argument("--file", default=str(CORPUS / "prusaslicer25_plate150_gyroid_big.gcode"))
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)
    src = Path(args.file)
    if not src.is_file():
        print(f"{src} not found", file=sys.stderr)
        return 2
    exe = [sys.executable, "-m", "gcodeplan.cli"]
    with tempfile.TemporaryDirectory() as tmp:
        grbl_file = Path(tmp) / (src.stem + "_noE.gcode")
        without_e(src, grbl_file)
        # each model beside the klipper policy on the same file: grbl on the file without E words, Marlin on
        # the file as sliced (its extruder moves are part of its planning)
        groups = [[("grbl-1.1 (grbl preset)", grbl_file, ["--machine", "grbl", "--no-bounds"]),
                   ("klipper policy (klipper preset)", grbl_file, ["--machine", "klipper", "--no-bounds"])],
                  [("marlin-2.1.2 (marlin preset)", src, ["--machine", "marlin", "--no-bounds"]),
                   ("klipper policy (klipper preset)", src, ["--machine", "klipper", "--no-bounds"])]]
        est = ["estimate", "--quiet", "--json"]
        for rows in groups:                              # warm numba's on-disk cache
            for _name, f, opts in rows:
                best_wall(exe + est + opts + [str(f)], 1)
        print(f"file: {src.name} ({src.stat().st_size / 1e6:.1f} MB; "
              f"without E words {grbl_file.stat().st_size / 1e6:.1f} MB)\n")
        print("| model | file | wall s (best of %d) | × klipper policy | total time s |" % args.repeat)
        print("|---|---|---:|---:|---:|")
        for rows in groups:
            # the model and the klipper policy take turns, so that other work on a shared machine slows both
            # alike (all of one, then all of the other, put a change of load into the ratio)
            best = [(float("inf"), "")] * len(rows)
            for _ in range(args.repeat):
                for k, (_name, f, opts) in enumerate(rows):
                    wall, out = best_wall(exe + est + opts + [str(f)], 1)
                    if wall < best[k][0]:
                        best[k] = (wall, out)
            walls = [(name, f, wall, json.loads(out)["total_time_s"])
                     for (name, f, _opts), (wall, out) in zip(rows, best)]
            ref = walls[-1][2]
            for name, f, wall, total in walls:
                tag = "without E" if f == grbl_file else "as sliced"
                print(f"| {name} | {tag} | {wall:.2f} | {wall / ref:.2f} | {total:.3f} |")
        npz = Path(tmp) / "s.npz"
        wall, out = best_wall(exe + ["steps", "--machine", "grbl", "--no-bounds", "-o", str(npz), str(grbl_file)], 1)
        n = sum(int(m.group(1).replace(",", "")) for m in re.finditer(r": ([0-9,]+) steps", out))
        print(f"\ngcodeplan steps --machine grbl: {n:,} step pulses in {wall:.2f} s = {n / wall:,.0f} steps/s")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
