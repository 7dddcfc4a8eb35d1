"""``python tools/bench.py linuxcnc [--runs N] [FILE]``: wall time of ``gcodeplan estimate`` with the linuxcnc
policy against the junction-deviation policy on the same LinuxCNC machine (target: within 3×)."""
from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SHARED = ROOT.parent / "shared"


def _wall(cmd: list[str], runs: int) -> float:
    best = float("inf")
    for _ in range(runs):
        t = time.perf_counter()
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
        best = min(best, time.perf_counter() - t)
    return best


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="bench.py linuxcnc")
    ap.add_argument("file", nargs="?", default=str(SHARED / "gcode" / "linuxcnc_stellabee1.ngc"))
    ap.add_argument("--ini", default=str(SHARED / "reference" / "linuxcnc" / "config" / "mill.ini"))
    ap.add_argument("--runs", type=int, default=3)
    a = ap.parse_args(argv)
    if not Path(a.file).exists() or not Path(a.ini).exists():
        print(f"missing {a.file} or {a.ini}", file=sys.stderr)
        return 2
    base = [sys.executable, "-m", "gcodeplan.cli", "estimate", a.file, "--linuxcnc-ini", a.ini, "-q"]
    t_lc = _wall(base + ["--policy", "linuxcnc"], a.runs)
    t_jd = _wall(base + ["--policy", "junction-deviation"], a.runs)
    print(f"{Path(a.file).name}: linuxcnc {t_lc:.2f} s, junction-deviation {t_jd:.2f} s, "
          f"ratio {t_lc / t_jd:.2f} (target ≤ 3), best of {a.runs}")
    return 0
