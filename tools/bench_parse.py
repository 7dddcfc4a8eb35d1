"""Parse benchmark: ``python tools/bench.py parse [--file F] [--small F] [--runs N]``.

End to end, in subprocesses (interpreter start, imports and numba cache loading included), on the largest
corpus file:

* ``gcodeplan parse FILE`` cold: an empty numba cache (``NUMBA_CACHE_DIR`` set to a fresh directory), so
  the kernels are compiled; then warm: the same cache, the kernels loaded from it (the normal case);
* the same, in-process: the reader's own time once the kernels are loaded (no start-up);
* a plain ``for line in open(FILE, 'rb'): pass`` loop, with and without the interpreter start;
* the ``gcodeparser`` package (PyPI), on a smaller file (it builds Python objects per line), as lines/s.

Peak RSS is the child's ``ru_maxrss`` (os.wait4); it would include the parent's size if the parent were
larger (pre-exec pages), which this small script is not. Prints a Markdown table.
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("GCODEPLAN_SHARED", REPO.parent / "shared"))
DEFAULT_FILE = SHARED / "gcode" / "prusaslicer25_plate150_gyroid_big.gcode"
DEFAULT_SMALL = SHARED / "gcode" / "cura413_ender3_cylinder30.gcode"


def _run(cmd: list[str], env: dict | None = None) -> tuple[float, float, int, str]:
    """(wall s, user+sys s, peak RSS MB, stdout) of one child process."""
    t0 = time.perf_counter()
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    out = p.stdout.read()
    err = p.stderr.read()
    _, status, ru = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t0
    p.returncode = os.waitstatus_to_exitcode(status)
    if p.returncode != 0:
        raise SystemExit(f"bench: {' '.join(cmd)} failed ({p.returncode}): {err.decode()[-500:]}")
    return wall, ru.ru_utime + ru.ru_stime, ru.ru_maxrss // 1024, out.decode()


def _lines(path: Path) -> int:
    n = 0
    with open(path, "rb") as fh:
        while block := fh.read(1 << 22):
            n += block.count(b"\n")
    return n


_IN_PROCESS = r"""
import sys, time
from gcodeplan.gcode import GcodeReader
from gcodeplan.gcode.scan import warm_up
from gcodeplan.machine import Machine
warm_up()
best = 1e9
for _ in range(int(sys.argv[2])):
    t = time.perf_counter()
    r = GcodeReader(sys.argv[1], Machine(flavor="klipper"))
    for b in r.batches():
        pass
    best = min(best, time.perf_counter() - t)
print(best)
"""

_PLAIN = "import sys\nfor line in open(sys.argv[1], 'rb'):\n    pass\n"
_PLAIN_TIMED = ("import sys, time\nt = time.perf_counter()\nfor line in open(sys.argv[1], 'rb'):\n    pass\n"
                "print(time.perf_counter() - t)\n")
_GCODEPARSER = ("import sys, time\nfrom gcodeparser import GcodeParser\nt = time.perf_counter()\n"
                "GcodeParser(open(sys.argv[1]).read())\nprint(time.perf_counter() - t)\n")


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="bench.py parse", description=__doc__.split("\n")[0])
    ap.add_argument("--file", type=Path, default=DEFAULT_FILE, help="file for gcodeplan and the plain loop")
    ap.add_argument("--small", type=Path, default=DEFAULT_SMALL, help="file for gcodeparser (slow)")
    ap.add_argument("--runs", type=int, default=3, help="warm runs (the best is reported)")
    args = ap.parse_args(argv)
    if not args.file.exists():
        print(f"bench: {args.file} not found (set GCODEPLAN_SHARED or give --file)", file=sys.stderr)
        return 2
    lines = _lines(args.file)
    size_mb = args.file.stat().st_size / 1e6
    py = sys.executable
    gp = shutil.which("gcodeplan")
    cmd = [gp] if gp else [py, "-m", "gcodeplan.cli"]
    cmd = cmd + ["parse", str(args.file), "--flavor", "klipper"]
    rows = []

    with tempfile.TemporaryDirectory(prefix="gcodeplan-bench-cache-") as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        wall, cpu, rss, _ = _run(cmd, env)
        rows.append(("gcodeplan parse, cold (numba compiles)", lines, wall, cpu, rss))
        best = None
        for _ in range(args.runs):
            r = _run(cmd, env)
            best = r if best is None or r[0] < best[0] else best
        rows.append(("gcodeplan parse, warm (numba cache)", lines, best[0], best[1], best[2]))
        _, _, rss_in, out = _run([py, "-c", _IN_PROCESS, str(args.file), str(args.runs)], env)
        t_in = float(out.strip().splitlines()[-1])
        rows.append(("gcodeplan reader in-process (no start-up)", lines, t_in, None, None))

    best = min((_run([py, "-c", _PLAIN, str(args.file)]) for _ in range(args.runs)), key=lambda r: r[0])
    rows.append(("plain `for line in file` (process)", lines, best[0], best[1], best[2]))
    _, _, _, out = _run([py, "-c", _PLAIN_TIMED, str(args.file)])
    rows.append(("plain `for line in file` (loop only)", lines, float(out.strip()), None, None))

    small_lines = _lines(args.small) if args.small.exists() else 0
    try:
        _, _, rss_gp, out = _run([py, "-c", _GCODEPARSER, str(args.small)])
        rows.append((f"gcodeparser 0.3 (PyPI), parse only, on {args.small.name}", small_lines,
                     float(out.strip()), None, rss_gp))
    except SystemExit as err:
        print(f"bench: gcodeparser not measured ({err}); pip install gcodeparser", file=sys.stderr)

    print(f"Parse benchmark: `{args.file.name}` ({size_mb:.1f} MB, {lines:,} lines), "
          f"{os.cpu_count()} CPUs, Python {sys.version.split()[0]}, load average "
          f"{os.getloadavg()[0]:.1f}\n")
    print("| what | lines | wall s | CPU s | lines/s (wall) | peak RSS MB |")
    print("|---|---:|---:|---:|---:|---:|")
    for name, n, wall, cpu, rss in rows:
        print(f"| {name} | {n:,} | {wall:.3f} | {'' if cpu is None else f'{cpu:.3f}'} | "
              f"{n / wall / 1e6:.2f} M | {'' if rss is None else rss} |")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
