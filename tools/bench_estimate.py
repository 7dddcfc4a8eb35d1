"""``python tools/bench.py estimate [--files F ...] [--peer-file F] [--no-peer]``

End-to-end ``gcodeplan estimate`` on each corpus file, as a user runs it: a fresh
interpreter per run (start-up and numba cache loading included), wall time and
peak RSS of that process (os.wait4). One warm-up run first so numba's cache is
hot; then the best of ``--repeat`` runs. Next to it, in the same run, the closest
Python peer (pyGCodeDecode, PyPI) on a smaller file, because it needs minutes and
gigabytes on the big ones.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
CORPUS = Path(os.environ.get("GCODEPLAN_SHARED", REPO.parent / "shared")) / "gcode"

PEER_SCRIPT = r"""
import sys
from pyGCodeDecode import gcode_interpreter as gi
sim = gi.simulation(gcode_path=sys.argv[1], machine_name="prusa_mini", verbosity_level=0)
print(sim.blocklist[-1].get_segments()[-1].t_end)
"""


def run_rss(cmd: list[str]) -> tuple[float, float, int, str]:
    """(wall s, peak RSS MB, exit code, stdout) of one child process; RSS from os.wait4 (Linux ru_maxrss is KiB)."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
    out = proc.stdout.read()
    _pid, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    proc.returncode = os.waitstatus_to_exitcode(status)
    return wall, usage.ru_maxrss / 1024.0, proc.returncode, out.decode()


def count_lines(path: Path) -> int:
    with open(path, "rb") as f:
        return sum(chunk.count(b"\n") for chunk in iter(lambda: f.read(1 << 24), b""))


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="bench.py estimate")
    ap.add_argument("--files", nargs="*", help="G-code files (default: every corpus file)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--peer-file", default=str(CORPUS / "prusaslicer25_cube20_marlin2.gcode"))
    ap.add_argument("--no-peer", action="store_true")
    args = ap.parse_args(argv)
    files = [Path(f) for f in args.files] if args.files else sorted(
        (p for p in CORPUS.glob("*") if p.suffix in (".gcode", ".ngc")), key=lambda p: p.stat().st_size)
    if not files:
        print(f"no files (looked in {CORPUS})", file=sys.stderr)
        return 2
    exe = [sys.executable, "-m", "gcodeplan.cli", "estimate", "--quiet", "--json"]
    run_rss(exe + [str(files[0])])  # warm numba's on-disk cache
    print("| file | lines | MB | wall s (best of %d) | lines/s | peak RSS MB | total time |" % args.repeat)
    print("|---|---:|---:|---:|---:|---:|---|")
    for f in files:
        lines = count_lines(f)
        best = None
        for _ in range(args.repeat):
            wall, rss, rc, out = run_rss(exe + [str(f)])
            if rc != 0:
                print(f"| {f.name} | {lines} | | failed (exit {rc}) | | | |")
                break
            if best is None or wall < best[0]:
                best = (wall, rss, out)
        if best is None:
            continue
        import json

        total = json.loads(best[2])["total_time_hms"]
        print(f"| {f.name} | {lines:,} | {f.stat().st_size / 1e6:.1f} | {best[0]:.2f} | "
              f"{lines / best[0]:,.0f} | {best[1]:.0f} | {total} |")
    if not args.no_peer:
        peer = Path(args.peer_file)
        try:
            import pyGCodeDecode  # noqa: F401
        except ImportError:
            print("\n(pyGCodeDecode not installed: `pip install pygcodedecode` to compare)")
            return 0
        lines = count_lines(peer)
        wall, rss, rc, _ = run_rss([sys.executable, "-c", PEER_SCRIPT, str(peer)])
        ours, ours_rss, _, _ = run_rss(exe + [str(peer)])
        print(f"\nSame run, {peer.name} ({lines:,} lines):\n")
        print("| tool | wall s | lines/s | peak RSS MB |")
        print("|---|---:|---:|---:|")
        print(f"| gcodeplan estimate | {ours:.2f} | {lines / ours:,.0f} | {ours_rss:.0f} |")
        if rc == 0:
            print(f"| pyGCodeDecode 1.5 (prusa_mini preset) | {wall:.2f} | {lines / wall:,.0f} | {rss:.0f} |")
        else:
            print(f"| pyGCodeDecode | failed (exit {rc}) | | |")
    return 0
