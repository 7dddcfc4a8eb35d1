"""``python tools/bench.py startup [--runs N] [--big FILE] [--imports]``: start-up cost of ``gcodeplan estimate``.

Measured in one run, best of N fresh processes each (wall time; the machine is shared, so the best run is the
one least disturbed):

* a one-line G-code file: ``gcodeplan estimate -q`` against ``python -c pass``, ``python -c "import numpy"``
  and ``python -c "import numpy, numba"`` (target: ≤ 0.30 s). A file this small never imports numba: its
  kernels run as Python (gcodeplan/_jit.py), so its floor is Python + NumPy + gcodeplan's own modules;
* the 50 MB corpus file (``../shared/gcode/prusaslicer25_plate150_gyroid_big.gcode``, or ``--big``):
  ``gcodeplan estimate -q --json`` against a bare Python loop over its lines, ``for line in open(f)`` as the
  issue measured it (target: ≤ 5×); the loop over bytes, ``open(f, 'rb')``, is printed too.

The first, unmeasured run of each command is made with bytecode writing allowed, as ``pip install`` compiles
a package's ``.pyc`` files: where ``PYTHONDONTWRITEBYTECODE`` is set (this sandbox sets it) every later process
would otherwise compile gcodeplan's sources again (about 0.08 s here).

``--imports`` also prints the modules the tiny estimate imports, heaviest first (``python -X importtime``).
"""
from __future__ import annotations

import argparse
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("GCODEPLAN_SHARED", REPO.parent / "shared"))
BIG = SHARED / "gcode" / "prusaslicer25_plate150_gyroid_big.gcode"


CPU: dict[str, float] = {}     # command -> least CPU time (user + sys, s) of its runs


def best_of(cmd: list[str], runs: int) -> float:
    """Least wall time (s) of ``runs`` runs of ``cmd`` (output discarded; a failure stops the benchmark). The
    least CPU time (user + sys) goes to ``CPU[" ".join(cmd)]``: on a loaded machine it moves less than wall time."""
    best = float("inf")
    key = " ".join(cmd)
    for _ in range(runs):
        r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        best = min(best, time.perf_counter() - t0)
        r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
        CPU[key] = min(CPU.get(key, float("inf")), cpu)
    return best


def cpu_of(cmd: list[str]) -> float:
    return CPU[" ".join(cmd)]


def gcodeplan_cmd() -> list[str]:
    exe = shutil.which("gcodeplan")
    return [exe] if exe else [sys.executable, "-m", "gcodeplan.cli"]


def imports(tiny: Path) -> list[tuple[float, str]]:
    """(cumulative ms, module) of the top-level imports of ``gcodeplan estimate`` on ``tiny``."""
    out = subprocess.run([sys.executable, "-X", "importtime", "-c",
                          "import sys; from gcodeplan.cli import main; sys.exit(main(sys.argv[1:]))",
                          "estimate", "-q", str(tiny)], capture_output=True, text=True)
    rows = []
    for line in out.stderr.splitlines():
        parts = line.split("|")
        if len(parts) != 3 or "cumulative" in line:
            continue
        name = parts[2]
        if len(name) - len(name.lstrip()) <= 1:
            rows.append((int(parts[1]) / 1000.0, name.strip()))
    return sorted(rows, reverse=True)


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="bench.py startup", description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=7, help="fresh processes per figure (best is kept)")
    ap.add_argument("--big-runs", type=int, default=3)
    ap.add_argument("--big", type=Path, default=BIG, help="the big file (default: the 50 MB corpus file)")
    ap.add_argument("--imports", action="store_true", help="list the heaviest imports of the tiny estimate")
    args = ap.parse_args(argv)
    gp = gcodeplan_cmd()
    with tempfile.TemporaryDirectory() as tmp:
        tiny = Path(tmp) / "one_line.gcode"
        tiny.write_text("G1 X10 F600\n")
        warm_env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
        # warm the caches: .pyc files (as an install writes them) and numba's, for the small and the big path
        subprocess.run(gp + ["estimate", "-q", str(tiny)], check=True, stdout=subprocess.DEVNULL, env=warm_env)
        many = Path(tmp) / "many_lines.gcode"
        many.write_text("G1 X10 F600\nG1 X0\n" * 2000)
        subprocess.run(gp + ["estimate", "-q", str(many)], check=True, stdout=subprocess.DEVNULL, env=warm_env)
        # the least any numba program pays: NumPy, numba, numba's first-call set-up (BLAS probe skipped as the
        # CLI does) and one kernel loaded from numba's cache
        (Path(tmp) / "one_kernel.py").write_text(
            "import numba\n@numba.njit(cache=True)\ndef total(a):\n    s = 0.0\n    for x in a:\n"
            "        s += x\n    return s\n")
        floor = ("import sys, numpy; sys.path.insert(0, sys.argv[1]); sys.modules['scipy.linalg'] = None\n"
                 "import numba.np.arraymath\ndel sys.modules['scipy.linalg']\nimport one_kernel\n"
                 "one_kernel.total(numpy.zeros(3))")
        c_floor = [sys.executable, "-c", floor, tmp]
        subprocess.run(c_floor, check=True)                                 # compile it into the cache once
        c_py = [sys.executable, "-c", "pass"]
        c_np = [sys.executable, "-c", "import numpy"]
        c_libs = [sys.executable, "-c", "import numpy, numba"]
        c_est = gp + ["estimate", "-q", str(tiny)]
        c_many = gp + ["estimate", "-q", str(many)]
        py, npy, libs, fl, est, est_many = (best_of(c, args.runs)
                                            for c in (c_py, c_np, c_libs, c_floor, c_est, c_many))
        print(f"| what (best of {args.runs}) | wall s | CPU s |")
        print("|---|---:|---:|")
        print(f"| `python -c pass` | {py:.3f} | {cpu_of(c_py):.3f} |")
        print(f"| `python -c \"import numpy\"` | {npy:.3f} | {cpu_of(c_np):.3f} |")
        print(f"| `python -c \"import numpy, numba\"` | {libs:.3f} | {cpu_of(c_libs):.3f} |")
        print(f"| NumPy + numba + one cached kernel called (the floor of any numba program) | {fl:.3f} | "
              f"{cpu_of(c_floor):.3f} |")
        print(f"| `gcodeplan estimate` on a one-line file | {est:.3f} | {cpu_of(c_est):.3f} |")
        print(f"| `gcodeplan estimate` on a 4,000-line file ({many.stat().st_size // 1000} kB: compiled kernels) | "
              f"{est_many:.3f} | {cpu_of(c_many):.3f} |")
        print(f"one-line estimate {est:.3f} s: target 0.30 s {'met' if est <= 0.30 else 'MISSED'}")
        if args.imports:
            print("\nheaviest top-level imports of the one-line estimate (cumulative ms):")
            for ms, name in imports(tiny)[:25]:
                print(f"  {ms:8.1f}  {name}")
    if args.big.is_file():
        c_loop = [sys.executable, "-c", "import sys\nfor line in open(sys.argv[1]): pass", str(args.big)]
        c_loop_b = [sys.executable, "-c", "import sys\nfor line in open(sys.argv[1], 'rb'): pass", str(args.big)]
        c_big = gp + ["estimate", "-q", "--json", str(args.big)]
        loop, loop_b, big = (best_of(c, args.big_runs) for c in (c_loop, c_loop_b, c_big))
        mb = args.big.stat().st_size / 1e6
        print(f"\n| {args.big.name} ({mb:.0f} MB), best of {args.big_runs} | wall s | CPU s |")
        print("|---|---:|---:|")
        print(f"| bare Python line loop, `for line in open(f)` | {loop:.3f} | {cpu_of(c_loop):.3f} |")
        print(f"| the same over bytes, `open(f, 'rb')` | {loop_b:.3f} | {cpu_of(c_loop_b):.3f} |")
        print(f"| `gcodeplan estimate --json` | {big:.3f} | {cpu_of(c_big):.3f} |")
        print(f"ratio {big / loop:.2f}× wall, {cpu_of(c_big) / cpu_of(c_loop):.2f}× CPU "
              f"({big / loop_b:.2f}× the byte loop): target 5× {'met' if big <= 5 * loop else 'MISSED'}")
    else:
        print(f"\n{args.big} not found: big-file figure skipped")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
